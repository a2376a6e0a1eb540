// Starting points of a fit: a given initial guess, the multi-start over
// log-spaced widths solved on a subset of the samples, and for sums of lobes
// the nested sub-sums (StartSearch).
#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <memory>
#include <numeric>
#include <optional>
#include <random>
#include <stdexcept>
#include <unordered_map>
#include <utility>

#include "fit/fit_internal.h"

namespace brdfkit::fit {

namespace {

// A solution: packed user parameters and its cost on the samples it was solved on.
struct Candidate {
  std::vector<double> p;
  double cost = std::numeric_limits<double>::infinity();
  std::string origin;
  bool on_all = true;  // solved on all samples (else on the middle subset; cost on all samples)
  bool bounded = false;  // its solve stopped where its optimum lay above the level it was to reach
  bool nested = false;  // a nested sub-sum's optimum
};

// On large tables a sub-sum whose cost at its middle-subset optimum is more
// than this fraction above the sum's final cost is not solved on all
// samples: that solve lowered the cost by 0.7 % at most in the measured
// cases (bench/RESULTS.md), and it is the most expensive step of a search.
constexpr double kNestedMargin = 0.05;

// A sub-sum's optimum on the middle subset lies within this of its optimum
// on all samples (internal parameters, relative for widths and for values
// above 1): 0.009 in the measured case (bench/RESULTS.md). A final solve
// that ends with the sub-sum's lobes switched off this close to the
// sub-sum's middle optimum has solved that sub-sum on all samples.
constexpr double kSubsetSpread = 0.02;

// Coarse to fine on large tables (more than 64 x start_subset samples): a
// start's optimum is first refined on a middle-sized subset (16 x
// start_subset), to this function tolerance, so that the solve on all
// samples (whose iterations cost the most) starts near its optimum and
// needs few.
bool LargeTable(const FitState& s) { return s.full.size() > 64 * s.o.start_subset; }
std::size_t MiddleSize(const Options& o) { return 16 * o.start_subset; }
constexpr double kMiddleTolerance = 1e-7;

// The contenders of a level: its best few distinct optima within this
// fraction of the best cost on all samples, each refined before the choice.
// A subset's optimum is compared unrefined with a sub-sum's refined one; in
// the measured case (bench/RESULTS.md, beckmann_ggx_mixture) the basin that
// ended 0.9 % lower was 0.35 % higher before refinement. Every level
// chooses so, the sub-sums too: a sum of n lobes is then never worse than
// the fit of n - 1 lobes on its own. A candidate whose
// cost is within kSameBasin of the previous contender's is taken to lie in
// its basin and is not refined: were it another basin, its optimum could
// differ by about that fraction only.
constexpr std::size_t kContenders = 3;
constexpr double kContenderMargin = 0.01;
// The subset's own best optimum contends within a wider margin: the subset
// preferred its basin, and its point there can lie far from the basin's
// optimum on all samples (a Fresnel-shaping pair of copies: 3.7 % above the
// nested fit unrefined, 0.08 % below it refined).
constexpr double kSubsetBestMargin = 0.05;
constexpr double kSameBasin = 1e-4;
// A peak split off a lobe after the final solve (StartSearch::SplitPeak)
// starts with this share of the lobe's switch.
constexpr double kSplitShare = 1e-3;
// Its solve on all samples runs at most kSplitIterations and must end
// kSplitGain below the fit's cost; it is given up when after kSplitLook
// iterations its cost is still kSplitAbove above. In the measured cases a
// split peak was within 3.2e-4 of the fit's cost after one iteration and
// below it after 2-9 (by 1.5e-5 to 8.2e-4 at the end), and a seed that
// returned to the fit's own optimum (the copy switched off again) stayed
// 3e-3 to 2e-2 above it for 20 iterations (bench/RESULTS.md).
constexpr double kSplitGain = 1e-6;
constexpr double kSplitAbove = 1e-3;
constexpr int kSplitLook = 3;
// The Fresnel pair split off a copy starts at the fit's own point where it
// shapes one channel (its two lobes reproduce the copy), a wide lobe a
// thousandth of the copy's weight from it: each is given up unless
// kPairLook iterations take it kSplitGain below the fit's cost (measured:
// a wide lobe that paid was 4.8e-4 below after 2 iterations; 17 that did
// not were 1.6e-10 to 1.5e-3 above after one and crept back to the fit's
// optimum, bench/RESULTS.md).
constexpr int kPairLook = 2;
constexpr int kSplitIterations = 12;
// Two active copies whose widths lie within this of each other (relative)
// are near: a final solve that creeps beside them pauses, and SplitPeak
// tries them merged into one, the lobe so freed as its seeds.
constexpr double kMergeSpread = 0.2;
std::string MiddleStage(const std::string& name, std::size_t samples) {
  return (name.empty() ? "" : name + ": ") + "refine (" + std::to_string(samples) + " samples)";
}

// The packed slots of lobe k (its own and its weight).
std::vector<std::size_t> LobeSlots(const Model& m, std::size_t k) {
  std::vector<std::size_t> out;
  for (std::size_t q = 0; q < m.LobeInfo(k).PackedSize(); ++q) out.push_back(m.LobeOffset(k) + q);
  if (m.LobeWeightIndex(k) >= 0) out.push_back(std::size_t(m.LobeWeightIndex(k)));
  return out;
}

// The slots that switch lobe k off at 0: its weight, or its colour
// parameters whose range starts at 0.
std::vector<std::size_t> SwitchSlots(const Model& m, std::size_t k) {
  if (m.LobeWeightIndex(k) >= 0) return {std::size_t(m.LobeWeightIndex(k))};
  std::vector<std::size_t> out;
  const ModelInfo& li = m.LobeInfo(k);
  for (std::size_t i = 0; i < li.params.size(); ++i)
    if (li.params[i].colour && li.params[i].lower == 0)
      for (int c = 0; c < 3; ++c) out.push_back(m.LobeOffset(k) + li.Offset(i) + std::size_t(c));
  return out;
}

// First log-scale parameter of lobe k (its width), as a packed slot; -1 when none.
std::ptrdiff_t WidthSlot(const Model& m, std::size_t k) {
  const ModelInfo& li = m.LobeInfo(k);
  for (std::size_t i = 0; i < li.params.size(); ++i)
    if (li.params[i].scale == ParamInfo::Scale::kLog && !li.params[i].colour)
      return std::ptrdiff_t(m.LobeOffset(k) + li.Offset(i));
  return -1;
}

// Log-spaced start values of a log-scale parameter (packed slot k) within its bounds.
std::vector<double> StartWidths(const Layout& layout, std::size_t k, double default_value, int starts_per_param) {
  const int K = std::max(1, starts_per_param);
  if (K == 1) return {std::clamp(default_value, layout.lo[k], layout.hi[k])};
  double l = std::max(layout.lo[k] > 0 ? layout.lo[k] : 0.0, default_value / 30.0);
  double h = std::min(layout.hi[k], default_value * 30.0);
  if (!(l < h)) {  // bounds away from the default: span them
    l = layout.lo[k] > 0 ? layout.lo[k] : 1e-3 * layout.hi[k];
    h = layout.hi[k];
  }
  std::vector<double> out;
  for (int q = 0; q < K; ++q) out.push_back(std::exp(std::log(l) + (std::log(h) - std::log(l)) * q / (K - 1)));
  return out;
}

// Every combination of start widths of the free log-scale parameters (at
// most 64; beyond that the diagonal of the grid), other parameters at the
// layout's values. copy_of(slot) names the lobe whose width the parameter at
// that packed slot is, when that lobe is one of several interchangeable
// copies (empty otherwise): the copies' widths start in increasing order.
std::vector<std::vector<double>> GridStarts(const ModelInfo& info, const Layout& layout, int starts_per_param,
                                            const std::function<std::string(std::size_t)>& copy_of) {
  std::vector<double> start = layout.value;
  std::vector<std::size_t> slots, sizes;      // leading packed slot and size of each free log parameter
  std::vector<std::vector<double>> values;
  std::vector<std::string> lobe_of;           // copy_of its slot
  std::size_t off = 0;
  for (const ParamInfo& p : info.params) {
    const std::size_t width = p.colour ? 3 : 1;
    if (p.scale == ParamInfo::Scale::kLog && layout.free_of[off] >= 0 && layout.leader[off] < 0) {
      slots.push_back(off);
      sizes.push_back(width);
      values.push_back(StartWidths(layout, off, p.default_value, starts_per_param));
      lobe_of.push_back(copy_of(off));
    }
    off += width;
  }
  const auto ordered = [&](const std::vector<int>& c) {
    for (std::size_t a = 0; a < c.size(); ++a)
      for (std::size_t b = a + 1; b < c.size(); ++b)
        if (!lobe_of[a].empty() && lobe_of[a] == lobe_of[b] && !(c[a] < c[b])) return false;
    return true;
  };
  const int K = std::max(1, starts_per_param);
  double total = 1;
  for (std::size_t j = 0; j < slots.size(); ++j) total *= K;
  std::vector<std::vector<int>> combos;
  if (slots.empty()) {
    combos.push_back({});
  } else if (total <= 64) {
    std::vector<int> c(slots.size(), 0);
    while (true) {
      if (ordered(c)) combos.push_back(c);
      std::size_t j = 0;
      while (j < c.size() && ++c[j] == K) c[j++] = 0;
      if (j == c.size()) break;
    }
    if (combos.empty()) combos.push_back(std::vector<int>(slots.size(), 0));
  } else {
    for (int k = 0; k < K; ++k) combos.push_back(std::vector<int>(slots.size(), k));
  }
  std::vector<std::vector<double>> out;
  for (const std::vector<int>& c : combos) {
    std::vector<double> p = start;
    for (std::size_t j = 0; j < slots.size(); ++j) {
      const double v = values[j][std::size_t(std::min<int>(c[j], int(values[j].size()) - 1))];
      for (std::size_t q = 0; q < sizes[j]; ++q) p[slots[j] + q] = v;
    }
    out.push_back(std::move(p));
  }
  return out;
}

// Whether internal parameters u and v are one solution: within 1e-3 in
// every parameter (relative for widths, which are logarithms inside).
bool SameSolution(const std::vector<double>& u, const std::vector<double>& v) {
  double d = 0;
  for (std::size_t j = 0; j < u.size(); ++j) d = std::max(d, std::abs(u[j] - v[j]));
  return d < 1e-3;
}

// Whether internal parameters u and v differ by at most kSubsetSpread in
// every parameter (relative where either is above 1).
bool WithinSpread(const std::vector<double>& u, const std::vector<double>& v) {
  for (std::size_t j = 0; j < u.size(); ++j)
    if (!(std::abs(u[j] - v[j]) <= kSubsetSpread * std::max({1.0, std::abs(u[j]), std::abs(v[j])}))) return false;
  return true;
}

// Internal parameters u clamped to the bounds of engine e.
void ClampToBounds(const Engine& e, std::vector<double>& u) {
  std::vector<double> lo, hi;
  Bounds(e.layout(), e.log_mask(), lo, hi);
  for (std::size_t j = 0; j < u.size(); ++j) u[j] = std::clamp(u[j], lo[j], hi[j]);
}

// One start: solves from internal parameters u (updated in place) over `d`
// for at most `iterations`, traced as the next start under `stage`
// (SolveToEnd; `from` as there).
Solved SolveStart(const FitState& s, const Engine& e, const Prepared& d, std::vector<double>& u, int iterations,
                  double ftol, const std::string& stage, const NormalCache::Normal* from = nullptr,
                  double stop_above = std::numeric_limits<double>::infinity()) {
  ceres::Solver::Options so = SolverOptions(s.o, LinearSolver::kDenseQr, iterations);
  so.function_tolerance = ftol;
  const int start = ++s.res.starts;
  return SolveToEnd(
      e, d, s.chunk, u, so, from,
      [&](int iteration, double cost, const std::vector<double>& at) {
        // The plain engine has no robust loss.
        s.res.trace.push_back({iteration, s.elapsed(), cost, RmseAt(e, d, at, cost, !s.sigma), start, stage});
      },
      stop_above);
}

// Multi-start and nested sub-sums of a sum of lobes (Fit's start strategy).
// Level(mask) fits the sum with the lobes in `mask` switched off.
class StartSearch {
 public:
  StartSearch(const Model& model, const FitState& s, const Prepared& subset, const Prepared* middle)
      : model_(model), s_(s), o_(s.o), base_(s.layout), full_(s.full), subset_(subset), middle_(middle) {
    plain_options_ = o_;
    for (const ParamInfo& p : model.Info().params)
      for (int c = 0; c < (p.colour ? 3 : 1); ++c) {
        channel_.push_back(p.colour ? c : -1);
        log_scale_.push_back(p.scale == ParamInfo::Scale::kLog);
      }
    plain_options_.loss = Loss::kNone;
    const std::size_t L = model.LobeCount();
    const ModelInfo& info = model.Info();
    for (std::size_t k = 0; k < L; ++k) {
      // A lobe can be switched off (and swapped with a copy of itself) only
      // when none of its parameters is fixed, tied or given bounds.
      bool untouched = true;
      for (std::size_t q : LobeSlots(model, k)) {
        const bool leads = std::find(base_.leader.begin(), base_.leader.end(), int(q)) != base_.leader.end();
        untouched = untouched && base_.free_of[q] >= 0 && base_.leader[q] < 0 && !leads;
      }
      std::size_t i = 0, off = 0;
      for (; i < info.params.size(); ++i) {
        for (std::size_t q : LobeSlots(model, k))
          if (q >= off && q < off + (info.params[i].colour ? 3 : 1))
            untouched = untouched && base_.lo[q] == info.params[i].lower && base_.hi[q] == info.params[i].upper;
        off += info.params[i].colour ? 3 : 1;
      }
      untouched_.push_back(untouched);
    }
  }

