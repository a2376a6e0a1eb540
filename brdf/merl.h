// MERL BRDF database binary format (Matusik, Pfister, Brand, McMillan 2003,
// "A Data-Driven Reflectance Model", SIGGRAPH): a reader, an atomic writer,
// tabulation of any f(wi, wo), and the model [merl] that evaluates a table.
//
// File layout: three little-endian int32 (90, 90, 180: the theta_h, theta_d
// and phi_d resolutions), then 3 x 90 x 90 x 180 little-endian float64,
// planar (all red, then all green, then all blue): 34,992,012 bytes. The
// stored value times kScale[c] is f_r in 1/sr (without the cosine); a
// negative value marks a missing sample.
//
// Coordinates are Rusinkiewicz's half/difference angles (Rusinkiewicz 1998,
// "A New Change of Variables for Efficient BRDF Representation", sec. 3):
// h = normalize(wi + wo) gives theta_h, phi_h; the difference vector d is wi
// rotated by -phi_h about the normal and then by -theta_h about the
// binormal, with spherical angles theta_d, phi_d. Isotropy drops phi_h, and
// reciprocity (swapping wi and wo maps phi_d to phi_d + pi) folds phi_d
// into [0, pi). Bins: theta_h non-linear, i = floor(sqrt(theta_h / (pi/2)) 90),
// so that the specular peak gets most of them; theta_d and phi_d linear.
#pragma once

#include "brdf/atomic_file.h"
#include "brdf/core.h"

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

namespace brdfkit {

class MerlTable {
 public:
  static constexpr int kThetaH = 90, kThetaD = 90, kPhiD = 180;
  static constexpr std::size_t kCells = 90 * 90 * 180;  // per channel
  static constexpr std::size_t kHeaderBytes = 12;
  static constexpr std::size_t kFileSize = 34992012;
  static_assert(kFileSize == kHeaderBytes + 3 * kCells * sizeof(double));
  static constexpr double kScale[3] = {1.0 / 1500, 1.15 / 1500, 1.66 / 1500};

  // f_r in 1/sr (already multiplied by the scale), planar: channel c at
  // c * kCells + Index(...). Negative values mark missing samples.
  std::vector<double> values = std::vector<double>(3 * kCells, -1.0);

  MerlTable() = default;

  // Half/difference angles; phi_d unfolded in [-pi, pi].
  struct HalfDiff {
    double theta_h = 0, phi_h = 0, theta_d = 0, phi_d = 0;
  };

  static std::size_t Index(int theta_h_bin, int theta_d_bin, int phi_d_bin) {
    return static_cast<std::size_t>(phi_d_bin) +
           kPhiD * (static_cast<std::size_t>(theta_d_bin) + kThetaD * static_cast<std::size_t>(theta_h_bin));
  }

  // Bin of each coordinate, with the arithmetic of the original reader
  // (BRDFRead.cpp): floor, clamped to the table.
  static int ThetaHalfIndex(double theta_h) {
    if (!(theta_h > 0)) return 0;  // the sqrt map starts at 0; also catches NaN
    const double x = std::sqrt(theta_h / (kPi / 2) * kThetaH * kThetaH);
    return static_cast<int>(std::min(x, double(kThetaH - 1)));
  }
  static int ThetaDiffIndex(double theta_d) {
    const double x = theta_d / (kPi / 2) * kThetaD;
    if (!(x > 0)) return 0;  // clamp below; also catches NaN
    return static_cast<int>(std::min(x, double(kThetaD - 1)));
  }
  static int PhiDiffIndex(double phi_d) {
    if (phi_d < 0) phi_d += kPi;  // reciprocity: f(phi_d) = f(phi_d + pi)
    const double x = phi_d / kPi * kPhiD;
    if (!(x > 0)) return 0;  // clamp below; also catches NaN
    return static_cast<int>(std::min(x, double(kPhiD - 1)));
  }

