// vcsim rod: an inextensible Cosserat rod after CoRdE (Spillmann and Teschner 2007) as modified
// by VCSim3: mass points on the centreline, one quaternion material frame per edge, bending and
// twisting from the discrete Darboux vector, a penalty ("parallel constraint") holding each edge
// along its frame's third director, and a chain of distance constraints solved globally.
//
// Indexing: n nodes x_0 .. x_{n-1}, m = n - 1 edges; edge j joins x_j and x_{j+1} and carries
// frame q_j. Vertex v (0 .. m) sits between frame v-1 and frame v; vertex 0 couples the base
// clamp frame to q_0 and vertex m couples q_{m-1} to the tip clamp frame (both only when the
// clamp is active). Everything is SI (m, kg, s, N, Pa, rad).
#pragma once

#include <Eigen/Cholesky>

#include "vcsim/core.h"

#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace vcsim {

// One section of a shaped tip. Sections are listed from proximal to distal and occupy the distal
// end of the rod. An arc bends about the axis cos(plane) d1 + sin(plane) d2 of the current frame.
struct TipSection {
  enum class Kind { kStraight, kArc };
  Kind kind = Kind::kStraight;
  double length = 0.0;  // straight sections (m)
  double radius = 0.0;  // arc radius (m)
  double angle = 0.0;   // arc angle (rad)
  double plane = 0.0;   // bending plane about d3 (rad)

  static TipSection straight(double length_m) { return {Kind::kStraight, length_m, 0, 0, 0}; }
  static TipSection arc(double radius_m, double angle_rad, double plane_rad = 0.0) {
    return {Kind::kArc, radius_m * (angle_rad < 0 ? -angle_rad : angle_rad), radius_m, angle_rad,
            plane_rad};
  }
};

enum class BoundaryKind {
  kFree,     // nothing held
  kPinned,   // end node held in place, frame free
  kClamped,  // end node held and the end frame held by a clamp frame (half-vertex coupling)
};

// Definition of a rod (what an instrument file describes). Defaults give a 100 mm polymer rod.
struct RodDef {
  double length = 0.1;            // rest length (m)
  int segments = 32;              // number of edges (nodes = segments + 1)
  double grading = 1.0;           // distal / proximal segment length (< 1: finer toward the tip)
  double youngs_modulus = 1.0e9;  // shaft E (Pa)
  double shear_modulus = 0.0;     // G (Pa); 0 means E / (2 (1 + poisson))
  double poisson = 0.3;
  double outer_radius = 0.5e-3;    // (m)
  double inner_radius = 0.0;       // (m), 0 for a solid wire
  double density = 1000.0;         // (kg/m^3)
  double tip_length = 0.0;         // soft tip length (m)
  double tip_modulus_ratio = 1.0;  // alpha = E_tip / E_shaft, in (0, 1]
  // A wire's ground core: over core_taper_length proximal to the soft tip, E and G rise from the
  // tip's to the shaft's as a core whose diameter grows linearly would, (a + (1 - a) u)^4 with
  // a = alpha^(1/4) and u from 0 at the soft tip to 1 at the shaft (m; 0 for a step).
  double core_taper_length = 0.0;
  // Tapered distal end (a balloon catheter's tip): the outer radius falls linearly over the last
  // taper_length to taper_outer_radius at the tip; section, mass and stiffness follow. 0: none.
  double taper_length = 0.0;          // (m)
  double taper_outer_radius = 0.0;    // (m), in (inner_radius, outer_radius] when tapered
  std::vector<TipSection> tip_shape;  // rest shape of the distal end
  // Parallel-constraint penalty K_p (N). 0 selects the physical shear stiffness kappa G A
  // (kappa = 0.9), which makes the model a discrete Timoshenko rod.
  double parallel_stiffness = 0.0;
  // Scales the frames' rotational inertia; > 1 relaxes the explicit time-step limit at the cost
  // of rotary inertia (negligible for low bending modes while scale * I k^2 << A).
  double rotational_inertia_scale = 1.0;
  Vec3 base_position = Vec3::Zero();
  Quat base_orientation = Quat::Identity();  // d3 of this frame is the rod's initial direction
  BoundaryKind base = BoundaryKind::kClamped;
  BoundaryKind tip = BoundaryKind::kFree;
  bool start_in_rest_shape = false;  // otherwise start straight along the base d3

