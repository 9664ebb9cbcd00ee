// Kernels of the beating lumen: the per-step patch update for instruments along the route to the
// lesion, against moving the whole heart, and the motion field itself. The whole-step figure of
// the issue is `vcsim bench anatomy`.
#include <benchmark/benchmark.h>

#include "vcsim/anatomy.h"

namespace vcsim {
namespace {

struct Scene {
  VesselTree tree = default_patient();
  Lumen lumen = build_lumen(tree);  // cached after the first run
  CardiacMotion motion{tree, MotionSettings{}};
  std::vector<Vec3> nodes;
  Scene() { nodes = route(tree, tree.access, tree.target, 2e-3); }
};

Scene& scene() {
  static Scene s;
  return s;
}

void BM_BeatingUpdateAlongRoute(benchmark::State& st) {
  Scene& s = scene();
  BeatingLumenSettings bs;
  bs.patch_triangles = static_cast<int>(st.range(0));
  BeatingLumen bl(s.lumen.mesh, s.motion, bs);
  const std::vector<double> radii{1.0e-3};
  double t = 0.0;
  int tris = 0;
  for (auto _ : st) {
    tris = bl.update(t, s.nodes, radii).triangles_updated;
    t += 1e-3;
  }
  st.counters["triangles_moved"] = tris;
  st.counters["patches"] = bl.num_patches();
}
BENCHMARK(BM_BeatingUpdateAlongRoute)->Arg(16)->Arg(32)->Arg(64)->Unit(benchmark::kMicrosecond);

void BM_BeatingUpdateAll(benchmark::State& st) {
  Scene& s = scene();
  BeatingLumen bl(s.lumen.mesh, s.motion);
  double t = 0.0;
  for (auto _ : st) {
    bl.update_all(t);
    t += 1e-3;
  }
}
BENCHMARK(BM_BeatingUpdateAll)->Unit(benchmark::kMicrosecond);

void BM_MotionAmplitudes(benchmark::State& st) {
  Scene& s = scene();
  Vec3 a, b;
  std::size_t i = 0;
  for (auto _ : st) {
    s.motion.amplitudes(s.lumen.mesh.vertices[i++ % s.lumen.mesh.vertices.size()], a, b);
    benchmark::DoNotOptimize(a);
  }
}
BENCHMARK(BM_MotionAmplitudes);

}  // namespace
}  // namespace vcsim
