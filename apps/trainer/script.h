// Scripted input for the trainer (tests, the benchmark, screenshots for the docs): events at
// wall-clock times since the window's first frame, fed through the same functions as the
// window's keyboard, mouse and gamepad callbacks (docs/trainer.md "Scripted input").
//
//   {"events": [
//     {"t_s": 0.5, "key": "SPACE", "action": "press"},
//     {"t_s": 0.6, "key": "W", "action": "press", "mods": ["shift"]},
//     {"t_s": 2.0, "key": "W", "action": "release"},
//     {"t_s": 2.5, "mouse": "left", "action": "press", "x": 300, "y": 400},
//     {"t_s": 2.6, "cursor": [300, 380]},
//     {"t_s": 3.0, "gamepad": {"axes": [0, -0.5, 0, 0, -1, -1], "buttons": [1]}},
//     {"t_s": 3.5, "gamepad": null},
//     {"t_s": 4.0, "screenshot": "lao.png"},
//     {"t_s": 4.0, "resize": [1024, 700]},
//     {"t_s": 6.0, "close": true}]}
#pragma once

#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

#include "controls.h"

namespace vcsim::trainer {

struct ScriptEvent {
  enum class Type { kKey, kMouse, kCursor, kGamepad, kGamepadLost, kScreenshot, kResize, kClose };
  double t = 0.0;  // s of wall clock since the first frame
  Type type = Type::kKey;
  int key = 0;     // GLFW key code, or mouse button
  int action = 0;  // GLFW_PRESS / GLFW_RELEASE
  int mods = 0;
  double x = 0.0, y = 0.0;  // window coordinates (mouse, cursor); width, height (resize)
  GamepadState pad;
  std::string file;  // screenshot
};

// Parses a script; InputError naming `source` and the field ("events[3].key").
std::vector<ScriptEvent> parse_script(std::string_view json_text, const std::string& source);
std::vector<ScriptEvent> load_script(const std::filesystem::path& file);
// The GLFW key code of a name ("W", "SPACE", "F1", "LEFT_BRACKET"); -1 when unknown.
int key_code(std::string_view name);

// The benchmark's input (docs/trainer.md "Speed"): the pedal held throughout, the wire pushed
// and pulled in short strokes (each press and release an event whose latency is measured), a
// turn, the C-arm turned, an injection; closes at `seconds`.
std::vector<ScriptEvent> bench_script(double seconds, int instruments);

}  // namespace vcsim::trainer
