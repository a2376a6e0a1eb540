// The gonioreflectometer's forward model: the reflectance an instrument with
// finite source and detector apertures reports for a given BRDF.
//
// Measurement equation (Nicodemus et al. 1977, NBS Monograph 160, eq. 3.8;
// Nicodemus 1978): the detector signal is
//   S = A W_e L_s int_{Omega_s} int_{Omega_d} f_r(wi, wo) cos(theta_i) cos(theta_o) dwo dwi
// and the instrument reports f_hat = S / (E Omega_d,proj W_e A) with the
// irradiance E = L_s int_{Omega_s} cos(theta_i) dwi and the projected solid
// angle Omega_d,proj = int_{Omega_d} cos(theta_o) dwo. So f_hat is f_r
// averaged over both cones with weights cos(theta_i) cos(theta_o).
//
// Quadrature over each cone (angular radius r around its axis): with
// u = 1 - cos(alpha) (alpha the angle from the axis) the solid angle element
// is du dbeta, so an order-n rule takes n Gauss-Legendre nodes in
// u in [0, 1 - cos r] times 4n trapezoid nodes in beta (exact for trigonometric
// polynomials of degree < 4n). It integrates polynomials of total degree
// 4n - 1 in the tangent-plane offsets exactly, so the error falls
// geometrically with n for lobes wider than the aperture. A cone of radius 0 is
// one node of weight 1 (an ideal point source or detector). The whole rule is
// the product of the two cone rules: (4 n^2)^2 BRDF evaluations.
//
// The numerator uses cosines about the TRUE sample normal (a tilted sample
// receives and sends a different projected flux); the normalisation uses the
// instrument's NOMINAL frame, as a real instrument calibrated without
// knowing its misalignment does. No light arrives from, or leaves towards,
// below the true horizon: a cone the horizon cuts is integrated over its part
// above it (PlaceCone).
//
// Templated on the scalar T of the BRDF parameters (double or ceres::Jet),
// directions stay double: fits can optimise through this model.
#pragma once

#include <Eigen/Core>

#include <cmath>
#include <type_traits>
#include <vector>

#include "brdf/core.h"
#include "data_synth/instrument.h"

