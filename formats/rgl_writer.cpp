#include "formats/rgl_writer.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <random>
#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include <tbb/parallel_for.h>

#include "brdf/params.h"

namespace brdfkit::formats {

namespace {

// D is floored at this fraction of its maximum: low enough that it follows
// the lobes' tails (values f cos 4 sigma / D stay smooth where f cos is
// above 1e-12 of its peak), high enough that the values stay within float.
constexpr double kNdfFloor = 1e-12;
// The vndf of a slice, row by row (a row: one azimuth of wm, u_x from the
// pole to the equator). Each row is built with mass 1 (then weighted, in
// isotropic files, by kRowCrowd's profile below), and within it a band
// around the horizon of wo whose density in cos(theta_o) is the same in
// every row and slice: kBandShare times a Gaussian of cos(theta_o) /
// kHorizonBand (anisotropic files: a width that changes slowly with
// theta_i, below). The rest (the visible normals, a kUniformShare of uniform
// density for the pole and the rows facing away from wi) is zero within a
// gap |cos(theta_o)| < w of the horizon (RestGap), rises smoothly to full
// weight at 2 w, and is scaled on each side of the horizon so that the
// row's CDF reaches 1 - kBelowHorizon at the horizon: the horizon then sits
// at the same square coordinate s_x in every row, near it the CDF is the
// band's alone, one function of cos(theta_o) in every row and slice, so the
// reader's blend of neighbouring rows and slices puts a query's horizon
// where it is, and the values' interpolation (bilinear within a slice,
// linear across slices) follows f cos(theta_o) to it.
constexpr double kVndfSpread = 0.2, kLobeShare = 0.35, kUniformShare = 0.5, kBandShare = 0.4, kHorizonBand = 0.2,
                 kBelowHorizon = 0.4;
// The band's width in anisotropic files, whose neighbouring phi_i slices
// (15.7 degrees apart by default) see a normal at cos(theta_o) up to
// sin(theta_i) x their spacing (0.27 towards grazing) apart: cos(theta_i)
// (the largest |cos(theta_o)| every row reaches), within kHorizonBand and
// kAnisotropicBand.
constexpr double kAnisotropicBand = 0.4;
// The theta_i slices lie with density 1 / (kSliceCos + cos(theta_i)): the
// horizon of the reflection moves fastest with theta_i towards grazing,
// where the slices' blend at a fixed square coordinate errs most (lambert
// and GGX 1 near the forward direction, the normals near the pole). 1 would
// be uniform in tan(theta_i / 2), twice as dense at grazing as at normal
// incidence; 0.6 makes it 2.5 times.
constexpr double kSliceCos = 0.6;
// Isotropic files: the row of relative azimuth phi holds the mass 1 +
// kRowCrowd exp(-cos^2(phi) / (2 kRowWidth^2)), so that the value rows
// (uniform in the square's s_y, which follows the row masses) lie about 2.4
// times as dense 90 degrees off wi, where at grazing incidence the normal
// that reflects wi onto the horizon sweeps from the equator to theta_m = 45
// degrees within cot(theta_i) of cos(phi). The profile is the same in every
// slice (the slices' blend at a fixed s_y needs one azimuth per s_y) and
// wide (the Marginal2D conditional between two rows weighs them by their
// masses: steep changes from row to row shift the band near the horizon).
// Anisotropic files keep equal rows: theirs are absolute azimuths, and 90
// degrees off wi moves with the phi_i slice.
constexpr double kRowCrowd = 2, kRowWidth = 0.5;

// The gap w of a slice at theta_i. At a query's horizon the cos(theta_o) of
// the blended neighbours differ by up to the node spacing (|d cos(theta_o) /
// d phi_m| and |d cos(theta_o) / d theta_i| are at most 1), so w is at
// least 1.2 spacing (the largest spacing of the vndf rows and theta_i
// slices, in radians); away from grazing it widens to 0.5 cos(theta_i), up
// to 0.12; and it stays below 0.9 cos(theta_i): every row reaches
// |cos(theta_o)| = cos(theta_i) on both sides (at the pole and at the
// equator), so the rest keeps room there.
double RestGap(double theta_i, double spacing) {
  const double c = std::cos(theta_i);
  return std::min({0.12, std::max(1.2 * spacing, 0.5 * c), 0.9 * c});
}

double Luminance(const Rgb<double>& c) { return 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]; }

void Check(bool ok, const std::string& what) {
  if (!ok) throw std::invalid_argument("RGL writer: " + what);
}

// The source at (wi, wo), checked.
Rgb<double> SourceAt(const BrdfFunction& f, const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) {
  const Rgb<double> v = f(wi, wo);
  if (!v.isFinite().all())
    throw std::runtime_error("RGL writer: the source is not finite at wi = (" + std::to_string(wi.x()) + ", " +
                             std::to_string(wi.y()) + ", " + std::to_string(wi.z()) + "), wo = (" +
                             std::to_string(wo.x()) + ", " + std::to_string(wo.y()) + ", " + std::to_string(wo.z()) + ")");
  return v.max(0.0);
}

// The values' variation along each row of a slice's vndf: at every node
// (vy rows of the azimuth of wm x vx columns of u_x) d = sqrt(|l''| + l'^2)
// of l = log(f(wi, wo) / D(wm)) along u_x, which bounds |v'' / v| for the
// values v ~ f cos(theta_o) / D away from the horizon (the band resolves
// the cosine's zero there); the largest over the channels, and 0 where f
// cos(theta_o) is below kSignificant of the slice's maximum (no error
// there counts, and the floored ndf would make l steep). For a microfacet
// lobe f / D varies slowly; a sum of lobes moves from one lobe's ratio to
// the other's where their shares cross, and at grazing incidence (where
// the specular part of f grows as 1 / cos(theta_i)) the ndf, learnt from the
// retro-reflection, crosses far from f.
constexpr double kSignificant = 1e-3, kValueTolerance = 1.5e-3;
std::vector<double> ValueVariation(const BrdfFunction& f, const Warp2D& ndf, const Eigen::Vector3d& wi,
                                   std::size_t vy, std::size_t vx) {
  const double h = 1.0 / double(vx - 1);
  const double kNone = std::numeric_limits<double>::quiet_NaN();  // no value above the horizon
  std::array<std::vector<double>, 3> l, fc;
  for (int c = 0; c < 3; ++c) {
    l[c].assign(vy * vx, kNone);
    fc[c].assign(vy * vx, 0.0);
  }
  Rgb<double> fc_max = Rgb<double>::Zero();
  for (std::size_t y = 0; y < vy; ++y)
    for (std::size_t x = 0; x < vx; ++x) {
      const double ux = double(x) * h, uy = double(y) / double(vy - 1);
      const Eigen::Vector3d wm = RglBsdf::Direction(RglBsdf::UToTheta(ux), RglBsdf::UToPhi(uy));
      if (wi.dot(wm) <= 0) continue;
      const Eigen::Vector3d wo = (2 * wi.dot(wm) * wm - wi).normalized();
      if (wo.z() <= 0) continue;
      const Rgb<double> v = SourceAt(f, wi, wo);
      const double log_d = std::log(ndf.Eval(ux, uy));
      for (int c = 0; c < 3; ++c)
        if (v[c] > 0) {
          l[c][y * vx + x] = std::log(v[c]) - log_d;
          fc[c][y * vx + x] = v[c] * wo.z();
          fc_max[c] = std::max(fc_max[c], fc[c][y * vx + x]);
        }
    }
  std::vector<double> d(vy * vx, 0.0);
  for (int c = 0; c < 3; ++c)
    for (std::size_t i = 0; i < vy * vx; ++i) {
      const std::size_t x = i % vx;
      if (x == 0 || x + 1 == vx || !(fc[c][i] >= kSignificant * fc_max[c])) continue;
      const double a = l[c][i - 1], m = l[c][i], b = l[c][i + 1];
      if (std::isnan(a) || std::isnan(b)) continue;
      const double d1 = (b - a) / (2 * h), d2 = (b - 2 * m + a) / (h * h);
      d[i] = std::max(d[i], std::sqrt(std::abs(d2) + d1 * d1));
    }
  return d;
}

// An n x n table over the warped square, value(x, y) at node (x, y),
// computed side by side; for an isotropic source (constant in the azimuth
// of the square's y axis) row 0 only, copied to the others.
template <class T, class Value>
std::vector<T> SquareTable(std::size_t n, bool iso, const Value& value) {
  std::vector<T> out(n * n);
  tbb::parallel_for(std::size_t{0}, (iso ? 1 : n) * n,
                    [&](std::size_t k) { out[k] = static_cast<T>(value(k % n, k / n)); });
  if (iso)
    for (std::size_t y = 1; y < n; ++y) std::copy_n(out.begin(), n, out.begin() + std::ptrdiff_t(y * n));
  return out;
}

// One row of a slice's vndf (above): theta_i of the slice, phi the azimuth
// of wm relative to wi's, gap the rest's (RestGap), band_width the band's
// (kHorizonBand, or in anisotropic files kAnisotropicBand's rule), lobe the
// row of the visible normals (a density over the square), n nodes, mass
// the row's (its CDF's shape does not depend on it).
void AlignedRow(double theta_i, double phi, double gap, double band_width, const double* lobe, std::size_t n,
                double mass, float* out) {
  const double h = 1.0 / double(n - 1);
  // cos(theta_o) of the reflection of wi about wm = (theta, phi) is
  // r cos(2 theta - delta): one zero, at theta = (delta + pi / 2) / 2.
  const double a = std::sin(theta_i) * std::cos(phi), c = std::cos(theta_i);
  const double delta = std::atan2(a, c), r = std::hypot(a, c);
  const double xh = RglBsdf::ThetaToU((delta + kPi / 2) / 2) / h;  // in node units
  const std::size_t k = std::min(static_cast<std::size_t>(xh), n - 2);
  std::vector<double> band(n), left(n, 0.0), right(n, 0.0);
  for (std::size_t x = 0; x < n; ++x) {
    const double ux = double(x) * h, theta = RglBsdf::UToTheta(ux);
    const double cos_o = r * std::cos(2 * theta - delta), z = cos_o / band_width;
    const double dz = 2 * r * std::abs(std::sin(2 * theta - delta)) * kPi * ux / band_width;  // |dz / du_x|
    band[x] = kBandShare * std::exp(-z * z) * dz / std::sqrt(kPi);
    const double t = std::clamp((std::abs(cos_o) - gap) / gap, 0.0, 1.0), taper = t * t * (3 - 2 * t);
    (x <= k ? left : right)[x] = (kLobeShare * lobe[x] + kUniformShare) * taper;
  }
  // Integrals over [0, horizon] and over the row of the piecewise-linear density.
  auto integrals = [&](const std::vector<double>& v) {
    std::array<double, 2> m = {0.0, 0.0};
    for (std::size_t j = 0; j + 1 < n; ++j) {
      const double t = std::clamp(xh - double(j), 0.0, 1.0);
      m[0] += h * (v[j] * t + (v[j + 1] - v[j]) * t * t / 2);
      m[1] += h * (v[j] + v[j + 1]) / 2;
    }
    return m;
  };
  const auto il = integrals(left), ir = integrals(right), ib = integrals(band);
  // alpha, beta: the scales of the rest above and below the horizon, so
  // that the row holds 1 - kBelowHorizon up to the horizon and 1 in all.
  const double r1 = 1 - kBelowHorizon - ib[0], r2 = kBelowHorizon - (ib[1] - ib[0]);
  const double a11 = il[0], a12 = ir[0], a21 = il[1] - il[0], a22 = ir[1] - ir[0], det = a11 * a22 - a12 * a21;
  double alpha = det != 0 ? (r1 * a22 - a12 * r2) / det : 1, beta = det != 0 ? (a11 * r2 - a21 * r1) / det : 1;
  // Where the band alone overfills a side (rows of grazing slices) the rest
  // stays positive, and that row's CDF misses 1 - kBelowHorizon at its horizon.
  alpha = std::max(alpha, 1e-3);
  beta = std::max(beta, 1e-3);
  for (std::size_t x = 0; x < n; ++x) out[x] = static_cast<float>(mass * (alpha * left[x] + beta * right[x] + band[x]));
}

}  // namespace

