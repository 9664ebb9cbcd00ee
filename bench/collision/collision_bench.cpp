// Collision kernels at instrument scale: 256 nodes of radius 0.45 mm in a bent vessel of radius
// 3 mm meshed with about 10k to 50k triangles; the batch sphere query, the refit after the wall
// moves, and the build for reference.
#include "vcsim/collision.h"

#include <benchmark/benchmark.h>

#include <cmath>
#include <random>

namespace vcsim {
namespace {

constexpr double kNodeRadius = 0.45e-3;
constexpr int kNodes = 256;

// Bent tube (20 mm, 90 degrees on a 15 mm radius, 20 mm; lumen radius 3 mm) whose ring spacing
// gives about `triangles` triangles with 48 sides.
BentTubeSpec vessel(int triangles) {
  BentTubeSpec spec;
  spec.radius = 3e-3;
  spec.sides = 48;
  const double length = spec.straight1 + spec.bend_radius * spec.bend_angle + spec.straight2;
  spec.ring_spacing = length / (triangles / (2.0 * spec.sides));
  return spec;
}

// Instrument nodes along the centreline, 0.25 mm apart, each pushed off the axis at a random
// angle; about a third of them touch the wall and a few have crossed it.
std::vector<Vec3> instrument_nodes(const BentTubeSpec& spec) {
  const auto line =
      bent_centreline(spec.straight1, spec.bend_radius, spec.bend_angle, spec.straight2, 0.25e-3);
  std::mt19937 rng(2024);
  std::uniform_real_distribution<double> angle(0.0, 2.0 * 3.141592653589793);
  std::uniform_real_distribution<double> offset(0.0, spec.radius + 0.2 * kNodeRadius);
  std::vector<Vec3> nodes;
  for (int i = 0; i < kNodes; ++i) {
    const std::size_t k = std::min(line.size() - 2, static_cast<std::size_t>(i));
    const Vec3 t = (line[k + 1] - line[k]).normalized();
    const Vec3 u = t.cross(Vec3::UnitY()).normalized();
    const Vec3 v = t.cross(u);
    const double a = angle(rng);
    nodes.push_back(line[k] + offset(rng) * (std::cos(a) * u + std::sin(a) * v));
  }
  return nodes;
}

// A smooth wave on the wall, about a pulsating coronary's amplitude (0.2 mm).
void deform(const std::vector<Vec3>& rest, double phase, TriangleMesh& mesh) {
  for (std::size_t i = 0; i < rest.size(); ++i) {
    const Vec3& p = rest[i];
    mesh.vertices[i] =
        p + 0.2e-3 * Vec3(std::sin(300.0 * p.z() + phase), std::sin(300.0 * p.x() + phase), 0.0);
  }
}

void BM_BatchSphereQuery(benchmark::State& state) {
  const BentTubeSpec spec = vessel(static_cast<int>(state.range(0)));
  TriangleMesh mesh = make_bent_tube(spec);
  check_and_repair(mesh);
  AabbTree tree;
  tree.build(mesh);
  const std::vector<Vec3> nodes = instrument_nodes(spec);
  const std::vector<double> radius{kNodeRadius};
  std::vector<SphereContact> out(nodes.size());
  for (auto _ : state) {
    tree.query_spheres(mesh, nodes, radius, out);
    benchmark::DoNotOptimize(out.data());
    benchmark::ClobberMemory();
  }
  int touching = 0;
  for (const auto& c : out) touching += c.touching;
  state.counters["triangles"] = mesh.num_triangles();
  state.counters["touching"] = touching;
  state.counters["depth"] = tree.depth();
  state.SetItemsProcessed(state.iterations() * kNodes);
}
BENCHMARK(BM_BatchSphereQuery)->Arg(10000)->Arg(20000)->Arg(50000)->Unit(benchmark::kMicrosecond);

void BM_Refit(benchmark::State& state) {
  const BentTubeSpec spec = vessel(static_cast<int>(state.range(0)));
  TriangleMesh mesh = make_bent_tube(spec);
  check_and_repair(mesh);
  AabbTree tree;
  tree.build(mesh);
  const std::vector<Vec3> rest = mesh.vertices;
  deform(rest, 0.3, mesh);
  for (auto _ : state) {
    tree.refit(mesh);
    benchmark::ClobberMemory();
  }
  state.counters["triangles"] = mesh.num_triangles();
  state.SetItemsProcessed(state.iterations() * mesh.num_triangles());
}
BENCHMARK(BM_Refit)->Arg(10000)->Arg(20000)->Arg(50000)->Unit(benchmark::kMicrosecond);

// What the anatomy stage pays per step: move the wall, recompute normals, refit.
void BM_DeformNormalsRefit(benchmark::State& state) {
  const BentTubeSpec spec = vessel(static_cast<int>(state.range(0)));
  TriangleMesh mesh = make_bent_tube(spec);
  check_and_repair(mesh);
  AabbTree tree;
  tree.build(mesh);
  const std::vector<Vec3> rest = mesh.vertices;
  double phase = 0.0;
  for (auto _ : state) {
    deform(rest, phase += 0.01, mesh);
    mesh.recompute_normals();
    tree.refit(mesh);
    benchmark::ClobberMemory();
  }
  state.counters["triangles"] = mesh.num_triangles();
}
BENCHMARK(BM_DeformNormalsRefit)->Arg(20000)->Unit(benchmark::kMicrosecond);

void BM_Build(benchmark::State& state) {
  TriangleMesh mesh = make_bent_tube(vessel(static_cast<int>(state.range(0))));
  check_and_repair(mesh);
  for (auto _ : state) {
    AabbTree tree;
    tree.build(mesh);
    benchmark::DoNotOptimize(tree.nodes().data());
  }
  state.counters["triangles"] = mesh.num_triangles();
}
BENCHMARK(BM_Build)->Arg(20000)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace vcsim
