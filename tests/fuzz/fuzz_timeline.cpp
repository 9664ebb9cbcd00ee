// libFuzzer target: the scripted timeline (ScriptedTimeline::parse).
#include "fuzz_common.h"
#include "vcsim/haptics.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  vcsim::fuzz::expect_only_input_errors(
      [&] { vcsim::ScriptedTimeline::parse(vcsim::fuzz::text(data, size), "fuzz.json"); });
  return 0;
}
