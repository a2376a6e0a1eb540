// RGL-EPFL measured BSDF files (Dupuy & Jakob 2018, "An Adaptive
// Parameterization for Efficient Material Acquisition and Rendering", ACM
// TOG 37(6)): the reader, the reconstruction of f_r, and the model [rgl].
//
// A file is a tensor file (brdf/tensor_file.h) with the fields
//   description u8 [n]              free text
//   jacobian    u8 [1]              1: the values are divided by the density (below); 0: they are f_r cos(theta_o)
//   theta_i     f32 [n_theta]       incident elevations of the slices, radians
//   phi_i       f32 [n_phi]         incident azimuths, radians; isotropic when n_phi <= 2; spanning
//                                   2 pi / k from -pi (k = 1, 2, 4) in anisotropic files
//   ndf         f32 [H, W]          D(wm) over the warped square of wm
//   sigma       f32 [H', W']        projected area sigma(wi) = int D(m) <wi, m>+ dm over that of wi
//   vndf        f32 [n_phi, n_theta, H'', W'']   the visible-normal density D_wi(wm) per slice
//   luminance   f32 [n_phi, n_theta, N, M]       luminance of the measurements (for sampling)
//   rgb         f32 [n_phi, n_theta, 3, N, M]    or
//   spectra     f32 [n_phi, n_theta, L, N, M] with wavelengths f32 [L] (nm)
//   valid       u8 (bit mask), accepted and not used.
//
// Warped square: a direction (theta, phi) sits at u = (sqrt(2 theta / pi),
// (phi + pi) / (2 pi)) in [0,1]^2, so dw = 2 pi^2 u_x sin(theta) du. Every 2D
// table is bilinear on uniform nodes over the square, its first coordinate
// along the last (contiguous) axis; the slice axes (phi_i, theta_i, channel)
// are linear between their nodes and constant beyond the end nodes.
//
// Reconstruction (the paper's sec. 5; what the format's loaders compute):
// the measurement at incidence wi was taken at outgoing directions wo drawn
// by reflecting wi about normals wm drawn from the visible-normal
// distribution, whose density in wo is D(wm) / (4 sigma(wi)); each stored
// value is f_r(wi, wo) cos(theta_o) divided by that density, tabulated over
// the uniform square of the warp's input. So, for a query (wi, wo):
//   wm = normalize(wi + wo); u_wi, u_wm its warped coordinates (isotropic
//   files: the azimuth of wm relative to that of wi);
//   s = V^-1(u_wm | phi_i, theta_i), the inverse of the vndf warp: the
//       marginal-then-conditional CDF of the bilinear density (rows along
//       u_y first, then u_x within the row), each slice normalised to one;
//   f_r cos(theta_o) = value(s | phi_i, theta_i, c) ndf(u_wm) / (4 sigma(u_wi)),
//   the last factor only where jacobian is 1 (as Mitsuba 3 reads it; the
//   reference loader powitacq and pbrt-v4 apply it whatever the flag).
// Anisotropic files whose azimuth nodes span pi or pi / 2 (reduction k = 2
// or 4) hold the BSDF of a symmetric material for part of the incident
// azimuths; a query is first folded into them (RglBsdf::Fold), as Mitsuba
// 3 does (powitacq and pbrt-v4 refuse such files).
// The format's readers (Mitsuba 3, powitacq, pbrt-v4) require square value
// and luminance tables (N = M); brdfkit reads any N x M.
// Spectra reduce to linear sRGB by the CIE 1931 observer (brdf/cie.h).
#pragma once

#include "brdf/cie.h"
#include "brdf/core.h"
#include "brdf/tensor_file.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace brdfkit {

