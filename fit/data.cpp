// Datasets: samples from BRDF tables and measurement files.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <stdexcept>

#include <tbb/parallel_for.h>

#include "brdf/astm.h"
#include "brdf/merl.h"
#include "brdf/params.h"
#include "brdf/rgl.h"
#include "brdf/utia.h"
#include "data_synth/instrument.h"
#include "data_synth/table_io.h"
#include "fit/fit.h"
#include "fit/fit_internal.h"

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
  // Room for every cell: no reallocation (a transient second copy), and the
  // pages of cells below the horizon are never touched, so never resident.
  d.samples.reserve(MerlTable::kCells);
  // Rows of theta_h are converted in parallel a block at a time and appended
  // in order: the samples keep the table's order, and the rows held besides
  // the result are one block's (a tenth of the data), not a second copy.
  // One buffer holds a block's rows, a row's room each.
  constexpr int kBlock = 9;
  constexpr std::size_t kRow = std::size_t(MerlTable::kThetaD) * MerlTable::kPhiD;
  std::vector<Sample> rows(kBlock * kRow);
  std::vector<std::size_t> kept(kBlock, 0), missing(kBlock, 0);
  for (int first = 0; first < MerlTable::kThetaH; first += kBlock) {
    const int count = std::min(kBlock, MerlTable::kThetaH - first);
    tbb::parallel_for(0, count, [&](int r) {
      const int i = first + r;
      Sample* out = rows.data() + std::size_t(r) * kRow;
      std::size_t& n_out = kept[std::size_t(r)];
      n_out = 0;
      missing[std::size_t(r)] = 0;
      for (int j = 0; j < MerlTable::kThetaD; ++j)
        for (int k = 0; k < MerlTable::kPhiD; ++k) {
          const std::size_t n = MerlTable::Index(i, j, k);
          Sample s;
          bool lost = false;
          for (int c = 0; c < 3; ++c) {
            s.f[c] = table.values[c * MerlTable::kCells + n];
            lost = lost || s.f[c] < 0;
          }
          MerlTable::BinDirections(i, j, k, s.wi, s.wo);
          // A bin centre at or below the horizon is no reflectance sample.
          if (lost || !MerlTable::AboveHorizon(s.wi, s.wo)) {
            ++missing[std::size_t(r)];
            continue;
          }
          s.sigma.setZero();
          out[n_out++] = s;
        }
    });
    for (int r = 0; r < count; ++r) {
      const auto row = rows.begin() + std::ptrdiff_t(std::size_t(r) * kRow);
      d.samples.insert(d.samples.end(), row, row + std::ptrdiff_t(kept[std::size_t(r)]));
      d.missing += missing[std::size_t(r)];
    }
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
  else if (ext == ".binary" || (regular && LooksLikeMerl(path))) {
    d = FromMerl(MerlTable::Read(path), path);
  } else
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
