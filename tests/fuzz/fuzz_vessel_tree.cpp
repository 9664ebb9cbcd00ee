// libFuzzer target: the vessel tree format (parse_vessel_tree), with validate_tree and its limits.
#include "fuzz_common.h"
#include "vcsim/anatomy.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  vcsim::fuzz::expect_only_input_errors(
      [&] { vcsim::parse_vessel_tree(vcsim::fuzz::text(data, size), "fuzz.json"); });
  return 0;
}
