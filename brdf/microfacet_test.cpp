// Closed forms and published values for the microfacet family.
#include <gtest/gtest.h>

#include <cmath>

#include "brdf/model.h"
#include "brdf/params.h"
#include "tests/test_util.h"

namespace brdfkit {
namespace {

double Albedo(const Model& m, const std::vector<double>& p, double mu) {
  const auto b = m.Make<double>();
  const Eigen::Vector3d wo(std::sqrt(1 - mu * mu), 0, mu);
  return test::HemisphereIntegral(
      [&](const Eigen::Vector3d& wi) { return b->Eval(p.data(), wi, wo)[0] * wi.z(); }, 32, 128, 1e-3);
}

TEST(Microfacet, GgxAlphaOneNormalIncidence) {
  const Model ggx = Model::Parse("ggx");
  const std::vector<double> p = ParseParams(ggx.Info(), "alpha=1");
  EXPECT_DOUBLE_EQ(ggx.Make<double>()->Microfacet()->D(p.data(), Eigen::Vector3d(0, 0, 1)), 1 / kPi);
  EXPECT_NEAR(Albedo(ggx, p, 1.0), 1 - std::log(2.0), 1e-8);  // REFERENCE: 0.306852819...
}

// REFERENCE.md: GGX, F = 1, alpha = 1: E(mu) = 1 - mu ln(1 + 1/mu) with
// height-correlated Smith, 2 (1 - ln 2) / (1 + mu) with separable Smith.
TEST(Microfacet, GgxAlphaOneAlbedoClosedForms) {
  const Model hc = Model::Parse("ggx"), sep = Model::Parse("ggx_separable");
  const std::vector<double> p = ParseParams(hc.Info(), "alpha=1");
  for (double mu : {1.0, 0.7, 0.3, 0.1, 0.02}) {
    EXPECT_NEAR(Albedo(hc, p, mu), 1 - mu * std::log(1 + 1 / mu), 2e-7) << "mu " << mu;
    EXPECT_NEAR(Albedo(sep, p, mu), 2 * (1 - std::log(2.0)) / (1 + mu), 2e-7) << "mu " << mu;
  }
}

TEST(Microfacet, BeckmannNormalValue) {
  const Model m = Model::Parse("beckmann");
  const std::vector<double> p = ParseParams(m.Info(), "alpha=0.1");
  EXPECT_NEAR(m.Make<double>()->Microfacet()->D(p.data(), Eigen::Vector3d(0, 0, 1)), 31.8309886183790672, 1e-12);
}

// Anisotropic D with alpha_x = alpha_y is the isotropic D.
TEST(Microfacet, AnisotropicReducesToIsotropic) {
  const Model iso = Model::Parse("ggx"), aniso = Model::Parse("ggx_aniso");
  const std::vector<double> pi = ParseParams(iso.Info(), "alpha=0.37,f0=0.2"),
                            pa = ParseParams(aniso.Info(), "alpha_x=0.37,alpha_y=0.37,f0=0.2");
  std::mt19937_64 rng(2);
  for (int k = 0; k < 50; ++k) {
    const Eigen::Vector3d wi = test::RandomUpperDirection(rng), wo = test::RandomUpperDirection(rng);
    EXPECT_NEAR(iso.Make<double>()->Eval(pi.data(), wi, wo)[0], aniso.Make<double>()->Eval(pa.data(), wi, wo)[0],
                1e-13 * iso.Make<double>()->Eval(pi.data(), wi, wo)[0]);
  }
}

// Smith Lambda against its defining integral, Heitz 2014 eq. 72:
// Lambda(wo) = int D(m) max(0, -wo.m)... written through the projected area:
// cos(theta_o) (1 + Lambda) = int D(m) max(0, wo.m) dm.
TEST(Microfacet, LambdaMatchesProjectedAreaIntegral) {
  for (const char* name : {"ggx", "beckmann"}) {
    const Model m = Model::Parse(name);
    const std::vector<double> p = ParseParams(m.Info(), "alpha=0.6");
    const auto b = m.Make<double>();
    const MicrofacetView<double>* mf = b->Microfacet();
    for (double theta : {0.2, 0.9, 1.3, 1.55}) {
      const Eigen::Vector3d wo = test::DirectionFromAngles(theta, 0.8);
      const double projected = test::HemisphereIntegral(
          [&](const Eigen::Vector3d& wm) { return mf->D(p.data(), wm) * std::max(0.0, wo.dot(wm)); }, 24, 96, 1e-5,
          wo);
      const double g1 = mf->G1(p.data(), wo, Eigen::Vector3d(0, 0, 1));
      EXPECT_NEAR(projected, wo.z() / g1, 1e-7 * projected) << name << " theta " << theta;
    }
  }
}

TEST(Fresnel, KnownValues) {
  EXPECT_EQ(FresnelSchlick(1.0, 0.3), 1.0);  // f0 = 1 means F = 1 exactly
  EXPECT_DOUBLE_EQ(FresnelSchlick(0.04, 0.0), 1.0);
  EXPECT_NEAR(FresnelDielectric(1.5, 1.0), 0.04, 1e-15);  // ((1.5 - 1) / (1.5 + 1))^2
  EXPECT_NEAR(FresnelDielectric(1.5, 0.0), 1.0, 1e-15);
  // Brewster angle: p-polarised reflectance vanishes, F = rs^2 / 2.
  const double tb = std::atan(1.5), ct = std::cos(tb), st = std::sin(tb);
  const double cos_t = std::sqrt(1 - st * st / 2.25);
  const double rs = (ct - 1.5 * cos_t) / (ct + 1.5 * cos_t);
  EXPECT_NEAR(FresnelDielectric(1.5, ct), rs * rs / 2, 1e-15);
  // Conductor at normal incidence, and k = 0 equals the dielectric.
  const double eta = 0.2, k = 3.0;
  EXPECT_NEAR(FresnelConductor(eta, k, 1.0), ((eta - 1) * (eta - 1) + k * k) / ((eta + 1) * (eta + 1) + k * k), 1e-14);
  for (double c : {1.0, 0.8, 0.4, 0.1, 0.01})
    EXPECT_NEAR(FresnelConductor(1.5, 0.0, c), FresnelDielectric(1.5, c), 1e-13) << c;
  EXPECT_NEAR(FresnelConductor(eta, k, 0.0), 1.0, 1e-14);
}

}  // namespace
}  // namespace brdfkit
