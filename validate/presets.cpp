#include "validate/presets.h"

#include <ImfChannelList.h>
#include <ImfFloatVectorAttribute.h>
#include <ImfFrameBuffer.h>
#include <ImfHeader.h>
#include <ImfMultiPartOutputFile.h>
#include <ImfOutputPart.h>
#include <ImfPartType.h>
#include <ImfStdIO.h>
#include <ImfStringAttribute.h>
#include <half.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/partitioner.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <map>
#include <memory>
#include <sstream>

#include "brdf/atomic_file.h"
#include "brdf/microfacet.h"
#include "brdf/model.h"
#include "brdf/registry.h"
#include "validate/albedo.h"

namespace brdfkit::validate {

namespace {

// --- integrands that are not registered models -----------------------------

// An integrand for the albedo rules that is not a model: no sampling, grey,
// a glossy lobe (subclasses give its Width), described by its name alone.
class Integrand : public Bxdf<double> {
 public:
  explicit Integrand(const std::string& name) { info_.name = name; }
  const ModelInfo& Info() const override { return info_; }
  BsdfSample<double> Sample(const double*, const Vec3<double>&, double, double) const override { return {}; }
  double Pdf(const double*, const Vec3<double>&, const Vec3<double>&) const override { return 0; }
  double SampleWeight(const double*) const override { return 1; }
  bool CanSample() const override { return false; }
  unsigned Kind() const override { return LobeKind::kGlossy; }
  bool ChannelsIndependent() const override { return true; }

 private:
  ModelInfo info_;
};

// The mean of s(wi.h) over the visible normals h of wi, counting only the
// reflections wo = reflect(wi, h) that leave above the surface:
//   s_bar(wi) = int D_wi(h) [wo.z > 0] s(wi.h) dh,  D_wi(h) = G1(wi) max(0, wi.h) D(h) / wi.z
// (Heitz 2018), written as an albedo over wo with dh = dwo / (4 wo.h):
//   s_bar(wi) = int f(wo, wi) wo.z dwo,  f(wo, wi) = D(h) G1(wi) s(wi.h) / (4 wo.z wi.z),
// so the half-vector rule integrates it as the directional albedo of wi.
// GGX, isotropic, alpha held here (the parameter vector is not read).
class VisibleNormalMean final : public Integrand {
 public:
  VisibleNormalMean(double alpha, std::function<double(double)> s)
      : Integrand("visible_normal_mean"), alpha_(alpha), s_(std::move(s)) {}
  Rgb<double> Eval(const double*, const Vec3<double>& wo, const Vec3<double>& wi) const override {
    if (wo.z() <= 0 || wi.z() <= 0) return Rgb<double>::Zero();
    const Vec3<double> hv = wo + wi;
    const double len = hv.norm();
    if (!(len > 0)) return Rgb<double>::Zero();  // opposite directions: no half vector
    const Vec3<double> h = hv / len;
    const double c = std::min(1.0, wi.dot(h));
    if (c <= 0) return Rgb<double>::Zero();
    const double g1 = 1 / (1 + LambdaGgx(wi, alpha_, alpha_));
    return Rgb<double>::Constant(DGgx(h, alpha_, alpha_) * g1 * s_(c) / (4 * wo.z() * wi.z()));
  }
  LobeWidth Width(const double*) const override { return {alpha_, alpha_}; }

 private:
  double alpha_;
  std::function<double(double)> s_;
};

// Filament's cloth lobe: the Charlie sheen distribution (Estevez & Kulla
// 2017) D(h) = (2 + 1 / alpha) sin(theta_h)^(1 / alpha) / (2 pi) with
// Neubelt & Pettineo's visibility V = 1 / (4 (NoL + NoV - NoL NoV)); f = D V.
double CharlieNeubelt(double alpha, const Vec3<double>& wi, const Vec3<double>& wo) {
  if (wi.z() <= 0 || wo.z() <= 0) return 0;
  const Vec3<double> hv = wi + wo;
  const double len2 = hv.squaredNorm();
  if (!(len2 > 0)) return 0;  // opposite directions: no half vector
  // sin^2(theta_h) from the tangential components, exact near the pole.
  const double sin2 = (hv.x() * hv.x() + hv.y() * hv.y()) / len2;
  const double d = (2 + 1 / alpha) * std::pow(sin2, 0.5 / alpha) / (2 * kPi);
  const double v = 1 / (4 * (wi.z() + wo.z() - wi.z() * wo.z()));
  return d * v;
}

// A registered model with its parameters set by name (colour parameters on
// every channel, or per channel).
struct Configured {
  std::unique_ptr<Bxdf<double>> bxdf;
  std::vector<double> params;
};
Configured Configure(const std::string& spec, const std::vector<std::pair<std::string, Eigen::Array3d>>& values) {
  const Model m = Model::Parse(spec);
  Configured c{m.Make<double>(), m.Info().Defaults()};
  for (const auto& [name, v] : values)
    for (std::size_t i = 0; i < m.Info().params.size(); ++i)
      if (m.Info().params[i].name == name)
        for (std::size_t k = 0; k < (m.Info().params[i].colour ? 3u : 1u); ++k) c.params[m.Info().Offset(i) + k] = v[k];
  return c;
}
Eigen::Array3d All(double v) { return Eigen::Array3d::Constant(v); }

// Filament's three DFG channels in one integrand: GGX with f0 = 0 (F =
// (1 - v.h)^5) and f0 = 1 (F = 1) in R and G, the cloth lobe in B, so that
// one quadrature serves the texel (the error estimate is the largest of
// the three).
class FilamentDfg final : public Integrand {
 public:
  explicit FilamentDfg(double alpha)
      : Integrand("filament_dfg"),
        alpha_(alpha),
        ggx_(Configure("ggx", {{"alpha", All(alpha)}, {"f0", Eigen::Array3d(0, 1, 0)}})) {}
  Rgb<double> Eval(const double*, const Vec3<double>& wi, const Vec3<double>& wo) const override {
    Rgb<double> f = ggx_.bxdf->Eval(ggx_.params.data(), wi, wo);
    f[2] = CharlieNeubelt(alpha_, wi, wo);
    return f;
  }
  void EvalBatch(const double*, const double* wi, std::size_t wi_stride, const double* wo, std::size_t wo_stride,
                 std::size_t n, double* out) const override {
    ggx_.bxdf->EvalBatch(ggx_.params.data(), wi, wi_stride, wo, wo_stride, n, out);
    for (std::size_t k = 0; k < n; ++k) {
      const double* a = wi + k * wi_stride;
      const double* b = wo + k * wo_stride;
      out[3 * k + 2] = CharlieNeubelt(alpha_, Vec3<double>(a[0], a[1], a[2]), Vec3<double>(b[0], b[1], b[2]));
    }
  }
  LobeWidth Width(const double*) const override { return ggx_.bxdf->Width(ggx_.params.data()); }