bool InvariantUnder(const BrdfFunction& f, const std::function<Eigen::Vector3d(const Eigen::Vector3d&)>& map) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> theta(0.05, 1.4), phi(0.0, 2 * kPi);
  for (int k = 0; k < 64; ++k) {
    const double theta_i = theta(rng), phi_i = phi(rng), theta_o = theta(rng), phi_o = phi(rng);
    const Eigen::Vector3d wi = RglBsdf::Direction(theta_i, phi_i), wo = RglBsdf::Direction(theta_o, phi_o);
    const Rgb<double> a = f(wi, wo), b = f(map(wi), map(wo));
    // Relative to the larger value; an absolute 1e-12 for values near 0.
    if (((a - b).abs() > 1e-6 * a.abs().max(b.abs()) + 1e-12).any()) return false;
  }
  return true;
}

int RglAnisotropicSlices(int symmetry) {
  // A symmetry below 1 counts as 1 here; MakeRgl refuses it with its message.
  const int k = std::max(symmetry, 1), intervals = kRglAnisotropicPhiI - 1;
  return 1 + (intervals + k - 1) / k;
}

RglOptions WithDefaults(RglOptions o) {
  // Isotropic files: the resolution at which every source of the accuracy
  // measure stays within 1 % (bench/RESULTS.md: value rows and vndf rows
  // follow the horizon's sweep in azimuth, slices its motion with theta_i,
  // 512 ndf nodes the steep tails of rough Beckmann lobes). Anisotropic
  // files store the vndf and values once per phi_i slice: 32 theta_i
  // slices of a 48^2 vndf and 40^2 values, RglAnisotropicSlices of them
  // when convert chooses.
  // vndf columns left automatic follow rows given explicitly (a square table).
  const bool iso = o.phi_i == 0;
  if (o.theta_i == 0) o.theta_i = iso ? 80 : 32;
  if (o.vndf_theta == 0) o.vndf_theta = o.vndf != 0 ? o.vndf : iso ? 128 : 48;
  if (o.vndf == 0) o.vndf = iso ? 512 : 48;
  if (o.samples == 0) o.samples = iso ? 208 : 40;
  return o;
}

