// The beating lumen's per-step update and query allocate nothing once warm (they run inside the
// physics step).
#include <gtest/gtest.h>

#include "vcsim/anatomy.h"

#include "counting_new.h"

using vcsim::test::g_allocations;

namespace vcsim {
namespace {

TEST(AnatomyAllocation, BeatingUpdateAndQueryAllocateNothingOnceWarm) {
#ifdef VCSIM_SANITIZE
  GTEST_SKIP() << "the sanitizer runtime owns operator new";
#endif
  // The first 40 mm of the default LAD on its heart: small, and all of it moves.
  const VesselTree full = default_patient();
  VesselTree t;
  t.name = "lad-only";
  t.heart = full.heart;
  VesselSegment s = full.segments[full.find("lad")];
  s.parent = -1;
  while (segment_length(s) > 40e-3) {
    s.points.pop_back();
    s.radii.pop_back();
  }
  t.segments = {s};
  t.open_start = true;
  t.access = {0, 0.0};
  t.target = {0, 20e-3};
  LumenSettings ls;
  ls.use_cache = false;
  const Lumen lu = build_lumen(t, ls);
  // The LAD's root is no aortic valve here; its first point holds still instead.
  const CardiacMotion mo(t, MotionSettings{});
  BeatingLumen bl(lu.mesh, mo);
  std::vector<Vec3> nodes;
  for (double x = 20e-3; x < 38e-3; x += 2e-3) nodes.push_back(point_at(t.segments[0], x));
  const std::vector<double> radii{1.0e-3};
  std::vector<SphereContact> out(nodes.size());
  bl.update(0.0, nodes, radii);
  bl.query_spheres(nodes, radii, out);  // warm

  const long before = g_allocations;
  int updated = 0;
  for (int step = 1; step <= 200; ++step) {
    updated += bl.update(step * 1e-3, nodes, radii).patches_updated;
    bl.query_spheres(nodes, radii, out);
  }
  EXPECT_EQ(g_allocations, before);
  EXPECT_GT(updated, 200);  // the test exercised real updates
}

}  // namespace
}  // namespace vcsim
