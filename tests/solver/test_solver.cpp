// An instrument in a vessel: non-penetration under a hard push, Coulomb friction against the
// analytic incline, the drive's reaction force and torque transmission, and the paper's
// compression targets.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <numbers>
#include <optional>
#include <string>

#include "solver_rig.h"
#include "test_rods.h"
#include "vcsim/experiments.h"
#include "vcsim/solver.h"

using namespace vcsim;

namespace {

// A quasi-static test rod: a stiff-enough polymer wire whose density is scaled so that the
// explicit step is 1 ms (the scaling changes inertia only, not statics or friction).
RodDef test_rod(double length, int segments) {
  return test::free_rod(length, segments, 0.45e-3, 2e9);
}

double scaled_density(RodDef d, double dt) {
  const RodModel md = build_rod(d);
  const double dt0 = estimate_stable_dt(md, RodSettings{});
  return d.density * std::max(1.0, std::pow(dt / dt0, 2));
}

struct StraightTube {
  TriangleMesh mesh;
  AabbTree tree;
  double radius, length;
  StraightTube(double r, double len, bool cap) : radius(r), length(len) {
    TubeSpec spec;
    spec.centreline = {Vec3::Zero(), Vec3(0, 0, len)};
    spec.radius = r;
    spec.sides = 24;
    spec.rings = static_cast<int>(len / 1.5e-3) + 2;
    spec.cap_end = cap;
    mesh = make_tube(spec);
    check_and_repair(mesh, "test tube");
    tree.build(mesh);
  }
  StaticWall wall() const { return StaticWall(mesh, tree); }
};

// The drive tests' scene: a 100 mm rod of 60 segments inserted `depth` into a frictionless
// dead-end tube (radius 2 mm, 60 mm long), mass-scaled for a 1 ms step (times `mass_factor`),
// drag 20 /s.
struct DeadEndScene {
  static constexpr double kDt = 1e-3;
  StraightTube tube{2.0e-3, 0.06, /*cap=*/true};
  std::optional<test::Rig> rig;
  SolverSettings s;
  explicit DeadEndScene(double depth, double mass_factor = 1.0) {
    RodDef d = test_rod(0.1, 60);
    d.density = mass_factor * scaled_density(d, kDt);
    rig.emplace(test::driven(d, Sheath{}, ContactMaterial{0.0, 0.0}, depth));
    s.rod.dt = kDt;
    s.rod.drag = 20.0;
  }
};

}  // namespace

TEST(Solver, HardPushIntoADeadEndStaysInsideForTenSeconds) {
  StraightTube tube(2.5e-3, 0.08, /*cap=*/true);
  RodDef d = test_rod(0.12, 80);
  const double dt = 1e-3;
  d.density = scaled_density(d, dt);
  ContactMaterial mat{0.1, 0.08};
  // A hand that never slips (physics.md 6.5): the contacts must hold whatever the drive does.
  // This rod's raw hand force swings by +-80 N with its scaled inertia, and a 20 N grip slips and
  // catches on those swings; the jerks left it crammed so that nodes passed the wall (5,698 steps
  // with one out, one 20 mm out): a limit of the contacts, noted in physics.md 6.5.
  Sheath hand;
  hand.grip_force = 1e9;
  hand.grip_torque = 1e9;
  test::Rig inst = test::driven(d, hand, mat, 0.05);
  SolverSettings s;
  s.rod.dt = dt;
  // Blood damps the frames' spin as it damps the nodes: without it the crammed rod's twist,
  // which wall contact (on nodes) cannot reach, never settles.
  s.rod.drag = 20.0;
  s.rod.angular_drag = 20.0;
  s.rod.gravity = Vec3(0, -9.81, 0);
  DriveCommand push{DriveCommand::Mode::kVelocity, 0.1, 0.0};  // 100 mm/s, on and on
  double worst = 0.0;
  int escapes = 0;  // steps in which the escape check saw a node out (physics.md 6.3)
  StaticWall wall = tube.wall();
  for (int k = 0; k < 10000; ++k) {
    inst.step(&wall, s, push);
    escapes += inst.ws.escape(0).node >= 0 ? 1 : 0;
    if (k % 50 != 0 && k < 9990) continue;
    for (int i = inst.drive().first_free; i < inst.md().n; ++i) {
      const Vec3& x = inst.rod().x[i];
      ASSERT_TRUE(x.allFinite()) << "node " << i << " at step " << k;
      const double radial = std::hypot(x.x(), x.y()) - tube.radius;
      const double beyond_cap = x.z() - tube.length;
      worst = std::max({worst, radial / d.outer_radius, beyond_cap / d.outer_radius});
    }
  }
  EXPECT_LT(worst, 0.10) << "a node left the lumen by more than 10 % of its radius";
  EXPECT_EQ(escapes, 0);
  // It really was a hard push: the whole rod is crammed into the blind tube. (The hand force of
  // this mass-scaled rod is dominated by its inflated inertia; DriveFeelsTheDeadEnd checks the
  // quasi-static force.)
  EXPECT_NEAR(inst.drive().depth, d.length - inst.md().rest_length[0], 1e-9);
}

class Incline : public ::testing::TestWithParam<double> {};

