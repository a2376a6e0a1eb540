#include "fit/fit.h"

#include <ceres/ceres.h>

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <map>
#include <numeric>
#include <random>
#include <sstream>
#include <stdexcept>

#include <tbb/blocked_range.h>
#include <tbb/info.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>
#include <tbb/task_arena.h>

#include "brdf/astm.h"
#include "brdf/merl.h"
#include "brdf/params.h"
#include "brdf/rgl.h"
#include "brdf/utia.h"
#include "data_synth/forward_model.h"
#include "data_synth/instrument.h"
#include "data_synth/table_io.h"
#include "fit/jet_models.h"

namespace brdfkit::fit {

// ---------------------------------------------------------------------------
// Names.

namespace {
// "a, b, c or d" of every name of an enumeration.
template <typename E, typename NameOf>
std::string Expected(const std::vector<E>& all, NameOf name_of) {
  std::string s;
  for (std::size_t i = 0; i < all.size(); ++i)
    s += (i == 0 ? "" : i + 1 == all.size() ? " or " : ", ") + name_of(all[i]);
  return s;
}
}  // namespace

const std::vector<Metric>& AllMetrics() {
  static const std::vector<Metric> kAll = {Metric::kL2, Metric::kRelative, Metric::kCosine, Metric::kLog,
                                           Metric::kCbrt};
  return kAll;
}

Metric ParseMetric(const std::string& name) {
  for (Metric m : AllMetrics())
    if (name == MetricName(m)) return m;
  throw std::invalid_argument("unknown metric '" + name + "' (expected " + Expected(AllMetrics(), MetricName) + ")");
}

std::string MetricName(Metric m) {
  switch (m) {
    case Metric::kL2: return "l2";
    case Metric::kRelative: return "relative";
    case Metric::kCosine: return "cosine";
    case Metric::kLog: return "log";
    case Metric::kCbrt: return "cbrt";
  }
  return "?";
}

const std::vector<Loss>& AllLosses() {
  static const std::vector<Loss> kAll = {Loss::kNone, Loss::kHuber, Loss::kCauchy};
  return kAll;
}

std::string LossName(Loss l) {
  switch (l) {
    case Loss::kNone: return "none";
    case Loss::kHuber: return "huber";
    case Loss::kCauchy: return "cauchy";
  }
  return "?";
}

Loss ParseLoss(const std::string& name) {
  for (Loss l : AllLosses())
    if (name == LossName(l)) return l;
  throw std::invalid_argument("unknown loss '" + name + "' (expected " + Expected(AllLosses(), LossName) + ")");
}

const std::vector<LinearSolver>& AllLinearSolvers() {
  static const std::vector<LinearSolver> kAll = {LinearSolver::kDenseQr, LinearSolver::kDenseNormalCholesky,
                                                 LinearSolver::kIterativeSchur, LinearSolver::kCgnr};
  return kAll;
}

LinearSolver ParseLinearSolver(const std::string& name) {
  std::string n = name;
  for (char& c : n) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  for (LinearSolver s : AllLinearSolvers())
    if (n == LinearSolverName(s)) return s;
  throw std::invalid_argument("unknown linear solver '" + name + "' (expected " +
                              Expected(AllLinearSolvers(), LinearSolverName) + ")");
}

std::string LinearSolverName(LinearSolver s) {
  switch (s) {
    case LinearSolver::kDenseQr: return "dense_qr";
    case LinearSolver::kDenseNormalCholesky: return "dense_normal_cholesky";
    case LinearSolver::kIterativeSchur: return "iterative_schur";
    case LinearSolver::kCgnr: return "cgnr";
  }
  return "?";
}

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

// ---------------------------------------------------------------------------
// Data.

namespace {

Eigen::Vector3d FromAngles(double theta, double phi) {
  const double s = std::sin(theta);
  return Eigen::Vector3d(s * std::cos(phi), s * std::sin(phi), std::cos(theta));
}

bool LooksLikeMerl(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  unsigned char h[12];
  if (!in.read(reinterpret_cast<char*>(h), 12)) return false;
  auto word = [&](int k) {
    return std::uint32_t(h[4 * k]) | std::uint32_t(h[4 * k + 1]) << 8 | std::uint32_t(h[4 * k + 2]) << 16 |
           std::uint32_t(h[4 * k + 3]) << 24;
  };
  return word(0) == 90 && word(1) == 90 && word(2) == 180;
}

}  // namespace

Dataset FromTable(const synth::BrdfTable& table, const std::string& source) {
  Dataset d;
  d.source = source;
  d.has_sigma = table.has_sigma;
  d.missing = table.missing;
  d.samples.reserve(table.rows.size());
  for (const synth::BrdfSample& r : table.rows)
    d.samples.push_back({FromAngles(r.theta_i, r.phi_i), FromAngles(r.theta_o, r.phi_o), r.f, r.sigma});
  return d;
}

Dataset FromMerl(const MerlTable& table, const std::string& source) {
  Dataset d;
  d.source = source;
  d.samples.reserve(MerlTable::kCells / 2);
  for (int i = 0; i < MerlTable::kThetaH; ++i)
    for (int j = 0; j < MerlTable::kThetaD; ++j)
      for (int k = 0; k < MerlTable::kPhiD; ++k) {
        const std::size_t n = MerlTable::Index(i, j, k);
        Sample s;
        bool missing = false;
        for (int c = 0; c < 3; ++c) {
          s.f[c] = table.values[c * MerlTable::kCells + n];
          missing = missing || s.f[c] < 0;
        }
        MerlTable::BinDirections(i, j, k, s.wi, s.wo);
        // A bin centre at or below the horizon is no reflectance sample.
        if (missing || !(s.wi.z() > 0 && s.wo.z() > 0)) {
          ++d.missing;
          continue;
        }
        s.sigma.setZero();
        d.samples.push_back(s);
      }
  return d;
}

namespace {

Dataset FromAngleSamples(const std::vector<AngleSample>& rows, const std::string& source) {
  Dataset d;
  d.source = source;
  for (const AngleSample& r : rows)
    d.samples.push_back({FromAngles(r.theta_i, r.phi_i), FromAngles(r.theta_o, r.phi_o), r.f, Eigen::Array3d::Zero()});
  return d;
}

bool StartsWith(const std::string& path, const std::string& magic) {
  std::ifstream in(path, std::ios::binary);
  std::string head(magic.size(), '\0');
  return in.read(head.data(), std::streamsize(head.size())) && head == magic;
}

}  // namespace

// The nodes of an RGL file (wi at each slice, wo by its warp, the cosine
// divided out), every node pair of a UTIA file, the rows of an ASTM table.
Dataset FromRgl(const RglBsdf& file, const std::string& source) {
  Dataset d;
  d.source = source;
  for (const RglBsdf::NodeSample& n : file.NodeSamples()) d.samples.push_back({n.wi, n.wo, n.f, Eigen::Array3d::Zero()});
  return d;
}

Dataset FromUtia(const UtiaTable& table, const std::string& source) {
  Dataset d;
  d.source = source;
  using U = UtiaTable;
  for (int ti = 0; ti < U::kTheta; ++ti)
    for (int pi = 0; pi < U::kPhi; ++pi)
      for (int tv = 0; tv < U::kTheta; ++tv)
        for (int pv = 0; pv < U::kPhi; ++pv) {
          const std::size_t n = U::Index(ti, pi, tv, pv);
          const Eigen::Array3d f(table.values[n], table.values[U::kPlane + n], table.values[2 * U::kPlane + n]);
          d.samples.push_back({U::NodeDirection(ti, pi), U::NodeDirection(tv, pv), f, Eigen::Array3d::Zero()});
        }
  return d;
}

Dataset LoadDataset(const std::string& path) {
  namespace fs = std::filesystem;
  std::error_code ec;
  std::string ext = fs::path(path).extension().string();
  for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  const bool regular = fs::is_regular_file(path, ec);
  Dataset d;
  if (ext == ".bsdf" || (regular && StartsWith(path, std::string("tensor_file\0", 12))))
    d = FromRgl(RglBsdf::Read(path), path);
  else if (ext == ".utia" || (ext == ".bin" && regular && fs::file_size(path, ec) == UtiaTable::kFileSize))
    d = FromUtia(UtiaTable::Read(path), path);
  else if (ext == ".astm")
    d = FromAngleSamples(AstmTable::Read(path).rows, path);
  else if (ext == ".binary" || (regular && LooksLikeMerl(path)))
    d = FromMerl(MerlTable::Read(path), path);
  else
    d = FromTable(synth::ReadTableCsv(path), path);
  const std::string side = path + ".json";
  if (fs::is_regular_file(side, ec)) {
    // The sidecar is a description, not data: one that cannot be read
    // leaves the data as they are.
    try {
      const synth::Instrument inst = synth::LoadInstrument(side);
      std::string what;
      if (inst.source.kind == synth::Source::Kind::kDisc && inst.source.angular_radius > 0)
        what = "a " + FormatDouble(inst.source.angular_radius * 180 / kPi) + " degree disc source";
      if (inst.detector.angular_radius > 0)
        what += (what.empty() ? "a " : " and a ") + FormatDouble(inst.detector.angular_radius * 180 / kPi) +
                " degree detector";
      if (!what.empty()) {
        d.apertures = what;
        d.sidecar = side;
      }
    } catch (const std::exception&) {
    }
  }
  return d;
}

// ---------------------------------------------------------------------------
// Residual evaluation.

namespace {

// Below this, cbrt is continued by its tangent: the derivative of cbrt is
// infinite at 0 and Jets must stay finite.
constexpr double kCbrtKnee = 1e-12;

template <class T>
T CbrtSafe(const T& x) {
  using std::cbrt;
  if (x < T(kCbrtKnee)) {
    const double c = std::cbrt(kCbrtKnee);
    return T(c) + (x - T(kCbrtKnee)) / T(3 * c * c);
  }
  return cbrt(x);
}

// The metric's transform G of a value v = f (l2, relative, cosine) or v = f cos_i.
template <class T>
T MetricTransform(Metric m, const T& f, double cos_i) {
  using std::log1p;
  switch (m) {
    case Metric::kLog: return log1p(f * T(cos_i));
    case Metric::kCbrt: return CbrtSafe(T(f * T(cos_i)));
    default: return f;
  }
}

// dG/df at f, for propagating sigma.
double MetricSlope(Metric m, double f, double cos_i) {
  switch (m) {
    case Metric::kLog: return cos_i / (1.0 + f * cos_i);
    case Metric::kCbrt: {
      const double x = std::max(f * cos_i, kCbrtKnee);
      const double c = std::cbrt(x);
      return cos_i / (3 * c * c);
    }
    default: return 1.0;
  }
}

// Samples prepared for one metric: struct of arrays.
struct Prepared {
  std::vector<Eigen::Vector3d> wi, wo;
  std::vector<double> cos_i;
  std::vector<Eigen::Array3d> reference;  // the data's f_r
  std::vector<Eigen::Array3d> target;    // G(reference)
  std::vector<Eigen::Array3d> w_fit;     // weights of the fitted residuals
  std::vector<Eigen::Array3d> w_metric;  // weights of the metric (no sigma)
  std::size_t size() const { return wi.size(); }
};

struct Selection {
  std::vector<std::size_t> index;  // samples used
  std::size_t dropped_angle = 0;
};

double MaxThetaRad(const Options& o) {
  const double deg = o.max_theta_deg > 0 ? o.max_theta_deg : (o.metric == Metric::kCosine ? 80.0 : 90.0);
  return deg * kPi / 180.0;
}

Selection Select(const Dataset& data, const Options& o) {
  Selection s;
  const double cos_max = std::cos(MaxThetaRad(o));
  // 1e-12 of slack keeps samples written at exactly the cut.
  for (std::size_t k = 0; k < data.samples.size(); ++k) {
    const Sample& x = data.samples[k];
    if (x.wi.z() < cos_max - 1e-12 || x.wo.z() < cos_max - 1e-12 || !(x.wi.z() > 0 && x.wo.z() > 0)) {
      ++s.dropped_angle;
      continue;
    }
    s.index.push_back(k);
  }
  return s;
}

Prepared Prepare(const Dataset& data, const std::vector<std::size_t>& index, const Options& o) {
  Prepared p;
  const std::size_t n = index.size();
  p.wi.resize(n);
  p.wo.resize(n);
  p.cos_i.resize(n);
  p.target.resize(n);
  p.reference.resize(n);
  p.w_fit.resize(n);
  p.w_metric.resize(n);
  // Relative metric: a floor keeps near-zero reference values from
  // dominating (and from dividing by zero).
  Eigen::Array3d floor = Eigen::Array3d::Zero();
  if (o.metric == Metric::kRelative) {
    Eigen::Array3d mean = Eigen::Array3d::Zero();
    for (std::size_t k : index) mean += data.samples[k].f.abs();
    mean /= std::max<std::size_t>(n, 1);
    floor = (1e-3 * mean).max(1e-300);
  }
  const bool sigma = data.has_sigma && o.use_sigma;
  for (std::size_t q = 0; q < n; ++q) {
    const Sample& s = data.samples[index[q]];
    p.wi[q] = s.wi.normalized();
    p.wo[q] = s.wo.normalized();
    const double c = p.wi[q].z();
    p.cos_i[q] = c;
    p.reference[q] = s.f;
    for (int ch = 0; ch < 3; ++ch) {
      const double g = s.f[ch];
      p.target[q][ch] = MetricTransform(o.metric, g, c);
      double w = 1;
      if (o.metric == Metric::kRelative) w = 1.0 / std::max(std::abs(g), floor[ch]);
      if (o.metric == Metric::kCosine) w = c;
      p.w_metric[q][ch] = w;
      // Standard deviation of the metric residual, to first order in sigma.
      p.w_fit[q][ch] = sigma ? 1.0 / (std::abs(MetricSlope(o.metric, g, c)) * s.sigma[ch]) : w;
    }
  }
  return p;
}

// Robust loss applied per residual as r -> sign(r) sqrt(rho(r^2)), so that
// the sum of squares is sum rho(r^2) while residuals stay grouped in blocks
// (a Ceres LossFunction would act on a whole block's squared norm).
template <class T>
T Robust(Loss loss, double a, const T& r) {
  using std::abs;
  using std::log1p;
  using std::sqrt;
  if (loss == Loss::kNone) return r;
  const T ar = abs(r);
  if (loss == Loss::kHuber) {
    if (ar <= T(a)) return r;
    const T v = sqrt(T(2 * a) * ar - T(a * a));
    return r < T(0) ? T(-v) : v;
  }
  // Cauchy: rho(s) = a^2 log(1 + s / a^2). Near 0 it is r itself to
  // O(r^3), and the sqrt's derivative would be infinite at r = 0.
  if (ar < T(1e-6 * a)) return r;
  const T v = T(a) * sqrt(log1p(r * r / T(a * a)));
  return r < T(0) ? T(-v) : v;
}

// Which packed parameters the optimiser moves. Packed slot k is free slot
// free_of[k] (tied slots share their leader's) or held at value[k]; the
// free slots' bounds (user space) are the intersection of the bounds of the
// packed slots they feed.
struct Layout {
  std::vector<int> free_of;           // packed -> free slot, -1: fixed
  std::vector<double> value;          // packed: the value of a fixed slot
  std::vector<int> leader;            // packed -> packed slot it follows (tie), -1
  std::vector<double> lo, hi;         // packed bounds, user space
  std::vector<std::size_t> rep;       // free -> first packed slot it feeds
  std::size_t Free() const { return rep.size(); }
  // Numbers the free slots in packed order.
  void Renumber() {
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
};

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

class Engine {
 public:
  Engine(const Evaluators& model, const Options& o, double loss_scale, const Layout& layout)
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
    jet_ = n_slots_ <= 4 ? 4 : n_slots_ <= 8 ? 8 : n_slots_ <= 16 ? 16 : 32;
    if (jet_ == 4) b4_ = model.MakeJet4();
    if (jet_ == 8) b8_ = model.MakeJet8();
    if (jet_ == 16) b16_ = model.MakeJet16();
    if (jet_ == 32) b32_ = model.MakeJet32();
    if (o.instrument) {
      int order = o.aperture_order > 0 ? o.aperture_order : o.instrument->quadrature.order;
      if (order <= 0) order = 3;  // automatic order of the synthesiser: 3 reaches ~1e-6 for 1-degree cones
      quad_ = std::make_unique<synth::ApertureQuadrature>(synth::MakeApertureQuadrature(*o.instrument, order));
    }
  }