  Candidate Level(unsigned mask, bool top) {
    if (auto it = memo_.find(mask); it != memo_.end()) return it->second;
    const std::size_t L = model_.LobeCount();
    const std::string name = ActiveSpec(mask);
    const Layout layout = LevelLayout(mask);
    Candidate best;
    if (layout.Free() == 0) return memo_[mask] = best;
    const Engine plain(evaluators_, plain_options_, 1.0, layout);
    std::vector<std::size_t> active;
    for (std::size_t k = 0; k < L; ++k)
      if (!(mask >> k & 1u)) active.push_back(k);

    // Nested sub-sums: each lobe switched off in turn (of copies of one
    // lobe, only the last: the others give the same sub-sum).
    std::vector<std::pair<Candidate, std::size_t>> kids;
    if (o_.nested && active.size() >= 2)
      for (auto it = active.rbegin(); it != active.rend(); ++it) {
        const std::size_t k = *it;
        if (!untouched_[k]) continue;
        bool copy_done = false;
        for (const auto& kid : kids)
          copy_done = copy_done || (untouched_[kid.second] && model_.LobeInfo(kid.second).name == model_.LobeInfo(k).name);
        if (copy_done) continue;
        const Candidate c = Level(mask | (1u << k), false);
        if (std::isfinite(c.cost)) kids.emplace_back(c, k);
        if (top) top_kids_.push_back(mask | (1u << k));
      }

    // Starts on the subset: the multi-start grid over the widths, then each
    // sub-sum's optimum with the lobe switched back on, at each start width
    // and scaled to the sub-sum's residual.
    std::vector<Candidate> starts;
    for (std::vector<double>& p : GridStarts(layout, mask)) starts.push_back({std::move(p), 0, ""});
    for (const auto& [kid, k] : kids)
      for (std::vector<double>& p : Seeded(plain, kid.p, k, layout))
        starts.push_back({std::move(p), 0, "(" + model_.LobePrefix(k) + " added to " + ActiveSpec(mask | (1u << k)) + ")"});
    std::vector<Candidate> solved;
    for (Candidate& s : starts) {
      const std::string label = name + ": start " + std::to_string(s_.res.starts + 1);
      Candidate c = Solve(plain, subset_, s.p, o_.start_iterations, 1e-8, label + " (subset)");
      c.origin = label + (s.origin.empty() ? "" : " " + s.origin);
      if (std::isfinite(c.cost)) solved.push_back(std::move(c));
    }
    std::sort(solved.begin(), solved.end(), [](const Candidate& a, const Candidate& b) { return a.cost < b.cost; });

    // Every sub-sum's optimum and the best distinct optima of the subset, by
    // their cost on all samples. The contenders among them are refined
    // (Refine) and the best is kept (at the top level Fit's final solve
    // refines it on all samples). A refinement starts at its candidate's
    // cost and only descends, so a sum is never worse than its nested
    // sub-sums.
    std::vector<Candidate> candidates;
    for (const auto& [kid, k] : kids)
      candidates.push_back({kid.p, kid.cost, "nested " + ActiveSpec(mask | (1u << k)), kid.on_all, false, true});
    std::vector<Candidate> distinct;
    for (const Candidate& c : solved) {
      // The best four distinct subset optima: each costs a pass over all samples.
      if (distinct.size() == 4) break;
      if (Contains(plain, distinct, c.p) || InSubSum(c.p, active, kids)) continue;
      distinct.push_back(c);
      candidates.push_back({c.p, FullCost(plain, c.p), c.origin + " (subset optimum)"});
    }
    const std::vector<Candidate> unrefined = Distinct(plain, std::move(candidates));
    if (unrefined.empty()) return memo_[mask] = best;
    // The subset's best optimum contends within kSubsetBestMargin.
    const std::vector<double>* subset_best = distinct.empty() ? nullptr : &distinct.front().p;
    std::vector<Candidate> refined;
    std::size_t contenders = 0;
    double last = -std::numeric_limits<double>::infinity();
    for (const Candidate& c : unrefined) {
      const bool contends = contenders < kContenders && c.cost <= unrefined.front().cost * (1 + kContenderMargin) &&
                            c.cost > last * (1 + kSameBasin);
      if (contends) {
        ++contenders;
        last = c.cost;
      }
      const bool subset_preferred = subset_best && c.p == *subset_best &&
                                    c.cost <= unrefined.front().cost * (1 + kSubsetBestMargin);
      refined.push_back(contends || subset_preferred ? Refine(plain, c, name) : c);
    }
    const std::vector<Candidate> optima = Distinct(plain, std::move(refined));
    if (top)
      for (const Candidate& c : optima) s_.res.local_optima.push_back({c.cost, c.p, c.origin});
    best = optima.front();
    // A subset optimum whose refinement fell into a sub-sum (InSubSum: a
    // copy switched off, or two copies alike) within kSameBasin of a
    // sub-sum's optimum is taken to lie in that sub-sum's basin, and the
    // sub-sum's optimum is kept: a solve from alike copies creeps along
    // their flat direction (the split of their switches), in the measured
    // case 23 iterations on all samples against 6 (bench/RESULTS.md).
    if (!best.nested && InSubSum(best.p, active, kids))
      for (const Candidate& c : optima)
        if (c.nested && c.cost <= best.cost * (1 + kSameBasin)) {
          best = c;
          break;
        }
    return memo_[mask] = best;
  }

