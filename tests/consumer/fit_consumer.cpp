// Builds against the installed compiled libraries (find_package(brdfkit
// COMPONENTS fit formats)): tabulates a known lambert+ggx into an ASTM E1392
// file with brdfkit::formats, reads it back as fit data and fits the model
// to it with brdfkit::fit; the parameters come back.
#include <cmath>
#include <cstdio>
#include <filesystem>

#include "brdf/model.h"
#include "fit/fit.h"
#include "formats/convert.h"

int main(int argc, char** argv) {
  using namespace brdfkit;
  const std::string path = (std::filesystem::path(argc > 1 ? argv[1] : ".") / "known.astm").string();
  const Model truth = Model::Parse("lambert+ggx");
  const std::vector<double> p = ParseParams(truth.Info(), "lambert.albedo=0.25,ggx.alpha=0.2,ggx.f0=0.04");
  const auto b = truth.Make<double>();
  formats::ConvertOptions o;
  o.step_deg = 5;
  formats::WriteFormat(path, [&](const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) { return b->Eval(p.data(), wi, wo); },
                       o);
  const fit::Dataset data = fit::LoadDataset(path);
  fit::Options fo;
  fo.covariance = false;
  const fit::Result r = fit::Fit(truth, data, fo);
  const auto at = [&r](const std::string& name) {
    for (std::size_t k = 0; k < r.packed_names.size(); ++k)
      if (r.packed_names[k] == name) return r.params[k];
    return std::nan("");
  };
  const double alpha = at("ggx.alpha"), albedo = at("lambert.albedo.g");
  std::printf("fit consumer: %zu samples from %s, ggx.alpha = %.9g, lambert.albedo.g = %.9g\n", data.samples.size(),
              path.c_str(), alpha, albedo);
  // The ASTM table holds the model at its nodes; the fit sees the nodes alone.
  if (std::abs(alpha - 0.2) > 1e-6 || std::abs(albedo - 0.25) > 1e-6) {
    std::printf("expected ggx.alpha = 0.2 and lambert.albedo = 0.25\n");
    return 1;
  }
  return 0;
}
