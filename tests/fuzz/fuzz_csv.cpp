// libFuzzer target: the BRDF table reader (data_synth/table_io.h). A table
// that reads without error holds finite values, round-trips through the
// writer, and reads back to the same rows.
#include <cmath>
#include <stdexcept>

#include "data_synth/table_io.h"
#include "fuzz_util.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace brdfkit::synth;
  const std::string path = brdfkit::fuzz::ScratchPath("input.csv");
  brdfkit::fuzz::WriteBytes(path, data, size);
  BrdfTable t;
  try {
    t = ReadTableCsv(path);
  } catch (const std::runtime_error& e) {
    if (std::string(e.what()).find(path) == std::string::npos) brdfkit::fuzz::Broken("message without the file name");
    return 0;
  }
  for (const BrdfSample& r : t.rows) {
    if (!std::isfinite(r.theta_i) || !std::isfinite(r.phi_i) || !std::isfinite(r.theta_o) || !std::isfinite(r.phi_o) ||
        !r.f.allFinite() || !r.sigma.allFinite())
      brdfkit::fuzz::Broken("non-finite value accepted");
  }
  const std::string back = brdfkit::fuzz::ScratchPath("back.csv");
  WriteTableCsv(back, t);
  const BrdfTable u = ReadTableCsv(back);
  if (u.rows.size() != t.rows.size() || u.has_sigma != t.has_sigma) brdfkit::fuzz::Broken("round trip changed the table");
  for (std::size_t k = 0; k < t.rows.size(); ++k)
    if (u.rows[k].theta_i != t.rows[k].theta_i || u.rows[k].phi_o != t.rows[k].phi_o ||
        (u.rows[k].f != t.rows[k].f).any() || (u.rows[k].sigma != t.rows[k].sigma).any())
      brdfkit::fuzz::Broken("round trip changed row " + std::to_string(k));
  return 0;
}