  // Bin centres used by most readers: theta_h = (i/90)^2 pi/2,
  // theta_d = j/90 pi/2, phi_d = k/180 pi. They are the lower edges of the
  // bins the original reader's floor lookup selects.
  static void BinCentre(int i, int j, int k, double& theta_h, double& theta_d, double& phi_d) {
    const double u = double(i) / kThetaH;
    theta_h = u * u * (kPi / 2);
    theta_d = double(j) / kThetaD * (kPi / 2);
    phi_d = double(k) / kPhiD * kPi;
  }

  // Unfolded conversion. wi and wo need not be unit vectors.
  static HalfDiff ToHalfDiff(const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) {
    HalfDiff r;
    Eigen::Vector3d h;
    double dx, dy, dz;
    Frame(wi, wo, h, r.theta_h, dx, dy, dz);
    r.phi_h = std::atan2(h.y(), h.x());
    r.theta_d = std::atan2(std::sqrt(dx * dx + dy * dy), dz);
    r.phi_d = std::atan2(dy, dx);
    return r;
  }

  static void FromHalfDiff(const HalfDiff& hd, Eigen::Vector3d& wi, Eigen::Vector3d& wo) {
    FromHalfDiffTrig(std::sin(hd.theta_h), std::cos(hd.theta_h), std::sin(hd.theta_d), std::cos(hd.theta_d),
                     std::sin(hd.phi_d), std::cos(hd.phi_d), std::sin(hd.phi_h), std::cos(hd.phi_h), wi, wo);
  }

  // FromHalfDiff from the sines (s..) and cosines (c..) of theta_h (t),
  // theta_d (d), phi_d (pd) and phi_h (p): for callers that convert many
  // directions on one grid of angles (BinDirections).
  static void FromHalfDiffTrig(double st, double ct, double sd, double cd, double spd, double cpd, double sp,
                               double cp, Eigen::Vector3d& wi, Eigen::Vector3d& wo) {
    const double dx = sd * cpd, dy = sd * spd;
    // wo is the mirror of wi about h: d_o = (-dx, -dy, dz) in the half frame.
    auto to_world = [&](double x, double y, double z) {
      const double xr = ct * x + st * z, zr = -st * x + ct * z;  // rotate by theta_h about the binormal
      return Eigen::Vector3d(cp * xr - sp * y, sp * xr + cp * y, zr);
    };
    wi = to_world(dx, dy, cd);
    wo = to_world(-dx, -dy, cd);
  }

  // phi_d folded into [0, pi). The fold picks the representative of
  // {d, -d} before the arctangent, so swapping wi and wo gives bit-identical
  // angles (exact reciprocity of every lookup).
  static void DirectionsToHalfDiff(const Eigen::Vector3d& wi, const Eigen::Vector3d& wo, double& theta_h,
                                   double& theta_d, double& phi_d) {
    Eigen::Vector3d h;
    double dx, dy, dz;
    Frame(wi, wo, h, theta_h, dx, dy, dz);
    theta_d = std::atan2(std::sqrt(dx * dx + dy * dy), dz);
    // -0 + 0 = +0: a zero component carries no direction, and its sign (from
    // the azimuth of a direction on the normal, where azimuth is undefined)
    // must not pick phi_d = pi over phi_d = 0.
    dx += 0.0;
    dy += 0.0;
    if (dy < 0 || (dy == 0 && dx < 0)) {
      dx = -dx;
      dy = -dy;
    }
    phi_d = std::atan2(dy, dx);
  }

  // With phi_h = 0.
  static void HalfDiffToDirections(double theta_h, double theta_d, double phi_d, Eigen::Vector3d& wi,
                                   Eigen::Vector3d& wo) {
    FromHalfDiff(HalfDiff{theta_h, 0.0, theta_d, phi_d}, wi, wo);
  }

