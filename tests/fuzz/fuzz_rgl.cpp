// libFuzzer target: the RGL tensor-file reader (brdf/rgl.h, RglBsdf::Read)
// and its reconstruction. A file read successfully evaluates finite and
// non-negative everywhere; a failure names the file.
#include <cmath>
#include <stdexcept>

#include "brdf/rgl.h"
#include "fuzz_util.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size > (1u << 20)) return 0;
  const std::string path = brdfkit::fuzz::ScratchPath("input.bsdf");
  brdfkit::fuzz::WriteBytes(path, data, size);
  brdfkit::RglBsdf b;
  try {
    b = brdfkit::RglBsdf::Read(path);
  } catch (const std::runtime_error& e) {
    if (std::string(e.what()).find(path) == std::string::npos) brdfkit::fuzz::Broken("message without the file name");
    return 0;
  }
  const Eigen::Vector3d dirs[] = {{0, 0, 1}, {0.6, 0, 0.8}, {-0.6, 0, 0.8}, {1, 0, 1e-12}, {0, 0.8, 0.6}};
  for (const auto& wi : dirs)
    for (const auto& wo : dirs) {
      const auto f = b.Fr(wi, wo);
      for (int c = 0; c < 3; ++c)
        if (!std::isfinite(f[c]) || f[c] < 0) brdfkit::fuzz::Broken("non-finite or negative reconstruction");
    }
  if (b.n_sample * b.m_sample * b.theta_i.size() < 4096)
    for (const auto& n : b.NodeSamples())
      for (int c = 0; c < 3; ++c)
        if (!std::isfinite(n.f[c])) brdfkit::fuzz::Broken("non-finite node sample");
  return 0;
}