  // Checks every field; throws InputError naming `source` and the field.
  void validate(const std::string& source = "rod") const;
};

// The immutable model built from a RodDef (flat arrays, sizes in comments).
struct RodModel {
  int n = 0;  // nodes
  int m = 0;  // edges
  double length = 0.0;
  BoundaryKind base = BoundaryKind::kFree;
  BoundaryKind tip = BoundaryKind::kFree;

  std::vector<double> rest_length;      // (m) edge rest lengths
  std::vector<double> edge_s;           // (m) arc length at edge midpoints
  std::vector<double> node_s;           // (n) arc length at nodes
  std::vector<double> node_mass;        // (n)
  std::vector<double> inv_mass;         // (n) 0 for held nodes
  std::vector<Vec3> inertia;            // (m) body-frame diagonal rotational inertia
  std::vector<Vec3> inv_inertia;        // (m)
  std::vector<double> kp;               // (m) parallel-constraint stiffness K_p
  std::vector<double> axial_stiffness;  // (m) E A, used by the penalty stretch method
  std::vector<double> youngs;           // (m) E per edge (soft tip applied)
  std::vector<double> shear;            // (m) G per edge
  std::vector<double> outer_radius;     // (m)
  std::vector<double> inner_radius;     // (m)
  std::vector<double> area;             // (m) cross-section A
  std::vector<double> bend_inertia;     // (m) I
  std::vector<double> vertex_length;    // (m+1) Voronoi length of each vertex
  std::vector<Vec3> vertex_stiffness;   // (m+1) (K1, K2, K3) = (E I, E I, G J), series-averaged
  std::vector<Vec3> rest_darboux;       // (m+1) intrinsic Darboux vector Omega_0 (1/m)
  std::vector<unsigned char> vertex_active;  // (m+1) 0 for boundary vertices without a clamp

  std::vector<Vec3> rest_position;  // (n) designed rest shape (base pose applied)
  std::vector<Quat> rest_frame;     // (m)

  // Every value into `h` (a model that a run must not change is checked by its hash).
  void hash_into(StateHasher& h) const;
};

// Everything that changes during a run (structure of arrays). Copying it is a snapshot.
struct RodState {
  std::vector<Vec3> x;                 // (n) positions
  std::vector<Vec3> v;                 // (n) velocities
  std::vector<Quat> q;                 // (m) unit quaternions, material frame -> world
  std::vector<Vec3> omega;             // (m) angular velocities in the body frame
  std::vector<Vec3> f_ext;             // (n) applied forces, world (inputs, held until changed)
  std::vector<Vec3> tau_ext;           // (m) applied torques, world
  Quat base_frame = Quat::Identity();  // clamp frames (inputs: turning one twists the rod)
  Quat tip_frame = Quat::Identity();
  double time = 0.0;
  long long steps = 0;
  // Outputs of the last step: what the rod exerts on its base and tip supports.
  Vec3 base_force = Vec3::Zero();
  Vec3 base_torque = Vec3::Zero();
  Vec3 tip_force = Vec3::Zero();
  Vec3 tip_torque = Vec3::Zero();

  // FNV-1a over every value above; equal states give equal hashes.
  std::uint64_t hash() const;
  void hash_into(StateHasher& h) const;
};

enum class DistanceMethod {
  kGlobal,       // tridiagonal J W J^T solved directly (LAPACK dpttrf/dpttrs) per iteration
  kLocalGS,      // local Gauss-Seidel sweep
  kLocalJacobi,  // local Jacobi sweep
  kPenalty,      // original CoRdE: extensible, stretch as a stiff spring (E A)
};

