// vcsim commands: what the hands do in one step, resolved. Every input source (a scripted
// timeline, an OpenIGTLink device, the autopilot, the trainer, a Python agent) turns its own
// names and units into these once, at its boundary; the step reads instruments by index and SI
// values only (docs/architecture.md "The sim step").
#pragma once

#include <cstdint>
#include <vector>

namespace vcsim {

// What one hand does at the sheath this step.
struct DriveCommand {
  enum class Mode { kPosition, kVelocity };
  Mode mode = Mode::kVelocity;
  double translation = 0.0;  // position mode: inserted depth (m); velocity mode: m/s
  double rotation = 0.0;     // position mode: roll (rad); velocity mode: rad/s
};

// The commands for one step of a scene.
struct StepCommands {
  // (instrument) one per instrument of the scene, in the scene's order. A velocity command of
  // zero holds the instrument where it is.
  std::vector<DriveCommand> drive;
  double syringe_flow = 0.0;      // m^3/s of contrast into the guide (> 0 injection)
  double balloon_pressure = 0.0;  // Pa (gauge) of the inflation device
  std::uint32_t buttons = 0;      // bit mask (docs/devices.md)

  // Sized for `instruments`, every hand holding still and nothing injected.
  void reset(std::size_t instruments) {
    drive.assign(instruments, DriveCommand{});
    syringe_flow = 0.0;
    balloon_pressure = 0.0;
    buttons = 0;
  }
};

// What a hand feels at the hub, by instrument index (sign: a positive force pushes the instrument
// back out of the patient; a positive torque opposes positive rotation).
struct HandFeedback {
  double axial_force = 0.0;  // N
  double torque = 0.0;       // N m
};

}  // namespace vcsim