// A 2D table over [0,1]^2 (w columns along x, h rows along y) for each slice
// of up to three parameter axes, bilinear in the square and linear across
// slices. A normalised warp also holds each slice's conditional and marginal
// CDFs, for Sample (square -> u) and Invert (u -> square).
class Warp2D {
 public:
  Warp2D() = default;
  // data: slices x h x w in C order; params: the node values of each slice
  // axis, outermost first (strictly increasing). Throws std::invalid_argument
  // on inconsistent sizes, and for a normalised warp on a slice of zero mass.
  Warp2D(std::vector<float> data, std::size_t h, std::size_t w, std::vector<std::vector<double>> params,
         bool normalised)
      : w_(w), h_(h), params_(std::move(params)) {
    if (w < 2 || h < 2) throw std::invalid_argument("a 2D table needs at least 2 x 2 nodes");
    slices_ = 1;
    for (const auto& p : params_) {
      if (p.empty()) throw std::invalid_argument("a slice axis has no nodes");
      slices_ *= p.size();
    }
    if (data.size() != slices_ * w * h) throw std::invalid_argument("table size disagrees with its shape");
    data_ = std::move(data);  // float as the files store it
    if (!normalised) return;
    cond_.resize(data_.size());
    marg_.resize(slices_ * h);
    for (std::size_t s = 0; s < slices_; ++s) {
      float* d = data_.data() + s * w * h;
      double* cond = cond_.data() + s * w * h;
      double* marg = marg_.data() + s * h;
      // The CDFs (trapezoidal along x, then over the rows) of the density d.
      const auto integrate = [&] {
        for (std::size_t y = 0; y < h; ++y) {
          cond[y * w] = 0;
          for (std::size_t x = 0; x + 1 < w; ++x)
            cond[y * w + x + 1] = cond[y * w + x] + 0.5 * (double(d[y * w + x]) + double(d[y * w + x + 1]));
        }
        marg[0] = 0;
        for (std::size_t y = 0; y + 1 < h; ++y) marg[y + 1] = marg[y] + 0.5 * (cond[y * w + w - 1] + cond[(y + 1) * w + w - 1]);
        return marg[h - 1];
      };
      const double total = integrate();
      if (!(total > 0)) throw std::invalid_argument("slice " + std::to_string(s) + " has no mass");
      // Normalised in float, then integrated again, so that the CDFs are
      // those of the stored density (Invert undoes Sample to rounding); their
      // total is then 1 to float rounding, and Sample and Invert scale by it.
      for (std::size_t i = 0; i < w * h; ++i) d[i] = static_cast<float>(d[i] / total);
      integrate();
    }
  }

  std::size_t Width() const { return w_; }
  std::size_t Height() const { return h_; }
  std::size_t Slices() const { return slices_; }

  // Up to 8 slices and their weights for parameter values p (one per axis).
  struct SliceMix {
    std::size_t index[8];
    double weight[8];
    int count = 1;
  };
  SliceMix Mix(const double* p) const {
    SliceMix m;
    m.index[0] = 0;
    m.weight[0] = 1;
    for (const auto& nodes : params_) {
      std::size_t i0 = 0;
      double t = 0;
      const double x = *p++;
      if (nodes.size() > 1) {
        const double v = std::clamp(x, nodes.front(), nodes.back());  // constant beyond the end nodes
        i0 = static_cast<std::size_t>(std::upper_bound(nodes.begin(), nodes.end(), v) - nodes.begin());
        i0 = std::min(i0 == 0 ? 0 : i0 - 1, nodes.size() - 2);
        t = std::clamp((v - nodes[i0]) / (nodes[i0 + 1] - nodes[i0]), 0.0, 1.0);
        if (!(t == t)) t = 0;  // NaN query: the first node
      }
      const int n = m.count;
      for (int k = 0; k < n; ++k) {
        const std::size_t base = m.index[k] * nodes.size();
        const double wk = m.weight[k];
        m.index[k] = base + i0;
        m.weight[k] = wk * (1 - t);
        if (nodes.size() > 1) {
          m.index[n + k] = base + i0 + 1;
          m.weight[n + k] = wk * t;
        }
      }
      if (nodes.size() > 1) m.count = 2 * n;
    }
    return m;
  }