// A free rod on a plane tilted by alpha (gravity tilted instead): it stays put while
// tan(alpha) < mu and slides with a = g (sin(alpha) - mu cos(alpha)) once tan(alpha) > mu.
TEST_P(Incline, SlidesOnlyBeyondTheFrictionAngle) {
  const double mu = 0.3, ratio = GetParam();
  const double alpha = std::atan(ratio * mu), g = 9.81;
  TriangleMesh plane;
  const double h = 0.5;
  plane.vertices = {Vec3(-h, -h, 0), Vec3(h, -h, 0), Vec3(h, h, 0), Vec3(-h, h, 0)};
  plane.triangles = {{0, 1, 2}, {0, 2, 3}};  // normals +z: the "lumen" is above
  plane.recompute_normals();
  AabbTree tree;
  tree.build(plane);
  RodDef d = test_rod(0.02, 10);
  d.base_orientation = Quat::FromTwoVectors(Vec3::UnitZ(), Vec3::UnitY());
  d.base_position = Vec3(0, -0.01, d.outer_radius);
  test::Rig inst = test::free_rod_rig(d, ContactMaterial{mu, mu});
  SolverSettings s;
  s.rod.dt = estimate_stable_dt(inst.md(), s.rod);
  s.rod.gravity = Vec3(g * std::sin(alpha), 0, -g * std::cos(alpha));
  const double t_end = 0.2;
  const int steps = static_cast<int>(t_end / s.rod.dt);
  // Let it settle onto the plane for a moment before measuring.
  double x0 = 0.0;
  StaticWall wall(plane, tree);
  for (int k = 0; k < steps; ++k) {
    if (k == steps / 10) x0 = inst.rod().x[5].x();
    inst.step(&wall, s, DriveCommand{});
  }
  const double t = t_end - (steps / 10) * s.rod.dt;
  const double moved = inst.rod().x[5].x() - x0;
  if (ratio < 1.0) {
    EXPECT_LT(std::abs(moved), 1e-6) << "stuck below the friction angle";
  } else {
    const double a = g * (std::sin(alpha) - mu * std::cos(alpha));
    // Sliding from (nearly) rest at the measurement start: x = v0 t + a t^2 / 2 with v0 from
    // the first tenth; compare the mean acceleration of the sliding phase.
    EXPECT_GT(moved, 0.25 * a * t * t) << "must slide beyond the friction angle";
    const double v_end = inst.rod().v[5].x();
    const double v_start = v_end - a * t;
    EXPECT_NEAR((v_end - v_start) / t, a, 0.05 * a);
    EXPECT_NEAR(moved, v_start * t + 0.5 * a * t * t, 0.05 * moved);
  }
  // Never sinks into the plane.
  for (const auto& x : inst.rod().x) EXPECT_GT(x.z(), 0.9 * d.outer_radius);
}
INSTANTIATE_TEST_SUITE_P(TanOverMu, Incline, ::testing::Values(0.8, 1.25, 2.0));

TEST(Solver, DriveFeelsTheDeadEnd) {
  DeadEndScene sc(0.03);
  test::Rig& inst = *sc.rig;
  const SolverSettings& s = sc.s;
  StaticWall wall = sc.tube.wall();
  auto push_to = [&](double depth, int settle) {
    DriveCommand c{DriveCommand::Mode::kPosition, depth, 0.0};
    for (int k = 0; k < settle; ++k) inst.step(&wall, s, c);
    return inst.drive().axial_force;
  };
  const double free_force = push_to(0.05, 800);  // tip 10 mm short of the end
  const double f1 = push_to(0.0605, 800);        // 0.5 mm past contact
  const double f2 = push_to(0.062, 800);         // 2 mm past contact
  EXPECT_LT(std::abs(free_force), 1e-3) << "free insertion in a frictionless tube costs nothing";
  EXPECT_GT(f1, 10 * std::abs(free_force) + 1e-3);
  EXPECT_GT(f2, f1) << "pushing on into the dead end must resist more";
}

TEST(Solver, TurningAtTheHandTurnsTheTip) {
  StraightTube tube(2.0e-3, 0.1, false);
  RodDef d = test_rod(0.1, 40);
  const double dt = 1e-3;
  d.density = scaled_density(d, dt);
  test::Rig inst = test::driven(d, Sheath{}, ContactMaterial{0.0, 0.0}, 0.06);
  SolverSettings s;
  s.rod.dt = dt;
  s.rod.drag = 20.0;
  s.rod.angular_drag = 20.0;
  const double turn = std::numbers::pi / 2;
  DriveCommand c{DriveCommand::Mode::kPosition, 0.06, turn};
  StaticWall wall = tube.wall();
  for (int k = 0; k < 3000; ++k) inst.step(&wall, s, c);
  const Vec3 d1 = inst.rod().q.back() * Vec3::UnitX();
  EXPECT_NEAR(std::atan2(d1.y(), d1.x()), turn, 0.02) << "the tip follows the hand's roll";
  EXPECT_NEAR(inst.drive().torque, 0.0, 1e-6) << "no friction: nothing resists once turned";
}