TensorFile MakeRgl(const BrdfFunction& f, const RglOptions& options) {
  const RglOptions o = WithDefaults(options);
  Check(o.theta_i >= 2 && o.theta_i <= 1024, "theta_i slices must be 2 to 1024");
  Check(o.phi_i == 0 || (o.phi_i >= 3 && o.phi_i <= 1024), "phi_i slices must be 0 (isotropic) or 3 to 1024");
  Check(o.symmetry == 1 || o.symmetry == 2 || o.symmetry == 4,
        "symmetry must be 1 (the whole circle of incident azimuths), 2 or 4, got " + std::to_string(o.symmetry));
  Check(o.symmetry == 1 || o.phi_i > 0, "symmetry " + std::to_string(o.symmetry) +
                                            " applies to anisotropic files (phi_i slices); an isotropic file holds one slice");
  if (o.symmetry == 2)
    Check(InvariantUnder(f, [](const Eigen::Vector3d& w) { return Eigen::Vector3d(-w.x(), -w.y(), w.z()); }),
          "symmetry 2: the source changes under a turn by pi about the normal, which the readers' fold assumes it does not");
  if (o.symmetry == 4)
    for (int axis : {0, 1})
      Check(InvariantUnder(f, [axis](Eigen::Vector3d w) { return w[axis] = -w[axis], w; }),
            std::string("symmetry 4: the source changes under the mirror ") + (axis == 0 ? "x -> -x" : "y -> -y") +
                ", which the readers' fold assumes it does not");
  Check(o.theta_max_deg > 0 && o.theta_max_deg <= kRglThetaMaxDeg,
        "theta_max must be in (0, " + FormatDouble(kRglThetaMaxDeg) + "] degrees, got " + FormatDouble(o.theta_max_deg) +
            " (closer to grazing a slice has no room for the horizon's band and the rest)");
  const std::pair<const char*, int> resolutions[] = {
      {"ndf", o.ndf},         {"sigma", o.sigma},     {"vndf", o.vndf},
      {"vndf_theta", o.vndf_theta}, {"samples", o.samples}};
  for (const auto& [name, r] : resolutions)
    Check(r >= 2 && r <= 4096, std::string("resolution ") + name + " must be 2 to 4096, got " + std::to_string(r));
  const bool iso = o.phi_i == 0;
  using RB = RglBsdf;

  // 1. ndf: the retro-reflection f(w, w) at every node (0 in the horizon
  // column, where no direction reflects back).
  const std::size_t nd = static_cast<std::size_t>(o.ndf), ns = static_cast<std::size_t>(o.sigma);
  const std::vector<double> retro = SquareTable<double>(nd, iso, [&](std::size_t x, std::size_t y) {
    if (x + 1 == nd) return 0.0;
    const Eigen::Vector3d wm = RB::Direction(RB::UToTheta(double(x) / double(nd - 1)), RB::UToPhi(double(y) / double(nd - 1)));
    return Luminance(SourceAt(f, wm, wm));
  });
  // Trapezoidal weights of the nodes over the square times the Jacobian.
  auto node_weight = [](std::size_t i, std::size_t n) { return (i == 0 || i + 1 == n ? 0.5 : 1.0) / double(n - 1); };
  std::vector<Eigen::Vector3d> m_dir(nd * nd);
  std::vector<double> m_w(nd * nd);
  for (std::size_t y = 0; y < nd; ++y)
    for (std::size_t x = 0; x < nd; ++x) {
      const double ux = x / double(nd - 1), theta = RB::UToTheta(ux);
      m_dir[y * nd + x] = RB::Direction(theta, RB::UToPhi(y / double(nd - 1)));
      m_w[y * nd + x] = node_weight(x, nd) * node_weight(y, nd) * 2 * kPi * kPi * ux * std::sin(theta);
    }
  // sigma(wi) of a normalised D on the ns x ns square of wi.
  auto sigma_of = [&](const std::vector<float>& dn) {
    return SquareTable<float>(ns, iso, [&](std::size_t x, std::size_t y) {
      const Eigen::Vector3d wi = RB::Direction(RB::UToTheta(double(x) / double(ns - 1)), RB::UToPhi(double(y) / double(ns - 1)));
      double sum = 0;
      for (std::size_t i = 0; i < nd * nd; ++i) sum += dn[i] * std::max(0.0, wi.dot(m_dir[i])) * m_w[i];
      return sum;
    });
  };
  // Floored (so that every direction keeps some density) and normalised so
  // that int D cos(theta_m) dw = 1.
  auto normalise = [&](std::vector<double> d) {
    double d_max = 0;
    for (double v : d) d_max = std::max(d_max, v);
    // A black source has no retro-reflection to learn from: a uniform density.
    const double floor = d_max > 0 ? kNdfFloor * d_max : 1.0;
    double norm = 0;
    for (std::size_t i = 0; i < nd * nd; ++i) {
      d[i] = std::max(d[i], floor);
      norm += d[i] * m_dir[i].z() * m_w[i];
    }
    std::vector<float> out(nd * nd);
    for (std::size_t i = 0; i < nd * nd; ++i) out[i] = static_cast<float>(d[i] / norm);
    return out;
  };
  // First D ~ f(w, w) cos^2 (sigma ~ cos), then the height-correlated Smith
  // fixed point D ~ f(w, w) cos (2 sigma - cos).
  std::vector<double> d(nd * nd);
  for (std::size_t i = 0; i < nd * nd; ++i) d[i] = retro[i] * m_dir[i].z() * m_dir[i].z();
  std::vector<float> ndf = normalise(d), sigma = sigma_of(ndf);
  {
    const Warp2D s_table(sigma, ns, ns, {}, false);
    for (std::size_t y = 0; y < nd; ++y)
      for (std::size_t x = 0; x < nd; ++x) {
        const std::size_t i = y * nd + x;
        const double mu = m_dir[i].z(), sg = s_table.Eval(x / double(nd - 1), y / double(nd - 1));
        // 2 sigma - cos >= sigma when D is symmetric about the normal (then
        // sigma >= cos); the max keeps other estimates positive.
        d[i] = retro[i] * mu * std::max(2 * sg - mu, sg);
      }
    ndf = normalise(d);
    sigma = sigma_of(ndf);
  }
  const Warp2D ndf_table(ndf, nd, nd, {}, false);
  const Warp2D sigma_table(sigma, ns, ns, {}, false);

  // Slices.
  // Density 1 / (c + cos theta) (step 0 above): int dtheta / (c + cos theta)
  // = 2 / sqrt(1 - c^2) atanh(k tan(theta / 2)), k = sqrt((1 - c) / (1 + c)),
  // so the nodes are uniform in atanh(k tan(theta / 2)); float as the file
  // stores them.
  std::vector<double> theta_nodes(static_cast<std::size_t>(o.theta_i)), phi_nodes;
  {
    const double k = std::sqrt((1 - kSliceCos) / (1 + kSliceCos));
    const double a_max = std::atanh(k * std::tan(o.theta_max_deg * kPi / 180 / 2));
    for (std::size_t j = 0; j < theta_nodes.size(); ++j)
      theta_nodes[j] =
          static_cast<float>(2 * std::atan(std::tanh(a_max * double(j) / double(theta_nodes.size() - 1)) / k));
  }
  if (iso) {
    phi_nodes = {0.0};
  } else {
    // From -pi over 2 pi / symmetry, where the readers fold a reduced file's queries.
    for (int k = 0; k < o.phi_i; ++k)
      phi_nodes.push_back(static_cast<float>(-kPi + 2 * kPi / o.symmetry * k / (o.phi_i - 1)));
  }
  const std::size_t np = phi_nodes.size(), nt = theta_nodes.size();
  auto slice_wi = [&](std::size_t a, std::size_t b) { return RB::Direction(theta_nodes[b], iso ? 0.0 : phi_nodes[a]); };

  // 3. vndf over vy rows (azimuth of wm) x vx columns (elevation), a slice per task.
  const std::size_t vy = static_cast<std::size_t>(o.vndf), vx = static_cast<std::size_t>(o.vndf_theta);
  const double hx = 1.0 / double(vx - 1);
  // The largest spacing of the vndf rows (azimuth of wm) and theta_i slices, in radians.
  double spacing = 2 * kPi / double(vy - 1);
  for (std::size_t b = 0; b + 1 < nt; ++b) spacing = std::max(spacing, theta_nodes[b + 1] - theta_nodes[b]);
  std::vector<float> vndf(np * nt * vy * vx);
  tbb::parallel_for(std::size_t{0}, np * nt, [&](std::size_t slice) {
    const std::size_t a = slice / nt, b = slice % nt;
    float* out = vndf.data() + slice * vy * vx;
    const Eigen::Vector3d wi = slice_wi(a, b);
    const double phi_i = iso ? 0.0 : phi_nodes[a];
    const double sig = sigma_table.Eval(RB::ThetaToU(theta_nodes[b]), RB::PhiToU(phi_i));
    // The visible normals (D + kVndfSpread sigma / pi) <wi, wm>+ times the
    // square's Jacobian u_x sin(theta_m), normalised over the square
    // (trapezoidal rule on the nodes, as the reader normalises).
    std::vector<double> lobe(vy * vx);
    double mass = 0;
    for (std::size_t y = 0; y < vy; ++y)
      for (std::size_t x = 0; x < vx; ++x) {
        const double ux = double(x) * hx, uy = double(y) / double(vy - 1), theta = RB::UToTheta(ux);
        const Eigen::Vector3d wm = RB::Direction(theta, RB::UToPhi(uy));
        const double q = (ndf_table.Eval(ux, uy) + kVndfSpread * sig / kPi) * std::max(0.0, wi.dot(wm)) * ux * std::sin(theta);
        lobe[y * vx + x] = q;
        mass += q * node_weight(x, vx) * node_weight(y, vy);
      }
    // Where the values vary along a row, value columns as dense as their
    // interpolation needs (ValueVariation): the lobe is raised to k d, so the
    // rest there holds at least about 0.25 k d (its lobe share 0.35 times
    // its scale, about 0.7), neighbouring value columns lie du <= 1 / (0.25
    // k d (nx - 1)) apart, and the linear interpolation's relative error
    // du^2 d^2 / 8 stays below kValueTolerance.
    const double k = 1 / (0.25 * double(o.samples - 1) * std::sqrt(8 * kValueTolerance));
    const std::vector<double> variation = ValueVariation(f, ndf_table, wi, vy, vx);
    for (std::size_t i = 0; i < vy * vx; ++i) lobe[i] = std::max(lobe[i] / mass, k * variation[i]);
    // Rows of anisotropic files are absolute azimuths of wm.
    const double gap = RestGap(theta_nodes[b], spacing);
    const double band =
        iso ? kHorizonBand : std::clamp(std::cos(double(theta_nodes[b])), kHorizonBand, kAnisotropicBand);
    for (std::size_t y = 0; y < vy; ++y) {
      const double phi = RB::UToPhi(double(y) / double(vy - 1)) - phi_i, c = std::cos(phi);
      const double row_mass = iso ? 1 + kRowCrowd * std::exp(-c * c / (2 * kRowWidth * kRowWidth)) : 1.0;
      AlignedRow(theta_nodes[b], phi, gap, band, lobe.data() + y * vx, vx, row_mass, out + y * vx);
    }
  });
  const Warp2D vndf_warp(vndf, vy, vx, {phi_nodes, theta_nodes}, true);

  // 4. values: ny rows x nx columns per slice, a slice per task.
  const std::size_t ny = static_cast<std::size_t>(o.samples), nx = ny, plane = ny * nx;
  std::vector<float> rgb(np * nt * 3 * plane), lum(np * nt * plane);
  tbb::parallel_for(std::size_t{0}, np * nt, [&](std::size_t slice) {
    const std::size_t a = slice / nt, b = slice % nt;
    const Eigen::Vector3d wi = slice_wi(a, b);
    const double sig = sigma_table.Eval(RB::ThetaToU(theta_nodes[b]), RB::PhiToU(iso ? 0.0 : phi_nodes[a]));
    for (std::size_t y = 0; y < ny; ++y)
      for (std::size_t x = 0; x < nx; ++x) {
        const std::array<double, 2> u = vndf_warp.Sample(double(x) / double(nx - 1), double(y) / double(ny - 1), slice);
        const Eigen::Vector3d wm = RB::Direction(RB::UToTheta(u[0]), RB::UToPhi(u[1]));
        const Eigen::Vector3d wo = 2 * wi.dot(wm) * wm - wi;
        // Below the horizon the value continues oddly in cos(theta_o): minus
        // the value at the mirror image of wo (with the ndf at its half
        // vector), so that across the horizon the values are c cos(theta_o)
        // on both sides and their interpolation crosses zero there.
        const Eigen::Vector3d wo_n = wo.normalized();
        const Eigen::Vector3d wo_up(wo_n.x(), wo_n.y(), std::max(std::abs(wo_n.z()), 1e-9));
        const Eigen::Vector3d wm_up = (wi + wo_up).normalized();
        const double d_at = wo_n.z() >= 0 ? ndf_table.Eval(u[0], u[1])
                                          : ndf_table.Eval(RB::ThetaToU(std::acos(std::min(wm_up.z(), 1.0))),
                                                           RB::PhiToU(std::atan2(wm_up.y(), wm_up.x())));
        const Rgb<double> v = SourceAt(f, wi, wo_up) * wo_n.z() * 4 * sig / d_at;
        for (int c = 0; c < 3; ++c) rgb[(slice * 3 + c) * plane + y * nx + x] = static_cast<float>(v[c]);
        lum[slice * plane + y * nx + x] = static_cast<float>(std::max(Luminance(v), 0.0));  // a sampling density
      }
    // A slice whose values are all black (a black source) gets a uniform
    // sampling density: the loaders normalise each slice by its sum (Mitsuba
    // 3 by 1 / sum unguarded) and would read NaN for all of it.
    float* l = lum.data() + slice * plane;
    if (std::all_of(l, l + plane, [](float v) { return v == 0; })) std::fill(l, l + plane, 1.0f);
  });

  TensorFile t;
  t.Add("description", std::vector<unsigned char>(o.description.begin(), o.description.end()));
  t.Add("jacobian", std::vector<unsigned char>{1});
  t.Add("theta_i", std::vector<float>(theta_nodes.begin(), theta_nodes.end()), {nt});
  t.Add("phi_i", std::vector<float>(phi_nodes.begin(), phi_nodes.end()), {np});
  t.Add("ndf", ndf, {nd, nd});
  t.Add("sigma", sigma, {ns, ns});
  t.Add("vndf", vndf, {np, nt, vy, vx});
  t.Add("luminance", lum, {np, nt, ny, nx});
  t.Add("rgb", rgb, {np, nt, 3, ny, nx});
  return t;
}

