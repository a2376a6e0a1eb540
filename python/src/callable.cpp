#include "python/src/callable.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <deque>
#include <limits>
#include <unordered_map>

#include "brdf/astm.h"
#include "brdf/params.h"
#include "fit/jet_models.h"

namespace brdfkit::python {

PythonModel::~PythonModel() {
  if (!Py_IsInitialized()) {
    // The interpreter is gone: its objects cannot be released any more.
    eval.release();
    sample.release();
    pdf.release();
    width.release();
    return;
  }
  py::gil_scoped_acquire gil;
  eval = py::object();
  sample = py::object();
  pdf = py::object();
  width = py::object();
}

namespace {

// A thread's Python state kept between calls of Python functions from that
// thread, deleted when the thread ends (the tools' worker threads end with
// each call) while the interpreter still runs.
class KeptThreadState {
 public:
  void Keep(py::gil_scoped_acquire& gil) {
    if (kept_) return;
    gil.inc_ref();
    kept_ = true;
  }
  ~KeptThreadState() {
    // At interpreter shutdown the state goes with the interpreter.
    if (!kept_ || !Py_IsInitialized() || _Py_IsFinalizing()) return;
    py::gil_scoped_acquire gil;
    gil.dec_ref();
  }

 private:
  bool kept_ = false;
};

}  // namespace

bool CallState::Stopped() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return error_ || (token_ && token_->cancelled());
}

void CallState::Fail(std::exception_ptr e) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!error_) error_ = std::move(e);
}

void CallState::RethrowIfFailed() const {
  std::exception_ptr e;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    e = error_;
  }
  if (e) std::rethrow_exception(e);
}

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

std::string FunctionName(const py::handle& fn) {
  if (py::hasattr(fn, "__qualname__")) return py::str(fn.attr("__qualname__")).cast<std::string>();
  return py::repr(fn).cast<std::string>();
}

std::string ShapeOf(const py::array& a) {
  std::string s = "(";
  for (py::ssize_t d = 0; d < a.ndim(); ++d) s += (d ? ", " : "") + std::to_string(a.shape(d));
  return s + (a.ndim() == 1 ? ",)" : ")");
}

// Calls into the functions of one PythonModel for one tool run. Every call
// takes the GIL for its duration only (the tools run on worker threads with
// it released), so Python runs one call at a time.
class Caller {
 public:
  Caller(std::shared_ptr<const PythonModel> model, std::shared_ptr<CallState> state)
      : model_(std::move(model)), state_(std::move(state)) {}
  const PythonModel& model() const { return *model_; }

  // f_r of n pairs (rows of stride 3, or 0 to repeat one) into out[3 n]; on
  // a failure out is NaN and, in the fitter's mode, false is returned.
  bool Eval(const double* p, const double* wi, std::size_t wi_stride, const double* wo, std::size_t wo_stride,
            std::size_t n, double* out) const {
    const bool ok = Guarded([&] {
      py::array_t<double> a = Rows(wi, wi_stride, n, 3), b = Rows(wo, wo_stride, n, 3);
      const py::object r = Call(model_->eval, a, b, p);
      const py::array_t<double> f = Result(r, model_->eval, "eval", n, 3);
      std::copy(f.data(), f.data() + 3 * n, out);
    });
    if (!ok) std::fill(out, out + 3 * n, kNaN);
    return ok;
  }

  BsdfSample<double> Sample(const double* p, const Vec3<double>& wo, double u1, double u2) const {
    BsdfSample<double> s;
    Guarded([&] {
      const double uu[2] = {u1, u2};
      py::array_t<double> a = Rows(wo.data(), 0, 1, 3), u = Rows(uu, 0, 1, 2);
      const py::object r = Call(model_->sample, a, u, p);
      if (!py::isinstance<py::tuple>(r) || py::len(r) != 2)
        throw DtypeError(Name(model_->sample, "sample") + " must return a tuple (wi (N, 3), pdf (N,))");
      const py::tuple t = r.cast<py::tuple>();
      const py::array_t<double> wi = Result(py::object(t[0]), model_->sample, "sample (wi)", 1, 3);
      const py::array_t<double> pdf = Result(py::object(t[1]), model_->sample, "sample (pdf)", 1, 0);
      s.wi = Vec3<double>(wi.data()[0], wi.data()[1], wi.data()[2]);
      s.pdf = pdf.data()[0];
      s.valid = s.pdf > 0 && s.wi.z() > 0;
    });
    return s;
  }

  double Pdf(const double* p, const Vec3<double>& wo, const Vec3<double>& wi) const {
    double out = 0;
    Guarded([&] {
      py::array_t<double> a = Rows(wo.data(), 0, 1, 3), b = Rows(wi.data(), 0, 1, 3);
      out = Result(Call(model_->pdf, a, b, p), model_->pdf, "pdf", 1, 0).data()[0];
    });
    return out;
  }