  std::size_t n() const { return nf_; }  // free parameters
  std::size_t packed() const { return n_; }
  int jet() const { return jet_; }
  const std::vector<bool>& log_mask() const { return log_; }
  const Layout& layout() const { return layout_; }

  // Internal (optimised, free) -> user parameters (packed).
  template <class T>
  void ToUser(const T* u, T* p) const {
    using std::exp;
    std::array<T, 64> y;
    for (std::size_t j = 0; j < nf_; ++j) y[j] = log_[j] ? exp(u[j]) : u[j];
    for (std::size_t k = 0; k < n_; ++k) {
      const int f = layout_.free_of[k];
      p[k] = f < 0 ? T(layout_.value[k]) : y[std::size_t(f)];
    }
  }
  std::vector<double> ToUser(const std::vector<double>& u) const {
    std::vector<double> p(n_);
    ToUser(u.data(), p.data());
    return p;
  }
  std::vector<double> ToInternal(const std::vector<double>& p) const {
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
  void SampleResiduals(const Bxdf<T>& b, const T* p, const Prepared& d, std::size_t q, bool fit, T* out) const {
    ResidualsOf(Prediction(b, p, d, q), d, q, fit, out);
  }
  template <class T>
  void ResidualsOf(const Rgb<T>& f, const Prepared& d, std::size_t q, bool fit, T* out) const {
    for (int c = 0; c < 3; ++c) {
      const T g = MetricTransform(metric_, f[c], d.cos_i[q]);
      if (fit) out[c] = Robust(loss_, loss_scale_, T(T(d.w_fit[q][c]) * (g - T(d.target[q][c]))));
      else out[c] = T(d.w_metric[q][c]) * (g - T(d.target[q][c]));
    }
  }

  // The model's value for sample q: f_r, or f_r through the instrument's apertures.
  template <class T>
  Rgb<T> Prediction(const Bxdf<T>& b, const T* p, const Prepared& d, std::size_t q) const {
    if (quad_) return synth::MeasuredBrdf(b, p, d.wi[q], d.wo[q], *quad_);
    const Vec3<T> wi = d.wi[q].template cast<T>(), wo = d.wo[q].template cast<T>();
    return b.Eval(p, wi, wo);
  }
  Eigen::Array3d Predict(const std::vector<double>& p, const Prepared& d, std::size_t q) const {
    return Prediction(*b_, p.data(), d, q);
  }

  // Residuals (3 per sample) over [begin, end), internal parameters u.
  bool EvalDouble(const double* u, const Prepared& d, std::size_t begin, std::size_t end, bool fit,
                  double* r) const {
    std::vector<double> p(n_);
    ToUser(u, p.data());
    if (quad_) {
      for (std::size_t q = begin; q < end; ++q) SampleResiduals(*b_, p.data(), d, q, fit, r + 3 * (q - begin));
    } else if (end > begin) {
      // f_r of the whole range in one EvalBatch call (the model's vectorised kernel).
      static_assert(sizeof(Eigen::Vector3d) == 3 * sizeof(double), "directions are packed rows of 3");
      std::vector<double> f(3 * (end - begin));
      b_->EvalBatch(p.data(), d.wi[begin].data(), 3, d.wo[begin].data(), 3, end - begin, f.data());
      for (std::size_t q = begin; q < end; ++q)
        ResidualsOf(Rgb<double>(Rgb<double>::Map(f.data() + 3 * (q - begin))), d, q, fit, r + 3 * (q - begin));
    }
    for (std::size_t k = 0; k < 3 * (end - begin); ++k)
      if (!std::isfinite(r[k])) return false;
    return true;
  }

  // Residuals and their Jacobian (row-major, 3 (end - begin) x free parameters).
  bool EvalJacobian(const double* u, const Prepared& d, std::size_t begin, std::size_t end, double* r,
                    double* jac) const {
    switch (jet_) {
      case 4: return EvalJet<4>(*b4_, u, d, begin, end, r, jac);
      case 8: return EvalJet<8>(*b8_, u, d, begin, end, r, jac);
      case 16: return EvalJet<16>(*b16_, u, d, begin, end, r, jac);
      default: return EvalJet<32>(*b32_, u, d, begin, end, r, jac);
    }
  }

 private:
  template <int N>
  bool EvalJet(const Bxdf<Jet<N>>& b, const double* u, const Prepared& d, std::size_t begin, std::size_t end,
               double* r, double* jac) const {
    std::array<Jet<N>, 64> uj, pj;
    for (std::size_t k = 0; k < nf_; ++k) uj[k] = Jet<N>(u[k], static_cast<int>(slot_[k]));
    ToUser(uj.data(), pj.data());
    for (std::size_t q = begin; q < end; ++q) {
      Jet<N> res[3];
      SampleResiduals(b, pj.data(), d, q, true, res);
      for (int c = 0; c < 3; ++c) {
        const std::size_t row = 3 * (q - begin) + c;
        r[row] = res[c].a;
        if (!std::isfinite(r[row])) return false;
        if (jac) {
          for (std::size_t k = 0; k < nf_; ++k) {
            const double v = channel_[k] < 0 || channel_[k] == c ? res[c].v[slot_[k]] : 0.0;
            if (!std::isfinite(v)) return false;
            jac[row * nf_ + k] = v;
          }
        }
      }
    }
    return true;
  }

  Metric metric_;
  Loss loss_;
  double loss_scale_;
  Layout layout_;
  std::size_t n_ = 0;   // packed parameters
  std::size_t nf_ = 0;  // free parameters
  std::vector<std::size_t> slot_;  // derivative slot of each free parameter
  std::vector<int> channel_;       // its channel when the slot is shared by r, g, b; else -1
  std::size_t n_slots_ = 0;
  int jet_ = 8;
  std::vector<bool> log_;
  std::unique_ptr<Bxdf<double>> b_;
  std::unique_ptr<Bxdf<Jet<4>>> b4_;
  std::unique_ptr<Bxdf<Jet<8>>> b8_;
  std::unique_ptr<Bxdf<Jet<16>>> b16_;
  std::unique_ptr<Bxdf<Jet<32>>> b32_;
  std::unique_ptr<synth::ApertureQuadrature> quad_;
};

// One residual block: a chunk of samples, all channels.
class ChunkCost final : public ceres::CostFunction {
 public:
  ChunkCost(const Engine* e, const Prepared* d, std::size_t begin, std::size_t end)
      : e_(e), d_(d), begin_(begin), end_(end) {
    set_num_residuals(static_cast<int>(3 * (end - begin)));
    mutable_parameter_block_sizes()->push_back(static_cast<int>(e->n()));
  }
  bool Evaluate(double const* const* x, double* r, double** jac) const override {
    if (!jac || !jac[0]) return e_->EvalDouble(x[0], *d_, begin_, end_, true, r);
    return e_->EvalJacobian(x[0], *d_, begin_, end_, r, jac[0]);
  }