  // After the final solve (user parameters p, their cost on all samples
  // without a robust loss: final_cost): each sub-sum with one lobe
  // removed that was not solved on all samples and whose cost there is
  // within kNestedMargin of final_cost is solved on all samples now, while
  // its cost less kGainBound times its Gauss-Newton gain stays below
  // final_cost, at its start and after each step (Solve's stop_above):
  // beyond, its optimum cannot reach final_cost. When
  // one ends below final_cost its parameters are returned for a new final
  // solve, so the sum is never worse than its sub-sums. A sub-sum whose
  // lobes the final solve left switched off, from a start (user parameters
  // `start`) in the sub-sum's own basin (SameSolution) or at a point within
  // the sampling spread of the sub-sum's middle optimum (WithinSpread), was
  // solved on all samples by the final solve itself: its optimum is
  // `final_p`.
  std::optional<Candidate> RefineNested(double final_cost, const std::vector<double>& final_p,
                                        const std::vector<double>& start) {
    std::optional<Candidate> better;
    for (unsigned mask : top_kids_) {
      Candidate& kid = memo_[mask];
      if (kid.on_all || !(kid.cost <= final_cost * (1 + kNestedMargin))) continue;
      const std::string name = ActiveSpec(mask);
      const Engine plain(evaluators_, plain_options_, 1.0, LevelLayout(mask));
      const auto trace = [&](double cost, const std::vector<double>& p, const std::string& what) {
        const double rmse = RmseAt(plain, full_, plain.ToInternal(p), cost, !s_.sigma);
        s_.res.trace.push_back({0, s_.elapsed(), cost, rmse, 0, name + ": " + what});
      };
      // The final point with its switched-off copies of a lobe last, as in the sub-sums.
      const std::vector<double> q = OffLast(final_p), mid = plain.ToInternal(kid.p);
      const bool same_start =
          SwitchedOff(mask, start) && SwitchedOff(mask, final_p) && SameSolution(plain.ToInternal(start), mid);
      if (same_start || (SwitchedOff(mask, q) && WithinSpread(plain.ToInternal(q), mid))) {
        kid = {same_start ? final_p : q, final_cost, kid.origin, true};
        trace(final_cost, kid.p, "solved by the final solve (all samples)");
        s_.res.local_optima.push_back({kid.cost, kid.p, "nested " + name + " (all samples, the final solve)"});
        continue;
      }
      // The bound at the start, in one Jacobian pass (no solver set up).
      {
        Eigen::MatrixXd jtj;
        Eigen::VectorXd g;
        const std::vector<double> u = plain.ToInternal(kid.p);
        NormalEquations(plain, full_, u, s_.chunk, jtj, g);
        if (kid.cost - kGainBound * GainWithinBounds(plain, u, jtj, g) > final_cost) {
          trace(kid.cost, kid.p, "bounded (all samples), not solved");
          continue;
        }
      }
      Candidate c = Solve(plain, full_, kid.p, o_.max_iterations, o_.function_tolerance, name + ": refine (all samples)",
                          final_cost);
      if (c.bounded) {
        trace(c.cost, c.p, "bounded above the fit's cost (all samples), stopped");
        continue;
      }
      if (c.cost <= kid.cost) kid = {c.p, c.cost, kid.origin, true};
      kid.on_all = true;
      s_.res.local_optima.push_back({kid.cost, kid.p, "nested " + name + " (all samples)"});
      if (kid.cost < final_cost && (!better || kid.cost < better->cost)) better = kid;
    }
    return better;
  }

