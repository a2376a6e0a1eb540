// ASTM E1392 BRDF tables (ASTM E1392-96, "Standard Practice for Angle
// Resolved Optical Scatter Measurements on Specular or Diffuse Surfaces"; the
// text layout gonioreflectometers write and libbsdf and ALTA read): a reader,
// an atomic writer, a nearest / interpolated lookup over scattered samples,
// and the model [astm].
//
// Layout: keyword lines ("SOURCE ...", "NUM_POINTS n", ...), a VARS line
// naming the comma-separated columns, then one sample per line, the values
// separated by commas. The first four columns are theta_i, phi_i, theta_s,
// phi_s in radians; then R,G,B, a single value column (grey), or wavelength
// columns (names ending in nm, reduced to linear sRGB by brdf/cie.h).
// brdfkit reads the values as f_r in 1/sr (no cosine), with the incident
// direction (theta_i, phi_i) and the scattered direction (theta_s, phi_s)
// both pointing away from the surface in one frame (the mirror direction of
// (theta, 0) is (theta, pi)). Lines starting with '#' are comments.
#pragma once

#include "brdf/atomic_file.h"
#include "brdf/cie.h"
#include "brdf/core.h"
#include "brdf/params.h"

#include <algorithm>
#include <array>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace brdfkit {

struct AngleSample {
  double theta_i = 0, phi_i = 0, theta_o = 0, phi_o = 0;
  Rgb<double> f = Rgb<double>::Zero();
};

inline Eigen::Vector3d SphericalDirection(double theta, double phi) {
  return {std::sin(theta) * std::cos(phi), std::sin(theta) * std::sin(phi), std::cos(theta)};
}

class AstmTable {
 public:
  std::vector<std::pair<std::string, std::string>> keywords;  // in file order, NUM_POINTS and VARS excluded
  std::vector<AngleSample> rows;

  // Throws std::runtime_error naming the file and the line.
  static AstmTable Read(const std::string& path) {
    namespace fs = std::filesystem;
    const std::string what = "ASTM file '" + path + "'";
    std::error_code ec;
    const fs::file_status st = fs::status(path, ec);
    if (!fs::exists(st)) throw std::runtime_error("cannot read " + what + ": no such file");
    if (fs::is_directory(st)) throw std::runtime_error("cannot read " + what + ": it is a directory");
    std::ifstream in(path, std::ios::binary);
    if (!in) throw std::runtime_error("cannot open " + what);
    std::stringstream ss;
    ss << in.rdbuf();
    return Parse(ss.str(), what);
  }