 private:
  const Engine* e_;
  const Prepared* d_;
  std::size_t begin_, end_;
};

// Bounds of the internal (free) parameters: the intersection of the bounds
// of the packed slots each one feeds.
void Bounds(const Layout& layout, const std::vector<bool>& log_mask, std::vector<double>& lo,
            std::vector<double>& hi) {
  const std::size_t nf = layout.Free();
  lo.assign(nf, -std::numeric_limits<double>::infinity());
  hi.assign(nf, std::numeric_limits<double>::infinity());
  for (std::size_t k = 0; k < layout.free_of.size(); ++k) {
    const int f = layout.free_of[k];
    if (f < 0) continue;
    lo[std::size_t(f)] = std::max(lo[std::size_t(f)], layout.lo[k]);
    hi[std::size_t(f)] = std::min(hi[std::size_t(f)], layout.hi[k]);
  }
  for (std::size_t j = 0; j < nf; ++j)
    if (log_mask[j]) {
      // A log-scale parameter must stay positive: a zero lower bound is
      // replaced by a tiny fraction of the upper one.
      const double l = lo[j] > 0 ? lo[j] : std::max(1e-12 * hi[j], 1e-300);
      lo[j] = std::log(l);
      hi[j] = std::log(hi[j]);
    }
}

class TraceCallback final : public ceres::IterationCallback {
 public:
  TraceCallback(std::function<void(const ceres::IterationSummary&)> f) : f_(std::move(f)) {}
  ceres::CallbackReturnType operator()(const ceres::IterationSummary& s) override {
    f_(s);
    return ceres::SOLVER_CONTINUE;
  }