  // After the final solve (and RefineNested), on large tables: a lobe that
  // the fit's point p (cost `cost` on all samples) leaves switched off,
  // with an active copy of width w, is switched back on as a narrower copy
  // of it (a peak split off the copy): its other parameters the copy's, its
  // width the narrowest start width if below w / 2, its switch kSplitShare
  // of the copy's. The seed is solved on all samples, at most
  // kSplitIterations (given up after kSplitLook when still kSplitAbove
  // above `cost`); when it ends below `cost` (by kSplitGain) with no more
  // lobes switched off than p (another copy may go off in turn: on gold
  // with three lobes under l2 the narrow copy comes on and the wide one
  // goes off) and no two copies alike it is returned for a new final
  // solve. The starts' subsets cannot tell such a lobe: on gold and
  // rough_plastic_haze under l2 a copy of alpha 0.001-0.01 on the specular
  // peak lowers the cost on all samples by 1.5e-5 and 8.2e-4, where the
  // subset solves of the starts switch it off, and the middle subset's
  // optimum lies in another basin (bench/RESULTS.md). The lobe is also
  // tried as a Fresnel pair with the copy (FresnelPair with the fit's point
  // to reproduce: the copy's parameters, its colour channels inside their
  // bounds at the lower bound in the lobe and the upper in the copy), which
  // starts at the fit's own cost where one channel is shaped and is given
  // up unless kPairLook iterations take it kSplitGain below: on he_plastic
  // under log such a pair (red's Fresnel curve of its own) lowers the cost
  // by 5.1e-5, where the start search's pair, every channel at its bounds,
  // is switched off by its subset solve. And it is tried as a wide lobe
  // beside its copies (the widest start width, its other parameters at
  // their defaults), on the pair's terms: on beckmann_ggx_mixture under log
  // with three lobes a lobe of alpha 1 and f0 1 beside the diffuse term
  // lowers the cost by 4.9e-4, an optimum the start search's subsets did
  // not keep. With `merge` the lobes freed by merging two near copies
  // (NearPairs, Merged) are tried as well.
  std::optional<Candidate> SplitPeak(double cost, std::vector<double> p, bool merge) {
    // The final solve's steps can leave a switch it turned off a rounding
    // error above 0 (2e-15 in the measured case): such a lobe is off.
    for (std::size_t k = 0; k < model_.LobeCount(); ++k) {
      const std::vector<std::size_t> sw = SwitchSlots(model_, k);
      if (untouched_[k] && std::all_of(sw.begin(), sw.end(), [&](std::size_t q) { return std::abs(p[q]) < 1e-12; }))
        for (std::size_t q : sw) p[q] = 0;
    }
    const Engine plain(evaluators_, plain_options_, 1.0, base_);
    const std::size_t L = model_.LobeCount();
    const auto off = [&](const std::vector<double>& x) {
      std::size_t n = 0;
      for (std::size_t k = 0; k < L; ++k) n += untouched_[k] && SwitchedOff(1u << k, x);
      return n;
    };
    const auto alike = [&](const std::vector<double>& x) {
      const std::vector<std::pair<std::size_t, std::size_t>> pairs = ActivePairs(x);
      return std::any_of(pairs.begin(), pairs.end(), [&](const auto& ab) { return Alike(x, ab.first, ab.second); });
    };
    struct Seed {
      std::vector<double> p;
      bool at_once;      // given up after kPairLook unless below the level (a pair, a wide lobe)
      std::string what;  // for the trace and the origin
      std::vector<std::size_t> grow = {};  // switches the cost must fall along at the seed, else it is not solved
    };
    std::vector<Seed> seeds;
    // The seeds of the lobes switched off at point x (p, or p with two near
    // copies merged: `merged` names them, and the peak split, which would
    // give the pair back, is not made).
    const auto seeds_at = [&](const std::vector<double>& x, const std::string& merged) {
      const std::string suffix = merged.empty() ? "" : " beside " + merged + " merged";
      std::vector<std::string> done;  // lobes already split (copies give the same seeds)
      for (std::size_t k = 0; k < L; ++k) {
        const std::string& lobe = model_.LobeInfo(k).name;
        const std::ptrdiff_t ws = WidthSlot(model_, k);
        if (!untouched_[k] || ws < 0 || !SwitchedOff(1u << k, x) ||
            std::find(done.begin(), done.end(), lobe) != done.end())
          continue;
        // The narrowest active copy, and the widest one's width.
        std::ptrdiff_t c = -1;
        double widest = 0;
        for (std::size_t b = 0; b < L; ++b)
          if (b != k && untouched_[b] && model_.LobeInfo(b).name == lobe && !SwitchedOff(1u << b, x)) {
            const double wb = x[std::size_t(WidthSlot(model_, b))];
            if (c < 0 || wb < x[std::size_t(WidthSlot(model_, std::size_t(c)))]) c = std::ptrdiff_t(b);
            widest = std::max(widest, wb);
          }
        if (c < 0) continue;
        done.push_back(lobe);
        const std::vector<std::size_t> own = LobeSlots(model_, k), from = LobeSlots(model_, std::size_t(c)),
                                       sw = SwitchSlots(model_, k);
        const double wc = x[std::size_t(WidthSlot(model_, std::size_t(c)))];
        // x with lobe k a copy of active copy b, its switches kSplitShare of b's.
        const auto beside = [&](std::size_t b) {
          std::vector<double> y = x;
          const std::vector<std::size_t> at = LobeSlots(model_, b);
          for (std::size_t j = 0; j < own.size(); ++j)
            y[own[j]] = (std::find(sw.begin(), sw.end(), own[j]) != sw.end() ? kSplitShare : 1.0) * x[at[j]];
          return y;
        };
        // The Fresnel pair of Seeded at the copy's width.
        std::vector<double> pair = x;
        for (std::size_t j = 0; j < own.size(); ++j) pair[own[j]] = x[from[j]];
        const std::vector<std::size_t> low = ColourSlots(k, base_);
        for (std::size_t q : low) pair[q] = base_.lo[q];
        if (std::optional<std::vector<double>> seed = FresnelPair(plain, pair, k, std::size_t(c), low, base_, &x))
          seeds.push_back({std::move(*seed), true, "a Fresnel pair split off" + suffix});
        // A copy beside an active copy held at the upper bound of a switch:
        // the lobe takes that copy's parameters and a thousandth of its
        // switches; the cost falls along them (the bound holds the copy).
        for (std::size_t b = 0; b < L; ++b) {
          if (b == k || !untouched_[b] || model_.LobeInfo(b).name != lobe || SwitchedOff(1u << b, x)) continue;
          const std::vector<std::size_t> bsw = SwitchSlots(model_, b);
          if (std::none_of(bsw.begin(), bsw.end(), [&](std::size_t q) {
                return base_.free_of[q] >= 0 && x[q] >= base_.hi[q];
              }))
            continue;
          seeds.push_back({beside(b), true, "a copy split off beside one at its bound" + suffix});
          break;
        }
        const std::vector<double> widths = LobeStartWidths(std::size_t(ws), base_);
        if (widths.empty()) continue;
        // A wide lobe beside the active copies: the widest start width, if
        // above twice the widest copy's, the lobe's other parameters at their
        // defaults (a Schlick f0 of 1: no Fresnel shaping), its switch
        // kSplitShare of the copy's.
        if (widths.back() > 2 * widest) {
          std::vector<double> wide = x;
          const std::vector<double> defaults = model_.Info().Defaults();
          for (std::size_t q : own) wide[q] = std::clamp(defaults[q], base_.lo[q], base_.hi[q]);
          for (std::size_t j = 0; j < own.size(); ++j)
            if (std::find(sw.begin(), sw.end(), own[j]) != sw.end()) wide[own[j]] = kSplitShare * x[from[j]];
          wide[std::size_t(ws)] = widths.back();
          seeds.push_back({std::move(wide), true, "a wide lobe split off" + suffix, sw});
        }
        if (!merged.empty() || !(widths.front() < wc / 2)) continue;
        std::vector<double> peak = beside(std::size_t(c));
        peak[std::size_t(ws)] = widths.front();
        seeds.push_back({std::move(peak), false, "a peak split off"});
      }
    };
    seeds_at(p, "");
    // With `merge` (the final solve paused beside near copies) each two near
    // copies merged into one free a lobe for the seeds: on
    // hazy_red_dielectric under cbrt with three lobes the final solve creeps
    // beside two peak copies of alpha 0.030 (f0 0.01 and 0.8), where the
    // brute force's optimum holds one peak and a wide red lobe
    // (bench/RESULTS.md).
    if (merge)
      for (const auto& [a, b] : NearPairs(p)) seeds_at(Merged(p, a, b), model_.LobePrefix(a) + "+" + model_.LobePrefix(b));
    if (seeds.empty()) return std::nullopt;
    const std::string name = ActiveSpec(0);
    const double level = cost * (1 - kSplitGain);
    std::vector<std::pair<Candidate, std::string>> paid;  // and the stage of its solve
    for (const auto& [seed, at_once, what, grow] : seeds) {
      const std::string stage = name + ": " + what + " (all samples)";
      if (!grow.empty()) {
        // One Jacobian pass: a wide lobe whose switch the cost rises along
        // goes back off (measured: the one that paid fell along it).
        Eigen::MatrixXd jtj;
        Eigen::VectorXd g;
        NormalEquations(plain, full_, plain.ToInternal(seed), s_.chunk, jtj, g);
        if (std::none_of(grow.begin(), grow.end(), [&](std::size_t q) {
              const int j = base_.free_of[q];
              return j >= 0 && g[Eigen::Index(j)] < 0;
            }))
          continue;
      }
      const int look = at_once ? kPairLook : kSplitLook;
      Candidate c = Solve(plain, full_, seed, look, o_.function_tolerance, stage);
      if (!(c.cost < (at_once ? level : cost * (1 + kSplitAbove))) || Returned(c.p, p)) continue;
      c = Solve(plain, full_, c.p, kSplitIterations - look, o_.function_tolerance, stage);
      if (!(c.cost < level) || off(c.p) > off(p) || alike(c.p)) continue;
      c.origin = name + ": " + what + " after the final solve (all samples)";
      paid.emplace_back(std::move(c), stage);
    }
    // Where more than one split pays, each is solved to convergence before
    // one is kept: their costs after kSplitIterations do not order their
    // optima (hazy_red_dielectric under cosine: a copy beside the haze at
    // its bound 400,437 against a Fresnel pair's 400,379 after 12
    // iterations, 400,255 against 400,379 at convergence).
    std::optional<Candidate> better;
    for (auto& [c, stage] : paid) {
      if (paid.size() > 1) {
        std::string origin = std::move(c.origin);
        c = Solve(plain, full_, c.p, o_.max_iterations, o_.function_tolerance, stage);
        c.origin = std::move(origin);
      }
      s_.res.local_optima.push_back({c.cost, c.p, c.origin});
      if (!better || c.cost < better->cost) better = std::move(c);
    }
    return better;
  }

