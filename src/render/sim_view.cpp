// A simulation seen by fluoroscopy: the simulator's anatomy, contrast and instruments drawn by
// the path-length renderer (docs/rendering.md).
#include <algorithm>

#include "vcsim/render.h"

namespace vcsim {

InstrumentVisual instrument_visual(const InstrumentSpec& spec, const std::string& name) {
  InstrumentVisual v;
  v.name = name;
  v.radii = {0.5 * spec.outer_diameter};
  const InstrumentRadiopacity& r = spec.radiopacity;
  // The tube is drawn solid, so the catalogue's attenuation (of the shaft as a whole, or of the
  // coil) becomes a fill fraction of the renderer's material with the same line integral.
  auto fill = [](double mu, XrayMaterial m) {
    return mu > 0.0
               ? static_cast<float>(std::min(1.0, mu / attenuation_per_m(m, BeamEnergy::k60keV)))
               : 1.0f;
  };
  v.shaft = spec.kind != InstrumentKind::kGuidewire || r.material != "nitinol"
                ? XrayMaterial::kSteel  // a catheter's braid and filled polymer, or a steel core
                : XrayMaterial::kNitinol;
  v.shaft_fill = fill(r.attenuation_60kev, v.shaft);
  v.radiopaque_length = r.coil_length;
  v.radiopaque = XrayMaterial::kPtIr;
  v.radiopaque_fill = fill(r.coil_attenuation_60kev, XrayMaterial::kPtIr);
  v.marker_from_tip = r.markers;
  return v;
}

namespace {

TriangleMesh placeholder_tube() {
  const std::vector<Vec3> p = {Vec3::Zero(), Vec3(0, 0, 1e-3)};
  const std::vector<double> r = {1e-4};
  return tube_mesh(p, r);
}

}  // namespace

SimFluoroscopy::SimFluoroscopy(const SimModel& md, int size, BeamEnergy energy)
    : renderer_(size), motion_(md.motion ? &*md.motion : nullptr) {
  renderer_.set_beam_energy(energy);
  const XrayMesh lumen = lumen_xray_mesh(md.lumen);
  lumen_rest_ = lumen.mesh.vertices;
  lumen_ = renderer_.add_mesh(lumen);
  for (const XrayMesh& m : body_xray_meshes(build_body_context(md.tree)))
    renderer_.set_static(renderer_.add_mesh(m), true);
  for (int i = 0; i < md.num_instruments(); ++i)
    instruments_.push_back(make_slots(md.specs[i], md.instrument_name(i)));
}

SimFluoroscopy::Slots SimFluoroscopy::make_slots(const InstrumentSpec& spec,
                                                 const std::string& name) {
  const TriangleMesh ph = placeholder_tube();
  Slots s;
  s.visual = instrument_visual(spec, name);
  s.catalogue = spec.name;
  s.shaft =
      renderer_.add_mesh({s.visual.name + "_shaft", ph, s.visual.shaft, s.visual.shaft_fill, {}});
  if (s.visual.radiopaque_length > 0.0)
    s.radiopaque = renderer_.add_mesh(
        {s.visual.name + "_radiopaque", ph, s.visual.radiopaque, s.visual.radiopaque_fill, {}});
  for (std::size_t k = 0; k < s.visual.marker_from_tip.size(); ++k)
    s.markers.push_back(
        renderer_.add_mesh({s.visual.name + "_marker", ph, XrayMaterial::kPtIr, 1.0f, {}}));
  return s;
}

void SimFluoroscopy::reslot(const SimModel& md) {
  std::vector<Slots> all = std::move(instruments_);
  for (Slots& s : spare_) all.push_back(std::move(s));
  spare_.clear();
  instruments_.clear();
  std::vector<unsigned char> used(all.size(), 0);
  for (int i = 0; i < md.num_instruments(); ++i) {
    std::size_t k = 0;
    while (k < all.size() && (used[k] || all[k].visual.name != md.instrument_name(i) ||
                              all[k].catalogue != md.specs[i].name))
      ++k;
    if (k < all.size()) {
      used[k] = 1;
      instruments_.push_back(std::move(all[k]));
    } else {
      instruments_.push_back(make_slots(md.specs[i], md.instrument_name(i)));
    }
  }
  for (std::size_t k = 0; k < all.size(); ++k) {
    if (used[k]) continue;
    for (int id : {all[k].shaft, all[k].radiopaque})
      if (id >= 0) renderer_.set_visible(id, false);
    for (int id : all[k].markers) renderer_.set_visible(id, false);
    spare_.push_back(std::move(all[k]));
  }
}

FrameSnapshot snapshot(const SimModel& md, const SimState& st) {
  FrameSnapshot f;
  f.time = st.time();
  f.contrast = st.contrast.concentration;
  f.model = st.model;
  f.nodes.resize(md.num_instruments());
  for (int i = 0; i < md.num_instruments(); ++i) {
    const InstrumentState& in = st.solver.instruments[i];
    if (in.drive.depth <= 1e-3) continue;
    // The part inside the body, from the node at the access point on.
    const int first = std::max(0, in.drive.first_free - 1);
    f.nodes[i].assign(in.rod.x.begin() + first, in.rod.x.end());
  }
  return f;
}

FrameSnapshot snapshot(const Simulator& sim) {
  return snapshot(sim.model(), sim.state());
}

void SimFluoroscopy::frame(const Simulator& sim, const CArmPose& pose,
                           const ImageChainSettings& chain, std::vector<std::uint8_t>& out) {
  frame(snapshot(sim), pose, chain, out);
}

void SimFluoroscopy::frame(const FrameSnapshot& snap, const CArmPose& pose,
                           const ImageChainSettings& chain, std::vector<std::uint8_t>& out) {
  if (motion_) {
    lumen_now_.resize(lumen_rest_.size());
    for (std::size_t v = 0; v < lumen_rest_.size(); ++v)
      lumen_now_[v] = lumen_rest_[v] + motion_->displacement(lumen_rest_[v], snap.time);
    renderer_.update_vertices(lumen_, lumen_now_);
  }
  renderer_.set_group_concentration(snap.contrast);
  if (snap.model && snap.model != slotted_) {
    reslot(*snap.model);
    slotted_ = snap.model;
  }
  for (std::size_t i = 0; i < instruments_.size(); ++i) {
    Slots& s = instruments_[i];
    s.visual.nodes = i < snap.nodes.size() ? snap.nodes[i] : std::vector<Vec3>{};
    std::vector<XrayMesh> meshes;
    if (s.visual.nodes.size() >= 2) meshes = instrument_xray_meshes(s.visual);
    std::size_t next = 0;
    auto assign = [&](int id, const std::string& suffix) {
      if (id < 0) return;
      if (next < meshes.size() && meshes[next].name == s.visual.name + suffix) {
        renderer_.update_mesh(id, meshes[next].mesh);
        renderer_.set_visible(id, true);
        ++next;
      } else {
        renderer_.set_visible(id, false);
      }
    };
    assign(s.shaft, "_shaft");
    assign(s.radiopaque, "_radiopaque");
    for (int id : s.markers) assign(id, "_marker");
  }
  renderer_.render(pose);
  renderer_.read_line_integral(line_integral_);
  image_chain(line_integral_, renderer_.size(), chain, out);
}

}  // namespace vcsim
