// libFuzzer target: the ASTM E1392 reader (brdf/astm.h) and the sample
// lookup over what it read.
#include <cmath>
#include <stdexcept>

#include "brdf/astm.h"
#include "fuzz_util.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size > (1u << 16)) return 0;
  const std::string path = brdfkit::fuzz::ScratchPath("input.astm");
  brdfkit::fuzz::WriteBytes(path, data, size);
  brdfkit::AstmTable t;
  try {
    t = brdfkit::AstmTable::Read(path);
  } catch (const std::runtime_error& e) {
    if (std::string(e.what()).find(path) == std::string::npos) brdfkit::fuzz::Broken("message without the file name");
    return 0;
  }
  for (const auto& r : t.rows)
    if (!std::isfinite(r.theta_i + r.phi_i + r.theta_o + r.phi_o) || !r.f.isFinite().all())
      brdfkit::fuzz::Broken("non-finite value accepted");
  if (t.rows.empty()) return 0;
  const brdfkit::SampleCloud cloud(t.rows);
  const Eigen::Vector3d dirs[] = {{0, 0, 1}, {0.6, 0, 0.8}, {0, 0.8, 0.6}};
  for (const auto& wi : dirs)
    for (const auto& wo : dirs)
      for (int k : {1, 8})
        if (!cloud.Lookup(wi, wo, k).isFinite().all()) brdfkit::fuzz::Broken("non-finite lookup");
  return 0;
}
