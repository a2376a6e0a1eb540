#include "data_synth/camera.h"

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <stdexcept>

#include "brdf/atomic_file.h"
#include "brdf/params.h"
#include "data_synth/noise.h"
#include "data_synth/outputs.h"

namespace brdfkit::synth {

namespace {

using nlohmann::json;

[[noreturn]] void Fail(const std::string& file, const std::string& key, const std::string& what) {
  throw std::runtime_error(file + ": " + key + ": " + what);
}

// Strict reader for one JSON object (every key must be known).
struct Fields {
  const json& j;
  std::string path, file;
  std::vector<std::string> used;
  Fields(const json& obj, std::string p, std::string f) : j(obj), path(std::move(p)), file(std::move(f)) {
    if (!j.is_object()) Fail(file, path, "expected an object");
  }
  std::string Key(const std::string& k) const { return path.empty() ? k : path + "." + k; }
  const json& Get(const std::string& k) {
    if (!j.contains(k)) Fail(file, Key(k), "missing (required)");
    used.push_back(k);
    return j.at(k);
  }
  double Number(const std::string& k, double lo, double hi, bool open_lo = false) {
    const json& v = Get(k);
    if (!v.is_number()) Fail(file, Key(k), "expected a number, got " + std::string(v.type_name()));
    const double x = v.get<double>();
    if (!std::isfinite(x) || x < lo || x > hi || (open_lo && x == lo))
      Fail(file, Key(k), "value " + v.dump() + " is outside " + (open_lo ? "(" : "[") + json(lo).dump() + ", " +
                             json(hi).dump() + "]");
    return x;
  }
  int Integer(const std::string& k, int lo, int hi) {
    const json& v = Get(k);
    if (!v.is_number_integer() || v.get<long long>() < lo || v.get<long long>() > hi)
      Fail(file, Key(k), "expected an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]");
    return v.get<int>();
  }
  std::string String(const std::string& k) {
    const json& v = Get(k);
    if (!v.is_string()) Fail(file, Key(k), "expected a string");
    return v.get<std::string>();
  }
  Eigen::Array3d Rgb(const std::string& k, double lo, double hi) {
    const json& v = Get(k);
    if (v.is_number()) return Eigen::Array3d::Constant(Number(k, lo, hi));
    if (!v.is_array() || v.size() != 3) Fail(file, Key(k), "expected a number or [r, g, b]");
    Eigen::Array3d a;
    for (int c = 0; c < 3; ++c) {
      if (!v[c].is_number() || !(v[c].get<double>() >= lo && v[c].get<double>() <= hi))
        Fail(file, Key(k) + "[" + std::to_string(c) + "]", "expected a number in [" + json(lo).dump() + ", " +
                                                               json(hi).dump() + "]");
      a[c] = v[c].get<double>();
    }
    return a;
  }
  void Finish() const {
    for (auto it = j.begin(); it != j.end(); ++it)
      if (std::find(used.begin(), used.end(), it.key()) == used.end()) Fail(file, Key(it.key()), "unknown key");
  }
};

// Camera frame: columns right, up, forward (forward from the pinhole to the
// sample centre).
Eigen::Matrix3d CameraFrame(const CameraRig& rig, Eigen::Vector3d& centre) {
  centre = rig.distance * DirectionFromAngles(rig.view_theta, rig.view_phi);
  const Eigen::Vector3d forward = -centre.normalized();
  Eigen::Vector3d right = forward.cross(Eigen::Vector3d::UnitZ());
  // Looking straight down the normal: any right vector will do; take e_x
  // rotated by the viewing azimuth so the image turns with phi.
  if (right.norm() < 1e-12) right = Eigen::Vector3d(std::sin(rig.view_phi), -std::cos(rig.view_phi), 0);
  right.normalize();
  Eigen::Matrix3d f;
  f.col(0) = right;
  f.col(1) = right.cross(forward);
  f.col(2) = forward;
  return f;
}

}  // namespace

CameraRig DefaultCameraRig() {
  CameraRig rig;
  rig.view_theta = 0;
  rig.light_theta = 30 * kDeg;
  rig.light_phi = 0;
  return rig;
}

CameraRig ParseCameraRig(const json& j, const std::string& file) {
  CameraRig rig;
  Fields top(j, "", file);
  {
    Fields c(top.Get("camera"), "camera", file);
    rig.focal_length = c.Number("focal_length_mm", 0, 1e4, true) * 1e-3;
    rig.f_number = c.Number("f_number", 0.5, 1000);
    rig.width = c.Integer("width", 1, 16384);
    rig.height = c.Integer("height", 1, 16384);
    rig.pixel_pitch = c.Number("pixel_pitch_um", 0, 1e5, true) * 1e-6;
    rig.distance = c.Number("distance", 0, 1e6, true);
    rig.view_theta = c.Number("view_theta_deg", 0, 89.9) * kDeg;
    rig.view_phi = c.Number("view_phi_deg", -360, 360) * kDeg;
    const json& e = c.Get("exposures");
    if (!e.is_array() || e.empty()) Fail(file, "camera.exposures", "expected a non-empty list of exposure times (s)");
    rig.exposures.clear();
    for (std::size_t k = 0; k < e.size(); ++k) {
      if (!e[k].is_number() || !(e[k].get<double>() > 0))
        Fail(file, "camera.exposures[" + std::to_string(k) + "]", "expected a positive exposure time (s)");
      rig.exposures.push_back(e[k].get<double>());
    }
    std::sort(rig.exposures.begin(), rig.exposures.end());
    rig.responsivity = c.Rgb("responsivity", 1e-300, 1e25);
    c.Finish();
  }
  {
    // The sensor block uses the gonioreflectometer's imperfection keys.
    json inst = InstrumentToJson(DefaultInstrument());
    inst["imperfections"] = top.Get("sensor");
    Imperfections m;
    try {
      m = ParseInstrument(inst, file).imperfections;
    } catch (const std::exception& ex) {
      std::string what = ex.what();
      const std::string from = file + ": imperfections";
      if (what.rfind(from, 0) == 0) what = file + ": sensor" + what.substr(from.size());
      throw std::runtime_error(what);
    }
    if (m.jitter_source > 0 || m.jitter_detector > 0 || m.drift_per_sample != 0)
      Fail(file, "sensor", "jitter and drift are gonioreflectometer settings, not sensor ones");
    if (m.saturation && !m.hdr_exposures.empty())
      Fail(file, "sensor.saturation.hdr_exposures", "give the brackets in camera.exposures");
    rig.sensor = m;
  }
  {
    Fields s(top.Get("sample"), "sample", file);
    const std::string shape = s.String("shape");
    if (shape == "flat") rig.shape = CameraRig::Shape::kFlat;
    else if (shape == "sphere") rig.shape = CameraRig::Shape::kSphere;
    else Fail(file, "sample.shape", "unknown shape '" + shape + "' (expected flat or sphere)");
    rig.size = s.Number(rig.shape == CameraRig::Shape::kFlat ? "side" : "radius", 0, 1e6, true);
    s.Finish();
  }
  {
    Fields l(top.Get("light"), "light", file);
    const std::string type = l.String("type");
    if (type == "distant") {
      rig.light = CameraRig::Light::kDistant;
      rig.light_theta = l.Number("theta_deg", 0, 180) * kDeg;
      rig.light_phi = l.Number("phi_deg", -360, 360) * kDeg;
      rig.irradiance = l.Rgb("irradiance", 0, 1e12);
    } else if (type == "point") {
      rig.light = CameraRig::Light::kPoint;
      const json& p = l.Get("position");
      if (!p.is_array() || p.size() != 3) Fail(file, "light.position", "expected [x, y, z] in m");
      for (int k = 0; k < 3; ++k) {
        if (!p[k].is_number()) Fail(file, "light.position[" + std::to_string(k) + "]", "expected a number");
        rig.light_position[k] = p[k].get<double>();
      }
      rig.intensity = l.Rgb("intensity", 0, 1e15);
    } else {
      Fail(file, "light.type", "unknown light '" + type + "' (expected distant or point)");
    }
    l.Finish();
  }
  top.Finish();
  if (rig.distance <= (rig.shape == CameraRig::Shape::kSphere ? rig.size : 0.0))
    Fail(file, "camera.distance", "the camera must be outside the sample");
  return rig;
}

CameraRig LoadCameraRig(const std::string& path) {
  // An ifstream opens a directory and fails only when read, with no file name.
  if (std::filesystem::is_directory(path)) throw std::runtime_error(path + ": is a directory, not a camera rig file");
  std::ifstream in(path);
  if (!in) throw std::runtime_error("cannot read camera rig file '" + path + "'");
  json j;
  try {
    j = json::parse(in);
  } catch (const json::exception& e) {  // parse errors, and out_of_range for numbers beyond a double
    throw std::runtime_error(path + ": not valid JSON: " + e.what());
  }
  return ParseCameraRig(j, path);
}

json CameraRigToJson(const CameraRig& rig) {
  json j;
  j["camera"] = {{"focal_length_mm", rig.focal_length * 1e3}, {"f_number", rig.f_number},
                 {"width", rig.width},                         {"height", rig.height},
                 {"pixel_pitch_um", rig.pixel_pitch * 1e6},    {"distance", rig.distance},
                 {"view_theta_deg", rig.view_theta / kDeg},    {"view_phi_deg", rig.view_phi / kDeg},
                 {"exposures", rig.exposures},                 {"responsivity", RgbJson(rig.responsivity)}};
  Instrument tmp;
  tmp.imperfections = rig.sensor;
  j["sensor"] = InstrumentToJson(tmp)["imperfections"];
  if (rig.shape == CameraRig::Shape::kFlat) j["sample"] = {{"shape", "flat"}, {"side", rig.size}};
  else j["sample"] = {{"shape", "sphere"}, {"radius", rig.size}};
  if (rig.light == CameraRig::Light::kDistant)
    j["light"] = {{"type", "distant"},
                  {"theta_deg", rig.light_theta / kDeg},
                  {"phi_deg", rig.light_phi / kDeg},
                  {"irradiance", RgbJson(rig.irradiance)}};
  else
    j["light"] = {{"type", "point"},
                  {"position", {rig.light_position.x(), rig.light_position.y(), rig.light_position.z()}},
                  {"intensity", RgbJson(rig.intensity)}};
  return j;
}

PixelGeometry CameraPixel(const CameraRig& rig, int x, int y) {
  PixelGeometry g;
  Eigen::Vector3d centre;
  const Eigen::Matrix3d frame = CameraFrame(rig, centre);
  const double xs = (x + 0.5 - 0.5 * rig.width) * rig.pixel_pitch;
  const double ys = (0.5 * rig.height - y - 0.5) * rig.pixel_pitch;
  const Eigen::Vector3d local(xs, ys, rig.focal_length);
  const double cos_p = rig.focal_length / local.norm();
  g.cos4 = cos_p * cos_p * cos_p * cos_p;
  const Eigen::Vector3d d = frame * local.normalized();
  Eigen::Vector3d point, normal;
  if (rig.shape == CameraRig::Shape::kFlat) {
    if (!(d.z() < 0)) return g;  // ray parallel to or away from the plane
    const double t = -centre.z() / d.z();
    point = centre + t * d;
    if (std::abs(point.x()) > rig.size / 2 || std::abs(point.y()) > rig.size / 2) return g;
    normal = Eigen::Vector3d::UnitZ();
  } else {
    const double b = centre.dot(d), c = centre.squaredNorm() - rig.size * rig.size;
    const double disc = b * b - c;
    if (!(disc > 0)) return g;  // misses the sphere (or grazes it)
    point = centre + (-b - std::sqrt(disc)) * d;
    normal = point.normalized();
  }
  Eigen::Vector3d to_light;
  if (rig.light == CameraRig::Light::kDistant) {
    to_light = DirectionFromAngles(rig.light_theta, rig.light_phi);
    g.e_perp = rig.irradiance;
  } else {
    const Eigen::Vector3d v = rig.light_position - point;
    to_light = v.normalized();
    g.e_perp = rig.intensity / v.squaredNorm();
  }
  // Local shading frame: z the normal, tangents from BasisFromZ (for the
  // flat sample that is the world frame, whose normal is e_z).
  Eigen::Vector3d t1 = Eigen::Vector3d::UnitX(), t2 = Eigen::Vector3d::UnitY();
  if (rig.shape == CameraRig::Shape::kSphere) BasisFromZ(normal, t1, t2);
  const Eigen::Vector3d wo_world = (centre - point).normalized();
  g.wi = Eigen::Vector3d(t1.dot(to_light), t2.dot(to_light), normal.dot(to_light));
  g.wo = Eigen::Vector3d(t1.dot(wo_world), t2.dot(wo_world), normal.dot(wo_world));
  g.hit = g.wi.z() > 0 && g.wo.z() > 0;
  return g;
}

namespace {

// Electron rate per unit radiance at a pixel: responsivity times pixel area
// times the pinhole factor (pi / 4) cos^4 / N^2.
double RatePerRadiance(const CameraRig& rig, int c, double cos4) {
  return rig.responsivity[c] * rig.pixel_pitch * rig.pixel_pitch * (kPi / 4) * cos4 / (rig.f_number * rig.f_number);
}

}  // namespace

CameraCapture RenderCamera(const CameraRig& rig, const Model& model, const std::vector<double>& params,
                           std::uint64_t seed) {
  ValidateParams(model.Info(), params);
  const auto bxdf = model.Make<double>();
  const std::size_t npix = std::size_t(rig.width) * std::size_t(rig.height);
  const SensorModel sensor(rig.sensor, rig.exposures.front());
  CameraCapture cap;
  cap.raw.assign(rig.exposures.size(), std::vector<float>(3 * npix, 0.f));
  tbb::parallel_for(tbb::blocked_range<int>(0, rig.height), [&](const auto& rows) {
    std::vector<PixelGeometry> row(static_cast<std::size_t>(rig.width));
    std::vector<double> wi, wo, f;
    std::vector<int> hit;
    for (int y = rows.begin(); y < rows.end(); ++y) {
      // The row's lit pixels in one EvalBatch call.
      wi.clear();
      wo.clear();
      hit.clear();
      for (int x = 0; x < rig.width; ++x) {
        const PixelGeometry& g = row[std::size_t(x)] = CameraPixel(rig, x, y);
        if (!g.hit) continue;
        wi.insert(wi.end(), {g.wi.x(), g.wi.y(), g.wi.z()});
        wo.insert(wo.end(), {g.wo.x(), g.wo.y(), g.wo.z()});
        hit.push_back(x);
      }
      f.assign(3 * hit.size(), 0.0);
      if (!hit.empty()) bxdf->EvalBatch(params.data(), wi.data(), 3, wo.data(), 3, hit.size(), f.data());
      std::size_t next = 0;
      for (int x = 0; x < rig.width; ++x) {
        const PixelGeometry& g = row[std::size_t(x)];
        Rgb<double> radiance = Rgb<double>::Zero();
        if (next < hit.size() && hit[next] == x) {
          radiance = Rgb<double>(f[3 * next], f[3 * next + 1], f[3 * next + 2]) * g.e_perp * g.wi.z();
          ++next;
        }
        const std::size_t p = std::size_t(y) * rig.width + x;
        SampleRng rng(seed, p);
        for (int c = 0; c < 3; ++c) {
          const double rate = RatePerRadiance(rig, c, g.cos4) * radiance[c];
          for (std::size_t k = 0; k < rig.exposures.size(); ++k)
            cap.raw[k][c * npix + p] = static_cast<float>(sensor.Raw(rate, rig.exposures[k], rng));
        }
      }
    }
  });
  return cap;
}

std::vector<std::string> WriteCameraCapture(const std::string& prefix, const CameraRig& rig, const CameraCapture& cap,
                                            const std::string& model_spec, const std::vector<double>& params,
                                            std::uint64_t seed) {
  const std::size_t npix = std::size_t(rig.width) * std::size_t(rig.height);
  std::vector<std::string> files;
  for (std::size_t k = 0; k < cap.raw.size(); ++k) {
    const std::string path = prefix + "_e" + std::to_string(k) + ".exr";
    const float* base = cap.raw[k].data();
    WriteExrFloat(path, rig.width, rig.height, {{"R", base}, {"G", base + npix}, {"B", base + 2 * npix}},
                  {{"brdfkit.exposure_time", json(rig.exposures[k]).dump()},
                   {"brdfkit.units", rig.sensor.adc ? "DN" : "electrons"}});
    files.push_back(path);
  }
  json side = {{"brdfkit_version", BRDFKIT_VERSION},
               {"model", model_spec},
               {"params", params},
               {"seed", seed},
               {"camera_rig", CameraRigToJson(rig)},
               {"images", files}};
  WriteFileAtomic(prefix + ".json", side.dump(2) + "\n");
  return files;
}

BrdfTable ReduceCamera(const CameraRig& rig, const std::vector<std::string>& raw_files) {
  if (raw_files.size() != rig.exposures.size())
    throw std::runtime_error("camera reduction: " + std::to_string(raw_files.size()) + " raw images for " +
                             std::to_string(rig.exposures.size()) + " exposures");
  const Imperfections& m = rig.sensor;
  const SensorModel sensor(m, rig.exposures.front());
  const int w = rig.width, h = rig.height;
  static const char* kChannel[3] = {"R", "G", "B"};

  // Geometry maps: cos^4 falloff, E_perp cos(theta_i), and the hit mask.
  cv::Mat cos4(h, w, CV_64F), mask(h, w, CV_8U, cv::Scalar(0));
  std::vector<cv::Mat> illum(3, cv::Mat(h, w, CV_64F, cv::Scalar(0)));
  for (int c = 0; c < 3; ++c) illum[c] = cv::Mat(h, w, CV_64F, cv::Scalar(0));
  std::vector<PixelGeometry> geom(std::size_t(w) * h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const PixelGeometry g = CameraPixel(rig, x, y);
      geom[std::size_t(y) * w + x] = g;
      cos4.at<double>(y, x) = g.cos4;
      if (!g.hit) continue;
      mask.at<unsigned char>(y, x) = 255;
      for (int c = 0; c < 3; ++c) illum[c].at<double>(y, x) = g.e_perp[c] * g.wi.z();
    }

  // Per channel: merge unsaturated exposures into an electron rate.
  std::vector<cv::Mat> rate(3), variance(3);
  cv::Mat saturated_all(h, w, CV_8U, cv::Scalar(0));
  for (int c = 0; c < 3; ++c) {
    cv::Mat sum_charge(h, w, CV_64F, cv::Scalar(0)), sum_t(h, w, CV_64F, cv::Scalar(0)),
        none_used(h, w, CV_8U, cv::Scalar(255));
    std::vector<cv::Mat> charge(rig.exposures.size()), used(rig.exposures.size());
    for (std::size_t k = 0; k < rig.exposures.size(); ++k) {
      const ExrImage img = ReadExrFloat(raw_files[k]);
      if (img.width != w || img.height != h)
        throw std::runtime_error("camera reduction: '" + raw_files[k] + "' is " + std::to_string(img.width) + "x" +
                                 std::to_string(img.height) + ", the rig says " + std::to_string(w) + "x" +
                                 std::to_string(h));
      const auto it = img.channels.find(kChannel[c]);
      if (it == img.channels.end())
        throw std::runtime_error("camera reduction: '" + raw_files[k] + "' has no channel " + kChannel[c]);
      cv::Mat raw;
      cv::Mat(h, w, CV_32F, const_cast<float*>(it->second.data())).convertTo(raw, CV_64F);
      // Saturated readings (noise.h's rule): at the ADC maximum or near the well.
      cv::Mat sat(h, w, CV_8U, cv::Scalar(0));
      if (m.adc) sat |= raw >= sensor.DnMax();
      const double gain = m.adc ? m.adc_gain : 1.0;
      const cv::Mat raw_charge = raw * gain;
      if (m.saturation) sat |= raw_charge >= m.full_well - 4 * m.read_noise;
      charge[k] = raw_charge - m.dark_current * rig.exposures[k];
      cv::bitwise_not(sat, used[k]);
      cv::add(sum_charge, charge[k], sum_charge, used[k]);
      cv::add(sum_t, cv::Scalar(rig.exposures[k]), sum_t, used[k]);
      none_used &= sat;
    }
    // Every exposure saturated: the shortest one gives a lower bound.
    charge[0].copyTo(sum_charge, none_used);
    sum_t.setTo(cv::Scalar(rig.exposures[0]), none_used);
    saturated_all |= none_used;
    cv::divide(sum_charge, sum_t, rate[c]);
    // Model variance of the merged rate, evaluated at the estimate.
    cv::Mat var(h, w, CV_64F, cv::Scalar(0));
    cv::Mat positive_rate = cv::max(rate[c], 0.0);
    for (std::size_t k = 0; k < rig.exposures.size(); ++k) {
      const double t = rig.exposures[k];
      cv::Mat vk(h, w, CV_64F, cv::Scalar(m.read_noise * m.read_noise + (m.adc ? m.adc_gain * m.adc_gain / 12.0 : 0.0)));
      if (m.shot_noise) vk += (positive_rate + m.dark_current) * t;
      cv::Mat use = used[k].clone();
      if (k == 0) use |= none_used;
      cv::add(var, vk, var, use);
    }
    cv::divide(var, sum_t.mul(sum_t), variance[c]);
  }

  // Radiance: divide by the cos^4 falloff, f-number, pixel area and
  // responsivity; f_r = L / (E_perp cos(theta_i)).
  std::vector<cv::Mat> f(3), sigma(3);
  for (int c = 0; c < 3; ++c) {
    cv::Mat k = cos4 * (rig.responsivity[c] * rig.pixel_pitch * rig.pixel_pitch * (kPi / 4) /
                        (rig.f_number * rig.f_number));
    cv::Mat denom = k.mul(illum[c]);
    denom.setTo(cv::Scalar(1), ~mask);  // not a sample pixel: any non-zero value, never reported
    cv::divide(rate[c], denom, f[c]);
    cv::Mat sd;
    cv::sqrt(variance[c], sd);
    cv::divide(sd, denom, sigma[c]);
  }

  BrdfTable table;
  table.has_sigma = m.AnyNoise();
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const PixelGeometry& g = geom[std::size_t(y) * w + x];
      if (!g.hit) continue;
      BrdfSample s;
      s.theta_i = std::atan2(std::hypot(g.wi.x(), g.wi.y()), g.wi.z());
      s.phi_i = std::atan2(g.wi.y(), g.wi.x());
      s.theta_o = std::atan2(std::hypot(g.wo.x(), g.wo.y()), g.wo.z());
      s.phi_o = std::atan2(g.wo.y(), g.wo.x());
      for (int c = 0; c < 3; ++c) {
        s.f[c] = f[c].at<double>(y, x);
        s.sigma[c] = sigma[c].at<double>(y, x);
      }
      table.rows.push_back(s);
    }
  return table;
}

}  // namespace brdfkit::synth