  LobeWidth Width(const double* p) const {
    LobeWidth w;
    if (model_->width.is_none()) {
      if (!(model_->kind & LobeKind::kGlossy)) return w;
      // Measured from the function as for measured data.
      const double x = MeasuredLobeWidth([&](const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) {
        Rgb<double> f;
        Eval(p, wi.data(), 0, wo.data(), 0, 1, f.data());
        return f;
      });
      return {x, x};
    }
    Guarded([&] {
      py::object v = model_->width;
      if (PyCallable_Check(v.ptr())) v = model_->info.params.empty() ? v() : v(ParamsDict(p));
      const std::string what = Name(model_->width, "width");
      if (py::isinstance<py::float_>(v) || py::isinstance<py::int_>(v)) {
        w.x = w.y = v.cast<double>();
      } else if (py::isinstance<py::sequence>(v) && py::len(v) == 2) {
        w.x = v.cast<py::sequence>()[0].cast<double>();
        w.y = v.cast<py::sequence>()[1].cast<double>();
      } else {
        throw DtypeError(what + " must be a number or a pair (x, y) of lobe widths in radians");
      }
      if (!(w.x > 0 && w.y > 0 && std::isfinite(w.x) && std::isfinite(w.y)))
        throw ArgumentError(what + " must be positive and finite (got " + FormatDouble(w.x) + ", " +
                            FormatDouble(w.y) + ")");
    });
    return w;
  }

 private:
  // Runs body with the GIL; records a failure, and throws it unless in the fitter's mode.
  template <typename F>
  bool Guarded(F&& body) const {
    if (state_->Stopped()) {
      if (!state_->throws()) return false;
      state_->RethrowIfFailed();
      throw Cancelled();
    }
    try {
      py::gil_scoped_acquire gil;
      // The thread's Python state is kept after the first call: creating
      // and deleting one per call costs ten times the call of a small function.
      thread_local KeptThreadState kept;
      kept.Keep(gil);
      body();
      return true;
    } catch (...) {
      state_->Fail(std::current_exception());
      if (state_->throws()) throw;
      return false;
    }
  }

  std::string Name(const py::handle& fn, const char* role) const {
    return std::string(role).substr(0, std::string(role).find(' ')) + " function '" + FunctionName(fn) +
           "' of PythonModel '" + model_->info.name + "'";
  }

  py::dict ParamsDict(const double* p) const {
    py::dict d;
    for (std::size_t k = 0; k < model_->info.params.size(); ++k) d[py::str(model_->info.params[k].name)] = p[k];
    return d;
  }

  py::object Call(const py::object& fn, const py::array& a, const py::array& b, const double* p) const {
    if (model_->info.params.empty()) return fn(a, b);
    return fn(a, b, ParamsDict(p));
  }

  static py::array_t<double> Rows(const double* x, std::size_t stride, std::size_t n, int width) {
    py::array_t<double> a(std::vector<py::ssize_t>{static_cast<py::ssize_t>(n), width});
    double* o = a.mutable_data();
    for (std::size_t k = 0; k < n; ++k)
      for (int c = 0; c < width; ++c) o[k * width + c] = x[k * stride + c];
    return a;
  }

  // The result of a function as (n, cols) float64 (cols 0: shape (n,)),
  // checked: real numbers, that shape, finite.
  py::array_t<double> Result(const py::handle& r, const py::handle& fn, const char* role, std::size_t n,
                             int cols) const {
    const auto what = [&] { return Name(fn, role); };  // only on an error: it asks Python for the name
    py::array raw = py::array::ensure(r);
    if (!raw) throw DtypeError(what() + " must return a numpy array of numbers");
    const char kind = raw.dtype().kind();
    if (kind != 'f' && kind != 'i' && kind != 'u')
      throw DtypeError(what() + " returned dtype " + py::str(py::object(raw.dtype())).cast<std::string>() +
                       "; expected real numbers");
    const bool shape_ok = cols == 0 ? raw.ndim() == 1 && raw.shape(0) == py::ssize_t(n)
                                    : raw.ndim() == 2 && raw.shape(0) == py::ssize_t(n) && raw.shape(1) == cols;
    if (!shape_ok)
      throw ArgumentError(what() + " returned shape " + ShapeOf(raw) + " for " + std::to_string(n) +
                          " directions; expected (" + std::to_string(n) + (cols ? ", " + std::to_string(cols) : ",") +
                          ")");
    auto out = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(raw);
    const std::size_t size = n * std::size_t(std::max(cols, 1));
    for (std::size_t k = 0; k < size; ++k)
      if (!std::isfinite(out.data()[k]))
        throw ArgumentError(what() + " returned a non-finite value (" + FormatDouble(out.data()[k]) + ") in row " +
                            std::to_string(k / std::max(cols, 1)));
    return out;
  }

  std::shared_ptr<const PythonModel> model_;
  std::shared_ptr<CallState> state_;
};

// sum_k w[k] f(wi, wo[k]) with the n values from one call eval(rows, f)
// (rows: wo as rows of 3; a failed call leaves NaN, Caller::Eval).
template <class EvalRows>
Rgb<double> WeightedSum(const Vec3<double>* wo, const double* w, std::size_t n, const EvalRows& eval) {
  std::vector<double> rows(3 * n), f(3 * n);
  for (std::size_t k = 0; k < n; ++k) std::copy(wo[k].data(), wo[k].data() + 3, rows.data() + 3 * k);
  eval(rows.data(), f.data());
  Rgb<double> sum = Rgb<double>::Zero();
  for (std::size_t k = 0; k < n; ++k) sum += Rgb<double>(f[3 * k], f[3 * k + 1], f[3 * k + 2]) * w[k];
  return sum;
}

