// vcsim assess: what an educator measures in a run, and the session report (docs/assessment.md).
//
// An `Assessment` watches a run from outside the state (a RunObserver): it reads the commands
// (the fluoroscopy and cine pedals, the syringe, the indeflator) and what a trainee sees of the
// state (tips, insertion depths, wall contacts, hand forces, the treatment), and never writes
// the simulation, so the state hash of a run is the same with or without it. At the end it adds
// its section to the run's metrics.json (schema "vcsim-metrics" version kMetricsVersion), writes
// a decimated time series (series.csv) and the film's frame index (frames.csv).
//
// The report reads a run's folder only: `write_report` makes one self-contained HTML file
// (timeline, plots, key frames, the tip's path over an angiogram, the metrics against reference
// ranges); `write_metrics_csv` and `write_compare_report` serve spreadsheets and progress over
// sessions. Everything read from a folder is checked at that boundary (InputError naming the
// file, the field and what was expected).
#pragma once

#include <cstdint>
#include <filesystem>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "vcsim/render.h"
#include "vcsim/sim.h"
#include "vcsim/units.h"

namespace vcsim {

// The metrics.json schema version this build writes and reads ("format": "vcsim-metrics").
inline constexpr int kMetricsVersion = 2;

// Thresholds and models of the assessment (docs/assessment.md gives each one's source).
struct AssessmentSettings {
  // Wall contacts of nodes within this arc length of an instrument's distal tip are its tip's.
  double tip_zone = 20e-3;  // m
  // A force event: the largest tip contact force of a guidewire whose tip is in a coronary, or
  // of a catheter, low-passed (first order, force_time_constant: a load held, not a one-step
  // impulse), above its threshold; it ends once the force stays below it for event_gap.
  double coronary_wire_force = 0.15;  // N
  double catheter_force = 1.0;        // N
  double force_time_constant = 0.01;  // s
  double event_gap = 0.05;            // s
  // Dose model: reference air kerma at the interventional reference point (IEC 60601-2-43:
  // 15 cm from the isocentre toward the source) = rate x fluoroscopy time + per-frame x cine
  // frames; the kerma-area product is that times the field's area at the reference point.
  double fluoro_kerma_rate = 20e-3 / 60.0;  // Gy/s (20 mGy/min)
  double cine_kerma_per_frame = 0.15e-3;    // Gy
  double cine_fps = 15.0;                   // frames per second of cine (clinical.md)
  double irp_offset = 0.15;                 // m, isocentre to reference point, toward the source
  // A guide's tip in a coronary this long counts as engaged (leaving it after: a disengagement).
  double engaged_time = 0.5;  // s
  // Deep intubation: a catheter's tip more than this far into the coronary tree (past a typical
  // left main, 10.5 +- 5.3 mm, clinical.md).
  double deep_intubation = 10e-3;  // m
  // Wire prolapse: a guidewire's distal `prolapse_length` pointing more than prolapse_angle away
  // from the way into the coronary it is in (its tip folded back).
  double prolapse_length = 3e-3;         // m
  double prolapse_angle = 120.0 * kDeg;  // rad
  // A loop, anywhere: an instrument come back onto itself, two of its inserted points at least
  // loop_arc apart along it within loop_gap of touching (find_loop), checked every loop_interval.
  double loop_arc = 30e-3;       // m
  double loop_gap = 0.5e-3;      // m
  double loop_interval = 20e-3;  // s
  // Tips are located in the vessel tree every location_interval (as landmarks are); the time
  // series keeps one row per series_interval (forces: the largest magnitude within it).
  double location_interval = 5e-3;  // s
  double series_interval = 0.05;    // s
};

// Fluoroscopy pedal (bit 0) and cine pedal (bit 1) of StepCommands::buttons (docs/devices.md).
inline constexpr std::uint32_t kFluoroPedal = 1u << 0;
inline constexpr std::uint32_t kCinePedal = 1u << 1;

// Beam-on time from the pedals, step by step. Cine has precedence over fluoroscopy while both are
// held. A cine run starts when the cine pedal goes down and records a frame at its start and
// every 1 / fps after, while held.
struct BeamTally {
  double fluoro_time = 0.0;  // s with the fluoroscopy pedal (and not the cine pedal) down
  double cine_time = 0.0;    // s with the cine pedal down
  int cine_runs = 0;
  std::int64_t cine_frames = 0;
  bool pedal_used = false;  // either pedal was pressed at some step
  // One step of dt ending at time t with these buttons held.
  void step(double dt, std::uint32_t buttons, double cine_fps);

 private:
  bool cine_down_ = false;
  double cine_clock_ = 0.0;  // s since the current cine run's next frame is due (< 0: not yet)
};

// Threshold crossings of a signal sampled each step: an event opens when the value exceeds the
// threshold and closes once it has stayed at or below it for `gap` s.
struct ForceEvent {
  double start = 0.0, end = 0.0;  // s
  double peak = 0.0;              // N
};
struct ThresholdEvents {
  std::vector<ForceEvent> events;
  double peak = 0.0;  // largest value seen
  void step(double t, double value, double threshold, double gap);
  void close();  // at the end of the run: an open event ends at its last sample above

