#include "formats/rgl_writer.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>
#include <vector>

namespace brdfkit::formats {

namespace {

double Luminance(const Rgb<double>& c) { return 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]; }

void Check(bool ok, const std::string& what) {
  if (!ok) throw std::invalid_argument("RGL writer: " + what);
}

// The source at (wi, wo), checked.
Rgb<double> Source(const BrdfFunction& f, const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) {
  const Rgb<double> v = f(wi, wo);
  if (!v.isFinite().all())
    throw std::runtime_error("RGL writer: the source is not finite at wi = (" + std::to_string(wi.x()) + ", " +
                             std::to_string(wi.y()) + ", " + std::to_string(wi.z()) + "), wo = (" +
                             std::to_string(wo.x()) + ", " + std::to_string(wo.y()) + ", " + std::to_string(wo.z()) + ")");
  return v.max(0.0);
}

}  // namespace

TensorFile MakeRgl(const BrdfFunction& f, const RglOptions& o) {
  Check(o.theta_i >= 2 && o.theta_i <= 1024, "theta_i slices must be 2 to 1024");
  Check(o.phi_i == 0 || (o.phi_i >= 3 && o.phi_i <= 1024), "phi_i slices must be 0 (isotropic) or 3 to 1024");
  Check(o.theta_max_deg > 0 && o.theta_max_deg < 90, "theta_max must be in (0, 90) degrees");
  for (int r : {o.ndf, o.sigma, o.vndf, o.samples}) Check(r >= 2 && r <= 4096, "resolutions must be 2 to 4096");
  const bool iso = o.phi_i == 0;
  using RB = RglBsdf;

  // 1. ndf.
  const std::size_t nd = static_cast<std::size_t>(o.ndf);
  std::vector<double> d(nd * nd);
  double d_max = 0;
  for (std::size_t y = 0; y < nd; ++y)
    for (std::size_t x = 0; x < nd; ++x) {
      const double theta = RB::UToTheta(x / double(nd - 1)), phi = RB::UToPhi(y / double(nd - 1));
      double v = 0;
      if (x + 1 < nd) {  // the last column is the horizon, where cos^2 vanishes
        if (iso && y > 0) {
          v = d[x];
        } else {
          const Eigen::Vector3d wm = RB::Direction(theta, phi);
          v = Luminance(Source(f, wm, wm)) * wm.z() * wm.z();
        }
      }
      d[y * nd + x] = v;
      d_max = std::max(d_max, v);
    }
  // A black source has no retro-reflection to learn from: a uniform density.
  const double floor = d_max > 0 ? 1e-5 * d_max : 1.0;
  for (double& v : d) v = std::max(v, floor);
  // Trapezoidal weights of the nodes over the square times the Jacobian.
  auto node_weight = [](std::size_t i, std::size_t n) { return (i == 0 || i + 1 == n ? 0.5 : 1.0) / double(n - 1); };
  std::vector<Eigen::Vector3d> m_dir(nd * nd);
  std::vector<double> m_w(nd * nd);
  double norm = 0;
  for (std::size_t y = 0; y < nd; ++y)
    for (std::size_t x = 0; x < nd; ++x) {
      const double ux = x / double(nd - 1), theta = RB::UToTheta(ux);
      m_dir[y * nd + x] = RB::Direction(theta, RB::UToPhi(y / double(nd - 1)));
      m_w[y * nd + x] = node_weight(x, nd) * node_weight(y, nd) * 2 * kPi * kPi * ux * std::sin(theta);
      norm += d[y * nd + x] * m_dir[y * nd + x].z() * m_w[y * nd + x];
    }
  std::vector<float> ndf(nd * nd);
  for (std::size_t i = 0; i < nd * nd; ++i) ndf[i] = static_cast<float>(d[i] / norm);
  const Warp2D ndf_table(ndf, nd, nd, {}, false);

  // 2. sigma.
  const std::size_t ns = static_cast<std::size_t>(o.sigma);
  std::vector<float> sigma(ns * ns);
  for (std::size_t y = 0; y < ns; ++y)
    for (std::size_t x = 0; x < ns; ++x) {
      if (iso && y > 0) {
        sigma[y * ns + x] = sigma[x];
        continue;
      }
      const Eigen::Vector3d wi = RB::Direction(RB::UToTheta(x / double(ns - 1)), RB::UToPhi(y / double(ns - 1)));
      double s = 0;
      for (std::size_t i = 0; i < nd * nd; ++i) s += ndf[i] * std::max(0.0, wi.dot(m_dir[i])) * m_w[i];
      sigma[y * ns + x] = static_cast<float>(s);
    }
  const Warp2D sigma_table(sigma, ns, ns, {}, false);

  // Slices.
  std::vector<double> theta_nodes(static_cast<std::size_t>(o.theta_i)), phi_nodes;
  for (std::size_t k = 0; k < theta_nodes.size(); ++k)
    theta_nodes[k] = static_cast<float>(o.theta_max_deg * kPi / 180 * double(k) / double(theta_nodes.size() - 1));
  if (iso) {
    phi_nodes = {static_cast<float>(-kPi), static_cast<float>(kPi)};
  } else {
    for (int k = 0; k < o.phi_i; ++k) phi_nodes.push_back(static_cast<float>(-kPi + 2 * kPi * k / (o.phi_i - 1)));
  }
  const std::size_t np = phi_nodes.size(), nt = theta_nodes.size();
  auto slice_wi = [&](std::size_t a, std::size_t b) { return RB::Direction(theta_nodes[b], iso ? 0.0 : phi_nodes[a]); };

  // 3. vndf.
  const std::size_t nv = static_cast<std::size_t>(o.vndf);
  // The warp's density adds a uniform share to D so that the tails and the
  // horizon keep nodes (D itself, in the reconstruction, is left alone).
  constexpr double spread = 0.2;
  std::vector<float> vndf(np * nt * nv * nv);
  for (std::size_t a = 0; a < np; ++a)
    for (std::size_t b = 0; b < nt; ++b) {
      float* out = vndf.data() + (a * nt + b) * nv * nv;
      if (iso && a > 0) {
        std::copy(vndf.begin() + std::ptrdiff_t(b * nv * nv), vndf.begin() + std::ptrdiff_t((b + 1) * nv * nv), out);
        continue;
      }
      const Eigen::Vector3d wi = slice_wi(a, b);
      const double sig = sigma_table.Eval(RB::ThetaToU(theta_nodes[b]), RB::PhiToU(iso ? 0.0 : phi_nodes[a]));
      for (std::size_t y = 0; y < nv; ++y)
        for (std::size_t x = 0; x < nv; ++x) {
          const double ux = x / double(nv - 1), uy = y / double(nv - 1), theta = RB::UToTheta(ux);
          const Eigen::Vector3d wm = RB::Direction(theta, RB::UToPhi(uy));
          out[y * nv + x] = static_cast<float>((ndf_table.Eval(ux, uy) + spread * sig / kPi) * std::max(0.0, wi.dot(wm)) /
                                               sig * 2 * kPi * kPi * ux * std::sin(theta));
        }
    }
  const Warp2D vndf_warp(vndf, nv, nv, {phi_nodes, theta_nodes}, true);

  // 4. values.
  const std::size_t n = static_cast<std::size_t>(o.samples), plane = n * n;
  std::vector<float> rgb(np * nt * 3 * plane), lum(np * nt * plane);
  for (std::size_t a = 0; a < np; ++a)
    for (std::size_t b = 0; b < nt; ++b) {
      const std::size_t slice = a * nt + b;
      if (iso && a > 0) {
        std::copy_n(rgb.begin() + std::ptrdiff_t(b * 3 * plane), 3 * plane, rgb.begin() + std::ptrdiff_t(slice * 3 * plane));
        std::copy_n(lum.begin() + std::ptrdiff_t(b * plane), plane, lum.begin() + std::ptrdiff_t(slice * plane));
        continue;
      }
      const Eigen::Vector3d wi = slice_wi(a, b);
      const double sig = sigma_table.Eval(RB::ThetaToU(theta_nodes[b]), RB::PhiToU(iso ? 0.0 : phi_nodes[a]));
      for (std::size_t y = 0; y < n; ++y)
        for (std::size_t x = 0; x < n; ++x) {
          const std::array<double, 2> u = vndf_warp.Sample(x / double(n - 1), y / double(n - 1), slice);
          const Eigen::Vector3d wm = RB::Direction(RB::UToTheta(u[0]), RB::UToPhi(u[1]));
          const Eigen::Vector3d wo = 2 * wi.dot(wm) * wm - wi;
          // Below the horizon the value continues f cos(theta_o) oddly (f at
          // the mirror image of wo, times the negative cosine), so that
          // interpolation across the horizon stays smooth and crosses zero there.
          const Eigen::Vector3d wo_n = wo.normalized();
          const Eigen::Vector3d wo_up(wo_n.x(), wo_n.y(), std::max(std::abs(wo_n.z()), 1e-9));
          const Rgb<double> v = Source(f, wi, wo_up) * wo_n.z() * 4 * sig / ndf_table.Eval(u[0], u[1]);
          for (int c = 0; c < 3; ++c) rgb[(slice * 3 + c) * plane + y * n + x] = static_cast<float>(v[c]);
          lum[slice * plane + y * n + x] = static_cast<float>(std::max(Luminance(v), 0.0));  // a sampling density
        }
    }

  TensorFile t;
  t.Add("description", std::vector<unsigned char>(o.description.begin(), o.description.end()));
  t.Add("jacobian", std::vector<unsigned char>{1});
  t.Add("theta_i", std::vector<float>(theta_nodes.begin(), theta_nodes.end()), {nt});
  t.Add("phi_i", std::vector<float>(phi_nodes.begin(), phi_nodes.end()), {np});
  t.Add("ndf", ndf, {nd, nd});
  t.Add("sigma", sigma, {ns, ns});
  t.Add("vndf", vndf, {np, nt, nv, nv});
  t.Add("luminance", lum, {np, nt, n, n});
  t.Add("rgb", rgb, {np, nt, 3, n, n});
  return t;
}