// The introducer sheath (physics.md 6.2): a 100 mm rod inserted 60 mm, no vessel wall, loaded
// sideways by its (scaled) weight. The nodes within the sheath's 30 mm stay within its lumen,
// 0.1 mm wider than the rod, while the part beyond it sags as a cantilever; without the sheath the
// node 20 mm in sags as well.
TEST(Solver, TheSheathHoldsWhatPassesThroughIt) {
  auto sag_at = [](double sheath_length, double s_in) {
    RodDef d = test_rod(0.1, 60);
    const double dt = 1e-3;
    d.density = scaled_density(d, dt);
    Sheath sh;
    sh.length = sheath_length;
    sh.inner_radius = d.outer_radius + 0.1e-3;
    test::Rig inst = test::driven(d, sh, ContactMaterial{0.0, 0.0}, 0.06);
    SolverSettings s;
    s.rod.dt = dt;
    s.rod.drag = 20.0;
    s.rod.gravity = Vec3(0.5, 0.0, 0.0);  // sideways, m/s^2 (the mass is scaled 10^2-fold)
    s.collisions = false;
    const DriveCommand c{DriveCommand::Mode::kPosition, 0.06, 0.0};
    double worst_inside = 0.0;
    for (int k = 0; k < 3000; ++k) {
      inst.step(nullptr, s, c);
      for (int i = inst.drive().first_free; i < inst.md().n; ++i)
        if (inst.md().node_s[i] - (inst.md().length - inst.drive().depth) <= sheath_length)
          worst_inside =
              std::max(worst_inside, std::hypot(inst.rod().x[i].x(), inst.rod().x[i].y()));
    }
    const double s_node = inst.md().length - inst.drive().depth + s_in;
    int i = 0;
    while (inst.md().node_s[i] < s_node) ++i;
    return std::pair(worst_inside, std::hypot(inst.rod().x[i].x(), inst.rod().x[i].y()));
  };
  const auto [inside, beyond] = sag_at(0.03, 0.055);
  const double play = 0.1e-3;
  EXPECT_LT(inside, 1.05 * play) << "within the sheath's lumen (m off the axis)";
  EXPECT_GT(beyond, 5.0 * play) << "beyond it the rod sags";
  EXPECT_GT(sag_at(0.0, 0.02).second, 2.0 * play) << "without a sheath it sags there too";
}

// A node taken into the hand away from its place on the sheath axis (as a wire folded back out
// of the body inside its catheter is, in the soak) goes there at most 1 mm a step beyond the
// hand's own motion, and gets there. Put there in one step, a fold of 5.5 mm left the soak's
// 0.014" wire at 51 m/s and blew the scene up (docs/measurements.md, 2026-11-27).
TEST(Solver, ANodeTakenIntoTheHandOffItsPlaceIsNotThrownThere) {
  RodDef d = test_rod(0.1, 60);
  const double dt = 1e-3;
  d.density = scaled_density(d, dt);
  const RodModel probe = build_rod(d);
  const int k = 20;  // the node the withdrawal takes into the hand
  // Inserted so that node k lies 0.1 mm inside the access point.
  const double depth = probe.length - probe.node_s[k] + 0.1e-3;
  test::Rig inst = test::driven(d, Sheath{}, ContactMaterial{0.0, 0.0}, depth);
  SolverSettings s;
  s.rod.dt = dt;
  inst.step(nullptr, s, DriveCommand{DriveCommand::Mode::kPosition, depth, 0.0});
  ASSERT_EQ(inst.drive().first_free, k);
  const Vec3 place = inst.rod().x[k];
  inst.rod().x[k] += Vec3(3e-3, 0.0, 0.0);  // 3 mm off the axis
  // Withdrawn 0.2 mm: node k is held from this step on.
  const DriveCommand pull{DriveCommand::Mode::kPosition, depth - 0.2e-3, 0.0};
  inst.step(nullptr, s, pull);
  ASSERT_GT(inst.drive().first_free, k);
  const Vec3 hand(0.0, 0.0, -0.2);  // the held part's velocity (m/s), along -z
  EXPECT_LE((inst.rod().v[k] - hand).norm(), 1.0 + 1e-9) << "1 mm in a 1 ms step";
  EXPECT_GT((inst.rod().x[k] - place).norm(), 1.5e-3) << "still on its way";
  for (int n = 0; n < 5; ++n) inst.step(nullptr, s, pull);
  const Vec3 target = place - Vec3(0.0, 0.0, 0.2e-3);
  EXPECT_LT((inst.rod().x[k] - target).norm(), 1e-9) << "on the axis within three steps";
}

TEST(Solver, BadInstrumentInputIsAnInputError) {
  RodDef d = test_rod(0.1, 20);
  EXPECT_THROW(test::driven(d, Sheath{}, ContactMaterial{0.1, 0.2}, 0.05), InputError);
  EXPECT_THROW(test::driven(d, Sheath{}, ContactMaterial{}, 0.2), InputError);
  d.base = BoundaryKind::kClamped;
  EXPECT_THROW(test::driven(d, Sheath{}, ContactMaterial{}, 0.05), InputError);
  // The linearly implicit rod step is refused where instruments collide (physics.md 5.5).
  SolverSettings s;
  s.rod.integrator = Integrator::kLinearlyImplicit;
  try {
    s.validate("scene");
    ADD_FAILURE() << "accepted the implicit step with collisions";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("rod.integrator"), std::string::npos) << e.what();
  }
  s.collisions = false;
  EXPECT_NO_THROW(s.validate("scene"));
}

