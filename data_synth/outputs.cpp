#include "data_synth/outputs.h"

#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfInputFile.h>
#include <OpenEXR/ImfOutputFile.h>
#include <OpenEXR/ImfStdIO.h>
#include <OpenEXR/ImfStringAttribute.h>

#include <cmath>
#include <filesystem>
#include <limits>
#include <stdexcept>

#include "brdf/atomic_file.h"
#include "brdf/merl.h"

namespace brdfkit::synth {

BrdfTable ToTable(const SynthResult& result) {
  BrdfTable t;
  // Noiseless data carry sigma = 0 in every row, which readers take as
  // unweighted data.
  t.has_sigma = result.noisy;
  for (std::size_t n = 0; n < result.samples.size(); ++n) {
    const SynthSample& s = result.samples[n];
    if (!s.valid) {
      ++t.missing;
      continue;
    }
    const PlannedPair& p = result.plan.pairs[n];
    t.rows.push_back({p.theta_i, p.phi_i, p.theta_o, p.phi_o, s.f, s.sigma});
  }
  return t;
}

nlohmann::json Sidecar(const Instrument& inst, const SynthResult& result, const Provenance& prov) {
  const SynthReport& r = result.report;
  nlohmann::json j;
  j["brdfkit_version"] = BRDFKIT_VERSION;
  j["model"] = prov.model;
  j["params"] = prov.params;
  j["params_text"] = prov.params_text;
  j["seed"] = prov.seed;
  if (!prov.command.empty()) j["command"] = prov.command;
  j["instrument"] = InstrumentToJson(inst);
  const bool automatic = inst.quadrature.order == 0;
  j["quadrature"] = {{"method", automatic ? "per pair, source and detector cone rules raised separately"
                                          : "product of the source and detector cone rules of one order"},
                     {"order", r.order},
                     {"source_degree", r.source_degree},
                     {"detector_degree", r.detector_degree},
                     {"estimated_relative_error", r.quadrature_error},
                     {"error_estimate", automatic ? "max over checked pairs of e_s + e_d, relative"
                                                  : "max over checked pairs of |I_n - I_(n+1)| / |I_(n+1)|"},
                     {"checked_pairs", r.checked_pairs},
                     {"horizon_crossing_pairs", r.horizon_crossing}};
  if (automatic && r.mean_evaluations > 0) {
    j["quadrature"]["mean_brdf_evaluations_per_pair"] = r.mean_evaluations;
    j["quadrature"]["largest_pair_error"] = r.pair_error;
    j["quadrature"]["pairs_at_max_order"] = r.pairs_at_max_order;
    j["quadrature"]["max_order_error"] = r.max_order_error;
  }
  j["counts"] = {{"planned", result.samples.size()},
                 {"measured", r.measured},
                 {"not_measured", r.not_measured},
                 {"saturated", r.saturated}};
  if (!result.plan.image_layout.empty())
    j["image"] = {{"width", result.plan.image_width},
                  {"height", result.plan.image_height},
                  {"layout", result.plan.image_layout}};
  return j;
}

void WriteMerlFile(const std::string& path, const SynthResult& result) {
  if (result.plan.merl_cell.size() != result.samples.size())
    throw std::runtime_error("cannot write MERL file '" + path + "': the sampling plan is not the MERL grid (plan.type merl)");
  MerlTable t;  // every cell starts missing (-1)
  for (std::size_t n = 0; n < result.samples.size(); ++n) {
    const SynthSample& s = result.samples[n];
    if (!s.valid) continue;
    for (int c = 0; c < 3; ++c)
      t.values[c * MerlTable::kCells + static_cast<std::size_t>(result.plan.merl_cell[n])] = s.f[c];
  }
  t.Write(path);
}

void WriteExrFloat(const std::string& path, int width, int height,
                   const std::vector<std::pair<std::string, const float*>>& planes,
                   const std::map<std::string, std::string>& attributes) {
  if (width <= 0 || height <= 0) throw std::runtime_error("cannot write '" + path + "': empty image");
  Imf::Header header(width, height);
  header.compression() = Imf::ZIP_COMPRESSION;
  for (const auto& [k, v] : attributes) header.insert(k, Imf::StringAttribute(v));
  Imf::FrameBuffer fb;
  for (const auto& [name, data] : planes) {
    header.channels().insert(name, Imf::Channel(Imf::FLOAT));
    fb.insert(name, Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(const_cast<float*>(data)), sizeof(float),
                               sizeof(float) * std::size_t(width)));
  }
  AtomicFile file(path, std::ios::out | std::ios::binary);
  try {
    Imf::StdOFStream os(file.stream(), path.c_str());
    Imf::OutputFile out(os, header);
    out.setFrameBuffer(fb);
    out.writePixels(height);
  } catch (const std::exception& e) {
    throw std::runtime_error("cannot write OpenEXR file '" + path + "': " + e.what());
  }
  file.Commit();
}

