// Scripted input for the trainer (script.h).
#include "script.h"

#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>

#include <algorithm>
#include <fstream>
#include <sstream>
#include <utility>

#include "json_fields.h"

namespace vcsim::trainer {

using internal::cat;
using internal::Json;
using internal::JsonFields;

int key_code(std::string_view name) {
  if (name.size() == 1) {
    const char c = name[0];
    if (c >= 'A' && c <= 'Z') return GLFW_KEY_A + (c - 'A');
    if (c >= 'a' && c <= 'z') return GLFW_KEY_A + (c - 'a');
    if (c >= '0' && c <= '9') return GLFW_KEY_0 + (c - '0');
  }
  if (name.size() >= 2 && name.size() <= 3 && name[0] == 'F') {
    int n = 0;
    for (char c : name.substr(1)) {
      if (c < '0' || c > '9') return -1;
      n = 10 * n + (c - '0');
    }
    if (n >= 1 && n <= 25) return GLFW_KEY_F1 + n - 1;
    return -1;
  }
  static const std::pair<const char*, int> kNamed[] = {
      {"SPACE", GLFW_KEY_SPACE},
      {"TAB", GLFW_KEY_TAB},
      {"ENTER", GLFW_KEY_ENTER},
      {"ESCAPE", GLFW_KEY_ESCAPE},
      {"BACKSPACE", GLFW_KEY_BACKSPACE},
      {"UP", GLFW_KEY_UP},
      {"DOWN", GLFW_KEY_DOWN},
      {"LEFT", GLFW_KEY_LEFT},
      {"RIGHT", GLFW_KEY_RIGHT},
      {"LEFT_BRACKET", GLFW_KEY_LEFT_BRACKET},
      {"RIGHT_BRACKET", GLFW_KEY_RIGHT_BRACKET},
      {"BACKSLASH", GLFW_KEY_BACKSLASH},
      {"MINUS", GLFW_KEY_MINUS},
      {"EQUAL", GLFW_KEY_EQUAL},
      {"LEFT_SHIFT", GLFW_KEY_LEFT_SHIFT},
      {"LEFT_CONTROL", GLFW_KEY_LEFT_CONTROL},
  };
  for (const auto& [n, k] : kNamed)
    if (name == n) return k;
  return -1;
}

std::vector<ScriptEvent> parse_script(std::string_view json_text, const std::string& source) {
  const Json doc = internal::parse_json_text(json_text, source);
  JsonFields root(doc, source, "");
  root.keys({"comment", "events"});
  root.get("comment");
  const Json& events = root.array("events");
  root.finish();
  std::vector<ScriptEvent> out;
  double prev = 0.0;
  for (std::size_t i = 0; i < events.size(); ++i) {
    JsonFields f(events[i], source, internal::index_path("events", i));
    f.keys({"t_s", "key", "action", "mods", "mouse", "x", "y", "cursor", "gamepad", "screenshot",
            "resize", "close", "comment"});
    f.get("comment");
    ScriptEvent e;
    e.t = f.nonnegative("t_s");
    if (e.t < prev) f.fail("t_s", cat("expected a time at or after the previous event's"));
    prev = e.t;
    auto action = [&] {
      const std::string a = f.string("action");
      if (a == "press") return GLFW_PRESS;
      if (a == "release") return GLFW_RELEASE;
      f.fail("action", cat("expected \"press\" or \"release\", got '", a, "'"));
    };
    auto mods = [&] {
      int m = 0;
      if (const Json* ms = f.get("mods")) {
        if (!ms->is_array()) f.fail("mods", "expected an array of \"shift\", \"ctrl\", \"alt\"");
        for (std::size_t k = 0; k < ms->size(); ++k) {
          const std::string s = f.as_string((*ms)[k], internal::index_path(f.field("mods"), k));
          if (s == "shift") {
            m |= GLFW_MOD_SHIFT;
          } else if (s == "ctrl") {
            m |= GLFW_MOD_CONTROL;
          } else if (s == "alt") {
            m |= GLFW_MOD_ALT;
          } else {
            throw InputError(source, internal::index_path(f.field("mods"), k),
                             cat("expected \"shift\", \"ctrl\" or \"alt\", got '", s, "'"));
          }
        }
      }
      return m;
    };
    if (f.has("key")) {
      e.type = ScriptEvent::Type::kKey;
      const std::string name = f.text("key");
      e.key = key_code(name);
      if (e.key < 0)
        f.fail("key", cat("expected a key name (W, SPACE, F1, LEFT, ...), got '", name, "'"));
      e.action = action();
      e.mods = mods();
    } else if (f.has("mouse")) {
      e.type = ScriptEvent::Type::kMouse;
      const std::string b = f.text("mouse");
      if (b == "left") {
        e.key = GLFW_MOUSE_BUTTON_LEFT;
      } else if (b == "right") {
        e.key = GLFW_MOUSE_BUTTON_RIGHT;
      } else {
        f.fail("mouse", cat("expected \"left\" or \"right\", got '", b, "'"));
      }
      e.action = action();
      e.mods = mods();
      e.x = f.number("x");
      e.y = f.number("y");
    } else if (f.has("cursor")) {
      e.type = ScriptEvent::Type::kCursor;
      const Json& c = f.array("cursor");
      if (c.size() != 2) f.fail("cursor", "expected [x, y]");
      e.x = f.as_number(c[0], f.field("cursor"));
      e.y = f.as_number(c[1], f.field("cursor"));
    } else if (f.has("gamepad")) {
      const Json& g = f.require("gamepad");
      if (g.is_null()) {
        e.type = ScriptEvent::Type::kGamepadLost;
      } else {
        e.type = ScriptEvent::Type::kGamepad;
        JsonFields gf(g, source, f.field("gamepad"));
        gf.keys({"axes", "buttons"});
        if (const Json* axes = gf.get("axes")) {
          if (!axes->is_array() || axes->size() > 6)
            gf.fail("axes", "expected up to 6 numbers in [-1, 1]");
          for (std::size_t k = 0; k < axes->size(); ++k)
            e.pad.axes[k] = static_cast<float>(std::clamp(
                gf.as_number((*axes)[k], internal::index_path(gf.field("axes"), k)), -1.0, 1.0));
        } else {
          e.pad.axes[GLFW_GAMEPAD_AXIS_LEFT_TRIGGER] = -1.0f;
          e.pad.axes[GLFW_GAMEPAD_AXIS_RIGHT_TRIGGER] = -1.0f;
        }
        if (const Json* buttons = gf.get("buttons")) {
          if (!buttons->is_array() || buttons->size() > 15)
            gf.fail("buttons", "expected up to 15 values 0 or 1");
          for (std::size_t k = 0; k < buttons->size(); ++k)
            e.pad.buttons[k] =
                gf.as_number((*buttons)[k], internal::index_path(gf.field("buttons"), k)) != 0.0
                    ? 1
                    : 0;
        }
        gf.finish();
      }
    } else if (f.has("screenshot")) {
      e.type = ScriptEvent::Type::kScreenshot;
      e.file = f.text("screenshot");
    } else if (f.has("resize")) {
      e.type = ScriptEvent::Type::kResize;
      const Json& r = f.array("resize");
      if (r.size() != 2) f.fail("resize", "expected [width, height]");
      e.x = require_in_range(f.as_number(r[0], f.field("resize")), 199.0, 8192.0, source,
                             f.field("resize"));
      e.y = require_in_range(f.as_number(r[1], f.field("resize")), 199.0, 8192.0, source,
                             f.field("resize"));
    } else if (f.has("close")) {
      e.type = ScriptEvent::Type::kClose;
      f.boolean_or("close", true);
    } else {
      f.fail("key", "expected one of key, mouse, cursor, gamepad, screenshot, resize, close");
    }
    f.finish();
    out.push_back(std::move(e));
  }
  return out;
}

std::vector<ScriptEvent> load_script(const std::filesystem::path& file) {
  std::ifstream in(file, std::ios::binary);
  if (!in) throw InputError(file.string(), "file", "expected a readable script file");
  std::stringstream ss;
  ss << in.rdbuf();
  return parse_script(ss.str(), file.string());
}

std::vector<ScriptEvent> bench_script(double seconds, int instruments) {
  std::vector<ScriptEvent> s;
  auto key = [&](double t, int k, int action, int mods = 0) {
    ScriptEvent e;
    e.t = t;
    e.type = ScriptEvent::Type::kKey;
    e.key = k;
    e.action = action;
    e.mods = mods;
    s.push_back(e);
  };
  key(0.5, GLFW_KEY_SPACE, GLFW_PRESS);  // the pedal, held throughout
  // Strokes of 0.4 s with 0.3 s between them: push, push, pull; every fifth a turn. Each press and
  // release changes what a hand does: an event whose latency to the screen is measured.
  double t = 1.0;
  int n = 0;
  while (t + 0.8 < seconds - 0.5) {
    int k = n % 3 == 2 ? GLFW_KEY_S : GLFW_KEY_W;
    if (n % 5 == 4) k = GLFW_KEY_D;
    key(t, k, GLFW_PRESS);
    key(t + 0.4, k, GLFW_RELEASE);
    // Half-way, the catheter follows the wire for a while (Tab selects the next instrument).
    if (instruments > 1 && n == 12) key(t + 0.5, GLFW_KEY_TAB, GLFW_PRESS, GLFW_MOD_SHIFT);
    if (instruments > 1 && n == 18) key(t + 0.5, GLFW_KEY_TAB, GLFW_PRESS);
    if (n == 8) key(t + 0.45, GLFW_KEY_L, GLFW_PRESS);  // the C-arm toward LAO for 1 s
    if (n == 10) key(t + 0.45, GLFW_KEY_L, GLFW_RELEASE);
    if (n == 14) key(t + 0.45, GLFW_KEY_E, GLFW_PRESS);  // an injection of about 2 s
    if (n == 17) key(t + 0.45, GLFW_KEY_E, GLFW_RELEASE);
    t += 0.7;
    ++n;
  }
  ScriptEvent close;
  close.t = seconds;
  close.type = ScriptEvent::Type::kClose;
  s.push_back(close);
  std::stable_sort(s.begin(), s.end(),
                   [](const ScriptEvent& a, const ScriptEvent& b) { return a.t < b.t; });
  return s;
}

}  // namespace vcsim::trainer
