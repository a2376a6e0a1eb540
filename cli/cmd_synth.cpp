// `brdfkit synth`: a virtual gonioreflectometer (or camera) measuring an
// analytic BRDF through the measurement equation, with the instrument's
// apertures and imperfections.
#include <algorithm>
#include <cstdio>
#include <iostream>

#include "cli/common.h"
#include "data_synth/camera.h"
#include "data_synth/outputs.h"

namespace brdfkit::cli {

void RegisterSynth(CLI::App& app) {
  auto* cmd = app.add_subcommand(
      "synth", "synthesise a measurement: a virtual gonioreflectometer (or camera) measures a model's BRDF");
  static ModelArgs margs;
  static std::string instrument_file, camera_file, reduce_out;
  static std::vector<std::string> outs;
  static std::uint64_t seed = 0;
  static bool print_instrument = false, quiet = false;
  AddModelOptions(cmd, margs, false);
  cmd->add_option("--instrument,-i", instrument_file,
                  "instrument description (JSON); default: the built-in instrument (see --print-instrument)");
  cmd->add_option("--camera", camera_file,
                  "camera rig description (JSON): render raw HDR images instead of gonioreflectometer data");
  cmd->add_option("--out,-o", outs,
                  "output file(s): .csv (BRDF table), .binary (MERL, merl plan), .exr (image of a grid plan; with "
                  "--camera: raw image prefix); FILE.json records how it was made");
  cmd->add_option("--reduce-out", reduce_out, "with --camera: also reduce the raw images to a BRDF table (.csv)");
  cmd->add_option("--seed", seed, "seed of every random draw (noise, jitter)");
  cmd->add_flag("--print-instrument", print_instrument,
                "print the instrument (or camera rig) description as JSON and exit");
  cmd->add_flag("--quiet,-q", quiet, "no summary on stderr");
  cmd->callback([] {
    if (!camera_file.empty()) {
      const synth::CameraRig rig = synth::LoadCameraRig(camera_file);
      if (print_instrument) {
        std::cout << synth::CameraRigToJson(rig).dump(2) << "\n";
        return;
      }
      if (margs.model.empty()) throw UsageError("synth: --model is required");
      if (outs.size() != 1) throw UsageError("synth --camera: give one --out PREFIX for the raw images");
      const LoadedModel m = LoadModel(margs);
      const synth::CameraCapture cap = synth::RenderCamera(rig, m.model, m.params, seed);
      const std::vector<std::string> files =
          synth::WriteCameraCapture(outs[0], rig, cap, m.model.Spec(), m.params, seed);
      if (!quiet)
        for (const std::string& f : files) std::fprintf(stderr, "wrote %s\n", f.c_str());
      if (!reduce_out.empty()) {
        const synth::BrdfTable t = synth::ReduceCamera(rig, files);
        synth::WriteTableCsv(reduce_out, t);
        if (!quiet) std::fprintf(stderr, "wrote %s (%zu BRDF samples)\n", reduce_out.c_str(), t.rows.size());
      }
      return;
    }
    const synth::Instrument inst =
        instrument_file.empty() ? synth::DefaultInstrument() : synth::LoadInstrument(instrument_file);
    if (print_instrument) {
      std::cout << synth::InstrumentToJson(inst).dump(2) << "\n";
      return;
    }
    if (margs.model.empty()) throw UsageError("synth: --model is required");
    if (outs.empty()) throw UsageError("synth: give --out FILE (.csv, .binary or .exr)");
    if (!reduce_out.empty()) throw UsageError("synth: --reduce-out needs --camera");
    const LoadedModel m = LoadModel(margs);
    const synth::SynthResult r = synth::Synthesize(inst, m.model, m.params, seed);
    synth::Provenance prov;
    prov.model = m.model.Spec();
    prov.params = m.params;
    prov.params_text = FormatParams(m.model.Info(), m.params);
    prov.seed = seed;
    for (const std::string& out : outs) synth::WriteSynthOutput(out, inst, r, prov);
    if (!quiet) {
      const synth::SynthReport& s = r.report;
      std::fprintf(stderr,
                   "synth: %zu pairs measured, %zu not measurable, %zu saturated; aperture quadrature order %d "
                   "(estimated relative error %.2e over %zu pairs, %zu pairs cut by the horizon); %.2f s\n",
                   s.measured, s.not_measured, s.saturated, s.order, s.quadrature_error, s.checked_pairs,
                   s.horizon_crossing, s.seconds);
      if (s.mean_evaluations > 0)
        std::fprintf(stderr,
                     "synth: automatic order: source rule up to degree %d, detector up to %d, %.0f BRDF evaluations "
                     "per pair; %zu pairs (%.2f %%) stopped above the tolerance, largest estimate %.2e\n",
                     s.source_degree, s.detector_degree, s.mean_evaluations, s.pairs_at_max_order,
                     100.0 * double(s.pairs_at_max_order) / double(std::max<std::size_t>(s.measured, 1)),
                     s.max_order_error);
      for (const std::string& out : outs) std::fprintf(stderr, "wrote %s and %s.json\n", out.c_str(), out.c_str());
    }
  });
}

}  // namespace brdfkit::cli
