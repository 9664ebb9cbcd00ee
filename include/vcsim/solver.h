// vcsim solver: an instrument (a rod) driven through an access sheath inside a vessel lumen.
// One step: drive kinematics, forces, velocities, collision detection, then N block iterations
// of [global distance solve, contacts with Coulomb friction], then positions
// (docs/architecture.md).
#pragma once

#include <array>
#include <span>
#include <vector>

#include "vcsim/collision.h"
#include "vcsim/rod.h"

namespace vcsim {

// The vessel wall instruments collide with. The solver asks it once per step and instrument for
// the contacts of spheres (nodes); a moving wall (anatomy's beating lumen, BeatingWall) first
// brings the part of itself those spheres can reach to the current time, so the interface is
// not const. Owned by the caller; one wall serves every instrument of a step.
class VesselWall {
 public:
  virtual ~VesselWall() = default;
  // Contact of each sphere with the wall (see AabbTree::query_spheres). Allocates nothing.
  virtual void query_spheres(std::span<const Vec3> centres, std::span<const double> radii,
                             std::span<SphereContact> out) = 0;
  // The same with a leaf cache per sphere (see LeafCache), refilled reaching `slack` m further.
  // A wall that is not one static tree ignores the caches (the default).
  virtual void query_spheres(std::span<const Vec3> centres, std::span<const double> radii,
                             std::span<LeafCache* const> caches, double slack,
                             std::span<SphereContact> out) {
    (void)caches;
    (void)slack;
    query_spheres(centres, radii, out);
  }
  // Velocity of the wall (m/s) at a contact the last query returned; zero for a static wall.
  virtual Vec3 velocity(const SphereContact& hit) const;
  // Bound on the wall's speed anywhere (m/s), 0 for a static wall. Lets the contact detection
  // skip nodes that cannot have reached the wall since their last query.
  virtual double speed_bound() const { return 0.0; }
};

// A wall that does not move: a lumen mesh and its AABB tree (owned elsewhere, must outlive it).
// The cached queries of a batch are independent (each writes its own contact and leaf cache), so
// a batch of at least `parallel_min` spheres is split across the TBB worker threads, in chunks of
// at least kParallelChunk; the results do not depend on the number of threads. 0: always serial.
class StaticWall final : public VesselWall {
 public:
  static constexpr int kParallelChunk = 8;
  StaticWall(const TriangleMesh& mesh, const AabbTree& tree, int parallel_min = 2 * kParallelChunk)
      : mesh_(&mesh), tree_(&tree), parallel_min_(parallel_min) {}
  void query_spheres(std::span<const Vec3> centres, std::span<const double> radii,
                     std::span<SphereContact> out) override;
  void query_spheres(std::span<const Vec3> centres, std::span<const double> radii,
                     std::span<LeafCache* const> caches, double slack,
                     std::span<SphereContact> out) override;