// A PythonModel as the tools' evaluator: batches go to Python in one call.
class PythonBxdf final : public Bxdf<double> {
 public:
  explicit PythonBxdf(std::shared_ptr<const Caller> caller) : c_(std::move(caller)) {}
  const ModelInfo& Info() const override { return c_->model().info; }
  Rgb<double> Eval(const double* p, const Vec3<double>& wi, const Vec3<double>& wo) const override {
    Rgb<double> f;
    c_->Eval(p, wi.data(), 0, wo.data(), 0, 1, f.data());
    return f;
  }
  Rgb<double> EvalSum(const double* p, const Vec3<double>& wi, const Vec3<double>* wo, const double* w,
                      std::size_t n) const override {
    return WeightedSum(wo, w, n, [&](const double* rows, double* f) { c_->Eval(p, wi.data(), 0, rows, 3, n, f); });
  }
  void EvalBatch(const double* p, const double* wi, std::size_t wi_stride, const double* wo, std::size_t wo_stride,
                 std::size_t n, double* out) const override {
    c_->Eval(p, wi, wi_stride, wo, wo_stride, n, out);
  }
  BsdfSample<double> Sample(const double* p, const Vec3<double>& wo, double u1, double u2) const override {
    if (!CanSample()) return {};
    return c_->Sample(p, wo, u1, u2);
  }
  double Pdf(const double* p, const Vec3<double>& wo, const Vec3<double>& wi) const override {
    if (!CanSample()) return 0;
    return c_->Pdf(p, wo, wi);
  }
  double SampleWeight(const double*) const override { return 1.0; }
  bool CanSample() const override { return !c_->model().sample.is_none(); }
  unsigned Kind() const override { return c_->model().kind; }
  LobeWidth Width(const double* p) const override { return c_->Width(p); }

 private:
  std::shared_ptr<const Caller> c_;
};

// --- the fitter's evaluators ---------------------------------------------

// Values and parameter derivatives of a PythonModel at every pair of a fit's
// data set: the fitter asks pair by pair, at one parameter vector for many
// pairs in a row, so the first request at a new vector evaluates the whole
// data set in one call (and 2 n more for the derivatives by central
// differences), and the following ones are looked up. Pairs outside the
// data set (an instrument's aperture nodes) are evaluated one by one.
class FitMemo {
 public:
  FitMemo(std::shared_ptr<const Caller> caller, const fit::Dataset& data) : c_(std::move(caller)) {
    n_ = c_->model().info.PackedSize();
    rows_ = data.samples.size();
    wi_.resize(3 * rows_);
    wo_.resize(3 * rows_);
    for (std::size_t k = 0; k < rows_; ++k) {
      // The fitter passes the data's directions as they are where all of
      // them are unit to rounding, else normalised (fit/metrics.cpp,
      // Prepare): both are keys of the row.
      const Eigen::Vector3d &ra = data.samples[k].wi, &rb = data.samples[k].wo;
      const Eigen::Vector3d a = ra.normalized(), b = rb.normalized();
      std::copy(a.data(), a.data() + 3, wi_.data() + 3 * k);
      std::copy(b.data(), b.data() + 3, wo_.data() + 3 * k);
      index_.emplace(Key(a.data(), b.data()), k);
      index_.emplace(Key(ra.data(), rb.data()), k);
    }
  }
  std::size_t n() const { return n_; }

  // f and, with dfdp, the derivatives (layout of Evaluate) of `rows` pairs
  // (wi, wo[k]) in one set of calls: an aperture's nodes, which are no pairs
  // of the data set.
  bool Many(const double* p, const double* wi, const double* wo, std::size_t rows, double* f, double* dfdp) const {
    return Evaluate(p, wi, 0, wo, rows, f, dfdp);
  }

  // f (3) and, with dfdp, the derivatives (3 per parameter, parameter major)
  // of pair (wi, wo) at parameters p; false after a failure.
  bool Get(const double* p, const double* wi, const double* wo, double* f, double* dfdp) {
    const auto it = index_.find(Key(wi, wo));
    if (it == index_.end()) return Evaluate(p, wi, 3, wo, 1, f, dfdp);
    std::lock_guard<std::mutex> lock(mutex_);
    const Entry* e = Find(p, dfdp != nullptr);
    if (!e) {
      Entry fresh;
      fresh.p.assign(p, p + n_);
      fresh.f.resize(3 * rows_);
      if (dfdp) fresh.dfdp.resize(3 * rows_ * n_);
      fresh.ok = Evaluate(p, wi_.data(), 3, wo_.data(), rows_, fresh.f.data(), dfdp ? fresh.dfdp.data() : nullptr);
      // A few vectors: the trust-region solver alternates between its point and a trial step.
      if (entries_.size() == 4) entries_.pop_front();
      entries_.push_back(std::move(fresh));
      e = &entries_.back();
    }
    const std::size_t k = it->second;
    std::copy(e->f.begin() + 3 * k, e->f.begin() + 3 * k + 3, f);
    if (dfdp)
      for (std::size_t j = 0; j < n_; ++j)
        std::copy(e->dfdp.begin() + 3 * (j * rows_ + k), e->dfdp.begin() + 3 * (j * rows_ + k) + 3, dfdp + 3 * j);
    return e->ok;
  }

