// Google Benchmark: the full instrument step of the paper's compression experiment (256 nodes,
// one global iteration, collisions and friction on) in its pushed, compressed state.
#include <benchmark/benchmark.h>

#include "vcsim/experiments.h"

namespace {

using namespace vcsim;

void BM_CompressionStep(benchmark::State& state) {
  CompressionOptions o;
  CompressionScene sc =
      make_compression_scene(o, DistanceMethod::kGlobal, static_cast<int>(state.range(0)));
  StaticWall wall = sc.wall();
  DriveCommand cmd{DriveCommand::Mode::kPosition, o.end_depth, 0.0};
  // Push to the end depth first: the benchmark times the loaded rod against the bend.
  const int push_steps =
      static_cast<int>((o.end_depth - o.start_depth) / o.push_speed / sc.settings.rod.dt) + 200;
  for (int k = 0; k < push_steps; ++k) {
    cmd.translation =
        std::min(o.end_depth, o.start_depth + o.push_speed * (k + 1) * sc.settings.rod.dt);
    instrument_step(sc.inst, &wall, sc.settings, cmd);
  }
  StepProfile prof;
  for (auto _ : state) {
    instrument_step(sc.inst, &wall, sc.settings, cmd, &prof);
    benchmark::DoNotOptimize(sc.inst.state.x.data());
  }
  state.counters["contacts"] = prof.num_contacts;
  state.counters["queries"] = prof.num_queries;
}
BENCHMARK(BM_CompressionStep)->Arg(1)->Arg(5)->Unit(benchmark::kMicrosecond);

}  // namespace
