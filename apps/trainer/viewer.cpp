// The trainer's window (trainer.h, viewer.h): GLFW + Dear ImGui on the main thread, the
// fluoroscopy drawn into the window's GL context from the latest copy of the state the physics
// thread hands over (physics.h), the controls (controls.h), scripted input (script.h), cine,
// screenshots, the frame loop, and the session's files at the end (the panels: panels.cpp).
// docs/trainer.md describes what the person sees and does.
#include "viewer.h"

#include <backends/imgui_impl_glfw.h>
#include <backends/imgui_impl_opengl3.h>
#include <imgui.h>
#include <stb_image_write.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>
#include <stdexcept>
#include <thread>

#include "vcsim/assess.h"
#include "vcsim/units.h"

namespace vcsim::trainer {

namespace {

std::string g_glfw_error;
void on_glfw_error(int code, const char* what) {
  g_glfw_error = what ? what : "";
  (void)code;
}

// The q-quantile (0.5: the median) of the values, 0 for none.
double quantile(std::vector<double> v, double q) {
  if (v.empty()) return 0.0;
  const auto k = static_cast<std::size_t>(q * static_cast<double>(v.size() - 1) + 0.5);
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(k), v.end());
  return v[k];
}

Viewer* g_viewer = nullptr;

void key_cb(GLFWwindow*, int key, int, int action, int mods) {
  if (g_viewer) g_viewer->on_key(key, action, mods, now_us());
}
void mouse_cb(GLFWwindow*, int button, int action, int mods) {
  if (g_viewer) g_viewer->on_mouse_button(button, action, mods, now_us());
}
void cursor_cb(GLFWwindow*, double x, double y) {
  if (g_viewer) g_viewer->on_cursor(x, y, now_us());
}
void scroll_cb(GLFWwindow*, double dx, double dy) {
  if (g_viewer) g_viewer->on_scroll(dx, dy);
}
void focus_cb(GLFWwindow*, int focused) {
  if (g_viewer && !focused) g_viewer->on_focus_lost();
}

}  // namespace

Viewer::Viewer(TrainerOptions& o, GLFWwindow* win)
    : o_(o),
      win_(win),
      physics_(o.scenario, o.device.get()),
      controls_(
          [&] {
            std::vector<std::string> n;
            for (const ScenarioInstrument& si : o.scenario.instruments) n.push_back(si.name);
            return n;
          }(),
          o.scenario),
      fluoro_(physics_.model(), o.fluoro_size,
              o.scenario.fluoro.energy_kev == 80 ? BeamEnergy::k80keV : BeamEnergy::k60keV),
      tex_(o.fluoro_size),
      home_(left_coronary_centre(physics_.model().tree)) {
  chain_.dose = o.scenario.fluoro.dose;
  try {
    catalogue_ = load_catalogue(default_catalogue_dir());
  } catch (const std::exception&) {
    // The exchange menu is then empty; the session does not need it.
  }
  image_.assign(static_cast<std::size_t>(o.fluoro_size) * o.fluoro_size, 0);
  if (o.write_outputs) {
    try {
      // An earlier session's frames.csv would name frames this one may not film.
      fs::remove(o.out / "frames.csv");
      film_ = std::make_unique<SessionFilm>(o.out / "frames", o.fluoro_size);
    } catch (const std::exception& e) {  // the session runs on; its report has no key frames
      status_ = std::string("not filming the session: ") + e.what();
    }
  }
  if (o.bench) {
    script_ = bench_script(o.bench_time, controls_.num_instruments());
  } else if (!o.script.empty()) {
    script_ = load_script(o.script);
  }
  g_viewer = this;
}

Viewer::~Viewer() {
  g_viewer = nullptr;
}

void Viewer::on_key(int key, int action, int mods, double when_us) {
  if (ImGui::GetCurrentContext() && ImGui::GetIO().WantTextInput) return;
  controls_.key(key, action, mods, when_us);
}

void Viewer::on_mouse_button(int button, int action, int mods, double when_us) {
  double x = 0, y = 0;
  glfwGetCursorPos(win_, &x, &y);
  if (button == GLFW_MOUSE_BUTTON_RIGHT || button == GLFW_MOUSE_BUTTON_LEFT) {
    const bool in3d = show3d_ && x >= view3d_rect_[0] && x <= view3d_rect_[2] &&
                      y >= view3d_rect_[1] && y <= view3d_rect_[3];
    if (in3d && action == GLFW_PRESS) {
      orbiting_ = true;
      last_cursor_[0] = x;
      last_cursor_[1] = y;
      return;
    }
    if (action == GLFW_RELEASE) orbiting_ = false;
  }
  controls_.mouse_button(button, action, mods, x, y, when_us);
}