 private:
  double alpha_;
  Configured ggx_;
};

// One entry of one table: fills channel c of entry `node` (every channel
// for c = -1).
struct Job {
  std::size_t table;  // index into the preset's tables
  std::size_t node;
  int channel;
  std::function<Estimate()> compute;
  bool average;  // E_avg jobs cost tens of entries: scheduled first
};

// A table computed from other tables once their jobs are done.
struct Derived {
  std::size_t table;
  std::vector<std::size_t> inputs;
  std::function<void(std::vector<PresetTable>&)> fill;
};

Estimate Exact(double v) {
  Estimate e;
  e.value = Eigen::Array3d::Constant(v);
  return e;
}

AlbedoQuadratureOptions Quadrature(const PresetOptions& o) {
  AlbedoQuadratureOptions q;
  q.abs_tolerance = o.abs_tolerance;
  q.max_evals = 4000000;
  return q;
}

LobeShape ShapeOf(double alpha) {
  LobeShape s;
  s.width = alpha;
  return s;
}

PresetAxis NodeAxis(const std::string& name, int n, double lo, double hi) {
  PresetAxis a;
  a.name = name;
  for (int k = 0; k < n; ++k) {
    const double c = n == 1 ? 0.0 : double(k) / (n - 1);
    a.coordinate.push_back(c);
    a.evaluated.push_back(std::clamp(c, lo, hi));
  }
  return a;
}

PresetTable NewTable(const std::string& name, const std::string& definition, std::vector<PresetAxis> axes,
                     std::vector<std::string> channels) {
  PresetTable t{name, definition, std::move(axes), std::move(channels), {}, {}, false};
  t.value.assign(t.nodes() * t.channels.size(), 0.0);
  t.error.assign(t.value.size(), 0.0);
  return t;
}

// Cycles' index axis: z = F0^(1/4), ior = (1 + z^2) / (1 - z^2).
double IorOfZ(double z) { return (1 + z * z) / (1 - z * z); }

// Cycles' singular cases (cycles_precompute through bsdf_microfacet.h): the
// smooth limit where alpha^2 <= 5e-7, no interface where |ior - 1| < 1e-4.
bool SmoothRoughness(double roughness) { return std::pow(roughness, 4) <= 5e-7; }
bool MatchedIndex(double ior) { return std::abs(ior - 1) < 1e-4; }

Configured Glass(double roughness, double eta) {
  return Configure("ggx_glass_correlated", {{"alpha", All(roughness * roughness)}, {"eta", All(eta)}});
}

// E_avg of rough glass with light from inside (eta = 1 / ior): the reflected
// average of that side plus the transmitted average from outside divided by
// ior^2. Generalised reciprocity, f(wi, wo) / eta_wo^2 = f(wo, wi) / eta_wi^2,
// makes the hemispherical transmittances of the two sides
// T_avg(1 / ior) = T_avg(ior) / ior^2; from outside no total internal
// reflection cuts the transmitted lobe, and its rule is the cheap one. The
// tolerance: 3/4 to the reflected part, 1/4 (times ior^2, undone by the
// division) to the transmitted part.
Estimate InsideGlassAverage(double roughness, double ior, const AlbedoQuadratureOptions& q) {
  using Part = AlbedoQuadratureOptions::Part;
  const LobeShape shape = ShapeOf(roughness * roughness);
  AlbedoQuadratureOptions qr = q, qt = q;
  qr.part = Part::kReflected;
  qr.abs_tolerance = 0.75 * q.abs_tolerance;
  qt.part = Part::kTransmitted;
  qt.abs_tolerance = 0.25 * q.abs_tolerance * ior * ior;
  const Configured inside = Glass(roughness, 1 / ior), outside = Glass(roughness, ior);
  const Estimate r = AverageAlbedo(*inside.bxdf, inside.params.data(), shape, qr);
  const Estimate t = AverageAlbedo(*outside.bxdf, outside.params.data(), shape, qt);
  Estimate e;
  e.value = r.value + t.value / (ior * ior);
  e.error = r.error + t.error / (ior * ior);
  e.evals = r.evals + t.evals;
  return e;
}

// Rough glass (GGX, height-correlated Smith) over (roughness, mu, z), from
// outside (eta = ior(z)) and from inside (eta = 1 / ior(z)): tables
// <stem>E, <stem>Eavg, <stem>inv_E, <stem>inv_Eavg.
void AddGlass(std::vector<PresetTable>& tables, std::vector<Job>& jobs, const std::string& stem,
              const std::array<PresetAxis, 3>& axes, const AlbedoQuadratureOptions& q) {
  const PresetAxis& rough = axes[0];
  const PresetAxis& mu_axis = axes[1];
  const PresetAxis& zior = axes[2];
  const std::size_t nr = rough.coordinate.size(), nm = mu_axis.coordinate.size(), nz = zior.coordinate.size();
  for (const bool inv : {false, true}) {
    const std::string name = stem + (inv ? "inv_" : "");
    const std::string side = inv ? "eta = 1 / ior(z), light from inside" : "eta = ior(z), light from outside";
    tables.push_back(NewTable(name + "E", "E_R + E_T(roughness, mu, z): power scattered by rough glass, " + side,
                              {rough, mu_axis, zior}, {"E"}));
    const std::size_t e = tables.size() - 1;
    tables.push_back(NewTable(name + "Eavg", "E_avg(roughness, z) = 2 int_0^1 (E_R + E_T) mu dmu, " + side,
                              {rough, zior}, {"E"}));
    const std::size_t avg = tables.size() - 1;
    for (std::size_t z = 0; z < nz; ++z) {
      const double ior = IorOfZ(zior.evaluated[z]);
      const double eta = inv ? 1 / ior : ior;
      for (std::size_t x = 0; x < nr; ++x) {
        const double r = rough.evaluated[x];
        // A smooth interface reflects F and transmits 1 - F; a matched one transmits all.
        const bool exact = SmoothRoughness(r) || MatchedIndex(ior);
        for (std::size_t y = 0; y < nm; ++y) {
          const double mu = mu_axis.evaluated[y];
          jobs.push_back({e, (z * nm + y) * nr + x, 0, [=] {
                            if (exact) return Exact(1);
                            const Configured c = Glass(r, eta);
                            return AlbedoAtMu(*c.bxdf, c.params.data(), mu, ShapeOf(r * r), q);
                          }, false});
        }
        jobs.push_back({avg, z * nr + x, 0, [=] {
                          if (exact) return Exact(1);
                          if (inv) return InsideGlassAverage(r, ior, q);
                          const Configured c = Glass(r, eta);
                          return AverageAlbedo(*c.bxdf, c.params.data(), ShapeOf(r * r), q);
                        }, true});
      }
    }
  }
}

void AddCycles(std::vector<PresetTable>& tables, std::vector<Job>& jobs, const PresetOptions& o) {
  const AlbedoQuadratureOptions q = Quadrature(o);
  const PresetAxis rough32 = NodeAxis("roughness", 32, 1e-4, 1), mu32 = NodeAxis("mu", 32, 1e-4, 1);
  const PresetAxis rough16 = NodeAxis("roughness", 16, 1e-4, 1), mu16 = NodeAxis("mu", 16, 1e-4, 1);
  const PresetAxis zior = NodeAxis("z", 16, 1e-4, 0.99);

  // GGX reflection, F = 1.
  tables.push_back(NewTable("table_ggx_E", "E(roughness, mu): GGX reflection albedo with F = 1 (single scattering)",
                            {rough32, mu32}, {"E"}));
  const std::size_t ggx_e = tables.size() - 1;
  tables.push_back(NewTable("table_ggx_Eavg", "E_avg(roughness) = 2 int_0^1 E(mu) mu dmu of table_ggx_E", {rough32},
                            {"E"}));
  const std::size_t ggx_avg = tables.size() - 1;
  for (std::size_t x = 0; x < 32; ++x) {
    const double r = rough32.evaluated[x];
    const bool smooth = SmoothRoughness(r);
    for (std::size_t y = 0; y < 32; ++y) {
      const double mu = mu32.evaluated[y];
      jobs.push_back({ggx_e, y * 32 + x, 0, [=] {
                        if (smooth) return Exact(1);  // a mirror with F = 1 reflects everything
                        const Configured c = Configure("ggx", {{"alpha", All(r * r)}, {"f0", All(1)}});
                        return AlbedoAtMu(*c.bxdf, c.params.data(), mu, ShapeOf(r * r), q);
                      }, false});
    }
    jobs.push_back({ggx_avg, x, 0, [=] {
                      if (smooth) return Exact(1);
                      const Configured c = Configure("ggx", {{"alpha", All(r * r)}, {"f0", All(1)}});
                      return AverageAlbedo(*c.bxdf, c.params.data(), ShapeOf(r * r), q);
                    }, true});
  }

  AddGlass(tables, jobs, "table_ggx_glass_", {rough16, mu16, zior}, q);

  // Generalised Schlick interpolation factors.
  for (const bool ior_mode : {true, false}) {
    PresetAxis zaxis = zior;
    tables.push_back(NewTable(
        ior_mode ? "table_ggx_gen_schlick_ior_s" : "table_ggx_gen_schlick_s",
        ior_mode ? "s_bar(roughness, mu, z): mean over the visible normals of (F(wi.h, ior(z)) - F0) / (1 - F0), "
                   "reflections above the surface"
                 : "s_bar(roughness, mu, z): mean over the visible normals of (1 - wi.h)^e, e = 5 (1 - z) / z, "
                   "reflections above the surface",
        {rough16, mu16, zaxis}, {"s"}));
    const std::size_t t = tables.size() - 1;
    for (std::size_t z = 0; z < 16; ++z) {
      const double zz = zior.evaluated[z];
      const double ior = ior_mode ? IorOfZ(zz) : 1.0;
      const double f0 = std::pow((ior - 1) / (ior + 1), 2);
      const double e = 5 * (1 - zz) / zz;
      std::function<double(double)> s;
      if (ior_mode) {
        s = [ior, f0](double c) {
          return std::clamp((FresnelDielectric(ior, c) - f0) / (1 - f0), 0.0, 1.0);
        };
      } else {
        s = [e](double c) { return std::pow(std::max(0.0, 1 - c), e); };
      }
      for (std::size_t x = 0; x < 16; ++x) {
        const double r = rough16.evaluated[x];
        for (std::size_t y = 0; y < 16; ++y) {
          const double mu = mu16.evaluated[y];
          jobs.push_back({t, (z * 16 + y) * 16 + x, 0, [=] {
                            // Matched index: F = F0 = 0 everywhere.
                            if (ior_mode && MatchedIndex(ior)) return Exact(0);
                            if (SmoothRoughness(r)) return Exact(s(mu));  // every visible normal is n
                            const VisibleNormalMean m(r * r, s);
                            return AlbedoAtMu(m, nullptr, mu, ShapeOf(r * r), q);
                          }, false});
        }
      }
    }
  }
}

// F_avg(eta) = 2 int_0^1 F(mu, eta) mu dmu of the exact dielectric Fresnel
// term, eta > 1 (smooth in mu: one Gauss-Kronrod panel converges).
Estimate FresnelAverage(double eta) {
  double err = 0;
  std::int64_t n = 0;
  const Eigen::Array3d v = AdaptiveGaussKronrod(
      [eta](double mu) { return Eigen::Array3d::Constant(2 * mu * FresnelDielectric(eta, mu)); }, 0, 1, {}, 1e-14, 100,
      &err, &n);
  Estimate e;
  e.value = v;
  e.error = Eigen::Array3d::Constant(err + 1e-15);  // plus the rounding of the sum
  e.evals = n;
  return e;
}

// Kulla & Conty 2017's energy compensation of rough glass: the glass tables
// of both sides (as AddGlass), the Fresnel averages of both sides, and the
// share x of the multiply scattered energy that crosses the interface,
//   x = t / (1 + t),  t = eta^2 (1 - F_avg(1/eta)) (1 - E_avg(1/eta)) / ((1 - F_avg(eta)) (1 - E_avg(eta))),
// the form of Imageworks' OSL dielectric and of MoonRay. Seen from inside
// the share is 1 - x.
void AddKullaConty(std::vector<PresetTable>& tables, std::vector<Job>& jobs, std::vector<Derived>& derived,
                   const PresetOptions& o) {
  const int n = o.size;
  const PresetAxis rough = NodeAxis("roughness", n, 1e-4, 1), mu = NodeAxis("mu", n, 1e-4, 1);
  const PresetAxis zior = NodeAxis("z", n, 1e-4, 0.99);
  const std::size_t first = tables.size();
  AddGlass(tables, jobs, "kc_glass_", {rough, mu, zior}, Quadrature(o));
  const std::size_t avg_out = first + 1, avg_in = first + 3;
  tables.push_back(NewTable("kc_Favg", "F_avg(z) = 2 int_0^1 F(mu, ior(z)) mu dmu, exact dielectric Fresnel, light from outside",
                            {zior}, {"F"}));
  const std::size_t f_out = tables.size() - 1;
  tables.push_back(NewTable("kc_inv_Favg",
                            "F_avg(z) = 2 int_0^1 F(mu, 1 / ior(z)) mu dmu = 1 - (1 - F_avg(ior)) / ior^2, light from inside",
                            {zior}, {"F"}));
  const std::size_t f_in = tables.size() - 1;
  for (std::size_t z = 0; z < std::size_t(n); ++z) {
    const double ior = IorOfZ(zior.evaluated[z]);
    const bool matched = MatchedIndex(ior);
    jobs.push_back({f_out, z, 0, [=] { return matched ? Exact(0) : FresnelAverage(ior); }, false});
    // Reciprocity of the smooth interface: ior^2 (1 - F_avg(1 / ior)) = 1 - F_avg(ior).
    jobs.push_back({f_in, z, 0, [=] {
                      if (matched) return Exact(0);
                      Estimate e = FresnelAverage(ior);
                      e.value = 1 - (1 - e.value) / (ior * ior);
                      e.error /= ior * ior;
                      return e;
                    }, false});
  }
  tables.push_back(NewTable("kc_x",
                            "x(roughness, z) = t / (1 + t), t = eta^2 (1 - F_avg(1/eta)) (1 - E_avg(1/eta)) / ((1 - "
                            "F_avg(eta)) (1 - E_avg(eta))), eta = ior(z): the share of the multiply scattered energy "
                            "that is transmitted, light from outside (1 - x from inside)",
                            {rough, zior}, {"x"}));
  const std::size_t xt = tables.size() - 1;
  tables[xt].derived = true;
  derived.push_back({xt, {avg_out, avg_in, f_out, f_in}, [=](std::vector<PresetTable>& t) {
                       const std::size_t nr = rough.coordinate.size();
                       for (std::size_t z = 0; z < zior.coordinate.size(); ++z) {
                         const double ior = IorOfZ(zior.evaluated[z]);
                         if (MatchedIndex(ior)) {
                           // No interface: both sides alike, and t -> 1 as ior -> 1.
                           std::fill_n(t[xt].value.begin() + z * nr, nr, 0.5);
                           continue;
                         }
                         const double to = 1 - t[f_out].value[z], ti = 1 - t[f_in].value[z];
                         const double eto = t[f_out].error[z], eti = t[f_in].error[z];
                         for (std::size_t r = 0; r < nr; ++r) {
                           if (SmoothRoughness(rough.evaluated[r])) continue;  // filled below from the next node
                           const std::size_t k = z * nr + r;
                           const double lo = 1 - t[avg_out].value[k], li = 1 - t[avg_in].value[k];
                           const double eo = t[avg_out].error[k], ei = t[avg_in].error[k];
                           // x at the ends of every factor's interval: its range bounds the error.
                           const auto x_of = [&](double a, double b, double c, double d) {
                             const double tt = ior * ior * a * b / (c * d);
                             return tt / (1 + tt);
                           };
                           const double x = x_of(ti, li, to, lo);
                           double err = 0;
                           if (!(lo - eo > 0 && li - ei > 0)) {
                             err = std::max(x, 1 - x);  // a loss not resolved: x is anywhere in [0, 1]
                           } else {
                             const double hi = x_of(ti + eti, li + ei, to - eto, lo - eo);
                             const double lw = x_of(ti - eti, li - ei, to + eto, lo + eo);
                             err = std::max(hi - x, x - lw) + 1e-15;  // plus rounding
                           }
                           t[xt].value[k] = x;
                           t[xt].error[k] = err;
                         }
                         // Roughness 0 loses nothing and x has no value there: the entry
                         // repeats the next node's, so that interpolation between them is flat.
                         for (std::size_t r = 0; r + 1 < nr; ++r)
                           if (SmoothRoughness(rough.evaluated[r])) {
                             std::size_t s = r + 1;
                             while (s + 1 < nr && SmoothRoughness(rough.evaluated[s])) ++s;
                             t[xt].value[z * nr + r] = t[xt].value[z * nr + s];
                             t[xt].error[z * nr + r] = t[xt].error[z * nr + s];
                           }
                       }
                     }});
}

void AddFilament(std::vector<PresetTable>& tables, std::vector<Job>& jobs, const PresetOptions& o) {
  const AlbedoQuadratureOptions q = Quadrature(o);
  const int n = o.size;
  PresetAxis nov{"NoV", {}, {}}, rough{"roughness", {}, {}};
  for (int i = 0; i < n; ++i) {
    nov.coordinate.push_back((i + 0.5) / n);
    nov.evaluated.push_back((i + 0.5) / n);
    // Row j holds perceptual roughness (j + 1.5) / N, one texel above the
    // coordinate (j + 0.5) / N the shader samples it at (cmgen's rows).
    rough.coordinate.push_back((i + 0.5) / n);
    rough.evaluated.push_back(std::min(1.0, (i + 1.5) / n));
  }
  tables.push_back(NewTable("DFG_LUT",
                            "R = int f(F = (1 - v.h)^5) NoL dl, G = int f(F = 1) NoL dl (GGX, height-correlated "
                            "Smith), B = int D_Charlie V_Neubelt NoL dl",
                            {nov, rough}, {"R", "G", "B"}));
  const std::size_t t = tables.size() - 1;
  for (int j = 0; j < n; ++j) {
    const double r = rough.evaluated[j], alpha = r * r;
    for (int i = 0; i < n; ++i) {
      const double mu = nov.evaluated[i];
      const std::size_t node = std::size_t(j) * n + i;
      jobs.push_back({t, node, -1, [=] {
                        const FilamentDfg m(alpha);
                        return AlbedoAtMu(m, nullptr, mu, ShapeOf(alpha), q);
                      }, false});
    }
  }
}

}  // namespace

std::vector<std::string> PresetNames() { return {"cycles", "filament", "kulla_conty"}; }

namespace {
// The tables of a preset, the jobs that fill them and the tables derived
// from them; options.size resolved to the preset's default (0) and checked.
void Plan(const std::string& name, PresetOptions options, std::vector<PresetTable>& tables, std::vector<Job>& jobs,
          std::vector<Derived>& derived) {
  options.size = PresetSize(name, options.size);
  if (name == "cycles") {
    AddCycles(tables, jobs, options);
  } else if (name == "filament") {
    AddFilament(tables, jobs, options);
  } else {
    AddKullaConty(tables, jobs, derived, options);
  }
}
}  // namespace

int PresetSize(const std::string& name, int size) {
  const auto sized = [&](int fallback, int lo, int hi) {
    if (size == 0) return fallback;
    if (size < lo || size > hi)
      throw ModelError("preset '" + name + "': size " + std::to_string(size) + " is outside [" + std::to_string(lo) +
                       ", " + std::to_string(hi) + "]");
    return size;
  };
  if (name == "cycles") {
    if (size != 0)
      throw ModelError("preset 'cycles' has Cycles' fixed sizes (32 and 16 nodes); size " + std::to_string(size) +
                       " cannot be set");
    return 0;
  }
  if (name == "filament") return sized(128, 2, 4096);
  if (name == "kulla_conty") return sized(16, 3, 256);
  std::string names;
  for (const std::string& n : PresetNames()) names += (names.empty() ? "" : ", ") + n;
  throw ModelError("unknown table preset '" + name + "' (presets: " + names + ")");
}

std::vector<std::string> PresetTableNames(const std::string& name) {
  PresetOptions o;
  o.size = name == "cycles" ? 0 : 3;
  std::vector<PresetTable> tables;
  std::vector<Job> jobs;
  std::vector<Derived> derived;
  Plan(name, o, tables, jobs, derived);
  std::vector<std::string> names;
  for (const PresetTable& t : tables) names.push_back(t.name);
  return names;
}

Preset BuildPreset(const std::string& name, const PresetOptions& options) {
  const auto start = std::chrono::steady_clock::now();
  Preset p;
  p.name = name;
  std::vector<Job> jobs;
  std::vector<Derived> derived;
  Plan(name, options, p.tables, jobs, derived);
  if (!options.tables.empty()) {
    std::string names;
    for (const PresetTable& t : p.tables) names += (names.empty() ? "" : ", ") + t.name;
    for (const std::string& want : options.tables)
      if (std::none_of(p.tables.begin(), p.tables.end(), [&](const PresetTable& t) { return t.name == want; }))
        throw ModelError("preset '" + name + "' has no table '" + want + "' (its tables: " + names + ")");
    // The wanted tables and those a wanted derived table is made from.
    std::vector<bool> needed(p.tables.size(), false);
    for (std::size_t t = 0; t < p.tables.size(); ++t)
      needed[t] = std::find(options.tables.begin(), options.tables.end(), p.tables[t].name) != options.tables.end();
    for (const Derived& d : derived)
      if (needed[d.table])
        for (std::size_t in : d.inputs) needed[in] = true;
    jobs.erase(std::remove_if(jobs.begin(), jobs.end(), [&](const Job& j) { return !needed[j.table]; }), jobs.end());
    derived.erase(std::remove_if(derived.begin(), derived.end(), [&](const Derived& d) { return !needed[d.table]; }),
                  derived.end());
  }
  std::stable_partition(jobs.begin(), jobs.end(), [](const Job& j) { return j.average; });
  std::atomic<std::size_t> done{0};
  std::atomic<std::int64_t> evals{0};
  const auto run = [&](Job& j) {
    const Estimate e = j.compute();
    PresetTable& t = p.tables[j.table];
    const std::size_t nc = t.channels.size();
    for (std::size_t c = 0; c < nc; ++c) {
      if (j.channel >= 0 && std::size_t(j.channel) != c) continue;
      t.value[j.node * nc + c] = e.value[j.channel >= 0 ? 0 : c];
      t.error[j.node * nc + c] = e.error[j.channel >= 0 ? 0 : c];
    }
    evals += e.evals;
    const std::size_t d = ++done;
    if (options.progress) options.progress(d, jobs.size());
  };
  // One job at a time per thread: their costs differ by a factor of 1000
  // (an average against a closed form), so chunks would leave threads idle.
  tbb::parallel_for(
      tbb::blocked_range<std::size_t>(0, jobs.size(), 1),
      [&](const tbb::blocked_range<std::size_t>& range) {
        for (std::size_t k = range.begin(); k < range.end(); ++k) run(jobs[k]);
      },
      tbb::simple_partitioner());
  for (const Derived& d : derived) d.fill(p.tables);
  if (!options.tables.empty()) {
    // Pruned only now: the jobs index the full list.
    std::vector<PresetTable> kept;
    for (PresetTable& t : p.tables)
      if (std::find(options.tables.begin(), options.tables.end(), t.name) != options.tables.end())
        kept.push_back(std::move(t));
    p.tables = std::move(kept);
  }
  for (const PresetTable& t : p.tables)
    for (double e : t.error)
      if (!t.derived) p.max_error = std::max(p.max_error, e);
  p.evals = std::size_t(evals.load());
  p.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return p;
}

std::string DescribePresetMisses(const Preset& p, double tolerance, std::size_t shown) {
  struct Miss {
    std::string where;
    double error;
  };
  std::vector<Miss> misses;
  for (const PresetTable& t : p.tables)
    for (std::size_t k = 0; k < t.error.size(); ++k)
      if (!t.derived && !(t.error[k] <= tolerance)) {
        const std::size_t node = k / t.channels.size();
        std::string at;
        std::size_t rest = node;
        for (const PresetAxis& a : t.axes) {
          const std::size_t i = rest % a.coordinate.size();
          rest /= a.coordinate.size();
          at += (at.empty() ? "" : ", ") + a.name + " " + FormatDouble(a.evaluated[i]);
        }
        misses.push_back({t.name + "[" + std::to_string(node) + "] " + t.channels[k % t.channels.size()] + " (" +
                              at + ")",
                          t.error[k]});
      }
  if (misses.empty()) return "";
  std::sort(misses.begin(), misses.end(), [](const Miss& a, const Miss& b) { return a.error > b.error; });
  std::ostringstream s;
  s << misses.size() << " preset entries miss the error tolerance " << FormatDouble(tolerance) << ":";
  for (std::size_t k = 0; k < std::min(shown, misses.size()); ++k)
    s << "\n  " << misses[k].where << ": error estimate " << FormatDouble(misses[k].error);
  return s.str();
}

unsigned short HalfBits(double v) { return half(float(v)).bits(); }

namespace {

bool IsFilament(const Preset& p) { return p.name == "filament"; }

std::string HexHalf(double v) {
  char buf[16];
  std::snprintf(buf, sizeof buf, "0x%04x", unsigned(HalfBits(v)));
  return buf;
}

// The array body: Cycles one row of the fastest axis a line, Filament four
// texels (twelve halves) a line.
std::string ArrayBody(const Preset& p, const PresetTable& t) {
  std::ostringstream s;
  if (IsFilament(p)) {
    for (std::size_t k = 0; k < t.value.size(); ++k)
      s << (k % 12 == 0 ? "    " : "") << HexHalf(t.value[k]) << ", " << (k % 12 == 11 ? "\n" : "");
    if (t.value.size() % 12) s << "\n";
    return s.str();
  }
  const std::size_t row = t.axes[0].coordinate.size();
  for (std::size_t k = 0; k < t.value.size(); ++k)
    s << (k % row == 0 ? "  " : " ") << FloatLiteral(t.value[k], t.name + "[" + std::to_string(k) + "]") << ","
      << (k % row == row - 1 ? "\n" : "");
  return s.str();
}

std::string AxesText(const PresetTable& t) {
  std::string s;
  for (const PresetAxis& a : t.axes) s += (s.empty() ? "" : ", ") + a.name + ":" + std::to_string(a.coordinate.size());
  return s;
}

}  // namespace

void WritePresetHeader(const Preset& p, const std::string& path) {
  std::ostringstream s;
  const bool inc = path.size() >= 4 && path.compare(path.size() - 4, 4, ".inc") == 0;
  if (inc) {
    if (!IsFilament(p))
      throw ModelError("'" + path + "': a .inc file holds Filament's one array; preset '" + p.name + "' has " +
                       std::to_string(p.tables.size()) + " (write a .h header)");
    // cmgen's dfg.inc: two comment lines, a blank line, the array body.
    s << "// generated with: brdfkit albedo --preset filament --header " << path << "\n"
      << "// DFG LUT stored as an RGB16F texture, in GL order\n\n"
      << ArrayBody(p, p.tables[0]);
    WriteFileAtomic(path, s.str());
    return;
  }
  s << "/* Generated by brdfkit albedo --preset " << p.name << ". Largest error estimate "
    << FormatDouble(p.max_error) << ".\n";
  if (IsFilament(p)) {
    const PresetTable& t = p.tables[0];
    const std::size_t n = t.axes[0].coordinate.size();
    s << " * Filament's split-sum DFG texture: " << n << " x " << n
      << " texels, RGB, IEEE half floats (round to nearest even).\n"
      << " * Element 3 (j " << n << " + i) + c: texel i (NoV = (i + 0.5) / " << n << ") of row j (perceptual\n"
      << " * roughness min(1, (j + 1.5) / " << n << "), sampled at (j + 0.5) / " << n << "), channel c:\n"
      << " *   R = int f(F = (1 - v.h)^5) NoL dl, G = int f(F = 1) NoL dl (GGX, height-correlated Smith),\n"
      << " *   B = int D_Charlie V_Neubelt NoL dl (cloth).\n"
      << " * Sample with linear filtering at (NoV, perceptual roughness), clamped to the edge; the\n"
      << " * specular response is mix(R, G, f0) and the energy compensation 1 + f0 (1 / G - 1). */\n"
      << "#ifndef BRDFKIT_FILAMENT_DFG_H\n#define BRDFKIT_FILAMENT_DFG_H\n\n#include <stdint.h>\n\n"
      << "#define DFG_LUT_SIZE " << n << "\n\n"
      << "static const uint16_t DFG_LUT[" << t.value.size() << "] = {\n"
      << ArrayBody(p, t) << "};\n\n"
      << "/* Channel c (0 R, 1 G, 2 B) of the texture at (NoV, perceptual roughness) in [0, 1]^2, as the\n"
      << " * shader's linear filter with clamp to edge samples it (texel centres at (i + 0.5) / N). C99, C++. */\n"
      << "static inline float dfg_lookup(float nov, float roughness, int c) {\n"
      << "  float u[2], w[2], sum = 0.0f;\n  int i[2], d, k;\n  u[0] = nov; u[1] = roughness;\n"
      << "  for (d = 0; d < 2; ++d) {\n"
      << "    float x = u[d] * (float)DFG_LUT_SIZE - 0.5f;\n"
      << "    x = x < 0.0f ? 0.0f : (x > (float)(DFG_LUT_SIZE - 1) ? (float)(DFG_LUT_SIZE - 1) : x);\n"
      << "    i[d] = (int)x;\n    if (i[d] > DFG_LUT_SIZE - 2) i[d] = DFG_LUT_SIZE - 2;\n    w[d] = x - (float)i[d];\n  }\n"
      << "  for (k = 0; k < 4; ++k) {\n"
      << "    const int a = k & 1, b = k >> 1;\n"
      << "    const unsigned h = DFG_LUT[3 * ((i[1] + b) * DFG_LUT_SIZE + i[0] + a) + c];\n"
      << "    const unsigned e = (h >> 10) & 31u, m = h & 1023u;\n"
      << "    /* IEEE half: subnormal m 2^-24, normal (1024 + m) 2^(e - 25). */\n"
      << "    float v = e ? (float)(1024u + m) * (float)(1u << e) / 33554432.0f : (float)m / 16777216.0f;\n"
      << "    if (h & 0x8000u) v = -v;\n"
      << "    sum += (a ? w[0] : 1.0f - w[0]) * (b ? w[1] : 1.0f - w[1]) * v;\n  }\n"
      << "  return sum;\n}\n\n#endif\n";
    WriteFileAtomic(path, s.str());
    return;
  }
  if (p.name == "cycles") {
    s << " * Blender Cycles' microfacet albedo tables (src/scene/shader.tables), in its layout: the first\n"
      << " * axis runs fastest, element [z nx ny + y nx + x]; node k of an axis of N nodes is k / (N - 1)\n"
      << " * and lookups map coordinate 0 and 1 onto the first and last node (kernel/util/lookup_table.h;\n"
      << " * cycles_table_lookup below).\n"
      << " * roughness: alpha = roughness^2; mu = cos(theta); z = F0^(1/4), ior = (1 + z^2) / (1 - z^2).\n"
      << " * Entries are evaluated where Cycles' generator evaluates them (mu and roughness at least 1e-4,\n"
      << " * z in [1e-4, 0.99]; roughness 0 as a smooth surface and z 0 as a matched index).\n";
  } else {
    s << " * Kulla & Conty 2017 energy compensation of rough glass (GGX, height-correlated Smith). The\n"
      << " * first axis runs fastest, element [z nx ny + y nx + x]; node k of an axis of N nodes is\n"
      << " * k / (N - 1), looked up by kc_lookup below (clamped, linear between nodes).\n"
      << " * roughness: alpha = roughness^2; mu = cos(theta); z = F0^(1/4), ior = (1 + z^2) / (1 - z^2).\n"
      << " * Entries are evaluated at mu and roughness at least 1e-4 and z in [1e-4, 0.99]; roughness 0\n"
      << " * is a smooth surface and z 0 a matched index (E = 1, F_avg = 0, x = 1/2 there); x at\n"
      << " * roughness 0, where nothing is lost, repeats the next node.\n"
      << " * The compensation lobe seen from outside: reflection c_R (1 - E(mu_o)) (1 - E(mu_i)) /\n"
      << " * (pi (1 - E_avg)), transmission c_T (1 - E(mu_o)) (1 - E_inv(mu_i)) / (pi (1 - E_inv_avg)),\n"
      << " * c_T = x (1 - F_avg), c_R = 1 - c_T; from inside swap the sides and use 1 - x.\n";
  }
  for (const PresetTable& t : p.tables) s << " *   " << t.name << " [" << AxesText(t) << "]: " << t.definition << "\n";
  std::string guard = "BRDFKIT_" + p.name + "_TABLES_H";
  std::transform(guard.begin(), guard.end(), guard.begin(), [](unsigned char c) { return char(std::toupper(c)); });
  s << " */\n#ifndef " << guard << "\n#define " << guard << "\n\n";
  for (const PresetTable& t : p.tables)
    s << "static const float " << t.name << "[" << t.value.size() << "] = {\n" << ArrayBody(p, t) << "};\n\n";
  const std::string lookup = p.name == "cycles" ? "cycles_table_lookup" : "kc_lookup";
  s << "/* Clamped multilinear lookup (C99, C++) in a table of dims axes (1 to 3), n nodes each at\n"
    << " * k / (n - 1), the first coordinate fastest, e.g. " << lookup << "(" << p.tables[0].name << ", "
    << p.tables[0].axes[0].coordinate.size() << ", " << p.tables[0].axes.size() << ", "
    << p.tables[0].axes[0].name << ", " << (p.tables[0].axes.size() > 1 ? p.tables[0].axes[1].name : "0") << ", "
    << (p.tables[0].axes.size() > 2 ? p.tables[0].axes[2].name : "0") << ")"
    << (p.name == "cycles" ? ", as kernel/util/lookup_table.h reads them" : "") << ". */\n"
    << "static inline float " << lookup << "(const float *table, int n, int dims, float x, float y, float z) {\n"
    << "  float c[3], w[3], sum = 0.0f;\n  int i[3], d, k;\n  c[0] = x; c[1] = y; c[2] = z;\n"
    << "  for (d = 0; d < 3; ++d) {\n"
    << "    float u = d < dims ? c[d] : 0.0f;\n"
    << "    u = (u < 0.0f ? 0.0f : (u > 1.0f ? 1.0f : u)) * (float)(n - 1);\n"
    << "    i[d] = (int)u;\n    if (i[d] > n - 2) i[d] = n - 2;\n    w[d] = u - (float)i[d];\n  }\n"
    << "  for (k = 0; k < (1 << dims); ++k) {\n"
    << "    float wt = 1.0f;\n    int at = 0, stride = 1;\n"
    << "    for (d = 0; d < dims; ++d) {\n"
    << "      const int b = (k >> d) & 1;\n"
    << "      wt *= b ? w[d] : 1.0f - w[d];\n      at += (i[d] + b) * stride;\n      stride *= n;\n    }\n"
    << "    sum += wt * table[at];\n  }\n  return sum;\n}\n\n";
  s << "#endif\n";
  WriteFileAtomic(path, s.str());
}

void WritePresetCsv(const Preset& p, const std::string& path) {
  std::ostringstream s;
  s << "table,index,axis0,coord0,at0,axis1,coord1,at1,axis2,coord2,at2,channel,value,error\n";
  for (const PresetTable& t : p.tables)
    for (std::size_t node = 0; node < t.nodes(); ++node)
      for (std::size_t c = 0; c < t.channels.size(); ++c) {
        s << t.name << "," << node;
        std::size_t rest = node;
        for (std::size_t k = 0; k < 3; ++k) {
          if (k < t.axes.size()) {
            const PresetAxis& a = t.axes[k];
            const std::size_t i = rest % a.coordinate.size();
            rest /= a.coordinate.size();
            s << "," << a.name << "," << FormatDouble(a.coordinate[i]) << "," << FormatDouble(a.evaluated[i]);
          } else {
            s << ",,,";
          }
        }
        const std::size_t at = node * t.channels.size() + c;
        s << "," << t.channels[c] << "," << FormatDouble(t.value[at]) << "," << FormatDouble(t.error[at]) << "\n";
      }
  WriteFileAtomic(path, s.str());
}

void WritePresetExr(const Preset& p, const std::string& path) {
  int max_w = 1, max_h = 1;
  for (const PresetTable& t : p.tables) {
    max_w = std::max(max_w, int(t.axes[0].coordinate.size()));
    max_h = std::max(max_h, int(t.nodes() / t.axes[0].coordinate.size()));
  }
  const Imath::Box2i display(Imath::V2i(0, 0), Imath::V2i(max_w - 1, max_h - 1));
  std::vector<Imf::Header> headers;
  std::vector<std::vector<float>> planes;  // per table, channel-major
  for (const PresetTable& t : p.tables) {
    const int w = int(t.axes[0].coordinate.size()), h = int(t.nodes() / t.axes[0].coordinate.size());
    Imf::Header hd(display, Imath::Box2i(Imath::V2i(0, 0), Imath::V2i(w - 1, h - 1)));
    hd.setName(t.name);
    hd.setType(Imf::SCANLINEIMAGE);
    hd.compression() = Imf::ZIP_COMPRESSION;
    const bool grey = t.channels.size() == 1;
    for (const std::string& c : t.channels) hd.channels().insert(grey ? "Y" : c, Imf::Channel(Imf::FLOAT));
    hd.insert("brdfkit.preset", Imf::StringAttribute(p.name));
    hd.insert("brdfkit.definition", Imf::StringAttribute(t.definition));
    hd.insert("brdfkit.axes", Imf::StringAttribute(AxesText(t)));
    for (const PresetAxis& a : t.axes) {
      hd.insert("brdfkit.nodes." + a.name, Imf::FloatVectorAttribute(std::vector<float>(a.coordinate.begin(),
                                                                                         a.coordinate.end())));
      hd.insert("brdfkit.evaluated." + a.name,
                Imf::FloatVectorAttribute(std::vector<float>(a.evaluated.begin(), a.evaluated.end())));
    }
    headers.push_back(hd);
    std::vector<float> plane(t.value.size());
    const std::size_t nc = t.channels.size(), nn = t.nodes();
    for (std::size_t node = 0; node < nn; ++node)
      for (std::size_t c = 0; c < nc; ++c) plane[c * nn + node] = float(t.value[node * nc + c]);
    planes.push_back(std::move(plane));
  }
  AtomicFile file(path, std::ios::out | std::ios::binary);
  {
    Imf::StdOFStream os(file.stream(), path.c_str());
    Imf::MultiPartOutputFile out(os, headers.data(), int(headers.size()));
    for (std::size_t k = 0; k < p.tables.size(); ++k) {
      const PresetTable& t = p.tables[k];
      const std::size_t w = t.axes[0].coordinate.size(), nn = t.nodes();
      Imf::OutputPart part(out, int(k));
      Imf::FrameBuffer fb;
      const bool grey = t.channels.size() == 1;
      for (std::size_t c = 0; c < t.channels.size(); ++c)
        fb.insert(grey ? "Y" : t.channels[c],
                  Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(planes[k].data() + c * nn), sizeof(float),
                             sizeof(float) * w));
      part.setFrameBuffer(fb);
      part.writePixels(int(nn / w));
    }
  }
  file.Commit();
}

}  // namespace brdfkit::validate
