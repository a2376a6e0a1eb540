// The Ceres problem: residual blocks of chunks of samples over the engine,
// bounds in the internal parameters, and the solver's settings.
#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <limits>
#include <numeric>
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
// residuals r with Jacobian J (m x n) are handed to Ceres as n + 1 values
// [z; rho] with Jacobian [B; 0], where B^T B = J^T J (B from the pivoted
// Cholesky factorisation of J^T J), B^T z = J^T r and |z|^2 + rho^2 = |r|^2.
// J^T J, J^T r and |r|^2 are those of the chunk, so every
// Levenberg-Marquardt step and cost is the one of the uncompressed problem,
// while Ceres holds (n + 1) x n values per chunk instead of m x n and its
// linear solver works on a system 3 chunk / (n + 1) times smaller. Forming
// J^T J costs m n^2 / 2 multiplications, a quarter of a Householder QR of
// [J r] (a lambert+ggx fit of a MERL file: 1.51 s against 1.75 s through
// QR, the same iterations and cost to 1e-15); its rounding is relative to
// the columns' norms, which the factorisation below scales out.
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
    using RowMajor = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
    const Eigen::Index k = Eigen::Index(n);
    Eigen::MatrixXd jtj = Eigen::MatrixXd::Zero(k, k);
    Eigen::VectorXd jtr = Eigen::VectorXd::Zero(k);
    double rr = 0;
    if (!e_->NormalOfRange(x[0], *d_, begin_, end_, jtj, jtr, rr)) return false;
    // With S the Jacobi scaling (unit diagonal; the columns' scales span
    // 1e20 where the cube root's derivative is steep), the Cholesky
    // factorisation with complete pivoting S J^T J S = P^T R^T R P (stable
    // for semidefinite matrices, stopped where the largest pivot left is at
    // rounding level: those directions carry no curvature) gives
    // B = R P S^(-1) and z = R^(-T) P S J^T r.
    const Eigen::VectorXd sc = JacobiScale(jtj);
    Eigen::MatrixXd g = sc.asDiagonal() * jtj * sc.asDiagonal();
    Eigen::VectorXd z = sc.cwiseProduct(jtr);
    std::vector<Eigen::Index> perm(static_cast<std::size_t>(k));
    std::iota(perm.begin(), perm.end(), Eigen::Index(0));
    Eigen::MatrixXd rf = Eigen::MatrixXd::Zero(k, k);
    Eigen::Index rank = 0;
    for (; rank < k; ++rank) {
      const Eigen::Index q = rank;
      Eigen::Index piv = q;
      for (Eigen::Index i = q + 1; i < k; ++i)
        if (g(i, i) > g(piv, piv)) piv = i;
      if (!(g(piv, piv) > 1e-13)) break;
      g.row(q).swap(g.row(piv));
      g.col(q).swap(g.col(piv));
      rf.col(q).swap(rf.col(piv));
      std::swap(perm[std::size_t(q)], perm[std::size_t(piv)]);
      std::swap(z[q], z[piv]);
      const double d = std::sqrt(g(q, q));
      rf(q, q) = d;
      rf.row(q).tail(k - q - 1) = g.row(q).tail(k - q - 1) / d;
      g.bottomRightCorner(k - q - 1, k - q - 1).noalias() -=
          rf.row(q).tail(k - q - 1).transpose() * rf.row(q).tail(k - q - 1);
    }
    // R^T z = P S J^T r over the pivots kept; the rest is rounding.
    rf.topLeftCorner(rank, rank).triangularView<Eigen::Upper>().transpose().solveInPlace(z.head(rank));
    z.tail(k - rank).setZero();
    Eigen::MatrixXd b = Eigen::MatrixXd::Zero(k, k);
    for (Eigen::Index c = 0; c < k; ++c) {
      const Eigen::Index col = perm[std::size_t(c)];
      if (sc[col] > 0) b.col(col).head(rank) = rf.col(c).head(rank) / sc[col];
    }
    if (!b.allFinite() || !z.allFinite()) return false;
    Eigen::Map<Eigen::VectorXd>(r, k) = z;
    // |r|^2 less the part z carries; never below zero by rounding.
    r[n] = std::sqrt(std::max(rr - z.squaredNorm(), 0.0));
    Eigen::Map<RowMajor> out(jac[0], k + 1, k);
    out.topRows(k) = b;
    out.row(k).setZero();
    if (cache_) {
      cache_->jtj[slot_] = jtj;
      cache_->jtr[slot_] = jtr;
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

Eigen::VectorXd JacobiScale(const Eigen::MatrixXd& jtj) {
  Eigen::VectorXd s(jtj.rows());
  for (Eigen::Index i = 0; i < jtj.rows(); ++i) s[i] = jtj(i, i) > 0 ? 1 / std::sqrt(jtj(i, i)) : 0.0;
  return s;
}

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
    cache->jtr.assign(blocks, Eigen::VectorXd());
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

namespace {
// Whether internal parameter value v with bounds [lo, hi] and gradient
// component g sits on a bound, and whether the descent direction -g pulls
// it inward from there: HoldingBounds holds a parameter on a bound until
// the gradient pulls it inward.
bool OnBound(double v, double lo, double hi) { return v <= lo || v >= hi; }
bool PulledInward(double v, double lo, double hi, double g) { return (v <= lo && g < 0) || (v >= hi && g > 0); }
}  // namespace

std::optional<NormalCache::Normal> HoldingBounds(const Evaluators& model, const Options& o, double loss_scale,
                                                 const Engine& engine, const Prepared& d, std::size_t chunk,
                                                 std::vector<double>& u,
                                                 const HeldSolve& solve) {
  std::vector<double> lo, hi;
  Bounds(engine.layout(), engine.log_mask(), lo, hi);
  const std::vector<double> p = engine.ToUser(u);
  std::vector<bool> held(u.size(), false);
  Layout inner = engine.layout();
  for (std::size_t k = 0; k < inner.free_of.size(); ++k) {
    const int j = inner.free_of[k];
    if (j < 0 || !OnBound(u[std::size_t(j)], lo[std::size_t(j)], hi[std::size_t(j)])) continue;
    held[std::size_t(j)] = true;
    inner.free_of[k] = -1;
    inner.value[k] = p[k];
  }
  inner.Renumber();
  if (std::find(held.begin(), held.end(), true) == held.end() || inner.Free() == 0) {
    solve(engine, u, nullptr);
    return std::nullopt;
  }
  const Engine held_engine(model, o, loss_scale, inner);
  std::vector<double> v = held_engine.ToInternal(p);
  solve(held_engine, v, nullptr);
  u = engine.ToInternal(held_engine.ToUser(v));
  NormalCache::Normal normal{Eigen::MatrixXd(), u, Eigen::VectorXd()};
  NormalEquations(engine, d, u, chunk, normal.jtj, normal.jtr);
  const Eigen::VectorXd& g = normal.jtr;
  for (std::size_t j = 0; j < u.size(); ++j) {
    if (held[j] && PulledInward(u[j], lo[j], hi[j], g[Eigen::Index(j)])) {
      solve(engine, u, &normal);
      return std::nullopt;
    }
  }
  return normal;
}

std::optional<NormalCache::Normal> NormalCache::Last() const {
  if (jtj.empty() || at[0].empty()) return std::nullopt;
  Normal out{Eigen::MatrixXd::Zero(jtj[0].rows(), jtj[0].cols()), at[0], Eigen::VectorXd::Zero(jtj[0].rows())};
  for (std::size_t b = 0; b < jtj.size(); ++b) {
    if (at[b] != out.at) return std::nullopt;
    out.jtj += jtj[b];
    out.jtr += jtr[b];
  }
  return out;
}

namespace {

// The structured secant update of A (the estimate of S) for a step s whose
// gradient changed by y, J^T J at its end being jtj: afterwards
// A s = y - jtj s, the part of the change Gauss-Newton does not explain.
void SecantUpdate(Eigen::MatrixXd& a, const Eigen::MatrixXd& jtj, const Eigen::VectorXd& s, const Eigen::VectorXd& y) {
  const double ys = y.dot(s);
  // Without positive curvature along s the update is undefined: A stays.
  if (!(ys > 0) || !y.allFinite()) return;
  const Eigen::VectorXd target = y - jtj * s;
  const double sas = s.dot(a * s);
  // NL2SOL's sizing: A is scaled down where it overstates the curvature along s.
  if (sas != 0) a *= std::min(1.0, std::abs(s.dot(target) / sas));
  const Eigen::VectorXd v = target - a * s;
  a += (v * y.transpose() + y * v.transpose()) / ys - (v.dot(s) / (ys * ys)) * (y * y.transpose());
}

// The step d of (jtj + a + lambda diag(jtj)) d = -g over the free entries
// (Jacobi-scaled), each other entry j moved by fixed[j] (0, or to its
// bound); false where that matrix is not positive definite.
bool TailStep(const Eigen::MatrixXd& jtj, const Eigen::MatrixXd& a, const Eigen::VectorXd& g,
              const std::vector<bool>& free, const Eigen::VectorXd& fixed, double lambda, Eigen::VectorXd& step) {
  std::vector<Eigen::Index> idx;
  for (std::size_t j = 0; j < free.size(); ++j)
    if (free[j]) idx.push_back(Eigen::Index(j));
  step = Eigen::VectorXd::Zero(g.size());
  for (std::size_t j = 0; j < free.size(); ++j)
    if (!free[j]) step[Eigen::Index(j)] = fixed[Eigen::Index(j)];
  if (idx.empty()) return true;
  // The gradient of the model at the fixed entries' moves.
  const Eigen::VectorXd moved = g + (jtj + a) * step;
  const Eigen::Index k = Eigen::Index(idx.size());
  Eigen::MatrixXd m(k, k);
  Eigen::VectorXd b(k), scale(k);
  const Eigen::VectorXd unit = JacobiScale(jtj);
  for (Eigen::Index i = 0; i < k; ++i) scale[i] = unit[idx[i]];
  for (Eigen::Index i = 0; i < k; ++i) {
    b[i] = -moved[idx[i]] * scale[i];
    for (Eigen::Index j = 0; j < k; ++j)
      m(i, j) = (jtj(idx[i], idx[j]) + a(idx[i], idx[j])) * scale[i] * scale[j] + (i == j ? lambda : 0.0);
  }
  const Eigen::LDLT<Eigen::MatrixXd> ldlt(m);
  if (ldlt.info() != Eigen::Success || !(ldlt.vectorD().minCoeff() > 0)) return false;
  const Eigen::VectorXd x = ldlt.solve(b);
  if (!x.allFinite()) return false;
  for (Eigen::Index i = 0; i < k; ++i) step[idx[i]] = x[i] * scale[i];
  return true;
}

}  // namespace

bool Creeps(const std::vector<double>& costs) {
  const std::size_t n = costs.size();
  if (n <= std::size_t(kCreepSteps)) return false;
  const double c = costs[n - 1], total = costs[n - 1 - kCreepSteps] - c, late = costs[n - 1 - kCreepSteps / 2] - c;
  return total <= kCreep * c && late >= kCreepRatio * (total - late);
}

Tail SecantTail(const Engine& e, const Prepared& d, std::size_t chunk, const NormalCache::Normal& last, double cost,
                const std::optional<NormalCache::Normal>& previous, double ftol, int max_iterations,
                const std::function<void(int, double, const std::vector<double>&)>& accepted,
                const Pause& pause) {
  Tail t;
  t.u = last.at;
  t.cost = cost;
  std::vector<double> costs{cost};  // at each accepted point
  t.normal = last;
  const Eigen::Index n = Eigen::Index(t.u.size());
  const auto vec = [](const std::vector<double>& v) { return Eigen::Map<const Eigen::VectorXd>(v.data(), Eigen::Index(v.size())); };
  Eigen::MatrixXd a = Eigen::MatrixXd::Zero(n, n);
  if (previous) SecantUpdate(a, last.jtj, vec(last.at) - vec(previous->at), last.jtr - previous->jtr);
  std::vector<double> lo, hi;
  Bounds(e.layout(), e.log_mask(), lo, hi);
  // Levenberg-Marquardt damping, relative to the Jacobi-scaled diagonal (1).
  double lambda = 1e-12;
  constexpr double kMaxLambda = 1e8;
  while (t.iterations < max_iterations && lambda <= kMaxLambda) {
    const Eigen::MatrixXd& jtj = t.normal.jtj;
    const Eigen::VectorXd& g = t.normal.jtr;
    // An entry that does not act on the cost, or sits on a bound the
    // gradient presses against, stays where it is.
    std::vector<bool> free(std::size_t(n), true);
    for (Eigen::Index j = 0; j < n; ++j) {
      const std::size_t k = std::size_t(j);
      free[k] = jtj(j, j) > 0 && !(t.u[k] <= lo[k] && g[j] > 0) && !(t.u[k] >= hi[k] && g[j] < 0);
    }
    // The step over the free entries. An entry that the step would take
    // past a bound is moved onto it and the rest solved again with that
    // move: the others' steps were solved for the whole of it, and cutting
    // it alone (projecting) leaves them overshooting.
    Eigen::VectorXd step, fixed = Eigen::VectorXd::Zero(n);
    bool solved = TailStep(jtj, a, g, free, fixed, lambda, step);
    for (Eigen::Index pass = 0; solved && pass < n; ++pass) {
      bool held = false;
      for (Eigen::Index j = 0; j < n; ++j) {
        const std::size_t k = std::size_t(j);
        if (!free[k]) continue;
        const double to = t.u[k] + step[j];
        if (to < lo[k] || to > hi[k]) {
          free[k] = false;
          fixed[j] = std::clamp(to, lo[k], hi[k]) - t.u[k];
          held = true;
        }
      }
      if (!held) break;
      solved = TailStep(jtj, a, g, free, fixed, lambda, step);
    }
    if (!solved) {
      lambda = std::max(10 * lambda, 1e-6);
      continue;
    }
    // Within the bounds (the pinned entries' moves can round past them).
    std::vector<double> trial(t.u);
    for (Eigen::Index j = 0; j < n; ++j) {
      const std::size_t k = std::size_t(j);
      trial[k] = std::clamp(t.u[k] + step[j], lo[k], hi[k]);
    }
    ++t.iterations;
    const double c = CostOf(e, d, trial);
    if (!(c < t.cost)) {
      lambda = std::max(10 * lambda, 1e-6);
      continue;
    }
    NormalCache::Normal next{Eigen::MatrixXd(), trial, Eigen::VectorXd()};
    NormalEquations(e, d, trial, chunk, next.jtj, next.jtr);
    SecantUpdate(a, next.jtj, vec(trial) - vec(t.u), next.jtr - g);
    const double decrease = t.cost - c;
    t.u = trial;
    t.cost = c;
    t.normal = std::move(next);
    lambda = std::max(lambda / 10, 1e-12);
    t.change = decrease / c;
    ++t.accepted;
    accepted(t.iterations, c, t.u);
    if (decrease <= ftol * c) {
      t.converged = true;
      break;
    }
    costs.push_back(c);
    if (pause && Creeps(costs) && pause(t.u)) {
      t.paused = true;
      break;
    }
  }
  // No step lowers the cost even as a short gradient step: the point is a
  // minimum to the precision of the cost.
  if (lambda > kMaxLambda) t.converged = true;
  return t;
}

// Where a Levenberg-Marquardt solve has become linear (SolveToEnd).
constexpr double kTailStart = 1e-4, kTailMinRatio = 0.1, kTailMaxRatio = 0.95;

double GaussNewtonGain(const Eigen::MatrixXd& jtj, const Eigen::VectorXd& g) {
  if (!jtj.allFinite() || !g.allFinite()) return std::numeric_limits<double>::infinity();
  const Eigen::VectorXd scale = JacobiScale(jtj);
  const Eigen::MatrixXd a = scale.asDiagonal() * jtj * scale.asDiagonal();
  const Eigen::VectorXd b = scale.asDiagonal() * g;
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(a);
  if (eig.info() != Eigen::Success) return std::numeric_limits<double>::infinity();
  const double top = eig.eigenvalues().maxCoeff();
  const Eigen::VectorXd proj = eig.eigenvectors().transpose() * b;
  double gain = 0;
  for (Eigen::Index k = 0; k < a.rows(); ++k) {
    const double l = eig.eigenvalues()[k];
    // Directions 1e-12 below the largest are the normal matrix's null
    // space, where the gradient vanishes too (g = J^T r).
    if (l > 1e-12 * top) gain += proj[k] * proj[k] / l;
  }
  return 0.5 * gain;
}

double GainWithinBounds(const Engine& e, const std::vector<double>& u, const Eigen::MatrixXd& jtj,
                        const Eigen::VectorXd& g) {
  std::vector<double> lo, hi;
  Bounds(e.layout(), e.log_mask(), lo, hi);
  std::vector<Eigen::Index> free;
  for (std::size_t j = 0; j < u.size(); ++j)
    if (!OnBound(u[j], lo[j], hi[j]) || PulledInward(u[j], lo[j], hi[j], g[Eigen::Index(j)]))
      free.push_back(Eigen::Index(j));
  return GaussNewtonGain(jtj(free, free), g(free));
}

Solved SolveToEnd(const Engine& e, const Prepared& d, std::size_t chunk, std::vector<double>& u,
                  ceres::Solver::Options so, const NormalCache::Normal* from,
                  const std::function<void(int, double, const std::vector<double>&)>& trace, double stop_above,
                  const Pause& pause) {
  ceres::Problem problem;
  NormalCache cache;
  BuildProblem(problem, e, d, chunk, u, &cache);
  so.update_state_every_iteration = true;  // trace reads u
  // The successful iterations' costs and the normal equations at the last two.
  std::vector<double> costs;
  std::optional<NormalCache::Normal> previous, last;
  Solved out;
  const auto above = [&](double cost, const NormalCache::Normal& n) {
    return std::isfinite(stop_above) && cost - kGainBound * GaussNewtonGain(n.jtj, n.jtr) > stop_above;
  };
  TraceCallback callback(
      [&](const ceres::IterationSummary& it) {
        if (it.iteration > 0 && !it.step_is_successful) return;
        trace(it.iteration, it.cost, u);
      },
      [&](const ceres::IterationSummary& it) {
        if (it.iteration > 0 && !it.step_is_successful) return false;
        previous = std::move(last);
        last = cache.Last();
        costs.push_back(it.cost);
        if (last && above(it.cost, *last)) {
          out.bounded = true;
          return true;
        }
        const std::size_t k = costs.size();
        if (k < 4 || !previous || !last) return false;
        const auto decrease = [&](std::size_t j) { return costs[j - 1] - costs[j]; };
        const auto steady = [](double later, double earlier) {
          return earlier > 0 && later >= kTailMinRatio * earlier && later <= kTailMaxRatio * earlier;
        };
        return decrease(k - 1) <= kTailStart * costs[k - 1] && steady(decrease(k - 1), decrease(k - 2)) &&
               steady(decrease(k - 2), decrease(k - 3));
      });
  so.callbacks.push_back(&callback);
  ceres::Solver::Summary& summary = out.summary;
  if (from) {
    summary.termination_type = ceres::USER_SUCCESS;
    summary.num_successful_steps = summary.num_unsuccessful_steps = 0;
    costs.assign(1, CostOf(e, d, u));
    trace(0, costs[0], u);
    last = *from;
    summary.final_cost = costs[0];
    out.bounded = above(costs[0], *from);
  } else {
    ceres::Solve(so, &problem, &summary);
  }
  out.normal = cache.Last();
  if (out.bounded) {
    summary.message = "Stopped: the cost less " + FormatDouble(kGainBound) +
                      " times the Gauss-Newton gain lies above " + FormatDouble(stop_above);
    return out;
  }
  if (summary.termination_type != ceres::USER_SUCCESS || !last) return out;
  const int done = summary.num_successful_steps + summary.num_unsuccessful_steps;
  const Tail t = SecantTail(e, d, chunk, *last, costs.back(), previous, so.function_tolerance,
                            so.max_num_iterations - done,
                            [&](int k, double cost, const std::vector<double>& at) { trace(done + k, cost, at); },
                            pause);
  u = t.u;
  out.paused = t.paused;
  out.normal = t.normal;
  summary.final_cost = t.cost;
  summary.num_successful_steps += t.accepted;
  summary.num_unsuccessful_steps += t.iterations - t.accepted;
  summary.termination_type = t.converged ? ceres::CONVERGENCE : ceres::NO_CONVERGENCE;
  if (t.paused) {
    summary.message = "Paused in the secant end phase, where the cost creeps";
    return out;
  }
  summary.message = t.converged ? "Function tolerance reached in the secant end phase" +
                                      (from ? std::string(" after held bounds were released")
                                            : " after " + std::to_string(done) + " Levenberg-Marquardt iterations") +
                                      ". |cost_change|/cost: " + FormatDouble(t.change) + " <= " +
                                      FormatDouble(so.function_tolerance)
                                : "Maximum number of iterations reached (" + std::to_string(so.max_num_iterations) +
                                      ") in the secant end phase";
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
