// Datasets: samples from BRDF tables and measurement files.
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <stdexcept>

#include "brdf/astm.h"
#include "brdf/merl.h"
#include "brdf/params.h"
#include "brdf/rgl.h"
#include "brdf/utia.h"
#include "data_synth/instrument.h"
#include "data_synth/table_io.h"
#include "fit/fit.h"

namespace brdfkit::fit {

namespace {

Eigen::Vector3d FromAngles(double theta, double phi) {
  const double s = std::sin(theta);
  return Eigen::Vector3d(s * std::cos(phi), s * std::sin(phi), std::cos(theta));
}

bool LooksLikeMerl(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  unsigned char h[12];
  if (!in.read(reinterpret_cast<char*>(h), 12)) return false;
  auto word = [&](int k) {
    return std::uint32_t(h[4 * k]) | std::uint32_t(h[4 * k + 1]) << 8 | std::uint32_t(h[4 * k + 2]) << 16 |
           std::uint32_t(h[4 * k + 3]) << 24;
  };
  return word(0) == 90 && word(1) == 90 && word(2) == 180;
}

}  // namespace

Dataset FromTable(const synth::BrdfTable& table, const std::string& source) {
  Dataset d;
  d.source = source;
  d.has_sigma = table.has_sigma;
  d.missing = table.missing;
  d.samples.reserve(table.rows.size());
  for (const synth::BrdfSample& r : table.rows)
    d.samples.push_back({FromAngles(r.theta_i, r.phi_i), FromAngles(r.theta_o, r.phi_o), r.f, r.sigma});
  return d;
}

Dataset FromMerl(const MerlTable& table, const std::string& source) {
  Dataset d;
  d.source = source;
  d.samples.reserve(MerlTable::kCells / 2);
  for (int i = 0; i < MerlTable::kThetaH; ++i)
    for (int j = 0; j < MerlTable::kThetaD; ++j)
      for (int k = 0; k < MerlTable::kPhiD; ++k) {
        const std::size_t n = MerlTable::Index(i, j, k);
        Sample s;
        bool missing = false;
        for (int c = 0; c < 3; ++c) {
          s.f[c] = table.values[c * MerlTable::kCells + n];
          missing = missing || s.f[c] < 0;
        }
        MerlTable::BinDirections(i, j, k, s.wi, s.wo);
        // A bin centre at or below the horizon is no reflectance sample.
        if (missing || !MerlTable::AboveHorizon(s.wi, s.wo)) {
          ++d.missing;
          continue;
        }
        s.sigma.setZero();
        d.samples.push_back(s);
      }
  return d;
}

namespace {

Dataset FromAngleSamples(const std::vector<AngleSample>& rows, const std::string& source) {
  Dataset d;
  d.source = source;
  for (const AngleSample& r : rows)
    d.samples.push_back({FromAngles(r.theta_i, r.phi_i), FromAngles(r.theta_o, r.phi_o), r.f, Eigen::Array3d::Zero()});
  return d;
}

bool StartsWith(const std::string& path, const std::string& magic) {
  std::ifstream in(path, std::ios::binary);
  std::string head(magic.size(), '\0');
  return in.read(head.data(), std::streamsize(head.size())) && head == magic;
}

}  // namespace

// The nodes of an RGL file (wi at each slice, wo by its warp, the cosine
// divided out), every node pair of a UTIA file, the rows of an ASTM table.
Dataset FromRgl(const RglBsdf& file, const std::string& source) {
  Dataset d;
  d.source = source;
  for (const RglBsdf::NodeSample& n : file.NodeSamples()) d.samples.push_back({n.wi, n.wo, n.f, Eigen::Array3d::Zero()});
  return d;
}

Dataset FromUtia(const UtiaTable& table, const std::string& source) {
  Dataset d;
  d.source = source;
  using U = UtiaTable;
  for (int ti = 0; ti < U::kTheta; ++ti)
    for (int pi = 0; pi < U::kPhi; ++pi)
      for (int tv = 0; tv < U::kTheta; ++tv)
        for (int pv = 0; pv < U::kPhi; ++pv) {
          const std::size_t n = U::Index(ti, pi, tv, pv);
          const Eigen::Array3d f(table.values[n], table.values[U::kPlane + n], table.values[2 * U::kPlane + n]);
          d.samples.push_back({U::NodeDirection(ti, pi), U::NodeDirection(tv, pv), f, Eigen::Array3d::Zero()});
        }
  return d;
}

Dataset LoadDataset(const std::string& path) {
  namespace fs = std::filesystem;
  std::error_code ec;
  std::string ext = fs::path(path).extension().string();
  for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  const bool regular = fs::is_regular_file(path, ec);
  Dataset d;
  if (ext == ".bsdf" || (regular && StartsWith(path, std::string("tensor_file\0", 12))))
    d = FromRgl(RglBsdf::Read(path), path);
  else if (ext == ".utia" || (ext == ".bin" && regular && fs::file_size(path, ec) == UtiaTable::kFileSize))
    d = FromUtia(UtiaTable::Read(path), path);
  else if (ext == ".astm")
    d = FromAngleSamples(AstmTable::Read(path).rows, path);
  else if (ext == ".binary" || (regular && LooksLikeMerl(path)))
    d = FromMerl(MerlTable::Read(path), path);
  else
    d = FromTable(synth::ReadTableCsv(path), path);
  const std::string side = path + ".json";
  if (fs::is_regular_file(side, ec)) {
    // The sidecar is a description, not data: one that cannot be read
    // leaves the data as they are.
    try {
      const synth::Instrument inst = synth::LoadInstrument(side);
      std::string what;
      if (inst.source.kind == synth::Source::Kind::kDisc && inst.source.angular_radius > 0)
        what = "a " + FormatDouble(inst.source.angular_radius * 180 / kPi) + " degree disc source";
      if (inst.detector.angular_radius > 0)
        what += (what.empty() ? "a " : " and a ") + FormatDouble(inst.detector.angular_radius * 180 / kPi) +
                " degree detector";
      if (!what.empty()) {
        d.apertures = what;
        d.sidecar = side;
      }
    } catch (const std::exception&) {
    }
  }
  return d;
}

}  // namespace brdfkit::fit