 private:
  std::function<void(const ceres::IterationSummary&)> f_;
};

// Builds the problem over `d` with internal parameters `u` (updated in place).
void BuildProblem(ceres::Problem& problem, const Engine& e, const Prepared& d, std::size_t chunk,
                  std::vector<double>& u) {
  problem.AddParameterBlock(u.data(), static_cast<int>(u.size()));
  for (std::size_t b = 0; b < d.size(); b += chunk)
    problem.AddResidualBlock(new ChunkCost(&e, &d, b, std::min(d.size(), b + chunk)), nullptr, u.data());
  std::vector<double> lo, hi;
  Bounds(e.layout(), e.log_mask(), lo, hi);
  for (std::size_t k = 0; k < u.size(); ++k) {
    problem.SetParameterLowerBound(u.data(), static_cast<int>(k), lo[k]);
    problem.SetParameterUpperBound(u.data(), static_cast<int>(k), hi[k]);
  }
}

ceres::LinearSolverType ToCeres(LinearSolver s) {
  switch (s) {
    case LinearSolver::kDenseQr: return ceres::DENSE_QR;
    case LinearSolver::kDenseNormalCholesky: return ceres::DENSE_NORMAL_CHOLESKY;
    case LinearSolver::kIterativeSchur: return ceres::ITERATIVE_SCHUR;
    case LinearSolver::kCgnr: return ceres::CGNR;
  }
  return ceres::DENSE_QR;
}

ceres::Solver::Options SolverOptions(const Options& o, LinearSolver solver, int max_iterations) {
  ceres::Solver::Options so;
  so.minimizer_type = ceres::TRUST_REGION;
  so.trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
  so.linear_solver_type = ToCeres(solver);
  so.num_threads = std::max(1, o.num_threads);
  so.max_num_iterations = max_iterations;
  so.function_tolerance = o.function_tolerance;
  so.gradient_tolerance = o.gradient_tolerance;
  so.parameter_tolerance = o.parameter_tolerance;
  so.logging_type = ceres::SILENT;
  so.minimizer_progress_to_stdout = false;
  return so;
}

// The sum of part(begin, end) over [0, n) cut into chunks of at most
// `grain`, on the TBB pool (the caller's arena sets the thread count); the
// chunks and the order of their sums do not depend on the thread count.
template <typename T, typename F>
T ChunkedSum(std::size_t n, std::size_t grain, T zero, F&& part) {
  return tbb::parallel_deterministic_reduce(
      tbb::blocked_range<std::size_t>(0, n, std::max<std::size_t>(1, grain)), zero,
      [&](const tbb::blocked_range<std::size_t>& r, T acc) { return T(acc + part(r.begin(), r.end())); },
      [](const T& a, const T& b) { return T(a + b); });
}

// Root mean square of the plain metric residuals.
double Rmse(const Engine& e, const Prepared& d, const std::vector<double>& u) {
  if (d.size() == 0) return 0;
  const double sum = ChunkedSum(d.size(), 1024, 0.0, [&](std::size_t begin, std::size_t end) {
    double r[3];
    double s = 0;
    for (std::size_t q = begin; q < end; ++q) {
      // Plain double evaluation of the metric residual.
      e.EvalDouble(u.data(), d, q, q + 1, false, r);
      s += r[0] * r[0] + r[1] * r[1] + r[2] * r[2];
    }
    return s;
  });
  return std::sqrt(sum / (3.0 * d.size()));
}

// Quantile q of sorted values, linear between order statistics (position
// q (n - 1), the usual sample quantile).
double Quantile(const std::vector<double>& sorted, double q) {
  const double pos = q * double(sorted.size() - 1);
  const std::size_t i = static_cast<std::size_t>(pos);
  if (i + 1 >= sorted.size()) return sorted.back();
  return sorted[i] + (pos - double(i)) * (sorted[i + 1] - sorted[i]);
}

ErrorStats StatsOf(std::vector<double> v) {
  ErrorStats s;
  s.count = v.size();
  if (v.empty()) return s;
  std::sort(v.begin(), v.end());
  s.median = Quantile(v, 0.5);
  s.p95 = Quantile(v, 0.95);
  s.max = v.back();
  return s;
}

// Relative errors of the fitted model (user parameters p) against the data,
// over all samples and by theta_h band (Result::relative_error).
void RelativeErrors(const Engine& e, const Prepared& d, const std::vector<double>& p, Result& res) {
  const std::size_t n = d.size();
  std::vector<Eigen::Array3d> pred(n);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 256), [&](const tbb::blocked_range<std::size_t>& r) {
    for (std::size_t q = r.begin(); q < r.end(); ++q) pred[q] = e.Predict(p, d, q);
  });
  Eigen::Array3d mean = Eigen::Array3d::Zero();
  for (const Eigen::Array3d& g : d.reference) mean += g.abs();
  // The floor keeps reference values near zero from dominating (as the relative metric).
  const Eigen::Array3d floor = (1e-3 * mean / double(std::max<std::size_t>(n, 1))).max(1e-300);
  constexpr std::size_t kBands = std::size(kThetaHBandEdgesDeg) - 1;
  std::vector<double> all;
  std::vector<std::vector<double>> bands(kBands);
  all.reserve(3 * n);
  for (std::size_t q = 0; q < n; ++q) {
    const Eigen::Vector3d h = (d.wi[q] + d.wo[q]).normalized();
    const double theta_h = std::acos(std::clamp(h.z(), -1.0, 1.0)) * 180 / kPi;
    std::size_t b = 0;
    while (b + 1 < kBands && theta_h >= kThetaHBandEdgesDeg[b + 1]) ++b;
    for (int c = 0; c < 3; ++c) {
      const double g = d.reference[q][c];
      const double rel = std::abs(pred[q][c] - g) / std::max(std::abs(g), floor[c]);
      all.push_back(rel);
      bands[b].push_back(rel);
    }
  }
  res.relative_error = StatsOf(std::move(all));
  res.relative_error_bands.clear();
  for (std::size_t b = 0; b < kBands; ++b)
    if (!bands[b].empty())
      res.relative_error_bands.push_back({kThetaHBandEdgesDeg[b], kThetaHBandEdgesDeg[b + 1], StatsOf(std::move(bands[b]))});
}

// J^T J over all residual blocks (internal parameters).
Eigen::MatrixXd NormalMatrix(const Engine& e, const Prepared& d, const std::vector<double>& u, std::size_t chunk) {
  const std::size_t n = e.n();
  const std::size_t blocks = (d.size() + chunk - 1) / chunk;
  return ChunkedSum(blocks, 8, Eigen::MatrixXd(Eigen::MatrixXd::Zero(n, n)), [&](std::size_t first, std::size_t last) {
    Eigen::MatrixXd part = Eigen::MatrixXd::Zero(n, n);
    std::vector<double> r(3 * chunk), jac(3 * chunk * n);
    for (std::size_t b = first; b < last; ++b) {
      const std::size_t begin = b * chunk, end = std::min(d.size(), begin + chunk);
      e.EvalJacobian(u.data(), d, begin, end, r.data(), jac.data());
      Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>> J(
          jac.data(), static_cast<Eigen::Index>(3 * (end - begin)), static_cast<Eigen::Index>(n));
      part.noalias() += J.transpose() * J;
    }
    return part;
  });
}

// Plain-words diagnosis of parameters the data cannot determine; empty when
// the normal matrix has full rank.
std::string Identifiability(const Eigen::MatrixXd& jtj, const std::vector<std::string>& names) {
  const Eigen::Index n = jtj.rows();
  Eigen::VectorXd scale(n);
  const double max_diag = jtj.diagonal().maxCoeff();
  std::vector<std::string> problems;
  std::vector<Eigen::Index> live;
  for (Eigen::Index k = 0; k < n; ++k) {
    // A column 1e-24 below the largest is numerically zero (cf. 1e-12 on singular values).
    if (!(jtj(k, k) > 1e-24 * max_diag)) {
      problems.push_back("parameter " + names[k] + " has no effect on the fitted samples");
      continue;
    }
    live.push_back(k);
  }
  if (!live.empty()) {
    const Eigen::Index m = static_cast<Eigen::Index>(live.size());
    Eigen::MatrixXd a(m, m);
    for (Eigen::Index i = 0; i < m; ++i) scale(i) = std::sqrt(jtj(live[i], live[i]));
    for (Eigen::Index i = 0; i < m; ++i)
      for (Eigen::Index j = 0; j < m; ++j) a(i, j) = jtj(live[i], live[j]) / (scale(i) * scale(j));
    Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(a);
    const double lmax = es.eigenvalues().maxCoeff();
    for (Eigen::Index i = 0; i < m; ++i) {
      // Singular values of the scaled Jacobian below 1e-6 of the largest:
      // the parameters move the model only in a fixed combination.
      if (es.eigenvalues()(i) > 1e-12 * lmax) continue;
      const Eigen::VectorXd v = es.eigenvectors().col(i);
      std::string list;
      int count = 0;
      for (Eigen::Index j = 0; j < m; ++j)
        if (std::abs(v(j)) > 0.1) {
          list += (list.empty() ? "" : ", ") + names[live[j]];
          ++count;
        }
      if (count <= 1)
        problems.push_back("parameter " + list + " is not determined by the data");
      else
        problems.push_back("the data cannot tell apart " + list + " (only a combination of them is determined)");
    }
  }
  std::string out;
  for (const std::string& p : problems) out += (out.empty() ? "" : "; ") + p;
  return out;
}

double Median(std::vector<double> v) {
  if (v.empty()) return 0;
  const std::size_t mid = v.size() / 2;
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(mid), v.end());
  return v[mid];
}

