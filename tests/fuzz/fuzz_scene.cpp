// libFuzzer target: the scene parser (cli/scene.h). Any text either parses
// or throws std::runtime_error naming the scene; relative paths resolve in
// a scratch folder.
#include <stdexcept>

#include "cli/scene.h"
#include "fuzz_util.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  try {
    (void)brdfkit::cli::ParseScene(text, "fuzz-scene.json", brdfkit::fuzz::ScratchPath("scene"));
  } catch (const std::runtime_error& e) {
    if (std::string(e.what()).find("fuzz-scene.json") == std::string::npos)
      brdfkit::fuzz::Broken(std::string("message without the scene name: ") + e.what());
  }
  return 0;
}