void Viewer::on_cursor(double x, double y, double when_us) {
  if (orbiting_ && view3d_) {
    view3d_->orbit(x - last_cursor_[0], y - last_cursor_[1]);
    last_cursor_[0] = x;
    last_cursor_[1] = y;
    return;
  }
  controls_.cursor(x, y, when_us);
}

void Viewer::on_scroll(double dx, double dy) {
  double x = 0, y = 0;
  glfwGetCursorPos(win_, &x, &y);
  if (show3d_ && view3d_ && x >= view3d_rect_[0] && x <= view3d_rect_[2] && y >= view3d_rect_[1] &&
      y <= view3d_rect_[3]) {
    view3d_->zoom(dy);
    return;
  }
  const bool over = x >= fluoro_x_ && x <= fluoro_x_ + fluoro_side_ && y >= fluoro_y_ &&
                    y <= fluoro_y_ + fluoro_side_;
  controls_.scroll(dx, dy, over, now_us());
}

void Viewer::run_script(double now) {
  const double t = (now - t0_us_) * 1e-6;
  while (next_event_ < script_.size() && script_[next_event_].t <= t) {
    const ScriptEvent& e = script_[next_event_++];
    const double due = t0_us_ + e.t * 1e6;
    switch (e.type) {
      case ScriptEvent::Type::kKey:
        on_key(e.key, e.action, e.mods, due);
        break;
      case ScriptEvent::Type::kMouse:
        glfwSetCursorPos(win_, e.x, e.y);
        on_mouse_button(e.key, e.action, e.mods, due);
        break;
      case ScriptEvent::Type::kCursor:
        on_cursor(e.x, e.y, due);
        break;
      case ScriptEvent::Type::kGamepad:
        scripted_pad_ = true;
        controls_.gamepad(e.pad, due);
        break;
      case ScriptEvent::Type::kGamepadLost:
        scripted_pad_ = true;
        controls_.gamepad_lost(due);
        break;
      case ScriptEvent::Type::kScreenshot:
        pending_shots_.push_back(out_path(e.file));
        break;
      case ScriptEvent::Type::kResize:
        glfwSetWindowSize(win_, static_cast<int>(e.x), static_cast<int>(e.y));
        break;
      case ScriptEvent::Type::kClose:
        glfwSetWindowShouldClose(win_, GLFW_TRUE);  // what the window's close button does
        break;
    }
  }
}

void Viewer::do_actions() {
  for (Action a : controls_.take_actions()) do_action(a);
}

void Viewer::do_action(Action a) {
  {
    switch (a) {
      case Action::kTogglePause:
        physics_.request(Request::kTogglePause);
        break;
      case Action::kRewind:
        physics_.request(Request::kRewind, 5.0);
        break;
      case Action::kRestart:
        physics_.request(Request::kRestart);
        break;
      case Action::kToggleReview:
        if (!cine_.empty() && !cine_.back().frames.empty()) {
          review_ = !review_;
          review_frame_ = 0;
          review_next_us_ = 0.0;
        } else {
          status_ = "no cine run to review (hold C to record one)";
        }
        break;
      case Action::kSaveCine:
        save_cine();
        break;
      case Action::kToggle3D:
        show3d_ = !show3d_;
        break;
      case Action::kToggleHelp:
        help_ = !help_;
        break;
      case Action::kQuit:
        glfwSetWindowShouldClose(win_, GLFW_TRUE);
        break;
    }
  }
}

