// Google Benchmark: the full instrument step of the paper's compression experiment (256 nodes,
// one global iteration, collisions and friction on), over the experiment as `vcsim bench
// compression` runs it, and in its pushed, compressed state.
#include <benchmark/benchmark.h>

#include <optional>

#include "vcsim/experiments.h"

namespace {

using namespace vcsim;

void BM_CompressionStep(benchmark::State& state) {
  CompressionOptions o;
  CompressionScene sc =
      make_compression_scene(o, DistanceMethod::kGlobal, static_cast<int>(state.range(0)));
  StaticWall wall = sc.wall();
  SolverWorkspace ws(sc.model);
  const double dt = sc.model.dt();
  DriveCommand cmd{DriveCommand::Mode::kPosition, o.end_depth, 0.0};
  const std::span<const DriveCommand> cmds(&cmd, 1);
  // Push to the end depth first: the benchmark times the loaded rod against the bend.
  const auto push_steps =
      static_cast<long long>((o.end_depth - o.start_depth) / o.push_speed / dt) + 200;
  for (long long k = 1; k <= push_steps; ++k) {
    cmd.translation = compression_depth(o, k, dt);
    solver_step(sc.model, sc.state, ws, &wall, cmds);
  }
  StepProfile prof;
  for (auto _ : state) {
    solver_step(sc.model, sc.state, ws, &wall, cmds, &prof);
    benchmark::DoNotOptimize(sc.state.instruments[0].rod.x.data());
  }
  state.counters["contacts"] = prof.num_contacts;
  state.counters["queries"] = prof.num_queries;
}
BENCHMARK(BM_CompressionStep)->Arg(1)->Arg(5)->Unit(benchmark::kMicrosecond);

// The experiment itself: each iteration is the next step of the push and the settling, and the
// experiment starts again when it ends. The mean over its steps (the CLI reports the median).
void BM_CompressionExperimentStep(benchmark::State& state) {
  const CompressionOptions o;
  const auto iterations = static_cast<int>(state.range(0));
  std::optional<CompressionScene> sc;
  std::optional<StaticWall> wall;
  std::optional<SolverWorkspace> ws;
  const auto start = [&] {
    sc.emplace(make_compression_scene(o, DistanceMethod::kGlobal, iterations));
    wall.emplace(sc->wall());
    ws.emplace(sc->model);
  };
  start();
  const double dt = sc->model.dt();
  const long long steps = compression_steps(o, dt);
  DriveCommand cmd{DriveCommand::Mode::kPosition, o.start_depth, 0.0};
  long long k = 0;
  for (auto _ : state) {
    if (k == steps) {
      state.PauseTiming();
      start();
      k = 0;
      state.ResumeTiming();
    }
    ++k;
    cmd.translation = compression_depth(o, k, dt);
    solver_step(sc->model, sc->state, *ws, &*wall, std::span<const DriveCommand>(&cmd, 1));
    benchmark::DoNotOptimize(sc->state.instruments[0].rod.x.data());
  }
  state.counters["steps_per_experiment"] = static_cast<double>(steps);
}
BENCHMARK(BM_CompressionExperimentStep)->Arg(1)->Unit(benchmark::kMicrosecond);

}  // namespace