 private:
  struct Entry {
    std::vector<double> p, f, dfdp;  // dfdp: parameter j, row k, channel c at 3 (j rows + k) + c
    bool ok = false;
  };
  using KeyType = std::array<double, 6>;
  struct KeyHash {
    std::size_t operator()(const KeyType& k) const {
      std::size_t h = 1469598103934665603ull;
      for (double x : k) {
        std::uint64_t b;
        std::memcpy(&b, &x, sizeof b);
        h = (h ^ b) * 1099511628211ull;
      }
      return h;
    }
  };
  static KeyType Key(const double* a, const double* b) { return {a[0], a[1], a[2], b[0], b[1], b[2]}; }

  const Entry* Find(const double* p, bool need_dfdp) const {
    for (const Entry& e : entries_)
      if ((!need_dfdp || !e.dfdp.empty()) && std::equal(e.p.begin(), e.p.end(), p)) return &e;
    return nullptr;
  }

  // Values of `rows` pairs at p and, with dfdp, central differences in each
  // parameter (one-sided at a bound, where the function may not be defined
  // beyond it).
  bool Evaluate(const double* p, const double* wi, std::size_t wi_stride, const double* wo, std::size_t rows,
                double* f, double* dfdp) const {
    if (!c_->Eval(p, wi, wi_stride, wo, 3, rows, f)) return false;
    if (!dfdp) return true;
    const ModelInfo& info = c_->model().info;
    std::vector<double> q(p, p + n_), up(3 * rows), down(3 * rows);
    for (std::size_t j = 0; j < n_; ++j) {
      // cbrt(eps) relative steps balance truncation and rounding for central
      // differences; 1e-3 keeps the step finite at p = 0.
      const double h = 6.0555e-6 * std::max(std::abs(p[j]), 1e-3);
      const bool can_up = p[j] + h <= info.params[j].upper, can_down = p[j] - h >= info.params[j].lower;
      q[j] = can_up ? p[j] + h : p[j];
      if (can_up && !c_->Eval(q.data(), wi, wi_stride, wo, 3, rows, up.data())) return false;
      q[j] = can_down ? p[j] - h : p[j];
      if (can_down && !c_->Eval(q.data(), wi, wi_stride, wo, 3, rows, down.data())) return false;
      q[j] = p[j];
      const double* hi = can_up ? up.data() : f;
      const double* lo = can_down ? down.data() : f;
      const double span = (can_up ? h : 0.0) + (can_down ? h : 0.0);
      double* d = dfdp + 3 * j * rows;
      for (std::size_t k = 0; k < 3 * rows; ++k) d[k] = span > 0 ? (hi[k] - lo[k]) / span : 0.0;
    }
    return true;
  }

  std::shared_ptr<const Caller> c_;
  std::size_t n_ = 0, rows_ = 0;
  std::vector<double> wi_, wo_;
  std::unordered_map<KeyType, std::size_t, KeyHash> index_;
  std::mutex mutex_;
  std::deque<Entry> entries_;
};

// f_r on double for the fitter: looked up in the memo.
class FitBxdf final : public Bxdf<double> {
 public:
  explicit FitBxdf(std::shared_ptr<FitMemo> memo, const ModelInfo& info) : memo_(std::move(memo)), info_(info) {}
  const ModelInfo& Info() const override { return info_; }
  Rgb<double> Eval(const double* p, const Vec3<double>& wi, const Vec3<double>& wo) const override {
    Rgb<double> f;
    memo_->Get(p, wi.data(), wo.data(), f.data(), nullptr);
    return f;
  }
  // An aperture's nodes (a fit through an instrument) in one call.
  Rgb<double> EvalSum(const double* p, const Vec3<double>& wi, const Vec3<double>* wo, const double* w,
                      std::size_t n) const override {
    return WeightedSum(wo, w, n, [&](const double* rows, double* f) { memo_->Many(p, wi.data(), rows, n, f, nullptr); });
  }
  BsdfSample<double> Sample(const double*, const Vec3<double>&, double, double) const override { return {}; }
  double Pdf(const double*, const Vec3<double>&, const Vec3<double>&) const override { return 0; }
  double SampleWeight(const double*) const override { return 1.0; }
  bool CanSample() const override { return false; }

 private:
  std::shared_ptr<FitMemo> memo_;
  const ModelInfo& info_;
};

// f_r on Jets for the fitter: values and derivatives from the memo, chained
// with the derivatives the Jet parameters carry (df/du = sum_j df/dp_j dp_j/du).
template <int N>
class FitJetBxdf final : public Bxdf<fit::Jet<N>> {
  using J = fit::Jet<N>;