void WriteRgl(const std::string& path, const BrdfFunction& f, const RglOptions& options) {
  MakeRgl(f, options).Write(path);
}

namespace {

// The measure at theta_i = first, first + step .. up to last (degrees).
RglAccuracy MeasureOver(const RglBsdf& file, const BrdfFunction& f, double first, double last, double step_deg,
                        double threshold, double theta_o_max_deg) {
  const double deg = kPi / 180;
  std::vector<std::array<double, 2>> incident;  // (theta_i, phi_i) in degrees
  // Counted steps (no drift); 1e-3 degrees of slack keeps a node at `last`
  // (a file stores its slices' angles in float radians).
  for (int k = 0; first + k * step_deg <= last + 1e-3; ++k)
    for (double pi = 0; pi < 360; pi += 50) {
      incident.push_back({first + k * step_deg, pi});
      if (file.isotropic) break;
    }
  RglAccuracy acc;
  std::ostringstream where;
  where << "f cos(theta_o) above " << 100 * threshold << " % of its maximum over wo";
  if (!incident.empty())
    where << ", theta_i " << incident.front()[0] << ".." << incident.back()[0] << " deg in steps of " << step_deg
          << (file.isotropic ? "" : ", phi_i 0, 50 .. 350 deg");
  where << ", wo on a 1 x 2 deg grid (theta_o 0.5, 1.5 ..) below theta_o " << theta_o_max_deg << " deg";
  acc.where = where.str();
  // The errors of each incident direction, measured side by side.
  std::vector<std::vector<double>> per(incident.size());
  tbb::parallel_for(std::size_t{0}, incident.size(), [&](std::size_t k) {
    const Eigen::Vector3d wi = RglBsdf::Direction(incident[k][0] * deg, incident[k][1] * deg);
    std::vector<Eigen::Vector3d> wos;
    std::vector<Rgb<double>> ref;
    Rgb<double> peak = Rgb<double>::Zero();
    for (double to = 0.5; to < 90; to += 1)
      for (double po = 1; po < 360; po += 2) {
        const Eigen::Vector3d wo = RglBsdf::Direction(to * deg, po * deg);
        wos.push_back(wo);
        ref.push_back(f(wi, wo) * wo.z());
        peak = peak.max(ref.back());
      }
    for (std::size_t j = 0; j < wos.size(); ++j) {
      if (!(std::acos(std::min(wos[j].z(), 1.0)) < theta_o_max_deg * deg)) continue;
      const Rgb<double> got = file.FrCos(wi, wos[j]);
      for (int c = 0; c < 3; ++c)
        if (ref[j][c] > threshold * peak[c]) per[k].push_back(std::abs(got[c] - ref[j][c]) / ref[j][c]);
    }
  });
  std::vector<double> errors;
  for (const auto& e : per) errors.insert(errors.end(), e.begin(), e.end());
  acc.points = errors.size();
  if (errors.empty()) return acc;
  double sum = 0;
  for (double e : errors) {
    sum += e;
    acc.max_relative = std::max(acc.max_relative, e);
  }
  acc.mean_relative = sum / double(errors.size());
  std::sort(errors.begin(), errors.end());
  acc.p99_relative = errors[std::min(errors.size() - 1, static_cast<std::size_t>(0.99 * double(errors.size())))];
  return acc;
}

}  // namespace

RglAccuracy MeasureRglAccuracy(const RglBsdf& file, const BrdfFunction& f, double theta_max_deg, double step_deg,
                               double threshold, double theta_o_max_deg) {
  return MeasureOver(file, f, step_deg / 2, theta_max_deg, step_deg, threshold, theta_o_max_deg);
}

RglAccuracy MeasureRglAccuracyTowardsGrazing(const RglBsdf& file, const BrdfFunction& f, double from_deg,
                                             double step_deg) {
  const double last = file.theta_i.empty() ? 0.0 : file.theta_i.back() * 180 / kPi;
  // A file that ends before from_deg: its last slice alone.
  return MeasureOver(file, f, std::min(from_deg, last), last, step_deg, 0.01, 90);
}

}  // namespace brdfkit::formats