ExrImage ReadExrFloat(const std::string& path) {
  if (!std::filesystem::is_regular_file(path)) throw std::runtime_error("cannot read OpenEXR file '" + path + "'");
  ExrImage img;
  try {
    Imf::InputFile in(path.c_str());
    const Imath::Box2i dw = in.header().dataWindow();
    img.width = dw.max.x - dw.min.x + 1;
    img.height = dw.max.y - dw.min.y + 1;
    for (auto it = in.header().begin(); it != in.header().end(); ++it)
      if (const auto* s = dynamic_cast<const Imf::StringAttribute*>(&it.attribute())) img.attributes[it.name()] = s->value();
    Imf::FrameBuffer fb;
    const std::size_t n = std::size_t(img.width) * std::size_t(img.height);
    for (auto it = in.header().channels().begin(); it != in.header().channels().end(); ++it) {
      std::vector<float>& v = img.channels[it.name()];
      v.assign(n, 0.0f);
      char* base = reinterpret_cast<char*>(v.data()) -
                   (std::ptrdiff_t(dw.min.x) + std::ptrdiff_t(dw.min.y) * img.width) * std::ptrdiff_t(sizeof(float));
      fb.insert(it.name(), Imf::Slice(Imf::FLOAT, base, sizeof(float), sizeof(float) * std::size_t(img.width)));
    }
    in.setFrameBuffer(fb);
    in.readPixels(dw.min.y, dw.max.y);
  } catch (const std::exception& e) {
    throw std::runtime_error("cannot read OpenEXR file '" + path + "': " + e.what());
  }
  return img;
}

void WriteExrTable(const std::string& path, const SynthResult& result) {
  const ExpandedPlan& plan = result.plan;
  if (plan.pixel.size() != result.samples.size() || plan.image_width <= 0)
    throw std::runtime_error("cannot write OpenEXR file '" + path +
                             "': the sampling plan is not a grid (use a full, in_plane or merl plan)");
  const std::size_t n = std::size_t(plan.image_width) * std::size_t(plan.image_height);
  std::vector<float> r(n, 0.f), g(n, 0.f), b(n, 0.f), a(n, 0.f), sr(n, 0.f), sg(n, 0.f), sb(n, 0.f);
  for (std::size_t k = 0; k < result.samples.size(); ++k) {
    const SynthSample& s = result.samples[k];
    if (!s.valid) continue;
    const std::size_t p = static_cast<std::size_t>(plan.pixel[k]);
    r[p] = float(s.f[0]);
    g[p] = float(s.f[1]);
    b[p] = float(s.f[2]);
    a[p] = 1.f;
    sr[p] = float(s.sigma[0]);
    sg[p] = float(s.sigma[1]);
    sb[p] = float(s.sigma[2]);
  }
  WriteExrFloat(path, plan.image_width, plan.image_height,
                {{"R", r.data()}, {"G", g.data()}, {"B", b.data()}, {"A", a.data()},
                 {"sigma.R", sr.data()}, {"sigma.G", sg.data()}, {"sigma.B", sb.data()}},
                {{"brdfkit.layout", plan.image_layout}, {"brdfkit.units", "f_r in 1/sr (no cosine)"}});
}

void WriteSynthOutput(const std::string& path, const Instrument& inst, const SynthResult& result,
                      const Provenance& prov) {
  const std::string ext = std::filesystem::path(path).extension().string();
  if (ext == ".csv") {
    WriteTableCsv(path, ToTable(result));
  } else if (ext == ".binary") {
    WriteMerlFile(path, result);
  } else if (ext == ".exr") {
    WriteExrTable(path, result);
  } else {
    throw std::runtime_error("output '" + path + "': unknown format '" + ext + "' (expected .csv, .binary or .exr)");
  }
  WriteFileAtomic(path + ".json", Sidecar(inst, result, prov).dump(2) + "\n");
}

}  // namespace brdfkit::synth
