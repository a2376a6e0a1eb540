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
// knowing its misalignment does. Cones are evaluated with the BRDF set to
// zero below the true horizon; a cone that crosses the horizon has a kink in
// its integrand and converges only algebraically.
//
// Templated on the scalar T of the BRDF parameters (double or ceres::Jet),
// directions stay double: fits can optimise through this model.
#pragma once

#include <Eigen/Core>

#include <cmath>
#include <vector>

#include "brdf/core.h"
#include "data_synth/instrument.h"

namespace brdfkit::synth {

// Nodes of one cone in its own frame (z = cone axis) and their solid-angle
// weights in sr (their sum is the cone's solid angle, 2 pi (1 - cos r)).
struct ConeRule {
  double angular_radius = 0;
  std::vector<Eigen::Vector3d> offsets;
  std::vector<double> weights;
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
// weight * cos(theta) about the true normal (nodes below the true horizon
// dropped), and the nominal projected solid angle sum weight * max(0, cos)
// about the instrument's normal.
struct PlacedCone {
  std::vector<Eigen::Vector3d> directions;
  std::vector<double> weights;
  double nominal_projected = 0;
};

// `actual` is where the arm really points (jitter), `nominal` where the
// instrument believes it points; usually the same.
inline PlacedCone PlaceCone(const ConeRule& rule, const Eigen::Vector3d& actual, const Eigen::Vector3d& nominal,
                            const Eigen::Matrix3d& sample_from_lab) {
  PlacedCone c;
  c.directions.reserve(rule.offsets.size());
  c.weights.reserve(rule.offsets.size());
  const Eigen::Matrix3d fa = ArmFrame(actual);
  const Eigen::Matrix3d fn = ArmFrame(nominal);
  for (std::size_t k = 0; k < rule.offsets.size(); ++k) {
    const Eigen::Vector3d wn = fn * rule.offsets[k];
    c.nominal_projected += rule.weights[k] * std::max(0.0, wn.z());
    const Eigen::Vector3d ws = sample_from_lab * (fa * rule.offsets[k]);
    if (ws.z() <= 0) continue;  // below the true horizon: f_r = 0 there
    c.directions.push_back(ws);
    c.weights.push_back(rule.weights[k] * ws.z());
  }
  return c;
}

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
  for (std::size_t s = 0; s < source.directions.size(); ++s) {
    const Vec3<T> wi = source.directions[s].template cast<T>();
    Rgb<T> inner = Rgb<T>::Constant(T(0));
    for (std::size_t d = 0; d < detector.directions.size(); ++d)
      inner += bxdf.Eval(params, wi, detector.directions[d].template cast<T>()) * T(detector.weights[d]);
    out.weighted += inner * T(source.weights[s]);
  }
  return out;
}

// f_hat for nominal directions wi (towards the source) and wo (towards the
// detector), unit vectors in the instrument frame. Returns 0 when either
// nominal cone lies wholly below the horizon (nothing is measured there).
template <class T>
Rgb<T> MeasuredBrdf(const Bxdf<T>& bxdf, const T* params, const Eigen::Vector3d& wi, const Eigen::Vector3d& wo,
                    const ApertureQuadrature& q) {
  const PlacedCone src = PlaceCone(q.source, wi, wi, q.sample_from_lab);
  const PlacedCone det = PlaceCone(q.detector, wo, wo, q.sample_from_lab);
  const ApertureIntegral<T> a = IntegrateApertures(bxdf, params, src, det);
  const double norm = a.Norm();
  if (!(norm > 0)) return Rgb<T>::Constant(T(0));  // no nominal flux: not a measurable geometry
  return a.weighted / T(norm);
}

}  // namespace brdfkit::synth
