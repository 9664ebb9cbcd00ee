// A warm rod step allocates nothing on the heap (counted by replacing the global operator new).
#include <gtest/gtest.h>

#include <atomic>
#include <cstdlib>
#include <new>

#include "vcsim/rod.h"

#include "counting_new.h"

using vcsim::test::g_allocations;

using namespace vcsim;

#ifndef VCSIM_SANITIZE
namespace {

// A warm step of a bent 256-node rod with these settings allocates nothing (its first step may
// size what it needs).
void expect_warm_step_allocates_nothing(RodSettings s, bool stable_dt, const char* what) {
  RodDef d;
  d.segments = 255;
  d.tip_shape = {TipSection::arc(3e-3, 3.0)};
  d.base_orientation = Quat::FromTwoVectors(Vec3::UnitZ(), Vec3::UnitX());
  const RodModel md = build_rod(d);
  RodState st = make_state(md, d);
  RodWorkspace ws;
  ws.resize(md);
  s.gravity = Vec3(0, 0, -9.81);
  if (stable_dt) s.dt = estimate_stable_dt(md, s);
  RodProfile prof;
  rod_step(md, s, st, ws, &prof);  // warm
  const long before = g_allocations.load();
  for (int k = 0; k < 100; ++k) rod_step(md, s, st, ws, &prof);
  EXPECT_EQ(g_allocations.load() - before, 0) << what;
  EXPECT_TRUE(st.x.back().allFinite()) << what;
  // The counter works: a vector allocates.
  std::vector<double>* probe = new std::vector<double>(10);
  EXPECT_GT(g_allocations.load() - before, 0);
  delete probe;
}

}  // namespace
#endif

TEST(RodNoAlloc, WarmStepAllocatesNothing) {
#ifdef VCSIM_SANITIZE
  GTEST_SKIP() << "the sanitizer runtime owns operator new";
#else
  for (auto method : {DistanceMethod::kGlobal, DistanceMethod::kLocalGS,
                      DistanceMethod::kLocalJacobi, DistanceMethod::kPenalty}) {
    RodSettings s;
    s.distance = method;
    s.iterations = 3;
    s.internal_damping = 1e-7;
    s.drag = 1.0;
    s.angular_drag = 1.0;
    expect_warm_step_allocates_nothing(s, true, to_string(method));
  }
  // The linearly implicit step sizes its blocks on its first step.
  RodSettings s;
  s.integrator = Integrator::kLinearlyImplicit;
  s.dt = 0.5e-3;
  expect_warm_step_allocates_nothing(s, false, "linearly implicit");
#endif
}