  // Bilinear value at u in [0,1]^2 (clamped) of the mixed slices.
  double Eval(double ux, double uy, const SliceMix& m) const {
    std::size_t ox, oy;
    double tx, ty;
    Cell(ux, w_, ox, tx);
    Cell(uy, h_, oy, ty);
    const std::size_t i = oy * w_ + ox;
    auto at = [&](std::size_t j) { return Mixed(data_, j, m); };
    return (1 - ty) * ((1 - tx) * at(i) + tx * at(i + 1)) + ty * ((1 - tx) * at(i + w_) + tx * at(i + w_ + 1));
  }
  double Eval(double ux, double uy) const { return Eval(ux, uy, Mix(nullptr)); }

  // The warp's inverse: the square coordinate whose image is u (normalised warps).
  std::array<double, 2> Invert(double ux, double uy, const SliceMix& m) const {
    std::size_t ox, oy;
    double tx, ty;
    Cell(ux, w_, ox, tx);
    Cell(uy, h_, oy, ty);
    const std::size_t i = oy * w_ + ox;
    auto d = [&](std::size_t j) { return Mixed(data_, j, m); };
    auto c = [&](std::size_t j) { return Mixed(cond_, j, m); };
    const double v00 = d(i), v10 = d(i + 1), v01 = d(i + w_), v11 = d(i + w_ + 1);
    const double c0 = c(i) + tx * (v00 + 0.5 * tx * (v10 - v00));
    const double c1 = c(i + w_) + tx * (v01 + 0.5 * tx * (v11 - v01));
    const double r0 = c(oy * w_ + w_ - 1), r1 = c((oy + 1) * w_ + w_ - 1);
    const double row = (1 - ty) * r0 + ty * r1;
    double marg = 0, total = 0;
    for (int k = 0; k < m.count; ++k) {
      marg += m.weight[k] * marg_[m.index[k] * h_ + oy];
      total += m.weight[k] * marg_[m.index[k] * h_ + h_ - 1];
    }
    const double sy = (marg + ty * (r0 + 0.5 * ty * (r1 - r0))) / total;
    // A row of zero density has no conditional distribution: its start.
    const double sx = row > 0 ? ((1 - ty) * c0 + ty * c1) / row : 0.0;
    return {std::clamp(sx, 0.0, 1.0), std::clamp(sy, 0.0, 1.0)};
  }

  // The warp of one slice: square coordinate s -> u (the inverse of Invert).
  std::array<double, 2> Sample(double sx, double sy, std::size_t slice) const {
    const float* d = data_.data() + slice * w_ * h_;
    const double* cond = cond_.data() + slice * w_ * h_;
    const double* marg = marg_.data() + slice * h_;
    sy *= marg[h_ - 1];
    std::size_t oy = static_cast<std::size_t>(std::upper_bound(marg, marg + h_, sy) - marg);
    oy = std::min(oy == 0 ? 0 : oy - 1, h_ - 2);
    const double r0 = cond[oy * w_ + w_ - 1], r1 = cond[(oy + 1) * w_ + w_ - 1];
    const double ty = SolveCell(sy - marg[oy], r0, r1);
    const double target = sx * ((1 - ty) * r0 + ty * r1);
    std::size_t lo = 0, hi = w_ - 1;  // largest x with C(x) <= target, C(x) = lerp of the two rows
    auto C = [&](std::size_t x) { return (1 - ty) * cond[oy * w_ + x] + ty * cond[(oy + 1) * w_ + x]; };
    while (hi - lo > 1) {
      const std::size_t mid = (lo + hi) / 2;
      (C(mid) <= target ? lo : hi) = mid;
    }
    const double v0 = (1 - ty) * d[oy * w_ + lo] + ty * d[(oy + 1) * w_ + lo];
    const double v1 = (1 - ty) * d[oy * w_ + lo + 1] + ty * d[(oy + 1) * w_ + lo + 1];
    const double tx = SolveCell(target - C(lo), v0, v1);
    return {(lo + tx) / double(w_ - 1), (oy + ty) / double(h_ - 1)};
  }

