// A virtual gonioreflectometer: light source, detector, sample mounting,
// sampling plan, imperfections, and the aperture quadrature settings.
//
// Read from JSON (see README "Synthetic measurements"). Angles are given in
// degrees in JSON (keys end in _deg) and held in radians here. Units:
//  - source radiance L_s in W m^-2 sr^-1 (disc source), or the irradiance
//    E_perp in W m^-2 on a plane normal to a collimated beam;
//  - detector responsivity in electrons per joule of optical energy
//    (quantum efficiency times lambda / (h c)), exposure time in s;
//  - sample area in m^2 (area both illuminated and seen by the detector);
//  - read noise in electrons rms, dark current in electrons/s, ADC gain in
//    electrons per digital number (DN), full well in electrons.
#pragma once

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include <cstdint>
#include <string>
#include <vector>

namespace brdfkit::synth {

struct Source {
  enum class Kind { kCollimated, kDisc };
  Kind kind = Kind::kCollimated;
  double angular_radius = 0;                              // rad, disc only
  Eigen::Array3d radiance = Eigen::Array3d::Zero();       // W m^-2 sr^-1, disc only
  Eigen::Array3d irradiance = Eigen::Array3d::Constant(10.0);  // W m^-2 normal to the beam, collimated only

  // Irradiance on a plane normal to the beam axis: E_perp for a collimated
  // beam, L_s pi sin^2(r) for a uniform disc of angular radius r.
  Eigen::Array3d BeamIrradiance() const;
  // The factor that turns the aperture integral (sr-weighted over the source
  // cone) into power per unit area: L_s for a disc, E_perp for a collimated
  // beam, whose quadrature is one node of unit weight.
  Eigen::Array3d RadianceScale() const { return kind == Kind::kDisc ? radiance : irradiance; }
};

struct Detector {
  double angular_radius = 0;                                    // rad; 0 is an ideal point detector
  Eigen::Array3d responsivity = Eigen::Array3d::Constant(1e18);  // electrons per joule
  double exposure_time = 1e-3;                                  // s
};

struct SampleMount {
  double area = 1e-4;  // m^2
  // Misalignment: the true sample normal is R_y(tilt_y) R_x(tilt_x) e_z in
  // the instrument frame, while the instrument reports angles about e_z.
  double tilt_x = 0, tilt_y = 0;  // rad
  // Rotation taking instrument-frame directions to the true sample frame.
  Eigen::Matrix3d SampleFromLab() const;
};

struct SamplingPlan {
  enum class Kind { kFull, kInPlane, kMerl, kList, kRandom };
  Kind kind = Kind::kInPlane;
  // kFull: the product grid; kInPlane: theta_i and signed theta_o (phi_i = 0,
  // theta_o >= 0 at phi_o = pi, the specular side; theta_o < 0 at phi_o = 0).
  std::vector<double> theta_i, phi_i, theta_o, phi_o;  // rad
  // kMerl: every stride-th bin centre of the 90 x 90 x 180 half/difference grid.
  int merl_stride[3] = {1, 1, 1};
  // kList: a file of theta_i,phi_i,theta_o,phi_o rows, in radians or degrees.
  std::string list_file;
  bool list_degrees = false;
  // kRandom: count pairs, both directions uniform over the hemisphere.
  std::size_t random_count = 0;
  std::uint64_t random_seed = 0;
};

struct Imperfections {
  double jitter_source = 0, jitter_detector = 0;  // rad, std of each arm's pointing (per tangent axis)
  bool shot_noise = false;
  double read_noise = 0;        // electrons rms
  double dark_current = 0;      // electrons per second (its mean is subtracted, as a dark frame does)
  bool adc = false;
  int adc_bits = 16;
  double adc_gain = 1;          // electrons per DN
  bool saturation = false;
  double full_well = 0;         // electrons
  std::vector<double> hdr_exposures;  // s; empty: the detector's single exposure
  double drift_per_sample = 0;  // relative change of source output per sample, in plan order

  bool AnyNoise() const { return shot_noise || read_noise > 0 || dark_current > 0 || adc || saturation; }
  bool Any() const { return AnyNoise() || jitter_source > 0 || jitter_detector > 0 || drift_per_sample != 0; }
};

struct QuadratureSettings {
  int order = 0;            // 0: automatic, the smallest order meeting `tolerance`
  double tolerance = 1e-6;  // relative, for the automatic order
  int max_order = 10;
};

struct Instrument {
  Source source;
  Detector detector;
  SampleMount sample;
  SamplingPlan plan;
  QuadratureSettings quadrature;
  Imperfections imperfections;
};

// The built-in instrument (documented in README): collimated 10 W/m^2 beam,
// 1 degree detector, 1 cm^2 sample, in-plane plan, no imperfections.
Instrument DefaultInstrument();

// Parses and checks an instrument. `file` names the source in messages
// (e.g. "lab.json: detector.angular_radius_deg: expected a number").
// Relative list-file paths are taken relative to `base_dir`.
Instrument ParseInstrument(const nlohmann::json& j, const std::string& file, const std::string& base_dir = "");
// Reads an instrument file, or the sidecar (DATA.json) of a synthetic
// measurement, which records the instrument it was made with.
Instrument LoadInstrument(const std::string& path);

// The same JSON layout that ParseInstrument reads (round-trips).
nlohmann::json InstrumentToJson(const Instrument& inst);
// An RGB triple as the JSON array the instrument and camera-rig files hold.
nlohmann::json RgbJson(const Eigen::Array3d& rgb);

// Directions of one measurement as (theta, phi) pairs, radians.
struct PlannedPair {
  double theta_i, phi_i, theta_o, phi_o;
};

// Spherical angles to a unit vector in the local frame.
Eigen::Vector3d DirectionFromAngles(double theta, double phi);

}  // namespace brdfkit::synth