  static AstmTable Parse(const std::string& text, const std::string& what) {
    AstmTable t;
    long long num_points = -1;
    std::size_t num_points_line = 0;
    std::vector<std::string> vars;
    enum class Values { kRgb, kGrey, kSpectral } kind = Values::kGrey;
    std::vector<std::array<double, 3>> spectral_weights;
    std::size_t line_no = 0, pos = 0;
    auto fail = [&](const std::string& msg) {
      throw std::runtime_error(what + " line " + std::to_string(line_no) + ": " + msg);
    };
    while (pos < text.size()) {
      std::size_t end = text.find('\n', pos);
      if (end == std::string::npos) end = text.size();
      std::string line = Trim(text.substr(pos, end - pos));
      pos = end + 1;
      ++line_no;
      if (line.empty() || line[0] == '#') continue;
      const char c0 = line[0];
      if (std::isdigit(static_cast<unsigned char>(c0)) || c0 == '-' || c0 == '+' || c0 == '.') {
        if (vars.empty()) fail("a data row before the VARS line");
        const std::vector<std::string> cells = Split(line, ',');
        if (cells.size() != vars.size())
          fail((cells.size() < vars.size() ? "short row: " : "long row: ") + std::to_string(cells.size()) +
               " values, the VARS line names " + std::to_string(vars.size()));
        std::vector<double> v(cells.size());
        for (std::size_t k = 0; k < cells.size(); ++k) {
          if (!ParseDouble(cells[k], v[k])) fail("column '" + vars[k] + "': '" + cells[k] + "' is not a number");
          if (!std::isfinite(v[k])) fail("column '" + vars[k] + "' is not finite");
        }
        for (int k : {0, 2})
          if (v[k] < -1e-9 || v[k] > kPi / 2 + 1e-9)
            fail("column '" + vars[k] + "' = " + cells[k] + " is outside [0, pi/2] (angles are radians)");
        AngleSample s{std::clamp(v[0], 0.0, kPi / 2), v[1], std::clamp(v[2], 0.0, kPi / 2), v[3], Rgb<double>::Zero()};
        if (kind == Values::kRgb) {
          s.f = Rgb<double>(v[4], v[5], v[6]);
        } else if (kind == Values::kGrey) {
          s.f = Rgb<double>::Constant(v[4]);
        } else {
          for (std::size_t l = 0; l < spectral_weights.size(); ++l)
            for (int c = 0; c < 3; ++c) s.f[c] += spectral_weights[l][c] * v[4 + l];
        }
        t.rows.push_back(s);
        continue;
      }
      std::size_t split = 0;
      while (split < line.size() && !std::isspace(static_cast<unsigned char>(line[split])) && line[split] != ',') ++split;
      std::string key = line.substr(0, split);
      for (char& ch : key) ch = static_cast<char>(std::toupper(static_cast<unsigned char>(ch)));
      std::string rest = Trim(line.substr(split));
      if (!rest.empty() && rest[0] == ',') rest = Trim(rest.substr(1));
      if (key == "NUM_POINTS") {
        if (num_points >= 0) fail("a second NUM_POINTS keyword");
        double n;
        if (!ParseDouble(rest, n) || !(n >= 0) || n != std::floor(n) || n > 1e9)
          fail("NUM_POINTS '" + rest + "' is not a count");
        num_points = static_cast<long long>(n);
        num_points_line = line_no;
      } else if (key == "VARS") {
        if (!vars.empty()) fail("a second VARS line");
        vars = Split(rest, ',');
        if (vars.size() < 5) fail("VARS names " + std::to_string(vars.size()) + " columns, expected theta_i, phi_i, theta_s, phi_s and values");
        static const char* kAngles[4][3] = {{"theta_i", "theta_i", "theta_i"}, {"phi_i", "phi_i", "phi_i"},
                                            {"theta_s", "theta_r", "theta_o"}, {"phi_s", "phi_r", "phi_o"}};
        for (int k = 0; k < 4; ++k) {
          const std::string n = Lower(vars[k]);
          if (n != kAngles[k][0] && n != kAngles[k][1] && n != kAngles[k][2])
            fail("VARS column " + std::to_string(k + 1) + " is '" + vars[k] + "', expected " + kAngles[k][0]);
        }
        const std::size_t nv = vars.size() - 4;
        std::vector<double> lambda;
        for (std::size_t k = 4; k < vars.size(); ++k) {
          const std::string n = Lower(vars[k]);
          double l;
          if (n.size() > 2 && n.compare(n.size() - 2, 2, "nm") == 0 && ParseDouble(Trim(n.substr(0, n.size() - 2)), l))
            lambda.push_back(l);
        }
        if (nv == 3 && Lower(vars[4]) == "r" && Lower(vars[5]) == "g" && Lower(vars[6]) == "b") {
          kind = Values::kRgb;
        } else if (!lambda.empty() && lambda.size() == nv && nv > 1) {
          kind = Values::kSpectral;
          try {
            spectral_weights = cie::RgbWeights(lambda);
          } catch (const std::invalid_argument& e) {
            fail(std::string("VARS wavelengths: ") + e.what());
          }
        } else if (nv == 1) {
          kind = Values::kGrey;
        } else {
          fail("VARS value columns must be R,G,B, one column, or wavelengths ending in nm (got " +
               std::to_string(nv) + " columns)");
        }
      } else {
        if (!vars.empty()) fail("keyword '" + key + "' after the VARS line (data rows start with a number)");
        t.keywords.emplace_back(line.substr(0, split), rest);
      }
    }
    line_no = 0;
    if (num_points < 0) throw std::runtime_error(what + " has no NUM_POINTS keyword");
    if (vars.empty()) throw std::runtime_error(what + " has no VARS line");
    if (static_cast<std::size_t>(num_points) != t.rows.size())
      throw std::runtime_error(what + " line " + std::to_string(num_points_line) + ": NUM_POINTS says " +
                               std::to_string(num_points) + ", the file holds " + std::to_string(t.rows.size()) +
                               " data rows");
    return t;
  }

  // Writes atomically: keywords, NUM_POINTS, "VARS theta_i,phi_i,theta_s,phi_s,R,G,B",
  // then the rows with the shortest decimals that read back exactly.
  void Write(const std::string& path) const {
    std::string out;
    for (const auto& [k, v] : keywords) out += k + " " + v + "\n";
    out += "NUM_POINTS " + std::to_string(rows.size()) + "\n";
    out += "VARS theta_i,phi_i,theta_s,phi_s,R,G,B\n";
    for (const AngleSample& s : rows) {
      const double v[7] = {s.theta_i, s.phi_i, s.theta_o, s.phi_o, s.f[0], s.f[1], s.f[2]};
      for (int k = 0; k < 7; ++k) {
        if (!std::isfinite(v[k])) throw std::runtime_error("cannot write ASTM file '" + path + "': a non-finite value");
        out += (k ? "," : "") + FormatDouble(v[k]);
      }
      out += "\n";
    }
    WriteFileAtomic(path, out);
  }

