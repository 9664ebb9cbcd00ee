// Google Benchmark: the whole scene. A snapshot of the default scenario's state (a copy of its
// SimState) and a restore of it into a running simulator, with the snapshot's size; the scene
// taken 3 s into the procedure by its autopilot (the J wire and the catheter in the iliac
// arteries; a state's size does not change during a run).
//
// The procedure's cost per step (issue 25: a balloon or stent adds at most 15 us to a step), side
// by side in one tube scene (a 0.014" wire and a balloon catheter or stent system over it, its
// balloon across a 60 % lesion, as tests/sim/balloon_scene.h builds it): BM_TubeStep/deflated,
// /inflated (8 atm, held in the lesion it opened) and /stent (the stent system's stent deployed
// in the wall and its balloon deflated inside it). Counters: procedure_us, the procedure stage
// (pressures, fit, holds, the wall brought to the lesions, after-step) per step; step_us, the
// whole step.
//
// An instrument exchange in the default scene (3 s in, the same scene): BM_Exchange adds a 0.014"
// wire in the guide and removes it again, two exchanges per iteration (each a model rebuild of
// the instruments around the shared anatomy, the state carried over, the wall taken over);
// BM_RebuildModel times the model rebuild alone.
//
// The real workload (issue 30): BM_ProcedureStep/<moment> restores the default run at a moment of
// its procedure and steps the next 0.1 s with the commands its autopilot gave there (recorded
// once per program, run at the scenario's dt with its sub-steps): 0 the arch (3 s: the J wire
// and the guide on their way up), 1 the engagement (11.5 s: the guide seated in the left main),
// 2 the wire in the LAD (35 s: crossing the lesion), 3 the stent inflated in the lesion (62 s).
// Counters: step_us per step, and the stages' means (us per step) from the Simulator's profile.
#include <benchmark/benchmark.h>

#include <array>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "../../tests/sim/balloon_scene.h"
#include "vcsim/sim.h"
#include "vcsim/units.h"

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

InstrumentChange wire_change(InstrumentChange::Kind kind) {
  InstrumentChange c;
  c.kind = kind;
  c.name = "wire2";
  c.catalogue = "wire-014-floppy";
  c.inside = "catheter";
  c.rim = false;
  c.tip_segment = 2e-3;
  return c;
}

void BM_Exchange(benchmark::State& state) {
  static Scene s(3.0);
  Simulator& sim = *s.sim;
  const InstrumentChange add = wire_change(InstrumentChange::Kind::kAdd);
  const InstrumentChange remove = wire_change(InstrumentChange::Kind::kRemove);
  for (auto _ : state) {
    sim.exchange(add);
    sim.exchange(remove);
  }
  state.SetItemsProcessed(2 * state.iterations());  // exchanges
  state.counters["instruments"] = sim.num_instruments() + 1;
}
BENCHMARK(BM_Exchange)->Unit(benchmark::kMillisecond);

void BM_RebuildModel(benchmark::State& state) {
  static Scene s(3.0);
  const SimModel& md = s.sim->model();
  std::vector<ScenarioInstrument> list = md.scenario.instruments;
  list.push_back(to_scenario_instrument(wire_change(InstrumentChange::Kind::kAdd)));
  for (auto _ : state) {
    auto m = rebuild_sim_model(md, list, "bench", [](int) { return std::string("instruments"); });
    benchmark::DoNotOptimize(m.get());
  }
}
BENCHMARK(BM_RebuildModel)->Unit(benchmark::kMillisecond);

