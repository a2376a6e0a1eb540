// libFuzzer target: the MERL binary reader (brdf/merl.h, MerlTable::Read).
// Input byte 0 chooses the file: even, the remaining bytes as they are (header
// and size checks); odd, the remaining bytes at the start of a file of the
// exact MERL size, zero-filled (value checks, scaling, lookups).
#include <cmath>
#include <stdexcept>

#include "brdf/merl.h"
#include "fuzz_util.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using brdfkit::MerlTable;
  if (size == 0) return 0;
  const std::string path = brdfkit::fuzz::ScratchPath("input.binary");
  brdfkit::fuzz::WriteBytes(path, data + 1, std::min<std::size_t>(size - 1, MerlTable::kFileSize));
  if (data[0] & 1) std::filesystem::resize_file(path, MerlTable::kFileSize);
  MerlTable t;
  try {
    t = MerlTable::Read(path);
  } catch (const std::runtime_error& e) {
    if (std::string(e.what()).find(path) == std::string::npos) brdfkit::fuzz::Broken("message without the file name");
    return 0;
  }
  // A table read successfully holds finite values only; lookups stay finite.
  for (double v : t.values)
    if (!std::isfinite(v)) brdfkit::fuzz::Broken("non-finite value accepted");
  (void)t.MissingCount();
  const Eigen::Vector3d dirs[] = {{0, 0, 1}, {0.6, 0, 0.8}, {-0.6, 0, 0.8}, {1, 0, 1e-12}, {0, 0.8, 0.6}};
  for (const auto& wi : dirs)
    for (const auto& wo : dirs)
      for (bool tri : {false, true}) {
        const auto f = t.Lookup(wi, wo, tri);
        for (int c = 0; c < 3; ++c)
          if (!std::isfinite(f[c])) brdfkit::fuzz::Broken("non-finite lookup");
      }
  return 0;
}
