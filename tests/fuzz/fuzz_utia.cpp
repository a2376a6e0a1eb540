// libFuzzer target: the UTIA reader (brdf/utia.h). Input byte 0 chooses the
// file: even, the remaining bytes as they are (size checks); odd, the
// remaining bytes at the start of a zero-filled file of the exact UTIA size
// (value checks, lookups).
#include <cmath>
#include <stdexcept>

#include "brdf/utia.h"
#include "fuzz_util.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using brdfkit::UtiaTable;
  if (size == 0) return 0;
  const std::string path = brdfkit::fuzz::ScratchPath("input.utia");
  brdfkit::fuzz::WriteBytes(path, data + 1, std::min<std::size_t>(size - 1, UtiaTable::kFileSize));
  if (data[0] & 1) std::filesystem::resize_file(path, UtiaTable::kFileSize);
  UtiaTable t;
  try {
    t = UtiaTable::Read(path);
  } catch (const std::runtime_error& e) {
    if (std::string(e.what()).find(path) == std::string::npos) brdfkit::fuzz::Broken("message without the file name");
    return 0;
  }
  const Eigen::Vector3d dirs[] = {{0, 0, 1}, {0.6, 0, 0.8}, {-0.6, -1e-17, 0.8}, {1, 0, 1e-12}, {0, 0.8, 0.6}};
  for (const auto& wi : dirs)
    for (const auto& wo : dirs) {
      const auto f = t.Lookup(wi, wo);
      for (int c = 0; c < 3; ++c)
        if (!std::isfinite(f[c]) || f[c] < 0) brdfkit::fuzz::Broken("non-finite or negative lookup");
    }
  return 0;
}
