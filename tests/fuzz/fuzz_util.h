// Shared by the libFuzzer targets: the input as a file (the readers take
// paths, as users give them), and a trap for broken invariants.
#pragma once

#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>

#include "tests/scratch.h"

namespace brdfkit::fuzz {

// A per-process scratch file under the temporary folder.
inline std::string ScratchPath(const char* name) {
  return test::ScratchPath(name).string();
}

inline void WriteBytes(const std::string& path, const std::uint8_t* data, std::size_t size) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
}

// An invariant the reader promises does not hold: report and crash so the
// fuzzer saves the input.
[[noreturn]] inline void Broken(const std::string& what) {
  std::fprintf(stderr, "invariant broken: %s\n", what.c_str());
  std::abort();
}

}  // namespace brdfkit::fuzz
