#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <iostream>

#include <tbb/global_control.h>

#include "cli/common.h"
#include "cli/tasks.h"
#include "validate/albedo.h"
#include "validate/presets.h"

namespace brdfkit::cli {

nlohmann::json AlbedoTableJson(const validate::AlbedoTable& t) {
  nlohmann::json j = {{"model", t.model}, {"params", t.params_text}, {"part", t.part.empty() ? "E" : t.part},
                      {"mu", t.mu.nodes},
                      {"E", t.E},         {"E_avg", t.E_avg},        {"ms_norm", t.ms_norm},
                      {"max_error", t.max_error}, {"limit_error", t.limit_error}, {"seconds", t.seconds}};
  nlohmann::json axes_j = nlohmann::json::array();
  for (const auto& a : t.params) axes_j.push_back({{"name", a.name}, {"nodes", a.nodes}});
  j["axes"] = axes_j;
  if (t.f0_axis >= 0) {
    j["F_avg"] = t.F_avg;
    j["E1"] = t.E1;
    j["E1_avg"] = t.E1_avg;
    j["F_ms"] = t.F_ms;
  }
  return j;
}

nlohmann::json PresetJson(const validate::Preset& p) {
  nlohmann::json tables = nlohmann::json::array();
  for (const validate::PresetTable& t : p.tables) {
    nlohmann::json axes_j = nlohmann::json::array();
    for (const validate::PresetAxis& a : t.axes)
      axes_j.push_back({{"name", a.name}, {"nodes", a.coordinate}, {"evaluated", a.evaluated}});
    tables.push_back({{"name", t.name}, {"definition", t.definition}, {"axes", axes_j}, {"channels", t.channels},
                      {"value", t.value}, {"error", t.error}, {"derived", t.derived}});
  }
  return {{"preset", p.name}, {"tables", tables}, {"max_error", p.max_error}, {"seconds", p.seconds}};
}

void RegisterAlbedo(CLI::App& app) {
  auto* cmd = app.add_subcommand(
      "albedo",
      "directional albedo tables E(mu, p) for renderers, E_avg(p) = 2 int E mu dmu, and the Kulla-Conty "
      "multiple-scattering compensation terms. The entry at mu = 0 holds the limit mu -> 0.");
  static ModelArgs margs;
  static std::string axes, nodes = "uniform", csv, exr, header, prefix, part = "total", preset;
  static int preset_size = 0;
  static std::vector<std::string> preset_tables;
  static double tolerance = validate::AlbedoQuadratureOptions{}.abs_tolerance, accept_error = 0;
  static std::string slice;
  static int channel = 0, threads = 0;
  static std::int64_t budget = validate::AlbedoQuadratureOptions{}.max_evals;
  static bool json = false;
  AddModelOptions(cmd, margs, false);
  cmd->add_option("--axes", axes,
                  "mu:N then up to two parameters, name:count[:lower:upper], e.g. mu:32,alpha:32 or "
                  "mu:32,alpha:32,f0:8 (default range: the parameter's bounds); mu:N alone tabulates E(mu) of the "
                  "model as given (a measured table: rgl:FILE)");
  cmd->add_option("--preset", preset,
                  "instead of --model and --axes: every table a renderer ships, on its nodes and in its layout: "
                  "cycles (Blender Cycles' shader.tables: GGX, glass and generalised-Schlick tables), filament "
                  "(Filament's DFG texture), kulla_conty (Kulla & Conty's rough-glass compensation: E and E_avg "
                  "from both sides, F_avg, the transmitted share x); default tolerance 1e-7. --header writes the "
                  "renderer's arrays (a path ending in .inc: the bare array, as Filament's build includes it)")
      ->check(CLI::IsMember(validate::PresetNames()));
  cmd->add_option("--size", preset_size,
                  "nodes per axis of --preset filament (texels per side; Filament: 128, 64 on mobile) or "
                  "kulla_conty (3 to 256, default 16); cycles' sizes are fixed")
      ->check(CLI::Range(2, 4096));
  cmd->add_option("--tables", preset_tables, "only these tables of --preset (array names, comma-separated)")
      ->delimiter(',');
  cmd->add_option("--nodes", nodes,
                  "uniform: mu uniform on [0, 1], roughness (log-scale parameters) uniform in sqrt(p), others "
                  "uniform, ends included; gauss: Gauss-Legendre nodes in the same coordinates (ends excluded)")
      ->check(CLI::IsMember({"uniform", "gauss"}));
  cmd->add_option("--part", part,
                  "for a transmitting model (ggx_glass, ...): total (E_R + E_T, the power scattered from light along "
                  "wo), reflected (E_R) or transmitted (E_T); other models tabulate E")
      ->check(CLI::IsMember(validate::PartNames()));
  cmd->add_option("--csv", csv,
                  "write FILE as mu,<p>[,<p2>],E and beside it <stem>_avg.csv (<p>[,<p2>],E_avg), <stem>_ms.csv "
                  "(E_avg, ms_norm = 1/(pi (1 - E_avg)) [, F_avg, E1_avg, F_ms]) and with an f0 axis <stem>_f1.csv "
                  "(the F = 1 table)");
  cmd->add_option("--exr", exr, "write a multi-part float32 OpenEXR (parts E, E_avg, ms_norm[, E1, E1_avg, F_ms]; "
                                "axes and node values as header attributes brdfkit.*)");
  cmd->add_option("--header", header, "write a C/C++ header with float arrays and node arrays");
  cmd->add_option("--header-prefix", prefix, "symbol prefix in the header (default <model>_albedo)");
  cmd->add_option("--tolerance", tolerance, "absolute error target per entry (default 1e-6, the tables' accuracy contract)")
      ->check(CLI::Range(1e-12, 1e-2));
  cmd->add_option("--accept-error", accept_error,
                  "accept entries whose error estimate is up to this (default: the tolerance). A table with an "
                  "entry above it is not written: the entries are listed and the exit code is 1")
      ->check(CLI::Range(1e-12, 1e3));
  cmd->add_option("--albedo-budget", budget,
                  "evaluations per directional albedo after which the adaptive rule stops refining (an entry "
                  "that has not reached the tolerance by then is reported)")
      ->capture_default_str()
      ->check(CLI::Range(std::int64_t{1000}, std::int64_t{1000000000}));
  cmd->add_option("--channel", channel, "RGB channel tabulated (0, 1, 2)")->check(CLI::Range(0, 2));
  cmd->add_option("--slice", slice,
                  "BEGIN:END: only nodes BEGIN..END-1 of the first parameter axis, with the full axis's node values "
                  "(pieces of one table computed apart and joined along that axis)");
  cmd->add_option("--threads", threads, "threads (default 0: every core; more than the cores are capped)");
  cmd->add_flag("--json", json, "print the tables as JSON on stdout");
  cmd->callback([cmd] {
    if (!preset.empty()) {
      if (!axes.empty() || !margs.model.empty())
        throw UsageError("--preset excludes --model and --axes: a preset has its own models and axes");
      validate::PresetOptions po;
      if (cmd->count("--tolerance")) po.abs_tolerance = tolerance;  // else the presets' 1e-7
      po.size = preset_size;
      po.tables = preset_tables;
      const tbb::global_control limit(tbb::global_control::max_allowed_parallelism,
                                      static_cast<std::size_t>(ThreadCount(threads)));
      const validate::Preset p = validate::BuildPreset(preset, po);
      const double accepted = std::max(accept_error, po.abs_tolerance);
      const std::string misses = validate::DescribePresetMisses(p, accepted);
      if (!misses.empty()) throw ResultError(misses + "\nNo table was written. Accept a looser table with --accept-error.");
      if (!csv.empty()) validate::WritePresetCsv(p, csv);
      if (!exr.empty()) validate::WritePresetExr(p, exr);
      if (!header.empty()) validate::WritePresetHeader(p, header);
      if (json) std::cout << PresetJson(p).dump() << std::endl;  // before the summary on stderr
      std::size_t entries = 0;
      for (const validate::PresetTable& t : p.tables) entries += t.value.size();
      std::fprintf(stderr, "albedo --preset %s: %zu tables, %zu entries in %.2f s; largest error estimate %.2g\n",
                   preset.c_str(), p.tables.size(), entries, p.seconds, p.max_error);
      return;
    }
    if (margs.model.empty() || axes.empty()) throw UsageError("albedo needs --model and --axes (or --preset)");
    const LoadedModel m = LoadModel(margs);
    if (!prefix.empty()) {
      bool ident = !std::isdigit(static_cast<unsigned char>(prefix[0]));
      for (char c : prefix) ident = ident && (std::isalnum(static_cast<unsigned char>(c)) || c == '_');
      if (!ident) throw UsageError("--header-prefix '" + prefix + "' is not a C identifier (letters, digits, '_')");
    }
    validate::AlbedoTableRequest req;
    req.axes = validate::ParseAxes(axes);
    req.rule = nodes == "gauss" ? validate::NodeRule::kGauss : validate::NodeRule::kUniform;
    req.quadrature.abs_tolerance = tolerance;
    req.quadrature.max_evals = budget;
    req.quadrature.part = validate::ParsePart(part);
    const double accepted = std::max(accept_error, tolerance);
    req.quadrature.accepted_error = accepted;
    req.channel = channel;
    if (!slice.empty()) {
      const std::size_t colon = slice.find(':');
      double b = -1, e = -1;
      if (colon == std::string::npos || !ParseDouble(slice.substr(0, colon), b) ||
          !ParseDouble(slice.substr(colon + 1), e) || b != std::floor(b) || e != std::floor(e) || b < 0 || e <= b ||
          e > 1e9)
        throw UsageError("--slice '" + slice + "': expected BEGIN:END, whole numbers with 0 <= BEGIN < END");
      req.slice_begin = static_cast<std::size_t>(b);
      req.slice_end = static_cast<std::size_t>(e);
    }
    const tbb::global_control limit(tbb::global_control::max_allowed_parallelism,
                                    static_cast<std::size_t>(ThreadCount(threads)));
    const validate::AlbedoTable t = validate::BuildAlbedoTable(m.model, m.params, req);
    const std::vector<validate::AlbedoMiss> misses = validate::EntriesAboveTolerance(t, accepted);
    if (!misses.empty())
      throw ResultError(validate::DescribeMisses(misses, accepted) +
                        "\nNo table was written. " + validate::MissAdvice(t) +
                        ", or accept a looser table with --accept-error.");
    if (!csv.empty()) validate::WriteAlbedoCsv(t, csv);
    if (!exr.empty()) validate::WriteAlbedoExr(t, exr);
    if (!header.empty()) {
      validate::WriteAlbedoHeader(t, header, prefix.empty() ? AlbedoHeaderPrefix(m.model.Spec()) : prefix);
    }
    if (json) {
      const nlohmann::json j = AlbedoTableJson(t);
      std::cout << j.dump() << "\n";
    } else if (csv.empty() && exr.empty() && header.empty()) {
      std::printf("mu,");
      for (const validate::Axis& a : t.params) std::printf("%s,", a.name.c_str());
      std::printf("E\n");
      for (std::size_t i1 = 0; i1 < t.n1(); ++i1)
        for (std::size_t i2 = 0; i2 < t.n2(); ++i2)
          for (std::size_t k = 0; k < t.n_mu(); ++k) {
            std::printf("%s,", FormatDouble(t.mu.nodes[k]).c_str());
            if (!t.params.empty()) std::printf("%s,", FormatDouble(t.params[0].nodes[i1]).c_str());
            if (t.params.size() > 1) std::printf("%s,", FormatDouble(t.params[1].nodes[i2]).c_str());
            std::printf("%s\n", FormatDouble(t.at(k, i1, i2)).c_str());
          }
    }
    std::fprintf(stderr, "albedo: %zu entries and %zu averages in %.2f s; largest error estimate %.2g, grazing limit %.2g\n",
                 t.E.size(), t.E_avg.size(), t.seconds, t.max_error, t.limit_error);
  });
}

}  // namespace brdfkit::cli