// ---------------------------------------------------------------------------
// Fixed, tied and bounded parameters.

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

// ---------------------------------------------------------------------------
// Starts of a sum of lobes.

// A solution: packed user parameters and its cost on the samples it was solved on.
struct Candidate {
  std::vector<double> p;
  double cost = std::numeric_limits<double>::infinity();
  std::string origin;
};

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

// Multi-start and nested sub-sums of a sum of lobes (Fit's start strategy).
// Level(mask) fits the sum with the lobes in `mask` switched off.
class StartSearch {
 public:
  StartSearch(const Model& model, const Options& o, const Layout& base, const Prepared& full,
              const Prepared& subset, bool sigma, Result& res, std::function<double()> elapsed)
      : model_(model), o_(o), base_(base), full_(full), subset_(subset), sigma_(sigma), res_(res),
        elapsed_(std::move(elapsed)) {
    plain_options_ = o;
    for (const ParamInfo& p : model.Info().params)
      for (int c = 0; c < (p.colour ? 3 : 1); ++c) channel_.push_back(p.colour ? c : -1);
    plain_options_.loss = Loss::kNone;
    const std::size_t L = model.LobeCount();
    const ModelInfo& info = model.Info();
    for (std::size_t k = 0; k < L; ++k) {
      // A lobe can be switched off (and swapped with a copy of itself) only
      // when none of its parameters is fixed, tied or given bounds.
      bool untouched = true;
      for (std::size_t q : LobeSlots(model, k)) {
        const bool leads = std::find(base.leader.begin(), base.leader.end(), int(q)) != base.leader.end();
        untouched = untouched && base.free_of[q] >= 0 && base.leader[q] < 0 && !leads;
      }
      std::size_t i = 0, off = 0;
      for (; i < info.params.size(); ++i) {
        for (std::size_t q : LobeSlots(model, k))
          if (q >= off && q < off + (info.params[i].colour ? 3 : 1))
            untouched = untouched && base.lo[q] == info.params[i].lower && base.hi[q] == info.params[i].upper;
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
      const std::string label = name + ": start " + std::to_string(res_.starts + 1);
      Candidate c = Solve(plain, subset_, s.p, o_.start_iterations, 1e-8, label + " (subset)");
      c.origin = label + (s.origin.empty() ? "" : " " + s.origin);
      if (std::isfinite(c.cost)) solved.push_back(std::move(c));
    }
    std::sort(solved.begin(), solved.end(), [](const Candidate& a, const Candidate& b) { return a.cost < b.cost; });

    // Every sub-sum's optimum (refined on all samples) and the best distinct
    // optima of the subset, by their cost on all samples. The best is
    // refined on all samples (at the top level by Fit's final solve); a
    // refinement starts at that cost and only descends, so a sum is never
    // worse than its nested sub-sums.
    std::vector<Candidate> candidates;
    for (const auto& [kid, k] : kids) candidates.push_back({kid.p, kid.cost, "nested " + ActiveSpec(mask | (1u << k))});
    std::vector<Candidate> distinct;
    for (const Candidate& c : solved) {
      // The best four distinct subset optima: each costs a pass over all samples.
      if (distinct.size() == 4) break;
      if (Contains(plain, distinct, c.p)) continue;
      distinct.push_back(c);
      candidates.push_back({c.p, FullCost(plain, c.p), c.origin + " (subset optimum)"});
    }
    std::sort(candidates.begin(), candidates.end(), [](const Candidate& x, const Candidate& y) { return x.cost < y.cost; });
    std::vector<Candidate> optima;
    for (const Candidate& c : candidates)
      if (std::isfinite(c.cost) && !Contains(plain, optima, c.p)) optima.push_back(c);
    if (optima.empty()) return memo_[mask] = best;
    if (top) {
      for (const Candidate& c : optima) res_.local_optima.push_back({c.cost, c.p, c.origin});
      best = optima.front();
    } else {
      best = Solve(plain, full_, optima.front().p, o_.max_iterations, o_.function_tolerance,
                   name + ": refine (all samples)");
      if (!(best.cost <= optima.front().cost)) best = optima.front();
    }
    return memo_[mask] = best;
  }

 private:
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

  // Whether p is within 1e-3 (internal units: relative for widths) of a solution in `set`.
  bool Contains(const Engine& e, const std::vector<Candidate>& set, const std::vector<double>& p) const {
    const std::vector<double> u = e.ToInternal(p);
    for (const Candidate& c : set) {
      const std::vector<double> v = e.ToInternal(c.p);
      double d = 0;
      for (std::size_t j = 0; j < u.size(); ++j) d = std::max(d, std::abs(u[j] - v[j]));
      if (d < 1e-3) return true;
    }
    return false;
  }

  // Copies of one lobe, none touched by fix/tie/bounds, all active: sorted
  // by width so that the symmetric copies of a solution are one.
  void Canonical(std::vector<double>& p, unsigned mask) const {
    const std::size_t L = model_.LobeCount();
    std::vector<bool> done(L, false);
    for (std::size_t a = 0; a < L; ++a) {
      if (done[a] || (mask >> a & 1u) || !untouched_[a] || WidthSlot(model_, a) < 0) continue;
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
        blocks.push_back(v);
      }
      const std::size_t w = std::size_t(WidthSlot(model_, a)) - model_.LobeOffset(a);
      std::stable_sort(blocks.begin(), blocks.end(), [w](const auto& x, const auto& y) { return x[w] < y[w]; });
      for (std::size_t g = 0; g < group.size(); ++g) {
        const std::vector<std::size_t> slots = LobeSlots(model_, group[g]);
        for (std::size_t q = 0; q < slots.size(); ++q) p[slots[q]] = blocks[g][q];
      }
    }
  }

