// libFuzzer target: a catalogue entry (parse_instrument).
#include "fuzz_common.h"
#include "vcsim/instruments.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  vcsim::fuzz::expect_only_input_errors(
      [&] { vcsim::parse_instrument(vcsim::fuzz::text(data, size), "fuzz.json", "fuzz"); });
  return 0;
}
