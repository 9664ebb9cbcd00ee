// vcsim haptics: what the trainee does at the groin and what the simulator gives back, at the
// boundary of the engine. Two sources: a scripted timeline (deterministic replay) and an
// OpenIGTLink server for hardware and 3D Slicer. docs/devices.md is the user's guide.
//
// Files and messages use the operator's units (mm, deg, atm, ml/s) and instrument names; an input
// source turns them into StepCommands (vcsim/commands.h: instruments by index, SI) once, when it
// is polled, so that the step reads neither names nor units.
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "vcsim/commands.h"
#include "vcsim/core.h"

namespace vcsim {

// One instrument's command as a device or a file gives it, in the operator's units.
struct InstrumentCommand {
  enum class Mode { kPosition, kVelocity };
  std::string name;  // instrument name, e.g. "guidewire"
  Mode mode = Mode::kPosition;
  // Position mode: insertion depth (mm) and angle about the instrument axis (deg), absolute.
  // Velocity mode: insertion speed (mm/s) and spin (deg/s), held until the next command.
  double translation_mm = 0.0;
  double rotation_deg = 0.0;
};
const char* to_string(InstrumentCommand::Mode m);
// The same resolved: SI units, the mode carried over.
DriveCommand to_drive_command(const InstrumentCommand& c);

// Hub forces handed to a device at its own message rate, below the physics rate: each message
// carries the mean of the forces and torques published since the previous one (a boxcar
// decimation filter), not the last sample, so a one-step spike reaches a motor divided by the
// steps per message and the signal does not alias (docs/devices.md). Not thread-safe on its own.
class FeedbackDecimator {
 public:
  void resize(std::size_t instruments);
  // One physics step's force (N) and torque (N m) of instrument i.
  void add(std::size_t i, double force_n, double torque_nm);
  // The means since the last take of instrument i (the last means again when nothing was added
  // since), and a fresh start.
  void take(std::size_t i, double& force_n, double& torque_nm);

 private:
  std::vector<double> force_sum_, torque_sum_, force_, torque_;
  std::vector<std::uint64_t> n_;
};

// Plausibility limits: a command beyond them is a malformed message (network) or an input error
// (timeline file), never a motion.
struct CommandLimits {
  double max_translation_mm = 5000.0;  // longer than any instrument
  double max_rotation_deg = 36000.0;   // a hundred turns
  double max_speed_mm_s = 1000.0;
  double max_spin_deg_s = 36000.0;
  // What the drive at the sheath follows (Sheath::max_speed 0.5 m/s and max_spin 30 rad/s in
  // vcsim/solver.h): a timeline asking for more, in a velocity keyframe or between two position
  // keyframes, is refused at load rather than capped silently in the step.
  double drive_speed_mm_s = 500.0;
  double drive_spin_deg_s = 1718.8733853924696;  // 30 rad/s
  double max_balloon_atm = 30.0;   // above any rated burst pressure (clinical.md: 14-18)
  double max_syringe_ml_s = 30.0;  // magnitude; hand injection is about 2 ml/s

  // Returns an empty string when the command is within limits, otherwise what is wrong.
  std::string check(const InstrumentCommand& c) const;
};

// A change of the scene's instruments during a run (docs/scenarios.md, "Instrument exchange"):
// an instrument added, outside the patient at the sheath (a balloon catheter to be advanced over
// the wire in place, another wire, a catheter over a wire), or one removed (withdrawn first).
struct InstrumentChange {
  enum class Kind { kAdd, kRemove };
  Kind kind = Kind::kAdd;
  std::string name;  // the instrument added or removed
  // kAdd: the instrument as a scenario declares one (instruments[] there)
  std::string catalogue;  // catalogue entry
  std::string inside;     // the instrument whose lumen holds it, "" for none
  std::string over;       // the wire it rides on, "" for none
  bool rim = true;
  int max_nodes = 256;
  double tip_segment = 1.0e-3;  // m
  // Where it was asked for, for errors: the timeline file and "keyframes[3].add", ...
  std::string source = "exchange";
  std::string field = "instruments";
};
const char* to_string(InstrumentChange::Kind k);
// "add stent stent-cocr-3.0x18 inside=guide over=wire", "remove wire": the grammar of the
// OpenIGTLink exchange device and of recordings (rim, max_nodes and tip_segment left out).
std::string describe(const InstrumentChange& c);
// Reads that grammar ("add NAME CATALOGUE [inside=X] [over=Y]" or "remove NAME") into `out`
// (the other fields at their defaults): "" when it parses, else what was expected.
std::string parse_exchange_request(std::string_view text, InstrumentChange& out);

// A source of commands, polled by the physics thread once per step.
class InputSource {
 public:
  virtual ~InputSource() = default;
  // Fills `out` with the commands for simulation time `sim_time` (s): one drive command per
  // instrument of the scene, SI units. Reuses `out`'s storage, so that a warm poll does not
  // allocate.
  virtual void poll(double sim_time, StepCommands& out) = 0;
  // Hands the latest hub forces (one per instrument, by index) to the device (may be called every
  // step; does not block long).
  virtual void publish(std::span<const HandFeedback> feedback) { (void)feedback; }