void Viewer::render_xray() {
  const bool fluoro = controls_.fluoro_pedal(), cine = controls_.cine_pedal();
  drew_ = false;
  xray_now_ = (fluoro || cine) && !view_.paused;
  if (!cine && cine_open_) cine_open_ = false;  // the cine pedal let go: the run is complete
  if (!xray_now_ || view_.version == drawn_version_) return;
  if (fluoro || cine) review_ = false;  // live images replace a review
  CArmPose pose;
  pose.primary_deg = controls_.primary_deg();
  pose.secondary_deg = controls_.secondary_deg();
  pose.fov = controls_.fov();
  pose.isocentre = home_ + controls_.table_pan();
  ImageChainSettings chain = chain_;
  chain.seed = static_cast<std::uint64_t>(++xray_frames_);
  const double t0 = now_us();
  fluoro_.frame(view_.frame, pose, chain, image_);
  tex_.upload(image_);
  render_s_ += (now_us() - t0) * 1e-6;
  have_image_ = true;
  drew_ = true;
  shown_time_ = view_.time;
  shown_pose_ = pose;
  drawn_version_ = view_.version;
  if (cine) {
    if (!cine_open_) {
      cine_.push_back({});
      cine_open_ = true;
      next_cine_ = view_.time;
    }
    if (view_.time >= next_cine_ - 1e-9 && cine_total_ < kMaxCineFrames) {
      cine_.back().frames.push_back(image_);
      ++cine_total_;
      next_cine_ += 1.0 / kCineFps;
    }
  }
}

void Viewer::film() {
  if (!film_) return;
  film_->rewound(view_.time);  // a rewind or a restart: the film goes back with the state
  // Key moments (what the report's key frames are picked at, docs/assessment.md): an event the
  // assessment marked (engaged, lesion crossed, a procedure event), an injection's end (the
  // angiograms before and after treatment), an inflation's start or end.
  if (view_.assessment_events != film_events_) film_key_ = true;
  if (film_flow_ > 0.0 && view_.syringe_flow <= 0.0) film_key_ = true;
  if ((film_pressure_ > 0.0) != (view_.balloon_pressure > 0.0)) film_key_ = true;
  film_events_ = view_.assessment_events;
  film_flow_ = view_.syringe_flow;
  film_pressure_ = view_.balloon_pressure;
  if (drew_) {
    shown_filmed_ = film_->due(shown_time_, film_key_);
    if (shown_filmed_) film_->keep(image_, shown_time_, shown_pose_);
    film_key_ = false;
  } else if (!xray_now_) {
    // The beam is off: the image held on screen (last image hold) is the last one shown, and
    // what a key moment now shows (unless a rewind has since taken its steps back).
    if (have_image_ && !shown_filmed_ && shown_time_ <= view_.time)
      film_->keep(image_, shown_time_, shown_pose_);
    shown_filmed_ = true;
    film_key_ = false;
  }
}

nlohmann::json Viewer::overlay_json() const {
  nlohmann::json j;
  j["procedure_time_s"] = view_.time;
  j["fluoroscopy_time_s"] = view_.fluoro_time;
  j["contrast_used_ml"] = view_.contrast_volume / kMl;
  j["syringe_flow_ml_s"] = view_.syringe_flow / kMl;
  j["primary_deg"] = controls_.primary_deg();
  j["secondary_deg"] = controls_.secondary_deg();
  j["angles"] = angles_text(controls_.primary_deg(), controls_.secondary_deg());
  j["field_mm"] = controls_.fov() * 1e3;
  j["fluoro_pedal"] = controls_.fluoro_pedal();
  j["xray_on"] = xray_now_;
  j["image_held"] = have_image_ && !xray_now_;
  j["paused"] = view_.paused;
  j["selected"] = controls_.name(controls_.selected());
  j["cine_runs"] = cine_.size();
  j["cine_frames"] = cine_total_;
  j["review"] = review_;
  j["steps"] = view_.steps;
  nlohmann::json inst = nlohmann::json::array();
  for (int i = 0; i < controls_.num_instruments(); ++i) {
    const auto u = static_cast<std::size_t>(i);
    inst.push_back({{"name", controls_.name(i)},
                    {"depth_mm", u < view_.depth.size() ? view_.depth[u] * 1e3 : 0.0},
                    {"force_n", u < view_.feedback.size() ? view_.feedback[u].axial_force : 0.0}});
  }
  j["instruments"] = inst;
  j["fluoro_panel"] = {fluoro_x_, fluoro_y_, fluoro_side_};
  return j;
}