// The tube scene of mode 0 (balloon deflated), 1 (inflated), 2 (stent deployed), brought to its
// steady state once per program.
struct Tube {
  std::unique_ptr<Simulator> sim;
  StepCommands cmds;
  explicit Tube(int mode) {
    test::TubeSpecs t;
    t.lesion_percent = 60;
    t.catalogue = mode == 2 ? "stent-cocr-3.0x18" : "balloon-sc-3.0x15";
    const auto dir =
        std::filesystem::temp_directory_path() / ("vcsim_bench_tube_" + std::to_string(mode));
    sim = std::make_unique<Simulator>(test::balloon_in_tube(dir, t));
    cmds.reset(2);
    for (DriveCommand& d : cmds.drive) d.mode = DriveCommand::Mode::kPosition;
    const double wire = test::kAccessS - 0.066 + 0.03;
    const double balloon = test::balloon_depth(sim->instrument_spec(1), 0.066);
    auto run = [&](double until, double pressure) {
      cmds.balloon_pressure = pressure;
      while (sim->time() < until) {
        cmds.drive[0].translation = std::min(wire, 0.05 * sim->time());
        cmds.drive[1].translation = std::min(balloon, 0.05 * sim->time() - 0.005);
        sim->step(cmds);
      }
    };
    run(4.0, 0.0);
    if (mode == 1) run(5.0, 8.0 * kAtm);
    if (mode == 2) {
      run(5.0, 10.0 * kAtm);
      run(6.0, 0.0);
    }
  }
};

void BM_TubeStep(benchmark::State& state) {
  static Tube tubes[3] = {Tube(0), Tube(1), Tube(2)};
  Tube& tube = tubes[state.range(0)];
  Simulator& sim = *tube.sim;
  const SimProfile before = sim.profile();
  for (auto _ : state) sim.step(tube.cmds);
  const SimProfile& after = sim.profile();
  const auto n = static_cast<double>(after.steps - before.steps);
  state.counters["procedure_us"] = (after.sum.procedure - before.sum.procedure) / n;
  state.counters["step_us"] = 1e6 * (after.wall_time - before.wall_time) / n;
  state.counters["deployed"] = sim.state().procedure.stents.empty()
                                   ? 0.0
                                   : static_cast<double>(sim.state().procedure.stents[0].phase ==
                                                         StentState::Phase::kDeployed);
}
BENCHMARK(BM_TubeStep)
    ->Arg(0)
    ->Arg(1)
    ->Arg(2)
    ->ArgName("deflated0_inflated1_stent2")
    ->Unit(benchmark::kMicrosecond);

// The default run's moments and the autopilot's commands right after each, recorded once.
struct Moments {
  static constexpr double kAt[] = {3.0, 11.5, 35.0, 62.0};
  static constexpr int kSteps = 200;  // 0.1 s at 0.5 ms
  std::unique_ptr<Simulator> sim;
  std::vector<SimState> start;
  std::vector<std::vector<StepCommands>> cmds;
  Moments() {
    sim = std::make_unique<Simulator>(load_scenario(default_scenarios_dir() / "default.json"));
    Autopilot pilot(*sim);
    StepCommands c;
    for (double at : kAt) {
      while (sim->time() < at - 1e-9) {
        pilot.command(*sim, c);
        sim->step(c);
      }
      start.push_back(sim->snapshot());
      cmds.emplace_back();
      for (int k = 0; k < kSteps; ++k) {
        pilot.command(*sim, c);
        cmds.back().push_back(c);
        sim->step(c);
      }
    }
  }
};

void BM_ProcedureStep(benchmark::State& state) {
  static Moments m;
  const auto i = static_cast<std::size_t>(state.range(0));
  Simulator& sim = *m.sim;
  sim.restore(m.start[i]);
  const SimProfile before = sim.profile();
  for (auto _ : state) {
    state.PauseTiming();
    sim.restore(m.start[i]);
    state.ResumeTiming();
    for (const StepCommands& c : m.cmds[i]) sim.step(c);
  }
  const SimProfile& after = sim.profile();
  const auto n = static_cast<double>(after.steps - before.steps);
  state.counters["step_us"] = 1e6 * (after.wall_time - before.wall_time) / n;
  const std::array<double, kNumSimStages> a = stage_times(after.sum), b = stage_times(before.sum);
  for (int k = 0; k < kNumSimStages; ++k) {
    const auto u = static_cast<std::size_t>(k);
    state.counters[to_string(static_cast<SimStage>(k))] = (a[u] - b[u]) / n;
  }
}
BENCHMARK(BM_ProcedureStep)
    ->Arg(0)
    ->Arg(1)
    ->Arg(2)
    ->Arg(3)
    ->ArgName("arch0_engaged1_lad2_stent3")
    ->Unit(benchmark::kMillisecond);

}  // namespace

BENCHMARK_MAIN();
