// vcsim render: fluoroscopy. C-arm geometry (DICOM angles), X-ray materials, closed meshes for
// the patient and the instruments, a path-length renderer (OpenGL 3.3 core, kept out of this
// header), the image chain (Beer-Lambert, quantum noise, log, window/level) and PNG output.
// SI units (m, rad in code, degrees where the name says deg); patient coordinates are LPS
// (+x patient left, +y posterior, +z head). Equations: docs/rendering.md.
#pragma once

#include "vcsim/anatomy.h"
#include "vcsim/collision.h"
#include "vcsim/core.h"
#include "vcsim/instruments.h"
#include "vcsim/sim.h"

#include <array>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <random>
#include <span>
#include <string>
#include <vector>

namespace vcsim {

// ---------------------------------------------------------------------------------------------
// C-arm geometry (GL-free, unit-tested)

inline constexpr double kPrimaryLimitDeg = 120.0;   // |primary| at most (LAO/RAO)
inline constexpr double kSecondaryLimitDeg = 60.0;  // |secondary| at most (CRA/CAU)

struct CArmPose {
  double primary_deg = 0.0;       // DICOM primary angle: + LAO, - RAO
  double secondary_deg = 0.0;     // DICOM secondary angle: + CRA, - CAU
  double sid = 1.200;             // m, source to detector
  double sod = 0.780;             // m, source to isocentre
  double fov = 0.200;             // m, side of the square detector field shown (zoom)
  Vec3 isocentre = Vec3::Zero();  // m, LPS: the patient point the table pan puts at the isocentre

