// Files written by a synthetic measurement, all atomically:
//  - .csv    the BRDF table (table_io.h), measured pairs only, with sigma
//            columns when the sensor noise model is on;
//  - .binary the MERL file (brdf/merl.h), MERL plans only; cells not
//            measured (below the horizon, or skipped by a stride) are -1;
//  - .exr    an OpenEXR float32 image of the data for grid plans, channels
//            R, G, B (f in 1/sr), A (1 measured, 0 not) and sigma.R,
//            sigma.G, sigma.B; the header attribute "brdfkit.layout" says what
//            rows and columns are;
// and beside each, FILE.json: instrument, model, parameters, seed and
// version, enough to regenerate the data set bit for bit.
#pragma once

#include <nlohmann/json.hpp>

#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "data_synth/synth.h"
#include "data_synth/table_io.h"

namespace brdfkit::synth {

BrdfTable ToTable(const SynthResult& result);

struct Provenance {
  std::string model;              // model specification, e.g. "lambert+ggx"
  std::vector<double> params;     // packed parameter values
  std::string params_text;        // the same as name=value text
  std::uint64_t seed = 0;
  std::string command;            // how it was made (the command line), may be empty
};

nlohmann::json Sidecar(const Instrument& inst, const SynthResult& result, const Provenance& prov);

void WriteMerlFile(const std::string& path, const SynthResult& result);

// Float32 OpenEXR with the channels named in `planes` (each width*height
// values, row-major, top row first) and string attributes.
void WriteExrFloat(const std::string& path, int width, int height,
                   const std::vector<std::pair<std::string, const float*>>& planes,
                   const std::map<std::string, std::string>& attributes);
// Reads every float or half channel of an OpenEXR file.
struct ExrImage {
  int width = 0, height = 0;
  std::map<std::string, std::vector<float>> channels;
  std::map<std::string, std::string> attributes;  // string attributes only
};
ExrImage ReadExrFloat(const std::string& path);

void WriteExrTable(const std::string& path, const SynthResult& result);

// Writes `path` in the format its extension names (.csv, .binary, .exr) and
// path + ".json". Throws std::runtime_error for an unknown extension or a
// format the plan cannot fill.
void WriteSynthOutput(const std::string& path, const Instrument& inst, const SynthResult& result,
                      const Provenance& prov);

}  // namespace brdfkit::synth