const char* to_string(DistanceMethod m);
DistanceMethod distance_method_from_string(const std::string& s, const std::string& source);

// How velocities follow from the forces (physics.md 5.3, 5.5).
enum class Integrator {
  // Forces at the start of the step (eq. 9): stable only while the step resolves the stiffest
  // mode, so fine instruments need mass scaling (5.4).
  kSymplecticEuler,
  // One Newton step of backward Euler on the elastic forces (bending, twisting, the parallel
  // penalty) with their Gauss-Newton Hessian and a block-tridiagonal solve: stable at any step
  // with the instrument's physical mass.
  kLinearlyImplicit,
};

struct RodSettings {
  double dt = 1.0e-3;  // (s)
  Integrator integrator = Integrator::kSymplecticEuler;
  Vec3 gravity = Vec3::Zero();  // (m/s^2)
  DistanceMethod distance = DistanceMethod::kGlobal;
  int iterations = 1;                  // block solver iterations
  double drag = 0.0;                   // mass-proportional damping of node velocities (1/s)
  double angular_drag = 0.0;           // inertia-proportional damping of frame spin (1/s)
  double internal_damping = 0.0;       // stiffness-proportional damping time beta (s)
  double penalty_modulus_scale = 1.0;  // scales E A for the penalty stretch method

  void validate(const std::string& source = "settings") const;
};

// Wall-clock time per stage of the last step (microseconds).
struct RodProfile {
  double forces = 0, integrate_velocities = 0, constraints = 0, integrate_positions = 0, total = 0;
};

// Scratch memory sized once, so that a step allocates nothing.
struct RodWorkspace {
  std::vector<Vec3> force;   // (n)
  std::vector<Vec3> torque;  // (m) world
  // (9 m) the frames' rotation matrices of this step (material -> world) as a structure of
  // arrays, so that the force loops vectorise: entry (r, c) of frame j is rot[(3 c + r) m + j].
  std::vector<double> rot;
  std::vector<Vec3> dir;                           // (m) constraint directions
  std::vector<double> diag, offdiag, rhs, lambda;  // (m) tridiagonal system
  std::vector<Vec3> dv;                            // (n) Jacobi accumulator
  std::vector<Vec3> pred;                          // (n) predicted positions x + dt v
  // Per-step effective inverse masses: the model's, with nodes and frames held by a drive or a
  // clamp set to zero (rod_begin_step copies the model's; a drive may then hold more).
  std::vector<double> inv_mass;           // (n)
  std::vector<double> frame_free;         // (m) 1 for a dynamic frame, 0 for a prescribed one
  std::vector<std::uint64_t> frame_mask;  // (m) frame_free as a bit mask (rod step scratch)
  std::vector<Vec3> node_impulse;  // (n) constraint impulses of this step (N s), held nodes too
  std::vector<double> scratch;     // 6 (m + 2): per-vertex and per-edge terms of rod_forces
  // Integrator::kLinearlyImplicit, sized on its first step: per node-and-frame pair p (node p,
  // frame p), the blocks of the symmetric (M + dt^2 H) coupling p to p and to p + 1, the
  // factors of the eliminated diagonal, the forces and the right-hand side.
  using Mat6 = Eigen::Matrix<double, 6, 6>;
  using Vec6 = Eigen::Matrix<double, 6, 1>;
  std::vector<Mat6> imp_diag, imp_upper;
  std::vector<Eigen::LLT<Mat6>> imp_llt;
  std::vector<Vec6> imp_force, imp_rhs;
  void resize(const RodModel& model);
  // Frame j's rotation matrix gathered from `rot`.
  Mat3 frame_rotation(int j) const;
};

RodModel build_rod(const RodDef& def);
RodState make_state(const RodModel& model, const RodDef& def);