  // Instrument exchange. Before each step the runner asks for changes of the scene (until this
  // returns false; none by default), applies each (Simulator::exchange), then reports back:
  // exchanged() with the scene's instrument names in their new order, or exchange_refused().
  virtual bool poll_exchange(double sim_time, InstrumentChange& out) {
    (void)sim_time;
    (void)out;
    return false;
  }
  // The scene's instruments changed (this source's change or another's): a source that resolved
  // names to indices binds them again here; drive commands follow the new order from the next
  // poll.
  virtual void exchanged(const InstrumentChange& change, std::span<const std::string> instruments) {
    (void)change;
    (void)instruments;
  }
  // The change asked for was refused and the scene is unchanged. By default the refusal is
  // thrown on: a script that asks for an impossible exchange is bad input. A live device logs
  // and answers it; the autopilot gives up.
  virtual void exchange_refused(const InstrumentChange& change, const InputError& why) {
    (void)change;
    throw why;
  }
};

// A timeline file replayed deterministically: the commands are a pure function of time.
//
//   {"keyframes": [
//     {"t_s": 0, "instruments": {"guidewire": {"translation_mm": 0, "rotation_deg": 0}}},
//     {"t_s": 2, "instruments": {"guidewire": {"translation_mm": 50, "rotation_deg": 90}},
//      "balloon_pressure_atm": 0, "syringe_flow_ml_s": 2, "buttons": 1},
//     {"t_s": 3, "instruments": {"catheter": {"mode": "velocity", "translation_mm": 10,
//                                             "rotation_deg": 0}}}]}
//
// Each instrument follows the keyframes that name it: between two position keyframes it moves
// linearly; a velocity keyframe holds its speeds until the instrument's next keyframe; before
// its first keyframe it rests at that keyframe's position (or zero speed). Balloon pressure
// moves linearly between the keyframes that give it; syringe flow and buttons hold from the
// keyframe that gives them. All three are 0 before their first keyframe.
//
// A keyframe may also change the scene's instruments (docs/scenarios.md, "Instrument exchange"):
//   {"t_s": 9, "remove": "wire"},
//   {"t_s": 9.5, "add": {"name": "balloon", "catalogue": "balloon-sc-3.0x15", "over": "wire2"}}
// ("add" takes the keys of a scenario's instruments[]); with both, the removal comes first. Each
// is asked for once (poll_exchange), before the first step at or after its time.
class ScriptedTimeline : public InputSource {
 public:
  static ScriptedTimeline parse(std::string_view json_text, const std::string& source,
                                const CommandLimits& limits = {});
  static ScriptedTimeline load(const std::filesystem::path& file, const CommandLimits& limits = {});

  // Resolves the timeline's instrument names to the scene's instruments, in the scene's order
  // (`instruments`); an instrument the timeline does not name is held still. A name that is not
  // one of them, nor one the timeline adds or removes itself, is an InputError naming the
  // timeline. poll() needs it first.
  void bind(std::span<const std::string> instruments);
  // The commands at sim_time, one per bound instrument, in SI units.
  void poll(double sim_time, StepCommands& out) override;
  void publish(std::span<const HandFeedback> feedback) override;
  // The next exchange whose keyframe time has come (each once, in order).
  bool poll_exchange(double sim_time, InstrumentChange& out) override;
  // Binds the scene's new instruments.
  void exchanged(const InstrumentChange& change, std::span<const std::string> instruments) override;

  struct TimedChange {
    double t = 0.0;  // s
    InstrumentChange change;
  };
  // The keyframes' exchanges, in order.
  const std::vector<TimedChange>& exchanges() const { return exchanges_; }
  double duration() const;  // time of the last keyframe (s)
  // True when a keyframe gives a balloon pressure above 0 (a scenario without a balloon refuses
  // it).
  bool inflates() const;
  const std::string& source() const { return source_; }
  const std::vector<std::string>& instrument_names() const { return names_; }  // sorted
  const std::vector<HandFeedback>& last_feedback() const { return feedback_; }

