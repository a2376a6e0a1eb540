// UTIA anisotropic BRDF files (Filip & Vavra 2014, "Template-Based Sampling
// of Anisotropic BRDFs", Computer Graphics Forum 33(7)): a reader, an atomic
// writer, tabulation of any f(wi, wo), and the model [utia].
//
// Headerless little-endian float64: 3 planes (R, G, B, sRGB primaries) x
// 6 theta_i x 48 phi_i x 6 theta_v x 48 phi_v = 248,832 values (1,990,656
// bytes); theta 0..75 degrees in 15 degree steps, phi 0..352.5 degrees in
// 7.5 degree steps; index = plane * 82944 + ((i_ti * 48 + i_pi) * 6 + i_tv)
// * 48 + i_pv. brdfkit reads the values as f_r in 1/sr (no cosine), with the
// illumination direction (theta_i, phi_i) and the view direction
// (theta_v, phi_v) both pointing away from the surface in one frame.
// Lookup: quadrilinear in (theta_i, phi_i, theta_v, phi_v), azimuths
// periodic (352.5 wraps to 0), elevations constant beyond 75 degrees.
#pragma once

#include "brdf/atomic_file.h"
#include "brdf/core.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <memory>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <vector>

namespace brdfkit {

class UtiaTable {
 public:
  static constexpr int kTheta = 6, kPhi = 48;
  static constexpr double kThetaStep = 15.0 * kPi / 180, kPhiStep = 7.5 * kPi / 180;
  static constexpr std::size_t kPlane = kTheta * kPhi * kTheta * kPhi;  // 82944
  static constexpr std::size_t kFileSize = 3 * kPlane * sizeof(double);  // 1,990,656

  std::vector<double> values = std::vector<double>(3 * kPlane, 0.0);  // planar, f_r in 1/sr

  static std::size_t Index(int ti, int pi, int tv, int pv) {
    return ((static_cast<std::size_t>(ti) * kPhi + pi) * kTheta + tv) * kPhi + pv;
  }
  static Eigen::Vector3d NodeDirection(int t, int p) {
    const double theta = t * kThetaStep, phi = p * kPhiStep;
    return {std::sin(theta) * std::cos(phi), std::sin(theta) * std::sin(phi), std::cos(theta)};
  }

  Rgb<double> Lookup(const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) const {
    if (!(wi.z() > 0 && wo.z() > 0)) return Rgb<double>::Zero();
    int t0[2], t1[2], p0[2], p1[2];
    double tt[2], tp[2];
    const Eigen::Vector3d* w[2] = {&wi, &wo};
    for (int k = 0; k < 2; ++k) {
      const Eigen::Vector3d d = w[k]->normalized();
      double x = std::atan2(std::sqrt(d.x() * d.x() + d.y() * d.y()), d.z()) / kThetaStep;
      x = std::clamp(x, 0.0, double(kTheta - 1));  // constant beyond 75 degrees
      t0[k] = std::min(static_cast<int>(x), kTheta - 2);
      t1[k] = t0[k] + 1;
      tt[k] = x - t0[k];
      double phi = std::atan2(d.y(), d.x());
      if (phi < 0) phi += 2 * kPi;
      double y = phi / kPhiStep;
      if (!(y >= 0 && y < kPhi)) y = 0;  // rounding at 2 pi (and NaN): the node at 0
      p0[k] = static_cast<int>(y);
      tp[k] = y - p0[k];
      p1[k] = (p0[k] + 1) % kPhi;  // 352.5 degrees wraps to 0
    }
    Rgb<double> out = Rgb<double>::Zero();
    for (int a = 0; a < 16; ++a) {
      const int ti = a & 1 ? t1[0] : t0[0], pi = a & 2 ? p1[0] : p0[0];
      const int tv = a & 4 ? t1[1] : t0[1], pv = a & 8 ? p1[1] : p0[1];
      const double weight = (a & 1 ? tt[0] : 1 - tt[0]) * (a & 2 ? tp[0] : 1 - tp[0]) *
                            (a & 4 ? tt[1] : 1 - tt[1]) * (a & 8 ? tp[1] : 1 - tp[1]);
      if (weight == 0) continue;
      const std::size_t n = Index(ti, pi, tv, pv);
      for (int c = 0; c < 3; ++c) out[c] += weight * values[c * kPlane + n];
    }
    return out;
  }

  // Tabulates f(wi, wo) (an RGB triple, anything with operator[]) at the nodes.
  template <class F>
  static UtiaTable FromFunction(F&& f) {
    UtiaTable t;
    for (int ti = 0; ti < kTheta; ++ti)
      for (int pi = 0; pi < kPhi; ++pi)
        for (int tv = 0; tv < kTheta; ++tv)
          for (int pv = 0; pv < kPhi; ++pv) {
            const auto v = f(NodeDirection(ti, pi), NodeDirection(tv, pv));
            for (int c = 0; c < 3; ++c) t.values[c * kPlane + Index(ti, pi, tv, pv)] = static_cast<double>(v[c]);
          }
    return t;
  }

