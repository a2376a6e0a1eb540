// Bxdf<T>::EvalBatch against Eval, pair by pair, for every registered model
// alone and in sums, in double and float, on every instruction set of the
// vectorised kernels this processor has (brdf/batch.h); Bxdf<Jet>::EvalAt
// against Eval. The measured models
// read from files other than MERL's (rgl, utia, astm) are left to the
// generic loop's test through merl: their writers live in formats/.
#include <gtest/gtest.h>

#include <limits>
#include <random>

#include "brdf/model.h"
#include "brdf/params.h"
#include "tests/known_merl.h"
#include "tests/test_util.h"
#include "validate/jet_models.h"

namespace brdfkit {
namespace {

// Directions as rows of three: random ones above the horizon, edge cases
// near the normal and the horizon, on it (z = 0) and below it.
std::vector<double> Directions(std::mt19937_64& rng, std::size_t n) {
  std::vector<Eigen::Vector3d> d;
  for (double theta : {0.0, 1e-8, 0.3, 1.0, 1.4, kPi / 2 - 1e-6, kPi / 2, 1.8, kPi})
    for (double phi : {0.0, 0.7, kPi}) d.push_back(test::DirectionFromAngles(theta, phi));
  for (const Eigen::Vector3d& w : {Eigen::Vector3d(1, 0, 0), Eigen::Vector3d(0, -1, 0), Eigen::Vector3d(0.6, -0.8, 0)})
    d.push_back(w);
  while (d.size() < n) d.push_back(test::RandomUpperDirection(rng));
  std::shuffle(d.begin(), d.end(), rng);
  std::vector<double> rows;
  for (std::size_t k = 0; k < n; ++k)
    for (int c = 0; c < 3; ++c) rows.push_back(d[k][c]);
  return rows;
}

// EvalBatch with strides sa, sb over n pairs equals Eval at every pair: 0
// exactly where Eval gives 0, else within `ulps` units in the last place of
// T (the kernels rearrange Eval's arithmetic; the generic loop is Eval).
template <typename T>
void ExpectBatchEqualsEval(const Bxdf<T>& b, const std::vector<double>& pd, const std::vector<double>& wi_d,
                           std::size_t sa, const std::vector<double>& wo_d, std::size_t sb, std::size_t n,
                           double ulps, const std::string& what) {
  const std::vector<T> p(pd.begin(), pd.end()), wi(wi_d.begin(), wi_d.end()), wo(wo_d.begin(), wo_d.end());
  // One sentinel row past the end: EvalBatch writes 3 n values, no more.
  std::vector<T> out(3 * n + 3, T(-7));
  b.EvalBatch(p.data(), wi.data(), sa, wo.data(), sb, n, out.data());
  for (int c = 0; c < 3; ++c) EXPECT_EQ(out[3 * n + c], T(-7)) << what << ": wrote past the end";
  const double eps = std::numeric_limits<T>::epsilon();
  for (std::size_t k = 0; k < n; ++k) {
    const T* a = wi.data() + k * sa;
    const T* o = wo.data() + k * sb;
    const Rgb<T> f = b.Eval(p.data(), Vec3<T>(a[0], a[1], a[2]), Vec3<T>(o[0], o[1], o[2]));
    for (int c = 0; c < 3; ++c) {
      const double want = f[c], got = out[3 * k + c];
      if (want == 0) {
        ASSERT_EQ(got, 0.0) << what << " pair " << k << " channel " << c;
      } else {
        ASSERT_NEAR(got, want, ulps * eps * std::abs(want)) << what << " pair " << k << " channel " << c;
      }
    }
  }
}

std::vector<BatchIsa> IsasHere() {
  std::vector<BatchIsa> out = {BatchIsa::kBaseline};
  if (DetectedBatchIsa() >= BatchIsa::kAvx2) out.push_back(BatchIsa::kAvx2);
  if (DetectedBatchIsa() >= BatchIsa::kAvx512) out.push_back(BatchIsa::kAvx512);
  return out;
}

// Restores the widest instruction set when a test ends.
struct IsaGuard {
  ~IsaGuard() { LimitBatchIsa(BatchIsa::kAvx512); }
};

template <typename T>
void CheckModel(const Model& model, std::mt19937_64& rng) {
  const auto b = model.Make<T>();
  const ModelInfo& info = model.Info();
  std::vector<std::vector<double>> params = {info.Defaults()};
  for (int k = 0; k < 2; ++k) params.push_back(test::RandomParams(info, rng, 0.0));
  const std::size_t n = 301;  // odd, and more than a sum's chunk of 256
  const std::vector<double> wi = Directions(rng, n), wo = Directions(rng, n);
  const double ulps = 16;
  IsaGuard guard;
  for (BatchIsa isa : IsasHere()) {
    LimitBatchIsa(isa);
    for (const std::vector<double>& p : params) {
      const std::string what = model.Spec() + (sizeof(T) == 8 ? " double" : " float") + " isa " +
                               std::to_string(static_cast<int>(isa)) + " params " + FormatParams(info, p);
      ExpectBatchEqualsEval<T>(*b, p, wi, 3, wo, 3, n, ulps, what + " strides 3, 3");
      ExpectBatchEqualsEval<T>(*b, p, wi, 3, wo, 3, 1, ulps, what + " n = 1");
      ExpectBatchEqualsEval<T>(*b, p, wi, 3, wo, 3, 0, ulps, what + " n = 0");
      ExpectBatchEqualsEval<T>(*b, p, wi, 3, wo, 3, 7, ulps, what + " n = 7");
      // One direction for every pair, on either side; then both.
      for (std::size_t j : {std::size_t(0), std::size_t(5), std::size_t(20)}) {
        const std::vector<double> one(wi.begin() + 3 * j, wi.begin() + 3 * j + 3);
        ExpectBatchEqualsEval<T>(*b, p, one, 0, wo, 3, n, ulps, what + " wi broadcast");
        ExpectBatchEqualsEval<T>(*b, p, wo, 3, one, 0, n, ulps, what + " wo broadcast");
        ExpectBatchEqualsEval<T>(*b, p, one, 0, one, 0, 5, ulps, what + " both broadcast");
      }
      // Another stride: every other row of a (2 n, 3) array.
      std::vector<double> wi2, wo2;
      for (std::size_t k = 0; k < n; ++k)
        for (int r = 0; r < 2; ++r)
          for (int c = 0; c < 3; ++c) {
            wi2.push_back(r == 0 ? wi[3 * k + c] : 9.0);
            wo2.push_back(r == 0 ? wo[3 * k + c] : 9.0);
          }
      ExpectBatchEqualsEval<T>(*b, p, wi2, 6, wo2, 6, n, ulps, what + " strides 6, 6");
    }
  }
}

// Bxdf<Jet>::EvalAt (double directions; the microfacet lobes keep the
// directions' arithmetic in double) against Eval at the directions cast to
// Jets: values and every derivative, to 1e-12 of the channel's largest
// (Jet arithmetic with a double operand rounds derivatives differently, and
// Beckmann's exp(-tan^2 / alpha^2) multiplies that by its exponent, up to
// about 700), at the edge and random directions of Directions.
void ExpectEvalAtEqualsEval(const Model& model, std::mt19937_64& rng) {
  using Jet = JetN<4>;
  const auto b = model.Make<Jet>();
  const ModelInfo& info = model.Info();
  const std::size_t n = 301;
  const std::vector<double> wi = Directions(rng, n), wo = Directions(rng, n);
  for (int round = 0; round < 3; ++round) {
    const std::vector<double> pd = round == 0 ? info.Defaults() : test::RandomParams(info, rng, 0.0);
    std::vector<Jet> p;
    for (std::size_t k = 0; k < pd.size(); ++k) p.push_back(Jet(pd[k], static_cast<int>(k % 4)));
    for (std::size_t k = 0; k < n; ++k) {
      const Eigen::Vector3d a(wi[3 * k], wi[3 * k + 1], wi[3 * k + 2]), o(wo[3 * k], wo[3 * k + 1], wo[3 * k + 2]);
      const Rgb<Jet> want = b->Eval(p.data(), Vec3<Jet>(a.cast<Jet>()), Vec3<Jet>(o.cast<Jet>()));
      const Rgb<Jet> got = b->EvalAt(p.data(), a, o);
      for (int c = 0; c < 3; ++c) {
        const std::string what = model.Spec() + " params " + FormatParams(info, pd) + " pair " + std::to_string(k) +
                                 " channel " + std::to_string(c);
        double scale = std::abs(want[c].a);
        for (int j = 0; j < 4; ++j) scale = std::max(scale, std::abs(want[c].v[j]));
        const double tol = 1e-12 * scale;
        ASSERT_NEAR(got[c].a, want[c].a, tol) << what;
        for (int j = 0; j < 4; ++j) ASSERT_NEAR(got[c].v[j], want[c].v[j], tol) << what << " derivative " << j;
      }
    }
  }
}

class BatchEval : public ::testing::TestWithParam<std::string> {};

TEST_P(BatchEval, EqualsEvalPairByPair) {
  const Model model = GetParam() == "merl" ? Model::Parse("merl:" + test::KnownMerlFile()) : Model::Parse(GetParam());
  std::mt19937_64 rng(5);
  CheckModel<double>(model, rng);
  CheckModel<float>(model, rng);
}

TEST_P(BatchEval, EvalAtEqualsEvalOnJets) {
  const Model model = GetParam() == "merl" ? Model::Parse("merl:" + test::KnownMerlFile()) : Model::Parse(GetParam());
  std::mt19937_64 rng(7);
  ExpectEvalAtEqualsEval(model, rng);
}

INSTANTIATE_TEST_SUITE_P(AllModels, BatchEval, ::testing::ValuesIn([] {
                           std::vector<std::string> names;
                           for (const ModelInfo& i : RegisteredModelInfos())
                             if (i.settings.empty() || i.name == "merl") names.push_back(i.name);
                           return names;
                         }()),
                         [](const auto& param) { return param.param; });

TEST(BatchEvalSums, EqualsEvalPairByPair) {
  std::mt19937_64 rng(6);
  for (const char* spec : {"lambert+ggx", "ggx+beckmann", "lambert+ggx_aniso+ggx_separable", "oren_nayar+ggx+ggx"}) {
    const Model model = Model::Parse(spec);
    CheckModel<double>(model, rng);
    CheckModel<float>(model, rng);
    ExpectEvalAtEqualsEval(model, rng);
  }
}

// The kernels' values against closed forms, independently of Eval: Lambert
// rho / pi above the horizon, and GGX at normal incidence and view, where
// D = 1 / (pi alpha^2), G2 = 1 and F = f0: f = 1 / (4 pi alpha^2) f0.
TEST(BatchEvalKernels, ClosedForms) {
  IsaGuard guard;
  for (BatchIsa isa : IsasHere()) {
    LimitBatchIsa(isa);
    const Model lambert = Model::Parse("lambert");
    const std::vector<double> pl = ParseParams(lambert.Info(), "albedo=0.2:0.5:0.8");
    const double up[3] = {0, 0, 1}, down[3] = {0.6, 0, -0.8}, horizon[3] = {1, 0, 0};
    double out[9];
    const double wi[9] = {up[0], up[1], up[2], down[0], down[1], down[2], horizon[0], horizon[1], horizon[2]};
    lambert.Make<double>()->EvalBatch(pl.data(), wi, 3, up, 0, 3, out);
    for (int c = 0; c < 3; ++c) {
      EXPECT_EQ(out[c], pl[c] * kInvPi);
      EXPECT_EQ(out[3 + c], 0.0);
      EXPECT_EQ(out[6 + c], 0.0);
    }
    const Model ggx = Model::Parse("ggx");
    const std::vector<double> pg = ParseParams(ggx.Info(), "alpha=0.2,f0=0.25:0.5:1");
    ggx.Make<double>()->EvalBatch(pg.data(), up, 0, up, 0, 1, out);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(out[c], pg[1 + c] / (4 * kPi * 0.04), 1e-15 * out[c]);
  }
}

// ceres::Jet takes the generic loop: values and derivatives as Eval's.
TEST(BatchEvalKernels, JetTakesTheGenericLoop) {
  using Jet = JetN<4>;
  const Model model = Model::Parse("ggx");
  const auto b = model.Make<Jet>();
  std::vector<Jet> p = {Jet(0.3, 0), Jet(0.5, 1), Jet(0.5), Jet(0.5)};
  const Jet wi[3] = {Jet(0.6), Jet(0.0), Jet(0.8)}, wo[3] = {Jet(0.0), Jet(0.28), Jet(0.96)};
  Jet out[3];
  b->EvalBatch(p.data(), wi, 0, wo, 0, 1, out);
  const Rgb<Jet> f = b->Eval(p.data(), Vec3<Jet>(wi[0], wi[1], wi[2]), Vec3<Jet>(wo[0], wo[1], wo[2]));
  for (int c = 0; c < 3; ++c) {
    EXPECT_EQ(out[c].a, f[c].a);
    EXPECT_EQ(out[c].v[0], f[c].v[0]);
    EXPECT_EQ(out[c].v[1], f[c].v[1]);
  }
  EXPECT_GT(std::abs(out[0].v[0]), 0.0);
  EXPECT_GT(std::abs(out[0].v[1]), 0.0);
}

}  // namespace
}  // namespace brdfkit
