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
#include <numeric>
#include <random>
#include <sstream>
#include <stdexcept>
#include <thread>

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

class Engine {
 public:
  Engine(const Evaluators& model, const Options& o, double loss_scale)
      : metric_(o.metric), loss_(o.loss), loss_scale_(loss_scale) {
    const ModelInfo& info = model.Info();
    n_ = info.PackedSize();
    for (const ParamInfo& p : info.params)
      for (int c = 0; c < (p.colour ? 3 : 1); ++c) log_.push_back(p.scale == ParamInfo::Scale::kLog);
    if (n_ > 32)
      throw std::invalid_argument("model '" + info.name + "' has " + std::to_string(n_) +
                                  " packed parameters; fitting supports at most 32");
    b_ = model.MakeDouble();
    // Derivative slots: one per scalar parameter and one per colour
    // parameter, shared by its r, g, b slots. Channel c of f_r depends only
    // on slot c of each colour parameter (the models declare it), so the shared
    // slot's derivative in channel c is the derivative by the c slot: Jets
    // of 3 slots instead of 7 for lambert+ggx.
    for (const ParamInfo& p : info.params)
      for (int c = 0; c < (p.colour ? 3 : 1); ++c) {
        slot_.push_back(n_slots_);
        channel_.push_back(p.colour ? c : -1);
        if (c == (p.colour ? 2 : 0)) ++n_slots_;
      }
    const bool shared = n_slots_ < n_ && b_->ChannelsIndependent();
    if (!shared) {
      for (std::size_t k = 0; k < n_; ++k) {
        slot_[k] = k;
        channel_[k] = -1;
      }
      n_slots_ = n_;
    }
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

  std::size_t n() const { return n_; }
  int jet() const { return jet_; }
  const std::vector<bool>& log_mask() const { return log_; }

  // Internal (optimised) -> user parameters.
  template <class T>
  void ToUser(const T* u, T* p) const {
    using std::exp;
    for (std::size_t k = 0; k < n_; ++k) p[k] = log_[k] ? exp(u[k]) : u[k];
  }
  std::vector<double> ToUser(const std::vector<double>& u) const {
    std::vector<double> p(n_);
    ToUser(u.data(), p.data());
    return p;
  }
  std::vector<double> ToInternal(const std::vector<double>& p) const {
    std::vector<double> u(n_);
    for (std::size_t k = 0; k < n_; ++k) u[k] = log_[k] ? std::log(p[k]) : p[k];
    return u;
  }

  // Residuals of sample q: out[3]. fit: fit weights and robust loss; else
  // the plain metric.
  template <class T>
  void SampleResiduals(const Bxdf<T>& b, const T* p, const Prepared& d, std::size_t q, bool fit, T* out) const {
    const Rgb<T> f = Prediction(b, p, d, q);
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
    for (std::size_t q = begin; q < end; ++q) SampleResiduals(*b_, p.data(), d, q, fit, r + 3 * (q - begin));
    for (std::size_t k = 0; k < 3 * (end - begin); ++k)
      if (!std::isfinite(r[k])) return false;
    return true;
  }

  // Residuals and their Jacobian (row-major, 3 (end - begin) x n).
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
    std::array<Jet<N>, 32> uj, pj;
    for (std::size_t k = 0; k < n_; ++k) uj[k] = Jet<N>(u[k], static_cast<int>(slot_[k]));
    ToUser(uj.data(), pj.data());
    for (std::size_t q = begin; q < end; ++q) {
      Jet<N> res[3];
      SampleResiduals(b, pj.data(), d, q, true, res);
      for (int c = 0; c < 3; ++c) {
        const std::size_t row = 3 * (q - begin) + c;
        r[row] = res[c].a;
        if (!std::isfinite(r[row])) return false;
        if (jac) {
          for (std::size_t k = 0; k < n_; ++k) {
            const double v = channel_[k] < 0 || channel_[k] == c ? res[c].v[slot_[k]] : 0.0;
            if (!std::isfinite(v)) return false;
            jac[row * n_ + k] = v;
          }
        }
      }
    }
    return true;
  }

