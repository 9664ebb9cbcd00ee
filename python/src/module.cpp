// vcsim's Python module (_vcsim, wrapped by the vcsim package): the engine as a library for
// learning and scripting (docs/python.md). Arrays are numpy, units SI (m, rad, N, s); stepping,
// snapshot restore and rendering release the GIL, so threads step simulators side by side.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <cmath>
#include <condition_variable>
#include <deque>
#include <exception>
#include <mutex>
#include <optional>
#include <sstream>
#include <thread>
#include <utility>

#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include "vcsim/anatomy.h"
#include "vcsim/render.h"
#include "vcsim/sim.h"
#include "vcsim/units.h"

namespace py = pybind11;
using namespace vcsim;

namespace {

using Array = py::array_t<double, py::array::c_style | py::array::forcecast>;

// (n, 3) array of points.
Array points_array(std::span<const Vec3> pts) {
  Array a({static_cast<py::ssize_t>(pts.size()), py::ssize_t{3}});
  auto m = a.mutable_unchecked<2>();
  for (std::size_t i = 0; i < pts.size(); ++i)
    for (int k = 0; k < 3; ++k) m(static_cast<py::ssize_t>(i), k) = pts[i][k];
  return a;
}

std::string shape_of(const py::array& a) {
  std::ostringstream o;
  o << "(";
  for (py::ssize_t i = 0; i < a.ndim(); ++i) o << (i ? ", " : "") << a.shape(i);
  o << (a.ndim() == 1 ? ",)" : ")");
  return o.str();
}

Vec3 vec3_arg(const py::handle& h, const char* name) {
  Array a = Array::ensure(h);
  if (!a || a.ndim() != 1 || a.shape(0) != 3)
    throw py::value_error(std::string(name) + ": expected 3 numbers (x, y, z in m)");
  Vec3 v(a.at(0), a.at(1), a.at(2));
  if (!v.allFinite()) throw py::value_error(std::string(name) + ": expected finite values");
  return v;
}

// ------------------------------------------------------------------------------------------
// Anatomy

VesselTree builtin_tree(const std::string& name) {
  if (name == "arch") return arch_anatomy(PatientVariant::kRightDominant);
  if (name == "arch-tortuous" || name == "arch-left-dominant")
    return arch_anatomy(PatientVariant::kLeftDominantTortuous);
  if (name == "default" || name == "right-dominant")
    return default_patient(PatientVariant::kRightDominant);
  if (name == "left-dominant") return default_patient(PatientVariant::kLeftDominantTortuous);
  throw InputError(
      "Anatomy.builtin", "name",
      "expected default, right-dominant, left-dominant, arch or arch-tortuous, got '" + name + "'");
}

py::list centrelines(const VesselTree& t) {
  py::list out;
  for (int i = 0; i < t.num_segments(); ++i) {
    const VesselSegment& s = t.segments[static_cast<std::size_t>(i)];
    py::dict d;
    d["name"] = s.name;
    d["kind"] = std::string(to_string(s.kind));
    d["parent"] = s.parent;
    d["points"] = points_array(s.points);
    d["radii"] = Array(static_cast<py::ssize_t>(s.radii.size()), s.radii.data());
    d["closed_end"] = s.closed_end;
    d["ostium_distance"] = ostium_distance(t, i);
    out.append(d);
  }
  return out;
}

TreeLocation location(const VesselTree& t, const std::string& segment, double distance,
                      const char* what) {
  const int s = t.find(segment);
  if (s < 0) throw py::value_error(std::string(what) + ": no segment named '" + segment + "'");
  const double len = segment_length(t.segments[static_cast<std::size_t>(s)]);
  if (!(distance >= 0.0 && distance <= len))
    throw py::value_error(std::string(what) + ": expected a distance in [0, " +
                          std::to_string(len) + "] m along '" + segment + "'");
  return {s, distance};
}

// Length along the centrelines from a place to another (m).
double path_length(const VesselTree& t, const TreeLocation& a, const TreeLocation& b) {
  const std::vector<Vec3> r = route(t, a, b, 1e-3);
  double len = 0.0;
  for (std::size_t i = 1; i < r.size(); ++i) len += (r[i] - r[i - 1]).norm();
  return len;
}

// ------------------------------------------------------------------------------------------
// Simulator

struct PySnapshot {
  SimState state;
};

class PySimulator {
 public:
  PySimulator(Scenario sc, std::optional<VesselTree> tree) {
    py::gil_scoped_release nogil;
    sim_ = std::make_unique<Simulator>(tree ? build_sim_model(std::move(sc), std::move(*tree))
                                            : build_sim_model(std::move(sc)));
    cmd_.reset(static_cast<std::size_t>(sim_->num_instruments()));
  }
  Simulator& sim() { return *sim_; }
  const Simulator& sim() const { return *sim_; }
  int n() const { return sim_->num_instruments(); }

