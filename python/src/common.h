// Shared pieces of the Python extension: numpy arguments checked into
// direction arrays, JSON to Python objects, and long C++ calls run with the
// GIL released, interruptible by Ctrl-C and on a chosen number of threads.
#pragma once

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <nlohmann/json.hpp>

#include <atomic>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "brdf/model.h"
#include "brdf/params.h"

namespace brdfkit::python {

namespace py = pybind11;

// An argument error: ValueError in Python (bad shape, non-finite value).
class ArgumentError : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};
// A non-numeric array: TypeError in Python.
class DtypeError : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

// Rows of an (n, 3) array of unit directions, or one direction (stride 0).
template <typename T>
struct Rows {
  py::array_t<T, py::array::c_style | py::array::forcecast> array;
  std::size_t n = 1;
  std::size_t stride = 3;  // 0: one row for every pair
  bool single = false;     // given as shape (width,)
  const T* data() const { return array.data(); }
};

// True when the argument is a float32 array (the single-precision models run).
bool IsFloat32(const py::handle& obj);

// Checks obj as rows of `width` finite numbers ((width,) or (n, width));
// unit = true also requires |row| = 1 within a relative 1e-5 (float32
// rounding), since the models take unit directions.
template <typename T>
Rows<T> AsRows(const py::handle& obj, const char* name, int width, bool unit);
// AsRows in two steps, for callers that check the values later, chunk by
// chunk, alongside the work: the shape and conversion (no copy of a
// C-contiguous array of type T), then the values (raises as AsRows).
template <typename T>
Rows<T> AsRowsUnchecked(const py::handle& obj, const char* name, int width);
template <typename T>
void CheckRows(const Rows<T>& r, const char* name, int width, bool unit);
// Whether rows of three are finite unit vectors as AsRows requires (no
// message, no Python call: runs with the GIL released).
template <typename T>
bool UnitRows(const T* d, std::size_t rows);

// The common row count of arguments that broadcast (a single row repeats).
std::size_t BroadcastRows(const char* a, std::size_t na, bool single_a, const char* b, std::size_t nb, bool single_b);

// An (n, width) array, or (width,) when every input was a single row.
template <typename T>
py::array_t<T> NewRows(std::size_t n, int width, bool single);

// JSON to Python (dict, list, float, int, str, bool, None).
py::object ToPython(const nlohmann::json& j);

// Raised by a progress callback or a model wrapper when Ctrl-C was pressed.
struct Cancelled : std::exception {
  const char* what() const noexcept override { return "interrupted"; }
};

// Cancellation flag of one long call.
class CancelToken {
 public:
  void Cancel() { flag_.store(true, std::memory_order_relaxed); }
  bool cancelled() const { return flag_.load(std::memory_order_relaxed); }
  void ThrowIfCancelled() const {
    if (cancelled()) throw Cancelled();
  }

 private:
  std::atomic<bool> flag_{false};
};

// Runs work(token) on a worker thread inside a TBB arena of `threads`
// threads (<= 0: every core) with the GIL released. The calling thread
// checks for signals every 50 ms; on Ctrl-C it cancels the token, waits for
// the work to stop, and raises KeyboardInterrupt. Exceptions of the work are
// rethrown in the caller.
void RunReleased(int threads, const std::function<void(const CancelToken&)>& work);

// A Bxdf<double> that stops (throws Cancelled) once its token is cancelled:
// lets validate::CheckPlausibility and the albedo quadrature be interrupted.
class CancellableBxdf final : public Bxdf<double> {
 public:
  CancellableBxdf(const Bxdf<double>& base, const CancelToken& token) : base_(base), token_(token) {}
  const ModelInfo& Info() const override { return base_.Info(); }
  Rgb<double> Eval(const double* p, const Vec3<double>& wi, const Vec3<double>& wo) const override {
    token_.ThrowIfCancelled();
    return base_.Eval(p, wi, wo);
  }
  Rgb<double> EvalSum(const double* p, const Vec3<double>& wi, const Vec3<double>* wo, const double* w,
                      std::size_t n) const override {
    token_.ThrowIfCancelled();
    return base_.EvalSum(p, wi, wo, w, n);
  }
  void EvalBatch(const double* p, const double* wi, std::size_t wi_stride, const double* wo, std::size_t wo_stride,
                 std::size_t n, double* out) const override {
    token_.ThrowIfCancelled();
    base_.EvalBatch(p, wi, wi_stride, wo, wo_stride, n, out);
  }
  BsdfSample<double> Sample(const double* p, const Vec3<double>& wo, double u1, double u2) const override {
    token_.ThrowIfCancelled();
    return base_.Sample(p, wo, u1, u2);
  }
  double Pdf(const double* p, const Vec3<double>& wo, const Vec3<double>& wi) const override {
    return base_.Pdf(p, wo, wi);
  }
  double SampleWeight(const double* p) const override { return base_.SampleWeight(p); }
  bool CanSample() const override { return base_.CanSample(); }
  unsigned Kind() const override { return base_.Kind(); }
  LobeWidth Width(const double* p) const override { return base_.Width(p); }
  bool ChannelsIndependent() const override { return base_.ChannelsIndependent(); }
  const MicrofacetView<double>* Microfacet() const override { return base_.Microfacet(); }

 private:
  const Bxdf<double>& base_;
  const CancelToken& token_;
};

// A registered model (or sum) with its parameter values, as the Python
// `Model` class holds it. Immutable, so several Python threads may share it.
struct PyModel {
  Model model;
  std::vector<double> params;
  std::vector<float> params_f;
  std::shared_ptr<const Bxdf<double>> bxdf;
  std::shared_ptr<const Bxdf<float>> bxdf_f;
  Settings settings;  // as given (e.g. path of a measured model)
};

// spec: "ggx", "lambert+ggx", "merl:FILE"; params: None, "name=value,...",
// or a dict {name: value or (r, g, b)} (settings such as path included).
PyModel MakeModel(const std::string& spec, const py::object& params);
// A Model argument of the tools: a PyModel, or a model name (params apply).
PyModel ModelArgument(const py::object& model, const py::object& params);

void BindModels(py::module_& m);
void BindTools(py::module_& m);

}  // namespace brdfkit::python