  Metric metric_;
  Loss loss_;
  double loss_scale_;
  std::size_t n_ = 0;
  std::vector<std::size_t> slot_;  // derivative slot of each packed parameter
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

// Bounds of the internal parameters.
void Bounds(const ModelInfo& info, const std::vector<bool>& log_mask, std::vector<double>& lo,
            std::vector<double>& hi) {
  for (const ParamInfo& p : info.params)
    for (int c = 0; c < (p.colour ? 3 : 1); ++c) {
      const std::size_t k = lo.size();
      if (log_mask[k]) {
        // A log-scale parameter must stay positive: a zero lower bound is
        // replaced by a tiny fraction of the upper one.
        const double l = p.lower > 0 ? p.lower : std::max(1e-12 * p.upper, 1e-300);
        lo.push_back(std::log(l));
        hi.push_back(std::log(p.upper));
      } else {
        lo.push_back(p.lower);
        hi.push_back(p.upper);
      }
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
                  const ModelInfo& info, std::vector<double>& u) {
  problem.AddParameterBlock(u.data(), static_cast<int>(u.size()));
  for (std::size_t b = 0; b < d.size(); b += chunk)
    problem.AddResidualBlock(new ChunkCost(&e, &d, b, std::min(d.size(), b + chunk)), nullptr, u.data());
  std::vector<double> lo, hi;
  Bounds(info, e.log_mask(), lo, hi);
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

// Root mean square of the plain metric residuals.
double Rmse(const Engine& e, const Prepared& d, const std::vector<double>& u, int threads) {
  if (d.size() == 0) return 0;
  const std::size_t workers = static_cast<std::size_t>(std::max(1, threads));
  std::vector<double> sums(workers, 0.0);
  std::vector<std::thread> pool;
  for (std::size_t w = 0; w < workers; ++w)
    pool.emplace_back([&, w] {
      const std::size_t begin = d.size() * w / workers, end = d.size() * (w + 1) / workers;
      double r[3];
      double s = 0;
      for (std::size_t q = begin; q < end; ++q) {
        // Plain double evaluation of the metric residual.
        e.EvalDouble(u.data(), d, q, q + 1, false, r);
        s += r[0] * r[0] + r[1] * r[1] + r[2] * r[2];
      }
      sums[w] = s;
    });
  for (auto& t : pool) t.join();
  return std::sqrt(std::accumulate(sums.begin(), sums.end(), 0.0) / (3.0 * d.size()));
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
void RelativeErrors(const Engine& e, const Prepared& d, const std::vector<double>& p, int threads, Result& res) {
  const std::size_t n = d.size();
  std::vector<Eigen::Array3d> pred(n);
  const std::size_t workers = static_cast<std::size_t>(std::max(1, threads));
  std::vector<std::thread> pool;
  for (std::size_t w = 0; w < workers; ++w)
    pool.emplace_back([&, w] {
      for (std::size_t q = n * w / workers; q < n * (w + 1) / workers; ++q) pred[q] = e.Predict(p, d, q);
    });
  for (auto& t : pool) t.join();
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
Eigen::MatrixXd NormalMatrix(const Engine& e, const Prepared& d, const std::vector<double>& u, std::size_t chunk,
                             int threads) {
  const std::size_t n = e.n();
  const std::size_t workers = static_cast<std::size_t>(std::max(1, threads));
  std::vector<Eigen::MatrixXd> parts(workers, Eigen::MatrixXd::Zero(n, n));
  const std::size_t blocks = (d.size() + chunk - 1) / chunk;
  std::vector<std::thread> pool;
  for (std::size_t w = 0; w < workers; ++w)
    pool.emplace_back([&, w] {
      std::vector<double> r(3 * chunk), jac(3 * chunk * n);
      for (std::size_t b = w; b < blocks; b += workers) {
        const std::size_t begin = b * chunk, end = std::min(d.size(), begin + chunk);
        e.EvalJacobian(u.data(), d, begin, end, r.data(), jac.data());
        Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>> J(
            jac.data(), static_cast<Eigen::Index>(3 * (end - begin)), static_cast<Eigen::Index>(n));
        parts[w].noalias() += J.transpose() * J;
      }
    });
  for (auto& t : pool) t.join();
  Eigen::MatrixXd out = Eigen::MatrixXd::Zero(n, n);
  for (const auto& m : parts) out += m;
  return out;
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

}  // namespace

double MetricRmse(const Model& model, const std::vector<double>& params, const Dataset& data,
                  const Options& options) {
  const Selection sel = Select(data, options);
  const Prepared d = Prepare(data, sel.index, options);
  const Engine e(ModelEvaluators(model), options, 1.0);
  return Rmse(e, d, e.ToInternal(params), options.num_threads);
}

struct ResidualBlocks::Impl {
  Impl(const Model& model, const Dataset& data, const Options& o, double loss_scale)
      : engine(ModelEvaluators(model), o, loss_scale), prepared(Prepare(data, Select(data, o).index, o)) {
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

Result Fit(const Evaluators& model, const Dataset& data, const Options& options) {
  // More worker threads than hardware threads only cost memory and start-up
  // (a count such as 100000 would exhaust the process's thread limit).
  Options o = options;
  o.num_threads = std::clamp(o.num_threads, 1, int(std::max(1u, std::thread::hardware_concurrency())));
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
  Options plain_options = o;
  plain_options.loss = Loss::kNone;
  const Engine plain(model, plain_options, 1.0);

  std::vector<double> lo, hi;
  Bounds(info, plain.log_mask(), lo, hi);
  auto clamp_internal = [&](std::vector<double>& u) {
    for (std::size_t k = 0; k < n; ++k) u[k] = std::clamp(u[k], lo[k], hi[k]);
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
  if (!o.initial.empty()) {
    if (o.initial.size() != n)
      throw std::invalid_argument("initial guess has " + std::to_string(o.initial.size()) + " values, model '" +
                                  info.name + "' needs " + std::to_string(n));
    best_u = plain.ToInternal(o.initial);
    clamp_internal(best_u);
    res.starts = 1;
  } else {
    // Starts: every combination of log-spaced values of the log-scale
    // parameters (at most 64; beyond that the diagonal of the grid), other
    // parameters at their defaults.
    std::vector<std::size_t> log_params;  // indices into info.params
    for (std::size_t i = 0; i < info.params.size(); ++i)
      if (info.params[i].scale == ParamInfo::Scale::kLog) log_params.push_back(i);
    const int K = std::max(1, o.starts_per_param);
    auto value = [&](std::size_t i, int k) {
      const ParamInfo& p = info.params[i];
      if (K == 1) return p.default_value;
      const double l = std::max(p.lower > 0 ? p.lower : 0.0, p.default_value / 30.0);
      const double h = std::min(p.upper, p.default_value * 30.0);
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
    const std::vector<double> defaults = info.Defaults();
    for (const std::vector<int>& c : combos) {
      std::vector<double> p = defaults;
      for (std::size_t j = 0; j < log_params.size(); ++j) {
        const std::size_t i = log_params[j];
        for (int ch = 0; ch < (info.params[i].colour ? 3 : 1); ++ch) p[info.Offset(i) + ch] = value(i, c[j]);
      }
      std::vector<double> u = plain.ToInternal(p);
      clamp_internal(u);
      ceres::Problem::Options po;
      ceres::Problem problem(po);
      BuildProblem(problem, plain, subset, chunk, info, u);
      ceres::Solver::Options so = SolverOptions(o, LinearSolver::kDenseQr, o.start_iterations);
      so.function_tolerance = 1e-8;
      so.update_state_every_iteration = sigma;  // the RMSE below reads u
      const int start = res.starts + 1;
      TraceCallback callback([&](const ceres::IterationSummary& s) {
        if (s.iteration > 0 && !s.step_is_successful) return;
        // Without sigma the plain engine's cost is the metric's sum of squares / 2.
        const double rmse = sigma ? Rmse(plain, subset, u, o.num_threads) : std::sqrt(2 * s.cost / (3.0 * subset.size()));
        res.trace.push_back({s.iteration, elapsed(), s.cost, rmse, start});
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
  if (o.initial.empty() && full.size() > 64 * o.start_subset) {
    const Prepared middle = Prepare(data, subset_index(16 * o.start_subset), o);
    ceres::Problem problem;
    std::vector<double> u = best_u;
    BuildProblem(problem, plain, middle, chunk, info, u);
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
  const Engine engine(model, o, loss_scale);
  res.init_seconds = elapsed();

  // --- final solve on all samples -------------------------------------------
  std::vector<double> u = best_u;
  ceres::Problem::Options po;
  ceres::Problem problem(po);
  BuildProblem(problem, engine, full, chunk, info, u);
  ceres::Solver::Options so = SolverOptions(o, o.solver, o.max_iterations);
  const std::size_t m = 3 * full.size();
  const bool weights_are_metric = !sigma && o.loss == Loss::kNone;
  so.update_state_every_iteration = !weights_are_metric;
  TraceCallback callback([&](const ceres::IterationSummary& s) {
    if (s.iteration > 0 && !s.step_is_successful) return;
    TracePoint tp;
    tp.iteration = s.iteration;
    tp.seconds = res.init_seconds + s.cumulative_time_in_seconds;
    tp.cost = s.cost;
    // Without sigma or a robust loss the cost is the metric's sum of squares / 2.
    tp.rmse = weights_are_metric ? std::sqrt(2 * s.cost / m) : Rmse(engine, full, u, o.num_threads);
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
  const double residual_variance = m > n ? 2 * res.cost / static_cast<double>(m - n) : 0.0;
  res.chi2_reduced = sigma ? residual_variance : std::numeric_limits<double>::quiet_NaN();
  res.rmse = Rmse(engine, full, u, o.num_threads);
  RelativeErrors(engine, full, res.params, o.num_threads, res);
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
    if (m <= n) {
      res.covariance_message = "no uncertainty: as many parameters as residuals";
    } else {
      const Eigen::MatrixXd jtj = NormalMatrix(engine, full, u, chunk, o.num_threads);
      const std::string why = Identifiability(jtj, res.packed_names);
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
        const auto nn = static_cast<Eigen::Index>(n);
        const Eigen::MatrixXd cu =
            unit.asDiagonal() * ldlt.solve(Eigen::MatrixXd::Identity(nn, nn)) * unit.asDiagonal();
        if (ldlt.info() != Eigen::Success || !ldlt.isPositive() || !cu.allFinite()) {
          res.covariance_message =
              "no uncertainty: the covariance could not be computed (the Jacobian is numerically rank deficient)";
        } else {
          // Back to the user's parameters: dp/du = p for log-scale ones.
          Eigen::VectorXd jd(n);
          for (std::size_t k = 0; k < n; ++k) jd(k) = engine.log_mask()[k] ? res.params[k] : 1.0;
          Eigen::MatrixXd cp = jd.asDiagonal() * cu * jd.asDiagonal();
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
          for (std::size_t k = 0; k < n; ++k)
            if (u[k] <= lo[k] || u[k] >= hi[k]) at_bound += (at_bound.empty() ? "" : ", ") + res.packed_names[k];
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

}  // namespace brdfkit::fit