void Viewer::take_screenshot(const fs::path& file) {
  int w = 0, h = 0;
  glfwGetFramebufferSize(win_, &w, &h);
  std::vector<std::uint8_t> px(static_cast<std::size_t>(w) * h * 3), flipped(px.size());
  glPixelStorei(GL_PACK_ALIGNMENT, 1);
  glReadBuffer(GL_BACK);
  glReadPixels(0, 0, w, h, GL_RGB, GL_UNSIGNED_BYTE, px.data());
  const std::size_t row = static_cast<std::size_t>(w) * 3;
  for (int y = 0; y < h; ++y)
    std::copy_n(px.data() + static_cast<std::size_t>(h - 1 - y) * row, row,
                flipped.data() + static_cast<std::size_t>(y) * row);
  std::error_code ec;
  if (file.has_parent_path()) fs::create_directories(file.parent_path(), ec);
  if (!stbi_write_png(file.string().c_str(), w, h, 3, flipped.data(), static_cast<int>(row))) {
    status_ = "could not write " + file.string();
    return;
  }
  // The overlay's values beside the picture: what the overlay drew in this frame.
  nlohmann::json j = overlay_json();
  j["width"] = w;
  j["height"] = h;
  fs::path side = file;
  side.replace_extension(".json");
  std::ofstream(side) << j.dump(2) << "\n";
  shots_taken_.push_back(file.string());
}

void Viewer::save_cine() {
  if (!o_.write_outputs) return;
  int saved = 0;
  for (std::size_t r = 0; r < cine_.size(); ++r) {
    CineRun& run = cine_[r];
    if (run.saved || run.frames.empty()) continue;
    char name[32];
    std::snprintf(name, sizeof name, "cine/run_%02zu", r + 1);
    run.dir = o_.out / name;
    std::error_code ec;
    fs::create_directories(run.dir, ec);
    for (std::size_t k = 0; k < run.frames.size(); ++k) {
      char f[32];
      std::snprintf(f, sizeof f, "frame_%05zu.png", k);
      write_png_grey((run.dir / f).string(), run.frames[k], o_.fluoro_size, o_.fluoro_size);
    }
    run.saved = true;
    ++saved;
  }
  status_ = saved ? "cine saved in " + (o_.out / "cine").string() : "no new cine run to save";
}

const SimModel& Viewer::scene_model() const {
  return view_.frame.model ? *view_.frame.model : physics_.model();
}

void Viewer::follow_scene() {
  if (view_.instruments.empty() || view_.frame.model == followed_) return;
  followed_ = view_.frame.model;
  controls_.set_instruments(view_.instruments, now_us());
  // Enter deploys the stent: the nominal pressure of the scene's stent system, else balloon.
  double deploy = 0.0;
  for (const InstrumentSpec& spec : scene_model().specs)
    if (spec.balloon && (deploy == 0.0 || spec.stent)) deploy = spec.balloon->nominal_pressure;
  controls_.set_deploy_pressure(deploy);
  physics_.set_operator(controls_.commands());
}

namespace {

// A name for an added instrument: its catalogue entry's, numbered when the scene has one.
std::string fresh_name(const std::string& base, const std::vector<std::string>& taken) {
  std::string name = base;
  for (int k = 2; std::find(taken.begin(), taken.end(), name) != taken.end(); ++k)
    name = base + "-" + std::to_string(k);
  return name;
}

InstrumentChange change_for(const InstrumentSpec& spec, const std::string& name) {
  InstrumentChange c;
  c.kind = InstrumentChange::Kind::kAdd;
  c.name = name;
  c.catalogue = spec.name;
  // As the default scenario declares its instruments: 256 nodes, the tip's segments 2 mm (1.5 mm
  // on a balloon, whose nodes carry its radii).
  c.max_nodes = 256;
  c.tip_segment = spec.balloon ? 1.5e-3 : 2e-3;
  c.rim = false;
  c.source = "trainer";
  c.field = "menu";
  return c;
}

}  // namespace

void Viewer::ask_add(const InstrumentSpec& spec, const std::string& inside,
                     const std::string& over) {
  InstrumentChange c = change_for(spec, fresh_name(spec.name, view_.instruments));
  c.inside = inside;
  c.over = over;
  physics_.exchange(c);
  status_ = "asked: " + describe(c);
}

