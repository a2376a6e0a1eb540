#include "validate/stress.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <set>
#include <sstream>

#include "brdf/params.h"
#include "validate/albedo.h"
#include "validate/integrators.h"
#include "validate/jet_models.h"

namespace brdfkit::validate {
namespace {

// Derivatives are seeded in chunks of this many packed parameters (a size
// compiled once, validate/jet_models.h).
constexpr int kJetSize = 8;
using Jet = JetN<kJetSize>;

struct Point {
  std::vector<double> p;
  std::string label;
};

void SetParam(const ModelInfo& info, std::size_t i, double v, std::vector<double>& p) {
  const std::size_t off = info.Offset(i);
  for (int c = 0; c < (info.params[i].colour ? 3 : 1); ++c) p[off + c] = v;
}

// Sweep values of one parameter: every decade of a log-scale range, the ends
// and middle of a linear one.
std::vector<double> SweepValues(const ParamInfo& pi) {
  std::set<double> v = {pi.lower, pi.upper};
  if (pi.scale == ParamInfo::Scale::kLog && pi.lower > 0) {
    for (int e = int(std::ceil(std::log10(pi.lower))); e <= int(std::floor(std::log10(pi.upper))); ++e)
      v.insert(std::pow(10.0, e));
  } else {
    v.insert(0.5 * (pi.lower + pi.upper));
  }
  return {v.begin(), v.end()};
}

double Clip(const ParamInfo& pi, double v) { return std::clamp(v, pi.lower, pi.upper); }

bool EndsWith(const std::string& s, const std::string& tail) {
  return s.size() >= tail.size() && s.compare(s.size() - tail.size(), tail.size(), tail) == 0;
}

std::vector<Point> ParameterPoints(const ModelInfo& info) {
  const std::vector<double> defaults = info.Defaults();
  std::vector<Point> out;
  std::set<std::vector<double>> seen;
  auto add = [&](std::vector<double> p) {
    if (seen.insert(p).second) out.push_back({p, FormatParams(info, p)});
  };
  add(defaults);
  const std::size_t n = info.params.size();
  for (std::size_t i = 0; i < n; ++i)
    for (double v : SweepValues(info.params[i])) {
      std::vector<double> p = defaults;
      SetParam(info, i, v, p);
      add(p);
    }
  // Every log-scale parameter at one end together.
  for (int end = 0; end < 2; ++end) {
    std::vector<double> p = defaults;
    for (std::size_t i = 0; i < n; ++i)
      if (info.params[i].scale == ParamInfo::Scale::kLog)
        SetParam(info, i, end ? info.params[i].upper : info.params[i].lower, p);
    add(p);
  }
  // Anisotropic pairs: ratio 1e4 both ways at each end of the range.
  for (std::size_t i = 0; i < n; ++i)
    for (std::size_t j = 0; j < n; ++j) {
      const std::string& a = info.params[i].name;
      const std::string& b = info.params[j].name;
      const bool pair = (EndsWith(a, "_x") && EndsWith(b, "_y") && a.substr(0, a.size() - 2) == b.substr(0, b.size() - 2)) ||
                        (a == "nu" && b == "nv");
      if (!pair) continue;
      const ParamInfo &pa = info.params[i], &pb = info.params[j];
      const double lo = std::max(pa.lower, pb.lower), hi = std::min(pa.upper, pb.upper);
      for (auto [x, y] : {std::pair{lo, lo * 1e4}, std::pair{hi, hi * 1e-4}}) {
        std::vector<double> p = defaults;
        SetParam(info, i, Clip(pa, x), p);
        SetParam(info, j, Clip(pb, y), p);
        add(p);
        SetParam(info, i, Clip(pa, y), p);
        SetParam(info, j, Clip(pb, x), p);
        add(p);
      }
    }
  // Conductor: eta and k together.
  std::size_t eta = n, k = n;
  for (std::size_t i = 0; i < n; ++i) {
    if (info.params[i].name == "eta") eta = i;
    if (info.params[i].name == "k") k = i;
  }
  if (eta < n && k < n) {
    const ParamInfo &pe = info.params[eta], &pk = info.params[k];
    for (double e : {pe.lower, Clip(pe, 0.2), Clip(pe, 1.0), pe.upper})
      for (double kv : {pk.lower, Clip(pk, 3.0), pk.upper})
        for (int sharp = 0; sharp < 2; ++sharp) {
          std::vector<double> p = defaults;
          SetParam(info, eta, e, p);
          SetParam(info, k, kv, p);
          if (sharp)
            for (std::size_t i = 0; i < n; ++i)
              if (info.params[i].scale == ParamInfo::Scale::kLog) SetParam(info, i, info.params[i].lower, p);
          add(p);
        }
  }
  return out;
}

// Test directions (double); duplicates of the normal removed.
std::vector<Eigen::Vector3d> Directions() {
  const double mus[] = {1, 0.9, 0.5, 0.1, 1e-3, 1e-6, 1e-12, 0, -1e-6, -0.5};
  const double phis[] = {0, 2.1, kPi, 2.1 + kPi};
  std::vector<Eigen::Vector3d> out;
  for (double mu : mus)
    for (double phi : phis) {
      if (mu == 1 && phi != 0) continue;
      const double s = std::sqrt(std::max(0.0, 1 - mu * mu));
      // Exact components at phi = 0 and pi (tangential mirror pairs).
      const double c = phi == 0 ? 1.0 : phi == kPi ? -1.0 : std::cos(phi);
      const double sn = (phi == 0 || phi == kPi) ? 0.0 : std::sin(phi);
      out.emplace_back(s * c, s * sn, mu);
    }
  return out;
}

std::string Vec(const Eigen::Vector3d& v) {
  char b[96];
  std::snprintf(b, sizeof b, "(%.17g, %.17g, %.17g)", v.x(), v.y(), v.z());
  return b;
}

template <typename T>
Vec3<T> Cast(const Eigen::Vector3d& v) {
  return Vec3<T>(T(v.x()), T(v.y()), T(v.z()));
}

template <typename T>
bool Finite(const T& x) {
  if constexpr (std::is_same_v<T, Jet>) return std::isfinite(x.a);
  else return std::isfinite(x);
}

double RelDiff(double a, double b, double floor) {
  const double d = std::abs(a - b);
  if (d == 0) return 0;
  return d / std::max({std::abs(a), std::abs(b), floor});
}

// Evaluates one model in scalar type T over every point and direction pair.
template <typename T>
void Sweep(const Model& model, const std::vector<Point>& points, const std::vector<Eigen::Vector3d>& dirs,
           StressRow& row) {
  const ModelInfo& info = model.Info();
  const std::unique_ptr<Bxdf<T>> b = model.Make<T>();
  const std::unique_ptr<Bxdf<double>> bd = std::is_same_v<T, float> ? model.Make<double>() : nullptr;
  const std::size_t n = info.PackedSize();
  const std::size_t m = dirs.size();
  // A transmitting model scatters to both sides: only the horizon itself
  // must give zero, and reciprocity is the generalised one.
  const bool sphere = (b->Kind() & LobeKind::kTransmission) != 0;
  std::vector<Vec3<T>> dt(m);
  std::vector<Eigen::Vector3d> dd(m);  // the directions as T rounds them
  for (std::size_t k = 0; k < m; ++k) {
    dt[k] = Cast<T>(dirs[k]);
    dd[k] = Eigen::Vector3d(Value(dt[k].x()), Value(dt[k].y()), Value(dt[k].z()));
  }
  std::vector<Eigen::Array3d> f(m * m);
  auto fail = [&](const Point& pt, const std::string& what, std::size_t i, std::size_t o, const Eigen::Array3d& v) {
    if (!row.first_failure.empty()) return;
    std::ostringstream s;
    s.precision(17);
    s << what << " at " << pt.label << " wi=" << Vec(dd[i]) << " wo=" << Vec(dd[o]) << " f=(" << v[0] << ", " << v[1]
      << ", " << v[2] << ")";
    row.first_failure = s.str();
  };
  for (const Point& pt : points) {
    // Parameters as T rounds them (float: the values a float renderer holds).
    std::vector<T> p(n);
    std::vector<double> pd(n);
    for (std::size_t k = 0; k < n; ++k) {
      p[k] = T(pt.p[k]);
      pd[k] = Value(p[k]);
    }
    const std::size_t chunks = std::is_same_v<T, Jet> ? (n + kJetSize - 1) / kJetSize : 1;
    for (std::size_t chunk = 0; chunk < chunks; ++chunk) {
      if constexpr (std::is_same_v<T, Jet>)
        for (std::size_t k = 0; k < n; ++k)
          p[k] = k / kJetSize == chunk ? Jet(pt.p[k], int(k % kJetSize)) : Jet(pt.p[k]);
      for (std::size_t i = 0; i < m; ++i)
        for (std::size_t o = 0; o < m; ++o) {
          const Rgb<T> v = b->Eval(p.data(), dt[i], dt[o]);
          Eigen::Array3d vd;
          for (int c = 0; c < 3; ++c) vd[c] = Value(v[c]);
          if constexpr (std::is_same_v<T, Jet>) {
            for (int c = 0; c < 3; ++c)
              if (std::isfinite(v[c].a) && !v[c].v.allFinite()) {
                ++row.nonfinite_derivative_count;
                fail(pt, "non-finite derivative", i, o, vd);
              }
          }
          if (chunk > 0) continue;
          ++row.evaluations;
          f[i * m + o] = vd;
          for (int c = 0; c < 3; ++c) {
            if (!std::isfinite(vd[c])) {
              ++row.nonfinite_count;
              fail(pt, "non-finite value", i, o, vd);
            } else if (vd[c] < 0) {
              ++row.negative_count;
              fail(pt, "negative value", i, o, vd);
            } else if (vd[c] != 0 && (sphere ? dd[i].z() == 0 || dd[o].z() == 0 : !(dd[i].z() > 0 && dd[o].z() > 0))) {
              ++row.horizon_nonzero_count;
              fail(pt, "non-zero value at or below the horizon", i, o, vd);
            }
          }
          if constexpr (std::is_same_v<T, float>) {
            const Eigen::Array3d ref = bd->Eval(pd.data(), dd[i], dd[o]);
            for (int c = 0; c < 3; ++c) {
              if (!std::isfinite(vd[c]) || !std::isfinite(ref[c])) continue;
              const double r = RelDiff(vd[c], ref[c], kStressValueFloor);
              if (r > row.float_double_max_rel_diff) {
                row.float_double_max_rel_diff = r;
                std::ostringstream s;
                s.precision(9);
                s << pt.label << " wi=" << Vec(dd[i]) << " wo=" << Vec(dd[o]) << " float " << vd[c] << " double "
                  << ref[c];
                row.worst_float_case = s.str();
              }
            }
          }
        }
    }
    if (info.reciprocal || sphere)
      for (std::size_t i = 0; i < m; ++i)
        for (std::size_t o = i + 1; o < m; ++o)
          for (int c = 0; c < 3; ++c) {
            // f(wi, wo) eta_r^2 = f(wo, wi) (eta_r = 1 for a reflection model).
            const double eta_r = sphere ? double(Value(b->RelativeIndex(p.data(), dt[i], dt[o]))) : 1.0;
            const double a = f[i * m + o][c] * eta_r * eta_r, r = f[o * m + i][c];
            if (std::isfinite(a) && std::isfinite(r))
              row.reciprocity_max_rel_error = std::max(row.reciprocity_max_rel_error, RelDiff(a, r, kStressValueFloor));
          }
    // Sampling and pdf at every wo (models that sample).
    if constexpr (!std::is_same_v<T, Jet>) {
      const double tol = std::is_same_v<T, float> ? 1e-4 : 1e-10;
      for (std::size_t o = 0; o < m && b->CanSample(); ++o) {
        for (double u1 : {0.0, 1e-12, 0.5, 1.0 - 1e-16})
          for (double u2 : {0.0, 0.5, 1.0 - 1e-16}) {
            const BsdfSample<T> s = b->Sample(p.data(), dt[o], u1, u2);
            if (!s.valid) continue;
            const double pdf = Value(s.pdf);
            const double len = std::sqrt(double(Value(s.wi.squaredNorm())));
            if (!std::isfinite(pdf) || pdf < 0 || !(std::abs(len - 1) <= tol)) {
              ++row.sample_failures;
              fail(pt, "bad sample (pdf " + std::to_string(pdf) + ", |wi| " + std::to_string(len) + ")", o, o,
                   Eigen::Array3d::Zero());
            }
          }
        for (std::size_t i = 0; i < m; ++i) {
          const double pdf = Value(b->Pdf(p.data(), dt[o], dt[i]));
          if (!std::isfinite(pdf) || pdf < 0) {
            ++row.sample_failures;
            fail(pt, "bad pdf " + std::to_string(pdf), i, o, Eigen::Array3d::Zero());
          }
        }
      }
    }
  }
}

// Values one ulp past each bound, and NaN, must be rejected.
void CheckBounds(const ModelInfo& info, StressRow& row) {
  const std::vector<double> defaults = info.Defaults();
  for (std::size_t i = 0; i < info.params.size(); ++i) {
    const ParamInfo& pi = info.params[i];
    for (double v : {std::nextafter(pi.lower, -std::numeric_limits<double>::infinity()),
                     std::nextafter(pi.upper, std::numeric_limits<double>::infinity()),
                     std::numeric_limits<double>::quiet_NaN()}) {
      std::vector<double> p = defaults;
      p[info.Offset(i)] = v;
      ++row.bound_checks;
      try {
        ValidateParams(info, p);
        ++row.bound_failures;
        if (row.first_failure.empty())
          row.first_failure = "accepted " + pi.name + " = " + FormatDouble(v) + " outside [" +
                              FormatDouble(pi.lower) + ", " + FormatDouble(pi.upper) + "]";
      } catch (const ModelError&) {
      }
      // The same value as text, as a user gives it.
      if (std::isnan(v)) continue;
      ++row.bound_checks;
      try {
        ParseParams(info, pi.name + "=" + FormatDouble(v));
        ++row.bound_failures;
      } catch (const ModelError&) {
      }
    }
  }
}

}  // namespace

std::vector<StressRow> RunStress(const StressOptions& options) {
  std::vector<std::string> names = options.models;
  if (names.empty())
    for (const ModelInfo& i : RegisteredModelInfos()) names.push_back(i.name);
  const std::vector<Eigen::Vector3d> dirs = Directions();
  std::vector<StressRow> rows;
  for (const std::string& name : names) {
    Settings settings;
    for (const auto& [n, s] : options.settings)
      if (n == name) settings = s;
    StressRow base;
    base.model = name;
    Model model;
    try {
      model = Model::Parse(name, settings);
    } catch (const ModelError& e) {
      // Unknown names are the caller's error; a model that needs a file is skipped.
      bool registered = false;
      for (const ModelInfo& i : RegisteredModelInfos()) registered = registered || i.name == name;
      if (!registered) throw;
      base.skipped = true;
      base.skip_reason = e.what();
      for (const char* type : {"float", "double", "jet"}) {
        base.type = type;
        rows.push_back(base);
      }
      continue;
    }
    CheckBounds(model.Info(), base);
    const std::vector<Point> points = ParameterPoints(model.Info());
    StressRow rf = base, rd = base, rj = base;
    rf.type = "float";
    rd.type = "double";
    rj.type = "jet";
    Sweep<float>(model, points, dirs, rf);
    Sweep<double>(model, points, dirs, rd);
    Sweep<Jet>(model, points, dirs, rj);
    rows.push_back(rf);
    rows.push_back(rd);
    rows.push_back(rj);
  }
  return rows;
}

}  // namespace brdfkit::validate

