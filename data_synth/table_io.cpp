#include "data_synth/table_io.h"

#include <array>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <memory>
#include <stdexcept>
#include <string_view>

#include "brdf/atomic_file.h"

namespace brdfkit::synth {
namespace {

// Longest accepted line: a row holds ten numbers, so anything far longer is
// not this format (and reading it whole could exhaust memory).
constexpr std::size_t kMaxLine = 4096;
constexpr double kHalfPi = 1.57079632679489661923;
constexpr double kTwoPi = 6.28318530717958647692;

// Reads lines through a fixed buffer, refusing lines longer than kMaxLine.
class LineReader {
 public:
  explicit LineReader(std::FILE* f) : f_(f), buf_(1 << 20) {}

  // False at end of file. Strips "\n" and "\r\n".
  bool Next(std::string& line, const std::string& path, std::size_t line_no) {
    line.clear();
    while (true) {
      if (pos_ == len_) {
        len_ = std::fread(buf_.data(), 1, buf_.size(), f_);
        pos_ = 0;
        if (len_ == 0) {
          if (std::ferror(f_)) throw std::runtime_error(path + ": read error: " + std::strerror(errno));
          if (line.empty()) return false;
          break;
        }
      }
      const char* start = buf_.data() + pos_;
      const void* nl = std::memchr(start, '\n', len_ - pos_);
      const std::size_t take = nl ? static_cast<const char*>(nl) - start : len_ - pos_;
      line.append(start, take);
      pos_ += take;
      if (line.size() > kMaxLine)
        throw std::runtime_error(path + ":" + std::to_string(line_no) + ": line longer than " +
                                 std::to_string(kMaxLine) + " characters (not a BRDF table)");
      if (nl) {
        ++pos_;
        break;
      }
    }
    if (!line.empty() && line.back() == '\r') line.pop_back();
    return true;
  }

 private:
  std::FILE* f_;
  std::vector<char> buf_;
  std::size_t pos_ = 0, len_ = 0;
};

std::string_view Trim(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t')) s.remove_suffix(1);
  return s;
}

std::vector<std::string_view> Split(std::string_view line) {
  std::vector<std::string_view> out;
  std::size_t start = 0;
  while (true) {
    const std::size_t comma = line.find(',', start);
    out.push_back(Trim(line.substr(start, comma == std::string_view::npos ? std::string_view::npos : comma - start)));
    if (comma == std::string_view::npos) break;
    start = comma + 1;
  }
  return out;
}

enum Column { kThetaI, kPhiI, kThetaO, kPhiO, kFr, kFg, kFb, kSr, kSg, kSb, kF, kS, kColumnCount };
const std::array<const char*, kColumnCount> kNames = {"theta_i", "phi_i",   "theta_o", "phi_o",
                                                      "f_r",     "f_g",     "f_b",     "sigma_r",
                                                      "sigma_g", "sigma_b", "f",       "sigma"};

}  // namespace

BrdfTable ReadTableCsv(const std::string& path) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (!fs::exists(path, ec)) throw std::runtime_error(path + ": no such file");
  if (fs::is_directory(path, ec)) throw std::runtime_error(path + ": is a directory, not a BRDF table");
  std::unique_ptr<std::FILE, int (*)(std::FILE*)> file(std::fopen(path.c_str(), "rb"), &std::fclose);
  if (!file) throw std::runtime_error(path + ": cannot open: " + std::strerror(errno));
  LineReader reader(file.get());

  std::string line;
  std::size_t line_no = 0;
  // Header: the first line that is neither blank nor a '#' comment.
  bool have_header = false;
  while (reader.Next(line, path, line_no + 1)) {
    ++line_no;
    const std::string_view t = Trim(line);
    if (t.empty() || t.front() == '#') continue;
    have_header = true;
    break;
  }
  if (!have_header) throw std::runtime_error(path + ": empty file (expected a header line theta_i,phi_i,theta_o,phi_o,f_r,f_g,f_b)");

  std::array<int, kColumnCount> col;
  col.fill(-1);
  const std::vector<std::string_view> header = Split(line);
  for (std::size_t k = 0; k < header.size(); ++k) {
    int which = -1;
    for (int c = 0; c < kColumnCount; ++c)
      if (header[k] == kNames[c]) which = c;
    if (which < 0)
      throw std::runtime_error(path + ":" + std::to_string(line_no) + ": unknown column '" + std::string(header[k]) +
                               "' (expected theta_i,phi_i,theta_o,phi_o,f_r,f_g,f_b[,sigma_r,sigma_g,sigma_b] or a single f[,sigma])");
    if (col[which] >= 0)
      throw std::runtime_error(path + ":" + std::to_string(line_no) + ": column '" + kNames[which] + "' appears twice");
    col[which] = static_cast<int>(k);
  }
  auto require = [&](int c) {
    if (col[c] < 0)
      throw std::runtime_error(path + ":" + std::to_string(line_no) + ": missing column '" + kNames[c] + "'");
  };
  for (int c : {kThetaI, kPhiI, kThetaO, kPhiO}) require(c);
  const bool rgb = col[kFr] >= 0 || col[kFg] >= 0 || col[kFb] >= 0;
  if (rgb && col[kF] >= 0)
    throw std::runtime_error(path + ":" + std::to_string(line_no) + ": give either f_r,f_g,f_b or a single f column, not both");
  if (rgb) {
    for (int c : {kFr, kFg, kFb}) require(c);
  } else {
    if (col[kF] < 0)
      throw std::runtime_error(path + ":" + std::to_string(line_no) + ": missing column 'f_r' (or a single grey 'f')");
  }
  const bool sig_rgb = col[kSr] >= 0 || col[kSg] >= 0 || col[kSb] >= 0;
  if (sig_rgb && col[kS] >= 0)
    throw std::runtime_error(path + ":" + std::to_string(line_no) + ": give either sigma_r,sigma_g,sigma_b or a single sigma column, not both");
  if (sig_rgb)
    for (int c : {kSr, kSg, kSb}) require(c);