 private:
  struct Key {
    double t = 0.0;
    InstrumentCommand::Mode mode = InstrumentCommand::Mode::kPosition;
    double translation = 0.0, rotation = 0.0;
  };
  struct ScalarKey {
    double t = 0.0, value = 0.0;
  };
  std::vector<std::string> names_;
  std::vector<std::vector<Key>> tracks_;  // (instrument) keyframes naming it, by time
  std::vector<ScalarKey> balloon_, syringe_, buttons_;
  std::vector<TimedChange> exchanges_;
  std::size_t next_exchange_ = 0;  // the first exchange not yet asked for
  double duration_ = 0.0;
  std::string source_;
  std::vector<int> track_of_;  // (bound instrument) its track, -1: not in the timeline
  bool bound_ = false;
  std::vector<HandFeedback> feedback_;
};

// The commands a session's physics used, step by step, exactly (docs/trainer.md "The command
// recording"): what an interactive session (the trainer) leaves so that `vcsim run SCENARIO
// --replay FILE` steps the same scene through the same commands to the same state, bit for bit.
// Stored as runs of equal steps (a hand held still or moving at one speed is one run). The file
// is JSON with every double written in 17 significant digits, which reads back to the same bits.
class CommandRecording {
 public:
  struct Run {
    std::int64_t steps = 0;  // how many consecutive steps had these commands
    double syringe_flow = 0.0, balloon_pressure = 0.0;
    std::uint32_t buttons = 0;
  };

  // What the recording was made of (checked by the replay against the scene it steps).
  std::string scenario;                  // the scenario's name
  std::string scenario_file;             // as the recording session read it
  double dt = 0.0;                       // s, the physics step
  std::vector<std::string> instruments;  // the scene's instruments, in its order
  std::uint64_t model_hash = 0;          // SimModel::hash of the scene recorded
  std::uint64_t state_hash = 0;          // SimState::hash after the last step (0: not given)
  std::string made_by = "trainer";       // what recorded it

  // An instrument exchange made before step `step` (0-based): the scene's instruments change
  // there, and the steps from it on have one drive command per instrument of the scene then.
  struct Exchange {
    std::int64_t step = 0;
    InstrumentChange change;
  };

  // Appends one step's commands (one drive per instrument of the scene, asserted). Allocates
  // only when a new run starts and the storage is full.
  void append(const StepCommands& c);
  // Records an exchange made before the next step appended (a run never spans one).
  void append_exchange(const InstrumentChange& c);
  // Keeps the first `steps` steps and the exchanges before them (a rewind to a snapshot taken
  // after that many steps).
  void truncate(std::int64_t steps);
  void clear() { truncate(0); }
  std::int64_t steps() const { return total_; }
  std::size_t num_runs() const { return runs_.size(); }
  const Run& run(std::size_t r) const { return runs_[r]; }
  std::span<const DriveCommand> run_drive(std::size_t r) const;
  const std::vector<Exchange>& exchanges() const { return exchanges_; }
  // Instruments in the scene after the exchanges recorded so far.
  std::size_t scene_size() const;
  // The commands of step `step` (0-based, < steps()), into `out` (no allocation once sized).
  void at(std::int64_t step, StepCommands& out) const;

  void save(const std::filesystem::path& file) const;  // InputError when it cannot be written
  std::string to_json() const;
  // InputError naming `source` and the field for anything malformed.
  static CommandRecording parse(std::string_view json_text, const std::string& source);
  static CommandRecording load(const std::filesystem::path& file);

 private:
  std::vector<Run> runs_;
  std::vector<DriveCommand> drive_;  // (run x its instruments)
  std::vector<std::size_t> start_;   // (run) its first drive command in drive_
  std::vector<std::size_t> width_;   // (run) instruments in the scene during it
  std::vector<std::int64_t> end_;    // (run) steps up to and including the run
  std::vector<Exchange> exchanges_;  // by step
  std::int64_t total_ = 0;
};

// A recording replayed as an input source: the commands of the step at sim_time (its index is
// round(sim_time / dt)), bit for bit as recorded, and its exchanges before the steps they were
// made before; after the last step every hand holds still.
class RecordingReplay : public InputSource {
 public:
  // Checks the recording against the scene (its instrument names in order, `dt`, and, when both
  // are given, the model hash): InputError naming `source` and the field that differs.
  RecordingReplay(CommandRecording recording, std::span<const std::string> instruments, double dt,
                  std::uint64_t model_hash, const std::string& source);
  void poll(double sim_time, StepCommands& out) override;
  bool poll_exchange(double sim_time, InstrumentChange& out) override;
  void exchanged(const InstrumentChange& change, std::span<const std::string> instruments) override;
  const CommandRecording& recording() const { return rec_; }
  double duration() const { return static_cast<double>(rec_.steps()) * rec_.dt; }  // s

