// Conversions between measured-data formats: MERL (.binary), RGL-EPFL
// (.bsdf), UTIA (.utia, or .bin of the UTIA size), ASTM E1392 (.astm) and
// brdfkit CSV (.csv). An input is read as a BRDF function (a registered
// model for the first four; the nearest sample for CSV); an output is
// tabulated from any BRDF function at the target's own nodes.
#pragma once

#include <nlohmann/json.hpp>

#include <memory>
#include <string>

#include "formats/rgl_writer.h"

namespace brdfkit::formats {

enum class Format { kMerl, kRgl, kUtia, kAstm, kCsv };
std::string FormatName(Format f);

// By the file name's extension; throws std::invalid_argument naming the path.
Format FormatOfName(const std::string& path);
// The format of an existing file: by extension, then checked against its
// header (magic, size or keywords); throws std::runtime_error naming the
// file when they disagree.
Format DetectFormat(const std::string& path);

struct Source {
  BrdfFunction f;
  Format format = Format::kCsv;
  bool anisotropic = false;           // UTIA files, and tables whose incident azimuths vary
  std::shared_ptr<const void> keep;   // the data f reads
};
// Reads a measured file as a BRDF function.
Source LoadSource(const std::string& path);

// Whether f changes when both directions turn about the normal: 64 fixed
// direction pairs, each turned by 0.9 and 2.3 radians, compared to 1e-6
// relative. Decides a model source's isotropy (convert --model).
bool IsAnisotropic(const BrdfFunction& f);

struct ConvertOptions {
  RglOptions rgl{.phi_i = -1};  // rgl.phi_i < 0: isotropic unless the source is anisotropic (then RglAnisotropicSlices)
  double step_deg = 5;        // ASTM / CSV grid: theta_i, theta_o 0..85 and phi_o 0..360 in this step
  int phi_i = -1;             // ASTM / CSV incident azimuths over [0, 360); < 0: 1, or 8 for anisotropic sources
  bool anisotropic = false;
};

// A model source f (spec and parameter text as the user gave them): what
// the sidecar records about it (model, params, anisotropic by
// IsAnisotropic), and options.anisotropic set when it is.
nlohmann::json ModelSource(const BrdfFunction& f, const std::string& spec, const std::string& params,
                           ConvertOptions& options);

// The RGL options WriteFormat writes with: rgl.phi_i < 0 resolved (0 for an
// isotropic source, RglAnisotropicSlices(symmetry) for an anisotropic one)
// and the automatic resolutions filled in (WithDefaults).
RglOptions RglTarget(const ConvertOptions& options);

// Tabulates f into `path` (format by its extension), atomically. Returns
// what the sidecar records about the target: its path, format and
// resolution, and a "warning" when the format cannot hold the source
// (anisotropy in MERL).
nlohmann::json WriteFormat(const std::string& path, const BrdfFunction& f, const ConvertOptions& options);

}  // namespace brdfkit::formats
