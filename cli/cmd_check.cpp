#include <algorithm>
#include <cstdio>
#include <iostream>
#include <sstream>

#include "cli/common.h"
#include "cli/tasks.h"
#include "validate/check.h"

namespace brdfkit::cli {

namespace {

// The property a reason belongs to: the text before its first ':'.
bool Names(const std::vector<std::string>& reasons, const std::string& property) {
  for (const std::string& s : reasons)
    if (s.rfind(property + ":", 0) == 0) return true;
  return false;
}
bool Failed(const validate::CheckResult& r, const std::string& property) { return Names(r.reasons, property); }
bool Undecided(const validate::CheckResult& r, const std::string& property) { return Names(r.inconclusive, property); }

nlohmann::json ResultJson(const validate::CheckResult& r) {
  nlohmann::json j = {
      {"reciprocity_max_rel_error", r.reciprocity_max_rel_error},
      {"albedo_max", r.albedo_max},
      {"albedo_max_at_mu", r.albedo_max_at_mu},
      {"min_value", r.min_value},
      {"nonfinite_count", r.nonfinite_count},
      {"pdf_integral", r.pdf_integral},
      {"chi2_p_value", r.chi2_p_value},
      {"plausible", r.plausible},
      {"verdict", r.Verdict()},
      {"reasons", r.reasons},
      {"inconclusive", r.inconclusive},
      {"albedo_tightened", r.albedo_tightened},
      {"albedo_evaluations", r.albedo_evaluations},
      {"albedo_integrand_evaluations", r.albedo_integrand_evals},
      {"albedo_max_error", r.albedo_max_error},
      {"albedo_max_at_phi", r.albedo_max_at_phi},
      {"albedo_max_per_channel", {r.albedo_max_per_channel[0], r.albedo_max_per_channel[1], r.albedo_max_per_channel[2]}},
      {"albedo_at_normal", r.albedo_at_normal},
      {"albedo_at_grazing", r.albedo_at_grazing},
      {"rotation_invariant", r.rotation_invariant},
      {"reciprocity_pairs", r.pairs_checked},
      {"values_checked", r.values_checked},
      {"sampling_checked", r.sampling_checked},
      {"valid_fraction", r.valid_fraction},
      {"chi2_min_p", r.chi2_min_p},
      {"sampling_directions", r.sampling_directions},
      {"microfacet", r.microfacet},
      {"seconds", r.seconds},
  };
  if (!r.sampling_checked) {
    j["pdf_integral"] = nullptr;
    j["chi2_p_value"] = nullptr;
    if (!r.sampling_note.empty()) j["sampling_note"] = r.sampling_note;
  }
  if (r.microfacet) {
    j["d_normalisation"] = r.d_normalisation;
    j["d_normalisation_error"] = r.d_normalisation_error;
    if (r.has_smith_g1) j["furnace"] = {r.furnace_min, r.furnace_max};
  }
  return j;
}

void PrintText(const validate::CheckResult& r) {
  const auto status = [&](const char* property) {
    return Failed(r, property) ? "FAIL" : (Undecided(r, property) ? "??  " : "ok  ");
  };
  std::printf("  reciprocity  %s max relative asymmetry %.3g over %lld pairs (normal, grazing 1e-6 rad, mirror, retro, random)\n",
              status("reciprocity"), r.reciprocity_max_rel_error, static_cast<long long>(r.pairs_checked));
  std::printf("  energy       %s max directional albedo %.9g (+- %.2g) at mu = %.3g%s; at normal %.6g, at mu = 1e-7 %.6g\n",
              status("energy"), r.albedo_max, r.albedo_max_error, r.albedo_max_at_mu,
              r.rotation_invariant ? "" : (", phi = " + std::to_string(r.albedo_max_at_phi * 180 / kPi) + " deg").c_str(),
              r.albedo_at_normal, r.albedo_at_grazing);
  std::printf("  values       %s min f_r %.3g, %lld non-finite of %lld\n", status("values"), r.min_value,
              static_cast<long long>(r.nonfinite_count), static_cast<long long>(r.values_checked));
  if (r.sampling_checked)
    std::printf("  sampling     %s pdf integral %.6g (valid fraction %.6g), chi-square p %.3g (Sidak over %d directions)\n",
                status("sampling"), r.pdf_integral, r.valid_fraction, r.chi2_p_value, r.sampling_directions);
  else if (!r.sampling_note.empty())
    std::printf("  sampling     --   %s\n", r.sampling_note.c_str());
  if (r.microfacet) {
    std::printf("  microfacet   %s int D cos = %.9f", status("microfacet"), r.d_normalisation);
    if (r.has_smith_g1) std::printf(", weak white furnace in [%.9f, %.9f]", r.furnace_min, r.furnace_max);
    std::printf("\n");
  }
  const std::string verdict = r.Verdict();
  std::printf("verdict: %s\n", verdict == "implausible" ? "NOT plausible" : verdict.c_str());
  for (const std::string& s : r.reasons) std::printf("  - %s\n", s.c_str());
  for (const std::string& s : r.inconclusive) std::printf("  ? %s\n", s.c_str());
}

}  // namespace

nlohmann::json CheckResultJson(const validate::CheckResult& r) { return ResultJson(r); }

void RegisterCheck(CLI::App& app) {
  auto* cmd = app.add_subcommand(
      "check",
      "physical plausibility: reciprocity, energy conservation (incl. grazing), finite non-negative values, "
      "sampling consistency (models that sample), microfacet normalisation. Thresholds: reciprocity 1e-9 "
      "relative; albedo <= 1 + 1e-6 (ok when the whole error bar is below, FAIL when it is wholly above, "
      "inconclusive, shown as ??, otherwise); chi-square p >= 0.01 (Sidak); int D cos and weak furnace = 1 within 1e-6. "
      "Verdict: plausible, NOT plausible or inconclusive; each is a result (exit 0).");
  static ModelArgs margs;
  static bool json = false, sweep = false, no_sampling = false;
  static int per_axis = 4;
  static std::int64_t samples = 100000, albedo_budget = validate::CheckOptions().albedo_budget;
  static std::string fixed;
  AddModelOptions(cmd, margs);
  cmd->add_flag("--json", json, "print JSON (keys reciprocity_max_rel_error, albedo_max, albedo_max_at_mu, min_value, "
                                "nonfinite_count, pdf_integral, chi2_p_value, plausible, reasons, ...)");
  cmd->add_flag("--sweep", sweep, "check over a grid of the parameter ranges (bounds included, log-spaced for "
                                  "log-scale parameters) and report where plausibility breaks");
  cmd->add_option("--per-axis", per_axis, "sweep: values per parameter (default 4; fewer when the grid would exceed 400 points)")
      ->check(CLI::Range(2, 50));
  cmd->add_option("--fixed", fixed, "sweep: comma-separated parameters kept at their --params value");
  cmd->add_option("--samples", samples, "samples per direction for the chi-square test (default 100000; sweep: a fifth)")
      ->check(CLI::Range(validate::CheckOptions::kMinSamples, validate::CheckOptions::kMaxSamples));
  cmd->add_flag("--no-sampling", no_sampling, "skip the sampling tests");
  cmd->add_option("--albedo-budget", albedo_budget,
                  "integrand evaluations per directional albedo of the energy search (default 400000; a measured "
                  "table, whose interpolation the adaptive rule cannot resolve to 1e-8, spends all of it)")
      ->check(CLI::Range(validate::CheckOptions::kMinAlbedoBudget, validate::CheckOptions::kMaxAlbedoBudget));
  cmd->callback([] {
    const LoadedModel m = LoadModel(margs);
    const ModelInfo& info = m.model.Info();
    validate::CheckOptions o;
    o.sampling = !no_sampling;
    o.sampling_samples = samples;
    o.albedo_budget = albedo_budget;
    if (!sweep) {
      const auto b = m.model.Make<double>();
      const validate::CheckResult r = validate::CheckPlausibility(*b, m.params.data(), o);
      if (json) {
        nlohmann::json j = ResultJson(r);
        j["model"] = m.model.Spec();
        j["params"] = FormatParams(info, m.params);
        std::cout << j.dump(2) << "\n";
      } else {
        std::printf("model %s (%s)\n", m.model.Spec().c_str(), FormatParams(info, m.params).c_str());
        PrintText(r);
      }
      return;
    }
    std::vector<std::size_t> fixed_idx;
    {
      std::stringstream ss(fixed);
      std::string name;
      while (std::getline(ss, name, ',')) {
        if (name.empty()) continue;
        std::size_t k = info.params.size();
        for (std::size_t i = 0; i < info.params.size(); ++i)
          if (info.params[i].name == name) k = i;
        if (k == info.params.size()) throw UsageError("--fixed: '" + name + "' is not a parameter of " + info.name);
        fixed_idx.push_back(k);
      }
    }
    o.sampling_samples = std::max<std::int64_t>(samples / 5, 1000);
    o.random_pairs = 1000;
    const auto points = validate::SweepGrid(info, m.params, per_axis, fixed_idx);
    const validate::SweepResult s = validate::SweepPlausibility(m.model, points, o);
    // Name and value of every swept parameter (first channel for colours).
    std::vector<std::size_t> shown;
    for (std::size_t i = 0; i < info.params.size(); ++i)
      if (std::find(fixed_idx.begin(), fixed_idx.end(), i) == fixed_idx.end() && info.params[i].lower < info.params[i].upper)
        shown.push_back(i);
    if (json) {
      nlohmann::json arr = nlohmann::json::array();
      for (std::size_t k = 0; k < points.size(); ++k) {
        nlohmann::json j = ResultJson(s.results[k]);
        nlohmann::json p = nlohmann::json::object();
        for (std::size_t i : shown) p[info.params[i].name] = points[k][info.Offset(i)];
        j["params"] = p;
        arr.push_back(j);
      }
      std::cout << arr.dump(2) << "\n";
      return;
    }
    std::printf("sweep of %s: %zu points\n", m.model.Spec().c_str(), points.size());
    for (std::size_t i : shown) std::printf("%12s ", info.params[i].name.c_str());
    std::printf("%12s %10s %12s %9s  %s\n", "albedo_max", "at_mu", "reciprocity", "verdict", "failed");
    std::size_t bad = 0, undecided = 0;
    for (std::size_t k = 0; k < points.size(); ++k) {
      const validate::CheckResult& r = s.results[k];
      for (std::size_t i : shown) std::printf("%12.4g ", points[k][info.Offset(i)]);
      std::string failed;
      for (const char* prop : {"reciprocity", "energy", "values", "sampling", "microfacet"})
        if (Failed(r, prop)) failed += (failed.empty() ? "" : ",") + std::string(prop);
      for (const char* prop : {"energy"})
        if (Undecided(r, prop)) failed += (failed.empty() ? "" : ",") + std::string(prop) + "?";
      std::printf("%12.6g %10.3g %12.3g %9s  %s\n", r.albedo_max, r.albedo_max_at_mu, r.reciprocity_max_rel_error,
                  r.plausible ? "ok" : (r.reasons.empty() ? "??" : "FAIL"), failed.c_str());
      bad += r.reasons.empty() ? 0 : 1;
      undecided += r.reasons.empty() && !r.inconclusive.empty() ? 1 : 0;
    }
    std::printf("%zu of %zu points implausible, %zu inconclusive\n", bad, points.size(), undecided);
  });
}

}  // namespace brdfkit::cli
