// Properties every registered model must have. Parameterised over the
// registry, so a newly registered model is covered with no new test code.
#include <gtest/gtest.h>

#include <filesystem>
#include <random>

#include "brdf/model.h"
#include "brdf/params.h"
#include "tests/model_settings.h"
#include "tests/test_util.h"
#include "validate/jet_models.h"
#include "validate/sampling_check.h"

namespace brdfkit {
namespace {

// One direction is seeded; the size is one compiled once (validate/jet_models.h).
using J = JetN<4>;

std::vector<std::string> ModelNames() {
  std::vector<std::string> names;
  for (const ModelInfo& i : RegisteredModelInfos()) names.push_back(i.name);
  return names;
}

using test::SettingsFor;

class ModelProperties : public ::testing::TestWithParam<std::string> {
 protected:
  void SetUp() override {
    for (const ModelInfo& i : RegisteredModelInfos())
      if (i.name == GetParam()) info_ = i;
    const Settings s = SettingsFor(info_);
    if (!info_.settings.empty() && s.empty()) GTEST_FAIL() << "no test data for model " << info_.name;
    model_ = std::make_unique<Model>(Model::Parse(GetParam(), s));
  }

  // Directions that break naive formulas, plus random ones.
  std::vector<Eigen::Vector3d> EdgeDirections() const {
    std::vector<Eigen::Vector3d> d;
    for (double theta : {0.0, 1e-8, 0.3, 1.0, 1.4, kPi / 2 - 1e-6, kPi / 2 - 1e-12})
      for (double phi : {0.0, 0.7, kPi})
        d.push_back(test::DirectionFromAngles(theta, phi));
    return d;
  }

  // A transmitting model scatters over the whole sphere (LobeKind::kTransmission).
  bool Transmits() const { return (model_->Make<double>()->Kind() & LobeKind::kTransmission) != 0; }