// The paper's Table 1 targets (issue 3): one global iteration compresses at most 0.45 %, 25
// at most 0.01 %; local sweeps improve with iterations; the penalty rod compresses by per cent.
TEST(Compression, PaperTargets) {
  CompressionOptions o;
  const auto g1 = run_compression(o, DistanceMethod::kGlobal, 1);
  const auto g25 = run_compression(o, DistanceMethod::kGlobal, 25);
  EXPECT_LE(g1.max_compression_percent, 0.45);
  EXPECT_LE(g25.max_compression_percent, 0.01);
  EXPECT_LT(g1.max_outside, 0.10);
  const auto gs1 = run_compression(o, DistanceMethod::kLocalGS, 1);
  const auto gs10 = run_compression(o, DistanceMethod::kLocalGS, 10);
  EXPECT_GT(gs1.max_compression_percent, gs10.max_compression_percent);
  EXPECT_GT(gs1.max_compression_percent, 10 * g1.max_compression_percent);
  const auto j1 = run_compression(o, DistanceMethod::kLocalJacobi, 1);
  const auto j10 = run_compression(o, DistanceMethod::kLocalJacobi, 10);
  EXPECT_GT(j1.max_compression_percent, j10.max_compression_percent);
  const auto pen = run_compression(o, DistanceMethod::kPenalty, 1);
  EXPECT_GT(pen.compression_percent, 1.0);
}

// Issue 4, force feedback: the hand feels the loads on the inserted part, not the rod's own
// (mass-scaled) inertia and drag. Pushed at 20 mm/s through a frictionless tube without touching
// it, the hand feels nothing, whether the rod is 1 or 4 times as heavy (two mass-scaling
// factors). The old definition (the held nodes' force balance) read the drag c m v of the held
// part and, through the constraints, of the inserted part: 2.2 kN here, 8.9 kN at mass 4.
TEST(Solver, HandForceDoesNotScaleWithTheRodsMass) {
  for (double mass_factor : {1.0, 4.0}) {
    DeadEndScene sc(0.03, mass_factor);
    test::Rig& inst = *sc.rig;
    const SolverSettings& s = sc.s;
    StaticWall wall = sc.tube.wall();
    const DriveCommand push{DriveCommand::Mode::kVelocity, 0.02, 0.0};  // 20 mm/s for 1 s
    double worst = 0.0;
    for (int k = 0; k < 1000; ++k) {
      inst.step(&wall, s, push);
      worst = std::max(worst, std::abs(inst.drive().axial_force));
    }
    EXPECT_NEAR(inst.drive().depth, 0.05, 1e-9);
    EXPECT_LT(worst, 1e-9) << "free insertion: no contact, no load (mass x " << mass_factor << ")";
  }
}

// The optional haptic low-pass: a first-order filter of the raw force with the set cutoff.
TEST(Solver, HandForceLowPassIsFirstOrder) {
  DeadEndScene sc(0.05);
  test::Rig& inst = *sc.rig;
  SolverSettings& s = sc.s;
  s.feedback_cutoff_hz = 30.0;
  StaticWall wall = sc.tube.wall();
  const double dt = DeadEndScene::kDt;
  const double g = 1.0 - std::exp(-2.0 * std::numbers::pi * 30.0 * dt);
  const DriveCommand c{DriveCommand::Mode::kPosition, 0.0605, 0.0};
  double prev = 0.0, worst = 0.0, range = 0.0;
  for (int k = 0; k < 300; ++k) {
    inst.step(&wall, s, c);
    const DriveState& dr = inst.drive();
    if (k > 0)
      worst = std::max(worst, std::abs(dr.axial_force - (prev + g * (dr.axial_force_raw - prev))));
    range = std::max(range, std::abs(dr.axial_force_raw));
    prev = dr.axial_force;
  }
  EXPECT_GT(range, 1e-3) << "the dead end was felt";
  EXPECT_LT(worst, 1e-12 * range);
  SolverSettings bad = s;
  bad.feedback_cutoff_hz = -1.0;
  EXPECT_THROW(bad.validate(), InputError);
}

// The wall queries of a step may run on several threads; each writes only its own contact and
// leaf cache, so the steps are the same bit for bit whether the batches split or not.
TEST(Solver, ParallelWallQueriesGiveTheSameSteps) {
  StraightTube tube(1.0e-3, 0.08, /*cap=*/true);  // narrow: most nodes are queried every step
  RodDef d = test_rod(0.1, 80);
  d.density = scaled_density(d, 1e-3);
  SolverSettings s;
  s.rod.dt = 1e-3;
  s.rod.drag = 20.0;
  const DriveCommand push{DriveCommand::Mode::kVelocity, 0.05, 2.0};
  auto run = [&](int parallel_min, int& max_queries) {
    test::Rig inst = test::driven(d, Sheath{}, ContactMaterial{0.1, 0.08}, 0.03);
    StaticWall wall(tube.mesh, tube.tree, parallel_min);
    StepProfile prof;
    for (int k = 0; k < 800; ++k) {
      inst.step(&wall, s, push, &prof);
      max_queries = std::max(max_queries, prof.num_queries);
    }
    return inst.rod().hash();
  };
  int serial_queries = 0, parallel_queries = 0;
  const std::uint64_t serial = run(0, serial_queries);
  const std::uint64_t parallel = run(1, parallel_queries);
  EXPECT_EQ(serial, parallel);
  EXPECT_EQ(serial_queries, parallel_queries);
  EXPECT_GE(parallel_queries, 2 * StaticWall::kParallelChunk) << "batches large enough to split";
}

// --- escape (physics.md 6.3) ---------------------------------------------------------------------

