// One-dimensional quadrature shared by every integrator of brdfkit (the
// models' own internal integrals, validate/'s hemisphere and albedo rules,
// data_synth/'s aperture rules): Gauss-Legendre rules, the Gauss-Kronrod
// (7, 15) pair with QUADPACK's error scaling, and the globally adaptive
// driver on it. Standard library and Eigen only.
#pragma once

#include <Eigen/Core>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <stdexcept>
#include <vector>

namespace brdfkit {

// Gauss-Legendre nodes z and weights on [-1, 1] by Newton iteration on the
// Legendre recurrence from Tricomi's initial guess (accurate to double
// precision for n <= 1000).
inline void GaussLegendreNodes(int n, double* x, double* w) {
  if (n < 1) throw std::invalid_argument("GaussLegendre: need at least one node");
  const double pi = 3.14159265358979323846;
  for (int i = 0; i < (n + 1) / 2; ++i) {
    double z = std::cos(pi * (i + 0.75) / (n + 0.5));
    double pp = 1;
    for (int it = 0; it < 100; ++it) {
      double p1 = 1, p2 = 0;
      for (int j = 0; j < n; ++j) {
        const double p3 = p2;
        p2 = p1;
        p1 = ((2.0 * j + 1.0) * z * p2 - j * p3) / (j + 1);
      }
      pp = n * (z * p1 - p2) / (z * z - 1.0);
      const double dz = p1 / pp;
      z -= dz;
      if (std::abs(dz) < 1e-16) break;
    }
    x[i] = -z;
    x[n - 1 - i] = z;
    w[i] = w[n - 1 - i] = 2.0 / ((1.0 - z * z) * pp * pp);
  }
}

// An n-point Gauss-Legendre rule computed once.
class GaussLegendre {
 public:
  explicit GaussLegendre(int n) : x_(std::max(n, 0)), w_(std::max(n, 0)) { GaussLegendreNodes(n, x_.data(), w_.data()); }
  int size() const { return static_cast<int>(x_.size()); }
  // Nodes and weights on [-1, 1].
  double node(int i) const { return x_[i]; }
  double weight(int i) const { return w_[i]; }
  // Nodes and weights mapped to [0, 1].
  double node01(int i) const { return 0.5 * (x_[i] + 1.0); }
  double weight01(int i) const { return 0.5 * w_[i]; }