  // Throws InputError(source, "primary_deg" | "secondary_deg" | "sid" | "sod" | "fov" |
  // "isocentre", ...) for a value out of its range (angles above, sid in [0.8, 1.5] m,
  // sod in [0.4 m, sid - 0.1 m], fov in [0.05, 0.5] m).
  void validate(const std::string& source) const;
};

// The C-arm in patient coordinates for a pose.
struct CArmFrame {
  Vec3 source;           // m, focal spot
  Vec3 detector_centre;  // m
  Vec3 beam;             // unit, source -> detector (central ray)
  Vec3 image_right;      // unit, the displayed image's +column direction on the detector
  Vec3 image_up;         // unit, the displayed image's up direction (row 0 is the top)
};
CArmFrame carm_frame(const CArmPose& pose);

using Mat4 = Eigen::Matrix4d;
// Patient (LPS, m) -> eye coordinates: x = image_right, y = image_up, z = -beam, origin at the
// source. The image is shown as seen from the detector, so this basis is a mirror (left-handed);
// the renderer swaps its front-face winding accordingly.
Mat4 carm_view_matrix(const CArmPose& pose);
// Eye -> clip: a perspective frustum through the detector field (fov x fov at distance sid).
Mat4 carm_projection_matrix(const CArmPose& pose, double near_m, double far_m);
// Where the ray from the source through p meets the detector plane: m from the detector centre
// along (image_right, image_up). p must lie in front of the source.
Eigen::Vector2d project_to_detector(const CArmPose& pose, const Vec3& p);
// Geometric magnification of a point: sid / (its distance from the source along the beam).
double magnification(const CArmPose& pose, const Vec3& p);

// ---------------------------------------------------------------------------------------------
// X-ray materials

// One path-length channel each (three RGBA float targets).
enum class XrayMaterial : std::uint8_t {
  kSoftTissue,  // the torso (every other part lies inside it)
  kLung,
  kBone,     // cortical bone; body parts use a cortical fill fraction (see body_part_mesh)
  kBlood,    // vessel lumen
  kIodine,   // contrast: lumen path length weighted by concentration (fraction of 350 mgI/ml)
  kNitinol,  // guidewire cores
  kSteel,    // 316L: catheter braid, wire cores
  kPtIr,     // Pt90/Ir10 coils and marker bands
  kCoCr,     // cobalt-chromium (L-605): stent struts
};
inline constexpr int kNumXrayMaterials = 9;
std::string_view to_string(XrayMaterial m);

enum class BeamEnergy : std::uint8_t { k60keV, k80keV };

// Linear attenuation coefficient, 1/m (shared/reference/clinical.md, from NIST tables). Iodine is
// the term added to blood by 350 mgI/ml contrast. Lung: soft tissue scaled by lung density
// (0.26 g/cm^3, an estimate for an inflated lung).
double attenuation_per_m(XrayMaterial m, BeamEnergy e);

// Weights w_k (1/m) of the line integral p = sum_k w_k L_k. Every part lies inside the torso, so
// each material counts by what it adds over the soft tissue it displaces (mu_k - mu_soft); the
// torso itself counts mu_soft; iodine counts its own term (it adds to blood).
std::array<float, kNumXrayMaterials> line_integral_weights(BeamEnergy e);

// ---------------------------------------------------------------------------------------------
// Closed meshes to draw

// A closed, consistently wound surface with outward normals (counter-clockwise seen from
// outside). The renderer accumulates path lengths by signed depth, exact only for closed surfaces.
struct XrayMesh {
  std::string name;
  TriangleMesh mesh;
  XrayMaterial material = XrayMaterial::kSoftTissue;
  float fill = 1.0f;  // volume fraction of the material inside the surface
  // Optional (nv): a group per vertex (e.g. the vessel segment); each group is closed by itself,
  // and its path length also goes to the iodine channel weighted by the group's concentration.
  std::vector<int> vertex_group;
};

// A closed tube around a polyline: `sides` vertices per ring, a ring per node with radius
// radii[i] (or radii[0] for all), frames by parallel transport, flat caps at both ends.
TriangleMesh tube_mesh(std::span<const Vec3> nodes, std::span<const double> radii, int sides = 8);

// Closes every boundary loop of a consistently wound mesh with a fan from the loop's centroid,
// keeping the winding. Returns the number of loops closed.
int cap_boundary_loops(TriangleMesh& mesh);

// Where the vertices of lumen_xray_mesh come from: each copies a vertex of the Lumen (a Lumen
// vertex on a junction is copied into each segment's closed surface), or is the centre of a cap
// (the mean of its boundary loop's vertices).
struct LumenXraySource {
  std::vector<int> vertex;      // (render vertices) the Lumen vertex it copies, -1: a cap's centre
  std::vector<int> cap_centre;  // (caps) render vertex at the cap's centre
  std::vector<int> cap_start;   // (caps + 1) each cap's loop in cap_loop
  std::vector<int> cap_loop;    // render vertices of the loops
};

// The lumen as one closed surface per vessel segment (the triangles of each segment, boundary
// loops at junctions and open ends capped by fans), wound outward, vertex_group = segment.
// Material blood; the renderer adds the iodine channel from per-segment concentrations.
// `source` (optional) says where each vertex comes from, to move them as the lumen's lesions open.
XrayMesh lumen_xray_mesh(const Lumen& lumen, LumenXraySource* source = nullptr);

// The rendered lumen following the lesions' opening: the render vertices that copy a vertex the
// lesions move (LesionMorph) and the caps whose loops hold any of them, so that a frame moves
// only those, like the collision lumen does (morph_positions).
struct LumenXrayMorph {
  std::vector<int> vertex;  // render vertices that copy a morph vertex
  std::vector<int> morph;   // (vertex) the index of that morph vertex in LesionMorph::vertices
  std::vector<int> cap_centre, cap_start, cap_loop;  // the caps touched, as in LumenXraySource
};
LumenXrayMorph make_lumen_xray_morph(const LumenXraySource& source, const LesionMorph& morph);
// Puts the morph vertices' positions (one per LesionMorph vertex, from morph_positions) into the
// render vertices that copy them, then re-centres the caps around them.
void apply_lumen_xray_morph(const LumenXrayMorph& m, std::span<const Vec3> morphed,
                            std::span<Vec3> render_vertices);

// A body part as an X-ray mesh: soft tissue and heart -> soft tissue, lung -> lung, bone ->
// bone with fill `bone_fill` (a solid mesh stands for a cortical shell around marrow).
inline constexpr float kBoneCorticalFill = 0.3f;  // estimate, docs/rendering.md
XrayMesh body_part_mesh(const BodyPart& part, float bone_fill = kBoneCorticalFill);
// The body context for X-ray: the torso as soft tissue, lungs, bones. Soft-tissue parts inside
// the torso (heart, diaphragm) are left out: they add nothing over the torso they lie in.
std::vector<XrayMesh> body_xray_meshes(const std::vector<BodyPart>& parts,
                                       float bone_fill = kBoneCorticalFill);

// An instrument seen by X-ray: a shaft along the nodes, a radiopaque distal length (a coil over
// the shaft) and marker bands.
struct InstrumentVisual {
  std::string name = "instrument";
  std::vector<Vec3> nodes;    // (n) proximal first, m
  std::vector<double> radii;  // (n) or (1), m
  XrayMaterial shaft = XrayMaterial::kNitinol;
  float shaft_fill = 1.0f;
  double radiopaque_length = 0.0;  // m from the distal end
  XrayMaterial radiopaque = XrayMaterial::kPtIr;
  float radiopaque_fill = 0.5f;         // coil winding fraction (estimate)
  std::vector<double> marker_from_tip;  // m, centre of each marker band from the distal end
  double marker_length = 1.0e-3;        // m
  double marker_radius_factor = 1.15;   // band radius / shaft radius
};
std::vector<XrayMesh> instrument_xray_meshes(const InstrumentVisual& inst);

// ---------------------------------------------------------------------------------------------
// Balloons and stents

// An inflated balloon holds contrast diluted 1:1 with saline, the usual preparation (a fraction of
// the 350 mgI/ml agent; docs/rendering.md cites it).
inline constexpr float kBalloonContrastFraction = 0.5f;

// An inflated balloon: a closed surface of revolution around its nodes (proximal first), radius
// radii[i] at node i, filled with contrast at `contrast` (fraction of 350 mgI/ml): material
// iodine with fill = contrast. Empty when fewer than two distinct nodes.
XrayMesh balloon_xray_mesh(std::span<const Vec3> nodes, std::span<const double> radii,
                           float contrast = kBalloonContrastFraction, int sides = 24);

// A stent as a thin-walled tube along its rings: the outer surface at each ring's radius, the
// inner `wall` m inside it (the strut thickness), closed at both ends (an annulus). The struts
// cover a fraction of the wall, so the shell is drawn with that fill: a ray through the wall at
// normal incidence meets mu strut_thickness metal_coverage, and any ray the mean metal along it.
// Material CoCr with `fill`.
XrayMesh stent_xray_mesh(std::span<const Vec3> rings, std::span<const double> radii, double wall,
                         float fill, int sides = 16);
// The fill of a stent's shell drawn as kCoCr: its metal coverage, scaled by its alloy's
// attenuation over L-605's at the beam energy when the catalogue gives one.
float stent_fill(const StentSpec& spec, BeamEnergy e);

// Instruments for a demonstration frame along the tree's routes: a 6F guiding catheter
// (polymer with a steel braid) from the access to the left main ostium, and a 0.014" nitinol
// guidewire from the access to the target with a 30 mm Pt/Ir coil tip.
std::vector<InstrumentVisual> demo_instruments(const VesselTree& tree);

// Per-segment contrast concentration: `c` for left_main and every segment below it (the left
// coronary tree), 0 elsewhere.
std::vector<float> left_coronary_contrast(const VesselTree& tree, float c);
// Where an operator centres the table for the coronaries: the mean of the left coronary tree's
// centreline points (left_main and its descendants), else the heart's centre, else the origin.
Vec3 left_coronary_centre(const VesselTree& tree);

// ---------------------------------------------------------------------------------------------
// GL: a headless context and the path-length renderer

// An OpenGL 3.3 core context made current on this thread without any display or window: EGL on
// a device (Mesa llvmpipe is fine) or the surfaceless platform. Throws std::runtime_error saying
// what failed. A desktop app makes its own context (GLFW) and uses FluoroRenderer the same way.
class HeadlessGlContext {
 public:
  HeadlessGlContext();
  ~HeadlessGlContext();
  HeadlessGlContext(const HeadlessGlContext&) = delete;
  HeadlessGlContext& operator=(const HeadlessGlContext&) = delete;
  const std::string& renderer() const { return renderer_; }  // GL_RENDERER string

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  std::string renderer_;
};

enum class FluoroOutput : std::uint8_t { kLineIntegral, kPathLengths };

// Draws the path length of each material along every detector pixel's ray into float targets
// and reduces them to the line integral. Needs a current GL 3.3 core context for its whole life.
class FluoroRenderer {
 public:
  explicit FluoroRenderer(int size);  // size x size pixels; InputError for size outside [16, 4096]
  ~FluoroRenderer();
  FluoroRenderer(const FluoroRenderer&) = delete;
  FluoroRenderer& operator=(const FluoroRenderer&) = delete;