 private:
  static void Cell(double u, std::size_t n, std::size_t& o, double& t) {
    double x = u * double(n - 1);
    if (!(x > 0)) x = 0;  // clamp below; also catches NaN
    x = std::min(x, double(n - 1));
    o = std::min(static_cast<std::size_t>(x), n - 2);
    t = x - double(o);
  }
  template <typename V>
  double Mixed(const std::vector<V>& v, std::size_t j, const SliceMix& m) const {
    double s = 0;
    for (int k = 0; k < m.count; ++k) s += m.weight[k] * double(v[m.index[k] * w_ * h_ + j]);
    return s;
  }
  // t in [0, 1] with t a + t^2 (b - a) / 2 = r: the CDF of a density linear
  // from a to b over the cell. The form 2 r / (a + sqrt(a^2 + 2 r (b - a)))
  // has no cancellation when b is close to a.
  static double SolveCell(double r, double a, double b) {
    if (!(r > 0)) return 0;
    const double disc = std::max(a * a + 2 * r * (b - a), 0.0);
    const double den = a + std::sqrt(disc);
    if (!(den > 0)) return 1;  // no density in the cell: its far end
    return std::clamp(2 * r / den, 0.0, 1.0);
  }

  std::size_t w_ = 0, h_ = 0, slices_ = 0;
  std::vector<std::vector<double>> params_;
  std::vector<float> data_;  // the density normalised per slice (normalised warps), else the table
  std::vector<double> cond_, marg_;
};

class RglBsdf {
 public:
  bool isotropic = true;
  // 1: the values are f_r cos(theta_o) over the density ndf / (4 sigma)
  // (the reconstruction multiplies it back); 0: they are f_r cos(theta_o).
  bool jacobian = true;
  // Anisotropic files whose phi_i nodes span 2 pi / k hold one k-th of the
  // incident azimuths (k = reduction: 1, 2 or 4); queries are folded into
  // it as Mitsuba 3's measured plugin folds them (Fold).
  int reduction = 1;
  std::string description;
  std::vector<double> theta_i, phi_i;
  Warp2D ndf, sigma, vndf, values;  // values: slices (phi_i, theta_i, channel)
  std::size_t n_values = 0, n_sample = 0, m_sample = 0;  // N x M square of the values

  static double ThetaToU(double theta) { return std::sqrt(std::max(theta, 0.0) * (2 / kPi)); }
  static double PhiToU(double phi) {
    const double u = (phi + kPi) / (2 * kPi);
    return u - std::floor(u);
  }
  static double UToTheta(double u) { return u * u * (kPi / 2); }
  static double UToPhi(double u) { return 2 * kPi * u - kPi; }
  static Eigen::Vector3d Direction(double theta, double phi) {
    return {std::sin(theta) * std::cos(phi), std::sin(theta) * std::sin(phi), std::cos(theta)};
  }

  // f_r(wi, wo) cos(theta_o) per channel, by the format's reconstruction;
  // 0 at or below the horizon. Negative reconstructed values (out-of-gamut
  // colours of spectral files) are clipped to 0.
  Rgb<double> FrCos(const Eigen::Vector3d& wi_in, const Eigen::Vector3d& wo_in) const {
    if (!(wi_in.z() > 0 && wo_in.z() > 0)) return Rgb<double>::Zero();
    Eigen::Vector3d wi = wi_in.normalized(), wo = wo_in.normalized();
    Fold(wi, wo);
    const Eigen::Vector3d wm = (wi + wo).normalized();
    const double theta_i_q = std::acos(std::min(wi.z(), 1.0)), phi_i_q = std::atan2(wi.y(), wi.x());
    const double theta_m = std::acos(std::min(wm.z(), 1.0)), phi_m = std::atan2(wm.y(), wm.x());
    const double uix = ThetaToU(theta_i_q), uiy = PhiToU(phi_i_q);
    const double umx = ThetaToU(theta_m), umy = PhiToU(isotropic ? phi_m - phi_i_q : phi_m);
    const double p[2] = {phi_i_q, theta_i_q};
    const Warp2D::SliceMix mix = vndf.Mix(p);
    const std::array<double, 2> s = vndf.Invert(umx, umy, mix);
    double scale = 1;
    if (jacobian) {
      const double s_ndf = ndf.Eval(umx, umy), s_sigma = sigma.Eval(uix, uiy);
      if (!(s_sigma > 0)) return Rgb<double>::Zero();  // no visible microfacets: nothing reflects
      scale = s_ndf / (4 * s_sigma);
    }
    Rgb<double> out;
    for (int c = 0; c < 3; ++c) {
      const double pc[3] = {phi_i_q, theta_i_q, double(c)};
      out[c] = std::max(values.Eval(s[0], s[1], values.Mix(pc)) * scale, 0.0);
    }
    return out;
  }

