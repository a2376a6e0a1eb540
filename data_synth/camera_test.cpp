// Image-based measurement: the pinhole measurement equation (cos^4 falloff,
// f-number), and render -> raw OpenEXR -> reduce round trips, noiseless and
// with sensor noise and bracketed exposures.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "brdf/model.h"
#include "brdf/params.h"
#include "data_synth/camera.h"
#include "data_synth/outputs.h"
#include "tests/cli_util.h"

namespace brdfkit::synth {
namespace {

namespace fs = std::filesystem;

TEST(Camera, RawImageFollowsThePinholeEquation) {
  // Flat Lambertian sample seen straight down, light at the normal.
  CameraRig rig = DefaultCameraRig();
  rig.shape = CameraRig::Shape::kFlat;
  rig.size = 1.0;  // fills the view
  rig.view_theta = 0;
  rig.light_theta = 0;
  rig.width = 41;
  rig.height = 31;
  rig.pixel_pitch = 1e-3;  // a wide field: corners 30 degrees off axis
  rig.focal_length = 0.05;
  rig.f_number = 4;
  rig.exposures = {1e-3};
  rig.responsivity = Eigen::Array3d(1e15, 2e15, 3e15);
  const Model model = Model::Parse("lambert");
  const std::vector<double> p = ParseParams(model.Info(), "albedo=0.6");
  const CameraCapture cap = RenderCamera(rig, model, p, 0);
  const std::size_t npix = std::size_t(rig.width) * rig.height;
  for (int y : {0, 15, 30})
    for (int x : {0, 20, 40}) {
      // Off-axis angle of the pixel centre; the lens aperture d = f / N.
      const double xs = (x + 0.5 - rig.width / 2.0) * rig.pixel_pitch, ys = (y + 0.5 - rig.height / 2.0) * rig.pixel_pitch;
      const double theta_p = std::atan(std::hypot(xs, ys) / rig.focal_length);
      const double d = rig.focal_length / rig.f_number;
      const double radiance = 0.6 / kPi * rig.irradiance[1];  // cos(theta_i) = 1
      const double e_img = kPi / 4 * (d / rig.focal_length) * (d / rig.focal_length) * std::pow(std::cos(theta_p), 4) *
                           radiance;
      const double electrons = e_img * rig.pixel_pitch * rig.pixel_pitch * rig.exposures[0] * rig.responsivity[1];
      EXPECT_NEAR(cap.raw[0][npix + std::size_t(y) * rig.width + x], electrons, 1e-6 * electrons) << x << " " << y;
    }
  // The corner is visibly darker: cos^4 of about 28 degrees.
  EXPECT_LT(cap.raw[0][npix], 0.65 * cap.raw[0][npix + 15 * rig.width + 20]);
}

CameraRig SphereRig() {
  CameraRig rig = DefaultCameraRig();
  rig.shape = CameraRig::Shape::kSphere;
  rig.size = 0.05;
  rig.distance = 1.0;
  rig.view_theta = 20 * kDeg;
  rig.view_phi = 0;
  rig.focal_length = 0.05;
  rig.f_number = 8;
  rig.width = 64;
  rig.height = 64;
  rig.pixel_pitch = 1e-4;
  rig.light = CameraRig::Light::kDistant;
  rig.light_theta = 40 * kDeg;
  rig.light_phi = 180 * kDeg;
  rig.irradiance = Eigen::Array3d(10, 12, 14);
  rig.responsivity = Eigen::Array3d::Constant(1e16);
  return rig;
}

TEST(Camera, NoiselessRoundTripRecoversTheBrdf) {
  CameraRig rig = SphereRig();
  rig.exposures = {1e-2};
  const Model model = Model::Parse("lambert+ggx");
  const std::vector<double> p = ParseParams(model.Info(), "lambert.albedo=0.3:0.4:0.5,ggx.alpha=0.2");
  const fs::path d = test::FreshDir("camera-clean");
  const CameraCapture cap = RenderCamera(rig, model, p, 0);
  const auto files = WriteCameraCapture((d / "raw").string(), rig, cap, model.Spec(), p, 0);
  ASSERT_EQ(files.size(), 1u);
  const BrdfTable t = ReduceCamera(rig, files);
  EXPECT_GT(t.rows.size(), 1000u);  // the sphere covers about 50 x 50 pixels
  EXPECT_FALSE(t.has_sigma);
  const auto bxdf = model.Make<double>();
  for (const BrdfSample& s : t.rows) {
    const Rgb<double> f =
        bxdf->Eval(p.data(), DirectionFromAngles(s.theta_i, s.phi_i), DirectionFromAngles(s.theta_o, s.phi_o));
    for (int c = 0; c < 3; ++c) {
      EXPECT_NEAR(s.f[c], f[c], 2e-6 * f[c]);  // float32 raw images
      EXPECT_EQ(s.sigma[c], 0.0);
    }
  }
}

TEST(Camera, NoisyBracketedRoundTripIsWithinTheNoise) {
  CameraRig rig = SphereRig();
  rig.exposures = {1e-3, 1e-2};
  Imperfections& m = rig.sensor;
  m.shot_noise = true;
  m.read_noise = 8;
  m.dark_current = 2000;
  m.adc = true;
  m.adc_bits = 16;
  m.adc_gain = 4;
  m.saturation = true;
  m.full_well = 2e5;
  const Model model = Model::Parse("lambert+ggx");
  const std::vector<double> p = ParseParams(model.Info(), "lambert.albedo=0.3:0.4:0.5,ggx.alpha=0.2");
  const auto bxdf = model.Make<double>();
  const fs::path d = test::FreshDir("camera-noisy");
  double n = 0, sum = 0, sum2 = 0;
  std::size_t saturated_long = 0;
  for (std::uint64_t seed = 0; seed < 4; ++seed) {
    const CameraCapture cap = RenderCamera(rig, model, p, seed);
    for (float v : cap.raw[1]) saturated_long += v * m.adc_gain >= m.full_well - 4 * m.read_noise;
    const auto files = WriteCameraCapture((d / ("raw" + std::to_string(seed))).string(), rig, cap, model.Spec(), p, seed);
    const BrdfTable t = ReduceCamera(rig, files);
    for (const BrdfSample& s : t.rows) {
      const Rgb<double> f =
          bxdf->Eval(p.data(), DirectionFromAngles(s.theta_i, s.phi_i), DirectionFromAngles(s.theta_o, s.phi_o));
      for (int c = 0; c < 3; ++c) {
        ASSERT_GT(s.sigma[c], 0);
        const double z = (s.f[c] - f[c]) / s.sigma[c];
        n += 1;
        sum += z;
        sum2 += z * z;
      }
    }
  }
  EXPECT_GT(saturated_long, 100u);  // the highlight needs the short exposure
  EXPECT_LT(std::abs(sum / n) * std::sqrt(n), 5.0) << "mean z " << sum / n;
  EXPECT_LT(std::abs(sum2 - n) / std::sqrt(2 * n), 5.0) << "mean z^2 " << sum2 / n;
}

TEST(Camera, RigJsonRoundTripsAndErrorsNameTheKey) {
  const CameraRig rig = SphereRig();
  const nlohmann::json j = CameraRigToJson(rig);
  const CameraRig back = ParseCameraRig(j, "rig.json");
  EXPECT_NEAR(back.pixel_pitch, rig.pixel_pitch, 1e-18);
  EXPECT_NEAR(back.view_theta, rig.view_theta, 1e-15);
  EXPECT_NEAR(back.light_phi, rig.light_phi, 1e-15);
  EXPECT_EQ(back.width, rig.width);
  EXPECT_EQ(back.exposures, rig.exposures);
  EXPECT_EQ(CameraRigToJson(back)["light"], j["light"]);
  nlohmann::json bad = j;
  bad["camera"]["f_number"] = "eight";
  try {
    ParseCameraRig(bad, "rig.json");
    ADD_FAILURE();
  } catch (const std::exception& e) {
    EXPECT_NE(std::string(e.what()).find("rig.json: camera.f_number: expected a number"), std::string::npos)
        << e.what();
  }
  bad = j;
  bad["sensor"] = {{"read_noise", {{"electron", 3}}}};
  try {
    ParseCameraRig(bad, "rig.json");
    ADD_FAILURE();
  } catch (const std::exception& e) {
    EXPECT_NE(std::string(e.what()).find("rig.json: sensor.read_noise"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace brdfkit::synth
