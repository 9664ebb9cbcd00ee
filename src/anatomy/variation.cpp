// Anatomy variations for domain randomisation (docs/anatomy.md, "Variations"): the built-in
// patient's vessels scaled in calibre, the ascending aorta and arch lengthened upward, and the
// whole tree bent by a smooth random displacement field (tortuosity). One smooth field of space
// moves every centreline point, so a branch's first point stays where its parent is.
#include <algorithm>
#include <cmath>
#include <set>
#include <sstream>

#include "vcsim/anatomy.h"
#include "vcsim/core.h"
#include "vcsim/units.h"

namespace vcsim {

namespace {
std::string num(double v) {
  std::ostringstream o;
  o << v;
  return o.str();
}
}  // namespace

void AnatomyVariation::validate(const std::string& source) const {
  auto in = [&](const char* field, double v, double lo, double hi, const char* unit) {
    if (!std::isfinite(v) || v < lo || v > hi)
      throw InputError(source, field,
                       "expected " + num(lo) + " to " + num(hi) + unit + ", got " + num(v));
  };
  in("aorta_radius_scale", aorta_radius_scale, 0.5, 1.5, "");
  in("artery_radius_scale", artery_radius_scale, 0.5, 1.5, "");
  in("coronary_radius_scale", coronary_radius_scale, 0.7, 1.3, "");
  in("arch_elongation", arch_elongation, 0.0, 40e-3, " m");
  in("tortuosity", tortuosity, 0.0, 8e-3, " m");
  in("tortuosity_wavelength", tortuosity_wavelength, 40e-3, 400e-3, " m");
}

namespace {

// A smooth random vector field: a sum of plane waves sin(k . p + phase) along random directions,
// each displacing perpendicular to its wave vector (so the field bends centrelines rather than
// compressing them), normalised to `amplitude` in root-mean-square per component.
struct WaveField {
  struct Wave {
    Vec3 k, dir;
    double phase = 0.0;
  };
  std::vector<Wave> waves;
  double amplitude = 0.0;

