// What every fuzz target asserts: a parser given any bytes returns or throws InputError (the
// error that names the file and field and exits 2). Any other exception escaping, a crash, a
// sanitizer report, a hang (-timeout) or memory beyond -rss_limit_mb is a finding.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string_view>

#include "vcsim/core.h"

namespace vcsim::fuzz {

inline std::string_view text(const std::uint8_t* data, std::size_t size) {
  return {reinterpret_cast<const char*>(data), size};
}

template <typename F>
void expect_only_input_errors(F&& parse) {
  try {
    parse();
  } catch (const InputError&) {
  }
}

}  // namespace vcsim::fuzz