  ModelInfo info_;
  std::unique_ptr<Model> model_;
};

TEST_P(ModelProperties, FiniteAndNonNegative) {
  std::mt19937_64 rng(11);
  const auto bd = model_->Make<double>();
  const auto bf = model_->Make<float>();
  const auto bj = model_->Make<J>();
  std::vector<std::vector<double>> param_sets = {info_.Defaults()};
  for (int k = 0; k < 6; ++k) param_sets.push_back(test::RandomParams(info_, rng, 0.0));
  // The bounds themselves.
  std::vector<double> lo, hi;
  for (const ParamInfo& q : info_.params)
    for (int c = 0; c < (q.colour ? 3 : 1); ++c) {
      lo.push_back(q.lower);
      hi.push_back(q.upper);
    }
  param_sets.push_back(lo);
  param_sets.push_back(hi);

  std::vector<Eigen::Vector3d> dirs = EdgeDirections();
  for (int k = 0; k < 40; ++k) dirs.push_back(test::RandomUpperDirection(rng));
  if (Transmits())
    for (std::size_t k = 0, n = dirs.size(); k < n; ++k) dirs.push_back(Eigen::Vector3d(dirs[k].x(), dirs[k].y(), -dirs[k].z()));
  int bad = 0;
  for (const auto& p : param_sets) {
    const std::vector<float> pf(p.begin(), p.end());
    std::vector<J> pj(p.begin(), p.end());
    for (auto& x : pj) x.v[0] = 1.0;  // derivative along the all-ones direction
    for (const auto& wi : dirs) {
      std::vector<Eigen::Vector3d> wos = {wi, Reflect(Eigen::Vector3d(wi)), Eigen::Vector3d(-wi.x(), -wi.y(), wi.z()),
                                          dirs[(&wi - dirs.data() + 5) % dirs.size()]};
      for (const auto& wo : wos) {
        const Rgb<double> fd = bd->Eval(p.data(), wi, wo);
        const Rgb<float> ff = bf->Eval(pf.data(), wi.cast<float>(), wo.cast<float>());
        const Rgb<J> fj = bj->Eval(pj.data(), wi.cast<J>(), wo.cast<J>());
        for (int c = 0; c < 3; ++c) {
          const bool ok = std::isfinite(fd[c]) && fd[c] >= 0 && std::isfinite(ff[c]) && ff[c] >= 0 &&
                          std::isfinite(fj[c].a) && std::isfinite(fj[c].v[0]);
          if (!ok && bad++ < 5)
            ADD_FAILURE() << info_.name << " params " << FormatParams(info_, p) << " wi " << wi.transpose()
                          << " wo " << wo.transpose() << " double " << fd[c] << " float " << ff[c] << " jet "
                          << fj[c];
        }
      }
    }
  }
  EXPECT_EQ(bad, 0);
}

// Zero below the horizon, except for a transmitting model, which is zero on
// the horizon only and refracts straight through (wi = -wo) at its defaults.
TEST_P(ModelProperties, BelowHorizonIsZero) {
  const auto b = model_->Make<double>();
  const std::vector<double> p = info_.Defaults();
  const Eigen::Vector3d up(0.3, 0.1, 0.9), down(0.3, 0.1, -0.9), horizon(1, 0, 0);
  EXPECT_TRUE((b->Eval(p.data(), horizon, up.normalized()) == 0).all());
  EXPECT_TRUE((b->Eval(p.data(), up.normalized(), horizon) == 0).all());
  if (Transmits()) {
    EXPECT_TRUE((b->Eval(p.data(), up.normalized(), -up.normalized()) > 0).all());
    EXPECT_TRUE((b->Eval(p.data(), -up.normalized(), up.normalized()) > 0).all());
    return;
  }
  EXPECT_TRUE((b->Eval(p.data(), up.normalized(), down.normalized()) == 0).all());
  EXPECT_TRUE((b->Eval(p.data(), down.normalized(), up.normalized()) == 0).all());
}

// The aperture quadrature's batched inner sum is the weighted sum of Eval,
// for the model alone and inside a sum of lobes.
TEST_P(ModelProperties, EvalSumIsTheWeightedSumOfEval) {
  std::mt19937_64 rng(5);
  const std::vector<double> p = info_.Defaults();
  std::vector<Eigen::Vector3d> wo;
  std::vector<double> w;
  for (int k = 0; k < 16; ++k) {
    wo.push_back(test::RandomUpperDirection(rng));
    w.push_back(0.1 + k);
  }
  const Settings settings = SettingsFor(info_);
  const Model sum = Model::Parse("lambert+" + GetParam() + (settings.empty() ? "" : ":" + settings.begin()->second));
  // The sum's own table: a lobe that cannot vanish carries a weight too.
  std::vector<double> ps = sum.Info().Defaults();
  ASSERT_EQ(ps.size(), 3 + p.size() + (sum.LobeWeightIndex(1) >= 0 ? 1 : 0)) << sum.Spec();
  ps[0] = 0.2, ps[1] = 0.3, ps[2] = 0.4;
  std::copy(p.begin(), p.end(), ps.begin() + static_cast<std::ptrdiff_t>(sum.LobeOffset(1)));
  if (sum.LobeWeightIndex(1) >= 0) ps[static_cast<std::size_t>(sum.LobeWeightIndex(1))] = 0.7;
  for (const auto& [m, params] : {std::pair<const Model*, const std::vector<double>*>{model_.get(), &p}, {&sum, &ps}}) {
    const auto b = m->Make<double>();
    for (int k = 0; k < 8; ++k) {
      const Eigen::Vector3d wi = test::RandomUpperDirection(rng);
      Rgb<double> expected = Rgb<double>::Zero();
      for (std::size_t j = 0; j < wo.size(); ++j) expected += b->Eval(params->data(), wi, wo[j]) * w[j];
      const Rgb<double> got = b->EvalSum(params->data(), wi, wo.data(), w.data(), wo.size());
      for (int c = 0; c < 3; ++c) EXPECT_NEAR(got[c], expected[c], 1e-12 * std::abs(expected[c])) << m->Spec();
    }
  }
}

TEST_P(ModelProperties, ReciprocalWhereClaimed) {
  std::mt19937_64 rng(5);
  const auto b = model_->Make<double>();
  double worst = 0;
  for (int k = 0; k < 4; ++k) {
    const std::vector<double> p = k == 0 ? info_.Defaults() : test::RandomParams(info_, rng);
    for (int n = 0; n < 500; ++n) {
      const Eigen::Vector3d wi = test::RandomUpperDirection(rng), wo = test::RandomUpperDirection(rng);
      const Rgb<double> a = b->Eval(p.data(), wi, wo), c = b->Eval(p.data(), wo, wi);
      const double scale = std::max(a.abs().maxCoeff(), c.abs().maxCoeff());
      if (scale > 0) worst = std::max(worst, (a - c).abs().maxCoeff() / scale);
    }
  }
  if (Transmits()) {
    // Generalised reciprocity over the sphere: f(wi, wo) eta_r^2 = f(wo, wi).
    double worst_generalised = 0;
    for (int n = 0; n < 2000; ++n) {
      const std::vector<double> p = n == 0 ? info_.Defaults() : test::RandomParams(info_, rng);
      Eigen::Vector3d wi = test::RandomUpperDirection(rng), wo = test::RandomUpperDirection(rng);
      if (n % 2) wi.z() = -wi.z();
      if (n % 4 > 1) wo.z() = -wo.z();
      const double r = b->RelativeIndex(p.data(), wi, wo);
      const Rgb<double> a = b->Eval(p.data(), wi, wo) * (r * r), c = b->Eval(p.data(), wo, wi);
      const double scale = std::max(a.abs().maxCoeff(), c.abs().maxCoeff());
      if (scale > 1e-290) worst_generalised = std::max(worst_generalised, (a - c).abs().maxCoeff() / scale);  // subnormals carry no relative precision
    }
    EXPECT_LE(worst_generalised, 1e-12) << info_.name << ": generalised reciprocity";
  } else if (info_.reciprocal) {
    EXPECT_LE(worst, 1e-12) << info_.name << " claims reciprocity";
  } else if (info_.settings.empty()) {
    // An analytic model that says it is not reciprocal must show it; a
    // measured one (settings: a file) is as reciprocal as its data.
    EXPECT_GT(worst, 1e-3) << info_.name << " says it is not reciprocal, yet it is";
  }
}

// Eval<double> equals the value part of Eval<Jet>, and the Jet derivatives
// match central finite differences.
TEST_P(ModelProperties, JetDerivativesMatchFiniteDifferences) {
  std::mt19937_64 rng(3);
  const auto bd = model_->Make<double>();
  const auto bj = model_->Make<J>();
  const std::size_t n = info_.PackedSize();
  int compared = 0, skipped = 0, failures = 0;
  for (int trial = 0; trial < 30; ++trial) {
    const std::vector<double> p = test::RandomParams(info_, rng, 0.1);
    const Eigen::Vector3d wi = test::RandomUpperDirection(rng), wo = test::RandomUpperDirection(rng);
    const Rgb<double> f0 = bd->Eval(p.data(), wi, wo);
    for (std::size_t j = 0; j < n; ++j) {
      std::vector<J> pj(p.begin(), p.end());
      pj[j].v[0] = 1.0;
      const Rgb<J> fj = bj->Eval(pj.data(), wi.cast<J>(), wo.cast<J>());
      auto fd_at = [&](double h) {
        std::vector<double> a = p, b = p;
        a[j] += h;
        b[j] -= h;
        return Rgb<double>((bd->Eval(a.data(), wi, wo) - bd->Eval(b.data(), wi, wo)) / (2 * h));
      };
      const double h = 1e-6 * std::max(std::abs(p[j]), 1e-3);
      const Rgb<double> d1 = fd_at(h), d2 = fd_at(h / 4);
      for (int c = 0; c < 3; ++c) {
        // Same value up to rounding: the compiler may contract a * b + c
        // differently, and a lobe exp(n log x) amplifies that by n log x.
        ASSERT_NEAR(fj[c].a, f0[c], 1e-12 * std::abs(f0[c])) << info_.name << ": Eval<Jet> value differs from Eval<double>";
        const double scale = std::max({std::abs(d2[c]), std::abs(fj[c].v[0]), std::abs(f0[c]) / std::max(std::abs(p[j]), 1e-3), 1e-300});
        // A kink (max, min, a clamp) within h makes the two differences
        // disagree: that point says nothing about the derivative.
        if (std::abs(d1[c] - d2[c]) > 1e-4 * scale) {
          ++skipped;
          continue;
        }
        ++compared;
        if (std::abs(fj[c].v[0] - d2[c]) > 1e-5 * scale) {
          if (failures++ < 5)
            ADD_FAILURE() << info_.name << " d f_" << c << " / d " << j << ": jet " << fj[c].v[0] << " fd " << d2[c]
                          << " params " << FormatParams(info_, p);
        }
      }
    }
  }
  EXPECT_EQ(failures, 0);
  if (n > 0) {
    EXPECT_LE(skipped, compared / 10 + 3) << "too many non-smooth points";
  }
}

TEST_P(ModelProperties, SamplingMatchesPdf) {
  const auto b = model_->Make<double>();
  if (!b->CanSample()) GTEST_SKIP() << info_.name << " provides no Sample/Pdf";
  const std::vector<double> p = info_.Defaults();
  // Sidak-corrected 1 % level over the whole family: every model, three wo
  // on each side.
  const double tests = 6.0 * RegisteredModelInfos().size();
  const double alpha = 1 - std::pow(1 - 0.01, 1.0 / tests);
  // A transmitting model samples the sphere, from either side (CheckSampling
  // bins the sphere for it).
  for (double side : Transmits() ? std::vector<double>{1.0, -1.0} : std::vector<double>{1.0})
  for (double theta_o_deg : {0.0, 45.0, 80.0}) {
    Eigen::Vector3d wo = test::DirectionFromAngles(theta_o_deg * kPi / 180, 0.4);
    wo.z() *= side;
    validate::SamplingCheckOptions opt;
    opt.samples = 100000;
    opt.seed = 17;
    const auto r = validate::CheckSampling(*b, p.data(), wo, opt);
    SCOPED_TRACE(info_.name + " at theta_o = " + std::to_string(theta_o_deg));
    EXPECT_EQ(r.nonfinite, 0);
    EXPECT_EQ(r.pdf_mismatch, 0) << "Sample's pdf differs from Pdf()";
    EXPECT_GT(r.valid_fraction, 0.05);
    // The pdf integrates over the upper hemisphere (sphere) to the sampled fraction.
    EXPECT_NEAR(r.pdf_integral, r.valid_fraction, 4 * std::sqrt(r.valid_fraction / opt.samples) + 2e-3);
    EXPECT_LE(r.pdf_integral, 1 + 2e-3);
    EXPECT_GT(r.p_value, alpha) << "chi2 " << r.chi2 << " dof " << r.dof;
  }
}

TEST_P(ModelProperties, MicrofacetDistributionIsNormalised) {
  const auto b = model_->Make<double>();
  const MicrofacetView<double>* mf = b->Microfacet();
  if (mf == nullptr) return;  // not a microfacet model: nothing to check
  const std::vector<double> p = info_.Defaults();
  const double norm = test::HemisphereIntegral([&](const Eigen::Vector3d& m) { return mf->D(p.data(), m) * m.z(); });
  EXPECT_NEAR(norm, 1.0, 1e-6) << info_.name;
  if (!mf->HasSmithG1()) return;
  for (double theta_o : {0.0, 0.7, 1.4}) {
    const Eigen::Vector3d wo = test::DirectionFromAngles(theta_o, 0.3);
    const double furnace = test::HemisphereIntegral([&](const Eigen::Vector3d& m) {
      return mf->D(p.data(), m) * mf->G1(p.data(), wo, m) * std::max(0.0, wo.dot(m)) / wo.z();
    }, 24, 96, 1e-5, wo);
    EXPECT_NEAR(furnace, 1.0, 1e-6) << info_.name << " weak white furnace at theta_o " << theta_o;
  }
}

TEST_P(ModelProperties, ParameterTableIsConsistent) {
  for (const ParamInfo& q : info_.params) {
    EXPECT_LE(q.lower, q.default_value) << q.name;
    EXPECT_LE(q.default_value, q.upper) << q.name;
    EXPECT_LT(q.lower, q.upper) << q.name;
    if (q.scale == ParamInfo::Scale::kLog) {
      EXPECT_GT(q.lower, 0) << q.name << " is log-scaled";
    }
    EXPECT_FALSE(q.meaning.empty()) << q.name;
  }
  EXPECT_FALSE(info_.summary.empty());
  // Default parameters round-trip through the text form.
  const std::vector<double> d = info_.Defaults();
  EXPECT_EQ(ParseParams(info_, FormatParams(info_, d)), d);
}

INSTANTIATE_TEST_SUITE_P(AllModels, ModelProperties, ::testing::ValuesIn(ModelNames()),
                         [](const auto& param_info) { return param_info.param; });

// A sum of lobes is the weighted sum of its lobes, with <lobe>.<param>
// names; a lobe that cannot vanish by its own parameters (ggx) has a weight.
TEST(SumOfLobes, EvaluatesToTheSumAndNamesParameters) {
  const Model sum = Model::Parse("lambert+ggx+ggx");
  std::vector<std::string> names;
  for (const ParamInfo& q : sum.Info().params) names.push_back(q.name);
  EXPECT_EQ(names, (std::vector<std::string>{"lambert.albedo", "ggx.alpha", "ggx.f0", "ggx.weight", "ggx#2.alpha",
                                             "ggx#2.f0", "ggx#2.weight"}));
  const std::vector<double> p = ParseParams(
      sum.Info(), "lambert.albedo=0.1:0.2:0.3,ggx.alpha=0.05,ggx.f0=0.04,ggx#2.alpha=0.6,ggx#2.weight=0.25");
  EXPECT_EQ(p[7], 1.0);  // the default weight: the lobe as it is alone
  const Model lambert = Model::Parse("lambert"), ggx = Model::Parse("ggx");
  const Eigen::Vector3d wi = test::DirectionFromAngles(0.4, 0.1), wo = test::DirectionFromAngles(0.5, 3.0);
  const Rgb<double> expected = lambert.Make<double>()->Eval(p.data(), wi, wo) +
                               ggx.Make<double>()->Eval(p.data() + 3, wi, wo) +
                               0.25 * ggx.Make<double>()->Eval(p.data() + 8, wi, wo);
  const Rgb<double> got = sum.Make<double>()->Eval(p.data(), wi, wo);
  for (int c = 0; c < 3; ++c) EXPECT_DOUBLE_EQ(got[c], expected[c]);
}

TEST(ModelSpec, RejectsUnknownNamesWithAClearMessage) {
  try {
    Model::Parse("lambert+ggxx");
    FAIL() << "accepted a typo";
  } catch (const ModelError& e) {
    EXPECT_NE(std::string(e.what()).find("unknown model 'ggxx'"), std::string::npos) << e.what();
  }
  EXPECT_THROW(Model::Parse(""), ModelError);
  EXPECT_THROW(Model::Parse("lambert+"), ModelError);
  EXPECT_THROW(Model::Parse("ggx:foo"), ModelError);  // ggx takes no setting
}

TEST(Params, ParseValidateAndReport) {
  const ModelInfo info = Model::Parse("ggx").Info();
  const std::vector<double> p = ParseParams(info, "alpha=0.25,f0=0.1:0.2:0.3");
  EXPECT_EQ(p, (std::vector<double>{0.25, 0.1, 0.2, 0.3}));
  EXPECT_EQ(ParseParams(info, "f0=0.5"), (std::vector<double>{0.3, 0.5, 0.5, 0.5}));
  auto message = [&](const std::string& text) {
    try {
      ParseParams(info, text);
    } catch (const ModelError& e) {
      return std::string(e.what());
    }
    return std::string("accepted");
  };
  EXPECT_NE(message("alpha=-0.1").find("'alpha' = -0.1 is outside its range"), std::string::npos);
  EXPECT_NE(message("alpha=0").find("'alpha'"), std::string::npos);
  EXPECT_NE(message("alpha=nan").find("'alpha'"), std::string::npos);
  EXPECT_NE(message("alpha=0.1x").find("'0.1x' is not a number"), std::string::npos);
  EXPECT_NE(message("beta=1").find("unknown parameter 'beta'"), std::string::npos);
  EXPECT_NE(message("f0=0.1:0.2").find("r:g:b"), std::string::npos);
  EXPECT_NE(message("alpha").find("expected name=value"), std::string::npos);
}

}  // namespace
}  // namespace brdfkit