 private:
  const TriangleMesh* mesh_;
  const AabbTree* tree_;
  int parallel_min_;
};

// Coulomb friction between an instrument and the vessel wall.
struct ContactMaterial {
  double mu_static = 0.1;
  double mu_dynamic = 0.08;
  void validate(const std::string& source = "contact") const;
};

// Access sheath: the instrument enters the body at access_point along d3 of `frame`; d1 is the
// reference for the roll angle. The part outside the body stays on the sheath axis.
struct Sheath {
  Vec3 access_point = Vec3::Zero();
  Quat frame = Quat::Identity();
  double max_speed = 0.5;  // m/s: translation rate limit (a tracked device cannot jump)
  double max_spin = 30.0;  // rad/s: rotation rate limit
  // The introducer sheath's straight tube inside the body, from the access point along the axis:
  // its length (0: none) and lumen radius (m). Free nodes inside it are held within its lumen
  // (physics.md 6.2) instead of meeting the vessel wall.
  double length = 0.0;
  double inner_radius = 0.0;
};

// What the hand does at the sheath this step.
struct DriveCommand {
  enum class Mode { kPosition, kVelocity };
  Mode mode = Mode::kVelocity;
  double translation = 0.0;  // position mode: inserted depth (m); velocity mode: m/s
  double rotation = 0.0;     // position mode: roll (rad); velocity mode: rad/s
};

struct DriveState {
  double depth = 0.0;        // inserted length beyond the access point (m)
  double roll = 0.0;         // rad
  double depth_rate = 0.0;   // m/s over the last step
  double roll_rate = 0.0;    // rad/s over the last step
  double axial_force = 0.0;  // N at the hand along the axis, > 0 when the rod resists insertion
  double torque = 0.0;       // N m at the hand about the axis, > 0 when it resists positive roll
  int first_free = 0;        // first node inside the body
  // The hand force and torque before the optional low-pass (SolverSettings::feedback_cutoff_hz;
  // physics.md 6.1); equal to axial_force and torque without it.
  double axial_force_raw = 0.0;  // N
  double torque_raw = 0.0;       // N m
};

// One contact of a node with the wall, solved in the block iterations.
struct NodeContact {
  int node = 0;
  Vec3 normal = Vec3::Zero();         // into the lumen
  double depth = 0.0;                 // > 0 penetration, < 0 speculative gap (m)
  double lambda_n = 0.0;              // accumulated normal impulse (N s)
  Vec3 lambda_t = Vec3::Zero();       // accumulated friction impulse (N s)
  Vec3 wall_velocity = Vec3::Zero();  // of the wall at the contact (m/s)
  double lambda_bias = 0.0;  // part of lambda_n taken back after the step (penetration fix-up)
};

struct Instrument {
  RodModel model;
  RodState state;
  RodWorkspace ws;
  Sheath sheath;
  ContactMaterial contact;
  DriveState drive;
  bool driven = true;  // false: a free rod (no sheath), e.g. lying on a surface
  // Entirely outside the body and not being inserted: the step skips it (nothing of it moves;
  // the owner sets and clears it, e.g. a wire waiting on the table).
  bool parked = false;
  // Contact scratch (sized once).
  std::vector<SphereContact> hits;       // (n)
  std::vector<Vec3> query_centre;        // (n) where each node was last queried
  std::vector<double> clearance;         // (n) wall-free radius around query_centre (0: unknown)
  std::vector<NodeContact> contacts;     // active contacts, capacity n
  std::vector<int> query_nodes;          // (n) nodes queried this step
  std::vector<Vec3> query_points;        // (n)
  std::vector<double> query_radii;       // (n)
  std::vector<LeafCache> leaf_cache;     // (n) wall leaves near each node (static walls)
  std::vector<LeafCache*> query_caches;  // (n) the queried nodes' caches
  std::vector<unsigned char> sheathed;   // (n) 1: inside another instrument's lumen this step
  std::vector<Vec3> coupling_impulse;    // (n) coaxial coupling impulses on each node this step
  // Hand-force scratch (physics.md 6.1): reactions of inner instruments on this one's nodes, and
  // each node's wall contact and coupling contact this step (-1: none).
  std::vector<Vec3> felt_load;       // (n)
  std::vector<int> wall_contact_of;  // (n)
  std::vector<int> coupling_of;      // (n)
  std::vector<int> rim_of;           // (n) the rim contact of the edge from node i (-1: none)
  double wall_travel = 0.0;          // wall motion bound accumulated since the queries
  std::array<double, 3> stage_us{};  // profile scratch: this instrument's stage times (us)
};

// Builds a driven instrument lying on the sheath axis with `depth` inserted. The rod's own
// boundaries must be free (the drive holds the outside part). Throws InputError for bad input.
Instrument make_instrument(const RodDef& def, const Sheath& sheath, const ContactMaterial& contact,
                           double depth, double roll = 0.0);
// A free rod (no drive), e.g. for friction experiments.
Instrument make_free_instrument(const RodDef& def, const ContactMaterial& contact);

struct SolverSettings {
  RodSettings rod;
  bool collisions = true;
  double contact_margin = 2e-4;         // m, speculative: contacts within this gap are solved
  double penetration_correction = 0.5;  // fraction of a penetration removed per step
  double coherence_margin = 0.6e-3;     // m, query radius beyond contact reach (for skipping)
  double leaf_cache_slack = 0.1e-3;  // m, how far a node may move before its leaves are re-listed
  // How the hand's axial force is formed (physics.md 6.1). kQuasiStatic (the default): the
  // reactions a rod of negligible mass (nodes and frames) would need in the step's shape, walked
  // from the tip; free of the scaled inertia. kImpulses: the step's own wall and coupling reactions
  // (less their fix-ups) and applied loads, carrying the scaled momentum they stop (8-15 times
  // the spikes in the default scenario). Both follow the capstan equation in slow motion
  // (tests/solver/test_feedback.cpp). The torque is the hub's twisting moment either way.
  enum class HandForce { kImpulses, kQuasiStatic };
  HandForce hand_force = HandForce::kQuasiStatic;
  // Optional first-order low-pass of the hand force and torque for a haptic device (Hz);
  // 0 reports the raw signal.
  double feedback_cutoff_hz = 0.0;
  // Steps with several instruments of 256 nodes or more run each instrument's forces,
  // integration and distance solve on the TBB threads (same results, bit for bit).
  bool parallel_instruments = true;
  void validate(const std::string& source = "solver") const;
};

struct StepProfile {
  double drive = 0, forces = 0, integrate_velocities = 0, collision = 0, constraints = 0,
         distance = 0, contacts = 0, integrate_positions = 0, total = 0;  // microseconds
  int num_contacts = 0;
  int num_queries = 0;
};

// One step of an instrument inside a vessel wall (nullptr: no collisions). No heap allocation
// once warm.
void instrument_step(Instrument& inst, VesselWall* wall, const SolverSettings& settings,
                     const DriveCommand& command, StepProfile* profile = nullptr);

// One wire node held inside the outer instrument's lumen (concentric constraint).
struct CoaxialContact {
  int node = 0;                // inner instrument's node
  int segment = 0;             // outer instrument's edge: nodes segment, segment + 1
  double t = 0.0;              // position of the projection on that edge (0 .. 1)
  Vec3 normal = Vec3::Zero();  // from the outer centreline toward the inner node
  double excess = 0.0;         // radial offset beyond the clearance (> 0 violated, < 0 gap), m
  double lambda_n = 0.0;
  Vec3 lambda_t = Vec3::Zero();
  // The inner point: node + a (node + 1 - node). Above 0 only for a rim contact: the inner rod's
  // edge leaving through the outer one's distal end, against its rim (outer node segment + 1).
  double a = 0.0;
};

// An inner instrument (wire) running in the lumen of an outer one (catheter). Both enter through
// the same sheath. Wire nodes whose inserted arc length is within the catheter's inserted depth
// are held within the clearance (ID - wire OD) / 2 by impulses perpendicular to the catheter,
// shared by the two nearest catheter nodes in proportion to their distance (VCSim3's concentric
// constraints), with optional lumen friction; they skip the wall collision.
struct Coupling {
  int inner = 0;
  int outer = 1;
  double mu = 0.04;  // wire-in-catheter lumen friction (clinical.md)
  // The edges that leave through the outer instrument's distal opening pass inside its rim and
  // wrap round it (physics.md 7.1); false: only the nodes are held (VCSim3's constraints).
  bool rim = true;
  std::vector<CoaxialContact> contacts;  // scratch, capacity = inner nodes
  double clearance = 0.0;                // m, set by step_instruments
};

// One step of several instruments in one lumen with their couplings (commands[i] drives
// instruments[i]). profile, if given, receives the sum over instruments.
void step_instruments(std::span<Instrument> instruments, std::span<Coupling> couplings,
                      VesselWall* wall, const SolverSettings& settings,
                      std::span<const DriveCommand> commands, StepProfile* profile = nullptr);

// Diagnostics: the centreline's arc length inside the body and its rest length.
double compression(const Instrument& inst);  // (rest - arc) / rest over the whole rod

}  // namespace vcsim