  // The directions (phi_h = 0) of bin centre (i, j, k), each index within
  // its axis: HalfDiffToDirections of BinCentre, with the sines and cosines
  // of the centres' angles computed once per axis (90 + 90 + 180 of each)
  // instead of eight per call.
  static void BinDirections(int i, int j, int k, Eigen::Vector3d& wi, Eigen::Vector3d& wo) {
    struct Trig {
      std::array<double, kThetaH> s_h, c_h;
      std::array<double, kThetaD> s_d, c_d;
      std::array<double, kPhiD> s_p, c_p;
    };
    static const Trig t = [] {
      Trig r;
      double th, td, pd;
      for (int n = 0; n < kThetaH; ++n) {
        BinCentre(n, 0, 0, th, td, pd);
        r.s_h[std::size_t(n)] = std::sin(th);
        r.c_h[std::size_t(n)] = std::cos(th);
      }
      for (int n = 0; n < kThetaD; ++n) {
        BinCentre(0, n, 0, th, td, pd);
        r.s_d[std::size_t(n)] = std::sin(td);
        r.c_d[std::size_t(n)] = std::cos(td);
      }
      for (int n = 0; n < kPhiD; ++n) {
        BinCentre(0, 0, n, th, td, pd);
        r.s_p[std::size_t(n)] = std::sin(pd);
        r.c_p[std::size_t(n)] = std::cos(pd);
      }
      return r;
    }();
    const std::size_t a = std::size_t(i), b = std::size_t(j), c = std::size_t(k);
    // phi_h = 0: sine 0, cosine 1.
    FromHalfDiffTrig(t.s_h[a], t.c_h[a], t.s_d[b], t.c_d[b], t.s_p[c], t.c_p[c], 0.0, 1.0, wi, wo);
  }

  // Nearest-bin lookup exactly as the original MERL reader (a floor onto the
  // bin centres, so biased by up to one bin towards smaller angles), or
  // trilinear interpolation between bin centres in the table's own
  // coordinates (sqrt-mapped theta_h, linear theta_d, phi_d periodic with
  // period pi; constant beyond the last centre of theta_h and theta_d).
  // Missing samples: nearest gives 0; trilinear drops the missing corners
  // and renormalises the weights of the others (0 if all are missing).
  // Directions at or below the horizon give 0.
  Rgb<double> Lookup(const Eigen::Vector3d& wi, const Eigen::Vector3d& wo, bool trilinear) const {
    if (!(wi.z() > 0 && wo.z() > 0)) return Rgb<double>::Zero();
    double th, td, pd;
    DirectionsToHalfDiff(wi, wo, th, td, pd);
    return LookupHalfDiff(th, td, pd, trilinear);
  }

  Rgb<double> LookupHalfDiff(double theta_h, double theta_d, double phi_d, bool trilinear) const {
    Rgb<double> out;
    if (!trilinear) {
      const std::size_t n = Index(ThetaHalfIndex(theta_h), ThetaDiffIndex(theta_d), PhiDiffIndex(phi_d));
      for (int c = 0; c < 3; ++c) {
        const double v = values[c * kCells + n];
        out[c] = v < 0 ? 0.0 : v;
      }
      return out;
    }
    int i0, i1, j0, j1, k0, k1;
    double ti, tj, tk;
    Axis(theta_h > 0 ? std::sqrt(theta_h / (kPi / 2)) * kThetaH : 0.0, kThetaH, i0, i1, ti);
    Axis(theta_d / (kPi / 2) * kThetaD, kThetaD, j0, j1, tj);
    {
      if (phi_d < 0) phi_d += kPi;  // reciprocity fold, as PhiDiffIndex
      double x = phi_d / kPi * kPhiD;
      if (!(x > 0)) x = 0;  // clamp below; also catches NaN, keeping the cast defined
      x = std::min(x, double(kPhiD));
      k0 = std::min(static_cast<int>(x), kPhiD - 1);
      tk = std::min(x - k0, 1.0);
      k1 = (k0 + 1) % kPhiD;  // phi_d = pi is phi_d = 0 again
    }
    const std::size_t ij[4] = {Index(i0, j0, 0), Index(i0, j1, 0), Index(i1, j0, 0), Index(i1, j1, 0)};
    const double wij[4] = {(1 - ti) * (1 - tj), (1 - ti) * tj, ti * (1 - tj), ti * tj};
    for (int c = 0; c < 3; ++c) {
      const double* base = values.data() + c * kCells;
      double sum = 0, wsum = 0;
      for (int q = 0; q < 4; ++q) {
        const double a = base[ij[q] + k0], b = base[ij[q] + k1];
        const double wa = wij[q] * (1 - tk), wb = wij[q] * tk;
        if (a >= 0) {
          sum += wa * a;
          wsum += wa;
        }
        if (b >= 0) {
          sum += wb * b;
          wsum += wb;
        }
      }
      out[c] = wsum > 0 ? sum / wsum : 0.0;
    }
    return out;
  }