// A short free rod across the wall of a straight tube (radius 2 mm) at z = 30 mm, along +x from
// the axis: the escape check sees the node farthest behind the wall that its query reaches, and
// only a node more than its radius out.
TEST(Escape, ANodeBehindTheWallByMoreThanItsRadiusIsSeen) {
  StraightTube tube(2.0e-3, 0.06, /*cap=*/false);
  auto first_step = [&](double length, int segments) {
    RodDef d = test::free_rod(length, segments, 0.2e-3, 2e9);
    d.base_position = Vec3(0, 0, 0.03);
    d.base_orientation = Quat::FromTwoVectors(Vec3::UnitZ(), Vec3::UnitX());
    test::Rig rig = test::free_rod_rig(d, ContactMaterial{0.0, 0.0});
    SolverSettings s;
    s.rod.dt = 1e-4;
    StaticWall wall = tube.wall();
    rig.step(&wall, s, std::span<const DriveCommand>(std::vector<DriveCommand>(1)));
    return std::pair(rig.ws.escape(0), static_cast<int>(rig.contacts().size()));
  };
  // Nodes every 0.4 mm to 3.2 mm: 0.4, 0.8 and 1.2 mm behind the wall. The query (node radius 0.2
  // mm + 0.2 mm contact margin + 0.6 mm coherence margin) reaches 1 mm: the node 0.8 mm out.
  const auto [far, far_contacts] = first_step(3.2e-3, 8);
  EXPECT_EQ(far.node, 7);
  EXPECT_EQ(far.exit, -1);
  EXPECT_NEAR(far.distance, 0.8e-3, 0.02e-3);  // the tube's 24 facets lie within 17 um of 2 mm
  EXPECT_GE(far_contacts, 2);
  // 0.1 mm behind the wall, less than its radius: a contact, not an escape.
  const auto [near, near_contacts] = first_step(2.1e-3, 3);
  EXPECT_EQ(near.node, -1) << near.distance;
  EXPECT_GE(near_contacts, 1) << "the node was queried and found behind the wall";
}

// A rod pushed straight along a tube (radius 2 mm, 40 mm) out of its open end. With the end as
// the wall's exit, the escape is seen once a node is more than its radius beyond the end's plane
// and before it is 1.5 mm further (a node is queried again after each ~0.6 mm of travel), and
// never before. The tube's start is an exit too: the rod's part outside the body lies beyond
// it, on the sheath's axis, and is not an escape.
// The scene of the two tests below: a rod driven 20 mm into a tube (radius 2 mm, 40 mm) open at
// both ends, both ends the wall's exits; the far end flagged as the access end or not.
struct OpenEndTube {
  static constexpr double length = 0.04, radius = 2.0e-3;
  static RodDef rod() {
    RodDef d = test_rod(0.1, 60);
    d.density = scaled_density(d, 1e-3);
    return d;
  }
  static SolverSettings settings() {
    SolverSettings s;
    s.rod.dt = 1e-3;
    s.rod.drag = 20.0;
    return s;
  }
  StraightTube tube{radius, length, /*cap=*/false};
  RodDef d = rod();
  test::Rig inst = test::driven(d, Sheath{}, ContactMaterial{0.0, 0.0}, 0.02);
  SolverSettings s = settings();
  StaticWall wall = tube.wall();
  explicit OpenEndTube(bool far_end_is_access) {
    WallExit far{Vec3(0, 0, length), Vec3::UnitZ(), radius};
    far.access = far_end_is_access;
    wall.set_exits({far, {Vec3::Zero(), -Vec3::UnitZ(), radius}});
  }
};

TEST(Escape, ANodePushedOutOfAnOpenEndIsSeen) {
  OpenEndTube sc(false);
  const double length = sc.length;
  const RodDef& d = sc.d;
  test::Rig& inst = sc.inst;
  const SolverSettings& s = sc.s;
  StaticWall& wall = sc.wall;
  const double r = d.outer_radius;
  const DriveCommand push{DriveCommand::Mode::kVelocity, 0.05, 0.0};
  int seen_at = -1;
  NodeEscape first;
  for (int k = 0; k < 600 && seen_at < 0; ++k) {
    double before = -1.0;  // the farthest free node's distance beyond the end, before the step
    for (int i = inst.drive().first_free; i < inst.md().n; ++i)
      before = std::max(before, inst.rod().x[i].z() - length);
    inst.step(&wall, s, push);
    const NodeEscape e = inst.ws.escape(0);
    if (e.node < 0) {
      EXPECT_LT(before, r + 1.5e-3) << "step " << k << ": a node this far out was not seen";
      continue;
    }
    EXPECT_GT(before, r) << "step " << k << ": seen before any node was out";
    seen_at = k;
    first = e;
  }
  ASSERT_GE(seen_at, 0) << "the rod went out of the open end unseen";
  EXPECT_EQ(first.exit, 0);
  EXPECT_EQ(first.node, inst.md().n - 1);
  EXPECT_GT(first.distance, r);
  EXPECT_LT(first.distance, r + 1.5e-3);
}