  // Whether a split's point x has returned to the fit's point p: as many
  // lobes switched off, and the active copies, taken in order of width,
  // within kSubsetSpread of p's in every parameter (relative for widths and
  // values above 1). Its solve then ends at the fit's optimum (measured: a
  // peak split on the outside material under cosine with three lobes, 7e-6
  // above the fit after 3 iterations with the copies swapped, 9 more
  // iterations and 3.2 s to return there, bench/RESULTS.md).
  bool Returned(const std::vector<double>& x, const std::vector<double>& p) const {
    const std::size_t L = model_.LobeCount();
    std::vector<double> a = OffLast(x), b = OffLast(p);
    unsigned mask = 0, mb = 0;
    for (std::size_t k = 0; k < L; ++k) {
      if (SwitchedOff(1u << k, a)) mask |= 1u << k;
      if (SwitchedOff(1u << k, b)) mb |= 1u << k;
    }
    if (mask != mb) return false;
    Canonical(a, mask);
    Canonical(b, mask);
    for (std::size_t k = 0; k < L; ++k) {
      if (mask >> k & 1u) continue;
      for (std::size_t q : LobeSlots(model_, k)) {
        const double d = log_scale_[q] ? std::abs(std::log(a[q] / b[q])) : std::abs(a[q] - b[q]);
        if (!(d <= kSubsetSpread * (log_scale_[q] ? 1.0 : std::max({1.0, std::abs(a[q]), std::abs(b[q])})))) return false;
      }
    }
    return true;
  }

  // Whether user parameters p are a point of a sub-sum among the nested
  // `kids`, whose own search covers its basin: one of the `active` lobes
  // switched off, or two active copies of a lobe alike in every parameter
  // but their switches (within 1e-3, relative for widths), which add up to
  // one lobe.
  bool InSubSum(const std::vector<double>& p, const std::vector<std::size_t>& active,
                const std::vector<std::pair<Candidate, std::size_t>>& kids) const {
    const auto has_kid = [&](std::size_t k) {
      return untouched_[k] && std::any_of(kids.begin(), kids.end(), [&](const auto& kid) {
               return model_.LobeInfo(kid.second).name == model_.LobeInfo(k).name;
             });
    };
    for (std::size_t a : active) {
      if (!has_kid(a)) continue;
      if (SwitchedOff(1u << a, p)) return true;
      for (std::size_t b : active)
        if (b > a && untouched_[b] && model_.LobeInfo(b).name == model_.LobeInfo(a).name && Alike(p, a, b))
          return true;
    }
    return false;
  }

  // Whether copies a and b of one lobe add up to one lobe in p: the same
  // parameters but for their switches (within 1e-3, relative for log-scale
  // parameters), and switches whose sums one copy's bounds hold. Two alike
  // copies whose weights add up beyond the bound are more than one lobe
  // (hazy_red_dielectric under cosine: two haze copies of weight 10 and
  // 8.65, bench/RESULTS.md).
  bool Alike(const std::vector<double>& p, std::size_t a, std::size_t b) const { return Close(p, a, b, 1e-3, true); }

  // Whether copies a and b of one lobe differ in p by less than `spread` in
  // their log-scale parameters (relative) and, with `linear`, in the rest
  // but their switches, and one copy's bounds hold the sums of their
  // switches.
  bool Close(const std::vector<double>& p, std::size_t a, std::size_t b, double spread, bool linear) const {
    const std::vector<std::size_t> qa = LobeSlots(model_, a), qb = LobeSlots(model_, b), sw = SwitchSlots(model_, a);
    for (std::size_t i = 0; i < qa.size(); ++i) {
      const double x = p[qa[i]], y = p[qb[i]];
      if (std::find(sw.begin(), sw.end(), qa[i]) != sw.end()) {
        if (!(x + y <= std::min(base_.hi[qa[i]], base_.hi[qb[i]]))) return false;
        continue;
      }
      if (!log_scale_[qa[i]] && !linear) continue;
      const double d = log_scale_[qa[i]] ? std::abs(std::log(x / y)) : std::abs(x - y);
      if (!(d < spread)) return false;
    }
    return true;
  }

  // The pairs (a < b) of active copies of one lobe in p, neither fixed,
  // tied nor bounded.
  std::vector<std::pair<std::size_t, std::size_t>> ActivePairs(const std::vector<double>& p) const {
    const std::size_t L = model_.LobeCount();
    std::vector<std::pair<std::size_t, std::size_t>> out;
    for (std::size_t a = 0; a < L; ++a)
      for (std::size_t b = a + 1; b < L; ++b)
        if (untouched_[a] && untouched_[b] && model_.LobeInfo(a).name == model_.LobeInfo(b).name &&
            !SwitchedOff(1u << a, p) && !SwitchedOff(1u << b, p))
          out.emplace_back(a, b);
    return out;
  }

  // The pairs of active copies of a lobe near each other in p (Near).
  std::vector<std::pair<std::size_t, std::size_t>> NearPairs(const std::vector<double>& p) const {
    std::vector<std::pair<std::size_t, std::size_t>> out = ActivePairs(p);
    std::erase_if(out, [&](const auto& ab) { return !Near(p, ab.first, ab.second); });
    return out;
  }

  // Whether active copies a and b of one lobe lie near each other in p:
  // widths within kMergeSpread (relative), and switches whose sums one
  // copy's bounds hold, so that Merged is a point of the sum. A lobe
  // without a width has no seeds to free (SplitPeak).
  bool Near(const std::vector<double>& p, std::size_t a, std::size_t b) const {
    return WidthSlot(model_, a) >= 0 && Close(p, a, b, kMergeSpread, false);
  }

  // p with copies a and b merged into a (Near): a's switches the sums of
  // both, its other parameters their means weighted by the switches
  // (geometric for log-scale ones), b switched off.
  std::vector<double> Merged(std::vector<double> p, std::size_t a, std::size_t b) const {
    const std::vector<std::size_t> qa = LobeSlots(model_, a), qb = LobeSlots(model_, b), sw = SwitchSlots(model_, a),
                                   swb = SwitchSlots(model_, b);
    double sa = 0, sb = 0;
    for (std::size_t q : sw) sa += p[q];
    for (std::size_t q : swb) sb += p[q];
    const double t = sb / (sa + sb);
    for (std::size_t i = 0; i < qa.size(); ++i) {
      double& x = p[qa[i]];
      const double y = p[qb[i]];
      if (std::find(sw.begin(), sw.end(), qa[i]) != sw.end())
        x += y;
      else
        x = log_scale_[qa[i]] ? std::exp((1 - t) * std::log(x) + t * std::log(y)) : (1 - t) * x + t * y;
    }
    for (std::size_t q : swb) p[q] = 0;
    return p;
  }

  // Cost of user parameters p on all samples, without a robust loss.
  double PlainFullCost(const std::vector<double>& p) const {
    const Engine plain(evaluators_, plain_options_, 1.0, base_);
    return FullCost(plain, p);
  }

 private:
  // Whether every lobe in `mask` is switched off in user parameters p.
  bool SwitchedOff(unsigned mask, const std::vector<double>& p) const {
    for (std::size_t k = 0; k < model_.LobeCount(); ++k)
      if (mask >> k & 1u)
        for (std::size_t q : SwitchSlots(model_, k))
          if (p[q] != 0) return false;
    return true;
  }

  std::string ActiveSpec(unsigned mask) const {
    std::string s;
    for (std::size_t k = 0; k < model_.LobeCount(); ++k)
      if (!(mask >> k & 1u)) s += (s.empty() ? "" : "+") + model_.LobePrefix(k);
    return s;
  }

  // The base layout with the lobes in `mask` switched off and the rest of
  // their parameters held (they have no effect).
  Layout LevelLayout(unsigned mask) const {
    Layout l = base_;
    for (std::size_t k = 0; k < model_.LobeCount(); ++k) {
      if (!(mask >> k & 1u)) continue;
      for (std::size_t q : LobeSlots(model_, k)) l.free_of[q] = -1;
      for (std::size_t q : SwitchSlots(model_, k)) l.value[q] = 0;
    }
    l.Renumber();
    return l;
  }

  // A contender refined: on large tables on the middle subset, costed on
  // all samples (the solve on all samples is the final solve's, or
  // RefineNested's), else on all samples. A refinement that ends higher on
  // all samples keeps c.
  Candidate Refine(const Engine& e, const Candidate& c, const std::string& name) {
    Candidate r;
    if (middle_) {
      r = Solve(e, *middle_, c.p, o_.max_iterations, kMiddleTolerance, MiddleStage(name, middle_->size()));
      if (std::isfinite(r.cost)) r.cost = FullCost(e, r.p);
      r.on_all = false;
    } else {
      r = Solve(e, full_, c.p, o_.max_iterations, o_.function_tolerance, name + ": refine (all samples)");
    }
    if (!(r.cost <= c.cost)) return c;
    r.nested = c.nested;
    r.origin = c.origin + (middle_ ? " refined on " + std::to_string(middle_->size()) + " samples" : " refined");
    return r;
  }

