// C-arm geometry from DICOM angles: no GL here, so it is unit-tested on its own.
#include <cmath>
#include <string>

#include "vcsim/render.h"
#include "vcsim/units.h"

namespace vcsim {

namespace {
void require_between(double v, double lo, double hi, const std::string& source,
                     const std::string& field, const std::string& unit) {
  require_finite(v, source, field);
  if (v < lo || v > hi)
    throw InputError(source, field,
                     "expected a value in [" + std::to_string(lo) + ", " + std::to_string(hi) +
                         "] " + unit + ", got " + std::to_string(v));
}
}  // namespace

void CArmPose::validate(const std::string& source) const {
  require_between(primary_deg, -kPrimaryLimitDeg, kPrimaryLimitDeg, source, "primary_deg",
                  "deg (+ LAO, - RAO)");
  require_between(secondary_deg, -kSecondaryLimitDeg, kSecondaryLimitDeg, source, "secondary_deg",
                  "deg (+ CRA, - CAU)");
  require_between(sid, 0.8, 1.5, source, "sid", "m");
  require_between(sod, 0.4, sid - 0.1, source, "sod", "m (and at least 0.1 m below sid)");
  require_between(fov, 0.05, 0.5, source, "fov", "m");
  if (!isocentre.allFinite()) throw InputError(source, "isocentre", "expected finite values");
}

CArmFrame carm_frame(const CArmPose& pose) {
  const double a = pose.primary_deg * kDeg, b = pose.secondary_deg * kDeg;
  // Horizontal direction from the isocentre to the detector: anterior (-y) at 0, toward the
  // patient's left (+x) for LAO. CRA tilts the detector toward the head (+z).
  const Vec3 h(std::sin(a), -std::cos(a), 0.0);
  const Vec3 z = Vec3::UnitZ();
  CArmFrame f;
  f.beam = std::cos(b) * h + std::sin(b) * z;
  f.image_up = -std::sin(b) * h + std::cos(b) * z;
  // Seen from the detector (looking along -beam) with the head up: AP shows the patient's left
  // on the image's right, as angiograms are displayed.
  f.image_right = (-f.beam).cross(f.image_up);
  f.source = pose.isocentre - pose.sod * f.beam;
  f.detector_centre = pose.isocentre + (pose.sid - pose.sod) * f.beam;
  return f;
}

Mat4 carm_view_matrix(const CArmPose& pose) {
  const CArmFrame f = carm_frame(pose);
  Mat4 V = Mat4::Identity();
  V.block<1, 3>(0, 0) = f.image_right.transpose();
  V.block<1, 3>(1, 0) = f.image_up.transpose();
  V.block<1, 3>(2, 0) = (-f.beam).transpose();
  V.block<3, 1>(0, 3) = -V.block<3, 3>(0, 0) * f.source;
  return V;
}

Mat4 carm_projection_matrix(const CArmPose& pose, double n, double far) {
  // glFrustum with the detector field fov x fov at distance sid.
  const double r = n * 0.5 * pose.fov / pose.sid;
  Mat4 P = Mat4::Zero();
  P(0, 0) = n / r;
  P(1, 1) = n / r;
  P(2, 2) = -(far + n) / (far - n);
  P(2, 3) = -2.0 * far * n / (far - n);
  P(3, 2) = -1.0;
  return P;
}

Eigen::Vector2d project_to_detector(const CArmPose& pose, const Vec3& p) {
  const CArmFrame f = carm_frame(pose);
  const Vec3 q = p - f.source;
  const Vec3 on_detector = f.source + q * (pose.sid / q.dot(f.beam));
  const Vec3 x = on_detector - f.detector_centre;
  return {x.dot(f.image_right), x.dot(f.image_up)};
}

double magnification(const CArmPose& pose, const Vec3& p) {
  const CArmFrame f = carm_frame(pose);
  return pose.sid / (p - f.source).dot(f.beam);
}

}  // namespace vcsim