  // Uploads a mesh; returns its id. Meshes stay until replaced.
  int add_mesh(const XrayMesh& mesh);
  // Replaces a mesh's geometry (instruments every frame); material and groups kept.
  void update_mesh(int id, const TriangleMesh& mesh);
  // Moves a mesh's vertices (same count and topology; grouped meshes too, e.g. a beating lumen).
  void update_vertices(int id, std::span<const Vec3> vertices);
  void set_visible(int id, bool visible);
  // Changes a mesh's fill (volume fraction of its material, e.g. a balloon's contrast).
  void set_fill(int id, float fill);
  // A static mesh (e.g. the body context) is drawn once per pose and beam energy into a cached
  // line integral that each kLineIntegral frame starts from; the others are drawn every frame.
  void set_static(int id, bool is_static);
  // Concentration per group (e.g. per segment), fraction of 350 mgI/ml; at most 256 groups.
  void set_group_concentration(std::span<const float> c);
  void set_beam_energy(BeamEnergy e) { energy_ = e; }
  BeamEnergy beam_energy() const { return energy_; }

  // Draws every visible mesh for the pose. kLineIntegral (frames) accumulates p = sum_k w_k L_k
  // directly into one float target; kPathLengths accumulates one channel per material, then
  // reduces them to p (inspection, tests): the same p either way.
  void render(const CArmPose& pose, FluoroOutput output = FluoroOutput::kLineIntegral);
  // After render(): (size * size) line integral p = sum_k w_k L_k, row 0 at the image top.
  void read_line_integral(std::vector<float>& out) const;
  // After render(kPathLengths): (size * size * kNumXrayMaterials) path lengths in m,
  // pixel-major, row 0 at the top.
  void read_path_lengths(std::vector<float>& out) const;
  int size() const { return size_; }

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  int size_ = 0;
  BeamEnergy energy_ = BeamEnergy::k60keV;
};

// ---------------------------------------------------------------------------------------------
// Image chain (CPU, after readback)

struct ImageChainSettings {
  double dose = 1e4;  // photons per pixel before the patient (I0); 0 = no quantum noise
  std::uint64_t seed = 1;
  // Window on the line integral p = -ln(I / I0): p <= level - window/2 is white, above
  // level + window/2 black. window <= 0: automatic, from the noise-free frame (percentiles inside
  // the collimated field), like a system's automatic brightness control.
  double window = 0.0;
  double level = 0.0;
  double gamma = 1.0;          // display gamma applied to the grey value
  double blur_sigma_px = 0.7;  // correlation blur (Gaussian, 3x3 kernel); 0 = none
  double vignetting = 0.25;    // brightness loss at the field edge (fraction)
  double collimation = 0.97;   // radius of the circular field / half the image side; >= 1.42 = none

