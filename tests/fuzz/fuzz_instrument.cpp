// libFuzzer target: the instrument parser (data_synth/instrument.h). Any
// JSON text either parses to an instrument or throws std::runtime_error
// naming the file; a parsed instrument round-trips through InstrumentToJson.
#include <nlohmann/json.hpp>

#include <stdexcept>

#include "data_synth/instrument.h"
#include "fuzz_util.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace brdfkit::synth;
  const nlohmann::json j = nlohmann::json::parse(data, data + size, nullptr, /*allow_exceptions=*/false);
  if (j.is_discarded()) return 0;
  Instrument inst;
  try {
    inst = ParseInstrument(j, "fuzz.json", brdfkit::fuzz::ScratchPath(""));
  } catch (const std::runtime_error& e) {
    if (std::string(e.what()).find("fuzz.json") == std::string::npos)
      brdfkit::fuzz::Broken(std::string("message without the file name: ") + e.what());
    return 0;
  }
  const nlohmann::json out = InstrumentToJson(inst);
  Instrument again;
  try {
    again = ParseInstrument(out, "round trip");
  } catch (const std::exception& e) {
    brdfkit::fuzz::Broken(std::string("written instrument does not read back: ") + e.what());
  }
  if (InstrumentToJson(again) != out) brdfkit::fuzz::Broken("round trip changed the instrument");
  return 0;
}
