#include "data_synth/instrument.h"

#include <cmath>
#include <filesystem>
#include <fstream>
#include <set>
#include <stdexcept>
#include <utility>

#include "brdf/core.h"

namespace brdfkit::synth {

namespace {

using nlohmann::json;

// A JSON object being read: every key must be consumed, so a typo is an
// error rather than a silently ignored setting.
class ObjectReader {
 public:
  ObjectReader(const json& j, std::string path, const std::string& file) : j_(j), path_(std::move(path)), file_(file) {
    if (!j_.is_object()) Fail(path_.empty() ? "expected a JSON object" : "expected an object");
  }

  [[noreturn]] void Fail(const std::string& what) const { FailAt(path_, what); }
  [[noreturn]] void FailAt(const std::string& key_path, const std::string& what) const {
    throw std::runtime_error(file_ + ": " + (key_path.empty() ? "" : key_path + ": ") + what);
  }
  std::string Path(const std::string& key) const { return path_.empty() ? key : path_ + "." + key; }

  bool Has(const std::string& key) const { return j_.contains(key); }

  const json& Get(const std::string& key) {
    if (!j_.contains(key)) FailAt(Path(key), "missing (required)");
    used_.insert(key);
    return j_.at(key);
  }

  double Number(const std::string& key, double lower, double upper, bool open_lower = false) {
    const json& v = Get(key);
    if (!v.is_number()) FailAt(Path(key), "expected a number, got " + std::string(v.type_name()));
    const double x = v.get<double>();
    if (!std::isfinite(x) || x < lower || x > upper || (open_lower && x == lower))
      FailAt(Path(key), "value " + v.dump() + " is outside " + (open_lower ? "(" : "[") + Fmt(lower) + ", " +
                            Fmt(upper) + "]");
    return x;
  }

  bool Bool(const std::string& key) {
    const json& v = Get(key);
    if (!v.is_boolean()) FailAt(Path(key), "expected true or false, got " + std::string(v.type_name()));
    return v.get<bool>();
  }

  std::string String(const std::string& key) {
    const json& v = Get(key);
    if (!v.is_string()) FailAt(Path(key), "expected a string, got " + std::string(v.type_name()));
    return v.get<std::string>();
  }

  std::int64_t Integer(const std::string& key, std::int64_t lower, std::int64_t upper) {
    const json& v = Get(key);
    if (!v.is_number_integer()) FailAt(Path(key), "expected an integer, got " + v.dump());
    const std::int64_t x = v.get<std::int64_t>();
    if (x < lower || x > upper)
      FailAt(Path(key), "value " + v.dump() + " is outside [" + std::to_string(lower) + ", " + std::to_string(upper) + "]");
    return x;
  }

  Eigen::Array3d Rgb(const std::string& key, double lower, double upper) {
    const json& v = Get(key);
    if (v.is_number()) {
      const double x = Number(key, lower, upper);
      return Eigen::Array3d::Constant(x);
    }
    if (!v.is_array() || v.size() != 3) FailAt(Path(key), "expected a number or [r, g, b]");
    Eigen::Array3d out;
    for (int c = 0; c < 3; ++c) {
      if (!v[c].is_number()) FailAt(Path(key) + "[" + std::to_string(c) + "]", "expected a number");
      out[c] = v[c].get<double>();
      if (!std::isfinite(out[c]) || out[c] < lower || out[c] > upper)
        FailAt(Path(key) + "[" + std::to_string(c) + "]",
               "value " + v[c].dump() + " is outside [" + Fmt(lower) + ", " + Fmt(upper) + "]");
    }
    return out;
  }

  // Angles in degrees: a list [a, b, ...] or {"start": a, "stop": b, "count": n}
  // (inclusive, evenly spaced). Returned in radians.
  std::vector<double> AngleList(const std::string& key, double lower_deg, double upper_deg) {
    const json& v = Get(key);
    std::vector<double> out;
    auto check = [&](double x, const std::string& p) {
      if (!std::isfinite(x) || x < lower_deg || x > upper_deg)
        FailAt(p, "angle " + Fmt(x) + " degrees is outside [" + Fmt(lower_deg) + ", " + Fmt(upper_deg) + "]");
    };
    if (v.is_array()) {
      if (v.empty()) FailAt(Path(key), "empty list of angles");
      for (std::size_t k = 0; k < v.size(); ++k) {
        const std::string p = Path(key) + "[" + std::to_string(k) + "]";
        if (!v[k].is_number()) FailAt(p, "expected a number (degrees)");
        const double x = v[k].get<double>();
        check(x, p);
        out.push_back(x * kDeg);
      }
      return out;
    }
    if (!v.is_object()) FailAt(Path(key), "expected a list of degrees or {\"start\", \"stop\", \"count\"}");
    ObjectReader r(v, Path(key), file_);
    const double a = r.Number("start", lower_deg, upper_deg);
    const double b = r.Number("stop", lower_deg, upper_deg);
    const std::int64_t n = r.Integer("count", 1, 100000);
    r.Finish();
    for (std::int64_t k = 0; k < n; ++k) out.push_back((n == 1 ? a : a + (b - a) * double(k) / double(n - 1)) * kDeg);
    return out;
  }

