// libFuzzer target: SimVascular .pth centrelines (parse_pth_paths).
#include <string>
#include "fuzz_common.h"
#include "vcsim/anatomy.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  vcsim::fuzz::expect_only_input_errors(
      [&] { vcsim::parse_pth_paths(std::string(vcsim::fuzz::text(data, size)), "fuzz.pth"); });
  return 0;
}