  // Reads an (instruments, 2) action into cmd_ (checked before anything changes).
  void read_action(const py::object& action, const std::string& mode) {
    DriveCommand::Mode m;
    if (mode == "velocity")
      m = DriveCommand::Mode::kVelocity;
    else if (mode == "position")
      m = DriveCommand::Mode::kPosition;
    else
      throw py::value_error("mode: expected 'velocity' or 'position', got '" + mode + "'");
    cmd_.reset(static_cast<std::size_t>(n()));
    if (action.is_none()) return;
    Array a = Array::ensure(action);
    if (!a) throw py::value_error("action: expected an array of numbers");
    const bool flat = a.ndim() == 1 && a.shape(0) == 2 * n();
    if (!flat && !(a.ndim() == 2 && a.shape(0) == n() && a.shape(1) == 2))
      throw py::value_error("action: expected shape (" + std::to_string(n()) +
                            ", 2) (instrument, [translation, rotation]), got " + shape_of(a));
    const double* d = a.data();
    for (int i = 0; i < n(); ++i) {
      for (int k = 0; k < 2; ++k)
        if (!std::isfinite(d[2 * i + k]))
          throw py::value_error("action: expected finite values, got " +
                                std::to_string(d[2 * i + k]) + " at [" + std::to_string(i) + ", " +
                                std::to_string(k) + "] (instrument '" +
                                sim_->model().instrument_name(i) + "')");
      cmd_.drive[static_cast<std::size_t>(i)] = {m, d[2 * i], d[2 * i + 1]};
    }
  }

  void step(const py::object& action, int steps, const std::string& mode, double syringe_flow,
            double balloon_pressure) {
    prepare(action, steps, mode, syringe_flow, balloon_pressure);
    py::gil_scoped_release nogil;
    advance(steps);
  }

  // step() in two halves: prepare() checks the arguments and sets the commands (with the GIL),
  // advance() steps (without it), so that step_many() can step several simulators at once.
  void prepare(const py::object& action, int steps, const std::string& mode, double syringe_flow,
               double balloon_pressure) {
    if (steps < 1)
      throw py::value_error("steps: expected at least 1, got " + std::to_string(steps));
    for (auto [v, name] :
         {std::pair{syringe_flow, "syringe_flow"}, std::pair{balloon_pressure, "balloon_pressure"}})
      if (!std::isfinite(v) || v < 0.0)
        throw py::value_error(std::string(name) + ": expected a finite value >= 0");
    read_action(action, mode);
    cmd_.syringe_flow = syringe_flow;
    cmd_.balloon_pressure = balloon_pressure;
  }
  void advance(int steps) {
    auto run = [&] {
      for (int s = 0; s < steps; ++s) sim_->step(cmd_);
    };
    if (arena_)
      arena_->execute(run);
    else
      run();
  }

  // The most threads a step may use: 0 for as many as the process allows (TBB's default), 1 to
  // keep the step on the calling thread, which is what several simulators stepped side by side
  // in threads want (otherwise each one's parallel collision queries compete for the same cores).
  // The results are the same bit for bit whatever the setting.
  int threads() const { return threads_; }
  void set_threads(int n) {
    if (n < 0)
      throw py::value_error("threads: expected 0 (as many as allowed) or more, got " +
                            std::to_string(n));
    if (n == threads_) return;
    threads_ = n;
    arena_ = n > 0 ? std::make_unique<tbb::task_arena>(n) : nullptr;
  }