  void Finish() const {
    for (auto it = j_.begin(); it != j_.end(); ++it)
      if (!used_.count(it.key())) FailAt(Path(it.key()), "unknown key");
  }

 private:
  static std::string Fmt(double x) {
    std::string s = json(x).dump();
    return s;
  }
  const json& j_;
  std::string path_;
  const std::string& file_;
  std::set<std::string> used_;
};

json GridJson(const std::vector<double>& v) {
  json a = json::array();
  for (double x : v) a.push_back(x / kDeg);
  return a;
}

}  // namespace

json RgbJson(const Eigen::Array3d& rgb) { return json::array({rgb[0], rgb[1], rgb[2]}); }

Eigen::Array3d Source::BeamIrradiance() const {
  if (kind == Kind::kCollimated) return irradiance;
  const double s = std::sin(angular_radius);
  return radiance * (kPi * s * s);
}

Eigen::Matrix3d SampleMount::SampleFromLab() const {
  const Eigen::Matrix3d r =
      (Eigen::AngleAxisd(tilt_y, Eigen::Vector3d::UnitY()) * Eigen::AngleAxisd(tilt_x, Eigen::Vector3d::UnitX()))
          .toRotationMatrix();
  return r.transpose();
}

Eigen::Vector3d DirectionFromAngles(double theta, double phi) {
  const double s = std::sin(theta);
  return Eigen::Vector3d(s * std::cos(phi), s * std::sin(phi), std::cos(theta));
}

Instrument DefaultInstrument() {
  Instrument inst;
  inst.source.kind = Source::Kind::kCollimated;
  inst.source.irradiance = Eigen::Array3d::Constant(10.0);
  inst.detector.angular_radius = 1.0 * kDeg;
  // Silicon photodiode near 550 nm: QE 0.5 times lambda / (h c) = 2.77e18 photons/J.
  inst.detector.responsivity = Eigen::Array3d::Constant(1.4e18);
  inst.detector.exposure_time = 1e-3;
  inst.sample.area = 1e-4;
  inst.plan.kind = SamplingPlan::Kind::kInPlane;
  for (int t = 0; t <= 75; t += 15) inst.plan.theta_i.push_back(t * kDeg);
  for (int t = -85; t <= 85; t += 5) inst.plan.theta_o.push_back(t * kDeg);
  return inst;
}

Instrument ParseInstrument(const json& j, const std::string& file, const std::string& base_dir) {
  Instrument inst;
  ObjectReader top(j, "", file);

  {
    ObjectReader r(top.Get("source"), "source", file);
    const std::string type = r.String("type");
    if (type == "collimated") {
      inst.source.kind = Source::Kind::kCollimated;
      inst.source.irradiance = r.Rgb("irradiance", 0, 1e12);
    } else if (type == "disc") {
      inst.source.kind = Source::Kind::kDisc;
      inst.source.angular_radius = r.Number("angular_radius_deg", 0, 45, true) * kDeg;
      inst.source.radiance = r.Rgb("radiance", 0, 1e15);
    } else {
      r.FailAt("source.type", "unknown source type '" + type + "' (expected collimated or disc)");
    }
    r.Finish();
  }
  {
    ObjectReader r(top.Get("detector"), "detector", file);
    inst.detector.angular_radius = r.Number("angular_radius_deg", 0, 45) * kDeg;
    inst.detector.responsivity = r.Rgb("responsivity", 0, 1e25);
    inst.detector.exposure_time = r.Number("exposure_time", 0, 1e6, true);
    r.Finish();
  }
  {
    ObjectReader r(top.Get("sample"), "sample", file);
    inst.sample.area = r.Number("area", 0, 1e6, true);
    inst.sample.tilt_x = r.Number("tilt_x_deg", -45, 45) * kDeg;
    inst.sample.tilt_y = r.Number("tilt_y_deg", -45, 45) * kDeg;
    r.Finish();
  }
  {
    ObjectReader r(top.Get("plan"), "plan", file);
    SamplingPlan& p = inst.plan;
    const std::string type = r.String("type");
    if (type == "full") {
      p.kind = SamplingPlan::Kind::kFull;
      p.theta_i = r.AngleList("theta_i_deg", 0, 90);
      p.phi_i = r.AngleList("phi_i_deg", -360, 360);
      p.theta_o = r.AngleList("theta_o_deg", 0, 90);
      p.phi_o = r.AngleList("phi_o_deg", -360, 360);
    } else if (type == "in_plane") {
      p.kind = SamplingPlan::Kind::kInPlane;
      p.theta_i = r.AngleList("theta_i_deg", 0, 90);
      p.theta_o = r.AngleList("theta_o_deg", -90, 90);
    } else if (type == "merl") {
      p.kind = SamplingPlan::Kind::kMerl;
      const json& s = r.Get("stride");
      if (!s.is_array() || s.size() != 3) r.FailAt("plan.stride", "expected [theta_h, theta_d, phi_d] strides");
      for (int k = 0; k < 3; ++k) {
        if (!s[k].is_number_integer() || s[k].get<int>() < 1)
          r.FailAt("plan.stride[" + std::to_string(k) + "]", "expected a positive integer");
        p.merl_stride[k] = s[k].get<int>();
      }
    } else if (type == "list") {
      p.kind = SamplingPlan::Kind::kList;
      const std::string f = r.String("file");
      const std::filesystem::path fp(f);
      p.list_file = fp.is_absolute() || base_dir.empty() ? f : (std::filesystem::path(base_dir) / fp).string();
      const std::string units = r.String("units");
      if (units != "rad" && units != "deg") r.FailAt("plan.units", "expected \"rad\" or \"deg\", got '" + units + "'");
      p.list_degrees = units == "deg";
    } else if (type == "random") {
      p.kind = SamplingPlan::Kind::kRandom;
      p.random_count = static_cast<std::size_t>(r.Integer("count", 1, 100000000));
      p.random_seed = static_cast<std::uint64_t>(r.Integer("seed", 0, std::numeric_limits<std::int64_t>::max()));
    } else {
      r.FailAt("plan.type", "unknown plan type '" + type + "' (expected full, in_plane, merl, list or random)");
    }
    r.Finish();
  }
  if (top.Has("quadrature")) {
    ObjectReader r(top.Get("quadrature"), "quadrature", file);
    const json& o = r.Get("order");
    if (o.is_string() && o.get<std::string>() == "auto") {
      inst.quadrature.order = 0;
    } else {
      inst.quadrature.order = static_cast<int>(r.Integer("order", 1, 32));
    }
    inst.quadrature.tolerance = r.Number("tolerance", 0, 1, true);
    inst.quadrature.max_order = static_cast<int>(r.Integer("max_order", 1, 32));
    r.Finish();
  }
  if (top.Has("imperfections")) {
    ObjectReader r(top.Get("imperfections"), "imperfections", file);
    Imperfections& m = inst.imperfections;
    if (r.Has("jitter")) {
      ObjectReader q(r.Get("jitter"), "imperfections.jitter", file);
      m.jitter_source = q.Number("source_deg", 0, 10) * kDeg;
      m.jitter_detector = q.Number("detector_deg", 0, 10) * kDeg;
      q.Finish();
    }
    if (r.Has("shot_noise")) m.shot_noise = r.Bool("shot_noise");
    if (r.Has("read_noise")) {
      ObjectReader q(r.Get("read_noise"), "imperfections.read_noise", file);
      m.read_noise = q.Number("electrons", 0, 1e12);
      q.Finish();
    }
    if (r.Has("dark")) {
      ObjectReader q(r.Get("dark"), "imperfections.dark", file);
      m.dark_current = q.Number("electrons_per_second", 0, 1e15);
      q.Finish();
    }
    if (r.Has("adc")) {
      ObjectReader q(r.Get("adc"), "imperfections.adc", file);
      m.adc = true;
      m.adc_bits = static_cast<int>(q.Integer("bits", 1, 32));
      m.adc_gain = q.Number("gain", 0, 1e15, true);
      q.Finish();
    }
    if (r.Has("saturation")) {
      ObjectReader q(r.Get("saturation"), "imperfections.saturation", file);
      m.saturation = true;
      m.full_well = q.Number("full_well", 0, 1e18, true);
      const json& e = q.Get("hdr_exposures");
      if (!e.is_array()) q.FailAt("imperfections.saturation.hdr_exposures", "expected a list of exposure times (s)");
      for (std::size_t k = 0; k < e.size(); ++k) {
        if (!e[k].is_number() || !(e[k].get<double>() > 0))
          q.FailAt("imperfections.saturation.hdr_exposures[" + std::to_string(k) + "]",
                   "expected a positive exposure time (s)");
        m.hdr_exposures.push_back(e[k].get<double>());
      }
      q.Finish();
    }
    if (r.Has("drift")) {
      ObjectReader q(r.Get("drift"), "imperfections.drift", file);
      m.drift_per_sample = q.Number("relative_per_sample", -1e-2, 1e-2);
      q.Finish();
    }
    r.Finish();
    if (m.AnyNoise() && inst.detector.angular_radius == 0)
      r.FailAt("detector.angular_radius_deg",
               "a point detector (radius 0) collects no photons; sensor noise needs a finite aperture");
    if (m.AnyNoise() && !((inst.detector.responsivity * inst.source.RadianceScale()).minCoeff() > 0))
      r.FailAt("detector.responsivity",
               "sensor noise needs a positive responsivity and source output in every channel");
  }
  top.Finish();
  return inst;
}

Instrument LoadInstrument(const std::string& path) {
  // An ifstream opens a directory and fails only when read, with no file name.
  if (std::filesystem::is_directory(path)) throw std::runtime_error(path + ": is a directory, not an instrument file");
  std::ifstream in(path);
  if (!in) throw std::runtime_error("cannot read instrument file '" + path + "'");
  json j;
  try {
    j = json::parse(in);
  } catch (const json::exception& e) {  // parse errors, and out_of_range for numbers beyond a double
    throw std::runtime_error(path + ": not valid JSON: " + e.what());
  }
  // A synthetic measurement's sidecar holds the instrument it was made with.
  if (j.is_object() && j.contains("brdfkit_version") && j.contains("instrument"))
    return ParseInstrument(j["instrument"], path + ": instrument", std::filesystem::path(path).parent_path().string());
  return ParseInstrument(j, path, std::filesystem::path(path).parent_path().string());
}

json InstrumentToJson(const Instrument& inst) {
  json j;
  if (inst.source.kind == Source::Kind::kCollimated) {
    j["source"] = {{"type", "collimated"}, {"irradiance", RgbJson(inst.source.irradiance)}};
  } else {
    j["source"] = {{"type", "disc"},
                   {"angular_radius_deg", inst.source.angular_radius / kDeg},
                   {"radiance", RgbJson(inst.source.radiance)}};
  }
  j["detector"] = {{"angular_radius_deg", inst.detector.angular_radius / kDeg},
                   {"responsivity", RgbJson(inst.detector.responsivity)},
                   {"exposure_time", inst.detector.exposure_time}};
  j["sample"] = {{"area", inst.sample.area},
                 {"tilt_x_deg", inst.sample.tilt_x / kDeg},
                 {"tilt_y_deg", inst.sample.tilt_y / kDeg}};
  const SamplingPlan& p = inst.plan;
  switch (p.kind) {
    case SamplingPlan::Kind::kFull:
      j["plan"] = {{"type", "full"},
                   {"theta_i_deg", GridJson(p.theta_i)},
                   {"phi_i_deg", GridJson(p.phi_i)},
                   {"theta_o_deg", GridJson(p.theta_o)},
                   {"phi_o_deg", GridJson(p.phi_o)}};
      break;
    case SamplingPlan::Kind::kInPlane:
      j["plan"] = {{"type", "in_plane"}, {"theta_i_deg", GridJson(p.theta_i)}, {"theta_o_deg", GridJson(p.theta_o)}};
      break;
    case SamplingPlan::Kind::kMerl:
      j["plan"] = {{"type", "merl"}, {"stride", {p.merl_stride[0], p.merl_stride[1], p.merl_stride[2]}}};
      break;
    case SamplingPlan::Kind::kList:
      j["plan"] = {{"type", "list"}, {"file", p.list_file}, {"units", p.list_degrees ? "deg" : "rad"}};
      break;
    case SamplingPlan::Kind::kRandom:
      j["plan"] = {{"type", "random"}, {"count", p.random_count}, {"seed", p.random_seed}};
      break;
  }
  j["quadrature"] = {{"order", inst.quadrature.order == 0 ? json("auto") : json(inst.quadrature.order)},
                     {"tolerance", inst.quadrature.tolerance},
                     {"max_order", inst.quadrature.max_order}};
  const Imperfections& m = inst.imperfections;
  json im = json::object();
  if (m.jitter_source > 0 || m.jitter_detector > 0)
    im["jitter"] = {{"source_deg", m.jitter_source / kDeg}, {"detector_deg", m.jitter_detector / kDeg}};
  if (m.shot_noise) im["shot_noise"] = true;
  if (m.read_noise > 0) im["read_noise"] = {{"electrons", m.read_noise}};
  if (m.dark_current > 0) im["dark"] = {{"electrons_per_second", m.dark_current}};
  if (m.adc) im["adc"] = {{"bits", m.adc_bits}, {"gain", m.adc_gain}};
  if (m.saturation) im["saturation"] = {{"full_well", m.full_well}, {"hdr_exposures", m.hdr_exposures}};
  if (m.drift_per_sample != 0) im["drift"] = {{"relative_per_sample", m.drift_per_sample}};
  j["imperfections"] = im;
  return j;
}

}  // namespace brdfkit::synth
