// Image-based BRDF measurement: a pinhole camera looks at a flat or
// spherical sample lit by a distant or point light (Marschner et al. 1999,
// "Image-Based BRDF Measurement Including Human Skin").
//
// Rendering follows the camera measurement equation: a pixel at off-axis
// angle theta_p receives the image irradiance (Horn 1986, "Robot Vision",
// eq. 10.7; Kingslake's cos^4 law)
//   E_img = (pi / 4) (d / f)^2 cos^4(theta_p) L = (pi / 4) cos^4(theta_p) L / N^2,
// N = f / d the f-number, from the scene radiance
//   L = f_r(wi, wo) E_perp cos(theta_i),
// with E_perp the light's irradiance normal to its rays (a distant light's
// given irradiance, or I / r^2 for a point light of intensity I at distance
// r). The pixel collects E_img pitch^2 t of energy and responsivity turns it
// into electrons; the sensor noise model of noise.h (shot, read, dark, ADC,
// full well) then gives raw values. One ray through each pixel centre
// defines the pixel's geometry (no pixel footprint averaging).
//
// Raw images are OpenEXR float32 in DN (ADC on) or electrons (ADC off), one
// file per bracketed exposure. Reduction (OpenCV) subtracts the dark level,
// merges unsaturated exposures into an electron rate (as noise.h), divides by
// the cos^4 falloff, f-number, pixel area, exposure and responsivity to get
// L, and divides L by E_perp cos(theta_i) to get f_r at each pixel whose ray
// hits the sample with both directions above its horizon.
#pragma once

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include <cstdint>
#include <string>
#include <vector>

#include "brdf/model.h"
#include "data_synth/instrument.h"
#include "data_synth/table_io.h"

namespace brdfkit::synth {

struct CameraRig {
  // Camera: pinhole at `distance` from the sample centre along the direction
  // (view_theta, view_phi), looking at the centre, image rows along the
  // projection of -e_theta (sample "up" in the image when possible).
  double focal_length = 0.05;     // m
  double f_number = 8;            // N = f / d
  int width = 96, height = 64;    // pixels
  double pixel_pitch = 1e-4;      // m (large pixels keep test images small)
  double distance = 1.0;          // m
  double view_theta = 0, view_phi = 0;  // rad
  std::vector<double> exposures = {1e-2};  // s, bracketed
  Eigen::Array3d responsivity = Eigen::Array3d::Constant(1.4e18);  // electrons per joule
  // Sensor imperfections (jitter and drift are not used by the camera).
  Imperfections sensor;

  enum class Shape { kFlat, kSphere };
  Shape shape = Shape::kSphere;
  double size = 0.1;  // flat: side of the square sample (m); sphere: radius (m)

  enum class Light { kDistant, kPoint };
  Light light = Light::kDistant;
  double light_theta = 0, light_phi = 0;                       // distant: direction towards the light (rad)
  Eigen::Array3d irradiance = Eigen::Array3d::Constant(10.0);  // distant: W m^-2 normal to the rays
  Eigen::Vector3d light_position = Eigen::Vector3d(0, 0, 1);   // point: m
  Eigen::Array3d intensity = Eigen::Array3d::Constant(10.0);   // point: W sr^-1
};

CameraRig DefaultCameraRig();
CameraRig ParseCameraRig(const nlohmann::json& j, const std::string& file);
CameraRig LoadCameraRig(const std::string& path);
nlohmann::json CameraRigToJson(const CameraRig& rig);

// The geometry seen by one pixel.
struct PixelGeometry {
  bool hit = false;          // the ray meets the sample with wi and wo above its horizon
  Eigen::Vector3d wi, wo;    // local frame of the surface point (z = normal)
  double cos4 = 0;           // cos^4 of the off-axis angle
  Eigen::Array3d e_perp;     // light irradiance normal to its rays at the point, W m^-2
};
PixelGeometry CameraPixel(const CameraRig& rig, int x, int y);

struct CameraCapture {
  // Raw values per exposure, planar RGB: raw[k][c * width * height + y * width + x].
  std::vector<std::vector<float>> raw;
};

CameraCapture RenderCamera(const CameraRig& rig, const Model& model, const std::vector<double>& params,
                           std::uint64_t seed);

// Writes PREFIX_e<k>.exr per exposure (attributes record the exposure time)
// and PREFIX.json (rig, model, parameters, seed, version). Returns the image
// paths in exposure order.
std::vector<std::string> WriteCameraCapture(const std::string& prefix, const CameraRig& rig, const CameraCapture& cap,
                                            const std::string& model_spec, const std::vector<double>& params,
                                            std::uint64_t seed);

// Reduces raw images (one per rig exposure, in order) to BRDF samples, with
// sigma from the sensor noise model evaluated at the measured value.
BrdfTable ReduceCamera(const CameraRig& rig, const std::vector<std::string>& raw_files);

}  // namespace brdfkit::synth