  // Throws std::runtime_error naming the file: no such file, wrong size,
  // non-finite or negative values (with their plane and node).
  static UtiaTable Read(const std::string& path) {
    namespace fs = std::filesystem;
    const std::string what = "UTIA file '" + path + "'";
    std::error_code ec;
    const fs::file_status st = fs::status(path, ec);
    if (!fs::exists(st)) throw std::runtime_error("cannot read " + what + ": no such file");
    if (fs::is_directory(st)) throw std::runtime_error("cannot read " + what + ": it is a directory");
    const std::uintmax_t size = fs::file_size(path, ec);
    if (ec) throw std::runtime_error("cannot read " + what + ": " + ec.message());
    if (size != kFileSize)
      throw std::runtime_error(what + " is " + std::to_string(size) + " bytes, expected " + std::to_string(kFileSize) +
                               " (3 x 6 x 48 x 6 x 48 float64, no header)");
    std::ifstream in(path, std::ios::binary);
    UtiaTable t;
    if (!in || !in.read(reinterpret_cast<char*>(t.values.data()), std::streamsize(kFileSize)))
      throw std::runtime_error("cannot read " + what);
    static const char* kChannel[3] = {"red", "green", "blue"};
    for (std::size_t i = 0; i < t.values.size(); ++i) {
      double& v = t.values[i];
      if constexpr (std::endian::native == std::endian::big) v = std::bit_cast<double>(SwapBytes(std::bit_cast<std::uint64_t>(v)));
      if (!std::isfinite(v) || v < 0) {
        const std::size_t n = i % kPlane;
        const std::size_t pv = n % kPhi, tv = (n / kPhi) % kTheta, pi = (n / (kPhi * kTheta)) % kPhi,
                          ti = n / (kPhi * kTheta * kPhi);
        throw std::runtime_error(what + " holds " + (std::isfinite(v) ? "a negative" : "a non-finite") + " value (" +
                                 std::to_string(v) + ") in the " + kChannel[i / kPlane] + " plane at theta_i " +
                                 std::to_string(15 * ti) + ", phi_i " + std::to_string(7.5 * double(pi)) +
                                 ", theta_v " + std::to_string(15 * tv) + ", phi_v " +
                                 std::to_string(7.5 * double(pv)) + " degrees (value " + std::to_string(i) + ")");
      }
    }
    return t;
  }

  // Writes atomically; throws on non-finite or negative values.
  void Write(const std::string& path) const {
    if (values.size() != 3 * kPlane)
      throw std::runtime_error("cannot write UTIA file '" + path + "': the table holds " +
                               std::to_string(values.size()) + " values, expected " + std::to_string(3 * kPlane));
    std::vector<std::uint64_t> raw(values.size());
    for (std::size_t i = 0; i < values.size(); ++i) {
      if (!std::isfinite(values[i]) || values[i] < 0)
        throw std::runtime_error("cannot write UTIA file '" + path + "': value " + std::to_string(i) + " is " +
                                 std::to_string(values[i]));
      raw[i] = std::bit_cast<std::uint64_t>(values[i]);
      if constexpr (std::endian::native == std::endian::big) raw[i] = SwapBytes(raw[i]);
    }
    AtomicFile f(path, std::ios::out | std::ios::binary);
    f.stream().write(reinterpret_cast<const char*>(raw.data()), std::streamsize(kFileSize));
    f.Commit();
  }

 private:
  static std::uint64_t SwapBytes(std::uint64_t u) {
    std::uint64_t r = 0;
    for (int b = 0; b < 8; ++b) r = (r << 8) | ((u >> (8 * b)) & 0xff);
    return r;
  }
};

// Model [utia]: a measured anisotropic BRDF in the UTIA binary format.
//
// No numeric parameters. Settings:
// | setting | values | meaning                                   |
// |---------|--------|-------------------------------------------|
// | path    | FILE   | the float64 file (also written "utia:FILE") |
//
// Eval is the quadrilinear lookup, a constant of T. Not reciprocal by
// construction (measured data). Sampling is cosine-weighted.
class Utia : public CosineSampling {
 public:
  explicit Utia(const Settings& settings) {
    const auto path = settings.find("path");
    if (path == settings.end() || path->second.empty())
      throw ModelError("model 'utia' needs path=FILE (a UTIA float64 BRDF file, e.g. utia:fabric.bin)");
    try {
      table_ = std::make_shared<const UtiaTable>(UtiaTable::Read(path->second));
    } catch (const std::runtime_error& e) {
      throw ModelError(e.what());
    }
    // Rough albedo for lobe choice in sums: pi times the mean value.
    double sum = 0;
    for (double v : table_->values) sum += v;
    weight_ = kPi * sum / double(table_->values.size());
    width_ = MeasuredLobeWidth(
        [&](const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) { return table_->Lookup(wi, wo); });
  }

  static ModelInfo Info() {
    ModelInfo info;
    info.name = "utia";
    info.summary = "measured anisotropic BRDF, UTIA float64 format (Filip & Vavra 2014)";
    info.reciprocal = false;         // measured data, tabulated per direction pair
    info.energy_conserving = false;  // measured data
    info.settings = {"path"};
    return info;
  }

  // Measured: whatever the file holds, taken as a diffuse part and a glossy
  // peak whose width is measured once from the data (MeasuredLobeWidth).
  static constexpr unsigned kKind = LobeKind::kDiffuse | LobeKind::kGlossy;
  static constexpr bool kChannelsIndependent = true;  // no parameters
  LobeWidth Width(const double*) const { return {width_, width_}; }

  const UtiaTable& Table() const { return *table_; }

  template <typename T>
  Rgb<T> Eval(const T*, const Vec3<T>& wi, const Vec3<T>& wo) const {
    if (!SameUpperHemisphere(wi, wo)) return Rgb<T>::Constant(T(0));
    const Rgb<double> f = table_->Lookup(Eigen::Vector3d(Value(wi.x()), Value(wi.y()), Value(wi.z())),
                                         Eigen::Vector3d(Value(wo.x()), Value(wo.y()), Value(wo.z())));
    return Rgb<T>(T(f[0]), T(f[1]), T(f[2]));
  }

  double SampleWeight(const double*) const { return weight_; }

 private:
  std::shared_ptr<const UtiaTable> table_;
  double width_ = 1;
  double weight_ = 0;
};

}  // namespace brdfkit