 private:
  std::vector<double> x_, w_;
};

// A fixed N-point rule on [0, 1] (nodes x, weights w), for the models'
// internal integrals.
template <int N>
struct GaussLegendre01 {
  std::array<double, N> x{}, w{};
  GaussLegendre01() {
    GaussLegendreNodes(N, x.data(), w.data());
    for (int i = 0; i < N; ++i) {
      x[i] = 0.5 * (x[i] + 1.0);
      w[i] *= 0.5;
    }
  }
};

// Gauss-Kronrod 15-point nodes (positive half, descending; the last is the
// centre) and weights, and the weights of the embedded Gauss 7-point rule
// on the odd-indexed nodes (Piessens et al. 1983, QUADPACK qk15).
inline constexpr std::array<double, 8> kGk15Nodes = {
    0.991455371120812639206854697526329, 0.949107912342758524526189684047851, 0.864864423359769072789712788640926,
    0.741531185599394439863864773280788, 0.586087235467691130294144845693013, 0.405845151377397166906606412076961,
    0.207784955007898467600689403773245, 0.0};
inline constexpr std::array<double, 8> kGk15Weights = {
    0.022935322010529224963732008058970, 0.063092092629978553290700663189204, 0.104790010322250183839876322541518,
    0.140653259715525918745189590510238, 0.169004726639267902826583426598550, 0.190350578064785409913256402421014,
    0.204432940075298892414161999234649, 0.209482141084727828012999174891714};
inline constexpr std::array<double, 4> kG7Weights = {0.129484966168869693270611432679082,
                                                     0.279705391489276667901467771423780,
                                                     0.381830050505118944950369775488975,
                                                     0.417959183673469387755102040816327};

// The 15 nodes on [-1, 1] in ascending order with their Kronrod and Gauss
// weights (zero for the Kronrod-only nodes).
struct Gk15Rule {
  std::array<double, 15> x{}, wk{}, wg{};
  constexpr Gk15Rule() {
    for (int j = 0; j < 7; ++j) {
      x[j] = -kGk15Nodes[j];
      x[14 - j] = kGk15Nodes[j];
      wk[j] = wk[14 - j] = kGk15Weights[j];
      wg[j] = wg[14 - j] = j % 2 == 1 ? kG7Weights[j / 2] : 0.0;
    }
    x[7] = 0.0;
    wk[7] = kGk15Weights[7];
    wg[7] = kG7Weights[3];
  }
};
inline constexpr Gk15Rule kGk15{};

// QUADPACK's scaling of a raw |K - G| difference (qk15): resasc
// min(1, (200 |K - G| / resasc)^1.5), floored at 50 machine epsilons of the
// absolute integral resabs for rounding. Per channel.
inline double QuadpackError(double raw, double resasc, double resabs) {
  double e = raw;
  if (resasc > 0 && e > 0) e = resasc * std::min(1.0, std::pow(200.0 * e / resasc, 1.5));
  return std::max(e, 50.0 * std::numeric_limits<double>::epsilon() * resabs);
}
inline Eigen::Array3d QuadpackError(const Eigen::Array3d& raw, const Eigen::Array3d& resasc,
                                    const Eigen::Array3d& resabs) {
  Eigen::Array3d e;
  for (int c = 0; c < 3; ++c) e[c] = QuadpackError(raw[c], resasc[c], resabs[c]);
  return e;
}

// Value of an integrand at a point and the error already made computing it
// (an inner integral's error estimate; zero for a plain function).
struct QuadValue {
  Eigen::Array3d value = Eigen::Array3d::Zero();
  Eigen::Array3d error = Eigen::Array3d::Zero();
};

// One segment [a, b] with its Kronrod estimate and QUADPACK error (plus the
// carried errors of its nodes).
struct QuadSegment {
  double a = 0, b = 0;
  Eigen::Array3d value = Eigen::Array3d::Zero();
  Eigen::Array3d error = Eigen::Array3d::Zero();
  double key = 0;  // largest channel error: the adaptive driver's priority
  bool operator<(const QuadSegment& o) const { return key < o.key; }
};

// An integrand evaluated a batch at a time: f(x, n, out) writes f(x[k]) to
// out[k] for k < n. Integrands that only take one point, f(x) -> QuadValue,
// are called point by point.
template <typename F>
concept QuadBatchIntegrand = requires(F& f, const double* x, std::size_t n, QuadValue* out) { f(x, n, out); };

// The Gauss-Kronrod (7, 15) estimate on [a, b] from the integrand's values
// at the rule's 15 nodes a + (b - a) (1 + x_i) / 2.
inline QuadSegment Kronrod15(double a, double b, const QuadValue* v) {
  const double h = 0.5 * (b - a);
  QuadSegment s;
  s.a = a;
  s.b = b;
  Eigen::Array3d k = Eigen::Array3d::Zero(), g = Eigen::Array3d::Zero(), carried = Eigen::Array3d::Zero(),
                 abs_sum = Eigen::Array3d::Zero();
  for (int i = 0; i < 15; ++i) {
    k += kGk15.wk[i] * v[i].value;
    g += kGk15.wg[i] * v[i].value;
    abs_sum += kGk15.wk[i] * v[i].value.abs();
    carried += kGk15.wk[i] * v[i].error;
  }
  const Eigen::Array3d mean = 0.5 * k;
  Eigen::Array3d resasc = Eigen::Array3d::Zero();
  for (int i = 0; i < 15; ++i) resasc += kGk15.wk[i] * (v[i].value - mean).abs();
  const double ah = std::abs(h);
  s.value = k * h;
  s.error = QuadpackError(((k - g) * ah).abs(), resasc * ah, abs_sum * ah) + carried * ah;
  s.key = s.error.maxCoeff();
  return s;
}

// Kronrod estimates on the segments [ends[2 j], ends[2 j + 1]], appended to
// `out`: one call of a batch integrand for all their nodes.
template <typename F>
void Kronrod15(F& f, const std::vector<double>& ends, std::vector<QuadSegment>& out) {
  const std::size_t count = ends.size() / 2;
  std::vector<double> x(15 * count);
  std::vector<QuadValue> v(15 * count);
  for (std::size_t j = 0; j < count; ++j) {
    const double c = 0.5 * (ends[2 * j] + ends[2 * j + 1]), h = 0.5 * (ends[2 * j + 1] - ends[2 * j]);
    for (int i = 0; i < 15; ++i) x[15 * j + i] = c + h * kGk15.x[i];
  }
  if constexpr (QuadBatchIntegrand<F>) {
    f(x.data(), x.size(), v.data());
  } else {
    for (std::size_t i = 0; i < x.size(); ++i) v[i] = f(x[i]);
  }
  for (std::size_t j = 0; j < count; ++j) out.push_back(Kronrod15(ends[2 * j], ends[2 * j + 1], v.data() + 15 * j));
}

// Globally adaptive quadrature of f over [a, b] split at `breaks` (any
// order; those outside (a, b) are ignored): bisects the segment with the
// largest error until every channel's total error is below max(abs_tol,
// rel_tol |value|), `max_splits` bisections are done, or stop() says the
// caller's evaluation budget is spent. Segments too short to split in
// double precision are final. Returns the sum and its error. f is a
// QuadBatchIntegrand or f(x) -> QuadValue; a batch integrand gets the first
// pass's nodes in one call and each bisection's 30 in one call.
template <typename F, typename Stop>
QuadValue AdaptiveKronrod(F& f, double a, double b, std::vector<double> breaks, double abs_tol, double rel_tol,
                          int max_splits, Stop&& stop) {
  std::vector<double> pts{a};
  std::sort(breaks.begin(), breaks.end());
  for (double x : breaks)
    if (x > pts.back() && x < b) pts.push_back(x);
  pts.push_back(b);
  std::vector<double> ends;
  for (std::size_t i = 0; i + 1 < pts.size(); ++i)
    if (pts[i + 1] > pts[i]) ends.insert(ends.end(), {pts[i], pts[i + 1]});
  std::vector<QuadSegment> heap;
  Kronrod15(f, ends, heap);
  std::make_heap(heap.begin(), heap.end());
  QuadValue total;
  const auto sum = [&] {
    total = QuadValue{};
    for (const QuadSegment& s : heap) {
      total.value += s.value;
      total.error += s.error;
    }
  };
  sum();
  for (int it = 0; it < max_splits && !heap.empty() && !stop(); ++it) {
    if ((total.error <= (rel_tol * total.value.abs()).max(abs_tol)).all()) break;
    std::pop_heap(heap.begin(), heap.end());
    const QuadSegment worst = heap.back();
    if (worst.key < 0) break;  // only final segments are left
    const double mid = 0.5 * (worst.a + worst.b);
    if (!(mid > worst.a && mid < worst.b)) {
      heap.back().key = -1;  // keep it, never pick it again
      std::push_heap(heap.begin(), heap.end());
      continue;
    }
    heap.pop_back();
    Kronrod15(f, {worst.a, mid, mid, worst.b}, heap);
    std::push_heap(heap.begin(), heap.end() - 1);
    std::push_heap(heap.begin(), heap.end());
    sum();
  }
  return total;
}

}  // namespace brdfkit