void Viewer::ask_replace(int selected, const InstrumentSpec& spec) {
  const SimModel& md = scene_model();
  const auto su = static_cast<std::size_t>(selected);
  if (su >= md.scenario.instruments.size()) return;
  const ScenarioInstrument& old = md.scenario.instruments[su];
  InstrumentChange out;
  out.kind = InstrumentChange::Kind::kRemove;
  out.name = old.name;
  out.source = "trainer";
  out.field = "menu";
  std::vector<std::string> taken = view_.instruments;
  std::erase(taken, old.name);
  InstrumentChange in = change_for(spec, fresh_name(spec.name, taken));
  in.inside = old.inside;
  in.over = old.over;
  in.rim = old.rim;
  physics_.exchange(out);
  physics_.exchange(in);
  status_ = "asked: " + describe(out) + ", then " + describe(in);
}

void Viewer::frame() {
  glfwPollEvents();
  const double now = now_us();
  if (!script_.empty()) run_script(now);
  if (!scripted_pad_) {
    bool found = false;
    for (int j = GLFW_JOYSTICK_1; j <= GLFW_JOYSTICK_LAST && !found; ++j) {
      GLFWgamepadstate st;
      if (glfwJoystickIsGamepad(j) && glfwGetGamepadState(j, &st)) {
        GamepadState g;
        std::copy(std::begin(st.axes), std::end(st.axes), g.axes.begin());
        std::copy(std::begin(st.buttons), std::end(st.buttons), g.buttons.begin());
        controls_.gamepad(g, now);
        found = true;
      }
    }
    if (!found) controls_.gamepad_lost(now);
  }
  if (controls_.update(now_us())) physics_.set_operator(controls_.commands());
  do_actions();
  physics_.latest(view_);
  // An event just handed over: wait a moment (at most 3 ms, a few physics steps) for the state
  // that used it, so that this frame shows it rather than the next.
  if (!view_.paused && !controls_.changes().empty() &&
      controls_.changes().back().seq > view_.input_seq) {
    const double until = now_us() + 3000.0;
    while (now_us() < until) {
      std::this_thread::sleep_for(std::chrono::microseconds(200));
      physics_.latest(view_);
      if (view_.input_seq >= controls_.changes().back().seq) break;
    }
  }
  follow_scene();
  render_xray();
  film();

  ImGui_ImplOpenGL3_NewFrame();
  ImGui_ImplGlfw_NewFrame();
  ImGui::NewFrame();
  draw_ui();
  ImGui::Render();
  int fw = 0, fh = 0;
  glfwGetFramebufferSize(win_, &fw, &fh);
  glBindFramebuffer(GL_FRAMEBUFFER, 0);
  glViewport(0, 0, fw, fh);
  glClearColor(0.05f, 0.05f, 0.06f, 1.0f);
  glClear(GL_COLOR_BUFFER_BIT);
  ImGui_ImplOpenGL3_RenderDrawData(ImGui::GetDrawData());
  for (const fs::path& f : pending_shots_) take_screenshot(f);
  pending_shots_.clear();
  glfwSwapBuffers(win_);
  const double swapped = now_us();
  frame_us_.push_back(swapped);
  // Latency: every input change the state of this frame used, from its event to this swap.
  auto& ch = controls_.changes();
  if (view_.paused) ch.clear();
  while (!ch.empty() && ch.front().seq <= view_.input_seq) {
    latency_ms_.push_back((swapped - ch.front().event_us) * 1e-3);
    ch.pop_front();
  }
  // No faster than 60 frames per second: the physics shares the machine.
  const double spent = now_us() - now;
  if (spent < 16000.0)
    std::this_thread::sleep_for(std::chrono::microseconds(static_cast<long>(16000.0 - spent)));
}

int Viewer::run(double started_us) {
  session_start_us_ = now_us();
  setup_s_ = (session_start_us_ - started_us) * 1e-6;
  physics_.start();
  t0_us_ = now_us();
  while (!glfwWindowShouldClose(win_) && !(o_.stop && o_.stop->load(std::memory_order_relaxed)))
    frame();
  finish();
  return 0;
}