  BrdfTable table;
  table.has_sigma = sig_rgb || col[kS] >= 0;
  const std::size_t fields = header.size();

  std::size_t zero_sigma_line = 0;  // first row whose sigma is 0 in every channel
  bool positive_sigma = false;
  while (reader.Next(line, path, line_no + 1)) {
    ++line_no;
    const std::string_view t = Trim(line);
    if (t.empty() || t.front() == '#') continue;
    const std::vector<std::string_view> v = Split(line);
    auto where = [&] { return path + ":" + std::to_string(line_no) + ": "; };
    if (v.size() != fields)
      throw std::runtime_error(where() + "expected " + std::to_string(fields) + " fields, found " +
                               std::to_string(v.size()));
    bool missing = false;
    // Parses column c; empty or NaN marks the sample missing.
    auto get = [&](int c) -> double {
      const std::string_view s = v[static_cast<std::size_t>(col[c])];
      if (s.empty()) {
        missing = true;
        return 0;
      }
      double x = 0;
      const char* b = s.data();
      const char* e = b + s.size();
      if (*b == '+') ++b;  // from_chars rejects a leading '+'
      auto [ptr, err] = std::from_chars(b, e, x);
      if (err == std::errc::result_out_of_range)
        throw std::runtime_error(where() + kNames[c] + " = '" + std::string(s) + "' is out of the range of a double");
      if (err != std::errc() || ptr != e)
        throw std::runtime_error(where() + kNames[c] + " = '" + std::string(s) + "' is not a number");
      if (std::isnan(x)) {
        missing = true;
        return 0;
      }
      if (std::isinf(x)) throw std::runtime_error(where() + kNames[c] + " = '" + std::string(s) + "' is not finite");
      return x;
    };
    BrdfSample r;
    r.theta_i = get(kThetaI);
    r.phi_i = get(kPhiI);
    r.theta_o = get(kThetaO);
    r.phi_o = get(kPhiO);
    if (rgb) r.f = Eigen::Array3d(get(kFr), get(kFg), get(kFb));
    else r.f = Eigen::Array3d::Constant(get(kF));
    if (sig_rgb) r.sigma = Eigen::Array3d(get(kSr), get(kSg), get(kSb));
    else if (col[kS] >= 0) r.sigma = Eigen::Array3d::Constant(get(kS));
    else r.sigma = Eigen::Array3d::Zero();
    if (missing) {
      ++table.missing;
      continue;
    }
    // 1e-9 rad of slack for angles written by a program near the limits.
    for (auto [c, x] : {std::pair{kThetaI, r.theta_i}, std::pair{kThetaO, r.theta_o}})
      if (x < -1e-9 || x > kHalfPi + 1e-9)
        throw std::runtime_error(where() + kNames[c] + " = " + std::to_string(x) +
                                 " is outside [0, pi/2] (angles are in radians)");
    for (auto [c, x] : {std::pair{kPhiI, r.phi_i}, std::pair{kPhiO, r.phi_o}})
      if (std::abs(x) > 2 * kTwoPi)
        throw std::runtime_error(where() + kNames[c] + " = " + std::to_string(x) +
                                 " is not an azimuth in radians");
    if (table.has_sigma) {
      if ((r.sigma == 0).all()) {
        // All-zero uncertainties mark a noiseless table; mixed with positive
        // ones they would give those samples infinite weight.
        if (zero_sigma_line == 0) zero_sigma_line = line_no;
      } else if (!(r.sigma > 0).all()) {
        throw std::runtime_error(where() + "sigma must be positive, or 0 in every row of a noiseless table");
      } else {
        positive_sigma = true;
      }
    }
    table.rows.push_back(r);
  }
  if (zero_sigma_line > 0 && positive_sigma)
    throw std::runtime_error(path + ":" + std::to_string(zero_sigma_line) +
                             ": sigma is 0 here but positive elsewhere (a zero uncertainty would give the sample "
                             "infinite weight; 0 is allowed only in every row of a noiseless table)");
  // Sigma columns without a positive value (noiseless data, or no rows at
  // all) carry no weights: such a table is fitted unweighted.
  if (!positive_sigma) table.has_sigma = false;
  return table;
}

void WriteTableCsv(const std::string& path, const BrdfTable& table) {
  AtomicFile out(path, std::ios::out | std::ios::binary);
  std::ofstream& s = out.stream();
  // Always the full header: a noiseless table carries sigma = 0.
  s << "theta_i,phi_i,theta_o,phi_o,f_r,f_g,f_b,sigma_r,sigma_g,sigma_b\n";
  char buf[512];
  for (const BrdfSample& r : table.rows) {
    int n = std::snprintf(buf, sizeof buf, "%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g", r.theta_i, r.phi_i,
                          r.theta_o, r.phi_o, r.f[0], r.f[1], r.f[2]);
    s.write(buf, n);
    if (table.has_sigma) {
      n = std::snprintf(buf, sizeof buf, ",%.17g,%.17g,%.17g", r.sigma[0], r.sigma[1], r.sigma[2]);
      s.write(buf, n);
    } else {
      s.write(",0,0,0", 6);
    }
    s.put('\n');
  }
  out.Commit();
}

}  // namespace brdfkit::synth