  void validate(const std::string& source) const;  // InputError naming the field
};

// One frame: quantum noise on I = I0 exp(-p), blur, log, window/level, gamma, vignetting,
// collimation -> 8-bit grey (size * size, row 0 top), dark where attenuation is high.
void image_chain(std::span<const float> line_integral, int size, const ImageChainSettings& s,
                 std::vector<std::uint8_t>& out);

// Writes an 8-bit grey PNG; InputError("png", path, ...) if the file cannot be written.
void write_png_grey(const std::string& path, std::span<const std::uint8_t> pixels, int width,
                    int height);

// ---------------------------------------------------------------------------------------------
// A simulation seen by fluoroscopy

// How a catalogue instrument shows: a wire's core of its material with its radiopaque coil, a
// catheter's braid (a small steel fraction of the wall) with its marker bands.
InstrumentVisual instrument_visual(const InstrumentSpec& spec, const std::string& name);

// What a frame shows of the simulator's state, copied so that another thread can draw it while
// the physics goes on (the anatomy and motion it also reads never change during a run).
// A balloon as a frame shows it.
struct BalloonFrame {
  int instrument = -1;
  double pressure = 0.0;       // Pa gauge; drawn when > 0
  float contrast = 0.0f;       // fraction of 350 mgI/ml inside (kBalloonContrastFraction inflated)
  std::vector<Vec3> nodes;     // (balloon nodes) its rod's nodes now, proximal first; empty when
                               // the balloon is not in the body
  std::vector<double> radius;  // (balloon nodes) BalloonState::radius (m)
};
// A stent as a frame shows it: crimped, on its balloon's nodes; deployed, at its rings in the
// vessel moved with the heart to the frame's time.
struct StentFrame {
  int balloon = -1;  // index in ProcedureModel::balloons (its spec)
  StentState::Phase phase = StentState::Phase::kCrimped;
  std::vector<Vec3> rings;     // (rings) centres now (m); empty when not in the body
  std::vector<double> radius;  // (rings) outer radius (m)
};
struct FrameSnapshot {
  double time = 0.0;                     // s (the lumen is moved to it)
  std::vector<std::vector<Vec3>> nodes;  // (instrument) inserted centreline, empty if outside
  std::vector<float> contrast;           // (segment)
  std::vector<BalloonFrame> balloons;    // (balloon of ProcedureModel::balloons)
  std::vector<StentFrame> stents;        // stent systems' stents
  std::vector<LesionOpening> opening;    // (lesion) ProcedureState::opening; empty: as built
  // The model whose instruments `nodes` follows (the state's): after an exchange of instruments
  // the renderer draws each by its own catalogue entry. Null: the renderer's model.
  std::shared_ptr<const SimModel> model;
};
FrameSnapshot snapshot(const SimModel& model, const SimState& state);
FrameSnapshot snapshot(const Simulator& sim);

// The simulator's scene uploaded once (lumen with per-segment contrast, body context when the
// anatomy has a heart, instruments); each frame moves the lumen with the heart and opens its
// lesions as the snapshot has them, re-meshes the inserted part of every instrument, draws the
// inflated balloons and the stents, and runs the image chain. Needs a current GL context for its
// whole life.
class SimFluoroscopy {
 public:
  // Reads the model's anatomy, body and instrument specs (never written during a run). The model
  // must outlive the renderer unless the snapshots carry theirs (FrameSnapshot::model, as every
  // snapshot of a Simulator's state does): from the first such frame on the renderer reads it
  // and keeps it alive, so an exchange may free the model it was built from.
  SimFluoroscopy(const SimModel& model, int size, BeamEnergy energy = BeamEnergy::k60keV);
  SimFluoroscopy(const Simulator& sim, int size, BeamEnergy energy = BeamEnergy::k60keV)
      : SimFluoroscopy(sim.model(), size, energy) {}
  void frame(const Simulator& sim, const CArmPose& pose, const ImageChainSettings& chain,
             std::vector<std::uint8_t>& out);
  void frame(const FrameSnapshot& snap, const CArmPose& pose, const ImageChainSettings& chain,
             std::vector<std::uint8_t>& out);
  FluoroRenderer& renderer() { return renderer_; }