  // Log-spaced values of a log-scale parameter (packed slot k) within its bounds.
  std::vector<double> Widths(const Layout& layout, std::size_t k, double default_value) const {
    const int K = std::max(1, o_.starts_per_param);
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

  // Every combination of start widths of the free log-scale parameters
  // (copies of one lobe in increasing order; beyond 64 the diagonal).
  std::vector<std::vector<double>> GridStarts(const Layout& layout, unsigned mask) const {
    const ModelInfo& info = model_.Info();
    std::vector<double> start = layout.value;
    std::vector<std::size_t> slots, sizes;      // leading packed slot and size of each free log parameter
    std::vector<std::vector<double>> values;
    std::vector<std::ptrdiff_t> lobe_of;        // its lobe when that is an untouched active copy, else -1
    std::size_t off = 0;
    for (const ParamInfo& p : info.params) {
      const std::size_t width = p.colour ? 3 : 1;
      if (p.scale == ParamInfo::Scale::kLog && layout.free_of[off] >= 0 && layout.leader[off] < 0) {
        slots.push_back(off);
        sizes.push_back(width);
        values.push_back(Widths(layout, off, p.default_value));
        std::ptrdiff_t lobe = -1;
        for (std::size_t k = 0; k < model_.LobeCount(); ++k)
          if (WidthSlot(model_, k) == std::ptrdiff_t(off) && untouched_[k] && !(mask >> k & 1u)) lobe = std::ptrdiff_t(k);
        lobe_of.push_back(lobe);
      }
      off += width;
    }
    const auto ordered = [&](const std::vector<int>& c) {
      for (std::size_t a = 0; a < c.size(); ++a)
        for (std::size_t b = a + 1; b < c.size(); ++b)
          if (lobe_of[a] >= 0 && lobe_of[b] >= 0 &&
              model_.LobeInfo(std::size_t(lobe_of[a])).name == model_.LobeInfo(std::size_t(lobe_of[b])).name &&
              !(c[a] < c[b]))
            return false;
      return true;
    };
    const int K = std::max(1, o_.starts_per_param);
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

  // The sub-sum's optimum p (lobe k off) with lobe k switched back on at
  // each start width, its switch scaled by least squares to the residual
  // the sub-sum leaves on the subset.
  std::vector<std::vector<double>> Seeded(const Engine& e, const std::vector<double>& p, std::size_t k,
                                          const Layout& layout) const {
    const ModelInfo& info = model_.Info();
    const std::ptrdiff_t ws = WidthSlot(model_, k);
    std::vector<double> widths = {ws >= 0 ? p[std::size_t(ws)] : 0.0};
    if (ws >= 0) {
      std::size_t i = 0, off = 0;
      while (off + (info.params[i].colour ? 3 : 1) <= std::size_t(ws)) off += info.params[i++].colour ? 3 : 1;
      widths = Widths(layout, std::size_t(ws), info.params[i].default_value);
    }
    const std::vector<std::size_t> sw = SwitchSlots(model_, k);
    const std::vector<double> defaults = info.Defaults();
    std::vector<std::vector<double>> out;
    for (double width : widths) {
      std::vector<double> on = p;
      for (std::size_t q : LobeSlots(model_, k)) on[q] = defaults[q];
      if (ws >= 0) on[std::size_t(ws)] = width;
      // Per channel for colour switches, one scale for a weight.
      Eigen::Array3d rg = Eigen::Array3d::Zero(), gg = Eigen::Array3d::Zero();
      for (std::size_t q = 0; q < subset_.size(); ++q) {
        const Eigen::Array3d base = e.Predict(p, subset_, q), with = e.Predict(on, subset_, q);
        const Eigen::Array3d g = with - base, r = subset_.reference[q] - base;
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

  // Cost (half the sum of squared residuals) of p on all samples.
  double FullCost(const Engine& e, const std::vector<double>& p) const {
    const std::vector<double> u = e.ToInternal(p);
    constexpr std::size_t chunk = 256;
    return ChunkedSum(full_.size(), chunk, 0.0, [&](std::size_t begin, std::size_t end) {
      double r[3 * chunk];
      // A non-finite residual makes the point unusable.
      if (!e.EvalDouble(u.data(), full_, begin, end, true, r)) return std::numeric_limits<double>::infinity();
      double s = 0;
      for (std::size_t k = 0; k < 3 * (end - begin); ++k) s += 0.5 * r[k] * r[k];
      return s;
    });
  }

  // Solves from p over `d` for at most `iterations`; the solution is put in
  // canonical order.
  Candidate Solve(const Engine& e, const Prepared& d, const std::vector<double>& p, int iterations, double ftol,
                  const std::string& stage) {
    std::vector<double> u = e.ToInternal(p);
    std::vector<double> lo, hi;
    Bounds(e.layout(), e.log_mask(), lo, hi);
    for (std::size_t j = 0; j < u.size(); ++j) u[j] = std::clamp(u[j], lo[j], hi[j]);
    ceres::Problem problem;
    BuildProblem(problem, e, d, std::max<std::size_t>(1, o_.chunk), u);
    ceres::Solver::Options so = SolverOptions(o_, LinearSolver::kDenseQr, iterations);
    so.function_tolerance = ftol;
    so.update_state_every_iteration = sigma_;  // the RMSE below reads u
    const int start = ++res_.starts;
    TraceCallback callback([&](const ceres::IterationSummary& s) {
      if (s.iteration > 0 && !s.step_is_successful) return;
      // Without sigma the plain engine's cost is the metric's sum of squares / 2.
      const double rmse = sigma_ ? Rmse(e, d, u) : std::sqrt(2 * s.cost / (3.0 * d.size()));
      res_.trace.push_back({s.iteration, elapsed_(), s.cost, rmse, start, stage});
    });
    so.callbacks.push_back(&callback);
    ceres::Solver::Summary summary;
    ceres::Solve(so, &problem, &summary);
    Candidate c;
    if (!summary.IsSolutionUsable()) return c;
    c.p = e.ToUser(u);
    c.cost = summary.final_cost;
    unsigned mask = 0;
    for (std::size_t k = 0; k < model_.LobeCount(); ++k)
      for (std::size_t q : SwitchSlots(model_, k))
        if (e.layout().free_of[q] < 0 && e.layout().value[q] == 0 && untouched_[k]) mask |= 1u << k;
    Canonical(c.p, mask);
    return c;
  }

  const Model& model_;
  const ModelEvaluators evaluators_{model_};
  const Options& o_;
  Options plain_options_;
  const Layout& base_;
  const Prepared& full_;
  const Prepared& subset_;
  bool sigma_;
  Result& res_;
  std::function<double()> elapsed_;
  std::vector<bool> untouched_;
  std::vector<int> channel_;  // packed slot -> channel of a colour parameter, else -1
  std::map<unsigned, Candidate> memo_;
};

}  // namespace

void CheckConstraints(const ModelInfo& info, const Options& options) { MakeLayout(info, options); }

double MetricRmse(const Model& model, const std::vector<double>& params, const Dataset& data,
                  const Options& options) {
  const Selection sel = Select(data, options);
  const Prepared d = Prepare(data, sel.index, options);
  const Engine e(ModelEvaluators(model), options, 1.0, AllFree(model.Info()));
  tbb::task_arena arena(std::clamp(options.num_threads, 1, std::max(1, tbb::info::default_concurrency())));
  return arena.execute([&] { return Rmse(e, d, e.ToInternal(params)); });
}

struct ResidualBlocks::Impl {
  Impl(const Model& model, const Dataset& data, const Options& o, double loss_scale)
      : engine(ModelEvaluators(model), o, loss_scale, AllFree(model.Info())), prepared(Prepare(data, Select(data, o).index, o)) {
    const std::size_t chunk = std::max<std::size_t>(1, o.chunk);
    for (std::size_t b = 0; b < prepared.size(); b += chunk)
      blocks.push_back(std::make_unique<ChunkCost>(&engine, &prepared, b, std::min(prepared.size(), b + chunk)));
  }
  Engine engine;
  Prepared prepared;
  std::vector<std::unique_ptr<ChunkCost>> blocks;
};

ResidualBlocks::ResidualBlocks(const Model& model, const Dataset& data, const Options& options, double loss_scale)
    : impl_(std::make_unique<Impl>(model, data, options, loss_scale)) {}
ResidualBlocks::~ResidualBlocks() = default;
std::size_t ResidualBlocks::size() const { return impl_->blocks.size(); }
const ceres::CostFunction& ResidualBlocks::block(std::size_t k) const { return *impl_->blocks.at(k); }
std::vector<double> ResidualBlocks::ToInternal(const std::vector<double>& params) const {
  return impl_->engine.ToInternal(params);
}

Result Fit(const Model& model, const Dataset& data, const Options& options) {
  Result res = Fit(ModelEvaluators(model), data, options);
  res.model = model;
  return res;
}

namespace {
Result FitInArena(const Evaluators& model, const Dataset& data, const Options& o);
}  // namespace

Result Fit(const Evaluators& model, const Dataset& data, const Options& options) {
  // More worker threads than the machine offers only cost memory and
  // start-up (a count such as 100000 would exhaust the process's thread limit).
  Options o = options;
  o.num_threads = std::clamp(o.num_threads, 1, std::max(1, tbb::info::default_concurrency()));
  // The project's TBB pool, limited to num_threads for this fit; Ceres runs
  // its solver threads itself.
  tbb::task_arena arena(o.num_threads);
  return arena.execute([&] { return FitInArena(model, data, o); });
}

namespace {

Result FitInArena(const Evaluators& model, const Dataset& data, const Options& o) {
  using Clock = std::chrono::steady_clock;
  const auto t0 = Clock::now();
  auto elapsed = [&] { return std::chrono::duration<double>(Clock::now() - t0).count(); };

  const ModelInfo& info = model.Info();
  Result res;
  res.metric = o.metric;
  res.missing = data.missing;
  res.packed_names = PackedNames(info);
  const std::size_t n = info.PackedSize();

  const Selection sel = Select(data, o);
  res.dropped_angle = sel.dropped_angle;
  res.used = sel.index.size();
  if (sel.index.empty())
    throw std::invalid_argument("no samples to fit" + (data.source.empty() ? "" : " in '" + data.source + "'") +
                                " (" + std::to_string(data.samples.size()) + " read, " +
                                std::to_string(sel.dropped_angle) + " beyond the angle cut, " +
                                std::to_string(data.missing) + " missing)");
  if (3 * sel.index.size() < n)
    throw std::invalid_argument("too few samples (" + std::to_string(sel.index.size()) + ") for " +
                                std::to_string(n) + " parameters");
  const Prepared full = Prepare(data, sel.index, o);
  const bool sigma = data.has_sigma && o.use_sigma;
  const std::size_t chunk = std::max<std::size_t>(1, o.chunk);

  // Engine without a robust loss for the start search; its scale is chosen below.
  const Layout layout = MakeLayout(info, o);
  Options plain_options = o;
  plain_options.loss = Loss::kNone;
  const Engine plain(model, plain_options, 1.0, layout);
  const std::size_t nf = layout.Free();

  std::vector<double> lo, hi;
  Bounds(layout, plain.log_mask(), lo, hi);
  auto clamp_internal = [&](std::vector<double>& u) {
    for (std::size_t k = 0; k < nf; ++k) u[k] = std::clamp(u[k], lo[k], hi[k]);
  };

  // A fixed pseudo-random choice of `count` samples, so runs repeat.
  auto subset_index = [&](std::size_t count) {
    std::vector<std::size_t> sub(full.size());
    std::iota(sub.begin(), sub.end(), std::size_t(0));
    if (sub.size() > count) {
      std::mt19937_64 rng(20050620);
      for (std::size_t k = 0; k < count; ++k) {
        std::uniform_int_distribution<std::size_t> pick(k, sub.size() - 1);
        std::swap(sub[k], sub[pick(rng)]);
      }
      sub.resize(count);
      std::sort(sub.begin(), sub.end());
    }
    std::vector<std::size_t> out(sub.size());
    for (std::size_t k = 0; k < sub.size(); ++k) out[k] = sel.index[sub[k]];
    return out;
  };

  // --- initialisation ---------------------------------------------------
  std::vector<double> best_u;
  // Only a registered model's sum has lobes to switch off and add back.
  const Model* sum = model.AsModel();
  const bool search_sum = o.initial.empty() && sum && sum->LobeCount() >= 2;
  if (!o.initial.empty()) {
    if (o.initial.size() != n)
      throw std::invalid_argument("initial guess has " + std::to_string(o.initial.size()) + " values, model '" +
                                  info.name + "' needs " + std::to_string(n));
    best_u = plain.ToInternal(o.initial);
    clamp_internal(best_u);
    res.starts = 1;
  } else if (search_sum) {
    // Sums: nested sub-sums and the multi-start, each refined on all
    // samples (StartSearch); the best of these local optima is kept.
    const Prepared subset = Prepare(data, subset_index(o.start_subset), o);
    StartSearch search(*sum, o, layout, full, subset, sigma, res, elapsed);
    const Candidate best = search.Level(0, true);
    if (!std::isfinite(best.cost))
      throw std::runtime_error("no starting point gave a finite residual for model '" + info.name + "'");
    for (std::size_t q = 0; q < res.local_optima.size(); ++q)
      if (res.local_optima[q].params == best.p) res.kept = int(q);
    best_u = plain.ToInternal(best.p);
    clamp_internal(best_u);
  } else {
    // Starts: every combination of log-spaced values of the log-scale
    // parameters (at most 64; beyond that the diagonal of the grid), other
    // parameters at their defaults.
    std::vector<std::size_t> log_params;  // indices into info.params, free ones
    for (std::size_t i = 0; i < info.params.size(); ++i)
      if (info.params[i].scale == ParamInfo::Scale::kLog && layout.free_of[info.Offset(i)] >= 0 &&
          layout.leader[info.Offset(i)] < 0)
        log_params.push_back(i);
    const int K = std::max(1, o.starts_per_param);
    auto value = [&](std::size_t i, int k) {
      const ParamInfo& p = info.params[i];
      const double lower = layout.lo[info.Offset(i)], upper = layout.hi[info.Offset(i)];
      if (K == 1) return std::clamp(p.default_value, lower, upper);
      double l = std::max(lower > 0 ? lower : 0.0, p.default_value / 30.0);
      double h = std::min(upper, p.default_value * 30.0);
      if (!(l < h)) {  // bounds away from the default: span them
        l = lower > 0 ? lower : 1e-3 * upper;
        h = upper;
      }
      return std::exp(std::log(l) + (std::log(h) - std::log(l)) * k / (K - 1));
    };
    std::vector<std::vector<int>> combos;
    double total = 1;
    for (std::size_t j = 0; j < log_params.size(); ++j) total *= K;
    if (log_params.empty()) {
      combos.push_back({});
    } else if (total <= 64) {
      std::vector<int> c(log_params.size(), 0);
      while (true) {
        combos.push_back(c);
        std::size_t j = 0;
        while (j < c.size() && ++c[j] == K) c[j++] = 0;
        if (j == c.size()) break;
      }
    } else {
      for (int k = 0; k < K; ++k) combos.push_back(std::vector<int>(log_params.size(), k));
    }
    const Prepared subset = Prepare(data, subset_index(o.start_subset), o);
    double best_cost = std::numeric_limits<double>::infinity();
    for (const std::vector<int>& c : combos) {
      std::vector<double> p = layout.value;
      for (std::size_t j = 0; j < log_params.size(); ++j) {
        const std::size_t i = log_params[j];
        for (int ch = 0; ch < (info.params[i].colour ? 3 : 1); ++ch) p[info.Offset(i) + ch] = value(i, c[j]);
      }
      std::vector<double> u = plain.ToInternal(p);
      clamp_internal(u);
      ceres::Problem::Options po;
      ceres::Problem problem(po);
      BuildProblem(problem, plain, subset, chunk, u);
      ceres::Solver::Options so = SolverOptions(o, LinearSolver::kDenseQr, o.start_iterations);
      so.function_tolerance = 1e-8;
      so.update_state_every_iteration = sigma;  // the RMSE below reads u
      const int start = res.starts + 1;
      TraceCallback callback([&](const ceres::IterationSummary& s) {
        if (s.iteration > 0 && !s.step_is_successful) return;
        // Without sigma the plain engine's cost is the metric's sum of squares / 2.
        const double rmse = sigma ? Rmse(plain, subset, u) : std::sqrt(2 * s.cost / (3.0 * subset.size()));
        res.trace.push_back({s.iteration, elapsed(), s.cost, rmse, start, "start " + std::to_string(start) + " (subset)"});
      });
      so.callbacks.push_back(&callback);
      ceres::Solver::Summary summary;
      ceres::Solve(so, &problem, &summary);
      ++res.starts;
      if (summary.IsSolutionUsable() && summary.final_cost < best_cost) {
        best_cost = summary.final_cost;
        best_u = u;
      }
    }
    if (best_u.empty())
      throw std::runtime_error("no starting point gave a finite residual for model '" + info.name + "'");
  }

  // Coarse to fine: on large tables the best start is first refined on a
  // 16x larger subset, so the full solve (whose iterations cost the most)
  // starts near its optimum and needs only a few.
  if (o.initial.empty() && !search_sum && full.size() > 64 * o.start_subset) {
    const Prepared middle = Prepare(data, subset_index(16 * o.start_subset), o);
    ceres::Problem problem;
    std::vector<double> u = best_u;
    BuildProblem(problem, plain, middle, chunk, u);
    ceres::Solver::Options so = SolverOptions(o, LinearSolver::kDenseQr, o.max_iterations);
    so.function_tolerance = 1e-10;
    ceres::Solver::Summary summary;
    ceres::Solve(so, &problem, &summary);
    if (summary.IsSolutionUsable()) best_u = u;
  }

  // --- robust loss scale --------------------------------------------------
  double loss_scale = o.loss_scale;
  if (o.loss != Loss::kNone && !(loss_scale > 0)) {
    if (sigma) {
      loss_scale = 3.0;
    } else {
      std::vector<double> abs_r;
      abs_r.reserve(3 * full.size());
      double r[3];
      for (std::size_t q = 0; q < full.size(); ++q) {
        plain.EvalDouble(best_u.data(), full, q, q + 1, true, r);
        for (double x : r) abs_r.push_back(std::abs(x));
      }
      // 1.4826 MAD estimates a normal standard deviation; a zero MAD
      // (noiseless data) falls back to the RMS so the scale stays positive.
      loss_scale = 3.0 * 1.4826 * Median(abs_r);
      if (!(loss_scale > 0)) {
        double s = 0;
        for (double x : abs_r) s += x * x;
        loss_scale = std::max(3.0 * std::sqrt(s / std::max<std::size_t>(abs_r.size(), 1)), 1e-300);
      }
    }
  }
  res.loss_scale = o.loss != Loss::kNone ? loss_scale : 0.0;
  const Engine engine(model, o, loss_scale, layout);
  res.init_seconds = elapsed();

  // --- final solve on all samples -------------------------------------------
  std::vector<double> u = best_u;
  ceres::Problem::Options po;
  ceres::Problem problem(po);
  BuildProblem(problem, engine, full, chunk, u);
  ceres::Solver::Options so = SolverOptions(o, o.solver, o.max_iterations);
  const std::size_t m = 3 * full.size();
  const bool weights_are_metric = !sigma && o.loss == Loss::kNone;
  so.update_state_every_iteration = !weights_are_metric;
  TraceCallback callback([&](const ceres::IterationSummary& s) {
    if (s.iteration > 0 && !s.step_is_successful) return;
    TracePoint tp;
    tp.stage = "final";
    tp.iteration = s.iteration;
    tp.seconds = res.init_seconds + s.cumulative_time_in_seconds;
    tp.cost = s.cost;
    // Without sigma or a robust loss the cost is the metric's sum of squares / 2.
    tp.rmse = weights_are_metric ? std::sqrt(2 * s.cost / m) : Rmse(engine, full, u);
    res.trace.push_back(tp);
    if (o.progress) o.progress(s.iteration, tp.seconds, s.cost);
  });
  so.callbacks.push_back(&callback);
  ceres::Solver::Summary summary;
  ceres::Solve(so, &problem, &summary);
  res.solve_seconds = elapsed();

  res.params = engine.ToUser(u);
  res.cost = summary.final_cost;
  res.iterations = summary.num_successful_steps + summary.num_unsuccessful_steps;
  res.converged = summary.termination_type == ceres::CONVERGENCE;
  res.message = summary.message;
  if (summary.termination_type == ceres::FAILURE)
    res.message = "the solver failed: " + summary.message;
  res.residuals = m;
  // Residual variance: chi^2 / dof with sigma weights; otherwise the scale
  // of the unweighted residuals, which only the covariance uses.
  const double residual_variance = m > nf ? 2 * res.cost / static_cast<double>(m - nf) : 0.0;
  res.fixed.assign(n, false);
  res.tied_to.assign(n, "");
  for (std::size_t k = 0; k < n; ++k) {
    res.fixed[k] = layout.free_of[k] < 0;
    if (layout.leader[k] >= 0) res.tied_to[k] = res.packed_names[std::size_t(layout.leader[k])];
  }
  if (res.local_optima.empty()) {
    res.local_optima.push_back({res.cost, res.params, o.initial.empty() ? "multi-start" : "initial"});
    res.kept = 0;
  }
  res.chi2_reduced = sigma ? residual_variance : std::numeric_limits<double>::quiet_NaN();
  res.rmse = Rmse(engine, full, u);
  RelativeErrors(engine, full, res.params, res);
  if (!o.instrument && !data.apertures.empty())
    res.warnings.push_back("the data were measured through finite apertures (" + data.apertures +
                           ", sidecar '" + data.sidecar +
                           "'): a plain fit takes the aperture-averaged values for f_r and biases narrow lobes; "
                           "fit through the instrument (brdfkit fit --instrument " + data.sidecar +
                           ", or \"instrument\" in a scene's fit task)");
  // Residuals more than twice the stated noise (chi^2 / dof > 4): the model
  // does not describe the data, whatever the standard deviations say.
  if (sigma && residual_variance > 4)
    res.warnings.push_back("model mismatch: the residuals are " + FormatDouble(std::round(std::sqrt(residual_variance) * 10) / 10) +
                           " times the noise the data state (reduced chi-square " +
                           FormatDouble(std::round(residual_variance * 100) / 100) +
                           "); the standard deviations, statistical given the model, understate how far it is from "
                           "the material");

  // --- uncertainty ------------------------------------------------------------
  res.stddev.assign(n, std::numeric_limits<double>::quiet_NaN());
  if (o.covariance) {
    std::vector<std::string> free_names;
    for (std::size_t j = 0; j < nf; ++j) free_names.push_back(res.packed_names[layout.rep[j]]);
    if (m <= nf) {
      res.covariance_message = "no uncertainty: as many parameters as residuals";
    } else {
      const Eigen::MatrixXd jtj = NormalMatrix(engine, full, u, chunk);
      const std::string why = Identifiability(jtj, free_names);
      if (!why.empty()) {
        res.covariance_message = "no uncertainty: the problem is rank deficient: " + why;
      } else {
        // Covariance (J^T J)^-1 of the internal parameters from the dense
        // n x n normal matrix: the estimator ceres::Covariance computes, without
        // its sparse QR of the whole m x n Jacobian. Scaled to unit diagonal
        // first (the rank test above bounds its condition number by 1e12).
        const Eigen::VectorXd unit = jtj.diagonal().cwiseSqrt().cwiseInverse();
        const Eigen::MatrixXd a = unit.asDiagonal() * jtj * unit.asDiagonal();
        const Eigen::LDLT<Eigen::MatrixXd> ldlt(a);
        const auto nn = static_cast<Eigen::Index>(nf);
        const Eigen::MatrixXd cu =
            unit.asDiagonal() * ldlt.solve(Eigen::MatrixXd::Identity(nn, nn)) * unit.asDiagonal();
        if (ldlt.info() != Eigen::Success || !ldlt.isPositive() || !cu.allFinite()) {
          res.covariance_message =
              "no uncertainty: the covariance could not be computed (the Jacobian is numerically rank deficient)";
        } else {
          // Back to the user's parameters: dp/du = p for log-scale ones; a
          // fixed slot has no variance, a tied one its leader's.
          Eigen::MatrixXd jd = Eigen::MatrixXd::Zero(static_cast<Eigen::Index>(n), nn);
          for (std::size_t k = 0; k < n; ++k)
            if (const int j = layout.free_of[k]; j >= 0)
              jd(static_cast<Eigen::Index>(k), j) = engine.log_mask()[std::size_t(j)] ? res.params[k] : 1.0;
          Eigen::MatrixXd cp = jd * cu * jd.transpose();
          // Without measured sigma the residual variance sets the scale.
          if (!sigma) cp *= residual_variance;
          res.correlation.resize(n, n);
          for (std::size_t k = 0; k < n; ++k) res.stddev[k] = std::sqrt(std::max(0.0, cp(k, k)));
          for (std::size_t i = 0; i < n; ++i)
            for (std::size_t j = 0; j < n; ++j) {
              const double d = res.stddev[i] * res.stddev[j];
              res.correlation(i, j) = i == j ? 1.0 : (d > 0 ? cp(i, j) / d : 0.0);
            }
          res.covariance_ok = true;
          // Active bounds: the Gaussian uncertainty ignores them.
          std::string at_bound;
          for (std::size_t k = 0; k < nf; ++k)
            if (u[k] <= lo[k] || u[k] >= hi[k]) at_bound += (at_bound.empty() ? "" : ", ") + free_names[k];
          if (!at_bound.empty())
            res.covariance_message = "parameters at a bound (their uncertainty ignores the bound): " + at_bound;
        }
      }
    }
  } else {
    res.covariance_message = "uncertainty not computed (disabled)";
  }
  res.seconds = elapsed();
  return res;
}

}  // namespace

}  // namespace brdfkit::fit
