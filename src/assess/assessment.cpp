// The assessment of a run (docs/assessment.md): pedals, contrast, dose, wall force events, wrong
// branches, exchanges, lesion crossing, guide engagement and the treatment, measured by watching
// the run from outside its state; written into metrics.json, series.csv and frames.csv.
#include <algorithm>
#include <cassert>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <map>
#include <nlohmann/json.hpp>
#include <sstream>

#include "vcsim/assess.h"
#include "vcsim/render.h"
#include "vcsim/units.h"

namespace vcsim {

namespace fs = std::filesystem;
using Json = nlohmann::json;

// ---------------------------------------------------------------------------------------------
// Kernels

void BeamTally::step(double dt, std::uint32_t buttons, double cine_fps) {
  const bool fluoro = (buttons & kFluoroPedal) != 0, cine = (buttons & kCinePedal) != 0;
  pedal_used = pedal_used || fluoro || cine;
  if (cine) {
    if (!cine_down_) {  // a new run: its first frame at once
      ++cine_runs;
      cine_clock_ = 0.0;
    }
    // Frames are due at 0, 1/fps, 2/fps, ... of the run; this step covers [clock, clock + dt).
    const double period = 1.0 / cine_fps;
    while (cine_clock_ < dt * (1.0 - 1e-9)) {
      ++cine_frames;
      cine_clock_ += period;
    }
    cine_clock_ -= dt;
    cine_time += dt;
  } else if (fluoro) {
    fluoro_time += dt;
  }
  cine_down_ = cine;
}

void ThresholdEvents::step(double t, double value, double threshold, double gap) {
  peak = std::max(peak, value);
  if (value > threshold) {
    if (!open_) {
      events.push_back({t, t, value});
      open_ = true;
    }
    ForceEvent& e = events.back();
    e.end = t;
    e.peak = std::max(e.peak, value);
    below_since_ = -1.0;
  } else if (open_) {
    if (below_since_ < 0.0) below_since_ = t;
    if (t - below_since_ >= gap - 1e-12) open_ = false;
  }
}

void ThresholdEvents::close() {
  open_ = false;
  below_since_ = -1.0;
}

DoseEstimate estimate_dose(double fluoro_time, std::int64_t cine_frames, double fov, double sid,
                           double sod, const AssessmentSettings& s) {
  DoseEstimate d;
  d.air_kerma =
      s.fluoro_kerma_rate * fluoro_time + s.cine_kerma_per_frame * static_cast<double>(cine_frames);
  // The square field of side fov at the detector, scaled back to the reference point.
  const double side = fov * (sod - s.irp_offset) / sid;
  d.field_area = side * side;
  d.kerma_area_product = d.air_kerma * d.field_area;
  return d;
}

double coronary_depth(const VesselTree& tree, const TreeLocation& loc) {
  if (loc.segment < 0 || tree.segments[loc.segment].kind != VesselKind::kCoronary) return -1.0;
  const int parent = tree.segments[loc.segment].parent;
  if (parent < 0 || tree.segments[parent].kind != VesselKind::kCoronary)
    return std::max(0.0, loc.distance - ostium_distance(tree, loc.segment));
  // A coronary branch: the parent's depth where it leaves, then along the branch.
  return coronary_depth(tree, {parent, attach_distance(tree, loc.segment)}) + loc.distance;
}

bool prolapsed(const Vec3& tip_direction, const Vec3& way_in, double angle) {
  return tip_direction.dot(way_in) < std::cos(angle);
}

std::pair<int, int> find_loop(std::span<const Vec3> x, std::span<const double> node_s,
                              std::span<const double> edge_radius, int first, double arc,
                              double gap) {
  const int n = static_cast<int>(x.size());
  const int m = static_cast<int>(edge_radius.size());
  if (n < 2 || m < 1 || first < 0 || first >= n) return {-1, -1};
  auto radius = [&](int i) { return edge_radius[static_cast<std::size_t>(std::min(i, m - 1))]; };
  // The longest step between neighbours and the thickest node bound how fast the distance to a
  // node can fall along the rod.
  double step = 0.0, r_max = 0.0;
  for (int i = first; i < n; ++i) {
    r_max = std::max(r_max, radius(i));
    if (i + 1 < n) step = std::max(step, (x[i + 1] - x[i]).norm());
  }
  if (!(step > 0.0)) return {-1, -1};
  for (int i = first; i < n; ++i) {
    int j = i + 1;
    while (j < n && node_s[j] - node_s[i] < arc) ++j;
    const double reach = radius(i) + r_max + gap;
    while (j < n) {
      const double d = (x[j] - x[i]).norm();
      if (d < radius(i) + radius(j) + gap) return {i, j};
      // Nodes within (d - reach) / step further along cannot be within reach.
      const double skip = std::floor((d - reach) / step);
      j += skip >= 1.0 ? static_cast<int>(std::min(skip, static_cast<double>(n))) + 1 : 1;
    }
  }
  return {-1, -1};
}

std::vector<unsigned char> allowed_segments(const VesselTree& tree) {
  std::vector<unsigned char> ok;
  if (tree.target.segment < 0 || tree.access.segment < 0) return ok;
  ok.assign(tree.segments.size(), 0);
  for (int s : {tree.target.segment, tree.access.segment})
    for (; s >= 0; s = tree.segments[s].parent) ok[s] = 1;
  for (std::size_t s = 0; s < tree.segments.size(); ++s)
    if (tree.segments[s].kind == VesselKind::kSinus) ok[s] = 1;
  return ok;
}

// ---------------------------------------------------------------------------------------------
// The observer

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

struct Track {
  std::string name, catalogue;
  InstrumentKind kind = InstrumentKind::kGuidewire;
  int index = -1;        // in the scene now, -1: not in it
  int tip_first = 0;     // first node of the tip zone
  std::size_t row0 = 0;  // first series row it has
  bool inside = false;
  int insertions = 0;
  double first_inserted = -1.0;
  double tip_path = 0.0;  // m
  Vec3 last_tip = Vec3::Zero();
  double peak_hand = 0.0;  // N, magnitude
  double wall_lp = 0.0;    // N, the tip's wall force low-passed
  ThresholdEvents force;
  double threshold = -1.0;  // N of the events that count now (< 0: none)
  bool any_threshold = false;
  // Location (every location_interval)
  TreeLocation loc;
  bool located = false;
  bool in_coronary = false;
  bool wrong = false;
  double wrong_time = 0.0;
  int wrong_entries = 0;
  double first_coronary = -1.0;
  double coronary_since = -1.0;  // catheter: since when its tip is in a coronary
  bool engaged = false;
  double engaged_at = -1.0;
  int disengagements = 0;
  int prolapse_node = 0;  // the node prolapse_length behind the tip
  // Deep intubation (catheters) and prolapse (guidewires): episodes, time, deepest
  bool deep = false, folded = false;
  int deep_count = 0, prolapse_count = 0;
  double deep_time = 0.0, prolapse_time = 0.0, max_depth = -1.0;
  // Loops (any instrument, anywhere): episodes and their time
  bool looped = false;
  int loop_count = 0;
  double loop_time = 0.0;
  // The series' current bin and its rows
  double bin_force = 0.0, bin_wall = 0.0;
  std::vector<float> depth_mm, force_n, wall_n, x_mm, y_mm, z_mm;
};

struct Interval {
  std::string row;
  double start = 0.0, end = -1.0;  // end < 0: open
};

struct Mark {
  double time = 0.0;
  std::string what, instrument;
};

}  // namespace