 private:
  struct Slots {
    InstrumentVisual visual;
    std::string catalogue;
    int shaft = -1, radiopaque = -1;
    std::vector<int> markers;
  };
  Slots make_slots(const InstrumentSpec& spec, const std::string& name);
  // The instruments of `model` (an exchange changed them): each drawn by its slots, those of an
  // instrument of the same name and catalogue entry kept, others added; slots no longer used
  // hidden and kept for later.
  void reslot(const SimModel& model);
  void show_opening(const std::vector<LesionOpening>& opening);
  // Meshes for the balloons and stents of `model` not yet drawn (an exchange may add some: the
  // procedure's balloons keep their index for the whole run, so the lists only grow).
  void add_procedure_slots(const SimModel& model);
  FluoroRenderer renderer_;
  const SimModel* model_;  // the one built from, then the latest snapshot's (slotted_)
  const CardiacMotion* motion_ = nullptr;
  int lumen_ = -1;
  std::vector<Vec3> lumen_rest_, lumen_now_;
  // The lesions' opening the lumen shows, and the vertices it moves (rest anatomy).
  LumenXrayMorph morph_;
  std::vector<LesionOpening> shown_opening_;
  std::vector<Vec3> morphed_;
  std::vector<Slots> instruments_;
  std::vector<Slots> spare_;                 // slots of instruments removed (hidden)
  std::shared_ptr<const SimModel> slotted_;  // the model instruments_ follows (null: the first)
  std::vector<int> balloons_, stents_;       // mesh ids (balloon), (stent frame slot)
  std::size_t balloon_models_ = 0;           // balloons of the procedure model with meshes
  std::vector<float> line_integral_;
};

// Films a run on a second thread, as the desktop app will draw: the physics thread hands over a
// copied state (FrameSnapshot) at each frame time; the worker owns the GL context, draws, runs the
// image chain and writes frame_NNNNN.png into `dir`. At most four frames wait, so a slow renderer
// holds the physics back instead of filling memory. The physics stays single-threaded and
// deterministic; each frame's noise seed is its index, so the frames do not depend on timing
// either. The model must outlive the recorder.
class FrameRecorder {
 public:
  // Starts the worker and its GL context; rethrows what stops it from starting (no GL, an
  // anatomy the renderer cannot draw) after the worker has ended.
  FrameRecorder(const SimModel& model, int size, BeamEnergy energy, ImageChainSettings chain,
                std::filesystem::path dir);
  ~FrameRecorder();
  FrameRecorder(const FrameRecorder&) = delete;
  FrameRecorder& operator=(const FrameRecorder&) = delete;