void Viewer::finish() {
  physics_.stop();
  const Simulator& sim = physics_.simulator();
  CommandRecording& rec = physics_.recording();
  rec.state_hash = sim.state().hash();
  rec.scenario_file = o_.scenario_file;
  const double wall = (now_us() - session_start_us_) * 1e-6;

  // Frame rate over the session after its first second (window start-up, shader compiles).
  double fps = 0.0;
  {
    std::size_t first = 0;
    while (first < frame_us_.size() && frame_us_[first] - frame_us_.front() < 1e6) ++first;
    if (frame_us_.size() > first + 1)
      fps = static_cast<double>(frame_us_.size() - 1 - first) /
            ((frame_us_.back() - frame_us_[first]) * 1e-6);
  }
  std::vector<double> lags;
  for (float l : physics_.lag_samples()) lags.push_back(static_cast<double>(l) * 1e3);
  const double lag_med = quantile(lags, 0.5), lag_p99 = quantile(lags, 0.99);
  const double lag_max = lags.empty() ? 0.0 : *std::max_element(lags.begin(), lags.end());
  const double lat_med = quantile(latency_ms_, 0.5), lat_p90 = quantile(latency_ms_, 0.9);
  const double lat_max =
      latency_ms_.empty() ? 0.0 : *std::max_element(latency_ms_.begin(), latency_ms_.end());
  const char* renderer = reinterpret_cast<const char*>(glGetString(GL_RENDERER));

  nlohmann::json perf = {
      {"fps", fps},
      {"frames", frame_us_.size()},
      {"xray_frames", xray_frames_},
      {"fluoro_size", o_.fluoro_size},
      {"lag_ms", {{"median", lag_med}, {"p99", lag_p99}, {"max", lag_max}, {"steps", lags.size()}}},
      {"latency_ms",
       {{"median", lat_med}, {"p90", lat_p90}, {"max", lat_max}, {"events", latency_ms_.size()}}},
      {"render_ms_per_xray_frame",
       xray_frames_ > 0 ? render_s_ * 1e3 / static_cast<double>(xray_frames_) : 0.0},
      {"sim_time_s", sim.time()},
      {"wall_time_s", wall},
      {"late_steps", physics_.loop_stats().late_steps},
      {"resyncs", physics_.loop_stats().resyncs},
      {"gl_renderer", renderer ? renderer : ""}};
  int w = 0, h = 0;
  glfwGetFramebufferSize(win_, &w, &h);
  perf["window"] = {w, h};

  if (o_.write_outputs) {
    std::error_code ec;
    fs::create_directories(o_.out, ec);
    save_cine();
    const fs::path rec_file = o_.out / "recording.json";
    rec.save(rec_file);
    RunReport report;
    report.scenario_file = o_.scenario_file;
    report.end_time = sim.time();
    report.wall_time = wall;
    report.setup_time = setup_s_;
    report.render_time = render_s_;
    report.frames = static_cast<int>(xray_frames_);
    report.fluoroscopy_time = physics_.fluoro_time();
    report.input_type = "trainer";
    report.realtime = true;
    report.loop = physics_.loop_stats();
    report.loop.stopped = o_.stop && o_.stop->load();
    if (o_.device) {
      report.device = o_.device->stats();
      report.device_address = o_.device_address;
      report.device_port = o_.device->port();
    }
    // The film: the image on screen at the end too, then every image on disk, in order.
    std::vector<double> film_times;
    std::vector<CArmPose> film_poses;
    if (film_) {
      try {
        if (have_image_ && !shown_filmed_ && shown_time_ <= view_.time)
          film_->keep(image_, shown_time_, shown_pose_);
        film_->finish(film_times, film_poses);
      } catch (const std::exception& e) {  // the session is saved; its report has no key frames
        std::cerr << "trainer: frames not written: " << e.what() << "\n";
        film_times.clear();
        film_poses.clear();
      }
    }
    const fs::path metrics = o_.out / "metrics.json";
    write_run_metrics(metrics, sim, report);
    // The session's assessment (docs/assessment.md), and frames.csv of the film.
    physics_.assessment().write(o_.out, sim, film_poses, film_times);
    // The trainer's own figures beside the run's (the assessment reads both).
    nlohmann::json j;
    {
      std::ifstream in(metrics);
      j = nlohmann::json::parse(in);
    }
    nlohmann::json t = perf;
    t["recording"] = rec_file.string();
    t["recorded_steps"] = rec.steps();
    t["recorded_runs"] = rec.num_runs();
    t["cine_runs"] = cine_.size();
    t["cine_frames"] = cine_total_;
    t["film_frames"] = film_times.size();
    t["rewinds"] = physics_.rewinds();
    t["restarts"] = physics_.restarts();
    t["exchanges"] = physics_.exchanges();
    t["screenshots"] = shots_taken_;
    if (o_.device) {
      const IgtlStats st = o_.device->stats();
      t["device"] = {{"connections", st.connections},
                     {"disconnections", st.disconnections},
                     {"messages_accepted", st.messages_accepted},
                     {"exchanges", st.exchanges},
                     {"exchanges_refused", st.exchanges_refused}};
    }
    j["trainer"] = t;
    std::ofstream(metrics) << j.dump(2) << "\n";
    fs::path html;
    try {
      html = write_report(o_.out);
    } catch (const std::exception& e) {  // the session is saved; only its page is missing
      std::cerr << "trainer: report not written: " << e.what() << "\n";
    }
    std::cerr << "trainer: session saved: " << rec_file.string() << " (" << rec.steps()
              << " steps, " << rec.num_runs() << " runs), " << metrics.string()
              << (html.empty() ? std::string() : ", " + html.string()) << "\n"
              << "trainer: replay it with: vcsim run " << o_.scenario_file << " --replay "
              << rec_file.string() << "\n";
  }
  if (o_.bench) std::cout << perf.dump(2) << std::endl;
}

