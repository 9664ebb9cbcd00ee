// The person's controls (docs/trainer.md "Controls"): keyboard, mouse and gamepad events turned
// into what the hands do (OperatorCommands, in SI, for the physics thread), the C-arm (angles,
// field size, table pan) and the session's actions (pause, rewind, cine, views). The window's
// GLFW callbacks and a scripted event feed call the same functions (key(), mouse_button(),
// cursor(), gamepad()), so a test drives the trainer through the path a keyboard takes. No GL.
#pragma once

#include <array>
#include <cstdint>
#include <deque>
#include <map>
#include <string>
#include <vector>

#include "physics.h"
#include "vcsim/core.h"

namespace vcsim::trainer {

enum class Action {
  kTogglePause,
  kRewind,
  kRestart,
  kToggleReview,  // replay the last cine run in the window
  kSaveCine,      // write the cine runs as PNGs
  kToggle3D,      // the educator's 3D view
  kToggleHelp,
  kQuit,
};

// The standard coronary views (shared/reference/clinical.md), F1 .. F7.
struct ViewPreset {
  const char* name;
  double primary_deg, secondary_deg;
};
inline constexpr std::array<ViewPreset, 7> kViewPresets = {{
    {"AP", 0.0, 0.0},
    {"LAO 45 CAU 30 (spider: left main)", 45.0, -30.0},
    {"RAO 30 CAU 30 (LCx)", -30.0, -30.0},
    {"RAO 10 CRA 40 (LAD)", -10.0, 40.0},
    {"LAO 40 CRA 30 (mid LAD, distal RCA)", 40.0, 30.0},
    {"LAO 50 (RCA)", 50.0, 0.0},
    {"RAO 30 (RCA)", -30.0, 0.0},
}};
// Field sizes of the detector (zoom), mm.
inline constexpr std::array<double, 5> kFieldSizesMm = {250.0, 200.0, 170.0, 140.0, 110.0};

// A gamepad's state as GLFW's gamepad API gives it (GLFWgamepadstate: Xbox layout).
struct GamepadState {
  std::array<float, 6> axes{};  // left x, left y, right x, right y, left trigger, right trigger
  std::array<unsigned char, 15> buttons{};
};

// Speeds (SI) and how they grow while a key is held.
struct ControlSettings {
  double push_min = 5e-3, push_max = 50e-3;  // m/s: first, and after `ramp` s held
  double spin_min = 0.785, spin_max = 6.28;  // rad/s (45 and 360 deg/s)
  double ramp = 2.0;                         // s from the first speed to the last
  double fine = 0.2;                         // Shift: speeds times this
  double carm_rate = 20.0;                   // deg/s of the C-arm while a key is held
  double pan_rate = 50e-3;                   // m/s of the table while a key is held
  double mouse_push = 0.25e-3;               // m/s per pixel of drag (up: push)
  double mouse_spin = 0.0262;                // rad/s per pixel of drag (1.5 deg/s)
  double deadzone = 0.15;                    // of a gamepad stick
  double inject_flow = 3e-6;                 // m^3/s while the inject control is held
  double balloon_step = 101325.0;            // Pa per indeflator key press (1 atm)
  double balloon_max = 20.0 * 101325.0;      // Pa
};

class Controls {
 public:
  Controls(std::vector<std::string> instruments, const Scenario& scenario,
           ControlSettings settings = {});

  // Events, as GLFW names them (key codes, GLFW_PRESS / GLFW_RELEASE / GLFW_REPEAT, modifier
  // bits); `now_us` is the wall clock (now_us()) when the event arrived.
  void key(int key, int action, int mods, double now_us);
  void mouse_button(int button, int action, int mods, double x, double y, double now_us);
  void cursor(double x, double y, double now_us);
  void scroll(double dx, double dy, bool over_fluoro, double now_us);
  void gamepad(const GamepadState& s, double now_us);
  void gamepad_lost(double now_us);
  // The window lost the keyboard: every key and the mouse let go (a release the window will
  // never see must not leave a wire moving or the beam on).
  void release_all(double now_us);
  // The fluoroscopy panel in window coordinates: a mouse drag starts only on it.
  void set_fluoro_area(double x0, double y0, double x1, double y1);
  // Menu items and sliders (the same effects as their keys).
  void select(int instrument, double now_us);
  // The scene's instruments changed (an exchange, a restart): every hand lets go; the selection
  // goes to an instrument that was not there before, else stays on its name, else the first.
  void set_instruments(std::vector<std::string> instruments, double now_us);
  void set_preset(int i);
  void set_field(int i);
  void set_inject_flow(double m3_s) { s_.inject_flow = m3_s; }
  void set_balloon(double pa, double now_us);
  void set_deploy(bool on, double now_us);
  // The pressure Enter inflates to: the nominal pressure of the scene's stent system (else of its
  // balloon); 0 for none.
  void set_deploy_pressure(double pa) { deploy_pressure_ = pa; }

  // Once per frame: speeds grow with the time held, the C-arm and the table move. Returns true
  // when the commands changed since the last call, by an event or here (then hand them to the
  // physics thread).
  bool update(double now_us);
  const OperatorCommands& commands() const { return cmd_; }
  std::vector<Action> take_actions();

  int selected() const { return selected_; }
  int num_instruments() const { return static_cast<int>(names_.size()); }
  const std::string& name(int i) const { return names_[static_cast<std::size_t>(i)]; }
  bool fluoro_pedal() const { return fluoro_key_ || fluoro_pad_; }
  bool cine_pedal() const { return cine_key_ || cine_pad_; }
  bool injecting() const { return inject_key_ || inject_pad_; }
  double inject_flow() const { return s_.inject_flow; }
  double balloon_pressure() const { return cmd_.balloon_pressure; }  // Pa
  double primary_deg() const { return primary_; }
  double secondary_deg() const { return secondary_; }
  int field() const { return field_; }
  double fov() const { return kFieldSizesMm[static_cast<std::size_t>(field_)] * 1e-3; }  // m
  const Vec3& table_pan() const { return pan_; }  // m, patient LPS, added to the isocentre
  bool gamepad_present() const { return pad_present_; }
  // Input events that changed the commands and when (for the latency measurement).
  struct Change {
    std::uint64_t seq;
    double event_us;
  };
  std::deque<Change>& changes() { return changes_; }

 private:
  bool held(int key) const { return keys_.count(key) > 0; }
  double held_for(int key, double now_us) const;
  void recompute(double now_us, bool from_event);
  void event_changed(double now_us);

  std::vector<std::string> names_;
  ControlSettings s_;
  OperatorCommands cmd_;
  int selected_ = 0;
  double deploy_pressure_ = 0.0;  // Pa
  std::map<int, double> keys_;    // key -> when pressed (now_us)
  int mods_ = 0;
  bool fluoro_key_ = false, cine_key_ = false, inject_key_ = false, deploy_ = false;
  bool fluoro_pad_ = false, cine_pad_ = false, inject_pad_ = false;
  // Mouse drag on the fluoroscopy panel: the offset from where it started sets the speeds.
  bool dragging_ = false;
  double drag_x0_ = 0, drag_y0_ = 0, drag_x_ = 0, drag_y_ = 0;
  double area_[4] = {0, 0, 0, 0};
  GamepadState pad_{};
  bool pad_present_ = false;
  double primary_ = 0.0, secondary_ = 0.0;
  int field_ = 1;
  Vec3 pan_ = Vec3::Zero();
  double last_update_us_ = 0.0;
  bool changed_ = false;
  std::vector<Action> actions_;
  std::deque<Change> changes_;
};

}  // namespace vcsim::trainer