  // The symmetry reduction of the format's loaders (Mitsuba 3's measured
  // plugin): with k = 2 the pair is turned by pi when wi.y >= +0, with k = 4
  // each of x and y is negated when wi's is >= +0; wi then lies in the
  // azimuths [-pi, -pi + 2 pi / k] that the file holds, wo moves with it.
  void Fold(Eigen::Vector3d& wi, Eigen::Vector3d& wo) const {
    if (reduction < 2) return;
    const auto flip = [](double v, double sign_of) { return std::signbit(sign_of) ? v : -v; };
    const double sy = wi.y(), sx = reduction == 4 ? wi.x() : sy;
    wi.x() = flip(wi.x(), sx);
    wi.y() = flip(wi.y(), sy);
    wo.x() = flip(wo.x(), sx);
    wo.y() = flip(wo.y(), sy);
  }

  Rgb<double> Fr(const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) const {
    if (!(wi.z() > 0 && wo.z() > 0)) return Rgb<double>::Zero();
    return FrCos(wi, wo) / wo.normalized().z();
  }

  // The measurements themselves: for every slice and node of the values'
  // square, wi at the slice (azimuth 0 in isotropic files), wo by the warp,
  // and f_r with the cosine divided out. Nodes whose wo falls at or below
  // the horizon are left out.
  struct NodeSample {
    Eigen::Vector3d wi, wo;
    Rgb<double> f;
  };
  std::vector<NodeSample> NodeSamples() const {
    std::vector<NodeSample> out;
    const std::size_t n_phi = isotropic ? 1 : phi_i.size();
    for (std::size_t a = 0; a < n_phi; ++a) {
      // The last azimuth node repeats the first when the nodes span the circle.
      if (a + 1 == n_phi && n_phi > 1 && std::abs(phi_i.back() - phi_i.front() - 2 * kPi) < 1e-4) break;
      for (std::size_t b = 0; b < theta_i.size(); ++b) {
        const double phi = isotropic ? 0.0 : phi_i[a];
        const Eigen::Vector3d wi = Direction(theta_i[b], phi);
        if (!(wi.z() > 1e-9)) continue;  // an incidence at the horizon measures nothing
        const std::size_t slice = (isotropic ? 0 : a) * theta_i.size() + b;
        const double sig = sigma.Eval(ThetaToU(theta_i[b]), PhiToU(phi));
        for (std::size_t y = 0; y < n_sample; ++y)
          for (std::size_t x = 0; x < m_sample; ++x) {
            const std::array<double, 2> u = vndf.Sample(x / double(m_sample - 1), y / double(n_sample - 1), slice);
            const Eigen::Vector3d wm = Direction(UToTheta(u[0]), UToPhi(u[1]) + (isotropic ? phi : 0.0));
            const Eigen::Vector3d wo = 2 * wi.dot(wm) * wm - wi;
            if (!(wo.z() > 1e-6) || (jacobian && !(sig > 0))) continue;  // grazing or invisible: no usable sample
            const double scale = (jacobian ? ndf.Eval(u[0], u[1]) / (4 * sig) : 1.0) / wo.z();
            NodeSample ns{wi, wo, Rgb<double>::Zero()};
            for (int c = 0; c < 3; ++c) {
              const double pc[3] = {isotropic ? phi_i.front() : phi_i[a], theta_i[b], double(c)};
              ns.f[c] = std::max(values.Eval(x / double(m_sample - 1), y / double(n_sample - 1), values.Mix(pc)), 0.0) * scale;
            }
            out.push_back(ns);
          }
      }
    }
    return out;
  }