  // Queues a frame (waits while four are queued); rethrows the worker's error.
  void push(FrameSnapshot snap, const CArmPose& pose);
  // Waits until every frame handed over is written; rethrows the worker's error.
  void finish();
  int frames() const { return submitted_; }
  double render_seconds() const;

 private:
  struct Shared;
  std::unique_ptr<Shared> s_;
  int submitted_ = 0;
};

// The C-arm as a scenario sets it: fluoroscopy angles and field, checked against the C-arm's
// limits (InputError naming the scenario's field); the isocentre is left at the origin.
CArmPose scenario_pose(const Scenario& scenario);

// Films a run through a FrameRecorder at the scenario's frame rate (a RunObserver), the table
// centred on the left coronary tree. With the scenario's follow_tip the operator pans the table
// when the leading tip nears the edge of the field (in moves, as at a real table, which also keeps
// the body's cached image valid), and back to the heart once the tip is there.
class RunFilm : public RunObserver {
 public:
  RunFilm(const SimModel& model, FrameRecorder& recorder);
  void after_step(const Simulator& sim) override;
  // The C-arm pose of each frame filmed so far, in order (the scenario's angles and field, the
  // table's pan in the isocentre).
  const std::vector<CArmPose>& poses() const { return poses_; }

 private:
  FrameRecorder& recorder_;
  CArmPose pose_;
  Vec3 home_;
  double frame_dt_;
  bool follow_tip_;
  double next_frame_ = 0.0;
  std::vector<CArmPose> poses_;
};

}  // namespace vcsim
