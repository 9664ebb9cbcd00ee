// The engine's parallel regions under ThreadSanitizer. TBB (Debian's libtbb) is not built with
// TSan, so TSan cannot see a task handed to a worker thread (nor the join) and reports every
// access in a task body as a race with the spawning thread. Under TSan the regions run their
// chunks on std::threads instead (the same bodies over the same chunks; thread creation and join
// are what TSan sees), so that what it reports is a race between chunks: two tasks touching the
// same data, the kind the engine must not have. At most tbb::this_task_arena::max_concurrency()
// threads, so a ThreadLimit still holds. Internal (src/core); only compiled under TSan.
#pragma once

#if defined(__SANITIZE_THREAD__)
#include <tbb/task_arena.h>

#include <algorithm>
#include <cstddef>
#include <thread>
#include <vector>

namespace vcsim::internal {

// body(b, e) for the ranges [c grain, min((c + 1) grain, n)) of [0, n), on up to max_concurrency
// threads, the caller's among them.
template <class F>
void tsan_chunks(std::size_t n, std::size_t grain, F&& body) {
  const std::size_t chunks = (n + grain - 1) / grain;
  const std::size_t threads = std::min<std::size_t>(
      chunks, static_cast<std::size_t>(std::max(1, tbb::this_task_arena::max_concurrency())));
  auto share = [&](std::size_t t) {
    for (std::size_t c = t; c < chunks; c += threads) body(c * grain, std::min(n, (c + 1) * grain));
  };
  std::vector<std::thread> pool;
  for (std::size_t t = 1; t < threads; ++t) pool.emplace_back(share, t);
  share(0);
  for (std::thread& th : pool) th.join();
}

}  // namespace vcsim::internal
#endif
