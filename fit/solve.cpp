// The Ceres problem: residual blocks of chunks of samples over the engine,
// bounds in the internal parameters, and the solver's settings.
#include <Eigen/Householder>
#include <Eigen/QR>

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

// One residual block of a chunk of samples, compressed: the chunk's m
// residuals r with Jacobian J (m x n) are handed to Ceres as the n + 1
// values of Q^T r from the QR factorisation [J r] = Q [R z; 0 rho], with
// Jacobian [R; 0]. J^T J, J^T r and |r|^2 are those of the chunk, so every
// Levenberg-Marquardt step and cost is the one of the uncompressed problem,
// while Ceres holds (n + 1) x n values per chunk instead of m x n and its
// linear solver works on a system 3 chunk / (n + 1) times smaller.
class CompressedChunkCost final : public ceres::CostFunction {
 public:
  CompressedChunkCost(const Engine* e, const Prepared* d, std::size_t begin, std::size_t end, NormalCache* cache,
                      std::size_t slot)
      : e_(e), d_(d), begin_(begin), end_(end), cache_(cache), slot_(slot) {
    set_num_residuals(static_cast<int>(e->n() + 1));
    mutable_parameter_block_sizes()->push_back(static_cast<int>(e->n()));
  }

  bool Evaluate(double const* const* x, double* r, double** jac) const override {
    const std::size_t n = e_->n(), m = 3 * (end_ - begin_);
    if (!jac || !jac[0]) {
      // The cost alone: any n + 1 values with the chunk's norm.
      std::vector<double> full(m);
      if (!e_->EvalDouble(x[0], *d_, begin_, end_, true, full.data())) return false;
      std::fill(r, r + n + 1, 0.0);
      r[0] = Eigen::Map<const Eigen::VectorXd>(full.data(), Eigen::Index(m)).norm();
      return true;
    }
    std::vector<double> res(m), j(m * n);
    if (!e_->EvalJacobian(x[0], *d_, begin_, end_, res.data(), j.data())) return false;
    using RowMajor = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
    Eigen::MatrixXd a(Eigen::Index(m), Eigen::Index(n + 1));
    a.leftCols(Eigen::Index(n)) = Eigen::Map<const RowMajor>(j.data(), Eigen::Index(m), Eigen::Index(n));
    a.col(Eigen::Index(n)) = Eigen::Map<const Eigen::VectorXd>(res.data(), Eigen::Index(m));
    Eigen::HouseholderQR<Eigen::Ref<Eigen::MatrixXd>> qr(a);
    // A chunk with fewer than n + 1 residuals gives a trapezoidal R, padded with zero rows.
    const Eigen::Index k = Eigen::Index(n + 1), rows = std::min(k, Eigen::Index(m));
    Eigen::MatrixXd R = Eigen::MatrixXd::Zero(k, k);
    R.topRows(rows) = a.topRows(rows).triangularView<Eigen::Upper>();
    Eigen::Map<Eigen::VectorXd>(r, k) = R.col(Eigen::Index(n));
    Eigen::Map<RowMajor>(jac[0], k, Eigen::Index(n)) = R.leftCols(Eigen::Index(n));
    if (cache_) {
      cache_->jtj[slot_] = R.leftCols(Eigen::Index(n)).transpose() * R.leftCols(Eigen::Index(n));
      cache_->at[slot_].assign(x[0], x[0] + n);
    }
    return true;
  }

 private:
  const Engine* e_;
  const Prepared* d_;
  std::size_t begin_, end_;
  NormalCache* cache_;
  std::size_t slot_;
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
                  std::vector<double>& u, NormalCache* cache) {
  problem.AddParameterBlock(u.data(), static_cast<int>(u.size()));
  const std::size_t blocks = (d.size() + chunk - 1) / chunk;
  if (cache) {
    cache->jtj.assign(blocks, Eigen::MatrixXd());
    cache->at.assign(blocks, {});
  }
  for (std::size_t b = 0; b < blocks; ++b)
    problem.AddResidualBlock(
        new CompressedChunkCost(&e, &d, b * chunk, std::min(d.size(), (b + 1) * chunk), cache, b), nullptr, u.data());
  std::vector<double> lo, hi;
  Bounds(e.layout(), e.log_mask(), lo, hi);
  for (std::size_t k = 0; k < u.size(); ++k) {
    problem.SetParameterLowerBound(u.data(), static_cast<int>(k), lo[k]);
    problem.SetParameterUpperBound(u.data(), static_cast<int>(k), hi[k]);
  }
}