 public:
  explicit FitJetBxdf(std::shared_ptr<FitMemo> memo, const ModelInfo& info) : memo_(std::move(memo)), info_(info) {}
  const ModelInfo& Info() const override { return info_; }
  Rgb<J> Eval(const J* p, const Vec3<J>& wi, const Vec3<J>& wo) const override {
    const std::array<double, 32> pa = Values(p);
    const double a[3] = {wi.x().a, wi.y().a, wi.z().a}, b[3] = {wo.x().a, wo.y().a, wo.z().a};
    double f[3];
    std::array<double, 3 * 32> d{};
    memo_->Get(pa.data(), a, b, f, d.data());
    return Chain(p, f, d.data());
  }
  // An aperture's nodes (a fit through an instrument) in one set of calls:
  // the weighted sums of the values and of their derivatives, chained as in Eval.
  Rgb<J> EvalSum(const J* p, const Vec3<J>& wi, const Vec3<J>* wo, const double* w, std::size_t m) const override {
    const std::size_t n = memo_->n();
    const std::array<double, 32> pa = Values(p);
    const double a[3] = {wi.x().a, wi.y().a, wi.z().a};
    std::vector<double> rows(3 * m), f(3 * m), d(3 * m * n);
    for (std::size_t k = 0; k < m; ++k)
      for (int c = 0; c < 3; ++c) rows[3 * k + std::size_t(c)] = wo[k][c].a;
    // After a failed call the tool stops; NaN until it does (a failed
    // difference call leaves the values finite and the derivatives unset).
    if (!memo_->Many(pa.data(), a, rows.data(), m, f.data(), d.data())) return Rgb<J>::Constant(J(kNaN));
    double fs[3] = {0, 0, 0};
    std::array<double, 3 * 32> ds{};
    for (std::size_t c = 0; c < 3; ++c) {
      for (std::size_t k = 0; k < m; ++k) fs[c] += w[k] * f[3 * k + c];
      for (std::size_t j = 0; j < n; ++j)
        for (std::size_t k = 0; k < m; ++k) ds[3 * j + c] += w[k] * d[3 * (j * m + k) + c];
    }
    return Chain(p, fs, ds.data());
  }
  BsdfSample<J> Sample(const J*, const Vec3<J>&, double, double) const override { return {}; }
  J Pdf(const J*, const Vec3<J>&, const Vec3<J>&) const override { return J(0); }
  double SampleWeight(const double*) const override { return 1.0; }
  bool CanSample() const override { return false; }

 private:
  // The parameters' values.
  std::array<double, 32> Values(const J* p) const {
    std::array<double, 32> pa{};
    for (std::size_t j = 0; j < memo_->n(); ++j) pa[j] = p[j].a;
    return pa;
  }
  // Values f (3) and derivatives d (3 per parameter, parameter major) chained
  // with the derivatives the Jet parameters carry.
  Rgb<J> Chain(const J* p, const double* f, const double* d) const {
    Rgb<J> out;
    for (int c = 0; c < 3; ++c) {
      out[c] = J(f[c]);
      for (std::size_t j = 0; j < memo_->n(); ++j) out[c].v += d[3 * j + std::size_t(c)] * p[j].v;
    }
    return out;
  }

  std::shared_ptr<FitMemo> memo_;
  const ModelInfo& info_;
};

class PythonEvaluators final : public fit::Evaluators {
 public:
  PythonEvaluators(std::shared_ptr<const PythonModel> model, std::shared_ptr<FitMemo> memo)
      : model_(std::move(model)), memo_(std::move(memo)) {}
  const ModelInfo& Info() const override { return model_->info; }
  std::unique_ptr<Bxdf<double>> MakeDouble() const override { return std::make_unique<FitBxdf>(memo_, Info()); }
  std::unique_ptr<Bxdf<fit::Jet<4>>> MakeJet4() const override { return Make<4>(); }
  std::unique_ptr<Bxdf<fit::Jet<8>>> MakeJet8() const override { return Make<8>(); }
  std::unique_ptr<Bxdf<fit::Jet<16>>> MakeJet16() const override { return Make<16>(); }
  std::unique_ptr<Bxdf<fit::Jet<32>>> MakeJet32() const override { return Make<32>(); }

 private:
  template <int N>
  std::unique_ptr<Bxdf<fit::Jet<N>>> Make() const {
    return std::make_unique<FitJetBxdf<N>>(memo_, Info());
  }
  std::shared_ptr<const PythonModel> model_;
  std::shared_ptr<FitMemo> memo_;
};

// --- tabulated functions ---------------------------------------------------

// Samples (wi, wo, f) looked up as the ASTM model does (brdf/astm.h
// SampleCloud): the nearest sample, or 1/d^2 weights of the 8 nearest;
// sampled by the cosine.
class TabulatedBxdf final : public Bxdf<double> {
 public:
  TabulatedBxdf(const std::vector<AngleSample>& rows, int neighbours, ModelInfo info)
      : cloud_(rows), neighbours_(neighbours), info_(std::move(info)) {
    width_ = MeasuredLobeWidth(
        [&](const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) { return cloud_.Lookup(wi, wo, neighbours_); });
  }
  const ModelInfo& Info() const override { return info_; }
  Rgb<double> Eval(const double*, const Vec3<double>& wi, const Vec3<double>& wo) const override {
    if (!SameUpperHemisphere(wi, wo)) return Rgb<double>::Zero();
    return cloud_.Lookup(wi, wo, neighbours_);
  }
  BsdfSample<double> Sample(const double* p, const Vec3<double>& wo, double u1, double u2) const override {
    return CosineSampling().Sample<double>(p, wo, u1, u2);
  }
  double Pdf(const double* p, const Vec3<double>& wo, const Vec3<double>& wi) const override {
    return CosineSampling().Pdf<double>(p, wo, wi);
  }
  double SampleWeight(const double*) const override { return 1.0; }
  unsigned Kind() const override { return LobeKind::kDiffuse | LobeKind::kGlossy; }
  LobeWidth Width(const double*) const override { return {width_, width_}; }
  bool ChannelsIndependent() const override { return true; }  // no parameters