  // The finite candidates by cost, each unless it is within 1e-3 of a cheaper one (Contains).
  std::vector<Candidate> Distinct(const Engine& e, std::vector<Candidate> candidates) const {
    std::stable_sort(candidates.begin(), candidates.end(),
                     [](const Candidate& x, const Candidate& y) { return x.cost < y.cost; });
    std::vector<Candidate> out;
    for (Candidate& c : candidates)
      if (std::isfinite(c.cost) && !Contains(e, out, c.p)) out.push_back(std::move(c));
    return out;
  }

  // Whether p is one solution (SameSolution) with one in `set`.
  bool Contains(const Engine& e, const std::vector<Candidate>& set, const std::vector<double>& p) const {
    const std::vector<double> u = e.ToInternal(p);
    return std::any_of(set.begin(), set.end(), [&](const Candidate& c) { return SameSolution(u, e.ToInternal(c.p)); });
  }

  // User parameters p with the switched-off copies of each lobe (untouched
  // by fix/tie/bounds) after the switched-on ones, each group in its order:
  // the same function, in the sub-sums' labelling (the last copy off).
  std::vector<double> OffLast(std::vector<double> p) const {
    ReorderCopies(p, 0u, [&](std::size_t a, std::vector<std::vector<double>>& blocks) {
      // The switch slots of a copy, by their place among its slots.
      const std::vector<std::size_t> own = LobeSlots(model_, a);
      std::vector<std::size_t> places;
      for (std::size_t q : SwitchSlots(model_, a))
        places.push_back(std::size_t(std::find(own.begin(), own.end(), q) - own.begin()));
      std::stable_partition(blocks.begin(), blocks.end(), [&](const std::vector<double>& v) {
        return std::any_of(places.begin(), places.end(), [&](std::size_t i) { return v[i] != 0; });
      });
    });
    return p;
  }

  // Copies of one lobe, none touched by fix/tie/bounds, all active: sorted
  // by width so that the symmetric copies of a solution are one.
  void Canonical(std::vector<double>& p, unsigned mask) const {
    ReorderCopies(p, mask, [&](std::size_t a, std::vector<std::vector<double>>& blocks) {
      if (WidthSlot(model_, a) < 0) return;
      const std::size_t w = std::size_t(WidthSlot(model_, a)) - model_.LobeOffset(a);
      std::stable_sort(blocks.begin(), blocks.end(), [w](const auto& x, const auto& y) { return x[w] < y[w]; });
    });
  }

  // Each group of two or more interchangeable copies of one lobe (untouched
  // by fix/tie/bounds, not switched off by `mask`) in p: their parameter
  // blocks (LobeSlots), in lobe order, reordered by reorder(first lobe of
  // the group, blocks) and written back.
  template <class Reorder>
  void ReorderCopies(std::vector<double>& p, unsigned mask, Reorder reorder) const {
    const std::size_t L = model_.LobeCount();
    std::vector<bool> done(L, false);
    for (std::size_t a = 0; a < L; ++a) {
      if (done[a] || (mask >> a & 1u) || !untouched_[a]) continue;
      std::vector<std::size_t> group;
      for (std::size_t b = a; b < L; ++b)
        if (!(mask >> b & 1u) && untouched_[b] && model_.LobeInfo(b).name == model_.LobeInfo(a).name) {
          group.push_back(b);
          done[b] = true;
        }
      if (group.size() < 2) continue;
      std::vector<std::vector<double>> blocks;
      for (std::size_t k : group) {
        std::vector<double> v;
        for (std::size_t q : LobeSlots(model_, k)) v.push_back(p[q]);
        blocks.push_back(std::move(v));
      }
      reorder(a, blocks);
      for (std::size_t g = 0; g < group.size(); ++g) {
        const std::vector<std::size_t> slots = LobeSlots(model_, group[g]);
        for (std::size_t q = 0; q < slots.size(); ++q) p[slots[q]] = blocks[g][q];
      }
    }
  }

  // The grid starts of the level: interchangeable copies of one lobe (untouched,
  // active) start in increasing order of width.
  std::vector<std::vector<double>> GridStarts(const Layout& layout, unsigned mask) const {
    return fit::GridStarts(model_.Info(), layout, o_.starts_per_param, [&](std::size_t slot) {
      for (std::size_t k = 0; k < model_.LobeCount(); ++k)
        if (WidthSlot(model_, k) == std::ptrdiff_t(slot) && untouched_[k] && !(mask >> k & 1u))
          return model_.LobeInfo(k).name;
      return std::string();
    });
  }

  // The start widths of a lobe's width (packed slot ws) within layout's
  // bounds, spaced around the parameter's default.
  std::vector<double> LobeStartWidths(std::size_t ws, const Layout& layout) const {
    return StartWidths(layout, ws, model_.Info().Defaults()[ws], o_.starts_per_param);
  }

  // The sub-sum's optimum p (lobe k off) with lobe k switched back on at
  // each start width and at the width of each active copy of it (so that a
  // lobe can split in two), each with its other parameters at their
  // defaults and again with its linear colour parameters at their lower
  // bounds (a Schlick f0 of 0 leaves only the grazing term: with a copy at
  // f0 = 1 the pair shapes its own Fresnel curve); its switch scaled by
  // least squares to the residual the sub-sum leaves on the subset. At a
  // copy's width a third seed makes that pair outright: lobe k at the lower
  // bounds, the copy at the upper bounds of those parameters, and the two
  // switches scaled together by least squares.
  std::vector<std::vector<double>> Seeded(const Engine& e, const std::vector<double>& p, std::size_t k,
                                          const Layout& layout) const {
    const ModelInfo& info = model_.Info();
    const std::ptrdiff_t ws = WidthSlot(model_, k);
    std::vector<double> widths = {ws >= 0 ? p[std::size_t(ws)] : 0.0};
    std::vector<std::ptrdiff_t> copy_of(1, -1);  // the copy whose width widths[i] is; -1: a start width
    if (ws >= 0) {
      widths = LobeStartWidths(std::size_t(ws), layout);
      copy_of.assign(widths.size(), -1);
      for (std::size_t c = 0; c < model_.LobeCount(); ++c)
        if (c != k && model_.LobeInfo(c).name == model_.LobeInfo(k).name && WidthSlot(model_, c) >= 0 &&
            layout.free_of[std::size_t(WidthSlot(model_, c))] >= 0) {
          widths.push_back(std::clamp(p[std::size_t(WidthSlot(model_, c))], layout.lo[std::size_t(ws)],
                                      layout.hi[std::size_t(ws)]));
          copy_of.push_back(std::ptrdiff_t(c));
        }
    }
    const std::vector<std::size_t> sw = SwitchSlots(model_, k);
    const std::vector<double> defaults = info.Defaults();
    const std::vector<std::size_t> low = ColourSlots(k, layout);
    // The sub-sum's prediction and residual on the subset, the same for every seed.
    std::vector<Eigen::Array3d> base(subset_.size());
    for (std::size_t q = 0; q < subset_.size(); ++q) base[q] = e.Predict(p, subset_, q);
    std::vector<std::vector<double>> out;
    for (std::size_t w = 0; w < widths.size(); ++w)
      for (int variant = 0; variant < (low.empty() ? 1 : copy_of[w] >= 0 ? 3 : 2); ++variant) {
        std::vector<double> on = p;
        for (std::size_t q : LobeSlots(model_, k)) on[q] = defaults[q];
        if (ws >= 0) on[std::size_t(ws)] = widths[w];
        if (variant >= 1)
          for (std::size_t q : low) on[q] = layout.lo[q];
        if (variant == 2) {
          if (std::optional<std::vector<double>> pair = FresnelPair(e, on, k, std::size_t(copy_of[w]), low, layout))
            out.push_back(std::move(*pair));
          continue;
        }
        // Per channel for colour switches, one scale for a weight.
        Eigen::Array3d rg = Eigen::Array3d::Zero(), gg = Eigen::Array3d::Zero();
        for (std::size_t q = 0; q < subset_.size(); ++q) {
          const Eigen::Array3d g = e.Predict(on, subset_, q) - base[q], r = subset_.Reference(q) - base[q];
          rg += r * g;
          gg += g * g;
        }
        for (std::size_t q : sw) {
          const int c = channel_[q];  // -1: a weight, scaling all channels
          const double num = c < 0 ? rg.sum() : rg[c], den = c < 0 ? gg.sum() : gg[c];
          const double scale = den > 0 ? num / den : 0.0;
          // A small positive floor: at 0 the lobe's other parameters have no gradient.
          on[q] = std::clamp(on[q] * std::max(scale, 1e-3), layout.lo[q], layout.hi[q]);
        }
        out.push_back(std::move(on));
      }
    return out;
  }