  // Number of missing samples (negative values), counted over all three channels.
  std::size_t MissingCount() const {
    return static_cast<std::size_t>(std::count_if(values.begin(), values.end(), [](double v) { return v < 0; }));
  }

  // Throws std::runtime_error naming the file: missing file, a directory,
  // wrong size, wrong header dimensions, non-finite values.
  static MerlTable Read(const std::string& path) {
    namespace fs = std::filesystem;
    const std::string what = "MERL file '" + path + "'";
    std::error_code ec;
    const fs::file_status st = fs::status(path, ec);
    if (!fs::exists(st)) throw std::runtime_error("cannot read " + what + ": no such file");
    if (fs::is_directory(st)) throw std::runtime_error("cannot read " + what + ": it is a directory");
    const std::uintmax_t size = fs::file_size(path, ec);
    if (ec) throw std::runtime_error("cannot read " + what + ": " + ec.message());
    std::ifstream in(path, std::ios::binary);
    if (!in) throw std::runtime_error("cannot open " + what);
    // The header first: a file of another resolution is better named by its
    // dimensions than by its size.
    if (size >= kHeaderBytes) {
      unsigned char h[kHeaderBytes];
      if (!in.read(reinterpret_cast<char*>(h), kHeaderBytes)) throw std::runtime_error("cannot read " + what);
      std::int32_t dims[3];
      for (int d = 0; d < 3; ++d) {
        const std::uint32_t u = std::uint32_t(h[4 * d]) | std::uint32_t(h[4 * d + 1]) << 8 |
                                std::uint32_t(h[4 * d + 2]) << 16 | std::uint32_t(h[4 * d + 3]) << 24;
        dims[d] = static_cast<std::int32_t>(u);
      }
      if (dims[0] != kThetaH || dims[1] != kThetaD || dims[2] != kPhiD)
        throw std::runtime_error(what + " has header dimensions " + std::to_string(dims[0]) + " x " +
                                 std::to_string(dims[1]) + " x " + std::to_string(dims[2]) +
                                 " (theta_h x theta_d x phi_d), expected 90 x 90 x 180");
    }
    if (size != kFileSize)
      throw std::runtime_error(what + " is " + (size < kFileSize ? "truncated" : "over-long") + ": " +
                               std::to_string(size) + " bytes, expected " + std::to_string(kFileSize) +
                               " (12-byte header + 3 x 90 x 90 x 180 float64)");
    MerlTable t;
    t.values.resize(3 * kCells);
    if (!in.read(reinterpret_cast<char*>(t.values.data()), std::streamsize(3 * kCells * sizeof(double))))
      throw std::runtime_error("cannot read " + what + ": read failed after the header");
    if constexpr (std::endian::native == std::endian::big)
      for (double& v : t.values) v = SwapBytes(v);
    static const char* kChannel[3] = {"red", "green", "blue"};
    for (int c = 0; c < 3; ++c) {
      double* v = t.values.data() + c * kCells;
      for (std::size_t n = 0; n < kCells; ++n) {
        if (!std::isfinite(v[n])) {
          const std::size_t k = n % kPhiD, j = (n / kPhiD) % kThetaD, i = n / (kPhiD * kThetaD);
          throw std::runtime_error(what + " holds a non-finite value (" + std::to_string(v[n]) + ") in the " +
                                   kChannel[c] + " channel at theta_h bin " + std::to_string(i) +
                                   ", theta_d bin " + std::to_string(j) + ", phi_d bin " + std::to_string(k));
        }
        v[n] *= kScale[c];
      }
    }
    return t;
  }