 private:
  SampleCloud cloud_;
  int neighbours_;
  ModelInfo info_;
  double width_ = 1;
};

struct Tabulated {
  std::shared_ptr<const Bxdf<double>> bxdf;
  std::size_t size = 0;
  std::string interp;
};

Tabulated MakeTabulated(const py::object& wi_obj, const py::object& wo_obj, const py::object& f_obj,
                        const std::string& interp) {
  if (interp != "nearest" && interp != "idw")
    throw ArgumentError("interp must be 'nearest' or 'idw' (got '" + interp + "')");
  const Rows<double> wi = AsRows<double>(wi_obj, "wi", 3, true);
  const Rows<double> wo = AsRows<double>(wo_obj, "wo", 3, true);
  const Rows<double> f = AsRows<double>(f_obj, "f", 3, false);
  if (wi.single || wo.single || f.single || wi.n != wo.n || wi.n != f.n || wi.n == 0)
    throw ArgumentError("Tabulated: wi, wo and f must all have shape (N, 3) with the same N > 0 (got " +
                        std::to_string(wi.n) + ", " + std::to_string(wo.n) + " and " + std::to_string(f.n) +
                        " rows)");
  std::vector<AngleSample> rows(wi.n);
  for (std::size_t k = 0; k < wi.n; ++k) {
    const double* a = wi.data() + 3 * k;
    const double* b = wo.data() + 3 * k;
    AngleSample& s = rows[k];
    s.theta_i = std::acos(std::clamp(a[2], -1.0, 1.0));
    s.phi_i = std::atan2(a[1], a[0]);
    s.theta_o = std::acos(std::clamp(b[2], -1.0, 1.0));
    s.phi_o = std::atan2(b[1], b[0]);
    s.f = Rgb<double>(f.data()[3 * k], f.data()[3 * k + 1], f.data()[3 * k + 2]);
  }
  ModelInfo info;
  info.name = "tabulated";
  info.summary = "samples given as arrays (" + interp + " lookup)";
  info.reciprocal = false;  // measured or computed samples: not reciprocal by construction
  Tabulated t;
  t.bxdf = std::make_shared<const TabulatedBxdf>(rows, interp == "idw" ? 8 : 1, info);
  t.size = wi.n;
  t.interp = interp;
  return t;
}

// --- PythonModel construction ---------------------------------------------

double Number(const py::handle& v, const std::string& what) {
  if (!(py::isinstance<py::float_>(v) || py::isinstance<py::int_>(v) ||
        (py::isinstance<py::array>(v) && py::reinterpret_borrow<py::array>(v).ndim() == 0)))
    throw DtypeError(what + " must be a number");
  const double x = v.cast<double>();
  if (!std::isfinite(x)) throw ArgumentError(what + " must be finite (got " + FormatDouble(x) + ")");
  return x;
}