// Advances one step of settings.dt: forces, velocity integration, `iterations` constraint
// iterations, position integration, quaternion renormalisation. No heap allocation.
void rod_step(const RodModel& model, const RodSettings& settings, RodState& state, RodWorkspace& ws,
              RodProfile* profile = nullptr);

// The stages rod_step runs, for a solver that interleaves other constraints (contacts, drives,
// coupling) with the distance solve. Order: begin, forces, integrate_velocities, then
// `iterations` x (distance_iteration, other constraints), then integrate_positions, end.
void rod_begin_step(const RodModel& model, RodWorkspace& ws);
void rod_forces(const RodModel& model, const RodSettings& settings, RodState& state,
                RodWorkspace& ws);
void rod_integrate_velocities(const RodModel& model, const RodSettings& settings, RodState& state,
                              RodWorkspace& ws);
void rod_distance_iteration(const RodModel& model, const RodSettings& settings, RodState& state,
                            RodWorkspace& ws);
void rod_integrate_positions(const RodModel& model, const RodSettings& settings, RodState& state,
                             RodWorkspace& ws);
// Time, step count and the support reactions (base/tip force from the held nodes' balance).
void rod_end_step(const RodModel& model, const RodSettings& settings, RodState& state,
                  const RodWorkspace& ws);

// Largest step for which explicit integration of the model's stiffest mode stays stable
// (a conservative estimate; see docs/physics.md).
double estimate_stable_dt(const RodModel& model, const RodSettings& settings);

// Selective mass scaling for a quasi-static explicit step of `dt` (physics.md 5.4): caps the
// parallel-constraint penalty at `kp_ratio` E I / l^2 per edge (still far stiffer than bending
// at the segment scale), then raises each node's mass and each frame's inertia only as far as
// its own stiffness needs (2 k dt^2), so that the fine tip does not make the whole rod heavy.
// Afterwards estimate_stable_dt(model, {}) >= dt. Returns the added mass (kg).
double scale_for_time_step(RodModel& model, double dt, double kp_ratio = 20.0);

// The quasi-static instruments (the simulator's, and the wire-in-catheter scene of the pair bench
// and tests), physics.md 5.4: the parallel-constraint cap for scale_for_time_step, and light
// damping for settings.dt: mass- and inertia-proportional drag of 0.5 / s (the nodes' scaled mass
// is small where the shaft is coarse, so a little settles it without loading a long inserted
// shaft axially) and stiffness-proportional damping of 0.4 dt (it takes out the fast release of
// stored bending, a catheter's curve whipping round, without loading insertion the way
// mass-proportional drag does; stable for beta w^2 dt < 1 with w dt <= 1).
inline constexpr double kQuasiStaticKpRatio = 5.0;
void set_quasi_static_damping(RodSettings& settings);

// Diagnostics.
double centreline_length(const RodState& state);
double max_stretch(const RodModel& model, const RodState& state);  // max |len/rest - 1|
double max_speed(const RodState& state);
// The discrete Darboux vector between two frames over the length l (frame a's coordinates),
// with the quaternion double cover resolved.
Vec3 darboux(const Quat& qa, const Quat& qb, double l);
// The bending and twisting moment (N m, world) at vertex k that frame k exerts on frame k - 1
// (physics.md eqs. 2-5, the torque the step adds to frame k - 1); zero at the rod's end vertices
// (k = 0, m: a clamp's moment is not computed here).
Vec3 vertex_moment(const RodModel& model, const RodState& state, int k);
// The elastic energy (J) of bending and twisting (physics.md eq. 5, l_v / 2 (Omega - Omega0)^T K
// (Omega - Omega0) over the interior vertices) and of the parallel-constraint penalty (eq. 6,
// K_p l / 2 |u - (u . d3) d3|^2 over the edges); the stretch penalty is not included.
double elastic_energy(const RodModel& model, const RodState& state);

}  // namespace vcsim