  // Writes atomically: a complete file or nothing (an existing file is kept
  // on failure). Throws on a table of the wrong size or with non-finite values.
  void Write(const std::string& path) const {
    const std::string what = "MERL file '" + path + "'";
    if (values.size() != 3 * kCells)
      throw std::runtime_error("cannot write " + what + ": the table holds " + std::to_string(values.size()) +
                               " values, expected " + std::to_string(3 * kCells));
    std::vector<double> raw(values.size());
    for (int c = 0; c < 3; ++c) {
      for (std::size_t n = 0; n < kCells; ++n) {
        const double v = values[c * kCells + n];
        if (!std::isfinite(v))
          throw std::runtime_error("cannot write " + what + ": non-finite value in channel " + std::to_string(c) +
                                   " at cell " + std::to_string(n));
        double r = v / kScale[c];
        if constexpr (std::endian::native == std::endian::big) r = SwapBytes(r);
        raw[c * kCells + n] = r;
      }
    }
    unsigned char header[kHeaderBytes];
    const std::uint32_t dims[3] = {kThetaH, kThetaD, kPhiD};
    for (int d = 0; d < 3; ++d)
      for (int b = 0; b < 4; ++b) header[4 * d + b] = static_cast<unsigned char>(dims[d] >> (8 * b));
    AtomicFile f(path, std::ios::out | std::ios::binary);
    f.stream().write(reinterpret_cast<const char*>(header), kHeaderBytes);
    f.stream().write(reinterpret_cast<const char*>(raw.data()), std::streamsize(raw.size() * sizeof(double)));
    f.Commit();
  }

  // Whether both directions of a bin centre are above the horizon. Two
  // centres lie on it (theta_h + theta_d = 90 degrees at phi_d = 0: bins
  // (30, 80, 0) and (60, 50, 0)), where rounding leaves a cosine of about
  // +-1e-16 and a model dividing by the cosine (Kajiya's) gives 1e19; every
  // other centre's cosines are above 1e-3.
  static bool AboveHorizon(const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) {
    constexpr double kOnHorizon = 1e-12;
    return wi.z() > kOnHorizon && wo.z() > kOnHorizon;
  }

  // Tabulates f(wi, wo) at the bin centres (directions with phi_h = 0). f
  // returns an RGB triple (anything with operator[]) or one number for all
  // channels. Cells whose centre puts a direction at or below the horizon
  // are stored as missing (-1), as in measured files.
  template <class F>
  static MerlTable FromFunction(F&& f) {
    MerlTable t;
    t.Tabulate(f, 0, kThetaH);
    return t;
  }

  // Fills theta_h rows [theta_h_begin, theta_h_end): disjoint row ranges
  // write disjoint memory, so callers may run them on separate threads.
  template <class F>
  void Tabulate(F&& f, int theta_h_begin, int theta_h_end) {
    if (values.size() != 3 * kCells) values.assign(3 * kCells, -1.0);
    double sd[kThetaD], cd[kThetaD], sp[kPhiD], cp[kPhiD];
    for (int j = 0; j < kThetaD; ++j) {
      double th, td, pd;
      BinCentre(0, j, 0, th, td, pd);
      sd[j] = std::sin(td);
      cd[j] = std::cos(td);
    }
    for (int k = 0; k < kPhiD; ++k) {
      double th, td, pd;
      BinCentre(0, 0, k, th, td, pd);
      sp[k] = std::sin(pd);
      cp[k] = std::cos(pd);
    }
    for (int i = std::max(theta_h_begin, 0); i < std::min(theta_h_end, kThetaH); ++i) {
      double th, td, pd;
      BinCentre(i, 0, 0, th, td, pd);
      const double st = std::sin(th), ct = std::cos(th);
      for (int j = 0; j < kThetaD; ++j) {
        for (int k = 0; k < kPhiD; ++k) {
          // As FromHalfDiff with phi_h = 0, from the tabulated sines and cosines.
          const double dx = sd[j] * cp[k], dy = sd[j] * sp[k], dz = cd[j];
          const Eigen::Vector3d wi(ct * dx + st * dz, dy, -st * dx + ct * dz);
          const Eigen::Vector3d wo(-ct * dx + st * dz, -dy, st * dx + ct * dz);
          const std::size_t n = Index(i, j, k);
          if (!AboveHorizon(wi, wo)) {
            for (int c = 0; c < 3; ++c) values[c * kCells + n] = -1.0;
            continue;
          }
          const auto v = f(wi, wo);
          for (int c = 0; c < 3; ++c) {
            if constexpr (std::is_arithmetic_v<std::decay_t<decltype(v)>>)
              values[c * kCells + n] = static_cast<double>(v);
            else
              values[c * kCells + n] = static_cast<double>(v[c]);
          }
        }
      }
    }
  }