namespace brdfkit::validate {

std::vector<StiffIntegral> RunStiffIntegrals() {
  struct Case {
    const char* model;
    const char* params;
  };
  const Case cases[] = {{"ggx", "alpha=1e-4"}, {"beckmann", "alpha=1e-4"}, {"ggx_aniso", "alpha_x=1e-4,alpha_y=1e-2"}};
  std::vector<StiffIntegral> out;
  for (const Case& c : cases) {
    bool registered = false;
    for (const ModelInfo& i : RegisteredModelInfos()) registered = registered || i.name == c.model;
    if (!registered) continue;
    const auto t0 = std::chrono::steady_clock::now();
    const Model model = Model::Parse(c.model);
    const std::vector<double> p = ParseParams(model.Info(), c.params);
    const std::unique_ptr<Bxdf<double>> b = model.Make<double>();
    StiffIntegral r;
    r.model = c.model;
    r.params = c.params;
    r.mu = 1e-6;
    const Eigen::Vector3d wo(std::sqrt(1 - r.mu * r.mu), 0, r.mu);
    const AlbedoValue a = AlbedoAtMu(*b, p.data(), r.mu, EstimateLobeShape(*b, p.data()));
    r.value = a.value[1];
    r.error = a.error[1];
    r.evals = a.evals;
    // The independent reference: scrambled Sobol' points through the model's
    // own visible-normal sampling, whose weights stay bounded at grazing.
    IntegrateOptions io;
    io.budget = 1 << 20;
    const Estimate e = DirectionalAlbedo(*b, p.data(), wo, Method::kSobol, io);
    r.reference = e.value[1];
    r.reference_error = e.error[1];
    r.reference_evals = e.evals;
    r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    r.finite = std::isfinite(r.value) && std::isfinite(r.error) && std::isfinite(r.reference);
    r.agree = r.finite && std::abs(r.value - r.reference) <= 3 * (r.error + r.reference_error) + 1e-9;
    out.push_back(r);
  }
  return out;
}

}  // namespace brdfkit::validate