  WaveField(double amp, double wavelength, std::uint64_t seed) : amplitude(amp) {
    Random rng{seed * 0x9E3779B97F4A7C15ull + 0x5EEDull};
    auto unit = [&] {
      for (;;) {
        const Vec3 v(2 * rng.uniform() - 1, 2 * rng.uniform() - 1, 2 * rng.uniform() - 1);
        const double n = v.norm();
        if (n > 0.1 && n <= 1.0) return Vec3(v / n);
      }
    };
    constexpr int kWaves = 6;
    for (int i = 0; i < kWaves; ++i) {
      Wave w;
      // Wavelengths from 0.75 to 1.5 times the nominal one.
      const double lambda = wavelength * (0.75 + 0.75 * rng.uniform());
      const Vec3 n = unit();
      w.k = n * (2 * kPi / lambda);
      Vec3 d = unit();
      d -= d.dot(n) * n;
      w.dir = d.normalized();
      w.phase = 2 * kPi * rng.uniform();
      waves.push_back(w);
    }
  }
  Vec3 operator()(const Vec3& p) const {
    Vec3 u = Vec3::Zero();
    for (const Wave& w : waves) u += std::sin(w.k.dot(p) + w.phase) * w.dir;
    // sin has rms 1/sqrt(2); the sum of n unit waves has rms sqrt(n / 2) over space.
    return u * (amplitude / std::sqrt(static_cast<double>(waves.size()) / 2.0));
  }
};

double smoothstep(double x) {
  x = std::clamp(x, 0.0, 1.0);
  return x * x * (3 - 2 * x);
}

}  // namespace

VesselTree vary_anatomy(const VesselTree& tree, const AnatomyVariation& v) {
  v.validate("anatomy variation");
  const bool moves = v.arch_elongation > 0.0 || v.tortuosity > 0.0;
  if (moves && tree.heart)
    throw InputError("anatomy variation", tree.heart ? "arch_elongation" : "tortuosity",
                     "expected 0 for an anatomy with a heart (its coronaries ride on the heart's "
                     "surface and move with it); vary the calibre only");
  VesselTree out = tree;
  for (VesselSegment& s : out.segments) {
    const double scale = s.kind == VesselKind::kAorta      ? v.aorta_radius_scale
                         : s.kind == VesselKind::kArtery   ? v.artery_radius_scale
                         : s.kind == VesselKind::kCoronary ? v.coronary_radius_scale
                                                           : v.aorta_radius_scale;
    for (double& r : s.radii) r *= scale;
  }
  if (!moves) return out;

  // Elongation: points above the sinotubular junction rise by up to arch_elongation, fully from
  // the top of the arch up (the supra-aortic branches move with their origins).
  double z0 = 0.0, z1 = 0.0;
  const int root = out.find("aortic_root");
  const int arch = out.find("aortic_arch");
  if (v.arch_elongation > 0.0) {
    if (root < 0 || arch < 0)
      throw InputError("anatomy variation", "arch_elongation",
                       "expected an anatomy with segments 'aortic_root' and 'aortic_arch'");
    z0 = out.segments[root].points.back().z();
    z1 = z0;
    for (const Vec3& p : out.segments[arch].points) z1 = std::max(z1, p.z());
    if (z1 <= z0 + 1e-3) z1 = z0 + 1e-3;
  }
  const WaveField field(v.tortuosity, v.tortuosity_wavelength, v.seed);
  auto move = [&](const Vec3& p) {
    Vec3 q = p;
    if (v.arch_elongation > 0.0) q.z() += v.arch_elongation * smoothstep((p.z() - z0) / (z1 - z0));
    if (v.tortuosity > 0.0) q += field(p);
    return q;
  };
  for (VesselSegment& s : out.segments)
    for (Vec3& p : s.points) p = move(p);
  // Sinuses (short closed lobes) keep their shape: move them rigidly with their first point.
  for (std::size_t i = 0; i < out.segments.size(); ++i) {
    VesselSegment& s = out.segments[i];
    if (s.kind != VesselKind::kSinus) continue;
    const VesselSegment& orig = tree.segments[i];
    const Vec3 shift = s.points.front() - orig.points.front();
    for (std::size_t k = 0; k < s.points.size(); ++k) s.points[k] = orig.points[k] + shift;
  }
  // The access and target keep their arc length, within their (changed) segment.
  for (TreeLocation* loc : {&out.access, &out.target}) {
    if (loc->segment < 0) continue;
    loc->distance = std::min(loc->distance, segment_length(out.segments[loc->segment]) - 1e-3);
  }
  validate_tree(out, "anatomy variation");
  return out;
}

VesselTree arch_anatomy(PatientVariant variant) {
  const VesselTree full = default_patient(variant);
  static const std::set<std::string> keep = {
      "aortic_root",         "ascending_aorta",     "aortic_arch",     "thoracic_aorta",
      "brachiocephalic",     "left_common_carotid", "left_subclavian", "right_coronary_sinus",
      "left_coronary_sinus", "noncoronary_sinus"};
  VesselTree t;
  t.name = full.name + " (aortic arch)";
  std::vector<int> index(full.segments.size(), -1);
  for (std::size_t i = 0; i < full.segments.size(); ++i) {
    const VesselSegment& s = full.segments[i];
    if (!keep.count(s.name)) continue;
    if (s.parent >= 0 && index[static_cast<std::size_t>(s.parent)] < 0) continue;
    VesselSegment c = s;
    c.parent = s.parent >= 0 ? index[static_cast<std::size_t>(s.parent)] : -1;
    index[i] = static_cast<int>(t.segments.size());
    t.segments.push_back(std::move(c));
  }
  t.open_start = full.open_start;
  // Instruments enter the descending thoracic aorta 60 % down its length (about 120 mm below the
  // arch), as in stEVE's arch benchmark, whose wire starts in the descending aorta.
  const int desc = t.find("thoracic_aorta");
  t.access = {desc, 0.6 * segment_length(t.segments[static_cast<std::size_t>(desc)])};
  t.target = {t.find("left_common_carotid"), 0.0};
  validate_tree(t, "arch anatomy");
  return t;
}

}  // namespace vcsim
