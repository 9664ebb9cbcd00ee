// The trainer's panels (viewer.h): the fluoroscopy panel with its overlay as a C-arm's monitor
// shows it, the procedure panel (times, contrast, instruments and their hand forces, C-arm,
// syringe, indeflator, device, landmarks), the menus, the educator's 3D view and the keys.
#include <backends/imgui_impl_glfw.h>
#include <imgui.h>

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "vcsim/units.h"
#include "viewer.h"

namespace vcsim::trainer {

void Viewer::draw_fluoro_panel(float x, float y, float side) {
  fluoro_x_ = x;
  fluoro_y_ = y;
  fluoro_side_ = side;
  controls_.set_fluoro_area(x, y, x + side, y + side);
  ImGui::SetNextWindowPos(ImVec2(x, y));
  ImGui::SetNextWindowSize(ImVec2(side, side));
  ImGui::PushStyleVar(ImGuiStyleVar_WindowPadding, ImVec2(0, 0));
  ImGui::PushStyleVar(ImGuiStyleVar_WindowBorderSize, 0.0f);
  ImGui::Begin("Fluoroscopy", nullptr,
               ImGuiWindowFlags_NoDecoration | ImGuiWindowFlags_NoMove |
                   ImGuiWindowFlags_NoBringToFrontOnFocus | ImGuiWindowFlags_NoScrollWithMouse);
  // In review the last cine run loops at its frame rate; otherwise the live (or held) image.
  if (review_ && !cine_.empty() && !cine_.back().frames.empty()) {
    const CineRun& run = cine_.back();
    const double now = now_us();
    if (review_next_us_ == 0.0 || now >= review_next_us_) {
      review_frame_ = (review_next_us_ == 0.0) ? 0 : (review_frame_ + 1) % run.frames.size();
      tex_.upload(run.frames[review_frame_]);
      review_next_us_ = now + 1e6 / kCineFps;
    }
  } else if (review_next_us_ != 0.0) {
    review_next_us_ = 0.0;
    if (have_image_) tex_.upload(image_);  // back to the held image
  }
  ImGui::Image(reinterpret_cast<ImTextureID>(static_cast<std::intptr_t>(tex_.id)),
               ImVec2(side, side));
  ImDrawList* dl = ImGui::GetWindowDrawList();
  const ImU32 amber = IM_COL32(255, 200, 60, 255), white = IM_COL32(235, 235, 235, 255);
  const float pad = 10.0f, line = ImGui::GetTextLineHeightWithSpacing();
  dl->AddText(ImVec2(x + pad, y + pad), white,
              angles_text(controls_.primary_deg(), controls_.secondary_deg()).c_str());
  char buf[96];
  std::snprintf(buf, sizeof buf, "FOV %.0f cm", controls_.fov() * 100.0);
  dl->AddText(ImVec2(x + pad, y + pad + line), white, buf);
  std::snprintf(buf, sizeof buf, "FL %s", clock_text(view_.fluoro_time).c_str());
  const float w = ImGui::CalcTextSize(buf).x;
  dl->AddText(ImVec2(x + side - w - pad, y + pad), amber, buf);
  std::snprintf(buf, sizeof buf, "T %s", clock_text(view_.time).c_str());
  dl->AddText(ImVec2(x + side - ImGui::CalcTextSize(buf).x - pad, y + pad + line), white, buf);
  if (xray_now_) {
    dl->AddCircleFilled(ImVec2(x + side - pad - 6, y + pad + 2.6f * line), 6.0f,
                        IM_COL32(255, 190, 0, 255));
    const char* what = controls_.cine_pedal() ? "CINE" : "FLUORO";
    dl->AddText(ImVec2(x + side - pad - 18 - ImGui::CalcTextSize(what).x, y + pad + 2.1f * line),
                amber, what);
  } else if (review_) {
    std::snprintf(buf, sizeof buf, "REVIEW %zu/%zu", review_frame_ + 1,
                  cine_.empty() ? 0 : cine_.back().frames.size());
    dl->AddText(ImVec2(x + pad, y + side - pad - line), amber, buf);
  } else if (have_image_) {
    dl->AddText(ImVec2(x + pad, y + side - pad - line), white, "LIH");
  } else {
    const char* t = "Hold SPACE for fluoroscopy";
    const ImVec2 ts = ImGui::CalcTextSize(t);
    dl->AddText(ImVec2(x + (side - ts.x) / 2, y + side / 2), IM_COL32(150, 150, 150, 255), t);
  }
  if (view_.paused) {
    const char* t = "PAUSED";
    dl->AddText(ImVec2(x + (side - ImGui::CalcTextSize(t).x) / 2, y + pad), amber, t);
  }
  if (controls_.injecting()) {
    std::snprintf(buf, sizeof buf, "INJECT %.1f ml/s", controls_.inject_flow() / kMl);
    dl->AddText(ImVec2(x + side - ImGui::CalcTextSize(buf).x - pad, y + side - pad - line), amber,
                buf);
  }
  ImGui::End();
  ImGui::PopStyleVar(2);
}

void Viewer::draw_side_panel(float x, float y, float w, float h) {
  ImGui::SetNextWindowPos(ImVec2(x, y));
  ImGui::SetNextWindowSize(ImVec2(w, h));
  ImGui::Begin("Procedure", nullptr,
               ImGuiWindowFlags_NoMove | ImGuiWindowFlags_NoResize | ImGuiWindowFlags_NoCollapse);
  const double wall = (now_us() - session_start_us_) * 1e-6;
  ImGui::Text("Procedure time   %s", clock_text(view_.time).c_str());
  ImGui::Text("Session (wall)   %s", clock_text(wall).c_str());
  ImGui::Text("Fluoroscopy time %s", clock_text(view_.fluoro_time).c_str());
  ImGui::Text("Cine runs        %zu (%zu frames)", cine_.size(), cine_total_);
  ImGui::Text("Contrast used    %.1f ml", view_.contrast_volume / kMl);
  ImGui::Text("Syringe          %.1f ml/s%s", view_.syringe_flow / kMl,
              controls_.injecting() ? "  (injecting)" : "");
  ImGui::Text("Physics lag      %.1f ms%s", view_.lag * 1e3, view_.paused ? "  PAUSED" : "");
  ImGui::Separator();
  ImGui::TextUnformatted("Instruments (Tab / 1-9 select; W/S push/pull, A/D turn)");
  const int n = controls_.num_instruments();
  for (int i = 0; i < n; ++i) {
    const auto u = static_cast<std::size_t>(i);
    char label[128];
    std::snprintf(label, sizeof label, "%d %s%s", i + 1, controls_.name(i).c_str(),
                  u < view_.device_driven.size() && view_.device_driven[u] ? " [device]" : "");
    if (ImGui::RadioButton(label, controls_.selected() == i)) controls_.select(i, now_us());
    const double depth = u < view_.depth.size() ? view_.depth[u] : 0.0;
    const double roll = u < view_.roll.size() ? view_.roll[u] : 0.0;
    const HandFeedback f = u < view_.feedback.size() ? view_.feedback[u] : HandFeedback{};
    ImGui::Text("   %6.1f mm  %7.0f\xc2\xb0  %+5.2f N  %+5.2f N mm", depth * 1e3, roll / kDeg,
                f.axial_force, f.torque * 1e3);
    // The hand force as a bar: full at 2 N (a firm push).
    char overlay[32];
    std::snprintf(overlay, sizeof overlay, "%.2f N", f.axial_force);
    const float frac = static_cast<float>(std::min(1.0, std::abs(f.axial_force) / 2.0));
    ImGui::PushStyleColor(ImGuiCol_PlotHistogram, f.axial_force >= 0
                                                      ? ImVec4(0.9f, 0.55f, 0.2f, 1.0f)
                                                      : ImVec4(0.3f, 0.6f, 0.9f, 1.0f));
    ImGui::ProgressBar(frac, ImVec2(-1, 0), overlay);
    ImGui::PopStyleColor();
  }
  ImGui::Separator();
  ImGui::TextUnformatted("C-arm (J/L RAO-LAO, I/K CAU-CRA, F1-F7 views)");
  ImGui::Text("%s   FOV %.0f cm",
              angles_text(controls_.primary_deg(), controls_.secondary_deg()).c_str(),
              controls_.fov() * 100.0);
  ImGui::Text("Table pan  %+.0f mm L  %+.0f mm H (Ctrl+arrows)", controls_.table_pan().x() * 1e3,
              controls_.table_pan().z() * 1e3);
  for (std::size_t i = 0; i < kViewPresets.size(); ++i) {
    char b[16];
    std::snprintf(b, sizeof b, "F%zu", i + 1);
    if (i > 0) ImGui::SameLine();
    if (ImGui::SmallButton(b)) controls_.set_preset(static_cast<int>(i));
    if (ImGui::IsItemHovered()) ImGui::SetTooltip("%s", kViewPresets[i].name);
  }
  ImGui::Separator();
  float flow = static_cast<float>(controls_.inject_flow() / kMl);
  if (ImGui::SliderFloat("Injection ml/s (hold E)", &flow, 0.5f, 6.0f, "%.1f"))
    controls_.set_inject_flow(flow * kMl);
  float atm = static_cast<float>(controls_.balloon_pressure() / kAtm);
  if (ImGui::SliderFloat("Indeflator atm ([ ])", &atm, 0.0f, 20.0f, "%.1f"))
    controls_.set_balloon(atm * kAtm, now_us());
  if (o_.device) {
    ImGui::Separator();
    ImGui::Text("OpenIGTLink %s:%d  %s", o_.device_address.c_str(), o_.device->port(),
                view_.device.connected ? "connected" : "waiting");
    ImGui::Text("  %llu connections, %llu messages",
                static_cast<unsigned long long>(view_.device.connections),
                static_cast<unsigned long long>(view_.device.messages_accepted));
  }
  const Scenario& sc = scene_model().scenario;
  if (!sc.landmarks.empty()) {
    ImGui::Separator();
    for (std::size_t k = 0; k < sc.landmarks.size(); ++k)
      ImGui::Text("%s %s", k < view_.landmarks.size() && view_.landmarks[k] ? "[x]" : "[ ]",
                  sc.landmarks[k].name.c_str());
  }
  if (!status_.empty() || !view_.message.empty()) {
    ImGui::Separator();
    ImGui::TextWrapped("%s", status_.empty() ? view_.message.c_str() : status_.c_str());
  }
  ImGui::End();
}

void Viewer::draw_menu() {
  if (!ImGui::BeginMainMenuBar()) return;
  if (ImGui::BeginMenu("Session")) {
    if (ImGui::MenuItem(view_.paused ? "Resume" : "Pause", "P"))
      physics_.request(Request::kTogglePause);
    if (ImGui::MenuItem("Rewind 5 s", "B")) physics_.request(Request::kRewind, 5.0);
    if (ImGui::MenuItem("Restart", "Ctrl+R")) physics_.request(Request::kRestart);
    ImGui::Separator();
    if (ImGui::MenuItem("Save cine runs as PNG", "Ctrl+S")) save_cine();
    if (ImGui::MenuItem("Screenshot")) pending_shots_.push_back(out_path("screenshot.png"));
    ImGui::Separator();
    if (ImGui::MenuItem("End session (save)", "Esc")) glfwSetWindowShouldClose(win_, GLFW_TRUE);
    ImGui::EndMenu();
  }
  if (ImGui::BeginMenu("View")) {
    ImGui::MenuItem("Educator's 3D view", "G", &show3d_);
    if (ImGui::MenuItem("Review last cine run", "V", review_)) do_action(Action::kToggleReview);
    ImGui::MenuItem("Keys", "H", &help_);
    ImGui::Separator();
    for (std::size_t i = 0; i < kViewPresets.size(); ++i) {
      char key[8];
      std::snprintf(key, sizeof key, "F%zu", i + 1);
      if (ImGui::MenuItem(kViewPresets[i].name, key)) controls_.set_preset(static_cast<int>(i));
    }
    ImGui::Separator();
    for (std::size_t i = 0; i < kFieldSizesMm.size(); ++i) {
      char name[32];
      std::snprintf(name, sizeof name, "Field %.0f cm", kFieldSizesMm[i] / 10.0);
      if (ImGui::MenuItem(name, nullptr, controls_.field() == static_cast<int>(i)))
        controls_.set_field(static_cast<int>(i));
    }
    ImGui::EndMenu();
  }
  if (ImGui::BeginMenu("Instruments")) {
    for (int i = 0; i < controls_.num_instruments(); ++i) {
      char key[16];
      std::snprintf(key, sizeof key, "%d", i + 1);
      if (ImGui::MenuItem(controls_.name(i).c_str(), key, controls_.selected() == i))
        controls_.select(i, now_us());
    }
    ImGui::Separator();
    // Exchanges (docs/trainer.md): made by the physics thread between two steps and recorded;
    // the engine refuses what cannot be (an instrument still in the patient, one another rides
    // on), and the status line says why.
    const SimModel& md = scene_model();
    const int sel = controls_.selected();
    const auto su = static_cast<std::size_t>(sel);
    if (su < md.specs.size()) {
      const ScenarioInstrument& si = md.scenario.instruments[su];
      const InstrumentKind kind = md.specs[su].kind;
      const bool wire = kind == InstrumentKind::kGuidewire;
      const bool out = su < view_.depth.size() && view_.depth[su] <= 1e-3;
      if (ImGui::BeginMenu("Replace selected by")) {
        for (const InstrumentSpec& spec : catalogue_.items) {
          // A wire by a wire; a catheter by a catheter, balloon or stent system.
          if ((spec.kind == InstrumentKind::kGuidewire) != wire) continue;
          if (ImGui::MenuItem(spec.name.c_str())) {
            if (out)
              ask_replace(sel, spec);
            else
              status_ = "pull " + controls_.name(sel) + " out of the patient first";
          }
          if (ImGui::IsItemHovered()) ImGui::SetTooltip("%s", spec.description.c_str());
        }
        ImGui::EndMenu();
      }
      // Rapid exchange: a balloon or stent catheter rides on the selected wire inside its guide.
      if (ImGui::BeginMenu("Add over selected wire", wire)) {
        for (const InstrumentSpec& spec : catalogue_.items) {
          if (!spec.balloon) continue;
          if (ImGui::MenuItem(spec.name.c_str())) ask_add(spec, si.inside, si.name);
          if (ImGui::IsItemHovered()) ImGui::SetTooltip("%s", spec.description.c_str());
        }
        ImGui::EndMenu();
      }
      if (ImGui::BeginMenu("Add a wire into selected", !wire)) {
        for (const InstrumentSpec& spec : catalogue_.items) {
          if (spec.kind != InstrumentKind::kGuidewire) continue;
          if (ImGui::MenuItem(spec.name.c_str())) ask_add(spec, si.name, "");
          if (ImGui::IsItemHovered()) ImGui::SetTooltip("%s", spec.description.c_str());
        }
        ImGui::EndMenu();
      }
      if (ImGui::MenuItem("Remove selected", nullptr, false, controls_.num_instruments() > 1)) {
        InstrumentChange c;
        c.kind = InstrumentChange::Kind::kRemove;
        c.name = si.name;
        c.source = "trainer";
        c.field = "menu";
        physics_.exchange(c);
        status_ = "asked: " + describe(c);
      }
    }
    ImGui::EndMenu();
  }
  if (ImGui::BeginMenu("Balloon & stent")) {
    // The indeflator's pressure reaches the engine as StepCommands::balloon_pressure (Pa) and is
    // recorded; the procedure layer inflates whichever balloon lies in the patient, and a stent
    // system's stent stays when its balloon deflates (docs/procedure.md).
    for (double a : {0.0, 4.0, 8.0, 12.0, 16.0}) {
      char name[32];
      std::snprintf(name, sizeof name, "Indeflator %.0f atm", a);
      if (ImGui::MenuItem(name, nullptr, std::abs(controls_.balloon_pressure() / kAtm - a) < 0.05))
        controls_.set_balloon(a * kAtm, now_us());
    }
    ImGui::Separator();
    // A balloon-expandable stent deploys by its balloon: inflated to the nominal pressure of the
    // stent system in the scene, then deflated, the stent stays (docs/procedure.md).
    for (std::size_t i = 0; i < scene_model().specs.size(); ++i) {
      const InstrumentSpec& spec = scene_model().specs[i];
      if (!spec.balloon) continue;
      char name[96];
      std::snprintf(name, sizeof name, "%s: nominal %.0f atm",
                    view_.instruments.size() > i ? view_.instruments[i].c_str() : spec.name.c_str(),
                    spec.balloon->nominal_pressure / kAtm);
      if (ImGui::MenuItem(name)) controls_.set_balloon(spec.balloon->nominal_pressure, now_us());
    }
    ImGui::EndMenu();
  }
  char buf[128];
  std::snprintf(buf, sizeof buf, "   %s   %s   FL %s", o_.scenario.name.c_str(),
                clock_text(view_.time).c_str(), clock_text(view_.fluoro_time).c_str());
  ImGui::TextUnformatted(buf);
  ImGui::EndMainMenuBar();
}

void Viewer::draw_ui() {
  int fw = 0, fh = 0;
  glfwGetWindowSize(win_, &fw, &fh);
  draw_menu();
  const float top = ImGui::GetFrameHeight();
  const float side_w = std::min(380.0f, std::max(260.0f, 0.34f * static_cast<float>(fw)));
  const float avail_h = static_cast<float>(fh) - top;
  const float side = std::max(64.0f, std::min(avail_h, static_cast<float>(fw) - side_w));
  draw_fluoro_panel(0.0f, top, side);
  draw_side_panel(side, top, static_cast<float>(fw) - side, avail_h);
  if (show3d_) {
    if (!view3d_) view3d_ = std::make_unique<View3D>(scene_model(), 384);
    view3d_->draw(view_.frame, controls_.selected());
    const float s = std::min(300.0f, 0.45f * side);
    ImGui::SetNextWindowPos(ImVec2(side - s - 8.0f, top + side - s - 30.0f), ImGuiCond_Appearing);
    ImGui::Begin("Educator's 3D view (drag: turn, wheel: zoom)", &show3d_,
                 ImGuiWindowFlags_AlwaysAutoResize | ImGuiWindowFlags_NoScrollWithMouse);
    const ImVec2 p = ImGui::GetCursorScreenPos();
    ImGui::Image(reinterpret_cast<ImTextureID>(static_cast<std::intptr_t>(view3d_->texture())),
                 ImVec2(s, s), ImVec2(0, 1), ImVec2(1, 0));
    view3d_rect_[0] = p.x;
    view3d_rect_[1] = p.y;
    view3d_rect_[2] = p.x + s;
    view3d_rect_[3] = p.y + s;
    ImGui::End();
  }
  if (help_) {
    ImGui::SetNextWindowPos(ImVec2(20, top + 60), ImGuiCond_Appearing);
    ImGui::Begin("Keys", &help_, ImGuiWindowFlags_AlwaysAutoResize);
    ImGui::TextUnformatted(
        "W / S or Up / Down   push / pull the selected instrument (faster the longer held;\n"
        "                     Shift: fine)\n"
        "A / D or Left/Right  turn it\n"
        "Mouse drag on image  push/pull (up/down) and turn (left/right)\n"
        "Tab, 1-9             select the instrument\n"
        "Space (hold)         fluoroscopy pedal (last image hold when released)\n"
        "C (hold)             cine pedal: records a run at 15 fps;  V review;  Ctrl+S save PNGs\n"
        "E (hold)             inject contrast at the set flow\n"
        "J / L, I / K         C-arm RAO / LAO, CAU / CRA;  F1-F7 standard views\n"
        "+ / - (or wheel)     field size;  Ctrl + arrows  table pan\n"
        "[ / ]  \\            indeflator -1 / +1 atm, deflate;  Enter: the stent system's nominal "
        "pressure\n"
        "P pause, B rewind 5 s, Ctrl+R restart, G 3D view, H keys, Esc end and save\n"
        "Gamepad: left stick drive, right stick C-arm, A fluoro, B inject, X cine,\n"
        "         LB/RB select, triggers field size, d-pad table, Back pause, Start rewind");
    ImGui::End();
  }
}

}  // namespace vcsim::trainer