 private:
  static std::string Trim(const std::string& s) {
    std::size_t a = 0, b = s.size();
    while (a < b && std::isspace(static_cast<unsigned char>(s[a]))) ++a;
    while (b > a && std::isspace(static_cast<unsigned char>(s[b - 1]))) --b;
    return s.substr(a, b - a);
  }
  static std::string Lower(std::string s) {
    for (char& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    return s;
  }
  static std::vector<std::string> Split(const std::string& s, char sep) {
    std::vector<std::string> out;
    std::size_t a = 0;
    while (true) {
      const std::size_t b = s.find(sep, a);
      out.push_back(Trim(s.substr(a, b == std::string::npos ? std::string::npos : b - a)));
      if (b == std::string::npos) break;
      a = b + 1;
    }
    return out;
  }
};

// Scattered samples (wi, wo, f) with a nearest-sample or inverse-distance
// lookup: a k-d tree over the 6-vectors (wi, wo). When every sample shares
// one incident azimuth (an isotropic measurement), a query is first rotated
// about the normal to that azimuth.
class SampleCloud {
 public:
  explicit SampleCloud(const std::vector<AngleSample>& samples) {
    if (samples.empty()) throw std::invalid_argument("no samples");
    rotate_ = true;
    phi_i_ = samples.front().phi_i;
    for (const AngleSample& s : samples) {
      const bool normal_incidence = s.theta_i < 1e-12;  // its azimuth means nothing
      if (!normal_incidence && std::abs(s.phi_i - phi_i_) > 1e-9) rotate_ = false;
      Point p;
      const Eigen::Vector3d wi = SphericalDirection(s.theta_i, s.phi_i), wo = SphericalDirection(s.theta_o, s.phi_o);
      p.x = {wi.x(), wi.y(), wi.z(), wo.x(), wo.y(), wo.z()};
      p.f = s.f;
      points_.push_back(p);
    }
    axis_.assign(points_.size(), 0);
    Build(0, points_.size());
  }

  std::size_t size() const { return points_.size(); }

  // k = 1: the nearest sample; otherwise weights 1 / d^2 over the k nearest
  // (an exact hit returns that sample).
  Rgb<double> Lookup(const Eigen::Vector3d& wi_in, const Eigen::Vector3d& wo_in, int k) const {
    Eigen::Vector3d wi = wi_in.normalized(), wo = wo_in.normalized();
    if (rotate_) {
      const double a = phi_i_ - std::atan2(wi.y(), wi.x());
      const double c = std::cos(a), s = std::sin(a);
      wi = Eigen::Vector3d(c * wi.x() - s * wi.y(), s * wi.x() + c * wi.y(), wi.z());
      wo = Eigen::Vector3d(c * wo.x() - s * wo.y(), s * wo.x() + c * wo.y(), wo.z());
    }
    const std::array<double, 6> q = {wi.x(), wi.y(), wi.z(), wo.x(), wo.y(), wo.z()};
    std::vector<std::pair<double, std::size_t>> best;  // ascending distance, at most k
    Search(0, points_.size(), q, std::max(k, 1), best);
    if (best.front().first == 0 || k <= 1) return points_[best.front().second].f;
    Rgb<double> sum = Rgb<double>::Zero();
    double wsum = 0;
    for (const auto& [d2, i] : best) {
      sum += points_[i].f / d2;
      wsum += 1 / d2;
    }
    return sum / wsum;
  }

