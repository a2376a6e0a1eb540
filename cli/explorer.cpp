#include "cli/explorer.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <regex>

#include "brdf/merl.h"
#include "validate/albedo.h"
#include "validate/plot.h"

namespace brdfkit::cli {

extern const char* const kExplorerJs;   // explorer_assets.cpp, generated from cli/explorer/
extern const char* const kExplorerCss;

namespace {

using json = nlohmann::json;

std::vector<double> Steps(double start, double stop, double step) {
  std::vector<double> v;
  for (int k = 0; start + k * step <= stop + 1e-9; ++k) v.push_back(start + k * step);
  return v;
}

const std::vector<double> kThetaI = Steps(0, 88, 2), kSlice = Steps(-89, 89, 1), kLobeTheta = Steps(0, 90, 6),
                          kLobePhi = Steps(0, 360, 12), kAnisoPhiI = Steps(0, 180, 30);

Eigen::Vector3d Dir(double theta_deg, double phi_deg) {
  const double t = theta_deg * kDeg, p = phi_deg * kDeg;
  return {std::sin(t) * std::cos(p), std::sin(t) * std::sin(p), std::cos(t)};
}

// Whether f changes when both directions turn about the normal (checked at
// fixed pairs, turned by 37 degrees): if not, one azimuth of incidence
// stands for all.
bool Isotropic(const Bxdf<double>& b, const double* p) {
  const double pairs[][4] = {{30, 10, 50, 200}, {60, 0, 20, 150}, {45, 80, 70, 300}, {10, 0, 80, 90}, {75, 30, 75, 200}};
  for (const auto& q : pairs) {
    const Rgb<double> a = b.Eval(p, Dir(q[0], q[1]), Dir(q[2], q[3]));
    const Rgb<double> c = b.Eval(p, Dir(q[0], q[1] + 37), Dir(q[2], q[3] + 37));
    for (int ch = 0; ch < 3; ++ch)
      if (std::abs(a[ch] - c[ch]) > 1e-9 * std::max({std::abs(a[ch]), std::abs(c[ch]), 1e-300})) return false;
  }
  return true;
}

struct Floats {
  std::vector<float> v;
  void Add(const Rgb<double>& f) {
    for (int c = 0; c < 3; ++c) v.push_back(std::isfinite(f[c]) ? float(f[c]) : NAN);
  }
  std::string B64() const {
    std::string bytes(v.size() * sizeof(float), '\0');
    std::memcpy(bytes.data(), v.data(), bytes.size());  // little-endian, as Float32Array reads it on every target
    return Base64(bytes);
  }
};

json MaterialJson(const ExplorerMaterial& m, int index) {
  const auto b = m.model.model.Make<double>();
  const double* p = m.model.params.data();
  const bool iso = Isotropic(*b, p);
  const std::vector<double> phi_i = iso ? std::vector<double>{0.0} : kAnisoPhiI;
  Floats in_plane, out_plane, lobe, albedo, halfdiff;
  const validate::LobeShape shape = validate::EstimateLobeShape(*b, p);
  // E(wo) at wo = wi's direction (by reciprocity also the albedo for light
  // from there), to 1e-5: the page draws and shows float32 values of E <= 1.
  // The integrations are most of the page's work: one per direction, in
  // parallel.
  validate::AlbedoQuadratureOptions ao;
  ao.abs_tolerance = 1e-5;
  ao.max_evals = 100000;
  std::vector<Eigen::Vector3d> albedo_dirs;
  for (double pi : phi_i)
    for (double ti : kThetaI) albedo_dirs.push_back(Dir(std::min(ti, 89.5), pi));
  const validate::IntegrateOptions io = ao.Integrate(shape);
  std::vector<Rgb<double>> e(albedo_dirs.size());
  tbb::parallel_for(std::size_t(0), albedo_dirs.size(), [&](std::size_t k) {
    const validate::AlbedoValue v = validate::DirectionalAlbedo(*b, p, albedo_dirs[k], validate::Method::kAdaptive, io);
    e[k] = Rgb<double>(v.value[0], v.value[1], v.value[2]);
  });
  for (const Rgb<double>& v : e) albedo.Add(v);
  for (double pi : phi_i)
    for (double ti : kThetaI) {
      const Eigen::Vector3d wi = Dir(ti, pi);
      for (double a : kSlice) in_plane.Add(b->Eval(p, wi, Dir(std::abs(a), a >= 0 ? pi : pi + 180)));
      for (double a : kSlice) out_plane.Add(b->Eval(p, wi, Dir(std::abs(a), a >= 0 ? pi + 90 : pi - 90)));
      for (double to : kLobeTheta)
        for (double po : kLobePhi) lobe.Add(b->Eval(p, wi, Dir(to, po)));
    }
  for (int j = 0; j < 90; ++j)
    for (int i = 0; i < 90; ++i) {
      Eigen::Vector3d wi, wo;
      MerlTable::BinDirections(i, j, 90, wi, wo);
      halfdiff.Add(wi.z() > 0 && wo.z() > 0 ? b->Eval(p, wi, wo) : Rgb<double>(NAN, NAN, NAN));
    }
  return {{"label", m.label},
          {"description", m.description},
          {"colour", validate::PaletteCss(index)},
          {"phi_i_deg", phi_i},
          {"in_plane", in_plane.B64()},
          {"out_of_plane", out_plane.B64()},
          {"lobe", lobe.B64()},
          {"albedo", albedo.B64()},
          {"halfdiff", halfdiff.B64()}};
}

}  // namespace

std::string Base64(const std::string& in) {
  static const char* k = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  out.reserve((in.size() + 2) / 3 * 4);
  std::size_t i = 0;
  for (; i + 2 < in.size(); i += 3) {
    const unsigned v = (unsigned char)in[i] << 16 | (unsigned char)in[i + 1] << 8 | (unsigned char)in[i + 2];
    out += k[v >> 18];
    out += k[(v >> 12) & 63];
    out += k[(v >> 6) & 63];
    out += k[v & 63];
  }
  if (i + 1 == in.size()) {
    const unsigned v = (unsigned char)in[i] << 16;
    out += k[v >> 18];
    out += k[(v >> 12) & 63];
    out += "==";
  } else if (i + 2 == in.size()) {
    const unsigned v = (unsigned char)in[i] << 16 | (unsigned char)in[i + 1] << 8;
    out += k[v >> 18];
    out += k[(v >> 12) & 63];
    out += k[(v >> 6) & 63];
    out += '=';
  }
  return out;
}

std::string HtmlEscape(const std::string& s) {
  std::string out;
  for (char c : s) {
    switch (c) {
      case '&': out += "&amp;"; break;
      case '<': out += "&lt;"; break;
      case '>': out += "&gt;"; break;
      case '"': out += "&quot;"; break;
      default: out += c;
    }
  }
  return out;
}

ExplorerMaterial ParseMaterialArg(const std::string& text) {
  static const std::regex kParamsStart(":[A-Za-z_][A-Za-z0-9_.#]*=");
  std::smatch m;
  ModelArgs args;
  if (std::regex_search(text, m, kParamsStart)) {
    args.model = text.substr(0, std::size_t(m.position(0)));
    args.params = text.substr(std::size_t(m.position(0)) + 1);
  } else {
    args.model = text;
  }
  if (args.model.empty()) throw UsageError("material '" + text + "': no model before the parameters");
  ExplorerMaterial out{text, "", LoadModel(args)};
  out.description = out.model.model.Spec() + " (" + FormatParams(out.model.model.Info(), out.model.params) + ")";
  return out;
}

std::string ExplorerSection(const std::vector<ExplorerMaterial>& materials) {
  if (materials.empty()) throw UsageError("the explorer needs at least one material");
  json d = {{"theta_i_deg", kThetaI}, {"slice_deg", kSlice},         {"lobe_theta_deg", kLobeTheta},
            {"lobe_phi_deg", kLobePhi}, {"halfdiff_n", 90},          {"materials", json::array()}};
  std::vector<double> th, td;
  for (int i = 0; i < 90; ++i) {
    double h, dd, pd;
    MerlTable::BinCentre(i, i, 90, h, dd, pd);
    th.push_back(h / kDeg);
    td.push_back(dd / kDeg);
  }
  d["halfdiff_theta_h_deg"] = th;
  d["halfdiff_theta_d_deg"] = td;
  for (std::size_t k = 0; k < materials.size(); ++k) d["materials"].push_back(MaterialJson(materials[k], int(k)));
  std::string data = d.dump();
  // Inside <script>, "</" would end the element early.
  for (std::size_t pos = 0; (pos = data.find("</", pos)) != std::string::npos; pos += 3) data.replace(pos, 2, "<\\/");
  return std::string("<section id=\"brdf-explorer\" class=\"brdf-explorer\">\n<style>\n") + kExplorerCss +
         "</style>\n<script type=\"application/json\" id=\"brdf-explorer-data\">" + data + "</script>\n<script>\n" +
         kExplorerJs + "</script>\n</section>\n";
}

std::string ExplorerPage(const std::string& title, const std::vector<ExplorerMaterial>& materials) {
  return "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>" + HtmlEscape(title) +
         "</title>\n<style>body{font-family:sans-serif;max-width:1100px;margin:1em auto;padding:0 1em;color:#222}"
         "h1{overflow-wrap:anywhere}</style></head>\n<body>\n<h1>" + HtmlEscape(title) + "</h1>\n" + ExplorerSection(materials) +
         "</body></html>\n";
}

}  // namespace brdfkit::cli