  // Throws std::runtime_error naming the file and the field.
  static RglBsdf Read(const std::string& path) {
    const std::string what = "RGL file '" + path + "'";
    return FromTensors(TensorFile::Read(path), what);
  }

  static RglBsdf FromTensors(const TensorFile& t, const std::string& what) {
    auto fail = [&](const std::string& field, const std::string& msg) {
      throw std::runtime_error(what + ": field '" + field + "' " + msg);
    };
    auto field = [&](const std::string& name, std::uint8_t dtype, std::size_t ndim) -> const TensorFile::Field& {
      const TensorFile::Field* f = t.Find(name);
      if (!f) throw std::runtime_error(what + " has no field '" + name + "'");
      if (f->dtype != dtype)
        fail(name, "has dtype " + TensorFile::DTypeName(f->dtype) + ", expected " + TensorFile::DTypeName(dtype));
      if (ndim && f->shape.size() != ndim)
        fail(name, "has " + std::to_string(f->shape.size()) + " dimensions, expected " + std::to_string(ndim));
      return *f;
    };
    auto shape_text = [](const std::vector<std::uint64_t>& s) {
      std::string r = "[";
      for (std::size_t k = 0; k < s.size(); ++k) r += (k ? ", " : "") + std::to_string(s[k]);
      return r + "]";
    };
    auto expect_shape = [&](const TensorFile::Field& f, const std::vector<std::uint64_t>& want, const std::string& why) {
      if (f.shape != want) fail(f.name, "has shape " + shape_text(f.shape) + ", expected " + shape_text(want) + " " + why);
    };
    auto floats = [&](const TensorFile::Field& f, bool non_negative) {
      std::vector<float> v = TensorFile::Floats(f);
      for (std::size_t i = 0; i < v.size(); ++i) {
        if (!std::isfinite(v[i])) fail(f.name, "holds a non-finite value at element " + std::to_string(i));
        if (non_negative && v[i] < 0)
          fail(f.name, "holds a negative value (" + std::to_string(v[i]) + ") at element " + std::to_string(i));
      }
      return v;
    };
    auto nodes = [&](const TensorFile::Field& f, double lo, double hi) {
      const std::vector<float> v = floats(f, false);
      if (v.empty()) fail(f.name, "is empty");
      std::vector<double> out(v.begin(), v.end());
      for (std::size_t k = 0; k < out.size(); ++k) {
        if (out[k] < lo - 1e-4 || out[k] > hi + 1e-4)
          fail(f.name, "node " + std::to_string(k) + " = " + std::to_string(out[k]) + " is outside [" +
                           std::to_string(lo) + ", " + std::to_string(hi) + "]");
        if (k && !(out[k] > out[k - 1])) fail(f.name, "nodes must increase strictly (node " + std::to_string(k) + ")");
      }
      return out;
    };
    auto table2d = [&](const std::string& name) {
      const TensorFile::Field& f = field(name, TensorFile::kF32, 2);
      if (f.shape[0] < 2 || f.shape[1] < 2) fail(name, "needs at least 2 x 2 nodes, has " + shape_text(f.shape));
      return Warp2D(floats(f, true), f.shape[0], f.shape[1], {}, false);
    };

    RglBsdf b;
    {
      const TensorFile::Field& d = field("description", TensorFile::kU8, 1);
      b.description.assign(d.bytes.begin(), d.bytes.end());
      const TensorFile::Field& j = field("jacobian", TensorFile::kU8, 1);
      expect_shape(j, {1}, "(one flag)");
      b.jacobian = j.bytes[0] != 0;
    }
    b.theta_i = nodes(field("theta_i", TensorFile::kF32, 1), 0, kPi / 2);
    b.phi_i = nodes(field("phi_i", TensorFile::kF32, 1), -2 * kPi, 2 * kPi);
    b.isotropic = b.phi_i.size() <= 2;
    if (!b.isotropic) {
      // The span of the azimuth nodes gives the symmetry reduction, as the
      // format's loaders compute it.
      const double span = b.phi_i.back() - b.phi_i.front();
      b.reduction = static_cast<int>(std::lround(2 * kPi / span));
      if (b.reduction != 1 && b.reduction != 2 && b.reduction != 4)
        fail("phi_i", "spans " + std::to_string(span) + " rad, 2 pi / " + std::to_string(2 * kPi / span) +
                          ": the format knows the spans 2 pi, pi and pi / 2 (symmetry reductions 1, 2 and 4)");
      if (b.reduction > 1 && std::abs(b.phi_i.front() + kPi) > 1e-3)
        fail("phi_i", "spans 2 pi / " + std::to_string(b.reduction) + " from " + std::to_string(b.phi_i.front()) +
                          " rad: a reduced file holds the azimuths from -pi, where the format's loaders fold queries");
    }
    const std::uint64_t np = b.phi_i.size(), nt = b.theta_i.size();
    b.ndf = table2d("ndf");
    b.sigma = table2d("sigma");

    const TensorFile::Field& v = field("vndf", TensorFile::kF32, 4);
    if (v.shape[2] < 2 || v.shape[3] < 2) fail("vndf", "needs at least 2 x 2 nodes per slice, has " + shape_text(v.shape));
    expect_shape(v, {np, nt, v.shape[2], v.shape[3]}, "(n_phi_i x n_theta_i x H x W)");
    try {
      b.vndf = Warp2D(floats(v, true), v.shape[2], v.shape[3], {b.phi_i, b.theta_i}, true);
    } catch (const std::invalid_argument& e) {
      fail("vndf", e.what() + std::string(" (a slice must hold a density)"));
    }

    const TensorFile::Field& lum = field("luminance", TensorFile::kF32, 4);
    if (lum.shape[2] < 2 || lum.shape[3] < 2) fail("luminance", "needs at least 2 x 2 nodes per slice, has " + shape_text(lum.shape));
    expect_shape(lum, {np, nt, lum.shape[2], lum.shape[3]}, "(n_phi_i x n_theta_i x N x M)");
    (void)floats(lum, true);
    b.n_sample = lum.shape[2];
    b.m_sample = lum.shape[3];
    const std::uint64_t n = b.n_sample, m = b.m_sample;

    if (const TensorFile::Field* rgb = t.Find("rgb")) {
      (void)field("rgb", TensorFile::kF32, 5);
      expect_shape(*rgb, {np, nt, 3, n, m}, "(n_phi_i x n_theta_i x 3 x N x M, as luminance)");
      b.values = Warp2D(floats(*rgb, false), n, m, {b.phi_i, b.theta_i, {0.0, 1.0, 2.0}}, false);
    } else if (const TensorFile::Field* spec = t.Find("spectra")) {
      (void)field("spectra", TensorFile::kF32, 5);
      const TensorFile::Field& wl = field("wavelengths", TensorFile::kF32, 1);
      const std::vector<double> lambda = nodes(wl, 1, 1e5);
      expect_shape(*spec, {np, nt, lambda.size(), n, m}, "(n_phi_i x n_theta_i x n_wavelengths x N x M)");
      std::vector<std::array<double, 3>> w;
      try {
        w = cie::RgbWeights(lambda);
      } catch (const std::invalid_argument& e) {
        fail("wavelengths", e.what());
      }
      const std::vector<float> s = floats(*spec, true);
      const std::size_t L = lambda.size(), plane = n * m;
      std::vector<float> out(np * nt * 3 * plane);
      for (std::size_t k = 0; k < np * nt; ++k)
        for (int c = 0; c < 3; ++c)
          for (std::size_t i = 0; i < plane; ++i) {
            double sum = 0;
            for (std::size_t l = 0; l < L; ++l) sum += w[l][c] * s[(k * L + l) * plane + i];
            out[(k * 3 + c) * plane + i] = static_cast<float>(sum);
          }
      b.values = Warp2D(std::move(out), n, m, {b.phi_i, b.theta_i, {0.0, 1.0, 2.0}}, false);
    } else {
      throw std::runtime_error(what + " has neither an 'rgb' nor a 'spectra' field");
    }
    if (const TensorFile::Field* valid = t.Find("valid"))
      if (valid->dtype != TensorFile::kU8) fail("valid", "has dtype " + TensorFile::DTypeName(valid->dtype) + ", expected uint8");
    b.n_values = 3;
    return b;
  }
};