// The access end's plane is a wall for free nodes (physics.md 6.3): the rod above pushed on
// against an end flagged as the access end is held at its plane (no node beyond it by more than
// its radius, no escape) while the hand keeps pushing, and the wall force reaches the hand.
TEST(Escape, TheAccessEndHoldsAFreeNodeLikeACap) {
  OpenEndTube sc(true);
  const double length = sc.length;
  test::Rig& inst = sc.inst;
  const SolverSettings& s = sc.s;
  StaticWall& wall = sc.wall;
  const double r = sc.d.outer_radius;
  const DriveCommand push{DriveCommand::Mode::kVelocity, 0.05, 0.0};
  double farthest = -1.0, force = 0.0;
  for (int k = 0; k < 600; ++k) {
    inst.step(&wall, s, push);
    EXPECT_LT(inst.ws.escape(0).node, 0) << "step " << k;
    for (int i = inst.drive().first_free; i < inst.md().n; ++i)
      farthest = std::max(farthest, inst.rod().x[i].z() - length);
    force = inst.drive().axial_force;
  }
  EXPECT_LT(farthest, r) << "m beyond the access end's plane";
  EXPECT_GT(farthest, -2 * r) << "the tip must have reached the plane";
  EXPECT_GT(std::abs(force), 0.01) << "N: the hand feels the end";
}

// A rod at rest along a dead-end tube (radius 2 mm, 60 mm), its tip 0.5 mm short of the end's
// cap, pushed in at 3 m/s from one step to the next (a hand faster than any drive lets through,
// as a wave down a chain of scaled masses or a tip let go can be). Detection sees each node at
// rest, so the tip's query reaches just past the gap; the chain's iterations then give the tip
// 3 mm of travel in the step. That node is queried again before the positions, and the cap stops
// it: no node ever lies more than its radius beyond the cap (physics.md 6.3).
TEST(Escape, ANodeSpedUpByItsChainDoesNotCrossTheWallUnseen) {
  const double length = 0.06;
  StraightTube tube(2.0e-3, length, /*cap=*/true);
  RodDef d = test_rod(0.1, 60);
  d.density = scaled_density(d, 1e-3);
  Sheath fast;
  fast.max_speed = 5.0;
  fast.grip_force = 1e3;  // the hand does not slip: the contacts alone must hold the tip
  const double r = d.outer_radius;
  test::Rig inst = test::driven(d, fast, ContactMaterial{0.0, 0.0}, length - r - 0.5e-3);
  SolverSettings s;
  s.rod.dt = 1e-3;
  s.rod.drag = 20.0;
  StaticWall wall = tube.wall();
  const DriveCommand hold{DriveCommand::Mode::kVelocity, 0.0, 0.0};
  for (int k = 0; k < 50; ++k) inst.step(&wall, s, hold);
  ASSERT_LT(inst.rod().x.back().z(), length - r) << "the tip starts short of the cap";
  const DriveCommand push{DriveCommand::Mode::kVelocity, 3.0, 0.0};
  double farthest = -1.0;  // the farthest any node's centre came beyond the cap's plane
  for (int k = 0; k < 5; ++k) {
    inst.step(&wall, s, push);
    for (int i = inst.drive().first_free; i < inst.md().n; ++i)
      farthest = std::max(farthest, inst.rod().x[i].z() - length);
  }
  EXPECT_LT(farthest, r) << "a node crossed the cap";
}

// A free rod lying along the side of a dead-end tube (radius 2 mm, 60 mm), 0.05 mm off the side
// and 0.3 mm short of the cap, every node sliding toward the cap at 1 m/s (1 mm a step): each
// node's query finds the side wall, the nearer face, so the nodes are in contact with it and held
// off it alone; the cap is the face they are about to cross. A node in contact that is about to
// slide further than its gap and the margin is queried where it will arrive, and the cap there
// becomes its second contact: no node ever lies more than its radius beyond the cap (physics.md
// 6.3).
// A tube (radius 2 mm) bent back on itself round a 3 mm bend: its legs 6 mm apart with 2 mm of
// wall between them, a ridge like the carina between the iliacs. Not moved once built (a wall
// points into it).
struct UTube {
  BentTubeSpec spec;
  TriangleMesh mesh;
  AabbTree tree;
  explicit UTube(int sides = 32) {
    spec.sides = sides;
    spec.bend_radius = 3e-3;
    spec.bend_angle = std::numbers::pi;
    mesh = make_bent_tube(spec);
    check_and_repair(mesh);
    tree.build(mesh);
  }
};

// An edge through the wall with both its nodes inside (physics.md 6.3): a tube (radius 2 mm)
// bent back on itself round a 3 mm bend, its two legs 6 mm apart with 2 mm of wall between them
// (a ridge, as the carina between the iliacs), and a free rod of two 3.2 mm edges laid straight
// across at z = 10 mm: nodes at x = -1.8 and 1.4 mm in the first leg, 4.6 mm in the second. Its
// nodes' queries see no escape; the edge check sees the second edge, its deepest point midway
// (x = 3 mm) 1.015 mm behind both walls, and reports it apart from the nodes' escapes. The check
// runs every edge_check_period of simulated time: not in a first step of 0.1 ms at 50 ms.
TEST(Escape, AnEdgeThroughTheWallBetweenNodesInsideIsSeen) {
  const UTube u;
  const double r = 0.2e-3;
  auto first_step = [&](const Vec3& from, const Vec3& dir, double length, double period) {
    RodDef d = test::free_rod(length, 2, r, 2e9);
    d.base_position = from;
    d.base_orientation = Quat::FromTwoVectors(Vec3::UnitZ(), dir);
    SolverSettings s;
    s.rod.dt = 1e-4;
    s.edge_check_period = period;
    s.edge_sample_spacing = 0.0;  // only the nodes collide: the edge stays where it is put
    test::Rig rig = test::free_rod_rig(d, ContactMaterial{0.0, 0.0}, s);
    StaticWall wall(u.mesh, u.tree);
    rig.step(&wall, s, std::span<const DriveCommand>(std::vector<DriveCommand>(1)));
    EXPECT_EQ(rig.ws.escape(0).node, -1) << "no node is out";
    return rig.ws.edge_escape(0);
  };
  // 0.3 mm off the plane of the rings' vertices.
  const Vec3 from(-1.8e-3, 0.3e-3, 10e-3);
  const NodeEscape e = first_step(from, Vec3::UnitX(), 6.4e-3, 0.0);
  EXPECT_TRUE(e.edge);
  EXPECT_EQ(e.node, 1);
  EXPECT_EQ(e.exit, -1);
  EXPECT_NEAR(e.distance, 1.015e-3, 0.02e-3);
  EXPECT_NEAR(e.along, 0.5, 0.02);
  EXPECT_EQ(first_step(from, Vec3::UnitX(), 6.4e-3, 0.05).node, -1) << "no check in this step";
  // The same rod along the first leg's axis: inside, no escape.
  EXPECT_EQ(first_step(Vec3(0, 0.3e-3, 2e-3), Vec3::UnitZ(), 16e-3, 0.0).node, -1);
  SolverSettings bad;
  bad.edge_check_period = -1.0;
  EXPECT_THROW(bad.validate(), InputError);
}