void WriteRgl(const std::string& path, const BrdfFunction& f, const RglOptions& options) {
  MakeRgl(f, options).Write(path);
}

RglAccuracy MeasureRglAccuracy(const RglBsdf& file, const BrdfFunction& f, double theta_max_deg, double step_deg,
                               double threshold) {
  RglAccuracy acc;
  std::vector<double> errors;
  const double deg = kPi / 180;
  std::vector<double> phis = {0.0};
  if (!file.isotropic)
    for (double p = 50; p < 360; p += 50) phis.push_back(p);
  for (double ti = step_deg / 2; ti <= theta_max_deg; ti += step_deg)
    for (double pi : phis) {
      const Eigen::Vector3d wi = RglBsdf::Direction(ti * deg, pi * deg);
      std::vector<Eigen::Vector3d> wos;
      std::vector<Rgb<double>> ref;
      Rgb<double> peak = Rgb<double>::Zero();
      for (double to = 0.5; to < 90; to += 1)
        for (double po = 1; po < 360; po += 2) {
          const Eigen::Vector3d wo = RglBsdf::Direction(to * deg, po * deg);
          wos.push_back(wo);
          ref.push_back(f(wi, wo) * wo.z());
          peak = peak.max(ref.back());
        }
      for (std::size_t k = 0; k < wos.size(); ++k) {
        const Rgb<double> got = file.FrCos(wi, wos[k]);
        for (int c = 0; c < 3; ++c) {
          if (!(ref[k][c] > threshold * peak[c])) continue;
          const double e = std::abs(got[c] - ref[k][c]) / ref[k][c];
          errors.push_back(e);
          acc.max_relative = std::max(acc.max_relative, e);
        }
      }
    }
  acc.points = errors.size();
  if (errors.empty()) return acc;
  double sum = 0;
  for (double e : errors) sum += e;
  acc.mean_relative = sum / double(errors.size());
  std::sort(errors.begin(), errors.end());
  acc.p99_relative = errors[std::min(errors.size() - 1, static_cast<std::size_t>(0.99 * double(errors.size())))];
  return acc;
}

}  // namespace brdfkit::formats
