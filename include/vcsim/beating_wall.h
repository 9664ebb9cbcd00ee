// The beating lumen as the solver's vessel wall: instruments collide with the wall where it is at
// the current time and are carried by its velocity (contacts and friction act on the velocity
// relative to the wall).
#pragma once

#include "vcsim/anatomy.h"
#include "vcsim/collision.h"

namespace vcsim {

class BeatingWall final : public VesselWall {
 public:
  // `lumen` is owned by the caller and must outlive the wall.
  explicit BeatingWall(BeatingLumen& lumen);

  // Time (s) the next queries see; the solver sets it before each (fine) step.
  void set_time(double t) override;
  double time() const { return time_; }

  // Moves the patches the spheres can touch to the current time, then queries them.
  void query_spheres(std::span<const Vec3> centres, std::span<const double> radii,
                     std::span<SphereContact> out) override;
  // The same, with the leaf caches used for the lumen's part that never moves.
  void query_spheres(std::span<const Vec3> centres, std::span<const double> radii,
                     std::span<LeafCache* const> caches, double slack,
                     std::span<SphereContact> out) override;
  // du/dt of the motion field at the rest point under the contact point.
  Vec3 velocity(const SphereContact& hit) const override;
  // max |a_cardiac| max |dc/dt| + max |a_resp| max |dr/dt| over the moving wall.
  double speed_bound() const override { return speed_bound_; }
  bool moves_near(const Vec3& centre, double radius) const override;
  SegmentCrossings segment_crossings(const Vec3& a, const Vec3& b) override;

 private:
  BeatingLumen* lumen_;
  double time_ = 0.0;
  // The waveforms and their rates at time_ (the same for every contact of a step).
  double c_ = 0.0, r_ = 0.0, c_rate_ = 0.0, r_rate_ = 0.0;
  double speed_bound_ = 0.0;
};

}  // namespace vcsim