// The ridge tests' rod: three 3 mm edges of radius 0.2 mm laid across the U-tube's bend 0.3 mm
// above the ridge's apex (`apex`), its middle edge over the ridge, mass-scaled for a 1 ms step,
// gravity 20 m/s^2 toward the ridge; samples `spacing` apart (0: none), edges checked every step.
test::Rig rod_over_the_ridge(double apex, double spacing) {
  RodDef d = test::free_rod(9e-3, 3, 0.2e-3, 2e9);
  d.base_position = Vec3(-1.5e-3, 0.3e-3, apex + 0.3e-3);
  d.base_orientation = Quat::FromTwoVectors(Vec3::UnitZ(), Vec3::UnitX());
  d.density = scaled_density(d, 1e-3);
  SolverSettings s;
  s.rod.dt = 1e-3;
  s.rod.gravity = Vec3(0, 0, -20.0);
  s.edge_check_period = 0.0;
  s.edge_sample_spacing = spacing;
  return test::free_rod_rig(d, ContactMaterial{0.3, 0.2}, s);
}

// The collision samples between the nodes (physics.md 6.3): the same tube bent back on itself,
// whose inner wall is a ridge of radius 1 mm round the bend's centre (x = 3 mm, z = 20 mm), its
// apex at z = 21 mm. A rod of three 3 mm edges lies across the bend 0.3 mm above the apex, its
// middle edge over the ridge (nodes at x = 1.5 and 4.5 mm, over the two legs' lumens), and gravity
// pulls it down for 0.1 s. With only the nodes colliding they fall down the legs and the middle
// edge cuts through the ridge; with a sample at each edge's middle it comes to rest on the apex.
TEST(Escape, AnEdgeWithASampleRestsOnARidgeItWouldCutWithout) {
  const UTube u;
  const BentTubeSpec& spec = u.spec;
  const double r = 0.2e-3, apex = spec.straight1 + spec.bend_radius - spec.radius;
  auto fall = [&](double spacing) {
    test::Rig rig = rod_over_the_ridge(apex, spacing);
    StaticWall wall(u.mesh, u.tree);
    NodeEscape crossed;
    for (int k = 0; k < 100; ++k) {
      rig.step(&wall, std::span<const DriveCommand>(std::vector<DriveCommand>(1)));
      EXPECT_EQ(rig.ws.escape(0).node, -1) << "no node is out";
      if (crossed.node < 0) crossed = rig.ws.edge_escape(0);
    }
    return std::make_pair(crossed, Vec3(0.5 * (rig.rod().x[1] + rig.rod().x[2])));
  };
  const auto [cut, cut_middle] = fall(0.0);
  EXPECT_EQ(cut.node, 1) << "without samples the middle edge goes through the ridge";
  EXPECT_LT(cut_middle.z(), apex - 2e-3);
  const auto [held, middle] = fall(2e-3);  // one sample in each edge, at its middle
  EXPECT_EQ(held.node, -1) << "no edge through the wall";
  EXPECT_NEAR(middle.z(), apex + r, 0.1e-3) << "resting on the apex";
  EXPECT_NEAR(middle.x(), spec.bend_radius, 0.2e-3);
  SolverSettings bad;
  bad.edge_sample_spacing = -1.0;
  EXPECT_THROW(bad.validate(), InputError);
}