std::optional<NormalCache::Normal> HoldingBounds(const Evaluators& model, const Options& o, double loss_scale,
                                                 const Engine& engine, const Prepared& d, std::size_t chunk,
                                                 std::vector<double>& u,
                                                 const std::function<void(const Engine&, std::vector<double>&)>& solve) {
  std::vector<double> lo, hi;
  Bounds(engine.layout(), engine.log_mask(), lo, hi);
  const auto at_bound = [&](std::size_t j) { return u[j] <= lo[j] || u[j] >= hi[j]; };
  const std::vector<double> p = engine.ToUser(u);
  std::vector<bool> held(u.size(), false);
  Layout inner = engine.layout();
  for (std::size_t k = 0; k < inner.free_of.size(); ++k) {
    const int j = inner.free_of[k];
    if (j < 0 || !at_bound(std::size_t(j))) continue;
    held[std::size_t(j)] = true;
    inner.free_of[k] = -1;
    inner.value[k] = p[k];
  }
  inner.Renumber();
  if (std::find(held.begin(), held.end(), true) == held.end() || inner.Free() == 0) {
    solve(engine, u);
    return std::nullopt;
  }
  const Engine held_engine(model, o, loss_scale, inner);
  std::vector<double> v = held_engine.ToInternal(p);
  solve(held_engine, v);
  u = engine.ToInternal(held_engine.ToUser(v));
  NormalCache::Normal normal{Eigen::MatrixXd(), u};
  Eigen::VectorXd g;
  NormalEquations(engine, d, u, chunk, normal.jtj, g);
  for (std::size_t j = 0; j < u.size(); ++j) {
    const bool inward = (u[j] <= lo[j] && g[Eigen::Index(j)] < 0) || (u[j] >= hi[j] && g[Eigen::Index(j)] > 0);
    if (held[j] && inward) {
      solve(engine, u);
      return std::nullopt;
    }
  }
  return normal;
}

std::optional<NormalCache::Normal> NormalCache::Last() const {
  if (jtj.empty() || at[0].empty()) return std::nullopt;
  Normal out{Eigen::MatrixXd::Zero(jtj[0].rows(), jtj[0].cols()), at[0]};
  for (std::size_t b = 0; b < jtj.size(); ++b) {
    if (at[b] != out.at) return std::nullopt;
    out.jtj += jtj[b];
  }
  return out;
}

ceres::Solver::Options SolverOptions(const Options& o, LinearSolver solver, int max_iterations) {
  ceres::Solver::Options so;
  so.minimizer_type = ceres::TRUST_REGION;
  so.trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
  // With bounds, every Levenberg-Marquardt step is followed by an Armijo
  // line search along it. Its default (cubic) interpolation evaluates the
  // gradient, a whole Jacobian pass, at each trial step; quadratic
  // interpolation needs only costs (the gradient at the start is known),
  // so an accepted step costs one Jacobian pass instead of two.
  so.line_search_interpolation_type = ceres::QUADRATIC;
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
  Impl(const Model& model, const Dataset& d, const Options& o, double loss_scale)
      : engine(ModelEvaluators(model), o, loss_scale, AllFree(model.Info())), data(d),
        prepared(Prepare(data, Select(data, o).index, o)) {
    const std::size_t chunk = std::max<std::size_t>(1, o.chunk);
    for (std::size_t b = 0; b < prepared.size(); b += chunk)
      blocks.push_back(std::make_unique<ChunkCost>(&engine, &prepared, b, std::min(prepared.size(), b + chunk)));
  }
  Engine engine;
  Dataset data;  // a copy: the blocks read it
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