 private:
  CommandRecording rec_;
  std::size_t next_exchange_ = 0;
  std::size_t scene_size_ = 0;  // instruments in the scene now
};

struct IgtlServerOptions {
  std::string address = "127.0.0.1";  // IPv4 address to listen on; loopback by default
  int port = 18944;                   // the OpenIGTLink default; 0 picks a free port
  // The device names accepted, in the scene's order: poll() gives commands by this index.
  std::vector<std::string> instruments = {"guidewire", "catheter"};
  double feedback_rate_hz = 200.0;  // force messages per second while a client is connected
  CommandLimits limits;
  // What the drive follows (Sheath::max_speed, max_spin; 0: unknown): a device moving an
  // instrument faster is followed at these speeds, and told so in one log line per instrument
  // (velocity commands as sent; positions by their change over 20 ms or more).
  double drive_max_speed_mm_s = 0.0;
  double drive_max_spin_deg_s = 0.0;
  // Where log lines go (one line each, no newline); default: stderr with a "vcsim igtl:" prefix.
  // Called from the server thread.
  std::function<void(const std::string&)> log;
};

struct IgtlStats {
  std::uint64_t connections = 0;        // clients accepted
  std::uint64_t disconnections = 0;     // clients lost or dropped
  std::uint64_t messages_accepted = 0;  // messages that changed a command
  std::uint64_t messages_dropped = 0;   // malformed, out of range, unknown name or type
  std::uint64_t feedback_sent = 0;      // force messages sent
  std::uint64_t exchanges = 0;          // instrument exchanges asked for and done
  std::uint64_t exchanges_refused = 0;  // asked for and refused by the simulation
  std::uint64_t clients_refused = 0;    // connections refused while a client was connected
  std::uint64_t messages_skipped = 0;   // well-formed but over 64 KiB: read past, not parsed
  // Instruments a device moved faster than the drive follows (each reported once).
  std::uint64_t beyond_drive = 0;
  bool connected = false;
};

// An OpenIGTLink server on a background thread: one client at a time (another connection is
// refused with a log line while one is connected; a client that vanishes without closing is
// dropped once 3 s of sent data go unacknowledged, so a device that restarts can reconnect),
// TRANSFORM and SENSOR messages in, SENSOR "force_<name>" out at feedback_rate_hz. A client that
// disconnects leaves position commands where they are and stops velocity commands and syringe
// flow. Bad messages are dropped and logged, a well-formed one over 64 KiB (an IMAGE) is read
// past and logged; a header that cannot be framed drops the connection. Listening beyond
// loopback is logged as a warning. Thread-safe: poll() and publish() come from the physics
// thread.
class IgtlServer : public InputSource {
 public:
  // Listens at once; throws InputError naming the option when the address, port or names are
  // unusable.
  explicit IgtlServer(IgtlServerOptions options = {});
  ~IgtlServer() override;
  IgtlServer(const IgtlServer&) = delete;
  IgtlServer& operator=(const IgtlServer&) = delete;

  int port() const;  // the port actually bound (useful with port 0)
  // Commands by index of IgtlServerOptions::instruments (after an exchange, of the scene's
  // instruments then), SI units.
  void poll(double sim_time, StepCommands& out) override;
  void publish(std::span<const HandFeedback> feedback) override;
  // Exchanges a client asked for on the "exchange" device, in order; each applied one answered
  // "done: ..." and the device names rebound, each refused one logged and answered
  // "refused: ..." (docs/devices.md).
  bool poll_exchange(double sim_time, InstrumentChange& out) override;
  void exchanged(const InstrumentChange& change, std::span<const std::string> instruments) override;
  void exchange_refused(const InstrumentChange& change, const InputError& why) override;
  IgtlStats stats() const;
  // Bit i set once a command for instrument i (by index of IgtlServerOptions::instruments) has
  // been accepted: which instruments the device drives, for an app that also has a keyboard.
  std::uint64_t commanded_mask() const;
  void stop();  // closes the connection and joins the thread; idempotent

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace vcsim
