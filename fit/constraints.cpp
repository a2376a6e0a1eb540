// Fixed, tied and bounded parameters: which packed slots the optimiser moves.
#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <utility>

#include "brdf/params.h"
#include "fit/fit_internal.h"

namespace brdfkit::fit {

std::vector<std::string> PackedNames(const ModelInfo& info) {
  std::vector<std::string> out;
  static const char* kChannel[3] = {"r", "g", "b"};
  for (const ParamInfo& p : info.params) {
    if (p.colour)
      for (int c = 0; c < 3; ++c) out.push_back(p.name + "." + kChannel[c]);
    else
      out.push_back(p.name);
  }
  return out;
}

void Layout::Renumber() {
  const std::size_t n = free_of.size();
  std::vector<int> fresh(n, -1);
  rep.clear();
  for (std::size_t k = 0; k < n; ++k) {
    if (free_of[k] < 0) continue;
    const int l = leader[k] >= 0 ? leader[k] : int(k);
    if (leader[k] >= 0 && free_of[std::size_t(l)] < 0) {
      free_of[k] = -1;  // follows a fixed parameter: fixed too
      continue;
    }
    if (std::size_t(l) == k) {
      fresh[k] = int(rep.size());
      rep.push_back(k);
    }
  }
  for (std::size_t k = 0; k < n; ++k)
    if (free_of[k] >= 0) free_of[k] = fresh[std::size_t(leader[k] >= 0 ? leader[k] : int(k))];
}

Layout AllFree(const ModelInfo& info) {
  Layout l;
  const std::size_t n = info.PackedSize();
  l.free_of.assign(n, 0);
  l.value = info.Defaults();
  l.leader.assign(n, -1);
  for (const ParamInfo& p : info.params)
    for (int c = 0; c < (p.colour ? 3 : 1); ++c) {
      l.lo.push_back(p.lower);
      l.hi.push_back(p.upper);
    }
  l.Renumber();
  return l;
}

namespace {

std::size_t FindParam(const ModelInfo& info, const std::string& option, const std::string& name) {
  for (std::size_t i = 0; i < info.params.size(); ++i)
    if (info.params[i].name == name) return i;
  std::string known;
  std::vector<KnownName> names;
  for (const ParamInfo& p : info.params) {
    known += (known.empty() ? "" : ", ") + p.name;
    names.push_back({p.name, p.meaning});
  }
  throw std::invalid_argument(option + ": unknown parameter '" + name + "' for model '" + info.name +
                              "' (parameters: " + (known.empty() ? "none" : known) + ")" + DidYouMean(name, names));
}

std::vector<std::pair<std::string, std::string>> Assignments(const std::string& option, const std::string& text) {
  try {
    return SplitAssignments(text);
  } catch (const ModelError& e) {
    throw std::invalid_argument(option + ": " + e.what());
  }
}

std::string Range(double lo, double hi) { return "[" + FormatDouble(lo) + ", " + FormatDouble(hi) + "]"; }

}  // namespace

Layout MakeLayout(const ModelInfo& info, const Options& o) {
  Layout l = AllFree(info);
  const std::size_t np = info.params.size();
  std::vector<bool> fixed(np, false), bounded(np, false);
  std::vector<int> tied(np, -1);
  for (const auto& [name, value] : Assignments("fix", o.fix)) {
    const std::size_t i = FindParam(info, "fix", name);
    if (fixed[i]) throw std::invalid_argument("fix: '" + name + "' is fixed twice");
    std::vector<double> packed;
    try {
      packed = ParseParams(info, name + "=" + value);
    } catch (const ModelError& e) {
      throw std::invalid_argument(std::string("fix: ") + e.what());
    }
    const std::size_t off = info.Offset(i);
    for (int c = 0; c < (info.params[i].colour ? 3 : 1); ++c) {
      l.free_of[off + c] = -1;
      l.value[off + c] = packed[off + c];
    }
    fixed[i] = true;
  }
  for (const auto& [name, value] : Assignments("bounds", o.bounds)) {
    const std::size_t i = FindParam(info, "bounds", name);
    const ParamInfo& p = info.params[i];
    if (fixed[i]) throw std::invalid_argument("bounds: '" + name + "' is fixed; give it a value or bounds, not both");
    if (bounded[i]) throw std::invalid_argument("bounds: '" + name + "' is bounded twice");
    const std::size_t colon = value.find(':');
    double lo = 0, hi = 0;
    if (colon == std::string::npos || !ParseDouble(value.substr(0, colon), lo) ||
        !ParseDouble(value.substr(colon + 1), hi) || !std::isfinite(lo) || !std::isfinite(hi))
      throw std::invalid_argument("bounds: '" + name + "=" + value + "': expected lo:hi (two numbers)");
    if (lo > hi)
      throw std::invalid_argument("bounds: '" + name + "' = " + Range(lo, hi) + " is inverted (lo above hi)");
    if (lo == hi)
      throw std::invalid_argument("bounds: '" + name + "' = " + Range(lo, hi) + " is empty (to hold it, use fix)");
    if (lo < p.lower || hi > p.upper)
      throw std::invalid_argument("bounds: '" + name + "' = " + Range(lo, hi) + " reaches outside its range " +
                                  Range(p.lower, p.upper));
    const std::size_t off = info.Offset(i);
    for (int c = 0; c < (p.colour ? 3 : 1); ++c) {
      l.lo[off + c] = lo;
      l.hi[off + c] = hi;
    }
    bounded[i] = true;
  }
  const auto kind = [](const ParamInfo& p) {
    return std::string(p.colour ? "a colour (r:g:b)" : "a scalar") +
           (p.scale == ParamInfo::Scale::kLog ? " on a log scale (a width or exponent)" : " on a linear scale");
  };
  for (const auto& [name, value] : Assignments("tie", o.tie)) {
    const std::size_t i = FindParam(info, "tie", name);
    const std::size_t j = FindParam(info, "tie", value);
    if (tied[i] >= 0) throw std::invalid_argument("tie: '" + name + "' is tied twice");
    if (fixed[i]) throw std::invalid_argument("tie: '" + name + "' is both fixed and tied");
    if (bounded[i])
      throw std::invalid_argument("tie: '" + name + "' has bounds of its own; bound '" + value +
                                  "', the parameter it follows");
    const ParamInfo &a = info.params[i], &b = info.params[j];
    if (a.colour != b.colour || a.scale != b.scale)
      throw std::invalid_argument("tie: '" + name + "' (" + kind(a) + ") and '" + value + "' (" + kind(b) +
                                  ") are parameters of different kinds");
    tied[i] = int(j);
  }
  for (std::size_t i = 0; i < np; ++i) {
    if (tied[i] < 0) continue;
    std::vector<std::size_t> path = {i};
    for (int k = tied[i]; k >= 0; k = tied[std::size_t(k)]) {
      if (std::find(path.begin(), path.end(), std::size_t(k)) != path.end()) {
        std::string cycle;
        for (std::size_t q : path) cycle += info.params[q].name + " -> ";
        throw std::invalid_argument("tie: the ties form a cycle (" + cycle + info.params[std::size_t(k)].name + ")");
      }
      path.push_back(std::size_t(k));
    }
    const std::size_t root = path.back();
    for (int c = 0; c < (info.params[i].colour ? 3 : 1); ++c)
      l.leader[info.Offset(i) + c] = int(info.Offset(root) + c);
  }
  l.Renumber();
  for (std::size_t i = 0; i < np; ++i) {
    if (tied[i] < 0) continue;
    const std::size_t off = info.Offset(i);
    for (int c = 0; c < (info.params[i].colour ? 3 : 1); ++c) {
      const std::size_t k = off + c, lead = std::size_t(l.leader[k]);
      const std::string follows = "tie: '" + info.params[i].name + "' follows '" + info.params[tied[i] >= 0 ? std::size_t(tied[i]) : i].name + "'";
      if (l.free_of[k] < 0) {
        l.value[k] = l.value[lead];
        if (l.value[k] < l.lo[k] || l.value[k] > l.hi[k])
          throw std::invalid_argument(follows + ", fixed at " + FormatDouble(l.value[k]) + ", outside its range " +
                                      Range(l.lo[k], l.hi[k]));
      } else if (std::max(l.lo[k], l.lo[lead]) >= std::min(l.hi[k], l.hi[lead])) {
        throw std::invalid_argument(follows + ": their ranges " + Range(l.lo[k], l.hi[k]) + " and " +
                                    Range(l.lo[lead], l.hi[lead]) + " leave nothing to fit");
      }
    }
  }
  if (l.Free() == 0)
    throw std::invalid_argument("fix: nothing left to fit in model '" + info.name +
                                "': every parameter is fixed or tied to a fixed one");
  return l;
}

void CheckConstraints(const ModelInfo& info, const Options& options) { MakeLayout(info, options); }

}  // namespace brdfkit::fit
