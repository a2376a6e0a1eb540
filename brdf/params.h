// Parameter values: parsing "name=value,name=r:g:b" against a model's table,
// bound checks, and printing.
#pragma once

#include "brdf/core.h"

#include <charconv>
#include <cstdio>
#include <cmath>
#include <sstream>
#include <string>
#include <vector>

namespace brdfkit {

// Parses one floating-point number; the whole string must be consumed.
inline bool ParseDouble(const std::string& text, double& out) {
  if (text.empty()) return false;
  const char* begin = text.data();
  const char* end = begin + text.size();
  auto [ptr, ec] = std::from_chars(begin, end, out);
  return ec == std::errc() && ptr == end;
}

// Shortest text that reads back to the same double.
inline std::string FormatDouble(double v) {
  char buf[64];
  auto [ptr, ec] = std::to_chars(buf, buf + sizeof buf, v);
  return std::string(buf, ec == std::errc() ? ptr : buf);
}

// Six significant digits (printf's %g): numbers in messages and verdicts.
inline std::string FormatShort(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%g", v);
  return buf;
}

// Checks a packed parameter vector against the table: finite and within
// [lower, upper]. Throws ModelError naming the parameter.
inline void ValidateParams(const ModelInfo& info, const std::vector<double>& packed) {
  if (packed.size() != info.PackedSize())
    throw ModelError("model '" + info.name + "' expects " + std::to_string(info.PackedSize()) +
                     " packed parameter values, got " + std::to_string(packed.size()));
  std::size_t k = 0;
  static const char* kChannel[3] = {"r", "g", "b"};
  for (const ParamInfo& p : info.params) {
    for (int c = 0; c < (p.colour ? 3 : 1); ++c, ++k) {
      const double v = packed[k];
      const std::string label =
          "parameter '" + p.name + "'" + (p.colour ? std::string(" (") + kChannel[c] + ")" : "");
      if (!std::isfinite(v)) throw ModelError(label + " is not a finite number");
      if (v < p.lower || v > p.upper)
        throw ModelError(label + " = " + FormatDouble(v) + " is outside its range [" + FormatDouble(p.lower) +
                         ", " + FormatDouble(p.upper) + "]");
    }
  }
}

// Splits "a=1,b=2:3:4" into (name, value text) pairs.
inline std::vector<std::pair<std::string, std::string>> SplitAssignments(const std::string& text) {
  std::vector<std::pair<std::string, std::string>> out;
  std::stringstream ss(text);
  std::string item;
  while (std::getline(ss, item, ',')) {
    if (item.empty()) continue;
    const auto eq = item.find('=');
    if (eq == std::string::npos || eq == 0)
      throw ModelError("malformed parameter assignment '" + item + "' (expected name=value)");
    out.emplace_back(item.substr(0, eq), item.substr(eq + 1));
  }
  return out;
}

// Starts from the defaults and applies "name=value" assignments. A colour
// parameter takes one value (all channels) or "r:g:b". Names that are model
// settings (e.g. path) are skipped here and returned in `settings`.
inline std::vector<double> ParseParams(const ModelInfo& info, const std::string& text,
                                       Settings* settings = nullptr) {
  std::vector<double> packed = info.Defaults();
  for (const auto& [name, value] : SplitAssignments(text)) {
    std::size_t index = info.params.size();
    for (std::size_t i = 0; i < info.params.size(); ++i)
      if (info.params[i].name == name) index = i;
    if (index == info.params.size()) {
      bool is_setting = false;
      for (const auto& s : info.settings) is_setting = is_setting || s == name;
      if (is_setting && settings) {
        (*settings)[name] = value;
        continue;
      }
      std::string known;
      std::vector<KnownName> names;
      for (const auto& p : info.params) {
        known += (known.empty() ? "" : ", ") + p.name;
        names.push_back({p.name, p.meaning});
      }
      for (const auto& s : info.settings) {
        known += (known.empty() ? "" : ", ") + s;
        names.push_back({s, ""});
      }
      throw ModelError("unknown parameter '" + name + "' for model '" + info.name + "' (parameters: " +
                       (known.empty() ? "none" : known) + ")" + DidYouMean(name, names));
    }
    const ParamInfo& p = info.params[index];
    std::vector<std::string> parts;
    {
      std::stringstream ss(value);
      std::string part;
      while (std::getline(ss, part, ':')) parts.push_back(part);
      if (!value.empty() && value.back() == ':') parts.push_back("");
    }
    const std::size_t want = p.colour ? 3 : 1;
    if (parts.size() != 1 && parts.size() != want)
      throw ModelError("parameter '" + name + "' = '" + value + "': expected " +
                       (p.colour ? "one value or r:g:b" : "one value"));
    const std::size_t off = info.Offset(index);
    for (std::size_t c = 0; c < want; ++c) {
      const std::string& t = parts.size() == 1 ? parts[0] : parts[c];
      double v;
      if (!ParseDouble(t, v)) throw ModelError("parameter '" + name + "': '" + t + "' is not a number");
      packed[off + c] = v;
    }
  }
  ValidateParams(info, packed);
  return packed;
}

// "name=value,..." with colour parameters as r:g:b; round-trips through ParseParams.
inline std::string FormatParams(const ModelInfo& info, const std::vector<double>& packed) {
  std::string out;
  std::size_t k = 0;
  for (const ParamInfo& p : info.params) {
    if (!out.empty()) out += ',';
    out += p.name;
    out += '=';
    for (int c = 0; c < (p.colour ? 3 : 1); ++c, ++k) {
      if (c) out += ':';
      out += FormatDouble(packed[k]);
    }
  }
  return out;
}

}  // namespace brdfkit