std::shared_ptr<PythonModel> MakePythonModel(const py::object& eval, const py::object& params,
                                             const py::object& sample, const py::object& pdf,
                                             const std::string& kind, const py::object& width,
                                             const std::string& name) {
  auto m = std::make_shared<PythonModel>();
  if (name.empty()) throw ArgumentError("PythonModel: name must not be empty");
  m->info.name = name;
  m->info.summary = "defined in Python by " + FunctionName(eval);
  m->info.reciprocal = true;
  if (!PyCallable_Check(eval.ptr())) throw DtypeError("PythonModel '" + name + "': eval must be callable");
  if (sample.is_none() != pdf.is_none())
    throw ArgumentError("PythonModel '" + name + "': give both sample and pdf, or neither");
  for (const auto& [fn, role] : {std::pair{&sample, "sample"}, std::pair{&pdf, "pdf"}})
    if (!fn->is_none() && !PyCallable_Check(fn->ptr()))
      throw DtypeError("PythonModel '" + name + "': " + role + " must be callable");
  if (kind == "diffuse") m->kind = LobeKind::kDiffuse;
  else if (kind == "glossy") m->kind = LobeKind::kGlossy;
  else if (kind == "diffuse+glossy") m->kind = LobeKind::kDiffuse | LobeKind::kGlossy;
  else
    throw ArgumentError("PythonModel '" + name + "': kind must be 'diffuse', 'glossy' or 'diffuse+glossy' (got '" +
                        kind + "')");
  if (!params.is_none()) {
    if (!py::isinstance<py::dict>(params))
      throw DtypeError("PythonModel '" + name +
                       "': params must be a dict {name: {\"default\": d, \"lower\": l, \"upper\": u}}");
    for (const auto& [key, spec] : params.cast<py::dict>()) {
      ParamInfo p;
      p.name = py::str(key).cast<std::string>();
      const std::string what = "PythonModel '" + name + "': parameter '" + p.name + "'";
      if (p.name.empty() || p.name.find_first_of("=,:+ ") != std::string::npos)
        throw ArgumentError(what + ": a name without '=', ',', ':', '+' or spaces");
      if (!py::isinstance<py::dict>(spec))
        throw DtypeError(what + " must be a dict with default, lower, upper (and optionally scale, meaning)");
      const py::dict d = spec.cast<py::dict>();
      for (const auto& [k, v] : d) {
        const std::string field = py::str(k).cast<std::string>();
        if (field != "default" && field != "lower" && field != "upper" && field != "scale" && field != "meaning")
          throw ArgumentError(what + ": unknown field '" + field +
                              "' (fields: default, lower, upper, scale, meaning)");
      }
      for (const char* field : {"default", "lower", "upper"})
        if (!d.contains(field)) throw ArgumentError(what + ": missing '" + field + "'");
      p.default_value = Number(py::object(d["default"]), what + " default");
      p.lower = Number(py::object(d["lower"]), what + " lower");
      p.upper = Number(py::object(d["upper"]), what + " upper");
      if (!(p.lower < p.upper) || p.default_value < p.lower || p.default_value > p.upper)
        throw ArgumentError(what + ": expected lower < upper and default in [lower, upper] (got default " +
                            FormatDouble(p.default_value) + ", range [" + FormatDouble(p.lower) + ", " +
                            FormatDouble(p.upper) + "])");
      if (d.contains("scale")) {
        const std::string scale = py::str(d["scale"]).cast<std::string>();
        if (scale == "log") p.scale = ParamInfo::Scale::kLog;
        else if (scale != "linear")
          throw ArgumentError(what + ": scale must be 'linear' or 'log' (got '" + scale + "')");
        if (p.scale == ParamInfo::Scale::kLog && !(p.upper > 0))
          throw ArgumentError(what + ": a log-scale parameter needs a positive upper bound");
      }
      if (d.contains("meaning")) p.meaning = py::str(d["meaning"]).cast<std::string>();
      m->info.params.push_back(p);
    }
  }
  m->eval = eval;
  m->sample = sample;
  m->pdf = pdf;
  m->width = width;
  if (!width.is_none() && !PyCallable_Check(width.ptr())) Number(width, "PythonModel '" + name + "': width");
  return m;
}

py::list ParamTable(const ModelInfo& info) {
  py::list out;
  for (const ParamInfo& p : info.params) {
    py::dict d;
    d["name"] = p.name;
    d["default"] = p.default_value;
    d["lower"] = p.lower;
    d["upper"] = p.upper;
    d["scale"] = p.scale == ParamInfo::Scale::kLog ? "log" : "linear";
    d["meaning"] = p.meaning;
    out.append(d);
  }
  return out;
}

}  // namespace

ToolModel ToolModelArgument(const py::object& model, const py::object& params) {
  ToolModel t;
  if (py::isinstance<PythonModel>(model)) {
    const auto pm = model.cast<std::shared_ptr<PythonModel>>();
    t.spec = pm->info.name;
    t.params = ParseParams(pm->info, ParamsText(params));
    t.calls = std::make_shared<CallState>(true);
    t.bxdf = std::make_shared<PythonBxdf>(std::make_shared<const Caller>(pm, t.calls));
    return t;
  }
  if (py::isinstance<Tabulated>(model)) {
    if (!params.is_none()) throw ArgumentError("a Tabulated has no parameters (got params)");
    const Tabulated& tab = model.cast<const Tabulated&>();
    t.spec = "tabulated";
    t.bxdf = tab.bxdf;
    return t;
  }
  if (!py::isinstance<PyModel>(model) && !py::isinstance<py::str>(model))
    throw DtypeError("model must be a brdfkit.Model, a model name such as 'lambert+ggx', a PythonModel or a "
                     "Tabulated");
  const PyModel m = ModelArgument(model, params);
  t.spec = m.model.Spec();
  t.params = m.params;
  t.bxdf = m.bxdf;
  t.settings = m.settings;
  return t;
}

void RunTool(const ToolModel& m, int threads, const std::function<void(const CancelToken&)>& work) {
  try {
    RunReleased(threads, [&](const CancelToken& token) {
      if (m.calls) m.calls->set_token(&token);
      work(token);
    });
  } catch (...) {
    if (m.calls) m.calls->RethrowIfFailed();
    throw;
  }
  // A tool may have caught an exception of a call and gone on (a failed step).
  if (m.calls) m.calls->RethrowIfFailed();
}

std::unique_ptr<fit::Evaluators> FitEvaluators(const std::shared_ptr<const PythonModel>& model,
                                               const fit::Dataset& data, const std::shared_ptr<CallState>& calls) {
  auto memo = std::make_shared<FitMemo>(std::make_shared<const Caller>(model, calls), data);
  return std::make_unique<PythonEvaluators>(model, std::move(memo));
}