  // Linear colour slots of lobe k, not switches, free, whose lower bound differs from the default.
  std::vector<std::size_t> ColourSlots(std::size_t k, const Layout& layout) const {
    const std::vector<std::size_t> sw = SwitchSlots(model_, k);
    const std::vector<double> defaults = model_.Info().Defaults();
    std::vector<std::size_t> low;
    for (std::size_t q : LobeSlots(model_, k))
      if (channel_[q] >= 0 && !log_scale_[q] && std::find(sw.begin(), sw.end(), q) == sw.end() &&
          layout.free_of[q] >= 0 && layout.leader[q] < 0 && layout.lo[q] != defaults[q])
        low.push_back(q);
    return low;
  }

  // The pair seed of Seeded: `on` with lobe k at its lower bounds (slots
  // `low`), copy c's matching slots at their upper bounds, and the two
  // lobes' switches scaled together by least squares to the residual of the
  // rest of the sum. With a point to `reproduce` (SplitPeak: the fit's,
  // where k is off and `on` holds c's parameters in k), channels c holds at
  // a bound stay there in both lobes, and the switches are scaled to
  // reproduce that point's prediction instead: with one channel shaped
  // (Schlick's f0 + (1 - f0) (1 - cos)^5 is linear in f0) the pair then
  // is the fit's own point, and any step from it gains.
  // Nothing when c's slots do not match k's, are not free, no channel is
  // shaped, or the lobes have no one weight each.
  std::optional<std::vector<double>> FresnelPair(const Engine& e, std::vector<double> on, std::size_t k, std::size_t c,
                                                 const std::vector<std::size_t>& low, const Layout& layout,
                                                 const std::vector<double>* reproduce = nullptr) const {
    const std::vector<std::size_t> sk = SwitchSlots(model_, k), sc = SwitchSlots(model_, c);
    if (sk.size() != 1 || sc.size() != 1 || channel_[sk[0]] >= 0) return std::nullopt;
    const std::size_t from_k = model_.LobeOffset(k), from_c = model_.LobeOffset(c);
    bool shaped = false;
    for (std::size_t q : low) {
      const std::size_t qc = q - from_k + from_c;
      if (layout.free_of[qc] < 0 || layout.leader[qc] >= 0) return std::nullopt;
      // A channel the copy holds at a bound wants a curve beyond the pair's
      // (flatter at the upper, steeper at the lower): lobe k joins the copy there.
      const double tol = 1e-9 * (layout.hi[qc] - layout.lo[qc]);
      if (reproduce && (on[qc] >= layout.hi[qc] - tol || on[qc] <= layout.lo[qc] + tol)) {
        on[q] = std::clamp(on[qc], layout.lo[q], layout.hi[q]);
        continue;
      }
      on[qc] = layout.hi[qc];
      shaped = true;
    }
    if (!shaped) return std::nullopt;
    // The prediction with both lobes off, and each lobe's part at its switch's value.
    std::vector<double> off = on;
    off[sk[0]] = off[sc[0]] = 0;
    std::vector<double> only_k = off, only_c = off;
    only_k[sk[0]] = on[sk[0]];
    only_c[sc[0]] = on[sc[0]];
    Eigen::Matrix2d a = Eigen::Matrix2d::Zero();
    Eigen::Vector2d b = Eigen::Vector2d::Zero();
    for (std::size_t q = 0; q < subset_.size(); ++q) {
      const Eigen::Array3d rest = e.Predict(off, subset_, q);
      const Eigen::Array3d gk = e.Predict(only_k, subset_, q) - rest, gc = e.Predict(only_c, subset_, q) - rest;
      const Eigen::Array3d r = (reproduce ? e.Predict(*reproduce, subset_, q) : subset_.Reference(q)) - rest;
      a(0, 0) += (gk * gk).sum();
      a(0, 1) += (gk * gc).sum();
      a(1, 1) += (gc * gc).sum();
      b(0) += (gk * r).sum();
      b(1) += (gc * r).sum();
    }
    a(1, 0) = a(0, 1);
    const Eigen::Vector2d scale = a.ldlt().solve(b);
    if (!scale.allFinite()) return std::nullopt;
    // A small positive floor: at 0 a lobe's other parameters have no gradient.
    on[sk[0]] = std::clamp(on[sk[0]] * std::max(scale(0), 1e-3), layout.lo[sk[0]], layout.hi[sk[0]]);
    on[sc[0]] = std::clamp(on[sc[0]] * std::max(scale(1), 1e-3), layout.lo[sc[0]], layout.hi[sc[0]]);
    return on;
  }

 private:
  // Cost of p on all samples.
  double FullCost(const Engine& e, const std::vector<double>& p) const { return CostOf(e, full_, e.ToInternal(p)); }

  // Solves from p over `d` for at most `iterations`; the solution is put in
  // canonical order. With a finite stop_above the solve stops where its
  // optimum is bounded above stop_above (SolveToEnd), and the candidate is
  // marked `bounded`.
  Candidate Solve(const Engine& e, const Prepared& d, const std::vector<double>& p, int iterations, double ftol,
                  const std::string& stage, double stop_above = std::numeric_limits<double>::infinity()) {
    std::vector<double> u = e.ToInternal(p);
    ClampToBounds(e, u);
    ceres::Solver::Summary summary;
    bool bounded = false;
    const auto solve = [&](const Engine& en, std::vector<double>& v, const NormalCache::Normal* from) {
      const Solved r = SolveStart(s_, en, d, v, iterations, ftol, stage, from, stop_above);
      summary = r.summary;
      bounded = r.bounded;
    };
    // Refinements (on all samples or the middle subset) hold the active
    // bounds: Ceres' bounded steps cost several Jacobian passes each (an l2
    // refinement on the middle subset took 2.3 s in 23 iterations).
    // A solve that holds parameters on their bounds bounds its gain with
    // them held; HoldingBounds takes its point for the whole problem's when
    // no held parameter is pulled inward there, else solves on without
    // holding them, and that solve's bound counts.
    if (&d != &subset_) HoldingBounds(evaluators_, plain_options_, 1.0, e, d, s_.chunk, u, solve);
    else solve(e, u, nullptr);
    Candidate c;
    if (!summary.IsSolutionUsable()) return c;
    c.p = e.ToUser(u);
    c.cost = summary.final_cost;
    c.bounded = bounded;
    unsigned mask = 0;
    for (std::size_t k = 0; k < model_.LobeCount(); ++k)
      for (std::size_t q : SwitchSlots(model_, k))
        if (e.layout().free_of[q] < 0 && e.layout().value[q] == 0 && untouched_[k]) mask |= 1u << k;
    Canonical(c.p, mask);
    return c;
  }

