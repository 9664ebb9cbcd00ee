// The trainer's window (trainer.h), internal to apps/trainer: the Viewer owns the window's
// side of a session (controls, the fluoroscopy and 3D view drawn in the window's GL context, cine,
// screenshots, scripted input, the session's files) and the PhysicsThread. viewer.cpp holds the
// frame loop, events and files; panels.cpp the ImGui panels and menus.
#pragma once

#define GL_GLEXT_PROTOTYPES
#include <GL/glcorearb.h>
#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "controls.h"
#include "film.h"
#include "physics.h"
#include "script.h"
#include "trainer.h"
#include "vcsim/render.h"
#include "view3d.h"

namespace vcsim::trainer {

namespace fs = std::filesystem;

// "LAO 40  CAU 30": the angles as a C-arm's display shows them.
inline std::string angles_text(double primary, double secondary) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%s %.0f\xc2\xb0  %s %.0f\xc2\xb0", primary >= 0 ? "LAO" : "RAO",
                std::abs(primary), secondary >= 0 ? "CRA" : "CAU", std::abs(secondary));
  return buf;
}

inline std::string clock_text(double s) {
  char buf[32];
  const int m = static_cast<int>(s / 60.0);
  std::snprintf(buf, sizeof buf, "%02d:%04.1f", m, s - 60.0 * m);
  return buf;
}

// The display of an image system: a grey texture (row 0 at the top) shown in ImGui.
struct GreyTexture {
  GLuint id = 0;
  int size = 0;
  explicit GreyTexture(int n) : size(n) {
    glGenTextures(1, &id);
    glBindTexture(GL_TEXTURE_2D, id);
    const std::vector<std::uint8_t> black(static_cast<std::size_t>(n) * n, 0);
    glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
    glTexImage2D(GL_TEXTURE_2D, 0, GL_R8, n, n, 0, GL_RED, GL_UNSIGNED_BYTE, black.data());
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
    const GLint swizzle[] = {GL_RED, GL_RED, GL_RED, GL_ONE};
    glTexParameteriv(GL_TEXTURE_2D, GL_TEXTURE_SWIZZLE_RGBA, swizzle);
  }
  ~GreyTexture() { glDeleteTextures(1, &id); }
  void upload(const std::vector<std::uint8_t>& img) {
    glBindTexture(GL_TEXTURE_2D, id);
    glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
    glTexSubImage2D(GL_TEXTURE_2D, 0, 0, 0, size, size, GL_RED, GL_UNSIGNED_BYTE, img.data());
  }
};

struct CineRun {
  std::vector<std::vector<std::uint8_t>> frames;
  bool saved = false;
  fs::path dir;
};

// Memory for cine: at most this many frames in all (512 x 512: 256 kB each, 150 MB).
inline constexpr std::size_t kMaxCineFrames = 600;
inline constexpr double kCineFps = 15.0;

class Viewer {
 public:
  Viewer(TrainerOptions& o, GLFWwindow* win);
  ~Viewer();
  int run(double started_us);

  // The GLFW callbacks land here (and the script calls the same). `when_us`: when the event
  // happened (the wall clock, now_us()); a callback passes the time it is called, the script the
  // time an event was due (it waits for the next frame as a key press waits in the X queue).
  void on_key(int key, int action, int mods, double when_us);
  void on_mouse_button(int button, int action, int mods, double when_us);
  void on_cursor(double x, double y, double when_us);
  void on_scroll(double dx, double dy);
  void on_focus_lost() { controls_.release_all(now_us()); }

 private:
  void frame();
  // The model of what the window shows: the latest view's (an exchange replaces it), never the
  // physics thread's own, which it may be replacing.
  const SimModel& scene_model() const;
  // The window's controls follow the scene's instruments after an exchange or a restart.
  void follow_scene();
  std::shared_ptr<const SimModel> followed_;  // the model follow_scene() last followed
  // Asks the physics thread to add `spec` (over `over`, inside `inside`) or to replace the
  // selected instrument by it; the status line says what was asked.
  void ask_add(const InstrumentSpec& spec, const std::string& inside, const std::string& over);
  void ask_replace(int selected, const InstrumentSpec& spec);
  void run_script(double now);
  void do_actions();
  void do_action(Action a);
  void render_xray();
  // Keeps the images the window shows for the session report's key frames (film.h).
  void film();
  void draw_ui();
  void draw_fluoro_panel(float x, float y, float side);
  void draw_side_panel(float x, float y, float w, float h);
  void draw_menu();
  void take_screenshot(const fs::path& file);
  void save_cine();
  void finish();
  nlohmann::json overlay_json() const;
  fs::path out_path(const std::string& name) const {
    const fs::path p(name);
    return p.is_absolute() ? p : o_.out / p;
  }

  TrainerOptions& o_;
  GLFWwindow* win_;
  PhysicsThread physics_;
  Controls controls_;
  SimFluoroscopy fluoro_;
  GreyTexture tex_;
  std::unique_ptr<View3D> view3d_;
  InstrumentCatalogue catalogue_;
  Vec3 home_;
  ImageChainSettings chain_;
  ViewState view_;
  std::vector<std::uint8_t> image_;
  bool have_image_ = false;
  std::uint64_t drawn_version_ = 0;
  std::int64_t xray_frames_ = 0;
  double render_s_ = 0.0;
  bool xray_now_ = false;
  bool drew_ = false;  // render_xray drew a new image in this frame
  // The session's film (film.h), null without outputs: one image a second while the beam is on,
  // the image shown at each key moment and the last one before the beam goes off.
  std::unique_ptr<SessionFilm> film_;
  bool film_key_ = false;       // a key moment since the last image shown
  int film_events_ = 0;         // the assessment's events when last looked at
  double film_flow_ = 0.0;      // the syringe's flow (m^3/s) when last looked at
  double film_pressure_ = 0.0;  // the balloon pressure (Pa) when last looked at
  bool shown_filmed_ = true;    // the image on screen is in the film
  double shown_time_ = 0.0;     // s simulated, of the image on screen
  CArmPose shown_pose_;         // the C-arm the image on screen was made through
  // Cine: runs recorded while the cine pedal is held, at 15 frames per simulated second.
  std::vector<CineRun> cine_;
  bool cine_open_ = false;
  double next_cine_ = 0.0;
  std::size_t cine_total_ = 0;
  bool review_ = false;
  std::size_t review_frame_ = 0;
  double review_next_us_ = 0.0;
  bool show3d_ = false, help_ = false;
  std::string status_;
  // Panels in window coordinates.
  float fluoro_x_ = 0, fluoro_y_ = 0, fluoro_side_ = 0;
  float view3d_rect_[4] = {0, 0, 0, 0};
  bool orbiting_ = false;
  double last_cursor_[2] = {0, 0};
  // Script and measurement.
  std::vector<ScriptEvent> script_;
  std::size_t next_event_ = 0;
  bool scripted_pad_ = false;
  double t0_us_ = 0.0;
  std::vector<fs::path> pending_shots_;
  std::vector<std::string> shots_taken_;
  std::vector<double> frame_us_;  // wall clock of each swap
  std::vector<double> latency_ms_;
  double session_start_us_ = 0.0;
  double setup_s_ = 0.0;
};

}  // namespace vcsim::trainer
