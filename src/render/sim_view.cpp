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
    : renderer_(size), model_(&md), motion_(md.motion ? &*md.motion : nullptr) {
  renderer_.set_beam_energy(energy);
  LumenXraySource source;
  const XrayMesh lumen = lumen_xray_mesh(md.lumen, &source);
  lumen_rest_ = lumen.mesh.vertices;
  lumen_ = renderer_.add_mesh(lumen);
  morph_ = make_lumen_xray_morph(source, md.procedure.morph);
  morphed_.resize(md.procedure.morph.vertices.size());
  // A tree without a heart (a test's tube) has no body around it.
  if (md.tree.heart)
    for (const XrayMesh& m : body_xray_meshes(build_body_context(md.tree)))
      renderer_.set_static(renderer_.add_mesh(m), true);
  for (int i = 0; i < md.num_instruments(); ++i)
    instruments_.push_back(make_slots(md.specs[i], md.instrument_name(i)));
  add_procedure_slots(md);
}

void SimFluoroscopy::add_procedure_slots(const SimModel& md) {
  // Balloons (diluted contrast) and stents (struts), hidden until a frame shows them.
  const TriangleMesh ph = placeholder_tube();
  const auto& balloons = md.procedure.balloons;
  for (; balloon_models_ < balloons.size(); ++balloon_models_) {
    const BalloonModel& bm = balloons[balloon_models_];
    balloons_.push_back(
        renderer_.add_mesh({"balloon", ph, XrayMaterial::kIodine, kBalloonContrastFraction, {}}));
    renderer_.set_visible(balloons_.back(), false);
    if (!bm.stent) continue;
    stents_.push_back(renderer_.add_mesh(
        {"stent", ph, XrayMaterial::kCoCr, stent_fill(*bm.stent, renderer_.beam_energy()), {}}));
    renderer_.set_visible(stents_.back(), false);
  }
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
  add_procedure_slots(md);
}

