// Settings that build every registered model in the cross-module tests: a
// model built from a file (merl) gets one made from a known analytic
// material, written once per test program.
#pragma once

#include <filesystem>
#include <string>

#include "brdf/model.h"
#include "brdf/params.h"

#if __has_include("brdf/merl.h")
#include "brdf/merl.h"
#define BRDFKIT_HAVE_MERL 1
#endif

namespace brdfkit::test {

inline Settings SettingsFor(const ModelInfo& info) {
  Settings s;
#ifdef BRDFKIT_HAVE_MERL
  if (info.name == "merl") {
    static const std::string path = [] {
      const auto file = std::filesystem::temp_directory_path() / "brdfkit_properties_test.binary";
      const Model m = Model::Parse("lambert+ggx");
      const auto b = m.Make<double>();
      const std::vector<double> p = ParseParams(m.Info(), "lambert.albedo=0.3:0.4:0.5,ggx.alpha=0.4,ggx.f0=0.5");
      MerlTable::FromFunction([&](const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) {
        return b->Eval(p.data(), wi, wo);
      }).Write(file.string());
      return file.string();
    }();
    s["path"] = path;
  }
#endif
  return s;
}

}  // namespace brdfkit::test
