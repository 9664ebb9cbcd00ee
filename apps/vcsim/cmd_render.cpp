// `vcsim render` (one fluoroscopy frame of the default patient as a PNG) and `vcsim bench render`
// (frame time: draw, readback and image chain) through a headless EGL context.
#include <cmath>
#include <fstream>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "commands.h"
#include "vcsim/anatomy.h"
#include "vcsim/render.h"

namespace vcsim::app {

namespace {

struct RenderOptions {
  std::string out;
  int size = 512;
  double primary_deg = 40.0;  // spider view: LAO 40 / CAU 30
  double secondary_deg = -30.0;
  double fov_mm = 200.0;
  double dose = 1e4;
  double contrast = 1.0;
  int energy_kev = 60;
  std::uint64_t seed = 1;
  int frames = 30;  // bench
  bool json = false;
};

// Checks the command-line values; InputError names the option.
CArmPose checked_pose(const RenderOptions& o, const std::string& cmd) {
  if (o.size != 512 && o.size != 1024)
    throw InputError(cmd, "--size", "expected 512 or 1024, got " + std::to_string(o.size));
  require_finite(o.primary_deg, cmd, "--primary");
  if (std::abs(o.primary_deg) > kPrimaryLimitDeg)
    throw InputError(cmd, "--primary", "expected degrees in [-120, 120] (+ LAO, - RAO)");
  require_finite(o.secondary_deg, cmd, "--secondary");
  if (std::abs(o.secondary_deg) > kSecondaryLimitDeg)
    throw InputError(cmd, "--secondary", "expected degrees in [-60, 60] (+ CRA, - CAU)");
  require_finite(o.fov_mm, cmd, "--fov-mm");
  if (o.fov_mm < 50.0 || o.fov_mm > 500.0)
    throw InputError(cmd, "--fov-mm", "expected a detector field of 50 to 500 mm");
  require_nonnegative(o.dose, cmd, "--dose");
  require_finite(o.contrast, cmd, "--contrast");
  if (o.contrast < 0.0 || o.contrast > 1.0)
    throw InputError(cmd, "--contrast", "expected a fraction of 350 mgI/ml in [0, 1]");
  if (o.energy_kev != 60 && o.energy_kev != 80)
    throw InputError(cmd, "--energy-kev", "expected 60 or 80");
  if (o.frames < 1 || o.frames > 10000) throw InputError(cmd, "--frames", "expected 1 to 10000");
  CArmPose pose;
  pose.primary_deg = o.primary_deg;
  pose.secondary_deg = o.secondary_deg;
  pose.fov = o.fov_mm * 1e-3;
  pose.validate(cmd);
  return pose;
}

// The default patient: lumen with contrast in the left coronary tree, body context, instruments.
struct Scene {
  VesselTree tree;
  std::vector<InstrumentVisual> instruments;
  int wire_mesh = -1;
};

Scene load_scene(FluoroRenderer& r, float contrast) {
  Scene s;
  s.tree = default_patient();
  const Lumen lumen = build_lumen(s.tree);
  r.add_mesh(lumen_xray_mesh(lumen));
  // The body does not move between frames (no respiration yet): drawn once per C-arm pose.
  for (const XrayMesh& m : body_xray_meshes(build_body_context(s.tree)))
    r.set_static(r.add_mesh(m), true);
  s.instruments = demo_instruments(s.tree);
  for (const InstrumentVisual& inst : s.instruments)
    for (const XrayMesh& m : instrument_xray_meshes(inst)) {
      const int id = r.add_mesh(m);
      if (m.name == "guidewire_shaft") s.wire_mesh = id;
    }
  r.set_group_concentration(left_coronary_contrast(s.tree, contrast));
  return s;
}

void apply(const RenderOptions& o, FluoroRenderer& r, CArmPose& pose, const Scene& s,
           ImageChainSettings& chain) {
  // The table is panned so that the left coronary tree (its centreline points' mean) is at the
  // isocentre, as an operator centres the vessels of interest.
  pose.isocentre = left_coronary_centre(s.tree);
  r.set_beam_energy(o.energy_kev == 80 ? BeamEnergy::k80keV : BeamEnergy::k60keV);
  chain.dose = o.dose;
  chain.seed = o.seed;
}

int cmd_render(const RenderOptions& o) {
  CArmPose pose = checked_pose(o, "render");
  if (o.out.empty()) throw InputError("render", "--out", "expected a PNG path");
  // Refuse an unwritable path before the lumen is built and the frame drawn.
  if (!std::ofstream(o.out, std::ios::binary))
    throw InputError("render", "--out", "expected a writable path, got '" + o.out + "'");
  HeadlessGlContext gl;
  FluoroRenderer r(o.size);
  const Scene s = load_scene(r, static_cast<float>(o.contrast));
  ImageChainSettings chain;
  apply(o, r, pose, s, chain);
  r.render(pose);
  std::vector<float> p;
  r.read_line_integral(p);
  std::vector<std::uint8_t> img;
  image_chain(p, o.size, chain, img);
  write_png_grey(o.out, img, o.size, o.size);
  std::cout << "render: wrote " << o.out << " (" << o.size << "x" << o.size << ", primary "
            << o.primary_deg << " deg, secondary " << o.secondary_deg << " deg, " << gl.renderer()
            << ")\n";
  return 0;
}

int bench_render(const RenderOptions& o) {
  CArmPose pose = checked_pose(o, "bench render");
  HeadlessGlContext gl;
  FluoroRenderer r(o.size);
  Scene s = load_scene(r, static_cast<float>(o.contrast));
  ImageChainSettings chain;
  apply(o, r, pose, s, chain);
  // The guidewire is re-meshed and re-uploaded every frame, as a moving instrument would be.
  const InstrumentVisual* wire = nullptr;
  for (const auto& inst : s.instruments)
    if (inst.name == "guidewire") wire = &inst;
  std::vector<float> p;
  std::vector<std::uint8_t> img;
  std::vector<double> total, draw, chain_ms;
  for (int f = -2; f < o.frames; ++f) {
    const double t0 = now_us();
    if (wire && s.wire_mesh >= 0) r.update_mesh(s.wire_mesh, tube_mesh(wire->nodes, wire->radii));
    r.render(pose);
    r.read_line_integral(p);
    const double t1 = now_us();
    chain.seed = o.seed + static_cast<std::uint64_t>(f + 2);
    image_chain(p, o.size, chain, img);
    const double t2 = now_us();
    if (f < 0) continue;  // warm-up
    total.push_back((t2 - t0) * 1e-3);
    draw.push_back((t1 - t0) * 1e-3);
    chain_ms.push_back((t2 - t1) * 1e-3);
  }
  const nlohmann::json j = {{"size", o.size},
                            {"frames", o.frames},
                            {"renderer", gl.renderer()},
                            {"frame_ms_median", median(total)},
                            {"draw_readback_ms_median", median(draw)},
                            {"image_chain_ms_median", median(chain_ms)}};
  if (o.json) {
    std::cout << j.dump(2) << "\n";
  } else {
    std::cout << "| size | frame (ms, median) | draw + readback | image chain | renderer |\n"
              << "|---|---|---|---|---|\n"
              << "| " << o.size << " | " << j["frame_ms_median"] << " | "
              << j["draw_readback_ms_median"] << " | " << j["image_chain_ms_median"] << " | "
              << gl.renderer() << " |\n";
  }
  return 0;
}

void add_view_options(CLI::App* cmd, RenderOptions& o) {
  cmd->add_option("--size", o.size, "Image size in pixels: 512 or 1024");
  cmd->add_option("--primary", o.primary_deg, "C-arm primary angle, deg (+ LAO, - RAO)");
  cmd->add_option("--secondary", o.secondary_deg, "C-arm secondary angle, deg (+ CRA, - CAU)");
  cmd->add_option("--fov-mm", o.fov_mm, "Detector field of view, mm (zoom)");
  cmd->add_option("--dose", o.dose, "Photons per pixel before the patient (0: no noise)");
  cmd->add_option("--contrast", o.contrast, "Contrast in the left coronaries, 0..1 of 350 mgI/ml");
  cmd->add_option("--energy-kev", o.energy_kev, "Effective beam energy: 60 or 80 keV");
  cmd->add_option("--seed", o.seed, "Noise seed");
}

void install(CLI::App& app, int& status) {
  auto opt = std::make_shared<RenderOptions>();
  auto* cmd = app.add_subcommand("render", "Render a fluoroscopy frame of the default patient");
  cmd->add_option("--out", opt->out, "PNG file to write")->required();
  add_view_options(cmd, *opt);
  cmd->callback([opt, &status] { status = cmd_render(*opt); });

  auto bopt = std::make_shared<RenderOptions>();
  auto* bench = bench_group(app).add_subcommand("render", "Time a fluoroscopy frame");
  add_view_options(bench, *bopt);
  bench->add_option("--frames", bopt->frames, "Timed frames");
  bench->add_flag("--json", bopt->json, "Print JSON");
  bench->callback([bopt, &status] { status = bench_render(*bopt); });
}

const int kRegistered = register_command(60, install);

}  // namespace

}  // namespace vcsim::app
