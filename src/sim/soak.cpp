// Soak: seeded random hands on every instrument of a scene for a long simulated time, watching
// for what must never happen (a non-finite value and its rollback, memory that grows) and for the
// hand force's smoothness (docs/scenarios.md, "Soak").
#include <algorithm>
#include <array>
#include <cmath>
#include <fstream>
#include <sstream>

#include "vcsim/sim.h"
#include "vcsim/units.h"

namespace vcsim {

namespace {

constexpr int kWindow = 11;  // steps in the neighbourhood whose median a force is compared with

}  // namespace

SoakHands::SoakHands(const SimModel& model, const SoakSettings& settings)
    : settings_(settings), rng_{settings.seed * 0x2545F4914F6CDD1Dull + 17} {
  const int n = model.num_instruments();
  hands_.resize(static_cast<std::size_t>(n));
  for (int i = 0; i < n; ++i) {
    Hand& h = hands_[static_cast<std::size_t>(i)];
    // Deep enough to reach every vessel from the groin, short of the instrument's end.
    const RodModel& rod = model.solver.instruments[static_cast<std::size_t>(i)].rod();
    h.max_depth = std::min(settings.max_depth, rod.length - 0.2);
    h.until = 0.0;
  }
}

double SoakHands::uniform(double lo, double hi) {
  return lo + (hi - lo) * rng_.uniform();
}

void SoakHands::next_gesture(Hand& h, double now, double depth) {
  const double u = rng_.uniform();
  const double v = settings_.max_speed, w = settings_.max_spin;
  h.speed = 0.0;
  h.spin = 0.0;
  h.reversal = 0.0;
  h.target = -1.0;
  if (u < 0.15) {  // hold
    h.gesture = Gesture::kHold;
    h.until = now + uniform(0.2, 1.0);
  } else if (u < 0.45) {  // push, turning a little
    h.gesture = Gesture::kPush;
    h.speed = uniform(0.1, 1.0) * v;
    h.spin = uniform(-0.3, 0.3) * w;
    h.until = now + uniform(0.3, 3.0);
  } else if (u < 0.6) {  // pull
    h.gesture = Gesture::kPull;
    h.speed = -uniform(0.1, 1.0) * v;
    h.until = now + uniform(0.3, 2.0);
  } else if (u < 0.75) {  // turn in place
    h.gesture = Gesture::kTurn;
    h.spin = uniform(-1.0, 1.0) * w;
    h.until = now + uniform(0.3, 2.0);
  } else if (u < 0.88) {  // fast reversals: push and pull every 0.1-0.3 s
    h.gesture = Gesture::kReversals;
    h.speed = uniform(0.5, 1.0) * v;
    h.reversal = uniform(0.1, 0.3);
    h.until = now + uniform(0.8, 2.5);
  } else if (u < 0.94 || depth < 0.05) {  // full withdrawal, then reinsertion
    h.gesture = Gesture::kWithdraw;
    h.speed = -v;
    h.target = 0.0;
    h.until = now + 60.0;
  } else {  // reinsert to a random depth at full speed
    h.gesture = Gesture::kReinsert;
    h.speed = v;
    h.target = uniform(0.2, 1.0) * h.max_depth;
    h.until = now + 60.0;
  }
  h.started = now;
}

void SoakHands::command(const Simulator& sim, StepCommands& out) {
  const int n = sim.num_instruments();
  out.reset(static_cast<std::size_t>(n));
  const double now = sim.time();
  for (int i = 0; i < n; ++i) {
    Hand& h = hands_[static_cast<std::size_t>(i)];
    const double depth = sim.depth(i);
    const bool reached = (h.gesture == Gesture::kWithdraw && depth <= 1e-3) ||
                         (h.gesture == Gesture::kReinsert && depth >= h.target);
    if (now >= h.until || reached) {
      if (h.gesture == Gesture::kWithdraw && reached) {
        h.gesture = Gesture::kReinsert;  // withdrawn: back in
        h.speed = settings_.max_speed;
        h.target = uniform(0.2, 1.0) * h.max_depth;
        h.until = now + 60.0;
        h.started = now;
      } else {
        next_gesture(h, now, depth);
      }
    }
    double speed = h.speed;
    if (h.gesture == Gesture::kReversals) {
      const auto half = static_cast<long>(std::floor((now - h.started) / h.reversal));
      speed = (half % 2 == 0) ? h.speed : -h.speed;
    }
    // The hand stays between the sheath and the instrument's usable length.
    if (depth >= h.max_depth && speed > 0.0) speed = 0.0;
    if (depth <= 0.0 && speed < 0.0) speed = 0.0;
    out.drive[static_cast<std::size_t>(i)] = {DriveCommand::Mode::kVelocity, speed, h.spin};
  }
  // Now and then a hand injection of contrast through the guide.
  if (now >= inject_until_ && rng_.uniform() < 2e-4) inject_until_ = now + uniform(0.5, 2.0);
  if (now < inject_until_) out.syringe_flow = 3.0 * kMl;
}

// ---------------------------------------------------------------------------------------------

SoakWatch::SoakWatch(int instruments)
    : window_(static_cast<std::size_t>(instruments)),
      inserted_(static_cast<std::size_t>(instruments), 0) {
  report_.instruments.resize(static_cast<std::size_t>(instruments));
  for (auto& w : window_) w.reserve(kWindow);
}

void SoakWatch::after_step(const Simulator& sim) {
  const int n = sim.num_instruments();
  for (int i = 0; i < n && i < static_cast<int>(window_.size()); ++i) {
    auto& w = window_[static_cast<std::size_t>(i)];
    const InstrumentState& st = sim.instrument(i);
    const double f = st.drive.axial_force;
    SoakReport::Instrument& r = report_.instruments[static_cast<std::size_t>(i)];
    r.deepest = std::max(r.deepest, st.drive.depth);
    if (st.drive.slipped) ++r.slipped_steps;
    const bool in = st.drive.depth >= Simulator::kWithdrawnDepth;
    if (!in && inserted_[static_cast<std::size_t>(i)]) ++r.withdrawals;
    inserted_[static_cast<std::size_t>(i)] = in ? 1 : 0;
    // Only while inserted: outside, the force is the sheath's and zero.
    if (!in) {
      w.clear();
      continue;
    }
    if (static_cast<int>(w.size()) == kWindow) w.erase(w.begin());
    w.push_back(f);
    if (static_cast<int>(w.size()) < kWindow) continue;
    // The middle step against the median of the 11.
    std::array<double, kWindow> sorted;
    std::copy(w.begin(), w.end(), sorted.begin());
    std::nth_element(sorted.begin(), sorted.begin() + kWindow / 2, sorted.end());
    const double off = std::abs(w[kWindow / 2] - sorted[kWindow / 2]);
    r.largest_departure = std::max(r.largest_departure, off);
    if (off > 1.0) ++r.departures;
    r.largest_force = std::max(r.largest_force, std::abs(f));
    ++r.checked_steps;
  }
}

double resident_megabytes() {
  std::ifstream f("/proc/self/statm");
  long pages_total = 0, pages_resident = 0;
  if (!(f >> pages_total >> pages_resident)) return 0.0;
  return static_cast<double>(pages_resident) * 4096.0 / (1024.0 * 1024.0);
}

SoakReport soak(Simulator& sim, const SoakSettings& settings, RunObserver* observer) {
  SoakHands hands(sim.model(), settings);
  SoakWatch watch(sim.num_instruments());
  StepCommands cmd;
  const double t0 = now_us();
  const double end = sim.time() + settings.duration;
  double next_sample = sim.time() + 60.0;
  SoakReport& rep = watch.report();
  rep.resident_start_mb = resident_megabytes();
  while (sim.time() < end - 0.5 * sim.dt()) {
    hands.command(sim, cmd);
    if (observer && !observer->before_step(sim, cmd)) break;
    sim.step(cmd);
    watch.after_step(sim);
    if (observer) observer->after_step(sim);
    if (sim.time() >= next_sample) {
      const double mb = resident_megabytes();
      if (rep.resident_after_first_minute_mb <= 0.0) rep.resident_after_first_minute_mb = mb;
      rep.resident_samples_mb.push_back(mb);
      next_sample += 60.0;
    }
  }
  rep.steps = sim.metrics().steps;
  rep.simulated = sim.time();
  rep.wall = (now_us() - t0) * 1e-6;
  rep.rollbacks = sim.metrics().rollbacks;
  rep.runaway_steps = sim.metrics().runaway_steps;
  rep.calmed_steps = sim.metrics().calmed_steps;
  rep.resident_end_mb = resident_megabytes();
  rep.finite = sim.state().hash() != 0;
  for (int i = 0; i < sim.num_instruments(); ++i) {
    const InstrumentState& st = sim.instrument(i);
    for (const Vec3& x : st.rod.x) rep.finite = rep.finite && x.allFinite();
    rep.instruments[static_cast<std::size_t>(i)].name = sim.model().instrument_name(i);
    if (static_cast<std::size_t>(i) < sim.metrics().escapes.size())
      rep.instruments[static_cast<std::size_t>(i)].escape =
          sim.metrics().escapes[static_cast<std::size_t>(i)];
  }
  return rep;
}

double SoakReport::memory_growth() const {
  if (resident_after_first_minute_mb <= 0.0) return 0.0;
  return (resident_end_mb - resident_after_first_minute_mb) / resident_after_first_minute_mb;
}

bool SoakReport::passed() const {
  bool escaped = false;
  for (const Instrument& i : instruments) escaped = escaped || i.escape.steps > 0;
  return finite && rollbacks == 0 && memory_growth() < 0.01 && !escaped;
}

}  // namespace vcsim