struct Assessment::Impl {
  AssessmentSettings set;
  std::vector<Track> tracks;  // every instrument the run had, in order of appearance
  std::vector<unsigned char> allowed;
  std::vector<unsigned char> retrograde;  // (segment) 1: the access' segment and its ancestors
  BeamTally beam;
  std::uint32_t buttons = 0;
  double flow = 0.0;      // m^3/s this step
  double pressure = 0.0;  // Pa this step
  double step_start = 0.0;
  double volume = 0.0;  // m^3 of positive flow
  struct Injection {
    double start = 0.0, end = -1.0, volume = 0.0;
  };
  std::vector<Injection> injections;
  std::vector<Interval> intervals;  // beam, inflations, insertions
  std::vector<Mark> marks;
  struct Phase {
    double start = 0.0;
    std::string label;
  };
  std::vector<Phase> phases;
  int pilot_phase = -1;
  int exchanges = 0;
  double next_location = 0.0;
  double next_loop = 0.0;
  double next_row = 0.0;
  // Series rows
  std::vector<float> row_t, beam_state, flow_ml_s, contrast_ml, fluoro_s, kerma_mgy;
  // Lesions: crossing
  struct Crossing {
    int segment = -1;
    double end = 0.0;  // m along the segment: the lesion's distal end
    double at = -1.0;
    std::string by;
    double time_to_cross = -1.0;
  };
  std::vector<Crossing> crossings;
  double inflated_since = -1.0;
  std::size_t procedure_events = 0;             // of ProcedureState::events already marked
  bool fluoro_open = false, cine_open = false;  // the beam's timeline intervals
  CArmPose pose;                                // the scenario's C-arm (field size for the dose)

  Track& track(const std::string& name) {
    for (Track& tr : tracks)
      if (tr.name == name) return tr;
    tracks.emplace_back();
    tracks.back().name = name;
    return tracks.back();
  }
  void open(const std::string& row, double t) { intervals.push_back({row, t, -1.0}); }
  void close(const std::string& row, double t) {
    for (auto it = intervals.rbegin(); it != intervals.rend(); ++it)
      if (it->row == row && it->end < 0.0) {
        it->end = t;
        return;
      }
  }
  void bind(const Simulator& sim) {
    for (Track& tr : tracks) tr.index = -1;
    for (int i = 0; i < sim.num_instruments(); ++i) {
      Track& tr = track(sim.scenario().instruments[i].name);
      if (tr.depth_mm.empty() && tr.row0 == 0) tr.row0 = row_t.size();
      tr.index = i;
      tr.catalogue = sim.scenario().instruments[i].catalogue;
      tr.kind = sim.instrument_spec(i).kind;
      const RodModel& rm = sim.rod_model(i);
      tr.tip_first = rm.n - 1;
      while (tr.tip_first > 0 && rm.node_s[rm.n - 1] - rm.node_s[tr.tip_first - 1] <= set.tip_zone)
        --tr.tip_first;
      tr.prolapse_node = rm.n - 1;
      while (tr.prolapse_node > 0 &&
             rm.node_s[rm.n - 1] - rm.node_s[tr.prolapse_node] < set.prolapse_length)
        --tr.prolapse_node;
      tr.last_tip = sim.tip(i);
    }
  }
};

