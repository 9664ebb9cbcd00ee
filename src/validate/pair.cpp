// The wire-in-catheter scene (paper Fig. 10): catalogue instruments through one sheath.
#include <numbers>

#include "vcsim/experiments.h"
#include "vcsim/instruments.h"

namespace vcsim {

void PairOptions::validate(const std::string& source) const {
  if (nodes < 16 || nodes > 512) throw InputError(source, "--nodes", "expected 16 .. 512");
  require_positive(dt, source, "--dt");
  require_positive(lumen_radius, source, "lumen_radius");
  require_nonnegative(catheter_depth, source, "catheter_depth");
  require_nonnegative(wire_depth, source, "wire_depth");
}

PairScene make_pair_scene(const PairOptions& o) {
  o.validate("pair");
  const InstrumentCatalogue cat = load_catalogue(
      o.catalogue_dir.empty() ? default_catalogue_dir() : std::filesystem::path(o.catalogue_dir));
  const InstrumentSpec& wire = cat.get(o.wire);
  const InstrumentSpec& cath = cat.get(o.catheter);
  if (cath.inner_diameter <= wire.outer_diameter) {
    throw InputError("pair", "wire", "expected a wire thinner than the catheter's lumen");
  }
  PairScene sc;
  BentTubeSpec tube;
  tube.straight1 = 0.3;
  tube.bend_radius = 0.05;
  tube.bend_angle = std::numbers::pi / 2;
  tube.straight2 = 0.1;
  tube.radius = o.lumen_radius;
  tube.sides = 24;
  tube.ring_spacing = 2e-3;
  sc.mesh = make_bent_tube(tube);
  check_and_repair(sc.mesh, "pair tube");
  sc.tree.build(sc.mesh, AabbTreeSettings::for_static_mesh());

  SolverSettings s;
  s.rod.dt = o.dt;
  s.rod.gravity = o.gravity ? Vec3(0, -9.81, 0) : Vec3::Zero();
  s.collisions = o.collisions;
  sc.model.settings = {s};
  Discretisation disc;
  disc.max_nodes = o.nodes;
  std::vector<InstrumentState> states;
  for (const auto* spec : {&wire, &cath}) {
    RodDef def = to_rod_def(*spec, disc);
    def.base = BoundaryKind::kFree;  // the sheath drive holds the proximal part
    def.tip = BoundaryKind::kFree;
    ContactMaterial mat{spec->friction.vessel_static, spec->friction.vessel_dynamic};
    sc.model.instruments.push_back(make_instrument_model(def, Sheath{}, mat));
  }
  // Quasi-static, as in the simulator: each node and frame only as heavy as the explicit step
  // needs (physics.md 5.4), with its damping. Scaling the whole rod's density for its finest
  // segment instead made the shaft hundreds of times too heavy, and the shaft snaked and the tip
  // folded.
  make_quasi_static(sc.model, 1);
  CouplingModel c;
  c.inner = 0;
  c.outer = 1;
  c.mu = cath.friction.lumen;
  sc.model.couplings.push_back(c);
  sc.model.validate("pair");
  sc.state = make_solver_state(sc.model,
                               {make_instrument_state(sc.model.instruments[0], o.wire_depth),
                                make_instrument_state(sc.model.instruments[1], o.catheter_depth)});
  return sc;
}

}  // namespace vcsim