void BindCallables(py::module_& m) {
  py::class_<PythonModel, std::shared_ptr<PythonModel>>(m, "PythonModel",
                                                        R"doc(A BRDF defined by Python functions on numpy arrays.

check, albedo_table, synth and fit take it wherever they take a Model, with
its parameter values in their ``params`` argument (defaults otherwise).

Parameters
----------
eval : callable
    ``eval(wi, wo, params) -> (N, 3)``: f_r in 1/sr per RGB channel (no
    cosine) for unit directions wi, wo of shape (N, 3) (local frame, z the
    normal); ``params`` is a dict {name: float}. Without parameters it is
    called as ``eval(wi, wo)``.
params : dict, optional
    ``{name: {"default": d, "lower": l, "upper": u, "scale": "linear" or
    "log", "meaning": text}}``: scalar parameters with their range (the
    fitter's bounds and the albedo axes' range) and the scale the fitter
    moves them on ("log" for roughness-like parameters, which also get the
    fit's multi-start).
sample, pdf : callable, optional
    ``sample(wo, u, params) -> (wi (N, 3), pdf (N,))`` for u of shape (N, 2)
    in [0, 1), and ``pdf(wo, wi, params) -> (N,)``, the solid-angle
    density of sample. Both or neither: without them check skips the
    sampling tests and says so in ``sampling_note``.
kind : {"diffuse+glossy", "diffuse", "glossy"}
    What the lobes are; a glossy lobe makes the albedo quadrature work
    over the half vector with the lobe width below.
width : float, callable or None
    Angular width in radians of the narrowest glossy lobe (on the scale of
    a microfacet alpha), a pair (x, y), or ``width(params)`` returning one;
    None measures it from eval (where f_r cos falls to half at normal view).
name : str
    The model's name in results.

Notes
-----
The tools call the functions on batches where they evaluate many pairs
(one call per data set and parameter vector in a fit) and pair by pair
elsewhere (the albedo quadrature, sampling), taking the GIL for each call.
A fit differentiates by central differences in the parameters (one-sided
at a bound), from 2 n + 1 calls per parameter vector. An exception raised
by a function stops the tool and is raised as itself; a result of the
wrong shape, dtype or with non-finite values raises ValueError or
TypeError naming the function.
)doc")
      .def(py::init(&MakePythonModel), py::arg("eval"), py::arg("params") = py::none(),
           py::arg("sample") = py::none(), py::arg("pdf") = py::none(), py::arg("kind") = "diffuse+glossy",
           py::arg("width") = py::none(), py::arg("name") = "python")
      .def_property_readonly("name", [](const PythonModel& p) { return p.info.name; }, "The model's name.")
      .def_property_readonly("params", [](const PythonModel& p) { return ParamTable(p.info); },
                             "Parameter table: name, default, lower, upper, scale, meaning.")
      .def_property_readonly("can_sample", [](const PythonModel& p) { return !p.sample.is_none(); },
                             "Whether sample and pdf were given.")
      .def("__repr__", [](const PythonModel& p) {
        return "brdfkit.PythonModel('" + p.info.name + "', " + std::to_string(p.info.params.size()) +
               " parameters" + (p.sample.is_none() ? "" : ", sampled") + ")";
      });

  py::class_<Tabulated>(m, "Tabulated", R"doc(A BRDF given as samples: f_r at direction pairs.

check, albedo_table and synth take it wherever they take a Model. The
lookup is that of the ASTM model: the sample nearest to (wi, wo) as a
6-vector, or inverse-square-distance weights of the 8 nearest ("idw"); a
measurement with one incident azimuth is rotated to it first (isotropy).
f_r is 0 when wi or wo is below the horizon; sampling is cosine-weighted.

Parameters
----------
wi, wo : array_like, shape (N, 3)
    Unit directions towards the light and towards the detector.
f : array_like, shape (N, 3)
    f_r in 1/sr per RGB channel.
interp : {"nearest", "idw"}
)doc")
      .def(py::init(&MakeTabulated), py::arg("wi"), py::arg("wo"), py::arg("f"), py::arg("interp") = "nearest")
      .def_property_readonly("size", [](const Tabulated& t) { return t.size; }, "Number of samples.")
      .def_property_readonly("interp", [](const Tabulated& t) { return t.interp; }, "The lookup.")
      .def(
          "eval",
          [](const Tabulated& t, const py::object& wi_obj, const py::object& wo_obj) {
            const Rows<double> wi = AsRows<double>(wi_obj, "wi", 3, true);
            const Rows<double> wo = AsRows<double>(wo_obj, "wo", 3, true);
            const std::size_t n = BroadcastRows("wi", wi.n, wi.single, "wo", wo.n, wo.single);
            py::array_t<double> out = NewRows<double>(n, 3, wi.single && wo.single);
            t.bxdf->EvalBatch(nullptr, wi.data(), wi.stride, wo.data(), wo.stride, n, out.mutable_data());
            return out;
          },
          py::arg("wi"), py::arg("wo"), "The looked-up f_r, shape (N, 3) or (3,), as Model.eval.")
      .def("__repr__", [](const Tabulated& t) {
        return "brdfkit.Tabulated(" + std::to_string(t.size) + " samples, '" + t.interp + "')";
      });
}

}  // namespace brdfkit::python