 private:
  // h, theta_h and the difference vector d = (dx, dy, dz) of wi. d is
  // computed from (wi - wo) / 2, whose rotation into the half frame is
  // (dx, dy, 0) because wo is the mirror of wi about h, and dz = cos theta_d
  // = |wi + wo| / 2: swapping wi and wo negates dx, dy exactly and leaves
  // dz and h unchanged.
  static void Frame(const Eigen::Vector3d& wi_in, const Eigen::Vector3d& wo_in, Eigen::Vector3d& h, double& theta_h,
                    double& dx, double& dy, double& dz) {
    const Eigen::Vector3d wi = wi_in.normalized(), wo = wo_in.normalized();
    const Eigen::Vector3d sum = wi + wo, diff = wi - wo;
    const double sum_norm = sum.norm();
    // wi = -wo leaves h undefined; take the normal (no lookup reaches this:
    // one of the two directions is then below the horizon).
    h = sum_norm > 0 ? Eigen::Vector3d(sum / sum_norm) : Eigen::Vector3d(0, 0, 1);
    const double sin_h = std::sqrt(h.x() * h.x() + h.y() * h.y());
    theta_h = std::atan2(sin_h, h.z());
    // cos and sin of phi_h; h on the normal has phi_h = 0.
    const double c = sin_h > 0 ? h.x() / sin_h : 1.0, s = sin_h > 0 ? h.y() / sin_h : 0.0;
    const double ux = 0.5 * (c * diff.x() + s * diff.y());  // rotated by -phi_h about the normal
    dy = 0.5 * (c * diff.y() - s * diff.x());
    dx = h.z() * ux - sin_h * (0.5 * diff.z());  // then by -theta_h about the binormal
    dz = 0.5 * sum_norm;
  }

  // Continuous coordinate x on an axis of n centres at 0..n-1: the two
  // neighbouring centres and the weight of the upper one.
  static void Axis(double x, int n, int& i0, int& i1, double& t) {
    if (!(x > 0)) x = 0;  // constant before the first centre; also catches NaN
    x = std::min(x, double(n - 1));  // and beyond the last
    i0 = std::min(static_cast<int>(x), n - 2);
    i1 = i0 + 1;
    t = x - i0;
  }

  static double SwapBytes(double v) {
    std::uint64_t u = std::bit_cast<std::uint64_t>(v), r = 0;
    for (int b = 0; b < 8; ++b) r = (r << 8) | ((u >> (8 * b)) & 0xff);
    return std::bit_cast<double>(r);
  }
};

// Model [merl]: a measured isotropic BRDF in the MERL binary format.
//
// No numeric parameters. Settings:
// | setting | values                       | meaning                                           |
// |---------|------------------------------|---------------------------------------------------|
// | path    | FILE                         | the .binary file (also written "merl:FILE")       |
// | interp  | nearest (default), trilinear | as the original reader, or trilinear in the table |
//
// Eval returns the table's value as a constant of T (zero derivative with
// respect to any parameter); missing samples evaluate to 0. Reciprocal:
// the phi_d fold makes every lookup symmetric in wi and wo. Not energy
// conserving by construction (measured data may exceed albedo 1 through
// noise). Sampling is cosine-weighted (pdf = cos_theta_i / pi).
class Merl : public CosineSampling {
 public:
  explicit Merl(const Settings& settings) {
    const auto path = settings.find("path");
    if (path == settings.end() || path->second.empty())
      throw ModelError("model 'merl' needs path=FILE (a MERL .binary file, e.g. merl:gold-paint.binary)");
    const auto interp = settings.find("interp");
    if (interp != settings.end()) {
      if (interp->second == "trilinear") trilinear_ = true;
      else if (interp->second != "nearest")
        throw ModelError("model 'merl': interp must be 'nearest' or 'trilinear' (got '" + interp->second + "')");
    }
    try {
      table_ = std::make_shared<const MerlTable>(MerlTable::Read(path->second));
    } catch (const std::runtime_error& e) {
      throw ModelError(e.what());
    }
    weight_ = EstimateAlbedo();
    width_ = EstimateWidth();
  }