// Model [rgl]: a measured BSDF in the RGL-EPFL tensor format.
//
// No numeric parameters. Settings:
// | setting | values | meaning                                      |
// |---------|--------|----------------------------------------------|
// | path    | FILE   | the .bsdf file (also written "rgl:FILE")     |
//
// Eval is the format's reconstruction (above) with the cosine of wo divided
// out, a constant of T. Not reciprocal: the reconstruction is tabulated per
// incident direction. Sampling is cosine-weighted.
class Rgl : public CosineSampling {
 public:
  explicit Rgl(const Settings& settings) {
    const auto path = settings.find("path");
    if (path == settings.end() || path->second.empty())
      throw ModelError("model 'rgl' needs path=FILE (an RGL .bsdf file, e.g. rgl:material.bsdf)");
    try {
      data_ = std::make_shared<const RglBsdf>(RglBsdf::Read(path->second));
    } catch (const std::runtime_error& e) {
      throw ModelError(e.what());
    }
    weight_ = EstimateAlbedo();
    width_ = MeasuredLobeWidth(
        [&](const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) { return data_->Fr(wi, wo); });
  }

  static ModelInfo Info() {
    ModelInfo info;
    info.name = "rgl";
    info.summary = "measured BSDF, RGL-EPFL tensor file .bsdf (Dupuy & Jakob 2018)";
    info.reciprocal = false;          // one table per incident direction
    info.energy_conserving = false;   // measured data
    info.settings = {"path"};
    return info;
  }

