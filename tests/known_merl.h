// A MERL file of a known analytic material for the tests that need a
// measured model: lambert+ggx (albedo 0.3:0.4:0.5, alpha 0.4, f0 0.5)
// tabulated by MerlTable::FromFunction, written once per test program.
#pragma once

#include <filesystem>
#include <string>

#include "brdf/merl.h"
#include "brdf/model.h"
#include "brdf/params.h"
#include "tests/scratch.h"

namespace brdfkit::test {

inline std::string KnownMerlFile() {
  static const std::string path = [] {
    const auto file = ScratchPath("known_lambert_ggx.binary");
    const Model m = Model::Parse("lambert+ggx");
    const auto b = m.Make<double>();
    const std::vector<double> p = ParseParams(m.Info(), "lambert.albedo=0.3:0.4:0.5,ggx.alpha=0.4,ggx.f0=0.5");
    MerlTable::FromFunction([&](const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) {
      return b->Eval(p.data(), wi, wo);
    }).Write(file.string());
    return file.string();
  }();
  return path;
}

}  // namespace brdfkit::test