void require_display() {
  const char* display = std::getenv("DISPLAY");
  const char* wayland = std::getenv("WAYLAND_DISPLAY");
  if ((!display || !*display) && (!wayland || !*wayland))
    throw InputError("trainer", "display",
                     "expected a display (DISPLAY is not set); on a machine without one run it "
                     "under a virtual X server: xvfb-run -a vcsim trainer");
}

int run_trainer(TrainerOptions o) {
  // A machine without a display: say how to run it anyway, before anything else is built.
  require_display();
  glfwSetErrorCallback(on_glfw_error);
  if (!glfwInit())
    throw InputError("trainer", "display",
                     "expected a display GLFW can open (" + g_glfw_error +
                         "); on a machine without one run it under xvfb-run -a vcsim trainer");
  struct GlfwEnd {
    ~GlfwEnd() { glfwTerminate(); }
  } glfw_end;
  glfwWindowHint(GLFW_CONTEXT_VERSION_MAJOR, 3);
  glfwWindowHint(GLFW_CONTEXT_VERSION_MINOR, 3);
  glfwWindowHint(GLFW_OPENGL_PROFILE, GLFW_OPENGL_CORE_PROFILE);
  glfwWindowHint(GLFW_OPENGL_FORWARD_COMPAT, GLFW_TRUE);
  const std::string title = "vcsim trainer: " + o.scenario.name;
  GLFWwindow* win = glfwCreateWindow(o.width, o.height, title.c_str(), nullptr, nullptr);
  if (!win) throw std::runtime_error("trainer: no OpenGL 3.3 core window (" + g_glfw_error + ")");
  struct WindowEnd {
    GLFWwindow* w;
    ~WindowEnd() { glfwDestroyWindow(w); }
  } window_end{win};
  glfwMakeContextCurrent(win);
  glfwSwapInterval(0);  // paced by the frame loop (at most 60 per second), not by the display
  // Our callbacks first: ImGui's backend chains to them.
  glfwSetKeyCallback(win, key_cb);
  glfwSetMouseButtonCallback(win, mouse_cb);
  glfwSetCursorPosCallback(win, cursor_cb);
  glfwSetScrollCallback(win, scroll_cb);
  glfwSetWindowFocusCallback(win, focus_cb);

  IMGUI_CHECKVERSION();
  ImGui::CreateContext();
  ImGui::GetIO().IniFilename = nullptr;  // no imgui.ini left in the working folder
  ImGui::StyleColorsDark();
  ImGui_ImplGlfw_InitForOpenGL(win, true);
  ImGui_ImplOpenGL3_Init("#version 330 core");
  struct ImGuiEnd {
    ~ImGuiEnd() {
      ImGui_ImplOpenGL3_Shutdown();
      ImGui_ImplGlfw_Shutdown();
      ImGui::DestroyContext();
    }
  } imgui_end;

  const double t0 = now_us();
  int status = 0;
  {
    Viewer viewer(o, win);
    std::cerr << "trainer: " << o.scenario.name << " ready in " << (now_us() - t0) * 1e-6 << " s ("
              << reinterpret_cast<const char*>(glGetString(GL_RENDERER)) << ")" << std::endl;
    status = viewer.run(t0);
  }
  return status;
}

}  // namespace vcsim::trainer