Assessment::Assessment(const Simulator& sim, AssessmentSettings settings)
    : p_(std::make_unique<Impl>()) {
  p_->set = settings;
  p_->allowed = allowed_segments(sim.tree());
  p_->retrograde.assign(sim.tree().segments.size(), 0);
  for (int sg = sim.tree().access.segment; sg >= 0; sg = sim.tree().segments[sg].parent)
    p_->retrograde[static_cast<std::size_t>(sg)] = 1;
  p_->pose = scenario_pose(sim.scenario());
  p_->bind(sim);
  for (const Lesion& l : sim.tree().lesions) {
    Impl::Crossing c;
    c.segment = l.segment;
    c.end = ostium_distance(sim.tree(), l.segment) + l.distance + l.length;
    p_->crossings.push_back(c);
  }
  p_->step_start = sim.time();
}

Assessment::~Assessment() = default;

Assessment::Assessment(const Assessment& other)
    : RunObserver(other), p_(std::make_unique<Impl>(*other.p_)), pilot_(other.pilot_) {}

Assessment& Assessment::operator=(const Assessment& other) {
  if (this != &other) {
    *p_ = *other.p_;
    pilot_ = other.pilot_;
  }
  return *this;
}

bool Assessment::before_step(const Simulator& sim, const StepCommands& c) {
  p_->buttons = c.buttons;
  p_->flow = c.syringe_flow;
  p_->pressure = c.balloon_pressure;
  p_->step_start = sim.time();
  return true;
}

void Assessment::exchanged(const Simulator& sim, const InstrumentChange& change) {
  Impl& p = *p_;
  ++p.exchanges;
  p.marks.push_back({sim.time(), std::string(to_string(change.kind)), change.name});
  p.bind(sim);
}

