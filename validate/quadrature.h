// Gauss-Legendre rules, nodes and weights computed once by Newton iteration
// on the Legendre recurrence (accurate to double precision for n <= 1000).
#pragma once

#include <vector>

namespace brdfkit::validate {

class GaussLegendre {
 public:
  explicit GaussLegendre(int n);
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

}  // namespace brdfkit::validate
