// libFuzzer target: the scenario format (parse_scenario).
#include "fuzz_common.h"
#include "vcsim/sim.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  vcsim::fuzz::expect_only_input_errors(
      [&] { vcsim::parse_scenario(vcsim::fuzz::text(data, size), "fuzz.json"); });
  return 0;
}
