// brdfkit convert: between MERL, RGL, UTIA, ASTM E1392 and brdfkit CSV, or
// from any model into one of them, with a JSON sidecar.
#include <chrono>
#include <cstdio>
#include <ctime>

#include "brdf/atomic_file.h"
#include "cli/common.h"
#include "formats/convert.h"

namespace brdfkit::cli {

void RegisterConvert(CLI::App& app) {
  auto* cmd = app.add_subcommand(
      "convert", "convert measured data between MERL (.binary), RGL (.bsdf), UTIA (.utia/.bin), ASTM (.astm) and "
                 "CSV (.csv), or tabulate a model into one of them; writes OUT and OUT.json (how it was made)");
  static std::vector<std::string> files;
  static ModelArgs margs;
  static formats::ConvertOptions o;
  static bool no_sidecar = false;
  cmd->add_option("files", files, "IN OUT, or OUT alone with --model")->expected(1, 2);
  AddModelOptions(cmd, margs, false);
  cmd->add_option("--rgl-theta-i", o.rgl.theta_i,
                  "RGL: incident elevation slices, denser toward grazing (default: 80 isotropic, 32 anisotropic)");
  cmd->add_option("--rgl-phi-i", o.rgl.phi_i,
                  "RGL: incident azimuth slices; 0 isotropic (default for anisotropic sources: 64, or 33 and 17 with "
                  "--rgl-symmetry 2 and 4, the same spacing)");
  cmd->add_option("--rgl-symmetry", o.rgl.symmetry,
                  "RGL, anisotropic: 2 or 4 to store the incident azimuths over pi or pi / 2 of a source unchanged by a "
                  "turn by pi (2) or by both mirrors x -> -x, y -> -y (4), by default in that many times fewer slices (the "
                  "same spacing, a smaller file); read by Mitsuba 3, refused by powitacq and pbrt-v4")
      ->capture_default_str();
  cmd->add_option("--rgl-samples", o.rgl.samples,
                  "RGL: value table nodes per axis, per slice (square: the format's readers require it; default: 208 "
                  "isotropic, 40 anisotropic)");
  cmd->add_option("--rgl-vndf", o.rgl.vndf,
                  "RGL: vndf nodes along the azimuth of the normal (default: 512 isotropic, 48 anisotropic)");
  cmd->add_option("--rgl-vndf-theta", o.rgl.vndf_theta,
                  "RGL: vndf nodes along the elevation of the normal (default: as --rgl-vndf if given, else 128 isotropic, 48 "
                  "anisotropic)");
  cmd->add_option("--rgl-ndf", o.rgl.ndf, "RGL: ndf nodes per axis")->capture_default_str();
  cmd->add_option("--step", o.step_deg, "ASTM / CSV: grid step in degrees")->capture_default_str();
  cmd->add_option("--phi-i", o.phi_i, "ASTM / CSV: incident azimuths (default 1, or 8 for anisotropic sources)");
  cmd->add_flag("--anisotropic", o.anisotropic, "treat the source as anisotropic (implied for UTIA files, anisotropic tables and models)");
  cmd->add_flag("--no-sidecar", no_sidecar, "do not write OUT.json");
  cmd->callback([] {
    nlohmann::json side;
    formats::BrdfFunction f;
    std::shared_ptr<const void> keep;
    std::string out;
    if (!margs.model.empty()) {
      if (files.size() != 1) throw UsageError("convert: with --model give only OUT");
      out = files[0];
      auto m = std::make_shared<LoadedModel>(LoadModel(margs));
      auto b = std::shared_ptr<const Bxdf<double>>(m->model.Make<double>().release());
      f = [m, b](const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) { return b->Eval(m->params.data(), wi, wo); };
      side["source"] = formats::ModelSource(f, m->model.Spec(), FormatParams(m->model.Info(), m->params), o);
    } else {
      if (files.size() != 2) throw UsageError("convert: give IN OUT (or --model SPEC OUT)");
      out = files[1];
      const formats::Source s = formats::LoadSource(files[0]);
      f = s.f;
      keep = s.keep;
      o.anisotropic = o.anisotropic || s.anisotropic;
      side["source"] = {{"path", files[0]}, {"format", formats::FormatName(s.format)}, {"anisotropic", s.anisotropic}};
    }
    (void)formats::FormatOfName(out);  // a bad target name fails before the work
    side["brdfkit"] = BRDFKIT_VERSION;
    side["command"] = "convert";
    side["target"] = formats::WriteFormat(out, f, o);
    if (side["target"].contains("warning"))  // what the target format cannot hold
      std::fprintf(stderr, "brdfkit: warning: %s\n", side["target"]["warning"].get<std::string>().c_str());
    side["conventions"] = "f_r in 1/sr without the cosine; wi and wo point away from the surface";
    const std::time_t now = std::time(nullptr);
    char date[32];
    std::strftime(date, sizeof date, "%Y-%m-%dT%H:%M:%SZ", std::gmtime(&now));
    side["date"] = date;
    if (!no_sidecar) WriteFileAtomic(out + ".json", side.dump(2) + "\n");
    std::printf("wrote %s (%s)%s\n", out.c_str(), side["target"]["format"].get<std::string>().c_str(),
                no_sidecar ? "" : (" and " + out + ".json").c_str());
  });
}

}  // namespace brdfkit::cli