  Merl(std::shared_ptr<const MerlTable> table, bool trilinear) : table_(std::move(table)), trilinear_(trilinear) {
    if (!table_ || table_->values.size() != 3 * MerlTable::kCells)
      throw ModelError("model 'merl': the table must hold 3 x 90 x 90 x 180 values");
    weight_ = EstimateAlbedo();
    width_ = EstimateWidth();
  }

  static ModelInfo Info() {
    ModelInfo info;
    info.name = "merl";
    info.summary = "measured isotropic BRDF table, MERL binary format (Matusik et al. 2003)";
    info.reciprocal = true;           // the phi_d fold symmetrises every lookup
    info.energy_conserving = false;   // measured data
    info.settings = {"path", "interp"};
    return info;
  }

  // Measured: whatever the table holds, taken as a diffuse part and a
  // glossy peak whose width is measured once from the table (Width).
  static constexpr unsigned kKind = LobeKind::kDiffuse | LobeKind::kGlossy;
  static constexpr bool kChannelsIndependent = true;  // no parameters
  LobeWidth Width(const double*) const { return {width_, width_}; }

  const MerlTable& Table() const { return *table_; }
  bool Trilinear() const { return trilinear_; }

  template <typename T>
  Rgb<T> Eval(const T*, const Vec3<T>& wi, const Vec3<T>& wo) const {
    if (!SameUpperHemisphere(wi, wo)) return Rgb<T>::Constant(T(0));
    const Eigen::Vector3d a(Value(wi.x()), Value(wi.y()), Value(wi.z()));
    const Eigen::Vector3d b(Value(wo.x()), Value(wo.y()), Value(wo.z()));
    const Rgb<double> f = table_->Lookup(a, b, trilinear_);
    return Rgb<T>(T(f[0]), T(f[1]), T(f[2]));
  }

  // Rough albedo, for choosing this lobe in a sum.
  double SampleWeight(const double*) const { return weight_; }

 private:
  // Mean over channels of the directional albedo at theta_o = 0, 30, 60 deg,
  // by 16 x 16 stratified cosine-weighted samples (estimator pi * mean f).
  double EstimateAlbedo() const {
    constexpr int kN = 16;
    double sum = 0;
    int count = 0;
    for (double theta_o : {0.0, kPi / 6, kPi / 3}) {
      const Eigen::Vector3d wo(std::sin(theta_o), 0, std::cos(theta_o));
      for (int a = 0; a < kN; ++a)
        for (int b = 0; b < kN; ++b) {
          const Eigen::Vector3d wi = SampleCosineHemisphere<double>((a + 0.5) / kN, (b + 0.5) / kN);
          sum += kPi * table_->Lookup(wi, wo, trilinear_).mean();
          ++count;
        }
    }
    return std::max(sum / count, 0.0);
  }

  double EstimateWidth() const {
    return MeasuredLobeWidth([&](const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) {
      return table_->Lookup(wi, wo, trilinear_);
    });
  }

  std::shared_ptr<const MerlTable> table_;
  bool trilinear_ = false;
  double weight_ = 0;
  double width_ = 1;
};

}  // namespace brdfkit