 private:
  struct Point {
    std::array<double, 6> x;
    Rgb<double> f;
  };
  static double Dist2(const std::array<double, 6>& a, const std::array<double, 6>& b) {
    double d = 0;
    for (int k = 0; k < 6; ++k) d += (a[k] - b[k]) * (a[k] - b[k]);
    return d;
  }
  void Build(std::size_t lo, std::size_t hi) {
    if (hi - lo <= 1) return;
    int axis = 0;
    double spread = -1;
    for (int a = 0; a < 6; ++a) {
      double mn = 1e300, mx = -1e300;
      for (std::size_t i = lo; i < hi; ++i) {
        mn = std::min(mn, points_[i].x[a]);
        mx = std::max(mx, points_[i].x[a]);
      }
      if (mx - mn > spread) {
        spread = mx - mn;
        axis = a;
      }
    }
    const std::size_t mid = (lo + hi) / 2;
    std::nth_element(points_.begin() + std::ptrdiff_t(lo), points_.begin() + std::ptrdiff_t(mid),
                     points_.begin() + std::ptrdiff_t(hi),
                     [axis](const Point& a, const Point& b) { return a.x[axis] < b.x[axis]; });
    axis_[mid] = axis;
    Build(lo, mid);
    Build(mid + 1, hi);
  }
  void Search(std::size_t lo, std::size_t hi, const std::array<double, 6>& q, int k,
              std::vector<std::pair<double, std::size_t>>& best) const {
    if (lo >= hi) return;
    const std::size_t mid = (lo + hi) / 2;
    const double d2 = Dist2(q, points_[mid].x);
    if (best.size() < std::size_t(k) || d2 < best.back().first) {
      best.insert(std::upper_bound(best.begin(), best.end(), std::make_pair(d2, mid)), {d2, mid});
      if (best.size() > std::size_t(k)) best.pop_back();
    }
    const int a = axis_[mid];
    const double diff = q[a] - points_[mid].x[a];
    const bool left_first = diff < 0;
    Search(left_first ? lo : mid + 1, left_first ? mid : hi, q, k, best);
    if (best.size() < std::size_t(k) || diff * diff < best.back().first)
      Search(left_first ? mid + 1 : lo, left_first ? hi : mid, q, k, best);
  }

  std::vector<Point> points_;
  std::vector<int> axis_;
  bool rotate_ = false;
  double phi_i_ = 0;
};

// Model [astm]: an ASTM E1392 table of scattered samples.
//
// No numeric parameters. Settings:
// | setting | values                    | meaning                                          |
// |---------|---------------------------|--------------------------------------------------|
// | path    | FILE                      | the table (also written "astm:FILE")             |
// | interp  | nearest (default), idw    | the nearest sample, or 1/d^2 weights of the 8 nearest |
//
// Eval is a constant of T. Not reciprocal by construction (measured data).
// Sampling is cosine-weighted.
class Astm : public CosineSampling {
 public:
  explicit Astm(const Settings& settings) {
    const auto path = settings.find("path");
    if (path == settings.end() || path->second.empty())
      throw ModelError("model 'astm' needs path=FILE (an ASTM E1392 table, e.g. astm:sample.astm)");
    const auto interp = settings.find("interp");
    if (interp != settings.end()) {
      if (interp->second == "idw") neighbours_ = 8;
      else if (interp->second != "nearest")
        throw ModelError("model 'astm': interp must be 'nearest' or 'idw' (got '" + interp->second + "')");
    }
    AstmTable t;
    try {
      t = AstmTable::Read(path->second);
    } catch (const std::runtime_error& e) {
      throw ModelError(e.what());
    }
    if (t.rows.empty()) throw ModelError("model 'astm': ASTM file '" + path->second + "' holds no samples");
    cloud_ = std::make_shared<const SampleCloud>(t.rows);
    double sum = 0;
    for (const AngleSample& s : t.rows) sum += s.f.mean();
    weight_ = std::max(kPi * sum / double(t.rows.size()), 0.0);  // pi times the mean value: a rough albedo
    width_ = MeasuredLobeWidth(
        [&](const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) { return cloud_->Lookup(wi, wo, neighbours_); });
  }

  static ModelInfo Info() {
    ModelInfo info;
    info.name = "astm";
    info.summary = "measured BRDF samples, ASTM E1392 table (nearest or interpolated)";
    info.reciprocal = false;         // measured data
    info.energy_conserving = false;  // measured data
    info.settings = {"path", "interp"};
    return info;
  }

  // Measured: whatever the file holds, taken as a diffuse part and a glossy
  // peak whose width is measured once from the data (MeasuredLobeWidth).
  static constexpr unsigned kKind = LobeKind::kDiffuse | LobeKind::kGlossy;
  static constexpr bool kChannelsIndependent = true;  // no parameters
  LobeWidth Width(const double*) const { return {width_, width_}; }

  template <typename T>
  Rgb<T> Eval(const T*, const Vec3<T>& wi, const Vec3<T>& wo) const {
    if (!SameUpperHemisphere(wi, wo)) return Rgb<T>::Constant(T(0));
    const Rgb<double> f = cloud_->Lookup(Eigen::Vector3d(Value(wi.x()), Value(wi.y()), Value(wi.z())),
                                         Eigen::Vector3d(Value(wo.x()), Value(wo.y()), Value(wo.z())), neighbours_);
    return Rgb<T>(T(f[0]), T(f[1]), T(f[2]));
  }

  double SampleWeight(const double*) const { return weight_; }

 private:
  std::shared_ptr<const SampleCloud> cloud_;
  int neighbours_ = 1;
  double width_ = 1;
  double weight_ = 0;
};

}  // namespace brdfkit