  Array depths() const {
    Array a(n());
    for (int i = 0; i < n(); ++i) a.mutable_at(i) = sim_->depth(i);
    return a;
  }
  Array rolls() const {
    Array a(n());
    for (int i = 0; i < n(); ++i) a.mutable_at(i) = sim_->instrument(i).drive.roll;
    return a;
  }
  Array tips() const {
    std::vector<Vec3> t;
    for (int i = 0; i < n(); ++i) t.push_back(sim_->tip(i));
    return points_array(t);
  }
  Array hand_forces() {
    sim_->feedback(fb_);
    Array a({static_cast<py::ssize_t>(n()), py::ssize_t{2}});
    auto m = a.mutable_unchecked<2>();
    for (int i = 0; i < n(); ++i) {
      m(i, 0) = fb_[static_cast<std::size_t>(i)].axial_force;
      m(i, 1) = fb_[static_cast<std::size_t>(i)].torque;
    }
    return a;
  }
  int check(int i) const {
    if (i < 0 || i >= n())
      throw py::index_error("instrument: expected an index in [0, " + std::to_string(n()) +
                            "), got " + std::to_string(i));
    return i;
  }
  int index(const py::object& inst) const {
    if (py::isinstance<py::str>(inst)) {
      const std::string name = inst.cast<std::string>();
      const int i = sim_->model().instrument_index(name);
      if (i < 0) {
        std::string names;
        for (const std::string& s : sim_->instrument_names())
          names += (names.empty() ? "" : ", ") + s;
        throw py::value_error("instrument: no instrument named '" + name + "' (the scene has " +
                              names + ")");
      }
      return i;
    }
    return check(inst.cast<int>());
  }
  Array positions(const py::object& inst, bool inserted_only) const {
    const int i = index(inst);
    const auto& x = sim_->instrument(i).rod.x;
    const std::size_t first =
        inserted_only ? static_cast<std::size_t>(sim_->instrument(i).drive.first_free) : 0;
    return points_array(std::span<const Vec3>(x).subspan(std::min(first, x.size())));
  }
  // `count` points along instrument i's inserted part from its tip back, `spacing` m apart by
  // arc length (the last inserted node repeated when the inserted part is shorter).
  Array tracking(const py::object& inst, int count, double spacing) const {
    const int i = index(inst);
    if (count < 1 || count > 10000)
      throw py::value_error("points: expected 1 to 10000, got " + std::to_string(count));
    if (!(spacing > 0.0 && spacing < 1.0))
      throw py::value_error("spacing: expected a length in (0, 1) m");
    std::vector<Vec3> out(static_cast<std::size_t>(count));
    {
      py::gil_scoped_release nogil;
      const auto& x = sim_->instrument(i).rod.x;
      const int first =
          std::min(sim_->instrument(i).drive.first_free, static_cast<int>(x.size()) - 1);
      int k = static_cast<int>(x.size()) - 1;  // walking from the tip toward the hub
      double along = 0.0;                      // arc length from the tip to node k
      for (int p = 0; p < count; ++p) {
        const double want = p * spacing;
        while (k > first && along + (x[k] - x[k - 1]).norm() < want) {
          along += (x[k] - x[k - 1]).norm();
          --k;
        }
        if (k > first) {
          const double seg = (x[k] - x[k - 1]).norm();
          const double t = seg > 0.0 ? std::clamp((want - along) / seg, 0.0, 1.0) : 0.0;
          out[static_cast<std::size_t>(p)] = x[k] + t * (x[k - 1] - x[k]);
        } else {
          out[static_cast<std::size_t>(p)] = x[k];
        }
      }
    }
    return points_array(out);
  }
  py::dict contacts(const py::object& inst) const {
    const int i = index(inst);
    const auto c = sim_->contacts(i);
    py::array_t<int> node(static_cast<py::ssize_t>(c.size()));
    Array normal({static_cast<py::ssize_t>(c.size()), py::ssize_t{3}});
    Array depth(static_cast<py::ssize_t>(c.size()));
    Array force(static_cast<py::ssize_t>(c.size()));
    auto nm = normal.mutable_unchecked<2>();
    for (std::size_t k = 0; k < c.size(); ++k) {
      const auto kk = static_cast<py::ssize_t>(k);
      node.mutable_at(kk) = c[k].node;
      for (int d = 0; d < 3; ++d) nm(kk, d) = c[k].normal[d];
      depth.mutable_at(kk) = c[k].depth;
      force.mutable_at(kk) = c[k].lambda_n / sim_->dt();
    }
    py::dict d;
    d["node"] = node;
    d["normal"] = normal;
    d["depth"] = depth;
    d["force"] = force;
    return d;
  }

 private:
  std::unique_ptr<Simulator> sim_;
  StepCommands cmd_;
  std::vector<HandFeedback> fb_;
  int threads_ = 0;
  std::unique_ptr<tbb::task_arena> arena_;
};

Scenario scenario_from(const py::object& obj) {
  if (py::isinstance<py::dict>(obj)) {
    const std::string text = py::module_::import("json").attr("dumps")(obj).cast<std::string>();
    return parse_scenario(text, "<scenario dict>", default_scenarios_dir());
  }
  if (py::isinstance<py::str>(obj) || py::hasattr(obj, "__fspath__")) {
    const std::string s = py::str(obj).cast<std::string>();
    return load_scenario(find_scenario(s, "Simulator", "scenario"));
  }
  throw py::type_error("scenario: expected a name ('default'), a file path or a dict");
}

// ------------------------------------------------------------------------------------------
// The autopilot as a policy at a control rate: what it would do over the next period, as the
// constant drive velocities that take each instrument from where it is to where the autopilot
// would have taken it (found by running it ahead on a copy of the state).
// Steps `sim` under `pilot` until its plan has done `phases` phases (all: -1), it fails, or
// `duration` s have passed; applies the instrument exchanges it asks for. True when the phases
// are done.
bool run_autopilot(Simulator& sim, Autopilot& pilot, int phases, double duration) {
  StepCommands cmd;
  const double end = sim.time() + duration;
  InstrumentChange change;
  while (sim.time() < end - 0.5 * sim.dt()) {
    if (pilot.finished() || (phases >= 0 && pilot.phase() >= phases)) break;
    if (pilot.exchange_wanted(change)) {
      try {
        sim.exchange(change);
        pilot.rebind(sim.model(), sim.state());
      } catch (const InputError& e) {
        pilot.refused(e);
        break;
      }
      continue;
    }
    pilot.command(sim, cmd);
    sim.step(cmd);
  }
  return !pilot.failed() && (phases < 0 ? pilot.finished() : pilot.phase() >= phases);
}

class AutopilotPolicy {
 public:
  AutopilotPolicy(const PySimulator& s, const Autopilot* from)
      : model_(s.sim().shared_model()), pilot_(from ? *from : Autopilot(s.sim())), ahead_(model_) {}

