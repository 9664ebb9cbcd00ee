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

  SolverSettings& s = sc.settings;
  s.rod.dt = o.dt;
  set_quasi_static_damping(s.rod);
  s.rod.gravity = o.gravity ? Vec3(0, -9.81, 0) : Vec3::Zero();
  s.collisions = o.collisions;
  Discretisation disc;
  disc.max_nodes = o.nodes;
  for (const auto* spec : {&wire, &cath}) {
    RodDef def = to_rod_def(*spec, disc);
    def.base = BoundaryKind::kFree;  // the sheath drive holds the proximal part
    def.tip = BoundaryKind::kFree;
    ContactMaterial mat{spec->friction.vessel_static, spec->friction.vessel_dynamic};
    const double depth = spec == &wire ? o.wire_depth : o.catheter_depth;
    sc.instruments.push_back(make_instrument(def, Sheath{}, mat, depth));
    // Quasi-static, as in the simulator: each node and frame only as heavy as the explicit step
    // needs (physics.md 5.4). Scaling the whole rod's density for its finest segment instead
    // made the shaft hundreds of times too heavy, and the shaft snaked and the tip folded.
    scale_for_time_step(sc.instruments.back().model, o.dt, kQuasiStaticKpRatio);
  }
  Coupling c;
  c.inner = 0;
  c.outer = 1;
  c.mu = cath.friction.lumen;
  c.contacts.reserve(sc.instruments[0].model.n);
  sc.couplings.push_back(std::move(c));
  s.validate("pair");
  return sc;
}

}  // namespace vcsim
