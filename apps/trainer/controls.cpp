// The person's controls (controls.h): events in, commands and actions out.
#include "controls.h"

#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>

#include <algorithm>
#include <cmath>

#include "vcsim/render.h"

namespace vcsim::trainer {

namespace {

double stick(float v, double deadzone) {
  const double a = std::abs(static_cast<double>(v));
  if (a < deadzone) return 0.0;
  return std::copysign((a - deadzone) / (1.0 - deadzone), static_cast<double>(v));
}

bool same(const OperatorCommands& a, const OperatorCommands& b) {
  if (a.syringe_flow != b.syringe_flow || a.balloon_pressure != b.balloon_pressure ||
      a.buttons != b.buttons || a.drive.size() != b.drive.size())
    return false;
  for (std::size_t i = 0; i < a.drive.size(); ++i)
    if (a.drive[i].mode != b.drive[i].mode || a.drive[i].translation != b.drive[i].translation ||
        a.drive[i].rotation != b.drive[i].rotation)
      return false;
  return true;
}

}  // namespace

Controls::Controls(std::vector<std::string> instruments, const Scenario& sc,
                   ControlSettings settings)
    : names_(std::move(instruments)), s_(settings) {
  cmd_.drive.assign(names_.size(), DriveCommand{});
  primary_ = sc.fluoro.primary_deg;
  secondary_ = sc.fluoro.secondary_deg;
  // The field size nearest the scenario's.
  for (std::size_t i = 0; i < kFieldSizesMm.size(); ++i)
    if (std::abs(kFieldSizesMm[i] - sc.fluoro.fov_mm) <
        std::abs(kFieldSizesMm[static_cast<std::size_t>(field_)] - sc.fluoro.fov_mm))
      field_ = static_cast<int>(i);
  // The first instrument that lies inside another leads (a wire in its guide); else the first.
  selected_ = 0;
  for (std::size_t i = 0; i < sc.instruments.size(); ++i)
    if (!sc.instruments[i].inside.empty()) {
      selected_ = static_cast<int>(i);
      break;
    }
}

double Controls::held_for(int k, double now_us) const {
  const auto it = keys_.find(k);
  return it == keys_.end() ? 0.0 : std::max(0.0, (now_us - it->second) * 1e-6);
}

void Controls::event_changed(double now_us) {
  recompute(now_us, true);
}

void Controls::recompute(double now_us, bool from_event) {
  OperatorCommands next = cmd_;
  for (DriveCommand& d : next.drive) d = DriveCommand{};
  const double fine = (mods_ & GLFW_MOD_SHIFT) ? s_.fine : 1.0;
  auto ramp = [&](int k1, int k2, double lo, double hi) {
    const double t = std::max(held_for(k1, now_us), held_for(k2, now_us));
    return (held(k1) || held(k2)) ? fine * (lo + (hi - lo) * std::min(1.0, t / s_.ramp)) : 0.0;
  };
  // Ctrl + arrows pan the table instead of driving.
  const bool ctrl = (mods_ & GLFW_MOD_CONTROL) != 0;
  double v = 0.0, w = 0.0;
  if (!ctrl) {
    v += ramp(GLFW_KEY_W, GLFW_KEY_UP, s_.push_min, s_.push_max);
    v -= ramp(GLFW_KEY_S, GLFW_KEY_DOWN, s_.push_min, s_.push_max);
    w += ramp(GLFW_KEY_D, GLFW_KEY_RIGHT, s_.spin_min, s_.spin_max);
    w -= ramp(GLFW_KEY_A, GLFW_KEY_LEFT, s_.spin_min, s_.spin_max);
  }
  if (dragging_) {
    v += std::clamp(-(drag_y_ - drag_y0_) * s_.mouse_push, -s_.push_max, s_.push_max);
    w += std::clamp((drag_x_ - drag_x0_) * s_.mouse_spin, -s_.spin_max, s_.spin_max);
  }
  if (pad_present_) {
    v += -stick(pad_.axes[GLFW_GAMEPAD_AXIS_LEFT_Y], s_.deadzone) * s_.push_max;
    w += stick(pad_.axes[GLFW_GAMEPAD_AXIS_LEFT_X], s_.deadzone) * s_.spin_max;
  }
  if (selected_ >= 0 && selected_ < static_cast<int>(next.drive.size())) {
    DriveCommand& d = next.drive[static_cast<std::size_t>(selected_)];
    d.mode = DriveCommand::Mode::kVelocity;
    d.translation = std::clamp(v, -s_.push_max, s_.push_max);
    d.rotation = std::clamp(w, -s_.spin_max, s_.spin_max);
  }
  next.syringe_flow = injecting() ? s_.inject_flow : 0.0;
  next.buttons = (fluoro_pedal() ? kButtonFluoro : 0u) | (cine_pedal() ? kButtonCine : 0u) |
                 (deploy_ ? kButtonDeploy : 0u);
  if (same(next, cmd_)) return;
  if (from_event) {
    next.seq = cmd_.seq + 1;
    next.event_us = now_us;
    changes_.push_back({next.seq, now_us});
    if (changes_.size() > 256) changes_.pop_front();
  }
  cmd_ = next;
  changed_ = true;
}

void Controls::key(int k, int action, int mods, double now_us) {
  mods_ = mods;
  if (action == GLFW_REPEAT) return;  // a held key is held: its speed grows in update()
  const bool press = action == GLFW_PRESS;
  if (press) {
    keys_.emplace(k, now_us);
  } else {
    keys_.erase(k);
  }
  const bool ctrl = (mods & GLFW_MOD_CONTROL) != 0;
  switch (k) {
    case GLFW_KEY_SPACE:
      fluoro_key_ = press;
      break;
    case GLFW_KEY_C:
      cine_key_ = press;
      break;
    case GLFW_KEY_E:
      inject_key_ = press;
      break;
    case GLFW_KEY_ENTER:
    case GLFW_KEY_KP_ENTER:
      deploy_ = press;
      break;
    default:
      break;
  }
  if (press) {
    if (k == GLFW_KEY_TAB) {
      select((selected_ + ((mods & GLFW_MOD_SHIFT) ? num_instruments() - 1 : 1)) %
                 std::max(1, num_instruments()),
             now_us);
    } else if (k >= GLFW_KEY_1 && k <= GLFW_KEY_9 && k - GLFW_KEY_1 < num_instruments()) {
      select(k - GLFW_KEY_1, now_us);
    } else if (k >= GLFW_KEY_F1 && k < GLFW_KEY_F1 + static_cast<int>(kViewPresets.size())) {
      set_preset(k - GLFW_KEY_F1);
    } else if (k == GLFW_KEY_EQUAL || k == GLFW_KEY_KP_ADD ||
               (k == GLFW_KEY_Z && !(mods & GLFW_MOD_SHIFT))) {
      set_field(field_ + 1);  // smaller field: magnified
    } else if (k == GLFW_KEY_MINUS || k == GLFW_KEY_KP_SUBTRACT || k == GLFW_KEY_Z) {
      set_field(field_ - 1);
    } else if (k == GLFW_KEY_RIGHT_BRACKET) {
      set_balloon(cmd_.balloon_pressure + s_.balloon_step, now_us);
    } else if (k == GLFW_KEY_LEFT_BRACKET) {
      set_balloon(cmd_.balloon_pressure - s_.balloon_step, now_us);
    } else if (k == GLFW_KEY_BACKSLASH) {
      set_balloon(0.0, now_us);
    } else if ((k == GLFW_KEY_ENTER || k == GLFW_KEY_KP_ENTER) && deploy_pressure_ > 0.0) {
      set_balloon(deploy_pressure_, now_us);  // the stent system's nominal pressure
    } else if (k == GLFW_KEY_P) {
      actions_.push_back(Action::kTogglePause);
    } else if (k == GLFW_KEY_B || k == GLFW_KEY_BACKSPACE) {
      actions_.push_back(Action::kRewind);
    } else if (k == GLFW_KEY_R && ctrl) {
      actions_.push_back(Action::kRestart);
    } else if (k == GLFW_KEY_V) {
      actions_.push_back(Action::kToggleReview);
    } else if (k == GLFW_KEY_S && ctrl) {
      actions_.push_back(Action::kSaveCine);
    } else if (k == GLFW_KEY_G || k == GLFW_KEY_F9) {
      actions_.push_back(Action::kToggle3D);
    } else if (k == GLFW_KEY_H || k == GLFW_KEY_F10) {
      actions_.push_back(Action::kToggleHelp);
    } else if (k == GLFW_KEY_ESCAPE) {
      actions_.push_back(Action::kQuit);
    }
  }
  event_changed(now_us);
}

void Controls::mouse_button(int button, int action, int mods, double x, double y, double now_us) {
  mods_ = mods;
  if (button != GLFW_MOUSE_BUTTON_LEFT) return;
  if (action == GLFW_PRESS) {
    if (x < area_[0] || x > area_[2] || y < area_[1] || y > area_[3]) return;
    dragging_ = true;
    drag_x0_ = drag_x_ = x;
    drag_y0_ = drag_y_ = y;
  } else if (action == GLFW_RELEASE) {
    dragging_ = false;
  }
  event_changed(now_us);
}

void Controls::cursor(double x, double y, double now_us) {
  if (!dragging_) return;
  drag_x_ = x;
  drag_y_ = y;
  event_changed(now_us);
}

void Controls::scroll(double, double dy, bool over_fluoro, double now_us) {
  if (!over_fluoro || dy == 0.0) return;
  set_field(field_ + (dy > 0 ? 1 : -1));
  event_changed(now_us);
}

void Controls::gamepad(const GamepadState& s, double now_us) {
  const GamepadState old = pad_;
  const bool was = pad_present_;
  pad_ = s;
  pad_present_ = true;
  auto pressed = [&](int b) { return s.buttons[b] && (!was || !old.buttons[b]); };
  fluoro_pad_ = s.buttons[GLFW_GAMEPAD_BUTTON_A] != 0;
  inject_pad_ = s.buttons[GLFW_GAMEPAD_BUTTON_B] != 0;
  cine_pad_ = s.buttons[GLFW_GAMEPAD_BUTTON_X] != 0;
  if (pressed(GLFW_GAMEPAD_BUTTON_Y)) actions_.push_back(Action::kToggleReview);
  if (pressed(GLFW_GAMEPAD_BUTTON_BACK)) actions_.push_back(Action::kTogglePause);
  if (pressed(GLFW_GAMEPAD_BUTTON_START)) actions_.push_back(Action::kRewind);
  const int n = std::max(1, num_instruments());
  if (pressed(GLFW_GAMEPAD_BUTTON_LEFT_BUMPER)) select((selected_ + n - 1) % n, now_us);
  if (pressed(GLFW_GAMEPAD_BUTTON_RIGHT_BUMPER)) select((selected_ + 1) % n, now_us);
  auto trigger = [&](int axis) { return s.axes[axis] > 0.5f && (!was || old.axes[axis] <= 0.5f); };
  if (trigger(GLFW_GAMEPAD_AXIS_RIGHT_TRIGGER)) set_field(field_ + 1);
  if (trigger(GLFW_GAMEPAD_AXIS_LEFT_TRIGGER)) set_field(field_ - 1);
  // Only a change of what the hands do counts as an event; a stick held still does not.
  recompute(now_us, true);
}

void Controls::gamepad_lost(double now_us) {
  if (!pad_present_) return;
  pad_present_ = false;
  pad_ = GamepadState{};
  fluoro_pad_ = cine_pad_ = inject_pad_ = false;
  event_changed(now_us);
}

void Controls::release_all(double now_us) {
  keys_.clear();
  mods_ = 0;
  fluoro_key_ = cine_key_ = inject_key_ = deploy_ = false;
  dragging_ = false;
  event_changed(now_us);
}

void Controls::set_fluoro_area(double x0, double y0, double x1, double y1) {
  area_[0] = x0;
  area_[1] = y0;
  area_[2] = x1;
  area_[3] = y1;
}

void Controls::select(int instrument, double now_us) {
  if (instrument < 0 || instrument >= num_instruments()) return;
  selected_ = instrument;
  event_changed(now_us);  // the one that was moving stops
}

void Controls::set_instruments(std::vector<std::string> instruments, double now_us) {
  if (instruments == names_) return;
  const std::string was =
      names_.empty() ? std::string() : names_[static_cast<std::size_t>(selected_)];
  int pick = -1, same = -1;
  for (std::size_t i = 0; i < instruments.size(); ++i) {
    if (std::find(names_.begin(), names_.end(), instruments[i]) == names_.end() && pick < 0)
      pick = static_cast<int>(i);
    if (instruments[i] == was) same = static_cast<int>(i);
  }
  names_ = std::move(instruments);
  selected_ = pick >= 0 ? pick : (same >= 0 ? same : 0);
  cmd_.drive.assign(names_.size(), DriveCommand{});
  event_changed(now_us);
}

void Controls::set_preset(int i) {
  if (i < 0 || i >= static_cast<int>(kViewPresets.size())) return;
  primary_ = kViewPresets[static_cast<std::size_t>(i)].primary_deg;
  secondary_ = kViewPresets[static_cast<std::size_t>(i)].secondary_deg;
}

void Controls::set_field(int i) {
  field_ = std::clamp(i, 0, static_cast<int>(kFieldSizesMm.size()) - 1);
}

void Controls::set_balloon(double pa, double now_us) {
  cmd_.balloon_pressure = std::clamp(pa, 0.0, s_.balloon_max);
  cmd_.seq += 1;
  cmd_.event_us = now_us;
  changes_.push_back({cmd_.seq, now_us});
  changed_ = true;
}

void Controls::set_deploy(bool on, double now_us) {
  deploy_ = on;
  event_changed(now_us);
}

bool Controls::update(double now_us) {
  const double dt = last_update_us_ > 0.0 ? std::min(0.1, (now_us - last_update_us_) * 1e-6) : 0.0;
  last_update_us_ = now_us;
  // The C-arm and the table move while their keys (or the right stick and d-pad) are held.
  const bool ctrl = (mods_ & GLFW_MOD_CONTROL) != 0;
  double dp = 0.0, ds = 0.0, px = 0.0, pz = 0.0;
  if (held(GLFW_KEY_L)) dp += 1.0;
  if (held(GLFW_KEY_J)) dp -= 1.0;
  if (held(GLFW_KEY_I)) ds += 1.0;
  if (held(GLFW_KEY_K)) ds -= 1.0;
  if (ctrl) {
    if (held(GLFW_KEY_LEFT)) px -= 1.0;
    if (held(GLFW_KEY_RIGHT)) px += 1.0;
    if (held(GLFW_KEY_UP)) pz += 1.0;
    if (held(GLFW_KEY_DOWN)) pz -= 1.0;
  }
  if (pad_present_) {
    dp += stick(pad_.axes[GLFW_GAMEPAD_AXIS_RIGHT_X], s_.deadzone) * 1.5;
    ds += -stick(pad_.axes[GLFW_GAMEPAD_AXIS_RIGHT_Y], s_.deadzone) * 1.5;
    if (pad_.buttons[GLFW_GAMEPAD_BUTTON_DPAD_LEFT]) px -= 1.0;
    if (pad_.buttons[GLFW_GAMEPAD_BUTTON_DPAD_RIGHT]) px += 1.0;
    if (pad_.buttons[GLFW_GAMEPAD_BUTTON_DPAD_UP]) pz += 1.0;
    if (pad_.buttons[GLFW_GAMEPAD_BUTTON_DPAD_DOWN]) pz -= 1.0;
  }
  primary_ = std::clamp(primary_ + dp * s_.carm_rate * dt, -kPrimaryLimitDeg, kPrimaryLimitDeg);
  secondary_ =
      std::clamp(secondary_ + ds * s_.carm_rate * dt, -kSecondaryLimitDeg, kSecondaryLimitDeg);
  // The image's left and right are the patient's right and left in an AP view; the table moves
  // the patient, so the operator's "left" moves the image content accordingly.
  pan_.x() = std::clamp(pan_.x() + px * s_.pan_rate * dt, -0.15, 0.15);
  pan_.z() = std::clamp(pan_.z() + pz * s_.pan_rate * dt, -0.4, 0.4);
  recompute(now_us, false);
  const bool changed = changed_;
  changed_ = false;
  return changed;
}

std::vector<Action> Controls::take_actions() {
  std::vector<Action> a;
  a.swap(actions_);
  return a;
}

}  // namespace vcsim::trainer