  // Measured: whatever the file holds, taken as a diffuse part and a glossy
  // peak whose width is measured once from the data (MeasuredLobeWidth).
  static constexpr unsigned kKind = LobeKind::kDiffuse | LobeKind::kGlossy;
  static constexpr bool kChannelsIndependent = true;  // no parameters
  LobeWidth Width(const double*) const { return {width_, width_}; }

  const RglBsdf& Data() const { return *data_; }

  template <typename T>
  Rgb<T> Eval(const T*, const Vec3<T>& wi, const Vec3<T>& wo) const {
    if (!SameUpperHemisphere(wi, wo)) return Rgb<T>::Constant(T(0));
    const Rgb<double> f = data_->Fr(Eigen::Vector3d(Value(wi.x()), Value(wi.y()), Value(wi.z())),
                                    Eigen::Vector3d(Value(wo.x()), Value(wo.y()), Value(wo.z())));
    return Rgb<T>(T(f[0]), T(f[1]), T(f[2]));
  }

  double SampleWeight(const double*) const { return weight_; }

 private:
  // Mean over channels of the directional albedo at theta_i = 0, 30, 60
  // degrees by 16 x 16 stratified cosine-weighted outgoing samples.
  double EstimateAlbedo() const {
    constexpr int kN = 16;
    double sum = 0;
    for (double theta_i : {0.0, kPi / 6, kPi / 3}) {
      const Eigen::Vector3d wi(std::sin(theta_i), 0, std::cos(theta_i));
      for (int a = 0; a < kN; ++a)
        for (int b = 0; b < kN; ++b)
          sum += kPi * data_->Fr(wi, SampleCosineHemisphere<double>((a + 0.5) / kN, (b + 0.5) / kN)).mean();
    }
    return std::max(sum / (3 * kN * kN), 0.0);
  }

  std::shared_ptr<const RglBsdf> data_;
  double width_ = 1;
  double weight_ = 0;
};

}  // namespace brdfkit
