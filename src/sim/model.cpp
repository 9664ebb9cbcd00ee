// The model of a scene: built once from a scenario (the anatomy and its wall, then the
// instruments at the femoral sheath), or rebuilt around the same anatomy when an exchange changes
// the instruments (docs/architecture.md, "Instrument exchange").
#include <algorithm>
#include <string>

#include "plan.h"
#include "vcsim/mesh_io.h"
#include "vcsim/sim.h"
#include "vcsim/units.h"

namespace vcsim {

namespace {

VesselTree load_anatomy(const Scenario& sc) {
  const std::string& a = sc.anatomy;
  if (is_mesh_file(a)) {
    const std::filesystem::path mesh = sc.base_dir / a;
    if (!std::filesystem::exists(mesh))
      throw InputError(sc.source, "anatomy",
                       "expected a file, '" + mesh.string() + "' does not exist");
    if (sc.centrelines.empty()) {
      // Computed from the mesh, from the opening nearest the given inlet point.
      MeshLoadOptions mo;
      mo.unit_scale = sc.mesh_unit;
      return centrelines_from_mesh(load_mesh(mesh.string(), mo), *sc.inlet, mesh.string());
    }
    const std::filesystem::path cl = sc.base_dir / sc.centrelines;
    if (!std::filesystem::exists(cl))
      throw InputError(sc.source, "centrelines",
                       "expected a file, '" + cl.string() + "' does not exist");
    return load_mesh_centrelines(cl.string(), mesh.string(), sc.mesh_unit);
  }
  const bool file = a.size() > 5 && a.substr(a.size() - 5) == ".json";
  if (!file) return default_patient(patient_variant_from_string(a, sc.source + ": anatomy"));
  const std::filesystem::path p = sc.base_dir / a;
  if (!std::filesystem::exists(p))
    throw InputError(sc.source, "anatomy",
                     "expected an anatomy file, '" + p.string() + "' does not exist");
  return load_vessel_tree(p.string());
}

int segment_named(const VesselTree& t, const std::string& name, const std::string& src,
                  const std::string& field) {
  const int s = t.find(name);
  if (s < 0) throw InputError(src, field, "no segment named '" + name + "' in the anatomy");
  return s;
}

void hash_tree(StateHasher& h, const VesselTree& t) {
  for (const VesselSegment& s : t.segments) {
    h.add_value(static_cast<int>(s.kind));
    h.add_value(s.parent);
    h.add(s.points);
    h.add(s.radii);
    h.add_value(s.closed_end);
  }
  for (const Lesion& l : t.lesions)
    for (double v : {l.distance, l.length, l.diameter_reduction, l.eccentricity, l.angle})
      h.add_value(v);
  h.add_value(t.access.segment);
  h.add_value(t.access.distance);
  h.add_value(t.open_start);
}

// The introducer sheath at the tree's access, pointing along the vessel toward the heart
// (retrograde, against the centreline's flow direction), or into it from an inlet. Its straight
// part in the femoral artery holds what passes through it on the axis; its lumen is set by the
// widest instrument.
Sheath make_sheath(const VesselTree& tree, double length) {
  const VesselSegment& acc = tree.segments[tree.access.segment];
  Sheath sheath;
  sheath.access_point = point_at(acc, tree.access.distance);
  // At an inlet (the root's open start: a phantom's or a segmented patient's cut end, within the
  // first half of the root) the instruments go in with the flow, into the vessel; elsewhere
  // against it, toward the heart.
  const bool inlet =
      acc.parent < 0 && tree.open_start && tree.access.distance < 0.5 * segment_length(acc);
  const Vec3 axis =
      inlet ? tangent_at(acc, tree.access.distance) : Vec3(-tangent_at(acc, tree.access.distance));
  sheath.frame = Quat::FromTwoVectors(Vec3::UnitZ(), axis).normalized();
  sheath.length = length;
  return sheath;
}

// A 6F sheath for a 6F catheter: 0.2 mm of play across.
double sheath_radius_for(std::span<const InstrumentSpec> specs) {
  double widest = 0.0;
  for (const InstrumentSpec& sp : specs) widest = std::max(widest, sp.outer_diameter);
  return 0.5 * widest + 0.1e-3;
}

// Each instrument's catalogue entry, and the nesting the specs allow (a lumen wider than what runs
// in it).
std::vector<InstrumentSpec> resolve_specs(std::span<const ScenarioInstrument> list,
                                          const InstrumentCatalogue& cat, const std::string& src,
                                          const std::function<std::string(int)>& field_of) {
  std::vector<InstrumentSpec> specs;
  for (std::size_t i = 0; i < list.size(); ++i) {
    const InstrumentSpec* s = cat.find(list[i].catalogue);
    if (!s)
      throw InputError(src, field_of(static_cast<int>(i)) + ".catalogue",
                       "expected an entry of " + default_catalogue_dir().string() + ", got '" +
                           list[i].catalogue + "'");
    specs.push_back(*s);
  }
  for (std::size_t i = 0; i < list.size(); ++i) {
    const int w = find_instrument_in(list, list[i].over);
    if (w >= 0 && specs[i].inner_diameter <= specs[w].outer_diameter)
      throw InputError(src, field_of(static_cast<int>(i)) + ".over",
                       "expected a wire thinner than the instrument's lumen: '" + specs[i].name +
                           "' has ID " + std::to_string(specs[i].inner_diameter / kMm) + " mm, '" +
                           specs[w].name + "' OD " + std::to_string(specs[w].outer_diameter / kMm) +
                           " mm");
    const int o = find_instrument_in(list, list[i].inside);
    if (o >= 0 && specs[o].inner_diameter <= specs[i].outer_diameter)
      throw InputError(src, field_of(static_cast<int>(i)) + ".inside",
                       "expected a lumen wider than the instrument: '" + specs[o].name +
                           "' has ID " + std::to_string(specs[o].inner_diameter / kMm) + " mm, '" +
                           specs[i].name + "' OD " + std::to_string(specs[i].outer_diameter / kMm) +
                           " mm");
  }
  return specs;
}

// The instruments part of a model, for md.scenario.instruments with md.specs and md.sheath set:
// the solver model (rods at the sheath, couplings, splits), the nesting and the landmarks'
// instruments by index (-1 for one not in the scene).
void build_instruments(SimModel& md, const std::string& src) {
  const Scenario& sc = md.scenario;
  const std::vector<ScenarioInstrument>& list = sc.instruments;
  md.outer_of.assign(list.size(), -1);
  for (std::size_t i = 0; i < list.size(); ++i)
    md.outer_of[i] = find_instrument_in(list, list[i].inside);
  SolverModel& sv = md.solver;
  SolverSettings s;
  s.rod.dt = sc.dt;
  s.collisions = true;
  s.hand_force = sc.feedback.hand_force;
  s.feedback_cutoff_hz = sc.feedback.cutoff_hz;
  sv.settings = {s};
  for (std::size_t i = 0; i < md.specs.size(); ++i) {
    Discretisation disc;
    disc.max_nodes = list[i].max_nodes;
    disc.tip_segment = list[i].tip_segment;
    RodDef def = to_rod_def(md.specs[i], disc);
    def.base = BoundaryKind::kFree;
    def.tip = BoundaryKind::kFree;
    sv.instruments.push_back(make_instrument_model(
        def, md.sheath,
        ContactMaterial{md.specs[i].friction.vessel_static, md.specs[i].friction.vessel_dynamic}));
  }
  // A wire an instrument rides on runs in that instrument's lumen first (it lies inside the
  // guide both are in), then in the guide's.
  for (std::size_t i = 0; i < list.size(); ++i) {
    const int w = find_instrument_in(list, list[i].over);
    if (w < 0) continue;
    CouplingModel c;
    c.inner = w;
    c.outer = static_cast<int>(i);
    c.mu = md.specs[w].friction.lumen;
    c.rim = list[w].rim;
    sv.couplings.push_back(c);
  }
  for (std::size_t i = 0; i < list.size(); ++i) {
    if (md.outer_of[i] < 0) continue;
    CouplingModel c;
    c.inner = static_cast<int>(i);
    c.outer = md.outer_of[i];
    c.mu = md.specs[i].friction.lumen;
    c.rim = list[i].rim;
    sv.couplings.push_back(c);
  }
  // Quasi-static (physics.md 5.4): each node and frame only as heavy as the explicit step needs,
  // for the scenario's step and for each split of it a fast hand may use.
  make_quasi_static(sv, std::max(1, sc.fine_steps));
  sv.substeps.speed = sc.fine_step_speed;
  sv.substeps.travel = sc.fine_step_travel;
  sv.substeps.jump = sc.fine_step_jump;
  sv.substeps.hold = sc.fine_step_hold;
  sv.substeps.runaway = sc.runaway_speed;
  sv.validate(src);
  md.landmark_ids.clear();
  for (const Landmark& l : sc.landmarks)
    md.landmark_ids.push_back({sc.find_instrument(l.instrument), md.tree.find(l.segment)});
}

// The balloon of instrument i, labelled with its name.
BalloonModel labelled_balloon(const SimModel& md, int i) {
  BalloonModel bm = make_balloon_model(md.solver, md.specs, i);
  bm.label = md.instrument_name(i);
  return bm;
}

}  // namespace

SimModel::SimModel(std::shared_ptr<const SimAnatomy> a)
    : anatomy(std::move(a)),
      tree(anatomy->tree),
      lumen(anatomy->lumen),
      motion(anatomy->motion),
      static_tree(anatomy->static_tree),
      locator(anatomy->locator) {}

std::shared_ptr<const SimModel> build_sim_model(Scenario scenario) {
  VesselTree tree = load_anatomy(scenario);
  return build_sim_model(std::move(scenario), std::move(tree));
}

std::shared_ptr<const SimModel> build_sim_model(Scenario scenario, VesselTree given) {
  const Scenario& sc = scenario;
  const std::string& src = sc.source;
  validate_tree(given, src + ": anatomy");
  auto anatomy = std::make_shared<SimAnatomy>();
  VesselTree& tree = anatomy->tree;
  tree = std::move(given);
  // Check every name before the expensive build.
  const std::vector<std::string> added = internal::plan_additions(sc);
  for (std::size_t i = 0; i < sc.landmarks.size(); ++i) {
    const std::string field = "landmarks[" + std::to_string(i) + "]";
    segment_named(tree, sc.landmarks[i].segment, src, field + ".segment");
    const std::string& inst = sc.landmarks[i].instrument;
    if (sc.find_instrument(inst) < 0 && std::find(added.begin(), added.end(), inst) == added.end())
      throw InputError(src, field + ".instrument",
                       "expected an instrument of the scenario, got '" + inst + "'");
  }
  for (std::size_t i = 0; i < sc.autopilot.size(); ++i) {
    const AutopilotPhase& ph = sc.autopilot[i];
    const std::string field = "autopilot[" + std::to_string(i) + "]";
    if (ph.kind == AutopilotPhase::Kind::kNavigate)
      segment_named(tree, ph.goal_segment, src, field + ".goal.segment");
    if (ph.kind == AutopilotPhase::Kind::kPlace &&
        (ph.lesion < 0 || ph.lesion >= static_cast<int>(tree.lesions.size())))
      throw InputError(
          src, field + ".lesion",
          "expected a lesion of the anatomy (it has " + std::to_string(tree.lesions.size()) + ")");
  }
  if (!sc.lesions.empty() && sc.lesions.size() != tree.lesions.size())
    throw InputError(src, "lesions",
                     "expected one entry per lesion of the anatomy (" +
                         std::to_string(tree.lesions.size()) + "), got " +
                         std::to_string(sc.lesions.size()));
  auto catalogue =
      std::make_shared<const InstrumentCatalogue>(load_catalogue(default_catalogue_dir()));
  auto field_of = [](int i) { return "instruments[" + std::to_string(i) + "]"; };
  std::vector<InstrumentSpec> specs = resolve_specs(sc.instruments, *catalogue, src, field_of);
  // What the autopilot's plan does with balloons needs them, in the scene when it does it.
  internal::walk_plan(sc, [&](std::size_t i, const std::vector<ScenarioInstrument>& scene) {
    const AutopilotPhase& ph = sc.autopilot[i];
    const std::string field = "autopilot[" + std::to_string(i) + "]";
    auto balloon = [&](const ScenarioInstrument& si) {
      const InstrumentSpec* s = catalogue->find(si.catalogue);
      return s && s->balloon;
    };
    if (ph.kind == AutopilotPhase::Kind::kPlace &&
        !balloon(scene[static_cast<std::size_t>(find_instrument_in(scene, ph.instrument))]))
      throw InputError(src, field + ".instrument",
                       "expected a balloon or stent catheter, got '" + ph.instrument + "'");
    if (ph.kind == AutopilotPhase::Kind::kInflate &&
        std::none_of(scene.begin(), scene.end(), balloon))
      throw InputError(src, field, "expected a balloon or stent catheter in the scenario");
    if (ph.kind == AutopilotPhase::Kind::kAdd && !catalogue->find(ph.added.catalogue))
      throw InputError(src, field + ".instrument.catalogue",
                       "expected an entry of " + default_catalogue_dir().string() + ", got '" +
                           ph.added.catalogue + "'");
  });

  anatomy->locator = TreeLocator(tree);
  Lumen& lumen = anatomy->lumen;
  // A mesh as given (a patient's segmentation, a phantom), else built from the centrelines.
  lumen = is_mesh_file(sc.anatomy)
              ? import_lumen((sc.base_dir / sc.anatomy).string(), tree, sc.mesh_unit)
              : build_lumen(tree);
  if (sc.beating && tree.heart) {
    anatomy->motion.emplace(tree, sc.motion);
  } else {
    anatomy->static_tree.build(lumen.mesh, AabbTreeSettings::for_static_mesh());
  }

  auto model = std::make_shared<SimModel>(std::move(anatomy));
  SimModel& md = *model;
  md.scenario = std::move(scenario);
  md.catalogue = std::move(catalogue);
  md.specs = std::move(specs);
  md.sheath = make_sheath(md.tree, md.scenario.sheath_length);
  md.sheath.inner_radius = sheath_radius_for(md.specs);
  build_instruments(md, src);
  md.procedure = make_procedure_model(md.tree, md.lumen, md.solver, md.specs, md.scenario.lesions);
  for (BalloonModel& bm : md.procedure.balloons) bm.label = md.instrument_name(bm.instrument);
  return model;
}

std::shared_ptr<const SimModel> rebuild_sim_model(const SimModel& from,
                                                  std::vector<ScenarioInstrument> instruments,
                                                  const std::string& src,
                                                  const std::function<std::string(int)>& field_of) {
  validate_instruments(instruments, src, field_of);
  auto model = std::make_shared<SimModel>(from.anatomy);
  SimModel& md = *model;
  md.scenario = from.scenario;
  md.scenario.instruments = std::move(instruments);
  md.catalogue = from.catalogue;
  md.specs = resolve_specs(md.scenario.instruments, *md.catalogue, src, field_of);
  // The introducer sheath stays as it was placed, unless a wider instrument must pass.
  md.sheath = from.sheath;
  md.sheath.inner_radius = std::max(from.sheath.inner_radius, sheath_radius_for(md.specs));
  build_instruments(md, src);
  // The lesions as they are; balloons by their index for the whole run: a kept instrument's
  // balloon stays where it was, a removed one's stays removed, an added one's comes after them.
  md.procedure.lesions = from.procedure.lesions;
  md.procedure.spans = from.procedure.spans;
  md.procedure.morph = from.procedure.morph;
  md.procedure.morph_limit = from.procedure.morph_limit;
  std::vector<unsigned char> has(md.specs.size(), 0);
  for (const BalloonModel& old : from.procedure.balloons) {
    const int i = old.removed() ? -1 : md.scenario.find_instrument(old.label);
    if (i < 0) {
      BalloonModel gone = old;
      gone.instrument = -1;
      gone.outers.clear();
      md.procedure.balloons.push_back(std::move(gone));
      continue;
    }
    md.procedure.balloons.push_back(labelled_balloon(md, i));
    has[static_cast<std::size_t>(i)] = 1;
  }
  for (std::size_t i = 0; i < md.specs.size(); ++i)
    if (md.specs[i].balloon && !has[i])
      md.procedure.balloons.push_back(labelled_balloon(md, static_cast<int>(i)));
  return model;
}

std::uint64_t SimModel::hash() const {
  StateHasher h;
  h.add_value(solver.hash());
  hash_tree(h, tree);
  h.add(lumen.mesh.vertices);
  for (const auto& t : lumen.mesh.triangles)
    for (int v : t) h.add_value(v);
  h.add(lumen.mesh.normals);
  for (const AabbNode& n : static_tree.nodes()) {
    h.add_value(n.box.lo);
    h.add_value(n.box.hi);
    h.add_value(n.first);
    h.add_value(n.count);
  }
  h.add(static_tree.triangle_order());
  h.add_value(motion.has_value());
  if (motion) {
    const MotionSettings& m = motion->settings();
    for (double v :
         {m.heart_rate_bpm, m.translation, m.radial_contraction, m.longitudinal_contraction,
          m.twist, m.respiratory_rate_per_min, m.respiratory_shift, m.respiratory_rotation})
      h.add_value(v);
    h.add_value(m.respiration);
  }
  const ContrastSettings& c = scenario.contrast;
  for (double v : {c.blood_flow, c.blood_speed, c.washout, c.concentration}) h.add_value(v);
  for (const auto& [inst, seg] : landmark_ids) {
    h.add_value(inst);
    h.add_value(seg);
  }
  for (const Landmark& l : scenario.landmarks) h.add_value(l.distance);
  h.add(outer_of);
  return h.value();
}

}  // namespace vcsim
