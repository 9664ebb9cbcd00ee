// The wall of a simulation: the lumen with its lesions opened as the state has them, and the
// deployed stents inside it (docs/procedure.md, "The wall").
#include <algorithm>
#include <cmath>

#include "sim_scratch.h"

namespace vcsim::internal {

namespace {

// How "deep" a contact is, for choosing between the lumen's and a stent's: behind a wall beats in
// front of one, and nearer beats farther (smaller is deeper).
double key(const SphereContact& c) {
  return c.centre_outside ? -c.distance : c.distance;
}

}  // namespace

void ProcedureWall::query_spheres(std::span<const Vec3> centres, std::span<const double> radii,
                                  std::span<SphereContact> out) {
  lumen->query_spheres(centres, radii, out);
  add_caps(centres, radii, out);
  add_stents(centres, radii, out);
}

void ProcedureWall::query_spheres(std::span<const Vec3> centres, std::span<const double> radii,
                                  std::span<LeafCache* const> caches, double slack,
                                  std::span<SphereContact> out) {
  lumen->query_spheres(centres, radii, caches, slack, out);
  add_caps(centres, radii, out);
  add_stents(centres, radii, out);
}

// A closed end's cap (physics.md 6.4): the hemisphere of the end's radius R on its disc, beyond
// its plane, which the tube's wall meets tangentially at the disc's rim. The mesh has no wall
// there, so a sphere beyond the plane and within R of the axis meets the cap from inside (centre
// within R of the disc's centre) or from behind (farther, as far as the sphere reaches: as the
// mesh's query, a centre deeper behind is "not near"). Beside the disc's cylinder the tube's rim
// and whatever lies beyond are the mesh's.
void ProcedureWall::add_caps(std::span<const Vec3> centres, std::span<const double> radii,
                             std::span<SphereContact> out) {
  const std::span<const WallExit> ends = exits();
  for (std::size_t k = 0; k < ends.size(); ++k) {
    const WallExit& e = ends[k];
    if (!e.closed) continue;
    const double rr = e.radius * e.radius;
    for (std::size_t i = 0; i < centres.size(); ++i) {
      const Vec3 rel = centres[i] - e.centre;
      const double b = rel.dot(e.outward);
      if (b <= 0.0) continue;
      const double d2 = rel.squaredNorm();
      if (d2 - b * b >= rr) continue;
      const double rad = radii.size() == 1 ? radii[0] : radii[i];
      const double rho = std::sqrt(d2);
      if (rho >= e.radius + rad) continue;
      SphereContact c;
      c.centre_outside = rho > e.radius;
      c.distance = std::abs(e.radius - rho);
      c.touching = c.centre_outside || c.distance < rad;
      if (!c.touching) continue;
      c.depth = c.centre_outside ? rad + c.distance : rad - c.distance;
      c.normal = -rel / rho;  // toward the disc's centre: into the lumen
      c.point = e.centre - c.normal * e.radius;
      c.num_touching = 1;
      c.cap = static_cast<int>(k);
      SphereContact& o = out[i];
      if (!o.touching || key(c) < key(o)) o = c;
    }
  }
}

bool ProcedureWall::moves_near(const Vec3& centre, double radius) const {
  if (lumen->moves_near(centre, radius)) return true;
  if (lumen->speed_bound() <= 0.0) return false;
  // A stent's tube is placed where the heart has carried it each step: within its reach of its
  // middle now, plus more than any cardiac displacement (2 cm) for where it may go. So is a
  // moving closed end's cap (a distal coronary's), within its radius of its disc's centre.
  constexpr double kStentTravel = 0.02;
  for (const StentTube& t : stents)
    if ((centre - t.middle).norm() < t.reach + radius + kStentTravel) return true;
  for (std::size_t k = 0; k < exits_rest.size(); ++k) {
    const WallExit& e = exits_rest[k];
    if (e.closed && (exit_amp_c[k].squaredNorm() > 0.0 || exit_amp_r[k].squaredNorm() > 0.0) &&
        (centre - e.centre).norm() < e.radius + radius + kStentTravel)
      return true;
  }
  return false;
}

std::span<const WallExit> ProcedureWall::exits() {
  if (exits_.size() != exits_rest.size()) {
    exits_ = exits_rest;
    exits_time_ = motion ? -1.0 : time_;
  }
  if (motion && exits_time_ != time_) {
    const double c = motion->cardiac_waveform(time_);
    const double r = motion->respiratory_waveform(time_);
    for (std::size_t k = 0; k < exits_.size(); ++k)
      exits_[k].centre = exits_rest[k].centre + c * exit_amp_c[k] + r * exit_amp_r[k];
    exits_time_ = time_;
  }
  return exits_;
}

int access_end(const VesselTree& tree, const Sheath& sheath) {
  const Vec3 axis = sheath.frame * Vec3::UnitZ();
  const std::vector<OpenEnd> ends = open_ends(tree);
  int best = -1;
  double best_d = 0.0;
  for (std::size_t k = 0; k < ends.size(); ++k) {
    const OpenEnd& e = ends[k];
    const double d = (e.centre - sheath.access_point).norm();
    if (e.outward.dot(axis) >= 0.0 || (e.centre - sheath.access_point).dot(axis) > 0.0 ||
        (best >= 0 && d >= best_d))
      continue;
    best = static_cast<int>(k);
    best_d = d;
  }
  return best;
}

void make_exits(const VesselTree& tree, const CardiacMotion* motion, ProcedureWall& wall,
                const Lumen* mesh_lumen, const Sheath* sheath) {
  wall.exits_rest.clear();
  wall.exit_amp_c.clear();
  wall.exit_amp_r.clear();
  auto add = [&](const WallExit& e) {
    wall.exits_rest.push_back(e);
    Vec3 a_c = Vec3::Zero(), a_r = Vec3::Zero();
    if (motion) motion->amplitudes(e.centre, a_c, a_r);
    wall.exit_amp_c.push_back(a_c);
    wall.exit_amp_r.push_back(a_r);
  };
  const std::vector<OpenEnd> ends = open_ends(tree);
  if (!mesh_lumen) {
    // A vessel cut off in the model goes on in a body: what is pushed into it meets resistance,
    // not free space. Only the access end, where the instruments come in, stays open.
    const int open = sheath ? access_end(tree, *sheath) : -1;
    for (std::size_t k = 0; k < ends.size(); ++k) {
      const OpenEnd& e = ends[k];
      const bool access = static_cast<int>(k) == open;
      add({e.centre, e.outward, e.radius, sheath != nullptr && !access, access});
    }
    return;
  }
  // A mesh as given has its own openings (boundary loops), and centrelines drawn or computed for
  // it may end short of them or past them: the openings are the exits. Each tree end takes the
  // nearest opening facing its way (so an escape there keeps the end's name); an end with none
  // (the mesh is closed there) gets an exit that never fires (no outward direction); openings no
  // end took follow.
  const std::vector<WallExit> openings =
      mesh_exits(mesh_lumen->mesh, mesh_lumen->report.boundary_loops);
  std::vector<char> taken(openings.size(), 0);
  for (const OpenEnd& e : ends) {
    int best = -1;
    double best_d = 0.0;
    for (std::size_t k = 0; k < openings.size(); ++k) {
      const double d = (openings[k].centre - e.centre).norm();
      if (taken[k] || openings[k].outward.dot(e.outward) <= 0.0 || (best >= 0 && d >= best_d))
        continue;
      best = static_cast<int>(k);
      best_d = d;
    }
    if (best >= 0) {
      taken[static_cast<std::size_t>(best)] = 1;
      add(openings[static_cast<std::size_t>(best)]);
    } else {
      add({e.centre, Vec3::Zero(), 0.0});
    }
  }
  for (std::size_t k = 0; k < openings.size(); ++k)
    if (!taken[k]) add(openings[k]);
}

Vec3 ProcedureWall::velocity(const SphereContact& hit) const {
  return lumen->velocity(hit);
}

// A stent as a smooth tube along its rings: a sphere whose centre projects inside its span and
// lies within its radius plus the sphere's meets it from inside (a node a strut's width outside is
// behind it: pushed back in); one farther out, or beyond its ends, does not.
void ProcedureWall::add_stents(std::span<const Vec3> centres, std::span<const double> radii,
                               std::span<SphereContact> out) const {
  for (const StentTube& st : stents) {
    const std::size_t k_max = st.centre.size();
    if (k_max < 2) continue;
    for (std::size_t i = 0; i < centres.size(); ++i) {
      const Vec3& p = centres[i];
      const double rad = radii.size() == 1 ? radii[0] : radii[i];
      if ((p - st.middle).norm() > st.reach + rad) continue;
      double best = 1e300, best_t = 0.0;
      std::size_t best_k = 0;
      for (std::size_t k = 0; k + 1 < k_max; ++k) {
        const Vec3 d = st.centre[k + 1] - st.centre[k];
        const double len2 = d.squaredNorm();
        const double t = len2 > 0.0 ? std::clamp((p - st.centre[k]).dot(d) / len2, 0.0, 1.0) : 0.0;
        const double d2 = (st.centre[k] + t * d - p).squaredNorm();
        if (d2 < best) {
          best = d2;
          best_t = t;
          best_k = k;
        }
      }
      // Beyond either end: not within the stent.
      if ((best_k == 0 && best_t <= 0.0) || (best_k + 2 == k_max && best_t >= 1.0)) continue;
      const Vec3 q = st.centre[best_k] + best_t * (st.centre[best_k + 1] - st.centre[best_k]);
      const double r = st.radius[best_k] + best_t * (st.radius[best_k + 1] - st.radius[best_k]);
      const double rho = std::sqrt(best);
      if (rho < 1e-12 || rho > r + rad) continue;
      SphereContact c;
      c.centre_outside = rho > r;
      c.distance = std::abs(r - rho);
      c.touching = c.centre_outside || c.distance < rad;
      if (!c.touching) continue;
      c.depth = c.centre_outside ? rad + c.distance : rad - c.distance;
      c.normal = (q - p) / rho;  // toward the stent's axis: into its lumen
      c.point = q - c.normal * r;
      c.triangle = -1;
      c.num_touching = 1;
      SphereContact& o = out[i];
      if (!o.touching || key(c) < key(o)) o = c;
    }
  }
}

void sync_wall(const SimModel& md, SimState& st, SimScratch& sc, double t1) {
  const ProcedureModel& pm = md.procedure;
  const ProcedureState& ps = st.procedure;
  bool changed = false;
  // The lesions' opening.
  bool same = true;
  for (std::size_t k = 0; k < ps.wall_opening.size() && same; ++k)
    same = ps.wall_opening[k].t == sc.shown_opening[k].t;
  if (!same) {
    morph_positions(md.lumen, pm.morph, ps.wall_opening, sc.morphed);
    if (sc.beating) {
      sc.beating->morph(sc.morphed);
    } else {
      for (std::size_t k = 0; k < pm.morph.vertices.size(); ++k)
        sc.static_mesh.vertices[pm.morph.vertices[k]] = sc.morphed[k];
      TriangleMesh& m = sc.static_mesh;
      for (int t : sc.morph_triangles) {
        const auto& tri = m.triangles[t];
        const Vec3 n = (m.vertices[tri[1]] - m.vertices[tri[0]])
                           .cross(m.vertices[tri[2]] - m.vertices[tri[0]]);
        const double len = n.norm();
        m.normals[t] = len > 0.0 ? Vec3(n / len) : Vec3::Zero();
      }
      sc.static_tree.refit(sc.static_mesh);
    }
    for (std::size_t k = 0; k < ps.wall_opening.size(); ++k)
      sc.shown_opening[k].t = ps.wall_opening[k].t;
    changed = true;
  }
  // The deployed stents: rebuilt when their rings change, moved to t1.
  const double c = md.motion ? md.motion->cardiac_waveform(t1) : 0.0;
  const double r = md.motion ? md.motion->respiratory_waveform(t1) : 0.0;
  for (std::size_t b = 0; b < ps.stents.size(); ++b) {
    const StentState& stent = ps.stents[b];
    StentTube& tube = sc.wall.stents[b];
    if (stent.phase != StentState::Phase::kDeployed) {
      tube.centre.clear();
      continue;
    }
    StateHasher h;
    h.add_value(stent.segment);
    h.add(stent.ring_s);
    h.add(stent.ring_radius);
    if (h.value() != sc.shown_stents[b] || tube.rest.empty()) {
      sc.shown_stents[b] = h.value();
      const std::size_t n = stent.ring_s.size();
      tube.rest.resize(n);
      tube.amp_c.resize(n);
      tube.amp_r.resize(n);
      tube.centre.resize(n);
      tube.radius = stent.ring_radius;
      for (std::size_t k = 0; k < n; ++k) {
        tube.rest[k] =
            lumen_section(md.tree, pm.spans, ps.opening, stent.segment, stent.ring_s[k]).centre;
        if (md.motion) {
          md.motion->amplitudes(tube.rest[k], tube.amp_c[k], tube.amp_r[k]);
        } else {
          tube.amp_c[k].setZero();
          tube.amp_r[k].setZero();
        }
      }
      changed = true;
    }
    Vec3 lo = Vec3::Constant(1e300), hi = Vec3::Constant(-1e300);
    for (std::size_t k = 0; k < tube.rest.size(); ++k) {
      tube.centre[k] = tube.rest[k] + c * tube.amp_c[k] + r * tube.amp_r[k];
      lo = lo.cwiseMin(tube.centre[k]);
      hi = hi.cwiseMax(tube.centre[k]);
    }
    tube.middle = 0.5 * (lo + hi);
    tube.reach = 0.5 * (hi - lo).norm() + *std::max_element(tube.radius.begin(), tube.radius.end());
  }
  if (changed) {
    for (InstrumentState& in : st.solver.instruments) {
      std::fill(in.clearance.begin(), in.clearance.end(), 0.0);
      std::fill(in.sample_clearance.begin(), in.sample_clearance.end(), 0.0);
    }
    sc.solver.clear_caches();
  }
}

}  // namespace vcsim::internal