void Assessment::after_step(const Simulator& sim) {
  Impl& p = *p_;
  const AssessmentSettings& set = p.set;
  const double t = sim.time(), dt = t - p.step_start;
  const SimModel& md = sim.model();
  // Pedals
  const int before_cine = p.beam.cine_runs;
  const double fluoro_before = p.beam.fluoro_time, cine_before = p.beam.cine_time;
  p.beam.step(dt, p.buttons, set.cine_fps);
  const bool cine_now = p.beam.cine_time > cine_before;
  const bool fluoro_now = p.beam.fluoro_time > fluoro_before;
  // The timeline's beam rows: a new interval where the beam's mode changes.
  if (p.cine_open && (!cine_now || p.beam.cine_runs != before_cine)) p.close("cine", p.step_start);
  if (p.fluoro_open && !fluoro_now) p.close("fluoroscopy", p.step_start);
  if (cine_now && (!p.cine_open || p.beam.cine_runs != before_cine)) p.open("cine", p.step_start);
  if (fluoro_now && !p.fluoro_open) p.open("fluoroscopy", p.step_start);
  p.cine_open = cine_now;
  p.fluoro_open = fluoro_now;
  // Contrast
  if (p.flow > 0.0) {
    if (p.injections.empty() || p.injections.back().end >= 0.0) {
      p.injections.push_back({p.step_start, -1.0, 0.0});
      p.open("injection", p.step_start);
    }
    p.injections.back().volume += p.flow * dt;
    p.volume += p.flow * dt;
  } else if (!p.injections.empty() && p.injections.back().end < 0.0) {
    p.injections.back().end = p.step_start;
    p.close("injection", p.step_start);
  }
  // Inflation (the indeflator above 1 atm)
  if (p.pressure > kAtm && p.inflated_since < 0.0) {
    p.inflated_since = p.step_start;
    p.open("inflation", p.step_start);
  } else if (p.pressure <= kAtm && p.inflated_since >= 0.0) {
    p.inflated_since = -1.0;
    p.close("inflation", p.step_start);
  }
  // The autopilot's phases
  if (pilot_ && pilot_->phase() != p.pilot_phase) {
    p.pilot_phase = pilot_->phase();
    p.phases.push_back({p.step_start, pilot_->status()});
  }
  // Instruments: insertion, tip path, forces
  const double fine_dt = md.solver.settings[static_cast<std::size_t>(sim.split() - 1)].rod.dt;
  for (Track& tr : p.tracks) {
    if (tr.index < 0) continue;
    const int i = tr.index;
    const InstrumentState& in = sim.instrument(i);
    const bool inside = in.drive.depth >= Simulator::kWithdrawnDepth;
    const Vec3 tip = sim.tip(i);
    if (in.drive.depth > 0.0) tr.tip_path += (tip - tr.last_tip).norm();
    tr.last_tip = tip;
    if (inside && !tr.inside) {
      ++tr.insertions;
      if (tr.first_inserted < 0.0) tr.first_inserted = t;
      p.open(tr.name, p.step_start);
    } else if (!inside && tr.inside) {
      p.close(tr.name, p.step_start);
    }
    tr.inside = inside;
    const double hand = in.drive.axial_force;
    tr.peak_hand = std::max(tr.peak_hand, std::abs(hand));
    if (std::abs(hand) > std::abs(tr.bin_force)) tr.bin_force = hand;
    // The tip zone's contacts with the vessel wall (not with the introducer sheath, which holds
    // a shaped tip straight on its way in).
    double wall = 0.0;
    if (!in.parked) {
      const RodModel& rm = sim.rod_model(i);
      const double tip_s = rm.node_s[static_cast<std::size_t>(rm.n - 1)];
      for (const NodeContact& c : sim.contacts(i)) {
        if (c.node < tr.tip_first) continue;
        const double inserted =
            in.drive.depth - (tip_s - rm.node_s[static_cast<std::size_t>(c.node)]);
        if (inserted > md.sheath.length) wall = std::max(wall, c.lambda_n / fine_dt);
      }
    }
    // First-order low-pass, exact for a step held over dt.
    tr.wall_lp += (wall - tr.wall_lp) * (1.0 - std::exp(-dt / set.force_time_constant));
    tr.bin_wall = std::max(tr.bin_wall, tr.wall_lp);
    // Which threshold applies: a wire's tip in a coronary, a catheter's anywhere.
    tr.threshold = tr.kind == InstrumentKind::kCatheter ? set.catheter_force
                   : tr.kind == InstrumentKind::kGuidewire && tr.in_coronary && inside
                       ? set.coronary_wire_force
                       : -1.0;
    if (tr.threshold > 0.0) {
      tr.any_threshold = true;
      tr.force.step(t, tr.wall_lp, tr.threshold, set.event_gap);
    } else {
      tr.force.step(t, 0.0, 1.0, set.event_gap);  // no contact that counts: an event ends
    }
  }
  // Locations, every location_interval
  if (t >= p.next_location - 1e-9) {
    const double dl = set.location_interval;
    p.next_location = t + dl;
    for (Track& tr : p.tracks) {
      if (tr.index < 0 || !tr.inside) {
        if (tr.wrong) tr.wrong = false;
        tr.deep = tr.folded = false;
        if (tr.engaged) {
          tr.engaged = false;
          p.close(tr.name + " engaged", t);
        }
        tr.in_coronary = false;
        tr.coronary_since = -1.0;
        continue;
      }
      const TreeHit h = sim.tip_location(tr.index);
      tr.loc = h.loc;
      tr.located = true;
      const int seg = h.loc.segment;
      tr.in_coronary = seg >= 0 && sim.tree().segments[seg].kind == VesselKind::kCoronary;
      if (tr.in_coronary && tr.first_coronary < 0.0) {
        tr.first_coronary = t;
        p.marks.push_back({t, "tip in a coronary", tr.name});
      }
      // Wrong branch
      const bool wrong = !p.allowed.empty() && seg >= 0 && !p.allowed[seg];
      if (wrong) {
        tr.wrong_time += dl;
        if (!tr.wrong) {
          ++tr.wrong_entries;
          p.marks.push_back({t, "wrong branch: " + sim.tree().segments[seg].name, tr.name});
        }
      }
      tr.wrong = wrong;
      // A guide's engagement and disengagement
      if (tr.kind == InstrumentKind::kCatheter) {
        if (tr.in_coronary) {
          if (tr.coronary_since < 0.0) tr.coronary_since = t;
          if (!tr.engaged && t - tr.coronary_since >= set.engaged_time - 1e-9) {
            tr.engaged = true;
            if (tr.engaged_at < 0.0) {
              tr.engaged_at = tr.coronary_since;
              p.marks.push_back({tr.coronary_since, "engaged", tr.name});
            }
            p.open(tr.name + " engaged", tr.coronary_since);
          }
        } else {
          tr.coronary_since = -1.0;
          if (tr.engaged) {
            tr.engaged = false;
            ++tr.disengagements;
            p.marks.push_back({t, "disengaged", tr.name});
            p.close(tr.name + " engaged", t);
          }
        }
      }
      // Deep intubation of a catheter; prolapse of a wire in a coronary
      if (tr.kind == InstrumentKind::kCatheter) {
        const double depth = coronary_depth(sim.tree(), h.loc);
        tr.max_depth = std::max(tr.max_depth, depth);
        const bool deep = depth > set.deep_intubation;
        if (deep) tr.deep_time += dl;
        if (deep && !tr.deep) {
          ++tr.deep_count;
          p.marks.push_back({t, "deep intubation", tr.name});
        }
        tr.deep = deep;
      }
      if (tr.kind == InstrumentKind::kGuidewire) {
        bool folded = false;
        if (tr.in_coronary) {
          const RodState& rod = sim.instrument(tr.index).rod;
          const Vec3 d = rod.x.back() - rod.x[static_cast<std::size_t>(tr.prolapse_node)];
          // The way in: toward the root on the access' side (instruments go up against the
          // flow from the groin), along the flow beyond it.
          const VesselSegment& sg = sim.tree().segments[seg];
          const Vec3 way_in = p.retrograde[static_cast<std::size_t>(seg)]
                                  ? Vec3(-tangent_at(sg, h.loc.distance))
                                  : tangent_at(sg, h.loc.distance);
          folded = d.norm() > 0.0 && prolapsed(d.normalized(), way_in, set.prolapse_angle);
        }
        if (folded) tr.prolapse_time += dl;
        if (folded && !tr.folded) {
          ++tr.prolapse_count;
          p.marks.push_back({t, "wire prolapse", tr.name});
        }
        tr.folded = folded;
      }
      // Lesions crossed by a wire's tip
      if (tr.kind == InstrumentKind::kGuidewire)
        for (std::size_t k = 0; k < p.crossings.size(); ++k) {
          Impl::Crossing& c = p.crossings[k];
          if (c.at >= 0.0 || seg != c.segment || h.loc.distance <= c.end) continue;
          c.at = t;
          c.by = tr.name;
          c.time_to_cross = tr.first_coronary >= 0.0 ? t - tr.first_coronary : t;
          p.marks.push_back({t, "lesion " + std::to_string(k) + " crossed", tr.name});
        }
    }
  }
  // Loops, every loop_interval: the inserted part of each instrument come back onto itself
  if (t >= p.next_loop - 1e-9) {
    p.next_loop = t + set.loop_interval;
    for (Track& tr : p.tracks) {
      bool looped = false;
      if (tr.index >= 0 && tr.inside) {
        const InstrumentState& in = sim.instrument(tr.index);
        const RodModel& rm = sim.rod_model(tr.index);
        looped = !in.parked && find_loop(in.rod.x, rm.node_s, rm.outer_radius, in.drive.first_free,
                                         set.loop_arc, set.loop_gap)
                                       .first >= 0;
      }
      if (looped) tr.loop_time += set.loop_interval;
      if (looped && !tr.looped) {
        ++tr.loop_count;
        p.marks.push_back({t, "loop", tr.name});
      }
      tr.looped = looped;
    }
  }
  // Procedure events (stent deployed, rupture, ...) as marks
  const auto& evs = sim.state().procedure.events;
  for (std::size_t k = p.procedure_events; k < evs.size(); ++k) {
    const ProcedureEvent& ev = evs[k];
    const std::string who =
        ev.balloon >= 0 ? md.procedure.balloons[static_cast<std::size_t>(ev.balloon)].label : "";
    p.marks.push_back({ev.time, std::string("procedure: ") + to_string(ev.kind), who});
  }
  p.procedure_events = evs.size();
  // The series: one row per series_interval
  if (t >= p.next_row - 1e-9) {
    p.next_row = t + set.series_interval;
    p.row_t.push_back(static_cast<float>(t));
    p.beam_state.push_back(static_cast<float>(cine_now ? 2 : fluoro_now ? 1 : 0));
    p.flow_ml_s.push_back(static_cast<float>(p.flow * 1e6));
    p.contrast_ml.push_back(static_cast<float>(p.volume * 1e6));
    p.fluoro_s.push_back(static_cast<float>(p.beam.fluoro_time + p.beam.cine_time));
    const DoseEstimate d = estimate_dose(p.beam.fluoro_time, p.beam.cine_frames, p.pose.fov,
                                         p.pose.sid, p.pose.sod, set);
    p.kerma_mgy.push_back(static_cast<float>(d.air_kerma * 1e3));
    for (Track& tr : p.tracks) {
      // Rows before it appeared, or while it was out of the scene: NaN.
      auto pad = [&](std::vector<float>& v) {
        while (v.size() + tr.row0 + 1 < p.row_t.size()) v.push_back(NAN);
      };
      for (auto* v : {&tr.depth_mm, &tr.force_n, &tr.wall_n, &tr.x_mm, &tr.y_mm, &tr.z_mm}) pad(*v);
      if (tr.index < 0) {
        for (auto* v : {&tr.depth_mm, &tr.force_n, &tr.wall_n, &tr.x_mm, &tr.y_mm, &tr.z_mm})
          v->push_back(NAN);
        continue;
      }
      const InstrumentState& in = sim.instrument(tr.index);
      tr.depth_mm.push_back(static_cast<float>(in.drive.depth * 1e3));
      tr.force_n.push_back(static_cast<float>(tr.bin_force));
      tr.wall_n.push_back(static_cast<float>(tr.bin_wall));
      const Vec3 r = tr.inside ? sim.tip_rest(tr.index) : Vec3::Constant(kNaN);
      tr.x_mm.push_back(static_cast<float>(r.x() * 1e3));
      tr.y_mm.push_back(static_cast<float>(r.y() * 1e3));
      tr.z_mm.push_back(static_cast<float>(r.z() * 1e3));
      tr.bin_force = 0.0;
      tr.bin_wall = 0.0;
    }
  }
}

