// Settings that build every registered model in the cross-module tests: a
// model built from a file (merl, rgl, utia, astm) gets one made from a known
// analytic material, written once per test program.
#pragma once

#include <filesystem>
#include <map>
#include <string>

#include "brdf/model.h"
#include "brdf/params.h"

#if __has_include("brdf/merl.h")
#include "tests/known_merl.h"
#define BRDFKIT_HAVE_MERL 1
#endif
#if __has_include("formats/convert.h")
#include "formats/convert.h"
#include "tests/scratch.h"
#define BRDFKIT_HAVE_FORMATS 1
#endif

namespace brdfkit::test {

inline Settings SettingsFor(const ModelInfo& info) {
  Settings s;
#ifdef BRDFKIT_HAVE_MERL
  if (info.name == "merl") s["path"] = KnownMerlFile();
#endif
#ifdef BRDFKIT_HAVE_FORMATS
  // The measured formats, written from a known analytic material (RGL at a
  // reduced resolution).
  static const char* kFormats[][2] = {{"rgl", ".bsdf"}, {"utia", ".utia"}, {"astm", ".astm"}};
  for (const auto& [name, ext] : kFormats) {
    if (info.name != name) continue;
    const auto file = ScratchPath(std::string("known_lambert_ggx") + ext);
    static std::map<std::string, bool> written;
    if (!written[name]) {
      const Model m = Model::Parse("lambert+ggx");
      const auto b = m.Make<double>();
      const std::vector<double> p = ParseParams(m.Info(), "lambert.albedo=0.3:0.4:0.5,ggx.alpha=0.4,ggx.f0=0.5");
      formats::ConvertOptions o;
      o.rgl.theta_i = 6;
      o.rgl.ndf = 32;
      o.rgl.sigma = o.rgl.vndf = o.rgl.samples = 16;
      o.step_deg = 15;
      formats::WriteFormat(file.string(), [&](const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) {
        return b->Eval(p.data(), wi, wo);
      }, o);
      written[name] = true;
    }
    s["path"] = file.string();
  }
#endif
  return s;
}

}  // namespace brdfkit::test
