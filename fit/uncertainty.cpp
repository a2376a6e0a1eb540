// Uncertainty of the fitted parameters: the normal matrix J^T J, the
// parameters the data cannot determine, and the covariance mapped back to
// the user's parameters.
#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <limits>

#include "fit/fit_internal.h"

namespace brdfkit::fit {

void NormalEquations(const Engine& e, const Prepared& d, const std::vector<double>& u, std::size_t chunk,
                     Eigen::MatrixXd& jtj, Eigen::VectorXd& jtr) {
  const std::size_t n = e.n();
  const std::size_t blocks = (d.size() + chunk - 1) / chunk;
  // [J^T J, J^T r] summed as one n x (n + 1) matrix.
  const Eigen::MatrixXd sum = ChunkedSum(
      blocks, 8, Eigen::MatrixXd(Eigen::MatrixXd::Zero(n, n + 1)), [&](std::size_t first, std::size_t last) {
        Eigen::MatrixXd part = Eigen::MatrixXd::Zero(n, n + 1), jtj_b(n, n);
        Eigen::VectorXd jtr_b(n);
        for (std::size_t b = first; b < last; ++b) {
          const std::size_t begin = b * chunk, end = std::min(d.size(), begin + chunk);
          jtj_b.setZero();
          jtr_b.setZero();
          double rr = 0;
          // A block with a value that is not finite adds NaN: the normal matrix says it is unusable.
          if (!e.NormalOfRange(u.data(), d, begin, end, jtj_b, jtr_b, rr)) jtj_b.fill(std::nan(""));
          part.leftCols(Eigen::Index(n)) += jtj_b;
          part.col(Eigen::Index(n)) += jtr_b;
        }
        return part;
      });
  jtj = sum.leftCols(Eigen::Index(n));
  jtr = sum.col(Eigen::Index(n));
}

namespace {

// J^T J over all residual blocks (internal parameters).
Eigen::MatrixXd NormalMatrix(const Engine& e, const Prepared& d, const std::vector<double>& u, std::size_t chunk) {
  Eigen::MatrixXd jtj;
  Eigen::VectorXd jtr;
  NormalEquations(e, d, u, chunk, jtj, jtr);
  return jtj;
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

}  // namespace

void Uncertainty(const FitState& s, const Engine& engine, const std::vector<double>& u, double residual_variance,
                 const std::optional<NormalCache::Normal>& final_jtj) {
  Result& res = s.res;
  const Layout& layout = s.layout;
  const std::size_t n = engine.packed(), nf = engine.n(), m = 3 * s.full.size();
  res.stddev.assign(n, std::numeric_limits<double>::quiet_NaN());
  if (!s.o.covariance) {
    res.covariance_message = "uncertainty not computed (disabled)";
    return;
  }
  std::vector<std::string> free_names;
  for (std::size_t j = 0; j < nf; ++j) free_names.push_back(res.packed_names[layout.rep[j]]);
  if (m <= nf) {
    res.covariance_message = "no uncertainty: as many parameters as residuals";
    return;
  }
  // The final solve's last normal matrix, when its point is within 0.1
  // standard deviation of u in every parameter; otherwise J^T J at u. The
  // Gaussian estimate already takes J as constant over several standard
  // deviations; on a MERL-size fit whose last step was 0.017 standard
  // deviations the two estimates differed by 6e-6 (relative), where their
  // own statistical error is 1 / sqrt(2 (m - n)) = 4e-4.
  Eigen::MatrixXd jtj;
  if (final_jtj && Identifiability(final_jtj->jtj, free_names).empty()) {
    const Eigen::MatrixXd c = final_jtj->jtj.ldlt().solve(Eigen::MatrixXd::Identity(final_jtj->jtj.rows(), final_jtj->jtj.cols()));
    const double scale = s.sigma ? 1.0 : residual_variance;
    bool near = c.allFinite();
    for (std::size_t j = 0; near && j < nf; ++j)
      near = std::abs(u[j] - final_jtj->at[j]) <= 0.1 * std::sqrt(std::max(0.0, c(Eigen::Index(j), Eigen::Index(j)) * scale));
    if (near) jtj = final_jtj->jtj;
  }
  if (jtj.size() == 0) jtj = NormalMatrix(engine, s.full, u, s.chunk);
  const std::string why = Identifiability(jtj, free_names);
  if (!why.empty()) {
    res.covariance_message = "no uncertainty: the problem is rank deficient: " + why;
    return;
  }
  // Covariance (J^T J)^-1 of the internal parameters from the dense
  // n x n normal matrix: the estimator ceres::Covariance computes, without
  // its sparse QR of the whole m x n Jacobian. Scaled to unit diagonal
  // first (the rank test above bounds its condition number by 1e12).
  const Eigen::VectorXd unit = JacobiScale(jtj);
  const Eigen::MatrixXd a = unit.asDiagonal() * jtj * unit.asDiagonal();
  const Eigen::LDLT<Eigen::MatrixXd> ldlt(a);
  const auto nn = static_cast<Eigen::Index>(nf);
  const Eigen::MatrixXd cu = unit.asDiagonal() * ldlt.solve(Eigen::MatrixXd::Identity(nn, nn)) * unit.asDiagonal();
  if (ldlt.info() != Eigen::Success || !ldlt.isPositive() || !cu.allFinite()) {
    res.covariance_message =
        "no uncertainty: the covariance could not be computed (the Jacobian is numerically rank deficient)";
    return;
  }
  // Back to the user's parameters: dp/du = p for log-scale ones; a
  // fixed slot has no variance, a tied one its leader's.
  Eigen::MatrixXd jd = Eigen::MatrixXd::Zero(static_cast<Eigen::Index>(n), nn);
  for (std::size_t k = 0; k < n; ++k)
    if (const int j = layout.free_of[k]; j >= 0)
      jd(static_cast<Eigen::Index>(k), j) = engine.log_mask()[std::size_t(j)] ? res.params[k] : 1.0;
  Eigen::MatrixXd cp = jd * cu * jd.transpose();
  // Without measured sigma the residual variance sets the scale.
  if (!s.sigma) cp *= residual_variance;
  res.correlation.resize(n, n);
  for (std::size_t k = 0; k < n; ++k) res.stddev[k] = std::sqrt(std::max(0.0, cp(k, k)));
  for (std::size_t i = 0; i < n; ++i)
    for (std::size_t j = 0; j < n; ++j) {
      const double d = res.stddev[i] * res.stddev[j];
      res.correlation(i, j) = i == j ? 1.0 : (d > 0 ? cp(i, j) / d : 0.0);
    }
  res.covariance_ok = true;
  // Active bounds: the Gaussian uncertainty ignores them.
  std::vector<double> lo, hi;
  Bounds(layout, engine.log_mask(), lo, hi);
  std::string at_bound;
  for (std::size_t k = 0; k < nf; ++k)
    if (u[k] <= lo[k] || u[k] >= hi[k]) at_bound += (at_bound.empty() ? "" : ", ") + free_names[k];
  if (!at_bound.empty())
    res.covariance_message = "parameters at a bound (their uncertainty ignores the bound): " + at_bound;
}

}  // namespace brdfkit::fit