namespace {

// The position at `fd` m from a balloon's distal end along its nodes (bm.from_distal decreases
// from the first node to the last), clamped to the balloon.
Vec3 along_balloon(const BalloonModel& bm, std::span<const Vec3> x, double fd) {
  const std::vector<double>& f = bm.from_distal;
  const std::size_t n = f.size();
  if (fd >= f.front()) return x[0];
  if (fd <= f.back()) return x[n - 1];
  std::size_t j = 0;
  while (j + 2 < n && f[j + 1] > fd) ++j;
  const double u = f[j] > f[j + 1] ? (f[j] - fd) / (f[j] - f[j + 1]) : 0.0;
  return x[j] + u * (x[j + 1] - x[j]);
}

}  // namespace

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
  // The procedure: balloons on their rods' nodes, stents crimped on them or deployed in the
  // vessel (rest anatomy with the lesions as opened, moved with the heart), the lesions' opening.
  const ProcedureModel& pm = md.procedure;
  const ProcedureState& ps = st.procedure;
  f.opening = ps.opening;
  for (std::size_t b = 0; b < pm.balloons.size(); ++b) {
    const BalloonModel& bm = pm.balloons[b];
    const BalloonState& bs = ps.balloons[b];
    // A balloon whose catheter an exchange removed keeps its index (and a deployed stent) but has
    // no rod to be drawn on.
    const InstrumentState* in = bm.removed() ? nullptr : &st.solver.instruments[bm.instrument];
    const bool inside =
        in && !in->parked && in->drive.depth > 1e-3 && bm.first >= in->drive.first_free;
    const std::span<const Vec3> x =
        inside ? std::span<const Vec3>(in->rod.x.data() + bm.first,
                                       static_cast<std::size_t>(bm.nodes()))
               : std::span<const Vec3>();
    BalloonFrame bf;
    bf.instrument = bm.instrument;
    bf.pressure = bs.pressure;
    bf.contrast = bs.pressure > 0.0 ? kBalloonContrastFraction : 0.0f;
    if (inside) {
      bf.nodes.assign(x.begin(), x.end());
      bf.radius = bs.radius;
    }
    f.balloons.push_back(std::move(bf));
    if (!bm.stent) continue;
    const StentState& ss = ps.stents[b];
    StentFrame sf;
    sf.balloon = static_cast<int>(b);
    sf.phase = ss.phase;
    if (ss.phase == StentState::Phase::kDeployed) {
      for (std::size_t k = 0; k < ss.ring_s.size(); ++k) {
        const Vec3 rest =
            lumen_section(md.tree, pm.spans, ps.opening, ss.segment, ss.ring_s[k]).centre;
        sf.rings.push_back(md.motion ? Vec3(rest + md.motion->displacement(rest, f.time)) : rest);
      }
      sf.radius = ss.ring_radius;
    } else if (inside) {
      // On its balloon, each ring as far as the balloon has expanded it (plastic).
      const std::size_t n = ss.expanded.size();
      for (std::size_t k = 0; k < n; ++k) {
        sf.rings.push_back(along_balloon(bm, x, stent_ring_from_distal(bm, k, n)));
        sf.radius.push_back(ss.expanded[k]);
      }
    }
    f.stents.push_back(std::move(sf));
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

void SimFluoroscopy::show_opening(const std::vector<LesionOpening>& opening) {
  // Only when the opening changed, and only the vertices the lesions move.
  const bool as_built = opening.size() != model_->tree.lesions.size();
  if (as_built && shown_opening_.empty()) return;
  if (!as_built && opening.size() == shown_opening_.size() &&
      std::equal(opening.begin(), opening.end(), shown_opening_.begin(),
                 [](const LesionOpening& a, const LesionOpening& b) { return a.t == b.t; }))
    return;
  if (as_built) {
    morph_positions(model_->lumen, model_->procedure.morph, 0.0, morphed_);
    shown_opening_.clear();
  } else {
    morph_positions(model_->lumen, model_->procedure.morph, opening, morphed_);
    shown_opening_ = opening;
  }
  apply_lumen_xray_morph(morph_, morphed_, lumen_rest_);
  if (!motion_) renderer_.update_vertices(lumen_, lumen_rest_);
}

void SimFluoroscopy::frame(const FrameSnapshot& snap, const CArmPose& pose,
                           const ImageChainSettings& chain, std::vector<std::uint8_t>& out) {
  if (snap.model && snap.model != slotted_) {
    // An exchange replaced the model: from now on the renderer reads the snapshot's (which it
    // keeps alive), never the one it was built from.
    reslot(*snap.model);
    slotted_ = snap.model;
    model_ = slotted_.get();
  }
  const SimModel& md = *model_;
  show_opening(snap.opening);
  if (motion_) {
    lumen_now_.resize(lumen_rest_.size());
    for (std::size_t v = 0; v < lumen_rest_.size(); ++v)
      lumen_now_[v] = lumen_rest_[v] + motion_->displacement(lumen_rest_[v], snap.time);
    renderer_.update_vertices(lumen_, lumen_now_);
  }
  renderer_.set_group_concentration(snap.contrast);
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
  // Inflated balloons, filled with diluted contrast.
  for (std::size_t b = 0; b < balloons_.size(); ++b) {
    const BalloonFrame* bf = b < snap.balloons.size() ? &snap.balloons[b] : nullptr;
    bool shown = false;
    if (bf && bf->pressure > 0.0 && bf->nodes.size() >= 2 &&
        bf->radius.size() == bf->nodes.size()) {
      const XrayMesh m = balloon_xray_mesh(bf->nodes, bf->radius, bf->contrast);
      shown = !m.mesh.triangles.empty();
      if (shown) {
        renderer_.update_mesh(balloons_[b], m.mesh);
        renderer_.set_fill(balloons_[b], m.fill);
      }
    }
    renderer_.set_visible(balloons_[b], shown);
  }
  // Stents: a thin wall of struts along their rings.
  for (std::size_t k = 0; k < stents_.size(); ++k) {
    const StentFrame* sf = k < snap.stents.size() ? &snap.stents[k] : nullptr;
    bool shown = false;
    const auto& models = md.procedure.balloons;
    if (sf && sf->rings.size() >= 2 && sf->radius.size() == sf->rings.size() && sf->balloon >= 0 &&
        sf->balloon < static_cast<int>(models.size()) && models[sf->balloon].stent) {
      const StentSpec& spec = *models[sf->balloon].stent;
      const XrayMesh m = stent_xray_mesh(sf->rings, sf->radius, spec.strut_thickness,
                                         stent_fill(spec, renderer_.beam_energy()));
      shown = !m.mesh.triangles.empty();
      if (shown) {
        renderer_.update_mesh(stents_[k], m.mesh);
        renderer_.set_fill(stents_[k], m.fill);
      }
    }
    renderer_.set_visible(stents_[k], shown);
  }
  renderer_.render(pose);
  renderer_.read_line_integral(line_integral_);
  image_chain(line_integral_, renderer_.size(), chain, out);
}

}  // namespace vcsim