  Array act(const PySimulator& s, double period) {
    if (!(period > 0.0 && period < 10.0))
      throw py::value_error("period: expected a control period in (0, 10) s");
    if (s.sim().shared_model() != model_)
      throw py::value_error("sim: expected the simulator this policy was made for");
    const int n = s.n();
    std::vector<double> d0(static_cast<std::size_t>(n)), r0(d0), d1(d0), r1(d0);
    {
      py::gil_scoped_release nogil;
      ahead_.restore(s.sim().state());
      for (int i = 0; i < n; ++i) {
        d0[static_cast<std::size_t>(i)] = ahead_.depth(i);
        r0[static_cast<std::size_t>(i)] = ahead_.instrument(i).drive.roll;
      }
      const int steps = std::max(1, static_cast<int>(std::lround(period / ahead_.dt())));
      for (int k = 0; k < steps && !pilot_.finished(); ++k) {
        pilot_.command(ahead_, cmd_);
        ahead_.step(cmd_);
      }
      for (int i = 0; i < n; ++i) {
        d1[static_cast<std::size_t>(i)] = ahead_.depth(i);
        r1[static_cast<std::size_t>(i)] = ahead_.instrument(i).drive.roll;
      }
    }
    Array a({static_cast<py::ssize_t>(n), py::ssize_t{2}});
    auto m = a.mutable_unchecked<2>();
    for (int i = 0; i < n; ++i) {
      m(i, 0) = (d1[static_cast<std::size_t>(i)] - d0[static_cast<std::size_t>(i)]) / period;
      m(i, 1) = (r1[static_cast<std::size_t>(i)] - r0[static_cast<std::size_t>(i)]) / period;
    }
    return a;
  }
  bool finished() const { return pilot_.finished(); }
  bool failed() const { return pilot_.failed(); }
  std::string status() const { return pilot_.status(); }

 private:
  std::shared_ptr<const SimModel> model_;
  Autopilot pilot_;
  Simulator ahead_;
  StepCommands cmd_;
};

// ------------------------------------------------------------------------------------------
// Fluoroscopy: a GL context lives on its own thread (EGL, llvmpipe), so any Python thread may
// ask for an image.
class PyFluoroscopy {
 public:
  PyFluoroscopy(const PySimulator& s, int size) : model_(s.sim().shared_model()), size_(size) {
    if (size < 16 || size > 2048)
      throw py::value_error("size: expected 16 to 2048 pixels, got " + std::to_string(size));
    py::gil_scoped_release nogil;
    worker_ = std::thread([this] { run(); });
    std::unique_lock lk(m_);
    cv_.wait(lk, [&] { return ready_; });
    if (error_) {
      lk.unlock();
      stop();
      std::rethrow_exception(error_);
    }
  }
  ~PyFluoroscopy() { stop(); }

  py::array_t<std::uint8_t> image(const PySimulator& s, const CArmPose& pose, double dose,
                                  std::uint64_t seed) {
    if (!(dose >= 0.0 && std::isfinite(dose)))
      throw py::value_error("dose: expected photons per pixel >= 0");
    pose.validate("Fluoroscopy.image");
    py::array_t<std::uint8_t> out({size_, size_});
    {
      py::gil_scoped_release nogil;
      std::unique_lock lk(m_);
      job_snap_ = snapshot(s.sim());
      job_pose_ = pose;
      job_chain_.dose = dose;
      job_chain_.seed = seed;
      has_job_ = true;
      error_ = nullptr;
      cv_.notify_all();
      cv_.wait(lk, [&] { return !has_job_; });
      if (error_) std::rethrow_exception(error_);
      std::copy(pixels_.begin(), pixels_.end(), out.mutable_data());
    }
    return out;
  }

 private:
  void run() {
    try {
      HeadlessGlContext gl;
      SimFluoroscopy fluoro(*model_, size_);
      {
        std::lock_guard lk(m_);
        ready_ = true;
      }
      cv_.notify_all();
      std::unique_lock lk(m_);
      for (;;) {
        cv_.wait(lk, [&] { return has_job_ || quit_; });
        if (quit_) return;
        try {
          fluoro.frame(job_snap_, job_pose_, job_chain_, pixels_);
        } catch (...) {
          error_ = std::current_exception();
        }
        has_job_ = false;
        cv_.notify_all();
      }
    } catch (...) {
      std::lock_guard lk(m_);
      error_ = std::current_exception();
      ready_ = true;
      cv_.notify_all();
    }
  }
  void stop() {
    {
      std::lock_guard lk(m_);
      quit_ = true;
    }
    cv_.notify_all();
    if (worker_.joinable()) worker_.join();
  }

  std::shared_ptr<const SimModel> model_;
  int size_;
  std::thread worker_;
  std::mutex m_;
  std::condition_variable cv_;
  bool ready_ = false, has_job_ = false, quit_ = false;
  std::exception_ptr error_;
  FrameSnapshot job_snap_;
  CArmPose job_pose_;
  ImageChainSettings job_chain_;
  std::vector<std::uint8_t> pixels_;
};

CArmPose make_pose(double primary_deg, double secondary_deg, double fov, double sid, double sod,
                   const py::object& isocentre) {
  CArmPose p;
  p.primary_deg = primary_deg;
  p.secondary_deg = secondary_deg;
  p.fov = fov;
  p.sid = sid;
  p.sod = sod;
  if (!isocentre.is_none()) p.isocentre = vec3_arg(isocentre, "isocentre");
  p.validate("CArm");
  return p;
}

}  // namespace

