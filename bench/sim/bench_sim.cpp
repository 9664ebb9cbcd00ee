// Google Benchmark: the whole scene. A snapshot of the default scenario's state (a copy of its
// SimState) and a restore of it into a running simulator, with the snapshot's size; the scene
// taken 3 s into the procedure by its autopilot (the J wire and the catheter in the iliac
// arteries; a state's size does not change during a run).
#include <benchmark/benchmark.h>

#include <memory>

#include "vcsim/sim.h"

namespace {

using namespace vcsim;

// The default scenario run by its autopilot to `seconds`, built once per benchmark program.
struct Scene {
  std::unique_ptr<Simulator> sim;
  explicit Scene(double seconds) {
    sim = std::make_unique<Simulator>(load_scenario(default_scenarios_dir() / "default.json"));
    Autopilot pilot(*sim);
    StepCommands cmds;
    while (sim->time() < seconds) {
      pilot.command(*sim, cmds);
      sim->step(cmds);
    }
  }
};

Scene& scene() {
  static Scene s(3.0);
  return s;
}

void BM_Snapshot(benchmark::State& state) {
  Simulator& sim = *scene().sim;
  SimState snap = sim.snapshot();
  for (auto _ : state) {
    snap = sim.state();  // into a snapshot's storage, as a rewind buffer reuses it
    benchmark::DoNotOptimize(snap.solver.instruments.data());
  }
  state.counters["bytes"] = static_cast<double>(snap.bytes());
}
BENCHMARK(BM_Snapshot)->Unit(benchmark::kMicrosecond);

void BM_SnapshotNew(benchmark::State& state) {
  Simulator& sim = *scene().sim;
  for (auto _ : state) {
    SimState snap = sim.snapshot();  // a fresh copy: allocates its arrays
    benchmark::DoNotOptimize(snap.solver.instruments.data());
  }
}
BENCHMARK(BM_SnapshotNew)->Unit(benchmark::kMicrosecond);

void BM_Restore(benchmark::State& state) {
  Simulator& sim = *scene().sim;
  const SimState snap = sim.snapshot();
  for (auto _ : state) {
    sim.restore(snap);
    benchmark::DoNotOptimize(sim.state().solver.instruments.data());
  }
  state.counters["bytes"] = static_cast<double>(snap.bytes());
}
BENCHMARK(BM_Restore)->Unit(benchmark::kMicrosecond);

void BM_StateHash(benchmark::State& state) {
  Simulator& sim = *scene().sim;
  for (auto _ : state) benchmark::DoNotOptimize(sim.state().hash());
}
BENCHMARK(BM_StateHash)->Unit(benchmark::kMicrosecond);

}  // namespace

BENCHMARK_MAIN();