namespace brdfkit::synth {

// Nodes of one cone in its own frame (z = cone axis) and their solid-angle
// weights in sr (their sum is the cone's solid angle, 2 pi (1 - cos r)).
struct ConeRule {
  double angular_radius = 0;
  int degree = 3;  // exact for polynomials of this degree in the tangent offsets
  std::vector<Eigen::Vector3d> offsets;
  std::vector<double> weights;
  // Gauss-Legendre nodes and weights on [0, 1] for the part of a cone above
  // a horizon (PlaceCone), in each of its two variables: (k + 1) / 2 of
  // them, so the cut rule has about as many nodes as the whole one.
  std::vector<double> clip_nodes, clip_weights;
  bool IsPoint() const { return offsets.size() == 1 && angular_radius == 0; }
};

struct ApertureQuadrature {
  ConeRule source, detector;
  // Instrument frame -> true sample frame (identity for a well-aligned sample).
  Eigen::Matrix3d sample_from_lab = Eigen::Matrix3d::Identity();
  int order = 1;
};

// Order-n rule over a cone of angular radius `radius` (rad); see above.
ConeRule MakeConeRule(double radius, int order);
// The rule of odd degree k >= 3: k + 1 trapezoid nodes in beta times
// (k - 1) / 4 + 1 Gauss-Legendre nodes in u, exact for polynomials of degree
// k in the tangent offsets (u ~ rho^2 / 2, so u needs degree (k - 1) / 2).
// Order n is degree 4n - 1; the degrees in between (5, 9, 13, ...: 12, 30,
// 56 nodes) let the automatic order rise in smaller steps.
ConeRule MakeConeRuleOfDegree(double radius, int degree);
// Rules for the instrument's source and detector cones and its sample tilt.
ApertureQuadrature MakeApertureQuadrature(const Instrument& inst, int order);

// Frame of a goniometer arm pointing along unit w: columns e_theta, e_phi, w
// (spherical unit vectors; at the pole phi = atan2(w.y, w.x) = 0 is used).
inline Eigen::Matrix3d ArmFrame(const Eigen::Vector3d& w) {
  const double sin_theta = std::hypot(w.x(), w.y());
  const double phi = std::atan2(w.y(), w.x());
  const double cos_phi = std::cos(phi), sin_phi = std::sin(phi);
  Eigen::Matrix3d f;
  f.col(0) = Eigen::Vector3d(w.z() * cos_phi, w.z() * sin_phi, -sin_theta);
  f.col(1) = Eigen::Vector3d(-sin_phi, cos_phi, 0.0);
  f.col(2) = w;
  return f;
}

// One cone placed on the instrument: node directions in the sample frame with
// weight * cos(theta) about the true normal, and the nominal projected solid
// angle sum weight * cos(theta) about the instrument's normal.
//
// A cone that reaches below a horizon (the true one for the nodes, the
// nominal one for the normalisation) is integrated over its part above that
// horizon only, with a rule fitted to that part, in the spherical
// coordinates (theta, phi) of the horizon's frame: theta = theta_a +
// r sin(psi) from the cone's top row down to the horizon, and phi across the
// cone's width at that theta, Gauss-Legendre in psi and in phi. The width
// opens and closes as a square root at the cone's top and bottom rows, and
// is smooth in psi, so the error still falls geometrically with the order;
// dropping the nodes below the horizon instead leaves a kink and algebraic
// convergence. (A cone over 45 degrees wide that also covers the normal
// has one more kink, where it starts to span every phi.)
struct PlacedCone {
  std::vector<Eigen::Vector3d> directions;
  std::vector<double> weights;
  double nominal_projected = 0;
  bool clipped = false;  // the true horizon cuts the cone
};

// `actual` is where the arm really points (jitter), `nominal` where the
// instrument believes it points; usually the same.
PlacedCone PlaceCone(const ConeRule& rule, const Eigen::Vector3d& actual, const Eigen::Vector3d& nominal,
                     const Eigen::Matrix3d& sample_from_lab);

template <class T>
struct ApertureIntegral {
  // sum over both cones of w_s w_d cos_i cos_o f_r (true geometry), in sr^2 / sr.
  Rgb<T> weighted = Rgb<T>::Constant(T(0));
  // Nominal projected solid angles of source and detector cones (sr).
  double source_projected = 0, detector_projected = 0;
  double Norm() const { return source_projected * detector_projected; }
};

template <class T>
ApertureIntegral<T> IntegrateApertures(const Bxdf<T>& bxdf, const T* params, const PlacedCone& source,
                                       const PlacedCone& detector) {
  ApertureIntegral<T> out;
  out.source_projected = source.nominal_projected;
  out.detector_projected = detector.nominal_projected;
  // Detector directions as T once per call (as they are for double).
  std::vector<Vec3<T>> cast;
  const Vec3<T>* wo;
  if constexpr (std::is_same_v<T, double>) {
    wo = detector.directions.data();
  } else {
    cast.reserve(detector.directions.size());
    for (const Eigen::Vector3d& d : detector.directions) cast.push_back(d.template cast<T>());
    wo = cast.data();
  }
  for (std::size_t s = 0; s < source.directions.size(); ++s) {
    const Vec3<T> wi = source.directions[s].template cast<T>();
    const Rgb<T> inner = bxdf.EvalSum(params, wi, wo, detector.weights.data(), detector.directions.size());
    out.weighted += inner * T(source.weights[s]);
  }
  return out;
}

// f_hat for nominal directions wi (towards the source) and wo (towards the
// detector), unit vectors in the instrument frame. Returns 0 when either
// nominal cone lies wholly below the horizon (nothing is measured there).
template <class T>
Rgb<T> MeasuredBrdf(const Bxdf<T>& bxdf, const T* params, const Eigen::Vector3d& wi, const Eigen::Vector3d& wo,
                    const ConeRule& source, const ConeRule& detector, const Eigen::Matrix3d& sample_from_lab) {
  const PlacedCone src = PlaceCone(source, wi, wi, sample_from_lab);
  const PlacedCone det = PlaceCone(detector, wo, wo, sample_from_lab);
  const ApertureIntegral<T> a = IntegrateApertures(bxdf, params, src, det);
  const double norm = a.Norm();
  if (!(norm > 0)) return Rgb<T>::Constant(T(0));  // no nominal flux: not a measurable geometry
  return a.weighted / T(norm);
}
template <class T>
Rgb<T> MeasuredBrdf(const Bxdf<T>& bxdf, const T* params, const Eigen::Vector3d& wi, const Eigen::Vector3d& wo,
                    const ApertureQuadrature& q) {
  return MeasuredBrdf(bxdf, params, wi, wo, q.source, q.detector, q.sample_from_lab);
}

// Automatic order: each cone's rule rises on its own, per pair, through the
// degrees 3, 5, 7, ... (levels L = 1, 2, 3, ...: degree 2 L + 1). I(a, b) is
// f_hat from the product of the level-a source rule and the level-b
// detector rule. From (a, b) = (1, 1): compute I(a, b), I(a+1, b) and
// I(a, b+1); the steps e_s = |I(a+1, b) - I(a, b)| and
// e_d = |I(a, b+1) - I(a, b)| (relative to the result, max over channels)
// estimate the error each cone's rule leaves. Once e_s + e_d is below the
// tolerance the result is I(a+1, b) + I(a, b+1) - I(a, b) (both leading
// errors removed) with e_s + e_d as its error estimate; otherwise the level
// of each cone whose step exceeds half the tolerance is raised, up to the
// ladder's top. A pair stops early, unconverged, when the ratio of a cone's
// last two steps predicts that it would not reach the tolerance within the
// ladder (a lobe narrower than the cone). A small source (or a collimated
// one, a single node) thereby stays low while the detector rises: a typical
// pair costs I(1,1) + I(2,1) + I(1,2) + I(2,2) +
// I(1,3) = 16 + 48 + 48 + 144 + 64 BRDF evaluations, where raising one common
// order until two successive orders agree costs 16 + 256 + 1,296.
struct ApertureLadder {
  std::vector<ConeRule> source, detector;  // [L - 1]: the rule of degree 2 L + 1 (a point cone has one entry)
  Eigen::Matrix3d sample_from_lab = Eigen::Matrix3d::Identity();
};
// Rules of degree 3, 5, ... up to the given degrees (a point cone keeps its single node).
ApertureLadder MakeApertureLadder(const Instrument& inst, int max_source_degree, int max_detector_degree);

struct AdaptiveMeasurement {
  Rgb<double> f = Rgb<double>::Zero();  // f_hat
  double norm = 0;    // nominal projected solid angles, source x detector, at the highest orders used (sr^2)
  double error = 0;   // relative error estimate e_s + e_d
  int source_degree = 0, detector_degree = 0;  // highest rule degrees used (0: a point cone)
  bool converged = false;  // error below the tolerance; false: the ladder's top was reached, or would not do
  long evaluations = 0;    // BRDF evaluations
  int source_level = 1, detector_level = 1;  // the levels (a, b) it stopped at (MeasuredAtLevels)
};
// f_hat with cones around the `actual` arm directions (jitter) normalised by
// the `nominal` ones, as PlaceCone.
AdaptiveMeasurement MeasureAdaptive(const Bxdf<double>& bxdf, const double* params, const Eigen::Vector3d& actual_i,
                                    const Eigen::Vector3d& nominal_i, const Eigen::Vector3d& actual_o,
                                    const Eigen::Vector3d& nominal_o, const ApertureLadder& ladder, double tolerance);

// MeasureAdaptive's f_hat at the levels (a, b) it stopped at, for any scalar
// T (ceres::Jet: fits through the instrument differentiate it with the
// levels held): I(a, b) plus the step of each cone below the ladder's top,
// I(a+1, b) - I(a, b) and I(a, b+1) - I(a, b). Nominal and actual arms are
// the same (no jitter).
template <class T>
Rgb<T> MeasuredAtLevels(const Bxdf<T>& bxdf, const T* params, const Eigen::Vector3d& wi, const Eigen::Vector3d& wo,
                        const ApertureLadder& ladder, int a, int b) {
  const auto I = [&](int i, int j) {
    return MeasuredBrdf(bxdf, params, wi, wo, ladder.source[i - 1], ladder.detector[j - 1], ladder.sample_from_lab);
  };
  const Rgb<T> p = I(a, b);
  Rgb<T> f = p;
  if (a < static_cast<int>(ladder.source.size())) f += I(a + 1, b) - p;
  if (b < static_cast<int>(ladder.detector.size())) f += I(a, b + 1) - p;
  return f;
}

}  // namespace brdfkit::synth
