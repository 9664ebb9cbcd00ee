// The educator's 3D view: the lumen (moved with the heart) as a translucent surface and the
// instruments as coloured tubes, seen by a camera orbiting the selected instrument's tip, drawn
// into a texture the window shows. Needs the window's GL 3.3 core context for its whole life.
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include "vcsim/render.h"

namespace vcsim::trainer {

class View3D {
 public:
  View3D(const SimModel& model, int size);
  ~View3D();
  View3D(const View3D&) = delete;
  View3D& operator=(const View3D&) = delete;

  // Draws the frame's anatomy and instruments (each by the frame's model, else the one built
  // from); the texture then holds the picture.
  void draw(const FrameSnapshot& frame, int selected);
  unsigned texture() const { return color_; }
  int size() const { return size_; }
  // Mouse drag (pixels) turns the camera; the wheel moves it nearer or farther.
  void orbit(double dx, double dy);
  void zoom(double steps);

 private:
  std::shared_ptr<const SimAnatomy> anatomy_;  // kept alive for motion_ (an exchange changes the
                                               // model, never the anatomy)
  const CardiacMotion* motion_ = nullptr;
  std::vector<double> radius_;  // (instrument) tube radius drawn, of the model last drawn
  int size_;
  unsigned fbo_ = 0, color_ = 0, depth_ = 0, prog_ = 0;
  unsigned lumen_vao_ = 0, lumen_vbo_ = 0, lumen_nbo_ = 0, lumen_ebo_ = 0;
  int lumen_count_ = 0;
  unsigned inst_vao_ = 0, inst_vbo_ = 0, inst_nbo_ = 0, inst_ebo_ = 0;
  int u_mvp_ = -1, u_color_ = -1, u_light_ = -1;
  std::vector<Vec3> rest_;
  std::vector<float> pos_, nrm_;
  Vec3 home_ = Vec3::Zero(), centre_ = Vec3::Zero();   // the heart; what the camera looks at
  double yaw_ = 0.6, pitch_ = 0.25, distance_ = 0.25;  // rad, rad, m
};

}  // namespace vcsim::trainer
