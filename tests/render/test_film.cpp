// The frame writer's thread (FrameRecorder, docs/rendering.md): a run filmed while it steps hands
// each frame's copy of the state to the worker, which draws and writes it. The frames are the
// same byte for byte on a second run, whatever the two threads' timing (each frame's noise seed
// is its index). Run under ThreadSanitizer too (the tsan preset).
#include <gtest/gtest.h>

#include <unistd.h>
#include <filesystem>
#include <string>

#include "vcsim/render.h"

#include "../common/cli_runner.h"
#include "balloon_scene.h"

namespace vcsim {
namespace {

namespace fs = std::filesystem;

// A 0.014" wire pushed 20 mm into the procedure tests' tube in 0.2 s, filmed at 100 frames per
// simulated second, 128 x 128; the frames' count.
int film(const fs::path& dir) {
  fs::remove_all(dir);
  fs::create_directories(dir);
  Scenario sc = test::tube_scenario(
      dir / "scene", test::TubeSpecs{},
      R"([{"name": "wire", "catalogue": "wire-014-floppy", "max_nodes": 64, "tip_segment_mm": 2}])");
  sc.fluoro.size = 128;
  sc.fluoro.fps = 100.0;
  Simulator sim(sc);
  ImageChainSettings chain;
  chain.dose = sc.fluoro.dose;
  FrameRecorder recorder(sim.model(), sc.fluoro.size, BeamEnergy::k60keV, chain, dir);
  RunFilm run_film(sim.model(), recorder);
  StepCommands cmds;
  cmds.reset(1);
  cmds.drive[0].mode = DriveCommand::Mode::kPosition;
  while (sim.time() < 0.2 - 1e-9) {
    cmds.drive[0].translation = 0.1 * (sim.time() + sim.dt());
    sim.step(cmds);
    run_film.after_step(sim);
  }
  recorder.finish();
  return recorder.frames();
}

TEST(FrameRecorder, AFilmedRunGivesTheSameFramesEveryTime) {
  const fs::path base =
      fs::temp_directory_path() / ("vcsim-test-film-" + std::to_string(::getpid()));
  const int a = film(base / "a"), b = film(base / "b");
  EXPECT_EQ(a, 21);  // after the first step, then every 10 ms through 0.2 s
  ASSERT_EQ(a, b);
  for (int k = 0; k < a; ++k) {
    char name[32];
    std::snprintf(name, sizeof name, "frame_%05d.png", k);
    const std::string fa = test::slurp(base / "a" / name), fb = test::slurp(base / "b" / name);
    EXPECT_GT(fa.size(), 100u) << name;
    EXPECT_EQ(fa, fb) << name;
  }
  fs::remove_all(base);
}

}  // namespace
}  // namespace vcsim