  const Model& model_;
  const ModelEvaluators evaluators_{model_};
  const FitState& s_;
  const Options& o_;
  Options plain_options_;
  const Layout& base_;
  const Prepared& full_;
  const Prepared& subset_;
  const Prepared* middle_;  // the middle-sized subset on large tables, else null
  std::vector<bool> untouched_;
  std::vector<int> channel_;  // packed slot -> channel of a colour parameter, else -1
  std::vector<bool> log_scale_;  // packed slot -> on a log scale
  std::map<unsigned, Candidate> memo_;
  std::vector<unsigned> top_kids_;  // the sub-sums with one lobe removed
};

// A fixed pseudo-random choice of `count` of the samples used (positions in
// s.full), so runs repeat.
std::vector<std::size_t> SubsetIndex(const FitState& s, std::size_t count) {
  const std::size_t n = s.full.size();
  std::vector<std::size_t> sub(std::min(n, count));
  std::iota(sub.begin(), sub.end(), std::size_t(0));
  if (n <= count) return sub;
  // The first `count` positions of a partial Fisher-Yates shuffle of 0 ..
  // n - 1; the entries it moved beyond them are kept in a map, not in an
  // array of all n (8.7 MB for a MERL file, faulted in on every call).
  std::unordered_map<std::size_t, std::size_t> moved;
  moved.reserve(count);
  std::mt19937_64 rng(20050620);
  for (std::size_t k = 0; k < count; ++k) {
    std::uniform_int_distribution<std::size_t> pick(k, n - 1);
    const std::size_t j = pick(rng);
    if (j < count) {
      std::swap(sub[k], sub[j]);
    } else {
      const auto it = moved.try_emplace(j, j).first;
      std::swap(sub[k], it->second);
    }
  }
  std::sort(sub.begin(), sub.end());
  return sub;
}

[[noreturn]] void NoFiniteStart(const FitState& s) {
  throw std::runtime_error("no starting point gave a finite residual for model '" + s.model.Info().name + "'");
}

// The local optimum with parameters p becomes the kept one (Result::kept),
// the list sorted by cost.
void Keep(const FitState& s, const std::vector<double>& p) {
  std::vector<LocalOptimum>& l = s.res.local_optima;
  std::stable_sort(l.begin(), l.end(), [](const LocalOptimum& a, const LocalOptimum& b) { return a.cost < b.cost; });
  for (std::size_t q = 0; q < l.size(); ++q)
    if (l[q].params == p) {
      s.res.kept = int(q);
      break;
    }
}

// Sums: nested sub-sums and the multi-start (StartSearch); the best of these
// local optima is kept. On large tables the sub-sums are checked once more
// after the final solve (StartSearch::RefineNested), and a lobe it left
// switched off is tried as the peak of a copy (StartSearch::SplitPeak).
Start SearchSum(const FitState& s, const Model& sum) {
  struct Search {
    Prepared subset, middle;
    std::optional<StartSearch> search;
  };
  auto state = std::make_shared<Search>();
  state->subset = Rows(s.full, SubsetIndex(s, s.o.start_subset));
  const bool large = LargeTable(s);
  if (large) state->middle = Rows(s.full, SubsetIndex(s, MiddleSize(s.o)));
  StartSearch& search = state->search.emplace(sum, s, state->subset, large ? &state->middle : nullptr);
  const Candidate best = search.Level(0, true);
  if (!std::isfinite(best.cost)) NoFiniteStart(s);
  Keep(s, best.p);
  Start start;
  start.u = s.plain.ToInternal(best.p);
  ClampToBounds(s.plain, start.u);
  if (large)
    start.after_final = [state, &s, kept = best.p](const std::vector<double>& p,
                                                   bool paused) -> std::optional<std::vector<double>> {
      StartSearch& after = *state->search;
      const double final_cost = after.PlainFullCost(p);
      std::optional<Candidate> better = after.RefineNested(final_cost, p, kept);
      // Then a lobe left switched off at the better point, split off a copy's peak.
      if (std::optional<Candidate> split = better ? after.SplitPeak(better->cost, better->p, paused)
                                                  : after.SplitPeak(final_cost, p, paused))
        better = std::move(split);
      Keep(s, better ? better->p : kept);
      if (!better) return std::nullopt;
      std::vector<double> u = s.plain.ToInternal(better->p);
      ClampToBounds(s.plain, u);
      return u;
    };
  // A final solve that creeps beside two near copies pauses for
  // after_final, which tries them merged (measured on hazy_red_dielectric
  // under cbrt with three lobes: 190 steps lowered the cost by 3.7e-5, the
  // merged copies' split 1.4e-4 more, bench/RESULTS.md).
  if (large) start.pause = [state](const std::vector<double>& p) { return !state->search->NearPairs(p).empty(); };
  return start;
}

// The independent search of Options::random_starts: points drawn at random
// (seed Options::seed) in the internal space, each solved to convergence on
// all samples (on large tables on the middle subset, costed on all); every
// distinct optimum is listed and the best one kept. Log-scale parameters are
// drawn log-uniformly within a factor 100 of the model's default, linear
// ones uniformly from their lower bound to three times the default's
// distance above it, both within the bounds.
Start RandomSearch(const FitState& s) {
  const Engine& e = s.plain;
  std::vector<double> lo, hi;
  Bounds(e.layout(), e.log_mask(), lo, hi);
  const std::vector<double> mid = e.ToInternal(s.model.Info().Defaults());
  std::vector<double> from(lo.size()), to(lo.size());
  for (std::size_t j = 0; j < lo.size(); ++j) {
    double a = e.log_mask()[j] ? mid[j] - std::log(100.0) : lo[j];
    double b = e.log_mask()[j] ? mid[j] + std::log(100.0) : lo[j] + 3 * (mid[j] - lo[j]);
    a = std::max(a, lo[j]);
    b = std::min(b, hi[j]);
    if (!(a < b)) {  // a default on a bound: the whole range
      a = lo[j];
      b = hi[j];
    }
    from[j] = a;
    to[j] = b;
  }
  std::optional<Prepared> middle;
  if (LargeTable(s)) middle = Rows(s.full, SubsetIndex(s, MiddleSize(s.o)));
  const Prepared& d = middle ? *middle : s.full;
  const std::string where = middle ? std::to_string(d.size()) + " samples" : "all samples";
  std::mt19937_64 rng(s.o.seed);
  std::vector<std::pair<double, std::vector<double>>> solved;  // cost on all samples, internal parameters
  for (int k = 1; k <= s.o.random_starts; ++k) {
    std::vector<double> u(lo.size());
    for (std::size_t j = 0; j < u.size(); ++j) u[j] = std::uniform_real_distribution<double>(from[j], to[j])(rng);
    const ceres::Solver::Summary summary = SolveStart(s, e, d, u, s.o.max_iterations, s.o.function_tolerance,
                                                      "random start " + std::to_string(k) + " (" + where + ")")
                                               .summary;
    if (!summary.IsSolutionUsable()) continue;
    const double cost = middle ? CostOf(e, s.full, u) : summary.final_cost;
    if (std::isfinite(cost)) solved.emplace_back(cost, std::move(u));
  }
  if (solved.empty()) NoFiniteStart(s);
  std::stable_sort(solved.begin(), solved.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
  std::vector<std::vector<double>> distinct;
  for (const auto& found : solved) {
    const std::vector<double>& u = found.second;
    if (std::any_of(distinct.begin(), distinct.end(), [&](const auto& v) { return SameSolution(u, v); })) continue;
    distinct.push_back(u);
    s.res.local_optima.push_back({found.first, e.ToUser(u), "random start"});
  }
  Keep(s, s.res.local_optima.front().params);
  return {solved.front().second, {}, {}};
}

// One lobe (or a model outside the registry): the grid starts, each solved
// on the subset, and the best of them.
std::vector<double> MultiStart(const FitState& s) {
  const Prepared subset = Rows(s.full, SubsetIndex(s, s.o.start_subset));
  const auto no_copies = [](std::size_t) { return std::string(); };
  std::vector<double> best_u;
  double best_cost = std::numeric_limits<double>::infinity();
  for (const std::vector<double>& p : GridStarts(s.model.Info(), s.layout, s.o.starts_per_param, no_copies)) {
    std::vector<double> u = s.plain.ToInternal(p);
    ClampToBounds(s.plain, u);
    const std::string stage = "start " + std::to_string(s.res.starts + 1) + " (subset)";
    const ceres::Solver::Summary summary = SolveStart(s, s.plain, subset, u, s.o.start_iterations, 1e-8, stage).summary;
    if (summary.IsSolutionUsable() && summary.final_cost < best_cost) {
      best_cost = summary.final_cost;
      best_u = u;
    }
  }
  if (best_u.empty()) NoFiniteStart(s);
  return best_u;
}

// Coarse to fine (LargeTable) for one lobe: the best start refined on the middle subset.
void RefineOnMiddle(const FitState& s, std::vector<double>& best_u) {
  const Prepared middle = Rows(s.full, SubsetIndex(s, MiddleSize(s.o)));
  std::vector<double> u = best_u;
  const ceres::Solver::Summary summary =
      SolveStart(s, s.plain, middle, u, s.o.max_iterations, kMiddleTolerance, MiddleStage("", middle.size())).summary;
  if (summary.IsSolutionUsable()) best_u = u;
}

}  // namespace

Start StartingPoint(const FitState& s) {
  const Options& o = s.o;
  if (!o.initial.empty()) {
    const ModelInfo& info = s.model.Info();
    if (o.initial.size() != info.PackedSize())
      throw std::invalid_argument("initial guess has " + std::to_string(o.initial.size()) + " values, model '" +
                                  info.name + "' needs " + std::to_string(info.PackedSize()));
    std::vector<double> u = s.plain.ToInternal(o.initial);
    ClampToBounds(s.plain, u);
    s.res.starts = 1;
    return {u, {}, {}};
  }
  if (o.random_starts > 0) return RandomSearch(s);
  // Only a registered model's sum has lobes to switch off and add back.
  const Model* sum = s.model.AsModel();
  if (sum && sum->LobeCount() >= 2) return SearchSum(s, *sum);
  std::vector<double> u = MultiStart(s);
  if (LargeTable(s)) RefineOnMiddle(s, u);
  return {u, {}, {}};
}

}  // namespace brdfkit::fit