// Steps several simulators at once, each `steps[i]` times with its action, on TBB's worker
// threads with the GIL released: what a vector environment's step does, without a Python
// thread pool's hand-offs. Every argument is checked before any simulator moves.
static void step_many(const std::vector<PySimulator*>& sims, const py::list& actions,
                      const std::vector<int>& steps, const std::string& mode) {
  const std::size_t n = sims.size();
  if (actions.size() != n || steps.size() != n)
    throw py::value_error("step_many: expected as many actions and step counts as simulators (" +
                          std::to_string(n) + "), got " + std::to_string(actions.size()) + " and " +
                          std::to_string(steps.size()));
  for (std::size_t i = 0; i < n; ++i) {
    if (sims[i] == nullptr) throw py::value_error("simulators: expected Simulator, got None");
    for (std::size_t j = 0; j < i; ++j)
      if (sims[j] == sims[i])
        throw py::value_error("simulators: the same Simulator appears twice (" + std::to_string(j) +
                              " and " + std::to_string(i) + ")");
  }
  for (std::size_t i = 0; i < n; ++i) sims[i]->prepare(actions[i], steps[i], mode, 0.0, 0.0);
  py::gil_scoped_release nogil;
  tbb::parallel_for(std::size_t{0}, n, [&](std::size_t i) { sims[i]->advance(steps[i]); });
}

// Steps simulators on threads of its own, one per slot, without the GIL, and hands back each
// slot as its physics finishes: a vector environment starts every environment's control step,
// then computes the reward and observation of each as it comes back while the others still
// step (with step_many, Python's share of every environment waited for the slowest's physics;
// issue 28). A simulator must not be used from Python between its start() and the wait() that
// returns its slot.
class Stepper {
 public:
  explicit Stepper(int slots) {
    if (slots < 1 || slots > 1024)
      throw py::value_error("slots: expected 1 to 1024, got " + std::to_string(slots));
    for (int i = 0; i < slots; ++i) slots_.push_back(std::make_unique<Slot>());
    for (int i = 0; i < slots; ++i) slots_[i]->thread = std::thread([this, i] { run(i); });
  }
  ~Stepper() {
    {
      std::lock_guard lk(m_);
      quit_ = true;
    }
    for (auto& s : slots_) s->wake.notify_all();
    // Steps started finish first, without the GIL (the workers never touch Python objects);
    // idle workers end at once, so the GIL is kept then (a Stepper freed as Python shuts down).
    auto join = [&] {
      for (auto& s : slots_)
        if (s->thread.joinable()) s->thread.join();
    };
    if (running_ > 0) {
      py::gil_scoped_release nogil;
      join();
    } else {
      join();
    }
  }
  int size() const { return static_cast<int>(slots_.size()); }
  int running() const { return running_; }

  // Checks the arguments and sets the commands (with the GIL), then the slot's thread steps.
  void start(int slot, const py::object& sim_obj, const py::object& action, int steps,
             const std::string& mode) {
    if (slot < 0 || slot >= size())
      throw py::index_error("slot: expected 0 to " + std::to_string(size() - 1) + ", got " +
                            std::to_string(slot));
    Slot& s = *slots_[slot];
    if (s.busy) throw py::value_error("slot " + std::to_string(slot) + " is still stepping");
    PySimulator* sim = sim_obj.cast<PySimulator*>();
    for (const auto& o : slots_)
      if (o->busy && o->sim == sim)
        throw py::value_error("sim: this Simulator is already stepping in another slot");
    sim->prepare(action, steps, mode, 0.0, 0.0);
    s.keep = sim_obj;  // alive until its slot is waited for
    s.sim = sim;
    s.steps = steps;
    s.busy = true;
    ++running_;
    {
      std::lock_guard lk(m_);
      s.go = true;
    }
    s.wake.notify_one();
  }

  // The next slot whose step has finished (each returned once), waiting without the GIL; its
  // step's exception, if it threw, is raised here.
  int wait() {
    if (running_ == 0) throw py::value_error("wait: no slot is stepping");
    int i;
    {
      py::gil_scoped_release nogil;
      std::unique_lock lk(m_);
      done_.wait(lk, [&] { return !finished_.empty(); });
      i = finished_.front();
      finished_.pop_front();
    }
    Slot& s = *slots_[i];
    s.busy = false;
    --running_;
    s.keep = py::object();
    s.sim = nullptr;
    if (s.error) std::rethrow_exception(std::exchange(s.error, nullptr));
    return i;
  }

 private:
  struct Slot {
    std::thread thread;
    std::condition_variable wake;
    PySimulator* sim = nullptr;
    py::object keep;
    int steps = 0;
    bool go = false, busy = false;
    std::exception_ptr error;
  };
  void run(int i) {
    Slot& s = *slots_[i];
    std::unique_lock lk(m_);
    for (;;) {
      s.wake.wait(lk, [&] { return s.go || quit_; });
      if (!s.go) return;  // a step started before the end is still made
      s.go = false;
      lk.unlock();
      std::exception_ptr error;
      try {
        s.sim->advance(s.steps);
      } catch (...) {
        error = std::current_exception();
      }
      lk.lock();
      s.error = error;
      finished_.push_back(i);
      done_.notify_one();
    }
  }

