// Residuals and Jacobians of a model over prepared samples: the parameter
// transform (log scale, fixed and tied slots), shared derivative slots of
// colour parameters, and the instrument's apertures.
#include <algorithm>
#include <array>
#include <cmath>
#include <stdexcept>
#include <string>
#include <type_traits>

#include "fit/fit_internal.h"

namespace brdfkit::fit {

namespace {
// The Jet size (of those the models are compiled for) that holds `slots` derivative slots.
int JetSize(std::size_t slots) { return slots <= 4 ? 4 : slots <= 8 ? 8 : slots <= 16 ? 16 : 32; }
}  // namespace

Engine::Engine(const Evaluators& model, const Options& o, double loss_scale, const Layout& layout)
    : metric_(o.metric), loss_(o.loss), loss_scale_(loss_scale), layout_(layout) {
  const ModelInfo& info = model.Info();
  n_ = info.PackedSize();
  nf_ = layout.Free();
  std::vector<std::size_t> param_of;  // packed slot -> index into info.params
  std::vector<int> channel_of;        // packed slot -> channel of a colour parameter, else -1
  for (std::size_t i = 0; i < info.params.size(); ++i)
    for (int c = 0; c < (info.params[i].colour ? 3 : 1); ++c) {
      param_of.push_back(i);
      channel_of.push_back(info.params[i].colour ? c : -1);
    }
  for (std::size_t j = 0; j < nf_; ++j)
    log_.push_back(info.params[param_of[layout.rep[j]]].scale == ParamInfo::Scale::kLog);
  b_ = model.MakeDouble();
  // Derivative slots: one per free scalar parameter and one per free
  // colour parameter, shared by its r, g, b slots. Channel c of f_r
  // depends only on slot c of each colour parameter (the models declare
  // it; a tie joins colour parameters channel by channel), so the shared
  // slot's derivative in channel c is the derivative by the c slot: Jets
  // of 3 slots instead of 7 for lambert+ggx.
  const bool shared = b_->ChannelsIndependent();
  std::vector<int> slot_of_param(info.params.size(), -1);
  for (std::size_t j = 0; j < nf_; ++j) {
    const std::size_t k = layout.rep[j];
    const int c = channel_of[k];
    if (shared && c >= 0) {
      int& s = slot_of_param[param_of[k]];
      if (s < 0) s = int(n_slots_++);
      slot_.push_back(std::size_t(s));
      channel_.push_back(c);
    } else {
      slot_.push_back(n_slots_++);
      channel_.push_back(-1);
    }
  }
  if (n_slots_ > 32 || n_ > 64)
    throw std::invalid_argument("model '" + info.name + "' has " + std::to_string(nf_) +
                                " free parameters; fitting supports at most 32 (and 64 packed values)");
  jet_ = JetSize(n_slots_);
  if (jet_ == 4) b4_ = model.MakeJet4();
  if (jet_ == 8) b8_ = model.MakeJet8();
  if (jet_ == 16) b16_ = model.MakeJet16();
  if (jet_ == 32) b32_ = model.MakeJet32();
  if (const Model* m = model.AsModel(); m && m->LobeCount() > 1) {
    bool smaller = false;
    for (std::size_t k = 0; k < m->LobeCount(); ++k) {
      LobeJet l;
      l.offset = m->LobeOffset(k);
      l.size = m->LobeInfo(k).PackedSize();
      l.weight = m->LobeWeightIndex(k);
      for (std::size_t i = l.offset; i < l.offset + l.size; ++i) {
        const int f = layout.free_of[i];
        if (f < 0) continue;
        const std::size_t s = slot_[std::size_t(f)];
        if (std::find(l.lanes.begin(), l.lanes.end(), s) == l.lanes.end()) l.lanes.push_back(s);
      }
      l.jet = JetSize(l.lanes.size());
      smaller = smaller || l.jet < jet_;
      const Model lobe = m->LobeAlone(k);
      if (l.jet == 4) l.b4 = lobe.Make<Jet<4>>();
      if (l.jet == 8) l.b8 = lobe.Make<Jet<8>>();
      if (l.jet == 16) l.b16 = lobe.Make<Jet<16>>();
      if (l.jet == 32) l.b32 = lobe.Make<Jet<32>>();
      lobes_.push_back(std::move(l));
    }
    if (!smaller) lobes_.clear();  // every lobe needs the sum's Jet: nothing to gain
  }
  if (o.instrument) {
    const synth::QuadratureSettings& settings = o.instrument->quadrature;
    const int order = o.aperture_order > 0 ? o.aperture_order : settings.order;
    if (order > 0) {
      quad_ = std::make_unique<synth::ApertureQuadrature>(synth::MakeApertureQuadrature(*o.instrument, order));
    } else {
      // Automatic order: each pair's rules rise on their own, as synth measures.
      const int degree = 4 * settings.max_order - 1;
      ladder_ = std::make_unique<synth::ApertureLadder>(synth::MakeApertureLadder(*o.instrument, degree, degree));
      tolerance_ = settings.tolerance;
    }
  }
}

// Internal (optimised, free) -> user parameters (packed).
template <class T>
void Engine::ToUser(const T* u, T* p) const {
  using std::exp;
  std::array<T, 64> y;
  for (std::size_t j = 0; j < nf_; ++j) y[j] = log_[j] ? exp(u[j]) : u[j];
  for (std::size_t k = 0; k < n_; ++k) {
    const int f = layout_.free_of[k];
    p[k] = f < 0 ? T(layout_.value[k]) : y[std::size_t(f)];
  }
}

std::vector<double> Engine::ToUser(const std::vector<double>& u) const {
  std::vector<double> p(n_);
  ToUser(u.data(), p.data());
  return p;
}

std::vector<double> Engine::ToInternal(const std::vector<double>& p) const {
  std::vector<double> u(nf_);
  for (std::size_t j = 0; j < nf_; ++j) {
    const double v = p[layout_.rep[j]];
    u[j] = log_[j] ? std::log(v) : v;
  }
  return u;
}

// Residuals of sample q: out[3]. fit: fit weights and robust loss; else
// the plain metric.
template <class T>
void Engine::SampleResiduals(const Bxdf<T>& b, const T* p, const Prepared& d, std::size_t q, bool fit, T* out) const {
  const Eigen::Vector3d wi = d.Wi(q), wo = d.Wo(q);
  ResidualsOf(Prediction(b, p, wi, wo), d, q, wi.z(), fit, out);
}

template <class T>
void Engine::ResidualsOf(const Rgb<T>& f, const Prepared& d, std::size_t q, double cos_i, bool fit, T* out) const {
  Rgb<T> g;
  for (int c = 0; c < 3; ++c) g[c] = MetricTransform(metric_, f[c], cos_i);
  ResidualsOfTransformed(g, d, q, fit, out);
}

template <class T>
void Engine::ResidualsOfTransformed(const Rgb<T>& g, const Prepared& d, std::size_t q, bool fit, T* out) const {
  for (int c = 0; c < 3; ++c) {
    T r = g[c] - T(d.target[q][c]);
    if (fit) {
      if (!d.w_fit.empty()) r *= d.w_fit[q][c];
      out[c] = loss_ == Loss::kNone ? r : Robust(loss_, loss_scale_, r);
    } else {
      out[c] = d.w_fit.empty() && d.w_metric.empty() ? r : T(T(d.WMetric(q)[c]) * r);
    }
  }
}

void Engine::ResidualsOfRange(const Prepared& d, std::size_t begin, std::size_t end, bool fit, double* r) const {
  static_assert(sizeof(Eigen::Array3d) == 3 * sizeof(double));  // the per-sample arrays read flat
  const std::size_t m = 3 * (end - begin);
  const double* t = d.target[begin].data();
  for (std::size_t k = 0; k < m; ++k) r[k] -= t[k];
  // The weights ResidualsOfTransformed applies: w_fit, or the metric's own.
  const std::vector<Eigen::Array3d>& w = fit || d.w_metric.empty() ? d.w_fit : d.w_metric;
  if (!w.empty()) {
    const double* wk = w[begin].data();
    for (std::size_t k = 0; k < m; ++k) r[k] *= wk[k];
  }
  if (fit && loss_ != Loss::kNone)
    for (std::size_t k = 0; k < m; ++k) r[k] = Robust(loss_, loss_scale_, r[k]);
}

// The model's value for the directions wi, wo: f_r, or f_r through the instrument's apertures.
template <class T>
Rgb<T> Engine::Prediction(const Bxdf<T>& b, const T* p, const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) const {
  if (quad_) return synth::MeasuredBrdf(b, p, wi, wo, *quad_);
  if (ladder_) {
    if constexpr (std::is_same_v<T, double>) {
      return synth::MeasureAdaptive(b, p, wi, wi, wo, wo, *ladder_, tolerance_).f;
    } else {
      // The levels the parameters' values stop at; the derivatives are taken with them held.
      std::array<double, 64> value;
      for (std::size_t k = 0; k < n_; ++k) value[k] = p[k].a;
      const synth::AdaptiveMeasurement m =
          synth::MeasureAdaptive(*b_, value.data(), wi, wi, wo, wo, *ladder_, tolerance_);
      return synth::MeasuredAtLevels(b, p, wi, wo, *ladder_, m.source_level, m.detector_level);
    }
  }
  return b.EvalAt(p, wi, wo);
}

namespace {
// The unit directions of samples [begin, end) for EvalBatch: read in place
// (the rows' own wi and wo, a Sample apart) when the rows are consecutive
// and unit, else packed into wi and wo as rows of 3.
struct DirectionRows {
  const double* wi;
  const double* wo;
  std::size_t stride;
};
DirectionRows Directions(const Prepared& d, std::size_t begin, std::size_t end, std::vector<double>& wi,
                         std::vector<double>& wo) {
  static_assert(sizeof(Sample) % sizeof(double) == 0 && sizeof(Eigen::Vector3d) == 3 * sizeof(double));
  if (d.unit && d.consecutive) {
    const Sample& s = d.Row(begin);
    return {s.wi.data(), s.wo.data(), sizeof(Sample) / sizeof(double)};
  }
  wi.resize(3 * (end - begin));
  wo.resize(3 * (end - begin));
  for (std::size_t q = begin; q < end; ++q) {
    Eigen::Map<Eigen::Vector3d>(wi.data() + 3 * (q - begin)) = d.Wi(q);
    Eigen::Map<Eigen::Vector3d>(wo.data() + 3 * (q - begin)) = d.Wo(q);
  }
  return {wi.data(), wo.data(), 3};
}
}  // namespace

Eigen::Array3d Engine::Predict(const std::vector<double>& p, const Prepared& d, std::size_t q) const {
  return Prediction(*b_, p.data(), d.Wi(q), d.Wo(q));
}

void Engine::PredictRange(const std::vector<double>& p, const Prepared& d, std::size_t begin, std::size_t end,
                          double* out) const {
  if (quad_ || ladder_) {
    for (std::size_t q = begin; q < end; ++q) Eigen::Map<Eigen::Array3d>(out + 3 * (q - begin)) = Predict(p, d, q);
  } else if (end > begin) {
    std::vector<double> wi, wo;
    const DirectionRows dir = Directions(d, begin, end, wi, wo);
    b_->EvalBatch(p.data(), dir.wi, dir.stride, dir.wo, dir.stride, end - begin, out);
  }
}

bool Engine::EvalDouble(const double* u, const Prepared& d, std::size_t begin, std::size_t end, bool fit,
                        double* r) const {
  std::vector<double> p(n_);
  ToUser(u, p.data());
  if (quad_ || ladder_) {
    for (std::size_t q = begin; q < end; ++q) SampleResiduals(*b_, p.data(), d, q, fit, r + 3 * (q - begin));
  } else if (end > begin) {
    // f_r of the whole range in one EvalBatch call (the model's vectorised
    // kernel), its transform G in one vectorised pass, then the residuals
    // w (G(f) - target) of the range at once, all in r.
    const std::size_t n = end - begin;
    std::vector<double> wi, wo, f;
    const DirectionRows dir = Directions(d, begin, end, wi, wo);
    if (metric_ == Metric::kCbrt || metric_ == Metric::kLog) {
      f.resize(3 * n);
      b_->EvalBatch(p.data(), dir.wi, dir.stride, dir.wo, dir.stride, n, f.data());
      if (metric_ == Metric::kCbrt) CbrtRows(dir.wi, dir.stride, f.data(), n, r);
      else Log1pRows(dir.wi, dir.stride, f.data(), n, r);
    } else {
      b_->EvalBatch(p.data(), dir.wi, dir.stride, dir.wo, dir.stride, n, r);  // G is f itself
    }
    ResidualsOfRange(d, begin, end, fit, r);
  }
  for (std::size_t k = 0; k < 3 * (end - begin); ++k)
    if (!std::isfinite(r[k])) return false;
  return true;
}

namespace {
// A parameter of the sum (derivatives by the sum's slots) as one of a lobe's
// (derivatives by the lobe's lanes, lanes[k] the sum's slot of lane k).
template <int M, int N>
Jet<M> ToLanes(const Jet<N>& p, const std::vector<std::size_t>& lanes) {
  Jet<M> out(p.a);
  for (std::size_t k = 0; k < lanes.size(); ++k) out.v[Eigen::Index(k)] = p.v[Eigen::Index(lanes[k])];
  return out;
}

template <int M, int N>
void AddLobe(const Bxdf<Jet<M>>& b, const Jet<M>* p, const std::vector<std::size_t>& lanes, const Jet<N>* weight,
             const Eigen::Vector3d& wi, const Eigen::Vector3d& wo, Rgb<Jet<N>>& f) {
  const Rgb<Jet<M>> g = b.EvalAt(p, wi, wo);
  // f += w g, with d(w g) = g dw + w dg and dg on the lobe's lanes only.
  const double w = weight ? weight->a : 1.0;
  for (int c = 0; c < 3; ++c) {
    f[c].a += w * g[c].a;
    if (weight) f[c].v += g[c].a * weight->v;
    for (std::size_t k = 0; k < lanes.size(); ++k) f[c].v[Eigen::Index(lanes[k])] += w * g[c].v[Eigen::Index(k)];
  }
}
}  // namespace

template <int N>
Engine::LobeParams Engine::ToLobes(const Jet<N>* pj) const {
  LobeParams lp;
  for (const LobeJet& l : lobes_) {
    const auto fill = [&](auto& v, auto tag) {
      constexpr int M = decltype(tag)::value;
      lp.base.push_back(v.size());
      for (std::size_t i = 0; i < l.size; ++i) v.push_back(ToLanes<M>(pj[l.offset + i], l.lanes));
    };
    if (l.jet == 4) fill(lp.p4, std::integral_constant<int, 4>());
    if (l.jet == 8) fill(lp.p8, std::integral_constant<int, 8>());
    if (l.jet == 16) fill(lp.p16, std::integral_constant<int, 16>());
    if (l.jet == 32) fill(lp.p32, std::integral_constant<int, 32>());
  }
  return lp;
}

template <int N>
Rgb<Jet<N>> Engine::SumOfLobes(const LobeParams& lp, const Jet<N>* pj, const Eigen::Vector3d& wi,
                               const Eigen::Vector3d& wo) const {
  Rgb<Jet<N>> f = Rgb<Jet<N>>::Constant(Jet<N>(0.0));
  for (std::size_t k = 0; k < lobes_.size(); ++k) {
    const LobeJet& l = lobes_[k];
    const Jet<N>* w = l.weight < 0 ? nullptr : pj + l.weight;
    const std::size_t at = lp.base[k];
    if (l.jet == 4) AddLobe(*l.b4, lp.p4.data() + at, l.lanes, w, wi, wo, f);
    if (l.jet == 8) AddLobe(*l.b8, lp.p8.data() + at, l.lanes, w, wi, wo, f);
    if (l.jet == 16) AddLobe(*l.b16, lp.p16.data() + at, l.lanes, w, wi, wo, f);
    if (l.jet == 32) AddLobe(*l.b32, lp.p32.data() + at, l.lanes, w, wi, wo, f);
  }
  return f;
}

template <int N, class Sink>
bool Engine::EvalJet(const Bxdf<Jet<N>>& b, const double* u, const Prepared& d, std::size_t begin,
                     std::size_t end, Sink&& sink) const {
  std::array<Jet<N>, 64> uj, pj;
  for (std::size_t k = 0; k < nf_; ++k) uj[k] = Jet<N>(u[k], static_cast<int>(slot_[k]));
  ToUser(uj.data(), pj.data());
  // Lobe by lobe where the sum has them (not through an instrument's apertures).
  const bool by_lobe = !lobes_.empty() && !quad_ && !ladder_;
  const LobeParams lp = by_lobe ? ToLobes(pj.data()) : LobeParams{};
  // Blocks of samples: their values first, then the metric's transform of
  // the block at once (cube root and log1p vectorised), then residuals.
  constexpr std::size_t kBlock = 16;
  std::array<Rgb<Jet<N>>, kBlock> g;
  std::array<double, 3 * kBlock> cos_rows{}, x, y;
  static constexpr double kUnitRow[3] = {0, 0, 1};
  for (std::size_t q0 = begin; q0 < end; q0 += kBlock) {
    const std::size_t m = std::min(kBlock, end - q0);
    for (std::size_t k = 0; k < m; ++k) {
      const Eigen::Vector3d wi = d.Wi(q0 + k), wo = d.Wo(q0 + k);
      g[k] = by_lobe ? SumOfLobes(lp, pj.data(), wi, wo) : Prediction(b, pj.data(), wi, wo);
      cos_rows[3 * k + 2] = wi.z();
    }
    if (metric_ == Metric::kCbrt || metric_ == Metric::kLog) {
      for (std::size_t k = 0; k < m; ++k)
        for (int c = 0; c < 3; ++c) x[3 * k + c] = g[k][c].a * cos_rows[3 * k + 2];
      if (metric_ == Metric::kCbrt) CbrtRows(kUnitRow, 0, x.data(), m, y.data());
      else Log1pRows(kUnitRow, 0, x.data(), m, y.data());
      for (std::size_t k = 0; k < m; ++k)
        for (int c = 0; c < 3; ++c) {
          const double v = x[3 * k + c];
          // d log1p(v) = dv / (1 + v); d cbrt(v) = dv / (3 cbrt(v)^2), on the
          // tangent below the knee (CbrtSafe).
          const double root = v < kCbrtKnee ? kCbrtKneeRoot : y[3 * k + c];
          const double dg = metric_ == Metric::kLog ? 1 / (1 + v) : 1 / (3 * root * root);
          g[k][c] = Jet<N>(y[3 * k + c], g[k][c].v * (cos_rows[3 * k + 2] * dg));
        }
    } else {
      for (std::size_t k = 0; k < m; ++k)
        for (int c = 0; c < 3; ++c) g[k][c] = MetricTransform(metric_, g[k][c], cos_rows[3 * k + 2]);
    }
    for (std::size_t k = 0; k < m; ++k) {
      const std::size_t q = q0 + k;
      Jet<N> res[3];
      ResidualsOfTransformed(g[k], d, q, true, res);
      for (int c = 0; c < 3; ++c)
        if (!std::isfinite(res[c].a) || !sink(3 * (q - begin) + std::size_t(c), c, res[c])) return false;
    }
  }
  return true;
}

bool Engine::EvalJacobian(const double* u, const Prepared& d, std::size_t begin, std::size_t end, double* r,
                          double* jac) const {
  switch (jet_) {
    case 4: return JacobianOfRange<4>(*b4_, u, d, begin, end, r, jac);
    case 8: return JacobianOfRange<8>(*b8_, u, d, begin, end, r, jac);
    case 16: return JacobianOfRange<16>(*b16_, u, d, begin, end, r, jac);
    default: return JacobianOfRange<32>(*b32_, u, d, begin, end, r, jac);
  }
}

bool Engine::NormalOfRange(const double* u, const Prepared& d, std::size_t begin, std::size_t end,
                           Eigen::MatrixXd& jtj, Eigen::VectorXd& jtr, double& rr) const {
  switch (jet_) {
    case 4: return NormalOfRange<4>(*b4_, u, d, begin, end, jtj, jtr, rr);
    case 8: return NormalOfRange<8>(*b8_, u, d, begin, end, jtj, jtr, rr);
    case 16: return NormalOfRange<16>(*b16_, u, d, begin, end, jtj, jtr, rr);
    default: return NormalOfRange<32>(*b32_, u, d, begin, end, jtj, jtr, rr);
  }
}

template <int N>
bool Engine::JacobianOfRange(const Bxdf<Jet<N>>& b, const double* u, const Prepared& d, std::size_t begin,
                             std::size_t end, double* r, double* jac) const {
  return EvalJet<N>(b, u, d, begin, end, [&](std::size_t row, int c, const Jet<N>& res) {
    r[row] = res.a;
    if (!jac) return true;
    for (std::size_t j = 0; j < nf_; ++j) {
      const double v = Acts(j, c) ? res.v[slot_[j]] : 0.0;
      if (!std::isfinite(v)) return false;
      jac[row * nf_ + j] = v;
    }
    return true;
  });
}

template <int N>
bool Engine::NormalOfRange(const Bxdf<Jet<N>>& b, const double* u, const Prepared& d, std::size_t begin,
                           std::size_t end, Eigen::MatrixXd& jtj, Eigen::VectorXd& jtr, double& rr) const {
  // Row (q, c) of J holds the residual's derivative slots where parameter j
  // acts on channel c (a scalar, or a colour parameter's c entry) and 0
  // elsewhere, so J^T J and J^T r are sums over the channels of each
  // channel's slot products s s^T and s r, read at the parameters' slots.
  std::array<Eigen::Matrix<double, N, N>, 3> ss;
  std::array<Eigen::Matrix<double, N, 1>, 3> sr;
  for (int c = 0; c < 3; ++c) {
    ss[std::size_t(c)].setZero();
    sr[std::size_t(c)].setZero();
  }
  double sum = 0;
  const bool done = EvalJet<N>(b, u, d, begin, end, [&](std::size_t, int c, const Jet<N>& res) {
    ss[std::size_t(c)].noalias() += res.v * res.v.transpose();
    sr[std::size_t(c)].noalias() += res.v * res.a;
    sum += res.a * res.a;
    return true;
  });
  if (!done) return false;
  const Eigen::Index n = Eigen::Index(n_slots_);
  for (int c = 0; c < 3; ++c)
    if (!ss[std::size_t(c)].topLeftCorner(n, n).allFinite() || !sr[std::size_t(c)].head(n).allFinite()) return false;
  rr += sum;
  for (std::size_t i = 0; i < nf_; ++i)
    for (int c = 0; c < 3; ++c) {
      if (!Acts(i, c)) continue;
      const Eigen::Index si = Eigen::Index(slot_[i]);
      jtr[Eigen::Index(i)] += sr[std::size_t(c)][si];
      for (std::size_t j = 0; j < nf_; ++j)
        if (Acts(j, c)) jtj(Eigen::Index(i), Eigen::Index(j)) += ss[std::size_t(c)](si, Eigen::Index(slot_[j]));
    }
  return true;
}

}  // namespace brdfkit::fit
