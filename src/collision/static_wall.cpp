// A lumen that does not move as the instruments' wall: its AABB tree's sphere queries, split over
// the TBB threads for a large batch.
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>

#include "tsan_tasks.h"
#include "vcsim/collision.h"

namespace vcsim {

void StaticWall::query_spheres(std::span<const Vec3> centres, std::span<const double> radii,
                               std::span<SphereContact> out) {
  tree_->query_spheres(*mesh_, centres, radii, out);
}

void StaticWall::query_spheres(std::span<const Vec3> centres, std::span<const double> radii,
                               std::span<LeafCache* const> caches, double slack,
                               std::span<SphereContact> out) {
  auto run = [&](std::size_t b, std::size_t e) {
    for (std::size_t i = b; i < e; ++i)
      out[i] = tree_->query_sphere(*mesh_, centres[i], radii[i], slack, *caches[i]);
  };
  const auto n = static_cast<int>(centres.size());
  const int chunks = std::min(tbb::this_task_arena::max_concurrency(), n / kParallelChunk);
  if (parallel_min_ <= 0 || n < parallel_min_ || chunks < 2) {
    run(0, centres.size());
    return;
  }
  // One chunk per thread: about 0.6 us per query, so finer chunks would cost more to hand out.
  const auto grain = static_cast<std::size_t>((n + chunks - 1) / chunks);
#if defined(__SANITIZE_THREAD__)
  internal::tsan_chunks(centres.size(), grain, run);
#else
  tbb::parallel_for(
      tbb::blocked_range<std::size_t>(0, centres.size(), grain),
      [&](const tbb::blocked_range<std::size_t>& r) { run(r.begin(), r.end()); },
      tbb::static_partitioner());
#endif
}

}  // namespace vcsim
