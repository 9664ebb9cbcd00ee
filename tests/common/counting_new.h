// Replaces the global operator new with a counting one, so a test can prove a code path
// allocates nothing. Include in exactly one source file of a test binary. Under the sanitizers
// the runtime owns operator new: nothing is replaced and tests should GTEST_SKIP.
#pragma once

#include <atomic>
#include <cstdlib>
#include <new>

namespace vcsim::test {
inline std::atomic<long> g_allocations{0};
}  // namespace vcsim::test

#ifndef VCSIM_SANITIZE
[[gnu::noinline]] void* operator new(std::size_t n) {
  vcsim::test::g_allocations.fetch_add(1, std::memory_order_relaxed);
  if (void* p = std::malloc(n ? n : 1)) return p;
  throw std::bad_alloc();
}
// noinline throughout: once inlined, GCC sees malloc'd memory meet operator delete and warns
// of a mismatch (-Wmismatched-new-delete).
[[gnu::noinline]] void operator delete(void* p) noexcept {
  std::free(p);
}
[[gnu::noinline]] void operator delete(void* p, std::size_t) noexcept {
  std::free(p);
}
// The array forms too, so that every allocation of the binary goes through the counter.
[[gnu::noinline]] void* operator new[](std::size_t n) {
  return ::operator new(n);
}
[[gnu::noinline]] void operator delete[](void* p) noexcept {
  std::free(p);
}
[[gnu::noinline]] void operator delete[](void* p, std::size_t) noexcept {
  std::free(p);
}
#endif
