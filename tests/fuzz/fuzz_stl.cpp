// libFuzzer target: a .stl mesh (load_mesh_bytes: vcsim's checks, then assimp, then
// check_and_repair).
#include <span>
#include "fuzz_common.h"
#include "vcsim/mesh_io.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  vcsim::fuzz::expect_only_input_errors([&] {
    vcsim::load_mesh_bytes(std::span<const char>(reinterpret_cast<const char*>(data), size), "stl",
                           "fuzz.stl");
  });
  return 0;
}
