// The beating lumen as the solver's wall: the motion field's rates against finite differences,
// the wall velocity at contacts, the speed bound, and a wire in the beating LAD moving with it.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <vector>

#include "anatomy_test_util.h"
#include "solver_rig.h"
#include "vcsim/beating_wall.h"

using namespace vcsim;
using test::patient;
using test::patient_lumen;

namespace {

constexpr double mm = 1e-3;

MotionSettings with_respiration() {
  MotionSettings s;
  s.respiration = true;
  return s;
}

// Distance from p to a polyline.
double distance_to_polyline(const std::vector<Vec3>& pts, const Vec3& p) {
  double best = 1e300;
  for (std::size_t i = 0; i + 1 < pts.size(); ++i) {
    const Vec3 d = pts[i + 1] - pts[i];
    const double t = std::clamp((p - pts[i]).dot(d) / d.squaredNorm(), 0.0, 1.0);
    best = std::min(best, (pts[i] + t * d - p).norm());
  }
  return best;
}

// A 0.014" coronary wire, 30 mm, laid on the LAD centreline from 20 mm to 50 mm past its origin
// (nodes on the centreline, frames along the edges), free (no sheath), no gravity. Its density is
// scaled so that the explicit step is 1 ms (quasi-static, docs/physics.md 5.3).
test::Rig wire_in_lad(const VesselSegment& lad, double s0) {
  RodDef d;
  d.length = 30 * mm;
  d.segments = 30;
  d.outer_radius = 0.178 * mm;
  d.youngs_modulus = 10e9;
  d.density = 6450;
  d.base = BoundaryKind::kFree;
  d.tip = BoundaryKind::kFree;
  const double dt0 = estimate_stable_dt(build_rod(d), RodSettings{});
  d.density *= std::max(1.0, std::pow(1e-3 / dt0, 2));
  test::Rig inst = test::free_rod_rig(d, ContactMaterial{0.1, 0.08});
  for (int i = 0; i < inst.md().n; ++i) inst.rod().x[i] = point_at(lad, s0 + inst.md().node_s[i]);
  for (int e = 0; e < inst.md().m; ++e) {
    const Vec3 t = (inst.rod().x[e + 1] - inst.rod().x[e]).normalized();
    inst.rod().q[e] = Quat::FromTwoVectors(Vec3::UnitZ(), t);
  }
  return inst;
}

struct Ride {
  double mean_wire = 0.0;         // mean node displacement at end-systole (m)
  double mean_vessel = 0.0;       // mean displacement of the vessel points the nodes started on (m)
  double worst_outside = -1e300;  // max over nodes of (distance to moved centreline - radius)
};

// Runs the wire from end-diastole (t = 0) to end-systole with the wall given, at 1 ms (the solver
// sets the wall's time at each step).
Ride ride_to_end_systole(VesselWall& wall) {
  const VesselTree& tree = patient();
  const VesselSegment& lad = tree.segments[tree.find("lad")];
  const CardiacMotion motion(tree, MotionSettings{});
  const double s0 = 20 * mm;
  test::Rig inst = wire_in_lad(lad, s0);
  const std::vector<Vec3> start = inst.rod().x;
  SolverSettings set;
  set.rod.dt = 1e-3;
  set.rod.drag = 5.0;
  set.rod.angular_drag = 5.0;
  const double t_es = 0.30 * motion.period();  // end-systole (phase 0.30)
  const int steps = static_cast<int>(std::lround(t_es / set.rod.dt));
  for (int k = 0; k < steps; ++k) {
    inst.step(&wall, set, DriveCommand{});
    for (const Vec3& x : inst.rod().x) EXPECT_TRUE(x.allFinite());
  }
  const double t = steps * set.rod.dt;
  const VesselSegment moved = motion.moved_tree(tree, t).segments[tree.find("lad")];
  Ride r;
  const int n = inst.md().n;
  for (int i = 0; i < n; ++i) {
    r.mean_wire += (inst.rod().x[i] - start[i]).norm() / n;
    r.mean_vessel += motion.displacement(start[i], t).norm() / n;
    const double s = s0 + inst.md().node_s[i];
    r.worst_outside = std::max(
        r.worst_outside, distance_to_polyline(moved.points, inst.rod().x[i]) - radius_at(moved, s));
  }
  return r;
}

}  // namespace

TEST(BeatingWall, WaveformRatesAreTheDerivativesOfTheWaveforms) {
  const CardiacMotion mo(patient(), with_respiration());
  const double h = 1e-6;
  for (double t = 0.013; t < 5.0; t += 0.0917) {
    const double fd_c = (mo.cardiac_waveform(t + h) - mo.cardiac_waveform(t - h)) / (2 * h);
    const double fd_r = (mo.respiratory_waveform(t + h) - mo.respiratory_waveform(t - h)) / (2 * h);
    const double c = mo.cardiac_waveform(t);
    // The waveform is clamped to [0, 1] where the cubic undershoots by < 1 %: skip those spots.
    if (c > 1e-3 && c < 1.0 - 1e-3) {
      EXPECT_NEAR(mo.cardiac_rate(t), fd_c, 1e-4) << "t " << t;
    }
    EXPECT_NEAR(mo.respiratory_rate(t), fd_r, 1e-5) << "t " << t;
  }
  const CardiacMotion still(patient(), MotionSettings{});
  EXPECT_EQ(still.respiratory_rate(1.3), 0.0);
}

