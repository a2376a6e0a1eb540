// Models defined in Python (brdfkit.PythonModel: numpy functions f(wi, wo,
// params), optionally with sample and pdf) and tabulated functions
// (brdfkit.Tabulated: samples wi, wo, f looked up by nearest neighbour or
// inverse distance), as the Bxdf<double> evaluators that check,
// albedo_table and synth take in place of a registered model, and as the
// fitter's evaluators (values and finite-difference derivatives in the
// parameters, one batched call per parameter vector).
#pragma once

#include <exception>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "fit/fit.h"
#include "python/src/common.h"

namespace brdfkit::python {

// brdfkit.PythonModel: immutable, shared by the evaluators made from it.
struct PythonModel {
  ModelInfo info;    // name, scalar parameters with bounds, defaults and scale
  py::object eval;   // eval(wi, wo[, params]) -> (N, 3)
  py::object sample; // sample(wo, u[, params]) -> (wi (N, 3), pdf (N,)), or None
  py::object pdf;    // pdf(wo, wi[, params]) -> (N,), or None
  py::object width;  // None (measured from eval), a number, or width([params]) -> number or (x, y)
  unsigned kind = LobeKind::kDiffuse | LobeKind::kGlossy;
  PythonModel() = default;
  PythonModel(const PythonModel&) = delete;
  PythonModel& operator=(const PythonModel&) = delete;
  ~PythonModel();  // drops the Python objects with the GIL held (the last owner may be a worker thread)
};

// The calls of one tool run into Python: the first error (an exception of a
// function, or a wrong result), after which no function is called again,
// and the run's cancellation. The fitter's threads must not throw (Ceres
// and its thread pools do not carry exceptions): with throws = false a
// failed call only records the error and the evaluators return NaN.
class CallState {
 public:
  explicit CallState(bool throws) : throws_(throws) {}
  bool throws() const { return throws_; }
  void set_token(const CancelToken* token) { token_ = token; }
  // True once a call failed or the run was cancelled.
  bool Stopped() const;
  void Fail(std::exception_ptr e);
  // Raises the recorded error (the function's own Python exception) if any.
  void RethrowIfFailed() const;

 private:
  const bool throws_;
  const CancelToken* token_ = nullptr;
  mutable std::mutex mutex_;
  std::exception_ptr error_;
};

// A model argument of check, albedo_table and synth: a registered model (a
// Model or a name with params), a PythonModel with params, or a Tabulated.
struct ToolModel {
  std::string spec;  // the result's "model"
  std::vector<double> params;
  std::shared_ptr<const Bxdf<double>> bxdf;
  std::shared_ptr<CallState> calls;  // PythonModel only
  Settings settings;                 // a Model's settings (e.g. path)
};
ToolModel ToolModelArgument(const py::object& model, const py::object& params);

// Runs work as RunReleased does; an error raised inside a Python model's
// function is raised as itself, whatever the tool made of it.
void RunTool(const ToolModel& m, int threads, const std::function<void(const CancelToken&)>& work);

// The fitter's evaluators of a PythonModel over data set `data`.
std::unique_ptr<fit::Evaluators> FitEvaluators(const std::shared_ptr<const PythonModel>& model,
                                               const fit::Dataset& data, const std::shared_ptr<CallState>& calls);

// "name=value,..." from None, a string or a dict {name: number or (r, g, b)}.
std::string ParamsText(const py::object& params);

void BindCallables(py::module_& m);

}  // namespace brdfkit::python
