// What every registered model declares about itself (brdf/model.h: kKind,
// Width, kChannelsIndependent, kSlots) held against independent
// measurements of the model: the lobe's width from f_r, the channel
// coupling from Jet derivatives, the slots from Info().
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

#include "brdf/model.h"
#include "brdf/params.h"
#include "fit/jet_models.h"
#include "tests/model_settings.h"
#include "tests/test_util.h"

namespace brdfkit {
namespace {

// A model of every registered name (merl from a known analytic material).
Model MakeModel(const ModelInfo& info) { return Model::Parse(info.name, test::SettingsFor(info)); }

// Half-vector angle (radians) along the tangent `axis` where the peak of
// f_r cos_i at normal view, above its value at 80 degrees, falls to half;
// wi is at twice the angle. pi / 4 when it does not fall that far.
double MeasuredHalfWidth(const Bxdf<double>& b, const double* p, const Eigen::Vector3d& axis) {
  const Eigen::Vector3d wo(0, 0, 1);
  const auto g = [&](double t) {
    const Eigen::Vector3d wi = std::sin(2 * t) * axis + std::cos(2 * t) * wo;
    return b.Eval(p, wi, wo).mean() * wi.z();
  };
  const double floor = g(0.7), peak = g(0) - floor;
  if (!(peak > 0)) return kPi / 4;
  double lo = 0, hi = 0.7;
  for (int i = 0; i < 60; ++i) {
    const double mid = 0.5 * (lo + hi);
    (g(mid) - floor >= 0.5 * peak ? lo : hi) = mid;
  }
  return hi;
}

// Parameter points: the defaults, and every log-scale parameter (roughness,
// exponents) a factor 3 down and up, within its bounds.
std::vector<std::vector<double>> Points(const ModelInfo& info) {
  std::vector<std::vector<double>> out = {info.Defaults()};
  for (double f : {1.0 / 3.0, 3.0}) {
    std::vector<double> p = info.Defaults();
    for (std::size_t i = 0; i < info.params.size(); ++i) {
      const ParamInfo& pi = info.params[i];
      if (pi.scale != ParamInfo::Scale::kLog) continue;
      for (int c = 0; c < (pi.colour ? 3 : 1); ++c)
        p[info.Offset(i) + c] = std::clamp(pi.default_value * f, pi.lower, pi.upper);
    }
    out.push_back(p);
  }
  return out;
}

TEST(ModelTraits, EveryModelDeclaresItsKind) {
  for (const ModelInfo& info : RegisteredModelInfos()) {
    const auto b = MakeModel(info).Make<double>();
    const unsigned k = b->Kind();
    EXPECT_NE(k & (LobeKind::kDiffuse | LobeKind::kGlossy | LobeKind::kSpecular), 0u) << info.name;
    // Transmission declared iff the model scatters through the surface: f
    // across it, straight through and at three tilted pairs, at the defaults.
    bool through = false;
    for (const auto& [wi, wo] : {std::pair<Eigen::Vector3d, Eigen::Vector3d>{{0.3, 0.1, 0.9}, {-0.3, -0.1, -0.9}},
                                 {{0.0, 0.0, 1.0}, {0.2, 0.0, -0.98}},
                                 {{0.6, 0.0, 0.8}, {-0.2, 0.1, -0.97}},
                                 {{0.0, 0.5, -0.87}, {0.0, -0.7, 0.71}}}) {
      const std::vector<double> d = info.Defaults();
      through = through || (b->Eval(d.data(), wi.normalized(), wo.normalized()) > 0).any();
    }
    EXPECT_EQ((k & LobeKind::kTransmission) != 0, through) << info.name << ": transmission iff f across the surface";
    for (const std::vector<double>& p : Points(info))
      EXPECT_EQ(b->Width(p.data()).Any(), (k & LobeKind::kGlossy) != 0) << info.name << ": glossy iff a width";
  }
}

// The declared width against the measured half-width of the lobe along x
// and y: within a factor 3 of each other for every glossy model (the
// declared width is on the scale of a Beckmann alpha, whose half-width is
// 0.83 alpha; a Phong lobe about the mirror direction measures 0.42 of its
// sqrt(2 / (n + 2))). A model with no glossy lobe measures broad.
TEST(ModelTraits, DeclaredLobeWidthMatchesTheLobe) {
  for (const ModelInfo& info : RegisteredModelInfos()) {
    const auto b = MakeModel(info).Make<double>();
    for (const std::vector<double>& p : Points(info)) {
      const LobeWidth w = b->Width(p.data());
      const double mx = MeasuredHalfWidth(*b, p.data(), Eigen::Vector3d::UnitX());
      const double my = MeasuredHalfWidth(*b, p.data(), Eigen::Vector3d::UnitY());
      SCOPED_TRACE(info.name + " at " + FormatParams(info, p));
      if (!w.Any()) {
        EXPECT_GT(std::min(mx, my), 0.3);
        continue;
      }
      // A lobe wider than the hemisphere's scale measures capped.
      EXPECT_GT(mx / std::min(w.x, 1.0), 1.0 / 3.0) << mx << " vs " << w.x;
      EXPECT_LT(mx / std::min(w.x, 1.0), 3.0) << mx << " vs " << w.x;
      EXPECT_GT(my / std::min(w.y, 1.0), 1.0 / 3.0) << my << " vs " << w.y;
      EXPECT_LT(my / std::min(w.y, 1.0), 3.0) << my << " vs " << w.y;
    }
  }
}

// Every named slot is the offset Info() gives that name, and every
// parameter of Info() has its slot.
TEST(ModelTraits, SlotsAreTheInfoOffsets) {
  for (const ModelInfo& info : RegisteredModelInfos()) {
    SCOPED_TRACE(info.name);
    const std::vector<Slot> slots = TraitsOf(info.name).slots;
    EXPECT_EQ(slots.size(), info.params.size());
    for (const Slot& s : slots) {
      std::size_t i = 0;
      while (i < info.params.size() && info.params[i].name != s.name) ++i;
      ASSERT_LT(i, info.params.size()) << "slot " << s.name << " is not a parameter";
      EXPECT_EQ(s.offset, info.Offset(i)) << s.name;
      EXPECT_EQ(s.colour, info.params[i].colour) << s.name;
    }
  }
}

// A model that declares independent channels has no derivative of channel
// c by another channel's slot of a colour parameter, at the defaults and
// at random points of the bounds, for random direction pairs.
TEST(ModelTraits, DeclaredChannelIndependenceHolds) {
  using J = fit::Jet<32>;
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  for (const ModelInfo& info : RegisteredModelInfos()) {
    const Model m = MakeModel(info);
    if (!m.Make<double>()->ChannelsIndependent() || info.PackedSize() > 32) continue;
    SCOPED_TRACE(info.name);
    const auto b = m.Make<J>();
    std::vector<int> channel;
    for (const ParamInfo& p : info.params)
      for (int c = 0; c < (p.colour ? 3 : 1); ++c) channel.push_back(p.colour ? c : -1);
    for (int trial = 0; trial < 16; ++trial) {
      std::vector<J> pj;
      std::size_t k = 0;
      for (const ParamInfo& p : info.params)
        for (int c = 0; c < (p.colour ? 3 : 1); ++c, ++k) {
          double v = p.default_value;
          if (trial > 0 && p.scale == ParamInfo::Scale::kLog && p.default_value > 0) {
            const double l = std::max(p.lower, p.default_value / 30), h = std::min(p.upper, p.default_value * 30);
            v = std::exp(std::log(l) + uni(rng) * (std::log(h) - std::log(l)));
          } else if (trial > 0) {
            v = p.lower + uni(rng) * (p.upper - p.lower);
          }
          pj.push_back(J(v, static_cast<int>(k)));
        }
      const double ti = std::acos(uni(rng)), to = std::acos(uni(rng)), ph = 2 * kPi * uni(rng);
      const Vec3<J> wi(J(std::sin(ti)), J(0.0), J(std::cos(ti)));
      const Vec3<J> wo(J(std::sin(to) * std::cos(ph)), J(std::sin(to) * std::sin(ph)), J(std::cos(to)));
      const Rgb<J> f = b->Eval(pj.data(), wi, wo);
      for (int c = 0; c < 3; ++c)
        for (std::size_t j = 0; j < channel.size(); ++j) {
          if (channel[j] >= 0 && channel[j] != c) {
            EXPECT_EQ(f[c].v[j], 0.0) << "channel " << c << " by slot " << j;
          }
        }
    }
  }
}

}  // namespace
}  // namespace brdfkit