  std::vector<std::unique_ptr<Slot>> slots_;
  std::mutex m_;
  std::condition_variable done_;
  std::deque<int> finished_;
  int running_ = 0;  // with the GIL
  bool quit_ = false;
};

PYBIND11_MODULE(_vcsim, m) {
  m.doc() = "vcsim: a simulator for training cardiovascular interventions (docs/python.md)";
  py::register_exception<InputError>(m, "InputError", PyExc_ValueError);

  // ---- Anatomy
  py::class_<VesselTree>(m, "Anatomy",
                         "A vessel tree (centrelines and radii, lesions, access, heart)")
      .def_static("builtin", &builtin_tree, py::arg("name") = "default",
                  "A built-in patient: 'default', 'left-dominant', 'arch' or 'arch-tortuous'")
      .def_static(
          "load", [](const std::string& path) { return load_vessel_tree(path); }, py::arg("path"),
          "A vcsim-anatomy JSON file")
      .def(
          "vary",
          [](const VesselTree& t, double aorta_radius_scale, double artery_radius_scale,
             double coronary_radius_scale, double arch_elongation, double tortuosity,
             double tortuosity_wavelength, std::uint64_t seed) {
            AnatomyVariation v;
            v.aorta_radius_scale = aorta_radius_scale;
            v.artery_radius_scale = artery_radius_scale;
            v.coronary_radius_scale = coronary_radius_scale;
            v.arch_elongation = arch_elongation;
            v.tortuosity = tortuosity;
            v.tortuosity_wavelength = tortuosity_wavelength;
            v.seed = seed;
            return vary_anatomy(t, v);
          },
          py::kw_only(), py::arg("aorta_radius_scale") = 1.0, py::arg("artery_radius_scale") = 1.0,
          py::arg("coronary_radius_scale") = 1.0, py::arg("arch_elongation") = 0.0,
          py::arg("tortuosity") = 0.0, py::arg("tortuosity_wavelength") = 80e-3,
          py::arg("seed") = 1, "A varied copy (docs/anatomy.md, 'Variations'); lengths in m")
      .def("save", [](const VesselTree& t, const std::string& p) { save_vessel_tree(t, p); })
      .def("to_json", &vessel_tree_to_json)
      .def_property_readonly("name", [](const VesselTree& t) { return t.name; })
      .def_property_readonly("segment_names",
                             [](const VesselTree& t) {
                               std::vector<std::string> n;
                               for (const auto& s : t.segments) n.push_back(s.name);
                               return n;
                             })
      .def_property_readonly("has_heart", [](const VesselTree& t) { return t.heart.has_value(); })
      .def_property_readonly("access",
                             [](const VesselTree& t) {
                               return py::make_tuple(t.segments[t.access.segment].name,
                                                     t.access.distance);
                             })
      .def("centrelines", &centrelines,
           "Per segment: name, kind, parent, points (k, 3) m, radii (k,) m, closed_end, "
           "ostium_distance m")
      .def(
          "segment_length",
          [](const VesselTree& t, const std::string& seg) {
            return segment_length(t.segments[location(t, seg, 0.0, "segment").segment]);
          },
          py::arg("segment"))
      .def(
          "point_at",
          [](const VesselTree& t, const std::string& seg, double dist) {
            const TreeLocation l = location(t, seg, dist, "point_at");
            const Vec3 p = point_at(t.segments[l.segment], l.distance);
            return points_array(std::span<const Vec3>(&p, 1)).attr("reshape")(3);
          },
          py::arg("segment"), py::arg("distance"))
      .def(
          "locate",
          [](const VesselTree& t, const py::object& p) {
            const TreeHit h = locate(t, vec3_arg(p, "point"));
            return py::make_tuple(h.loc.segment >= 0 ? t.segments[h.loc.segment].name : "",
                                  h.loc.distance, h.outside);
          },
          py::arg("point"), "(segment, distance m, m outside the lumen radius) nearest a point")
      .def(
          "path_length",
          [](const VesselTree& t, const std::string& s0, double d0, const std::string& s1,
             double d1) {
            const TreeLocation a = location(t, s0, d0, "from"), b = location(t, s1, d1, "to");
            py::gil_scoped_release nogil;
            return path_length(t, a, b);
          },
          py::arg("from_segment"), py::arg("from_distance"), py::arg("to_segment"),
          py::arg("to_distance"), "Length along the centrelines between two places, m");

  // ---- C-arm
  py::class_<CArmPose>(m, "CArm", "A C-arm pose (DICOM angles, geometry in m)")
      .def(py::init(&make_pose), py::kw_only(), py::arg("primary_deg") = 0.0,
           py::arg("secondary_deg") = 0.0, py::arg("fov") = 0.2, py::arg("sid") = 1.2,
           py::arg("sod") = 0.78, py::arg("isocentre") = py::none())
      .def_readonly("primary_deg", &CArmPose::primary_deg)
      .def_readonly("secondary_deg", &CArmPose::secondary_deg)
      .def_readonly("fov", &CArmPose::fov)
      .def_property_readonly(
          "isocentre",
          [](const CArmPose& p) {
            return points_array(std::span<const Vec3>(&p.isocentre, 1)).attr("reshape")(3);
          })
      .def(
          "project",
          [](const CArmPose& pose, const py::object& pts) {
            Array a = Array::ensure(pts);
            if (!a || a.ndim() != 2 || a.shape(1) != 3)
              throw py::value_error("points: expected shape (k, 3), got " +
                                    (a ? shape_of(a) : std::string("no array")));
            Array out({a.shape(0), py::ssize_t{2}});
            auto in = a.unchecked<2>();
            auto o = out.mutable_unchecked<2>();
            for (py::ssize_t i = 0; i < a.shape(0); ++i) {
              const Eigen::Vector2d q =
                  project_to_detector(pose, Vec3(in(i, 0), in(i, 1), in(i, 2)));
              o(i, 0) = q.x();
              o(i, 1) = q.y();
            }
            return out;
          },
          py::arg("points"),
          "Detector coordinates (m from the centre, along image right and up) of (k, 3) points");

  // ---- Simulator
  py::class_<PySnapshot>(m, "Snapshot", "A copy of a simulation's whole state")
      .def_property_readonly("time", [](const PySnapshot& s) { return s.state.time(); })
      .def_property_readonly("hash", [](const PySnapshot& s) { return s.state.hash(); })
      .def_property_readonly("bytes", [](const PySnapshot& s) { return s.state.bytes(); });

  py::class_<PySimulator>(m, "Simulator", "A scene (anatomy, instruments, procedure) and its state")
      .def(py::init([](const py::object& scenario, std::optional<VesselTree> anatomy,
                       std::optional<std::uint64_t> seed) {
             Scenario sc = scenario_from(scenario);
             if (seed) sc.seed = *seed;
             return std::make_unique<PySimulator>(std::move(sc), std::move(anatomy));
           }),
           py::arg("scenario") = "default", py::kw_only(), py::arg("anatomy") = py::none(),
           py::arg("seed") = py::none())
      .def("step", &PySimulator::step, py::arg("action") = py::none(), py::kw_only(),
           py::arg("steps") = 1, py::arg("mode") = "velocity", py::arg("syringe_flow") = 0.0,
           py::arg("balloon_pressure") = 0.0,
           "Steps `steps` times with the same commands: action (instruments, 2) = [translation "
           "m/s, rotation rad/s] (mode 'velocity') or [depth m, roll rad] (mode 'position')")
      .def("snapshot", [](const PySimulator& s) { return PySnapshot{s.sim().snapshot()}; })
      .def(
          "restore",
          [](PySimulator& s, const PySnapshot& snap) {
            py::gil_scoped_release nogil;
            s.sim().restore(snap.state);
          },
          py::arg("snapshot"))
      .def_property_readonly("time", [](const PySimulator& s) { return s.sim().time(); })
      .def_property_readonly("dt", [](const PySimulator& s) { return s.sim().dt(); })
      .def_property("threads", &PySimulator::threads, &PySimulator::set_threads,
                    "The most threads step() may use: 0 (default) as many as the process "
                    "allows, 1 the calling thread only; the results are the same either way")
      .def_property_readonly("num_instruments", &PySimulator::n)
      .def_property_readonly("instrument_names",
                             [](const PySimulator& s) { return s.sim().instrument_names(); })
      .def_property_readonly(
          "anatomy", [](const PySimulator& s) -> const VesselTree& { return s.sim().tree(); },
          py::return_value_policy::reference_internal,
          "The scene's anatomy at rest (lesions applied); lives as long as the simulator")
      .def_property_readonly("state_hash",
                             [](const PySimulator& s) { return s.sim().state().hash(); })
      .def_property_readonly("rollbacks",
                             [](const PySimulator& s) { return s.sim().metrics().rollbacks; })
      .def("depths", &PySimulator::depths, "Inserted length per instrument, m")
      .def("rolls", &PySimulator::rolls, "Hand roll per instrument, rad")
      .def("tips", &PySimulator::tips, "(instruments, 3) distal tips, m")
      .def("hand_forces", &PySimulator::hand_forces,
           "(instruments, 2): axial force N (> 0 resists insertion), torque N m")
      .def("positions", &PySimulator::positions, py::arg("instrument"),
           py::arg("inserted_only") = true, "(nodes, 3) centreline of an instrument, m")
      .def("tracking", &PySimulator::tracking, py::arg("instrument"), py::arg("points"),
           py::arg("spacing"),
           "(points, 3): the inserted part from the tip back, `spacing` m apart by arc length")
      .def("contacts", &PySimulator::contacts, py::arg("instrument"),
           "The last step's wall contacts: node, normal (k, 3), depth m, force N")
      .def(
          "tip_location",
          [](const PySimulator& s, const py::object& inst) {
            const int i = s.index(inst);
            TreeHit h;
            {
              py::gil_scoped_release nogil;
              h = s.sim().tip_location(i);
            }
            return py::make_tuple(
                h.loc.segment >= 0 ? s.sim().tree().segments[h.loc.segment].name : std::string(),
                h.loc.distance, h.outside);
          },
          py::arg("instrument"), "(segment, distance m, m outside the lumen radius) of a tip")
      .def(
          "tip_rest",
          [](const PySimulator& s, const py::object& inst) {
            const Vec3 p = s.sim().tip_rest(s.index(inst));
            return points_array(std::span<const Vec3>(&p, 1)).attr("reshape")(3);
          },
          py::arg("instrument"), "The tip carried back to the anatomy at rest, m")
      .def(
          "index", [](const PySimulator& s, const py::object& i) { return s.index(i); },
          py::arg("instrument"))
      .def(
          "lumen_mesh",
          [](const PySimulator& s) {
            const TriangleMesh& mesh = s.sim().lumen().mesh;
            py::array_t<std::int32_t> f(
                {static_cast<py::ssize_t>(mesh.triangles.size()), py::ssize_t{3}});
            auto fm = f.mutable_unchecked<2>();
            for (std::size_t i = 0; i < mesh.triangles.size(); ++i)
              for (int k = 0; k < 3; ++k) fm(static_cast<py::ssize_t>(i), k) = mesh.triangles[i][k];
            return py::make_tuple(points_array(mesh.vertices), f);
          },
          "The lumen at rest: vertices (v, 3) m, triangles (t, 3)")
      .def("all_landmarks_reached",
           [](const PySimulator& s) { return s.sim().all_landmarks_reached(); });

  py::class_<Autopilot>(m, "Autopilot",
                        "The scenario's autopilot plan and where it is in it (a plain value)")
      .def(py::init([](const PySimulator& s) { return Autopilot(s.sim()); }), py::arg("sim"))
      .def("copy", [](const Autopilot& a) { return Autopilot(a); })
      .def(
          "run",
          [](Autopilot& a, PySimulator& s, int phases, double duration) {
            if (!(duration >= 0.0 && std::isfinite(duration)))
              throw py::value_error("duration: expected a finite time >= 0 s");
            py::gil_scoped_release nogil;
            return run_autopilot(s.sim(), a, phases, duration);
          },
          py::arg("sim"), py::kw_only(), py::arg("phases") = -1, py::arg("duration") = 600.0,
          "Drives sim until `phases` phases of the plan are done (-1: all), the autopilot fails "
          "or `duration` s pass; True when the phases are done")
      .def_readwrite("max_retries", &Autopilot::max_retries,
                     "Retries per phase before it gives up (16)")
      .def_readwrite("trace", &Autopilot::trace,
                     "Print what it sees and does to stderr, 4 times a second (False)")
      .def_property_readonly("phase", &Autopilot::phase)
      .def_property_readonly("finished", &Autopilot::finished)
      .def_property_readonly("failed", &Autopilot::failed)
      .def_property_readonly("status", &Autopilot::status);

  py::class_<AutopilotPolicy>(m, "AutopilotPolicy",
                              "The scenario's autopilot as a policy at a control rate")
      .def(py::init([](const PySimulator& s, const Autopilot* from) {
             return std::make_unique<AutopilotPolicy>(s, from);
           }),
           py::arg("sim"), py::arg("autopilot") = nullptr)
      .def("act", &AutopilotPolicy::act, py::arg("sim"), py::arg("period"),
           "(instruments, 2) velocities [m/s, rad/s] for the next period")
      .def_property_readonly("finished", &AutopilotPolicy::finished)
      .def_property_readonly("failed", &AutopilotPolicy::failed)
      .def_property_readonly("status", &AutopilotPolicy::status);

  py::class_<PyFluoroscopy>(m, "Fluoroscopy", "Fluoroscopy images of a simulator's scene")
      .def(py::init<const PySimulator&, int>(), py::arg("sim"), py::arg("size") = 256)
      .def(
          "image",
          [](PyFluoroscopy& f, const PySimulator& s, const CArmPose& pose, double dose,
             std::uint64_t seed) { return f.image(s, pose, dose, seed); },
          py::arg("sim"), py::arg("carm"), py::kw_only(), py::arg("dose") = 1e4,
          py::arg("seed") = 1, "(size, size) uint8 grey image, row 0 at the top");

  py::class_<Stepper>(m, "Stepper",
                      "Steps simulators on threads of its own (one per slot, the GIL released) "
                      "and returns each slot as it finishes")
      .def(py::init<int>(), py::arg("slots"))
      .def("start", &Stepper::start, py::arg("slot"), py::arg("sim"), py::arg("action"),
           py::arg("steps"), py::kw_only(), py::arg("mode") = "velocity",
           "Starts `steps` steps of sim with action on slot's thread (arguments checked first); "
           "sim must not be used until wait() has returned the slot")
      .def("wait", &Stepper::wait,
           "The next slot whose step has finished (its exception raised here)")
      .def_property_readonly("running", &Stepper::running, "Slots started and not yet waited for")
      .def("__len__", &Stepper::size);

  m.def("step_many", &step_many, py::arg("sims"), py::arg("actions"), py::arg("steps"),
        py::kw_only(), py::arg("mode") = "velocity",
        "Steps simulators sims[i] steps[i] times with actions[i], in parallel threads with the "
        "GIL released (every argument checked first); a simulator's `threads` setting holds "
        "inside its own step");
}