const BeamTally& Assessment::beam() const {
  return p_->beam;
}
int Assessment::injections() const {
  return static_cast<int>(p_->injections.size());
}
int Assessment::exchanges() const {
  return p_->exchanges;
}
int Assessment::num_events() const {
  return static_cast<int>(p_->marks.size());
}

int Assessment::force_events(const std::string& name) const {
  for (const Track& tr : p_->tracks)
    if (tr.name == name) return static_cast<int>(tr.force.events.size());
  return -1;
}

double Assessment::wrong_branch_time(const std::string& name) const {
  for (const Track& tr : p_->tracks)
    if (tr.name == name) return tr.wrong_time;
  return -1.0;
}

double Assessment::fluoroscopy_time() const {
  return p_->beam.pedal_used ? p_->beam.fluoro_time : -1.0;
}

// ---------------------------------------------------------------------------------------------
// Writing

namespace {

Json num_or_null(double v) {
  return std::isfinite(v) && v >= 0.0 ? Json(v) : Json(nullptr);
}

double round_to(double v, double q) {
  return std::round(v / q) * q;
}

}  // namespace

void Assessment::write(const fs::path& dir, const Simulator& sim,
                       std::span<const CArmPose> frame_poses,
                       std::span<const double> frame_times) const {
  assert(frame_times.empty() || frame_times.size() == frame_poses.size());
  const Impl& p = *p_;
  const AssessmentSettings& set = p.set;
  const Scenario& sc = sim.scenario();
  const fs::path metrics_file = dir / "metrics.json";
  Json j;
  {
    std::ifstream in(metrics_file);
    if (!in) throw InputError(metrics_file.string(), "file", "expected the run's metrics.json");
    j = Json::parse(in, nullptr, false);
    if (!j.is_object()) throw InputError(metrics_file.string(), "file", "expected a JSON object");
  }
  const double end = sim.time();
  // Beam: the pedals when the input used them, else the beam was on throughout (a headless run
  // films the whole procedure at the scenario's frame rate).
  const bool pedal = p.beam.pedal_used;
  const double fluoro_time = pedal ? p.beam.fluoro_time : end;
  const double cine_time = pedal ? p.beam.cine_time : 0.0;
  const std::int64_t cine_frames = pedal ? p.beam.cine_frames : 0;
  const int cine_runs = pedal ? p.beam.cine_runs : 0;
  const CArmPose& pose = p.pose;
  const DoseEstimate dose =
      estimate_dose(fluoro_time, cine_frames, pose.fov, pose.sid, pose.sod, set);
  Json a;
  a["settings"] = {{"tip_zone_mm", set.tip_zone * 1e3},
                   {"coronary_wire_force_n", set.coronary_wire_force},
                   {"catheter_force_n", set.catheter_force},
                   {"force_time_constant_s", set.force_time_constant},
                   {"event_gap_s", set.event_gap},
                   {"fluoro_kerma_rate_mgy_min", set.fluoro_kerma_rate * 1e3 * 60.0},
                   {"cine_kerma_per_frame_mgy", set.cine_kerma_per_frame * 1e3},
                   {"cine_fps", set.cine_fps},
                   {"irp_offset_mm", set.irp_offset * 1e3},
                   {"engaged_time_s", set.engaged_time},
                   {"deep_intubation_mm", set.deep_intubation * 1e3},
                   {"prolapse_length_mm", set.prolapse_length * 1e3},
                   {"prolapse_angle_deg", set.prolapse_angle * 180.0 / kPi},
                   {"loop_arc_mm", set.loop_arc * 1e3},
                   {"loop_gap_mm", set.loop_gap * 1e3},
                   {"loop_interval_s", set.loop_interval},
                   {"location_interval_s", set.location_interval},
                   {"series_interval_s", set.series_interval}};
  a["procedure_time_s"] = end;
  a["beam"] = {{"source", pedal ? "pedals" : "whole run"},
               {"fluoroscopy_time_s", fluoro_time},
               {"cine_time_s", cine_time},
               {"cine_runs", cine_runs},
               {"cine_frames", cine_frames}};
  a["dose"] = {{"air_kerma_mgy", dose.air_kerma * 1e3},
               {"kerma_area_product_gy_cm2", dose.kerma_area_product * 1e4},
               {"field_area_cm2", dose.field_area * 1e4}};
  Json inj = Json::array();
  for (const Impl::Injection& e : p.injections)
    inj.push_back({{"start_s", e.start},
                   {"end_s", e.end >= 0.0 ? e.end : end},
                   {"volume_ml", e.volume * 1e6}});
  a["contrast"] = {{"volume_ml", p.volume * 1e6}, {"injections", inj}};
  Json insts = Json::array();
  int events_wire = 0, events_catheter = 0, entries = 0, insertions = 0, disengagements = 0;
  int deep_count = 0, prolapse_count = 0, loop_count = 0;
  double wrong_time = 0.0;
  for (const Track& tr : p.tracks) {
    Json ev = Json::array();
    for (const ForceEvent& e : tr.force.events)
      ev.push_back({{"start_s", e.start}, {"end_s", e.end}, {"peak_n", e.peak}});
    const int n = static_cast<int>(tr.force.events.size());
    (tr.kind == InstrumentKind::kCatheter ? events_catheter : events_wire) += n;
    entries += tr.wrong_entries;
    wrong_time += tr.wrong_time;
    insertions += tr.insertions;
    disengagements += tr.disengagements;
    Json e = {{"name", tr.name},
              {"catalogue", tr.catalogue},
              {"kind", to_string(tr.kind)},
              {"insertions", tr.insertions},
              {"first_inserted_s", num_or_null(tr.first_inserted)},
              {"tip_path_mm", tr.tip_path * 1e3},
              {"peak_hand_force_n", tr.peak_hand},
              {"peak_tip_wall_force_n", tr.force.peak},
              {"force_threshold_n", tr.kind == InstrumentKind::kCatheter ? Json(set.catheter_force)
                                    : tr.kind == InstrumentKind::kGuidewire
                                        ? Json(set.coronary_wire_force)
                                        : Json(nullptr)},
              {"force_events", ev},
              {"wrong_branch_time_s", tr.wrong_time},
              {"wrong_branch_entries", tr.wrong_entries},
              {"first_in_coronary_s", num_or_null(tr.first_coronary)},
              {"loops", tr.loop_count},
              {"loop_time_s", tr.loop_time}};
    if (tr.kind == InstrumentKind::kCatheter) {
      e["engaged_s"] = num_or_null(tr.engaged_at);
      e["disengagements"] = tr.disengagements;
      e["max_coronary_depth_mm"] = tr.max_depth >= 0.0 ? Json(tr.max_depth * 1e3) : Json(nullptr);
      e["deep_intubations"] = tr.deep_count;
      e["deep_intubation_time_s"] = tr.deep_time;
    }
    if (tr.kind == InstrumentKind::kGuidewire) {
      e["prolapses"] = tr.prolapse_count;
      e["prolapse_time_s"] = tr.prolapse_time;
    }
    deep_count += tr.deep_count;
    prolapse_count += tr.prolapse_count;
    loop_count += tr.loop_count;
    insts.push_back(e);
  }
  a["instruments"] = insts;
  a["exchanges"] = p.exchanges;
  Json les = Json::array();
  double time_to_cross = -1.0;
  for (std::size_t k = 0; k < p.crossings.size(); ++k) {
    const Impl::Crossing& c = p.crossings[k];
    les.push_back({{"segment", sim.tree().segments[c.segment].name},
                   {"crossed", c.at >= 0.0},
                   {"crossed_at_s", num_or_null(c.at)},
                   {"crossed_by", c.by},
                   {"time_to_cross_s", num_or_null(c.time_to_cross)}});
    if (k == 0) time_to_cross = c.time_to_cross;
  }
  a["lesions"] = les;
  // The treatment, as the procedure layer measures it.
  const SimModel& md = sim.model();
  double residual = -1.0, ratio = -1.0, pressure = -1.0, offset = kNaN, malapposition = -1.0;
  int miss = -1, complications = 0;
  if (!md.procedure.lesions.empty() || !md.procedure.balloons.empty()) {
    const ProcedureOutcome po = procedure_outcome(md.procedure, md.tree, sim.state().procedure);
    for (const LesionOutcome& o : po.lesions) residual = std::max(residual, 100.0 * o.stenosis_now);
    for (const BalloonOutcome& o : po.balloons) {
      if (o.max_pressure <= 0.0) continue;
      ratio = std::max(ratio, o.max_ratio);
      pressure = std::max(pressure, o.max_pressure / kAtm);
      complications += (o.ruptured ? 1 : 0) + (o.over_expanded ? 1 : 0);
    }
    for (const StentOutcome& so : po.stents) {
      if (!so.deployed) continue;
      if (!std::isfinite(offset) || std::abs(so.longitudinal_offset) > std::abs(offset * 1e-3))
        offset = so.longitudinal_offset * 1e3;
      miss = std::max(miss, so.geographic_miss ? 1 : 0);
      malapposition = std::max(malapposition, so.malapposition * 1e3);
    }
  }
  Json comp = Json::array();
  for (const Mark& m : p.marks)
    if (m.what == "procedure: rupture" || m.what == "procedure: over-expansion")
      comp.push_back(
          {{"time_s", m.time}, {"what", m.what.substr(11)}, {"instrument", m.instrument}});
  a["treatment"] = {{"residual_stenosis_percent", num_or_null(residual)},
                    {"balloon_to_artery_ratio", num_or_null(ratio)},
                    {"max_pressure_atm", num_or_null(pressure)},
                    {"stent_offset_mm", std::isfinite(offset) ? Json(offset) : Json(nullptr)},
                    {"geographic_miss", miss < 0 ? Json(nullptr) : Json(miss == 1)},
                    {"malapposition_mm", num_or_null(malapposition)},
                    {"complications", comp}};
  // The timeline
  Json phases = Json::array();
  for (std::size_t k = 0; k < p.phases.size(); ++k)
    phases.push_back({{"start_s", p.phases[k].start},
                      {"end_s", k + 1 < p.phases.size() ? p.phases[k + 1].start : end},
                      {"label", p.phases[k].label}});
  a["phases"] = phases;
  Json iv = Json::array();
  for (const Interval& i : p.intervals)
    iv.push_back({{"row", i.row}, {"start_s", i.start}, {"end_s", i.end >= 0.0 ? i.end : end}});
  if (!pedal)  // the beam was on throughout
    iv.push_back({{"row", "fluoroscopy"}, {"start_s", 0.0}, {"end_s", end}});
  a["intervals"] = iv;
  // Events in time order, the landmarks reached among them.
  std::vector<Mark> sorted = p.marks;
  const Json landmarks = j.contains("landmarks") ? j["landmarks"] : Json::array();
  for (const Json& l : landmarks)
    if (l.value("reached", false) && l["time_s"].is_number())
      sorted.push_back({l["time_s"].get<double>(), "landmark: " + l.value("name", std::string()),
                        l.value("instrument", std::string())});
  std::stable_sort(sorted.begin(), sorted.end(),
                   [](const Mark& x, const Mark& y) { return x.time < y.time; });
  Json marks = Json::array();
  for (const Mark& m : sorted)
    marks.push_back({{"time_s", m.time}, {"what", m.what}, {"instrument", m.instrument}});
  a["events"] = marks;
  // The scenario's fluoroscopy view (each frame's own pose, which a trainee may have changed:
  // frames.csv).
  a["view"] = {{"primary_deg", pose.primary_deg},
               {"secondary_deg", pose.secondary_deg},
               {"sid_mm", pose.sid * 1e3},
               {"sod_mm", pose.sod * 1e3},
               {"fov_mm", pose.fov * 1e3},
               {"size_px", sc.fluoro.size},
               {"fps", sc.fluoro.fps},
               {"frames", frame_poses.size()}};
  // The scalars a spreadsheet or a comparison reads (docs/assessment.md, "summary").
  int reached = 0;
  for (const Json& l : landmarks) reached += l.value("reached", false) ? 1 : 0;
  a["summary"] = {{"procedure_time_s", end},
                  {"fluoroscopy_time_s", fluoro_time},
                  {"cine_runs", cine_runs},
                  {"cine_frames", cine_frames},
                  {"contrast_volume_ml", p.volume * 1e6},
                  {"injections", p.injections.size()},
                  {"air_kerma_mgy", dose.air_kerma * 1e3},
                  {"kerma_area_product_gy_cm2", dose.kerma_area_product * 1e4},
                  {"force_events_wire", events_wire},
                  {"force_events_catheter", events_catheter},
                  {"wrong_branch_time_s", wrong_time},
                  {"wrong_branch_entries", entries},
                  {"exchanges", p.exchanges},
                  {"insertions", insertions},
                  {"guide_disengagements", disengagements},
                  {"deep_intubations", deep_count},
                  {"wire_prolapses", prolapse_count},
                  {"instrument_loops", loop_count},
                  {"time_to_cross_s", num_or_null(time_to_cross)},
                  {"residual_stenosis_percent", num_or_null(residual)},
                  {"balloon_to_artery_ratio", num_or_null(ratio)},
                  {"max_pressure_atm", num_or_null(pressure)},
                  {"stent_offset_mm", std::isfinite(offset) ? Json(offset) : Json(nullptr)},
                  {"geographic_miss", miss < 0 ? Json(nullptr) : Json(miss)},
                  {"complications", comp.size()},
                  {"landmarks_reached", reached},
                  {"landmarks", landmarks.size()},
                  {"success", j.value("success", false) ? 1 : 0}};
  j["assessment"] = a;
  {
    std::ofstream out(metrics_file);
    out << j.dump(2) << "\n";
    if (!out) throw InputError(metrics_file.string(), "file", "expected a writable file");
  }
  // series.csv: one row per series_interval
  const fs::path series_file = dir / "series.csv";
  std::ofstream s(series_file);
  s << "time_s,beam,syringe_flow_ml_s,contrast_ml,beam_on_s,air_kerma_mgy";
  for (const Track& tr : p.tracks)
    for (const char* col :
         {"depth_mm", "force_n", "tip_wall_force_n", "tip_x_mm", "tip_y_mm", "tip_z_mm"})
      s << ',' << tr.name << '_' << col;
  s << '\n';
  char buf[128];
  auto put = [&](float v, const char* fmt) {
    if (std::isfinite(v)) {
      std::snprintf(buf, sizeof buf, fmt, static_cast<double>(v));
      s << ',' << buf;
    } else {
      s << ',';
    }
  };
  for (std::size_t r = 0; r < p.row_t.size(); ++r) {
    std::snprintf(buf, sizeof buf, "%.3f", static_cast<double>(p.row_t[r]));
    s << buf;
    put(p.beam_state[r], "%.0f");
    put(p.flow_ml_s[r], "%.3f");
    put(p.contrast_ml[r], "%.3f");
    put(p.fluoro_s[r], "%.3f");
    put(p.kerma_mgy[r], "%.3f");
    for (const Track& tr : p.tracks) {
      auto at = [&](const std::vector<float>& v) {
        return r >= tr.row0 && r - tr.row0 < v.size() ? v[r - tr.row0] : NAN;
      };
      put(at(tr.depth_mm), "%.2f");
      put(at(tr.force_n), "%.4f");
      put(at(tr.wall_n), "%.4f");
      put(at(tr.x_mm), "%.2f");
      put(at(tr.y_mm), "%.2f");
      put(at(tr.z_mm), "%.2f");
    }
    s << '\n';
  }
  if (!s) throw InputError(series_file.string(), "file", "expected a writable file");
  // frames.csv: each frame's time and C-arm pose (table pan, angles, distances, field)
  if (!frame_poses.empty()) {
    const fs::path frames_file = dir / "frames.csv";
    std::ofstream f(frames_file);
    f << "frame,time_s,isocentre_x_mm,isocentre_y_mm,isocentre_z_mm,primary_deg,secondary_deg,"
         "sid_mm,sod_mm,fov_mm\n";
    const double frame_dt = 1.0 / sc.fluoro.fps;
    for (std::size_t k = 0; k < frame_poses.size(); ++k) {
      const CArmPose& fp = frame_poses[k];
      const double t = k < frame_times.size() ? frame_times[k] : static_cast<double>(k) * frame_dt;
      std::snprintf(buf, sizeof buf, "%.4f", round_to(t, 1e-4));
      f << k << ',' << buf;
      for (int d = 0; d < 3; ++d) {
        std::snprintf(buf, sizeof buf, ",%.3f", fp.isocentre[d] * 1e3);
        f << buf;
      }
      std::snprintf(buf, sizeof buf, ",%.3f,%.3f,%.3f,%.3f,%.3f", fp.primary_deg, fp.secondary_deg,
                    fp.sid * 1e3, fp.sod * 1e3, fp.fov * 1e3);
      f << buf << '\n';
    }
    if (!f) throw InputError(frames_file.string(), "file", "expected a writable file");
  }
}

// ---------------------------------------------------------------------------------------------

bool ObserverList::before_step(const Simulator& sim, const StepCommands& commands) {
  bool go = true;
  for (RunObserver* o : list_) go = o->before_step(sim, commands) && go;
  return go;
}

void ObserverList::after_step(const Simulator& sim) {
  for (RunObserver* o : list_) o->after_step(sim);
}

void ObserverList::exchanged(const Simulator& sim, const InstrumentChange& change) {
  for (RunObserver* o : list_) o->exchanged(sim, change);
}

}  // namespace vcsim
