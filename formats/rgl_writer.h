// Writing RGL-EPFL tensor files (brdf/rgl.h) from any BRDF: a model, a sum
// of lobes, a fit result or a measured table, isotropic or anisotropic.
//
// The file is built so that the format's own reconstruction reproduces the
// source. The writer is free in the slices, the ndf and the vndf (the
// reconstruction needs only value x ndf / (4 sigma) right) and chooses them,
// after the acquisition of Dupuy & Jakob 2018 (sec. 4-5), for interpolation:
//  0. slices: theta_i nodes with spacing proportional to 0.6 +
//     cos(theta_i) (2.5 times as dense at grazing as at normal incidence:
//     the reflection's horizon moves fastest with theta_i there); an
//     isotropic file holds one phi_i slice (phi_i = 0), which the format's
//     readers take as constant in phi_i;
//  1. ndf: D(wm) from the retro-reflection, first D ~ f(wm, wm) cos^2
//     theta_m, then one step of the height-correlated Smith fixed point D ~
//     f(w, w) cos (2 sigma(w) - cos) (exact for such microfacet BRDFs, whose
//     G2(w, w) = cos / (2 sigma - cos)); floored at 1e-12 of its maximum so
//     that it follows the lobes' tails, normalised so that
//     int D cos(theta_m) dw = 1;
//  2. sigma(wi) = int D(m) <wi, m>+ dm, by the trapezoidal rule over the
//     ndf nodes;
//  3. vndf per slice (phi_i, theta_i), over the warped square (jacobian =
//     1), in aligned rows (each row one azimuth of wm; in isotropic files
//     the rows 90 degrees off wi weigh up to 3 times as much, the same in
//     every slice, so that the value rows lie denser where the horizon's
//     normal sweeps at grazing incidence; in anisotropic files all rows
//     weigh the same): a band around the horizon of wo whose density in cos(theta_o)
//     is the same in every row and slice (40 %, a Gaussian of width 0.2 in
//     cos(theta_o)), and the rest, visible normals (D(wm) + 0.2 sigma / pi)
//     <wi, wm>+ u_x sin(theta_m) plus a uniform density (regular at the
//     pole u_x = 0, where the visible normals vanish as u_x^3), faded out
//     near the horizon and scaled on its two sides so that every row's CDF
//     reaches 0.6 at the horizon. The values near the horizon are then one
//     smooth function of s across rows and slices (theta_i, and phi_i in
//     anisotropic files), which the bilinear and the slice interpolation
//     follow. Where the values f / D vary steeply along a row (sums of
//     lobes, whose ndf learnt from the retro-reflection crosses from one
//     lobe to the other elsewhere than f does), the visible normals are
//     raised to a density that keeps the linear interpolation's relative
//     error there near 0.15 %;
//  4. rgb at the uniform N x N nodes s of each slice: wm = V(s), the warp of
//     the float32 vndf as the reader builds it, wo the reflection of wi
//     about wm, value = f(wi, wo) cos(theta_o) 4 sigma(wi) / D(wm) with
//     sigma and D the reader's bilinear values; below the horizon the value
//     continues oddly in cos(theta_o) (minus the value at the mirror image
//     of wo), so that interpolation crosses zero at the horizon;
//     luminance is the Rec. 709 luminance of rgb, clipped at 0.
// At every node the reconstruction then returns f cos(theta_o) to float32
// rounding; between nodes its error is that of the interpolation, measured
// by MeasureRglAccuracy.
#pragma once

#include <Eigen/Core>

#include <functional>
#include <string>

#include "brdf/core.h"
#include "brdf/rgl.h"