TEST(BeatingWall, ContactVelocityIsTheWallsAndTheSpeedBoundHolds) {
  const VesselTree& tree = patient();
  const Lumen& lu = patient_lumen();
  const CardiacMotion mo(tree, with_respiration());
  BeatingLumen bl(lu.mesh, mo);
  BeatingWall wall(bl);
  EXPECT_GT(wall.speed_bound(), 0.0);
  // Spheres against the LAD wall at several times: the reported wall velocity is the time
  // derivative of the wall point's motion.
  const VesselSegment& lad = tree.segments[tree.find("lad")];
  const double h = 1e-6;
  int checked = 0;
  for (double t : {0.05, 0.12, 0.4, 0.55, 1.7}) {
    wall.set_time(t);
    std::vector<Vec3> c;
    for (double s = 10 * mm; s < 50 * mm; s += 5 * mm) {
      const Vec3 p = point_at(lad, s), tg = tangent_at(lad, s);
      const Vec3 u = tg.cross(Vec3::UnitZ()).normalized();
      c.push_back(p + mo.displacement(p, t) + (radius_at(lad, s) - 0.1 * mm) * u);
    }
    const std::vector<double> r = {0.2 * mm};
    std::vector<SphereContact> out(c.size());
    wall.query_spheres(c, r, out);
    for (const SphereContact& hit : out) {
      if (!hit.touching) continue;
      ++checked;
      // The wall vertex nearest the contact, in the rest mesh: its velocity by finite differences.
      const auto& tri = lu.mesh.triangles[hit.triangle];
      Vec3 X = Vec3::Zero();
      for (int v : tri) X += lu.mesh.vertices[v] / 3.0;
      const Vec3 fd = (mo.displacement(X, t + h) - mo.displacement(X, t - h)) / (2 * h);
      // The contact point is within a triangle's size of the centroid; the field varies by far
      // less than 10 % of the speed over that distance.
      EXPECT_LT((wall.velocity(hit) - fd).norm(), 0.1 * fd.norm() + 1e-4) << "t " << t;
    }
  }
  EXPECT_GT(checked, 20);
  // The bound holds for every wall vertex at many times.
  double fastest = 0.0;
  for (double t = 0.0; t < 4.0; t += 0.0071)
    for (int v = 0; v < lu.mesh.num_vertices(); v += 7)
      fastest = std::max(fastest, mo.velocity(lu.mesh.vertices[v], t).norm());
  EXPECT_LE(fastest, wall.speed_bound());
  EXPECT_GT(fastest, 0.5 * wall.speed_bound()) << "the bound should not be loose";
}

// Issue target: instruments in a beating vessel move with it.
TEST(BeatingWall, AWireInTheBeatingLadMovesWithIt) {
  const VesselTree& tree = patient();
  const Lumen& lu = patient_lumen();
  const CardiacMotion mo(tree, MotionSettings{});
  BeatingLumen bl(lu.mesh, mo);
  BeatingWall beating(bl);
  const Ride ride = ride_to_end_systole(beating);
  std::printf("beating: wire %.3f vessel %.3f outside %.3f mm\n", ride.mean_wire / mm,
              ride.mean_vessel / mm, ride.worst_outside / mm);
  EXPECT_GT(ride.mean_vessel, 2 * mm) << "the LAD must move more than its radius for this test";
  EXPECT_GT(ride.mean_wire, 0.8 * ride.mean_vessel);
  EXPECT_LT(ride.mean_wire, 1.2 * ride.mean_vessel);
  EXPECT_LT(ride.worst_outside, 0.0) << "every node stays inside the moved lumen";

  // Control: against the wall held at rest the wire stays behind and the moved lumen leaves it.
  AabbTree rest_tree;
  rest_tree.build(lu.mesh);
  StaticWall still(lu.mesh, rest_tree);
  const Ride stays = ride_to_end_systole(still);
  std::printf("static: wire %.3f vessel %.3f outside %.3f mm\n", stays.mean_wire / mm,
              stays.mean_vessel / mm, stays.worst_outside / mm);
  EXPECT_LT(stays.mean_wire, 0.2 * stays.mean_vessel);
  EXPECT_GT(stays.worst_outside, 0.0);
}

