// The Ceres problem: residual blocks of chunks of samples over the engine,
// bounds in the internal parameters, and the solver's settings.
#include <algorithm>
#include <cctype>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "fit/fit_internal.h"

namespace brdfkit::fit {

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

namespace {

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

ceres::LinearSolverType ToCeres(LinearSolver s) {
  switch (s) {
    case LinearSolver::kDenseQr: return ceres::DENSE_QR;
    case LinearSolver::kDenseNormalCholesky: return ceres::DENSE_NORMAL_CHOLESKY;
    case LinearSolver::kIterativeSchur: return ceres::ITERATIVE_SCHUR;
    case LinearSolver::kCgnr: return ceres::CGNR;
  }
  return ceres::DENSE_QR;
}

}  // namespace

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

}  // namespace brdfkit::fit
