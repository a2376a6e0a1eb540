#include "validate/references.h"

#include <cmath>
#include <cstdio>
#include <memory>

#include "brdf/model.h"
#include "brdf/params.h"
#include "brdf/quadrature.h"

namespace brdfkit::validate {

namespace {

using Eigen::Array3d;
using Eigen::Vector3d;

Vector3d ViewDirection(double mu) { return Vector3d(std::sqrt(std::max(0.0, 1.0 - mu * mu)), 0.0, mu); }

struct LoadedModel {
  Model model;
  std::shared_ptr<Bxdf<double>> bxdf;
  std::vector<double> params;
};

std::shared_ptr<const LoadedModel> Load(const std::string& spec, const std::string& params) {
  auto m = std::make_shared<LoadedModel>(LoadedModel{Model::Parse(spec), nullptr, {}});
  m->bxdf = m->model.Make<double>();
  m->params = ParseParams(m->model.Info(), params);
  return m;
}

ReferenceCase AlbedoCase(const std::string& group, const std::string& name, const std::string& spec,
                         const std::string& params, double mu, const Array3d& exact, bool stiff) {
  const auto m = Load(spec, params);
  ReferenceCase c;
  c.name = name;
  c.group = group;
  c.exact = exact;
  c.stiff = stiff;
  c.integrate = [m, mu](Method method, const IntegrateOptions& o) {
    return DirectionalAlbedo(*m->bxdf, m->params.data(), ViewDirection(mu), method, o);
  };
  return c;
}

// Weak white furnace or D cos normalisation over microfacet normals m.
ReferenceCase MicrofacetCase(const std::string& group, const std::string& spec, const std::string& params,
                             double width_x, double width_y, double mu, bool furnace, const std::string& name) {
  const auto m = Load(spec, params);
  const MicrofacetView<double>* view = m->bxdf->Microfacet();
  if (!view) throw ModelError("model '" + spec + "' has no microfacet distribution");
  ReferenceCase c;
  c.name = name;
  c.group = group;
  c.exact = Array3d::Ones();
  c.stiff = std::min(width_x, width_y) < 1e-2 || mu < 1e-2;
  const Vector3d wo = ViewDirection(mu);
  c.integrate = [m, view, wo, furnace, width_x, width_y](Method method, const IntegrateOptions& o) {
    const double* p = m->params.data();
    std::function<Array3d(const Vector3d&)> g;
    if (furnace) {
      g = [view, p, wo](const Vector3d& wm) {
        const double wo_m = wo.dot(wm);
        if (!(wo_m > 0)) return Array3d::Zero().eval();  // facets facing away from wo are not seen
        return Array3d::Constant(view->D(p, wm) * view->G1(p, wo, wm) * wo_m / wo.z()).eval();
      };
    } else {
      g = [view, p](const Vector3d& wm) { return Array3d::Constant(view->D(p, wm) * wm.z()).eval(); };
    }
    return IntegrateHemisphere(g, method, o, Vector3d::UnitZ(), width_x, width_y,
                               furnace ? wo : Vector3d::Zero().eval());
  };
  return c;
}

// E_avg = 2 int_0^1 E(mu) mu dmu by Gauss-Legendre in mu (24 nodes, error
// from the difference to 12 nodes plus the nodes' own errors).
Estimate AverageAlbedo(const Bxdf<double>& bxdf, const double* p, Method method, const IntegrateOptions& o) {
  const GaussLegendre fine(24), coarse(12);
  Estimate out;
  IntegrateOptions per = o;
  per.budget = std::max<std::int64_t>(1, o.budget / 36);
  Array3d coarse_sum = Array3d::Zero();
  for (const GaussLegendre* rule : {&fine, &coarse}) {
    Array3d sum = Array3d::Zero(), err = Array3d::Zero();
    for (int i = 0; i < rule->size(); ++i) {
      const double mu = rule->node01(i), w = 2.0 * mu * rule->weight01(i);
      const Estimate e = DirectionalAlbedo(bxdf, p, ViewDirection(mu), method, per);
      sum += w * e.value;
      err += w * e.error;
      out.evals += e.evals;
      out.seconds += e.seconds;
    }
    if (rule == &fine) {
      out.value = sum;
      out.error = err;
    } else {
      coarse_sum = sum;
    }
  }
  out.error += (out.value - coarse_sum).abs();
  return out;
}

}  // namespace

std::vector<ReferenceCase> ReferenceCases() {
  std::vector<ReferenceCase> cases;
  const std::vector<double> mus = {1.0, 0.5, 0.1, 1e-2, 1e-4, 1e-6};

  cases.push_back(AlbedoCase("lambert", "lambert_mu0.5", "lambert", "albedo=0.2:0.5:0.9", 0.5,
                             Array3d(0.2, 0.5, 0.9), false));
  for (double mu : mus) {
    cases.push_back(AlbedoCase("ggx_alpha1", "ggx_alpha1_mu" + FormatShort(mu), "ggx", "alpha=1,f0=1", mu,
                               Array3d::Constant(1.0 - mu * std::log1p(1.0 / mu)), mu < 1e-2));
  }
  for (double mu : mus) {
    cases.push_back(AlbedoCase("ggx_separable_alpha1", "ggx_separable_alpha1_mu" + FormatShort(mu), "ggx_separable",
                               "alpha=1,f0=1", mu,
                               Array3d::Constant(2.0 * (1.0 - std::log(2.0)) / (1.0 + mu)), mu < 1e-2));
  }
  for (const char* dist : {"ggx", "beckmann"}) {
    for (double alpha : {0.5, 0.1, 1e-2, 1e-3, 1e-4}) {
      for (double mu : {1.0, 0.5, 0.1, 0.01}) {
        cases.push_back(
            MicrofacetCase(std::string("furnace_") + dist, dist, "alpha=" + FormatShort(alpha), alpha, alpha, mu, true,
                           std::string("furnace_") + dist + "_alpha" + FormatShort(alpha) + "_mu" + FormatShort(mu)));
      }
    }
  }
  // Anisotropy ratio 1e3.
  for (const char* dist : {"ggx_aniso", "beckmann_aniso"}) {
    for (double mu : {1.0, 0.1}) {
      cases.push_back(MicrofacetCase(std::string("furnace_") + dist, dist, "alpha_x=0.3,alpha_y=3e-4", 0.3, 3e-4, mu,
                                     true, std::string("furnace_") + dist + "_mu" + FormatShort(mu)));
    }
  }
  for (const char* dist : {"ggx", "beckmann"}) {
    for (double alpha : {0.5, 1e-2, 1e-4}) {
      cases.push_back(MicrofacetCase(std::string("dcos_") + dist, dist, "alpha=" + FormatShort(alpha), alpha, alpha,
                                     1.0, false, std::string("dcos_") + dist + "_alpha" + FormatShort(alpha)));
    }
  }
  // cos^n lobes: exponents 1e2 .. 1e6 (widths sqrt(2 / n) down to 1.4e-3).
  for (double n : {1e2, 1e4, 1e6}) {
    ReferenceCase c;
    c.name = "cosine_power_n" + FormatShort(n);
    c.group = "cosine_power";
    c.exact = Array3d::Ones();
    c.stiff = n > 1e4 / 2;
    c.integrate = [n](Method method, const IntegrateOptions& o) {
      auto g = [n](const Vector3d& w) { return Array3d::Constant((n + 1) * 0.5 * kInvPi * PowLobe(w.z(), n)).eval(); };
      return IntegrateHemisphere(g, method, o, Vector3d::UnitZ(), std::sqrt(2.0 / (n + 2.0)));
    };
    cases.push_back(c);
  }
  // Phong 1975 as a BRDF: f cos_i = ks cos^n(alpha); the lobe is clear of the
  // horizon (cos^n at the horizon below 1e-300) for these (n, mu).
  for (auto [n, mu] : {std::pair{1e2, 1.0}, std::pair{1e4, 0.5}, std::pair{1e6, 0.5}, std::pair{1e6, 0.1}}) {
    cases.push_back(AlbedoCase("phong_original", "phong_original_n" + FormatShort(n) + "_mu" + FormatShort(mu),
                               "phong_original", "ks=1,n=" + FormatShort(n), mu,
                               Array3d::Constant(2.0 * kPi / (n + 1.0)), n > 1e4 / 2));
  }
  {
    // Fujii 2012 with rho = 1, sigma (= B / A) = 1.
    const double a = 1.0 / (kPi + (kPi / 2 - 2.0 / 3.0)), b = a;
    cases.push_back(AlbedoCase("oren_nayar_fujii", "oren_nayar_fujii_mu1", "oren_nayar_fujii", "albedo=1,sigma=1",
                               1.0, Array3d::Constant(kPi * a), false));
    const auto m = Load("oren_nayar_fujii", "albedo=1,sigma=1");
    ReferenceCase c;
    c.name = "oren_nayar_fujii_avg";
    c.group = "oren_nayar_fujii";
    c.exact = Array3d::Constant(kPi * a + (2.0 * kPi - 5.6) / 3.0 * b);
    c.integrate = [m](Method method, const IntegrateOptions& o) {
      return AverageAlbedo(*m->bxdf, m->params.data(), method, o);
    };
    cases.push_back(c);
  }
  return cases;
}

double TrueError(const ReferenceCase& c, const Estimate& e) { return (e.value - c.exact).abs().maxCoeff(); }

double EstimatedError(const Estimate& e) { return e.error.maxCoeff(); }

}  // namespace brdfkit::validate
