// Shared helpers for the anatomy tests: the built-in patient's lumen built once per process (and
// cached across processes in the build tree), and slow, obvious reference computations.
#pragma once

#include "vcsim/anatomy.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>

namespace vcsim::test {

// The CLI's default settings and cache directory, so that every test process (and the CLI tests)
// shares one build of each built-in patient's lumen.
inline LumenSettings test_lumen_settings() {
  LumenSettings s;
  s.cache_dir = VCSIM_ANATOMY_TEST_CACHE "/xdg/vcsim/anatomy";
  return s;
}

// Sanitizer builds mesh about fifteen times slower: there, only the default patient's lumen is
// built (the second variant's lumen is checked in release builds).
inline bool skip_second_lumen() {
#ifdef VCSIM_SANITIZE
  return true;
#else
  return false;
#endif
}

inline const VesselTree& patient(PatientVariant v = PatientVariant::kRightDominant) {
  static std::map<PatientVariant, VesselTree> trees;
  auto it = trees.find(v);
  if (it == trees.end()) it = trees.emplace(v, default_patient(v)).first;
  return it->second;
}

inline const Lumen& patient_lumen(PatientVariant v = PatientVariant::kRightDominant) {
  static std::map<PatientVariant, Lumen> lumens;
  auto it = lumens.find(v);
  if (it == lumens.end())
    it = lumens.emplace(v, build_lumen(patient(v), test_lumen_settings())).first;
  return it->second;
}

inline TriangleMesh healthy_mesh(const Lumen& lu) {
  TriangleMesh m = lu.mesh;
  m.vertices = lu.healthy_vertices;
  m.recompute_normals();
  return m;
}

// Distance from p to segment s's swept spheres (negative inside), brute force.
inline double tube_field(const VesselSegment& s, const Vec3& p) {
  double f = std::numeric_limits<double>::infinity();
  for (std::size_t i = 0; i + 1 < s.points.size(); ++i) {
    const Vec3 d = s.points[i + 1] - s.points[i];
    const double t = std::clamp((p - s.points[i]).dot(d) / d.squaredNorm(), 0.0, 1.0);
    f = std::min(
        f, (p - s.points[i] - t * d).norm() - (s.radii[i] + t * (s.radii[i + 1] - s.radii[i])));
  }
  return f;
}

}  // namespace vcsim::test