namespace brdfkit::formats {

// f_r(wi, wo) in 1/sr per channel, unit directions in the upper hemisphere.
using BrdfFunction = std::function<Rgb<double>(const Eigen::Vector3d& wi, const Eigen::Vector3d& wo)>;

// The largest theta_max: beyond it a slice's rows (whose |cos(theta_o)|
// stays below cos(theta_i)) leave no room for both the band around the
// horizon and the rest, and the reconstruction fails (30-70 % errors
// between 85 and 88-88.5 degrees, bench/RESULTS.md).
constexpr double kRglThetaMaxDeg = 87.5;

// The incident azimuth slices over the whole circle of an anisotropic file
// when none are given (convert, Python's write): the blend of neighbouring
// slices at a fixed square coordinate is the anisotropic files' largest
// error and falls as the square of their spacing, so at about the same size
// 64 slices of smaller tables (vndf 48^2, values 40^2) beat 24 of 64^2
// (bench/RESULTS.md).
constexpr int kRglAnisotropicPhiI = 64;
// The slices of that spacing (2 pi / 63, or closer) over the 2 pi /
// symmetry a file holds: 64, 33 and 17 for symmetry 1, 2 and 4.
int RglAnisotropicSlices(int symmetry);

struct RglOptions {
  // Resolutions 0 are automatic (WithDefaults): isotropic files take the
  // resolution at which the reconstruction stays within 1 % (measured in
  // bench/RESULTS.md), anisotropic files, which store every table once per
  // phi_i slice, a coarser one.
  int theta_i = 0;           // incident elevation slices over [0, theta_max], denser toward grazing; 0: 80 isotropic, 32 anisotropic
  double theta_max_deg = kRglThetaMaxDeg;  // the last slice; (0, kRglThetaMaxDeg]
  int phi_i = 0;             // 0: isotropic; otherwise azimuth slices over [-pi, -pi + 2 pi / symmetry]
  // Anisotropic files: 1, the incident azimuths of the whole circle (the
  // last slice repeats the first); 2 or 4, those from -pi over pi or pi / 2
  // of a source unchanged by a turn by pi (2) or by both mirrors x -> -x
  // and y -> -y (4), which the format's readers fold queries into (Mitsuba
  // 3 reads such files; powitacq and pbrt-v4 refuse them): a given phi_i
  // then lies 2 or 4 times as dense, while convert's default
  // (RglAnisotropicSlices) keeps the whole circle's spacing in fewer
  // slices. MakeRgl checks the source's symmetry.
  int symmetry = 1;
  int ndf = 512;             // ndf resolution (square)
  int sigma = 64;            // sigma resolution (square)
  int vndf = 0;              // vndf rows per slice (azimuth of wm); 0: 512 isotropic, 48 anisotropic
  int vndf_theta = 0;        // vndf columns per slice (elevation of wm); 0: as vndf if given, else 128 isotropic, 48 anisotropic
  // The value (rgb and luminance) tables are samples x samples per slice:
  // the format's readers (Mitsuba 3's measured plugin, the reference loader
  // powitacq, pbrt-v4) refuse tables that are not square.
  int samples = 0;           // value table nodes per axis and slice; 0: 208 isotropic, 40 anisotropic
  std::string description = "written by brdfkit";
};

// The options with the automatic resolutions (0) filled in.
RglOptions WithDefaults(RglOptions options);

// Whether f stays the same (1e-6 relative, 1e-12 absolute) when both
// directions are mapped by `map`, at 64 fixed random direction pairs.
bool InvariantUnder(const BrdfFunction& f, const std::function<Eigen::Vector3d(const Eigen::Vector3d&)>& map);

// Throws std::invalid_argument on bad options (a symmetry the source lacks
// included), std::runtime_error on non-finite values of f.
TensorFile MakeRgl(const BrdfFunction& f, const RglOptions& options);
// Atomic: the complete file or nothing.
void WriteRgl(const std::string& path, const BrdfFunction& f, const RglOptions& options);

// Reconstruction error of `file` against f over a grid of directions: for
// each incident direction (theta_i from 0 to theta_max_deg in steps of
// step_deg, offset by half a step; azimuths 0, 50, 100 ... degrees for
// anisotropic files) and each outgoing direction on a 1 x 2 degree grid,
// relative error of f cos(theta_o) per channel, where the source value is
// above `threshold` times its maximum over wo for that wi and theta_o is
// below theta_o_max_deg.
struct RglAccuracy {
  double max_relative = 0;
  double mean_relative = 0;
  double p99_relative = 0;
  std::size_t points = 0;
  std::string where;  // the directions and the threshold measured, in words
};
RglAccuracy MeasureRglAccuracy(const RglBsdf& file, const BrdfFunction& f, double theta_max_deg = 80,
                               double step_deg = 2.5, double threshold = 0.01, double theta_o_max_deg = 90);
// The same measure towards grazing incidence, where a file errs most:
// theta_i from from_deg (or the last slice, if that comes first) to the
// file's last slice in steps of step_deg (beyond it the format's readers
// hold that slice).
RglAccuracy MeasureRglAccuracyTowardsGrazing(const RglBsdf& file, const BrdfFunction& f, double from_deg = 80,
                                             double step_deg = 0.25);

}  // namespace brdfkit::formats
