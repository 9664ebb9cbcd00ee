// Google Benchmark: one rod step (forces, integration, one global distance iteration, no
// contacts), explicit and linearly implicit, and the distance solve alone, for 64 .. 1024 nodes.
// Time per step is linear in N.
#include <benchmark/benchmark.h>

#include "distance.h"
#include "vcsim/rod.h"

namespace {

using namespace vcsim;

struct Rig {
  RodModel md;
  RodState st;
  RodSettings s;
  RodWorkspace ws;
  explicit Rig(int nodes, Integrator integrator = Integrator::kSymplecticEuler) {
    RodDef d;
    d.length = 0.255;
    d.segments = nodes - 1;
    d.outer_radius = 0.445e-3;
    d.youngs_modulus = 40e9;
    d.density = 6450;
    d.base_orientation = Quat::FromTwoVectors(Vec3::UnitZ(), Vec3::UnitX());
    md = build_rod(d);
    st = make_state(md, d);
    s.gravity = Vec3(0, 0, -9.81);
    s.integrator = integrator;
    // The explicit step at its stability limit; the implicit one at the scenarios' 0.5 ms, with
    // the physical mass (some 2000 times the explicit limit here).
    s.dt = integrator == Integrator::kSymplecticEuler ? estimate_stable_dt(md, s) : 0.5e-3;
    ws.resize(md);
    for (int k = 0; k < 2000; ++k) rod_step(md, s, st, ws);  // a bent, moving rod
  }
};

// One rod step with the given integrator; the implicit one (physics.md 5.5) adds the Hessian
// blocks and the block-tridiagonal solve to the same distance iteration and positions.
void rod_step_bench(benchmark::State& state, Integrator integrator) {
  Rig rig(static_cast<int>(state.range(0)), integrator);
  for (auto _ : state) {
    rod_step(rig.md, rig.s, rig.st, rig.ws);
    benchmark::DoNotOptimize(rig.st.x.data());
  }
  state.SetComplexityN(state.range(0));
  state.counters["nodes"] = static_cast<double>(state.range(0));
}
void BM_RodStep(benchmark::State& state) {
  rod_step_bench(state, Integrator::kSymplecticEuler);
}
BENCHMARK(BM_RodStep)->RangeMultiplier(2)->Range(64, 1024)->Complexity(benchmark::oN);
void BM_RodStepImplicit(benchmark::State& state) {
  rod_step_bench(state, Integrator::kLinearlyImplicit);
}
BENCHMARK(BM_RodStepImplicit)->RangeMultiplier(2)->Range(64, 1024)->Complexity(benchmark::oN);

void BM_GlobalDistanceSolve(benchmark::State& state) {
  Rig rig(static_cast<int>(state.range(0)));
  rod_begin_step(rig.md, rig.ws);
  for (auto _ : state) {
    internal::distance_global(rig.md, rig.s.dt, rig.st.x, rig.st.v, rig.ws);
    benchmark::DoNotOptimize(rig.st.v.data());
  }
  state.SetComplexityN(state.range(0));
}
BENCHMARK(BM_GlobalDistanceSolve)->RangeMultiplier(2)->Range(64, 1024)->Complexity(benchmark::oN);

}  // namespace