// moves_near (the contact coherence's test): where it says no moving part of the wall can come
// within r, none does at any phase (the whole wall gathered at nine times over a beat), and it
// says yes in the beating LAD and no in the still abdominal aorta.
TEST(BeatingWall, MovesNearIsTrueWhereverTheWallMoves) {
  const VesselTree& tree = patient();
  const Lumen& lu = patient_lumen();
  const CardiacMotion mo(tree, MotionSettings{});
  BeatingLumen bl(lu.mesh, mo);
  BeatingWall wall(bl);
  const VesselSegment& lad = tree.segments[tree.find("lad")];
  const VesselSegment& aorta = tree.segments[tree.find("abdominal_aorta")];
  EXPECT_TRUE(wall.moves_near(point_at(lad, 20 * mm), 1 * mm));
  EXPECT_FALSE(wall.moves_near(point_at(aorta, 0.5 * segment_length(aorta)), 3 * mm));
  // Points sampled along every segment's centreline, and radii of 1 and 4 mm.
  std::vector<std::pair<Vec3, double>> probes;
  for (const VesselSegment& seg : tree.segments)
    for (int k = 0; k <= 10; ++k)
      for (double r : {1 * mm, 4 * mm}) {
        const Vec3 p = point_at(seg, segment_length(seg) * k / 10.0);
        if (!wall.moves_near(p, r)) probes.emplace_back(p, r);
      }
  const int still = static_cast<int>(probes.size());
  TriangleMesh now;
  std::vector<Vec3> moved;
  for (int j = 0; j < 6; ++j) {
    bl.update_all(mo.period() * j / 6.0 + 0.01);
    bl.gather(now);
    moved.clear();
    for (std::size_t v = 0; v < now.vertices.size(); ++v)
      if ((now.vertices[v] - lu.mesh.vertices[v]).norm() > 1e-12) moved.push_back(now.vertices[v]);
    ASSERT_FALSE(moved.empty());
    for (const auto& [p, r] : probes)
      for (const Vec3& v : moved)
        ASSERT_GE((v - p).norm(), r) << "a moved wall vertex within r of a still probe";
  }
  EXPECT_GT(still, 100) << "most of the tree (aorta, iliacs) is still";
}

namespace {

// The beating wall with moves_near true everywhere: what the contact detection did before it
// asked (every node queried again whenever the wall moved anywhere).
struct MovingEverywhere final : VesselWall {
  BeatingWall& w;
  explicit MovingEverywhere(BeatingWall& wall) : w(wall) {}
  void set_time(double t) override { w.set_time(t); }
  void query_spheres(std::span<const Vec3> c, std::span<const double> r,
                     std::span<SphereContact> out) override {
    w.query_spheres(c, r, out);
  }
  Vec3 velocity(const SphereContact& hit) const override { return w.velocity(hit); }
  double speed_bound() const override { return w.speed_bound(); }
  bool moves_near(const Vec3&, double) const override { return true; }
  SegmentCrossings segment_crossings(const Vec3& a, const Vec3& b) override {
    return w.segment_crossings(a, b);
  }
};

// The LAD wire of wire_in_lad, but 30 mm along the still abdominal aorta, laid 8 mm off its axis
// and drifting toward its wall at 50 mm/s.
test::Rig wire_in_aorta(const VesselSegment& aorta) {
  test::Rig inst = wire_in_lad(aorta, 0.4 * segment_length(aorta));
  const Vec3 t = (inst.rod().x.back() - inst.rod().x.front()).normalized();
  const Vec3 side = t.unitOrthogonal();
  for (int i = 0; i < inst.md().n; ++i) {
    inst.rod().x[i] += 8 * mm * side;
    inst.rod().v[i] = 0.05 * side;
  }
  return inst;
}

}  // namespace

// Contact coherence while the heart beats: a wire in the still aorta is queried only as it moves,
// not as the wall moves elsewhere (against the same wall that says it moves everywhere, whose
// clearances shrink at its speed bound), and it meets the wall exactly as it does there.
TEST(BeatingWall, NodesAwayFromTheMovingWallKeepTheirCoherence) {
  const VesselTree& tree = patient();
  const Lumen& lu = patient_lumen();
  const CardiacMotion mo(tree, MotionSettings{});
  BeatingLumen bl_a(lu.mesh, mo), bl_b(lu.mesh, mo);
  BeatingWall a(bl_a), b_inner(bl_b);
  MovingEverywhere b(b_inner);
  const VesselSegment& aorta = tree.segments[tree.find("abdominal_aorta")];
  test::Rig ra = wire_in_aorta(aorta), rb = wire_in_aorta(aorta);
  SolverSettings set;
  set.rod.dt = 1e-3;
  set.rod.drag = 1.0;
  set.rod.angular_drag = 1.0;
  int queries_a = 0, queries_b = 0, contacts = 0;
  for (int k = 0; k < 400; ++k) {
    StepProfile pa, pb;
    ra.step(&a, set, DriveCommand{}, &pa);
    rb.step(&b, set, DriveCommand{}, &pb);
    queries_a += pa.num_queries;
    queries_b += pb.num_queries;
    contacts += pa.num_contacts;
    ASSERT_EQ(ra.rod().x, rb.rod().x) << "step " << k;
    ASSERT_EQ(ra.rod().v, rb.rod().v) << "step " << k;
  }
  std::printf("queries: %d (moving everywhere: %d), contacts %d\n", queries_a, queries_b, contacts);
  EXPECT_GT(contacts, 0) << "the wire reached the wall";
  EXPECT_LT(queries_a, queries_b);
}