// A collision sample's own clearance (physics.md 6.3): like a node, a sample in the open lumen
// is queried coherence_margin wider than its reach and then skipped until it has moved that far;
// the nodes' gaps alone would have it queried every step in the middle of a long edge. A rod of
// three 2.6 mm edges (nodes at x = -0.9, 1.7, 4.3 and 6.9 mm, over the U-tube's legs, a sample at
// each edge's middle) lies 1.5 mm above the ridge's apex and falls at 50 mm/s: the middle edge's
// sample is what meets the ridge. It is queried on a few of the 20 steps before it nears the
// ridge, and the rod comes to rest on the apex as when the samples are queried every step (no
// coherence margin).
TEST(Escape, ASampleIsSkippedInTheOpenLumenAndStillMeetsTheRidge) {
  const UTube u;
  const BentTubeSpec& spec = u.spec;
  const double r = 0.2e-3, apex = spec.straight1 + spec.bend_radius - spec.radius;
  auto fall = [&](double margin) {
    RodDef d = test::free_rod(7.8e-3, 3, r, 2e9);
    d.base_position = Vec3(-0.9e-3, 0.3e-3, apex + r + 1.5e-3);
    d.base_orientation = Quat::FromTwoVectors(Vec3::UnitZ(), Vec3::UnitX());
    d.density = scaled_density(d, 1e-3);
    SolverSettings s;
    s.rod.dt = 1e-3;
    s.edge_check_period = 0.0;
    s.edge_sample_spacing = 2e-3;
    s.coherence_margin = margin;
    test::Rig rig = test::free_rod_rig(d, ContactMaterial{0.3, 0.2}, s);
    for (Vec3& v : rig.rod().v) v = Vec3(0, 0, -0.05);
    StaticWall wall(u.mesh, u.tree);
    int early = 0;  // the middle sample's queries in the first 20 steps (1 mm of fall)
    bool crossed = false;
    for (int k = 0; k < 100; ++k) {
      StepProfile prof;
      rig.step(&wall, std::span<const DriveCommand>(std::vector<DriveCommand>(1)), &prof);
      if (k < 20) early += prof.num_sample_queries;
      EXPECT_EQ(rig.ws.escape(0).node, -1) << "no node is out";
      crossed = crossed || rig.ws.edge_escape(0).node >= 0;
    }
    EXPECT_FALSE(crossed) << "no edge through the wall";
    EXPECT_FALSE(rig.ws.edge_contacts(0).empty()) << "held by its sample";
    return std::make_pair(early, Vec3(0.5 * (rig.rod().x[1] + rig.rod().x[2])));
  };
  const auto [every, every_middle] = fall(0.0);
  const auto [skipped, middle] = fall(SolverSettings{}.coherence_margin);
  EXPECT_EQ(every, 3 * 20) << "without a margin each sample is queried every step";
  EXPECT_LE(skipped, 3 * 4);
  EXPECT_GE(skipped, 3);
  EXPECT_NEAR(middle.z(), apex + r, 0.1e-3) << "resting on the apex";
  EXPECT_NEAR(middle.z(), every_middle.z(), 0.02e-3);
  EXPECT_NEAR(middle.x(), spec.bend_radius, 0.2e-3);
}

// SolverWorkspace::clear_caches (a lumen rebuilt, as when a lesion opens) forgets the collision
// samples' leaf caches as well as the nodes': the rod of the test above resting on the ridge by
// its samples, then the tube remeshed (24 sides for 32), steps the same as a fresh workspace from
// the same state. Keeping the old tree's leaves, a sample meets the wrong triangles.
TEST(Escape, ClearCachesForgetsTheSamplesLeavesToo) {
  const UTube before(32), after(24);
  const double apex = before.spec.straight1 + before.spec.bend_radius - before.spec.radius;
  const std::vector<DriveCommand> still(1);
  test::Rig rig = rod_over_the_ridge(apex, 2e-3);
  StaticWall first(before.mesh, before.tree), second(after.mesh, after.tree);
  for (int k = 0; k < 100; ++k) rig.step(&first, still);
  ASSERT_FALSE(rig.ws.edge_contacts(0).empty()) << "resting on its samples";
  const SolverState rested = rig.state;
  rig.ws.clear_caches();
  test::Rig fresh = rod_over_the_ridge(apex, 2e-3);
  fresh.state = rested;
  for (int k = 0; k < 20; ++k) {
    rig.step(&second, still);
    fresh.step(&second, still);
  }
  EXPECT_FALSE(fresh.ws.edge_contacts(0).empty()) << "still resting on the remeshed ridge";
  EXPECT_EQ(rig.state.hash(), fresh.state.hash());
}

TEST(Escape, ANodeSlidingAlongOneWallDoesNotCrossAnotherUnseen) {
  const double length = 0.06, radius = 2.0e-3, r = 0.2e-3, dt = 1e-3;
  StraightTube tube(radius, length, /*cap=*/true);
  RodDef d = test::free_rod(10e-3, 10, r, 2e9);
  d.density = scaled_density(d, dt);
  // The tube's facets lie within 17 um of 2 mm.
  d.base_position = Vec3(radius - r - 0.05e-3, 0, length - 10e-3 - r - 0.3e-3);
  test::Rig rig = test::free_rod_rig(d, ContactMaterial{0.0, 0.0});
  SolverSettings s;
  s.rod.dt = dt;
  s.rod.drag = 20.0;
  StaticWall wall = tube.wall();
  for (Vec3& v : rig.rod().v) v = Vec3(0, 0, 1.0);
  double farthest = -1.0;  // the farthest any node's centre came beyond the cap's plane
  int side_contacts = 0;   // contacts on the side wall after the first step
  for (int k = 0; k < 10; ++k) {
    rig.step(&wall, s, std::span<const DriveCommand>(std::vector<DriveCommand>(1)));
    if (k == 0)
      for (const NodeContact& c : rig.contacts()) side_contacts += std::abs(c.normal.z()) < 0.1;
    for (const Vec3& x : rig.rod().x) farthest = std::max(farthest, x.z() - length);
  }
  EXPECT_GE(side_contacts, 10) << "the nodes were held by the side wall";
  EXPECT_LT(farthest, r) << "a node sliding along the side crossed the cap";
}