 private:
  bool open_ = false;
  double below_since_ = -1.0;
};

// Dose estimate from beam-on time (the model of AssessmentSettings; docs/assessment.md).
struct DoseEstimate {
  double air_kerma = 0.0;           // Gy at the interventional reference point
  double kerma_area_product = 0.0;  // Gy m^2
  double field_area = 0.0;          // m^2 at the reference point
};
DoseEstimate estimate_dose(double fluoro_time, std::int64_t cine_frames, double fov, double sid,
                           double sod, const AssessmentSettings& settings);

// How far a place in a coronary segment lies into the coronary tree along its centrelines (m):
// from the ostium of the first coronary segment on its way up (the left main's, the RCA's),
// through the attach points of side branches. -1 outside the coronaries.
double coronary_depth(const VesselTree& tree, const TreeLocation& loc);

// True when a wire's distal direction (unit, toward its tip) points more than `angle` (rad) away
// from `way_in` (unit, the vessel's direction away from the ostium at the tip).
bool prolapsed(const Vec3& tip_direction, const Vec3& way_in, double angle);

// A loop of a rod: two of its nodes from `first` on, at least `arc` apart along it (`node_s`, m),
// with their surfaces closer than `gap` (m; each node's radius that of the edge after it, the
// last edge's at the tip: `edge_radius`, one per edge). Returns the first such pair (i < j) found,
// or (-1, -1). Skips ahead by the distance a pair is from touching, so a rod far from itself costs
// a few distance checks a node.
std::pair<int, int> find_loop(std::span<const Vec3> x, std::span<const double> node_s,
                              std::span<const double> edge_radius, int first, double arc,
                              double gap);

// The segments a tip may be in on the way from the access to the treatment target: the access'
// and the target's segments and all their ancestors, and the aortic sinuses (where a guide seeks
// the ostium). (segment) 1 allowed, 0 a wrong branch; empty when the tree has no target.
std::vector<unsigned char> allowed_segments(const VesselTree& tree);

// Watches a run and measures it (docs/assessment.md). Register it as (or through) the run's
// observer: before_step reads the commands, after_step the state, exchanged the scene's changes.
class Assessment : public RunObserver {
 public:
  explicit Assessment(const Simulator& sim, AssessmentSettings settings = {});
  ~Assessment() override;
  // A copy is a snapshot of what was measured so far (the trainer keeps one with each snapshot of
  // the state, so that a rewind takes the assessment back with it).
  Assessment(const Assessment& other);
  Assessment& operator=(const Assessment& other);

  // The autopilot's phases become the timeline's phases (optional).
  void follow(const Autopilot* pilot) { pilot_ = pilot; }
  bool before_step(const Simulator& sim, const StepCommands& commands) override;
  void after_step(const Simulator& sim) override;
  void exchanged(const Simulator& sim, const InstrumentChange& change) override;

  const BeamTally& beam() const;
  int injections() const;
  double fluoroscopy_time() const;  // s as reported (the pedal's, or the whole run without one)
  int force_events(const std::string& instrument) const;  // -1: no such instrument
  double wrong_branch_time(const std::string& instrument) const;
  int exchanges() const;
  // Events marked so far (the report's timeline: engaged, lesion crossed, procedure events...);
  // it grows by one with each (a copy taken back by a rewind has fewer).
  int num_events() const;

  // Adds "assessment" to DIR/metrics.json (written before by write_run_metrics), writes
  // DIR/series.csv and, with frames, DIR/frames.csv (frame index, time and the C-arm pose each
  // was made through: `frame_poses`, one per frame in order; `frame_times`, s, each frame's
  // simulated time, or empty: frames at the scenario's fps from 0, as `vcsim run` films).
  // InputError naming the file when it cannot.
  void write(const std::filesystem::path& dir, const Simulator& sim,
             std::span<const CArmPose> frame_poses = {},
             std::span<const double> frame_times = {}) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> p_;
  const Autopilot* pilot_ = nullptr;
};

// Calls every observer in turn (the film, the assessment, a log); ends the run when any says so.
class ObserverList : public RunObserver {
 public:
  void add(RunObserver* o) {
    if (o) list_.push_back(o);
  }
  bool before_step(const Simulator& sim, const StepCommands& commands) override;
  void after_step(const Simulator& sim) override;
  void exchanged(const Simulator& sim, const InstrumentChange& change) override;

 private:
  std::vector<RunObserver*> list_;
};

// ---------------------------------------------------------------------------------------------
// The report (from a run's folder)

struct ReportOptions {
  // The page template (Mustache) and the plotting library inlined into the page.
  std::filesystem::path template_file;  // empty: default_report_template()
  std::filesystem::path plot_library;   // empty: the Debian package's dygraph.min.js
};
// data/report/report.html.mustache of the source tree ($VCSIM_REPORT_TEMPLATE if set).
std::filesystem::path default_report_template();

// Checks DIR/metrics.json (a JSON object of format "vcsim-metrics", version kMetricsVersion, with
// an "assessment") and returns it as text; InputError(file, field, expected) otherwise.
std::string read_run_metrics(const std::filesystem::path& run_dir);

// DIR/report.html (or `out`): one HTML file that needs nothing else. Returns the path written.
std::filesystem::path write_report(const std::filesystem::path& run_dir,
                                   const std::filesystem::path& out = {},
                                   const ReportOptions& options = {});
// One row per run: the assessment's scalar metrics, named in a header (docs/assessment.md).
void write_metrics_csv(std::span<const std::filesystem::path> run_dirs,
                       const std::filesystem::path& out);
// A trainee's progress: the runs in the order given, as a table and plots, in one HTML file.
void write_compare_report(std::span<const std::filesystem::path> run_dirs,
                          const std::filesystem::path& out, const ReportOptions& options = {});

}  // namespace vcsim
