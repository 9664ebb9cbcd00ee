// The educator's 3D view (view3d.h).
#include "view3d.h"

#define GL_GLEXT_PROTOTYPES
#include <GL/glcorearb.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <stdexcept>
#include <string>

namespace vcsim::trainer {

namespace {

const char* kVs = R"(#version 330 core
layout(location = 0) in vec3 a_pos;
layout(location = 1) in vec3 a_nrm;
uniform mat4 u_mvp;
out vec3 v_nrm;
void main() {
  v_nrm = a_nrm;
  gl_Position = u_mvp * vec4(a_pos, 1.0);
}
)";

const char* kFs = R"(#version 330 core
in vec3 v_nrm;
uniform vec4 u_color;
uniform vec3 u_light;
out vec4 o;
void main() {
  float l = 0.35 + 0.65 * abs(dot(normalize(v_nrm), u_light));
  o = vec4(u_color.rgb * l, u_color.a);
}
)";

unsigned compile(GLenum type, const char* src) {
  const GLuint s = glCreateShader(type);
  glShaderSource(s, 1, &src, nullptr);
  glCompileShader(s);
  GLint ok = 0;
  glGetShaderiv(s, GL_COMPILE_STATUS, &ok);
  if (!ok) {
    char log[1024];
    glGetShaderInfoLog(s, sizeof log, nullptr, log);
    throw std::runtime_error(std::string("trainer: 3D view shader: ") + log);
  }
  return s;
}

using Mat4f = Eigen::Matrix4f;

Mat4f look_at(const Vec3& eye, const Vec3& at, const Vec3& up) {
  const Vec3 f = (at - eye).normalized();
  const Vec3 s = f.cross(up).normalized();
  const Vec3 u = s.cross(f);
  Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
  m.block<1, 3>(0, 0) = s.transpose();
  m.block<1, 3>(1, 0) = u.transpose();
  m.block<1, 3>(2, 0) = -f.transpose();
  m(0, 3) = -s.dot(eye);
  m(1, 3) = -u.dot(eye);
  m(2, 3) = f.dot(eye);
  return m.cast<float>();
}

Mat4f perspective(double fovy, double aspect, double n, double f) {
  const double t = 1.0 / std::tan(fovy / 2);
  Eigen::Matrix4d m = Eigen::Matrix4d::Zero();
  m(0, 0) = t / aspect;
  m(1, 1) = t;
  m(2, 2) = (f + n) / (n - f);
  m(2, 3) = 2 * f * n / (n - f);
  m(3, 2) = -1;
  return m.cast<float>();
}

// Colours of the instruments, by index, and of the selected one.
constexpr std::array<std::array<float, 3>, 4> kColours = {
    {{0.95f, 0.75f, 0.2f}, {0.3f, 0.8f, 1.0f}, {0.6f, 1.0f, 0.4f}, {1.0f, 0.5f, 0.8f}}};

void upload(unsigned vao, unsigned vbo, unsigned nbo, unsigned ebo, const std::vector<float>& pos,
            const std::vector<float>& nrm, const std::vector<unsigned>* idx) {
  glBindVertexArray(vao);
  glBindBuffer(GL_ARRAY_BUFFER, vbo);
  glBufferData(GL_ARRAY_BUFFER, static_cast<GLsizeiptr>(pos.size() * sizeof(float)), pos.data(),
               GL_DYNAMIC_DRAW);
  glVertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, 0, nullptr);
  glEnableVertexAttribArray(0);
  glBindBuffer(GL_ARRAY_BUFFER, nbo);
  glBufferData(GL_ARRAY_BUFFER, static_cast<GLsizeiptr>(nrm.size() * sizeof(float)), nrm.data(),
               GL_DYNAMIC_DRAW);
  glVertexAttribPointer(1, 3, GL_FLOAT, GL_FALSE, 0, nullptr);
  glEnableVertexAttribArray(1);
  if (idx) {
    glBindBuffer(GL_ELEMENT_ARRAY_BUFFER, ebo);
    glBufferData(GL_ELEMENT_ARRAY_BUFFER, static_cast<GLsizeiptr>(idx->size() * sizeof(unsigned)),
                 idx->data(), GL_DYNAMIC_DRAW);
  }
  glBindVertexArray(0);
}

}  // namespace

View3D::View3D(const SimModel& model, int size)
    : anatomy_(model.anatomy), motion_(model.motion ? &*model.motion : nullptr), size_(size) {
  for (const InstrumentSpec& spec : model.specs) radius_.push_back(0.5 * spec.outer_diameter);
  glGenFramebuffers(1, &fbo_);
  glGenTextures(1, &color_);
  glBindTexture(GL_TEXTURE_2D, color_);
  glTexImage2D(GL_TEXTURE_2D, 0, GL_RGBA8, size, size, 0, GL_RGBA, GL_UNSIGNED_BYTE, nullptr);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
  glGenRenderbuffers(1, &depth_);
  glBindRenderbuffer(GL_RENDERBUFFER, depth_);
  glRenderbufferStorage(GL_RENDERBUFFER, GL_DEPTH_COMPONENT24, size, size);
  glBindFramebuffer(GL_FRAMEBUFFER, fbo_);
  glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, color_, 0);
  glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, depth_);
  if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE)
    throw std::runtime_error("trainer: 3D view framebuffer incomplete");
  glBindFramebuffer(GL_FRAMEBUFFER, 0);

  const unsigned vs = compile(GL_VERTEX_SHADER, kVs), fs = compile(GL_FRAGMENT_SHADER, kFs);
  prog_ = glCreateProgram();
  glAttachShader(prog_, vs);
  glAttachShader(prog_, fs);
  glLinkProgram(prog_);
  glDeleteShader(vs);
  glDeleteShader(fs);
  u_mvp_ = glGetUniformLocation(prog_, "u_mvp");
  u_color_ = glGetUniformLocation(prog_, "u_color");
  u_light_ = glGetUniformLocation(prog_, "u_light");

  unsigned* names[] = {&lumen_vbo_, &lumen_nbo_, &lumen_ebo_, &inst_vbo_, &inst_nbo_, &inst_ebo_};
  for (unsigned* n : names) glGenBuffers(1, n);
  glGenVertexArrays(1, &lumen_vao_);
  glGenVertexArrays(1, &inst_vao_);

  const TriangleMesh& mesh = model.lumen.mesh;
  rest_ = mesh.vertices;
  pos_.resize(3 * rest_.size());
  nrm_.resize(3 * rest_.size());
  for (std::size_t v = 0; v < rest_.size(); ++v)
    for (int k = 0; k < 3; ++k) {
      pos_[3 * v + k] = static_cast<float>(rest_[v][k]);
      nrm_[3 * v + k] = v < mesh.normals.size() ? static_cast<float>(mesh.normals[v][k]) : 0.0f;
    }
  std::vector<unsigned> idx;
  idx.reserve(3 * mesh.triangles.size());
  for (const auto& t : mesh.triangles)
    for (int k = 0; k < 3; ++k) idx.push_back(static_cast<unsigned>(t[k]));
  lumen_count_ = static_cast<int>(idx.size());
  upload(lumen_vao_, lumen_vbo_, lumen_nbo_, lumen_ebo_, pos_, nrm_, &idx);
  home_ = centre_ = left_coronary_centre(model.tree);
}

View3D::~View3D() {
  unsigned buffers[] = {lumen_vbo_, lumen_nbo_, lumen_ebo_, inst_vbo_, inst_nbo_, inst_ebo_};
  glDeleteBuffers(6, buffers);
  glDeleteVertexArrays(1, &lumen_vao_);
  glDeleteVertexArrays(1, &inst_vao_);
  glDeleteProgram(prog_);
  glDeleteFramebuffers(1, &fbo_);
  glDeleteTextures(1, &color_);
  glDeleteRenderbuffers(1, &depth_);
}

void View3D::orbit(double dx, double dy) {
  yaw_ += dx * 0.01;
  pitch_ = std::clamp(pitch_ + dy * 0.01, -1.5, 1.5);
}

void View3D::zoom(double steps) {
  distance_ = std::clamp(distance_ * std::pow(0.9, steps), 0.05, 2.0);
}

void View3D::draw(const FrameSnapshot& frame, int selected) {
  // The lumen moved with the heart to the frame's time (as the fluoroscopy shows it).
  if (motion_) {
    for (std::size_t v = 0; v < rest_.size(); ++v) {
      const Vec3 p = rest_[v] + motion_->displacement(rest_[v], frame.time);
      for (int k = 0; k < 3; ++k) pos_[3 * v + k] = static_cast<float>(p[k]);
    }
    glBindBuffer(GL_ARRAY_BUFFER, lumen_vbo_);
    glBufferSubData(GL_ARRAY_BUFFER, 0, static_cast<GLsizeiptr>(pos_.size() * sizeof(float)),
                    pos_.data());
  }
  // The camera orbits the selected instrument's tip while it is inside (else the heart), gliding
  // there over a few frames; LPS: +z toward the head, -y anterior (the educator stands at the
  // patient's front).
  const Vec3 target = selected >= 0 && static_cast<std::size_t>(selected) < frame.nodes.size() &&
                              frame.nodes[static_cast<std::size_t>(selected)].size() >= 2
                          ? frame.nodes[static_cast<std::size_t>(selected)].back()
                          : home_;
  centre_ += 0.15 * (target - centre_);
  const Vec3 dir(std::cos(pitch_) * std::sin(yaw_), -std::cos(pitch_) * std::cos(yaw_),
                 std::sin(pitch_));
  const Vec3 eye = centre_ + distance_ * dir;
  const Mat4f mvp = perspective(0.8, 1.0, 0.01, 3.0) * look_at(eye, centre_, Vec3(0, 0, 1));
  const Eigen::Vector3f light = dir.cast<float>().normalized();

  GLint viewport[4];
  glGetIntegerv(GL_VIEWPORT, viewport);
  glBindFramebuffer(GL_FRAMEBUFFER, fbo_);
  glViewport(0, 0, size_, size_);
  glClearColor(0.08f, 0.09f, 0.11f, 1.0f);
  glClear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);
  glEnable(GL_DEPTH_TEST);
  glDisable(GL_CULL_FACE);
  glUseProgram(prog_);
  glUniformMatrix4fv(u_mvp_, 1, GL_FALSE, mvp.data());
  glUniform3f(u_light_, light.x(), light.y(), light.z());

  // Instruments first (opaque), then the lumen translucent over them.
  std::vector<float> p, n;
  std::vector<unsigned> idx;
  struct Part {
    std::size_t first, count;
    int instrument;
  };
  std::vector<Part> parts;
  if (frame.model) {
    radius_.clear();
    for (const InstrumentSpec& spec : frame.model->specs)
      radius_.push_back(0.5 * spec.outer_diameter);
  }
  for (std::size_t i = 0; i < frame.nodes.size(); ++i) {
    const std::vector<Vec3>& nodes = frame.nodes[i];
    if (nodes.size() < 2) continue;
    // Thicker than life (at least 2 mm across) so that a wire shows at the view's scale.
    const double r = std::max(1.0e-3, i < radius_.size() ? radius_[i] : 0.0);
    const std::vector<double> radii = {r};
    const TriangleMesh tube = tube_mesh(nodes, radii, 6);
    const auto base = static_cast<unsigned>(p.size() / 3);
    for (std::size_t v = 0; v < tube.vertices.size(); ++v) {
      for (int k = 0; k < 3; ++k) p.push_back(static_cast<float>(tube.vertices[v][k]));
      // The nearest node's offset is a good enough normal for shading a thin tube.
      const std::size_t node = std::min(nodes.size() - 1, v / 6);
      const Vec3 d = (tube.vertices[v] - nodes[node]).normalized();
      for (int k = 0; k < 3; ++k) n.push_back(static_cast<float>(std::isfinite(d[k]) ? d[k] : 0.0));
    }
    const std::size_t first = idx.size();
    for (const auto& t : tube.triangles)
      for (int k = 0; k < 3; ++k) idx.push_back(base + static_cast<unsigned>(t[k]));
    parts.push_back({first, idx.size() - first, static_cast<int>(i)});
  }
  if (!parts.empty()) {
    upload(inst_vao_, inst_vbo_, inst_nbo_, inst_ebo_, p, n, &idx);
    glBindVertexArray(inst_vao_);
    for (const Part& part : parts) {
      const auto& c = kColours[static_cast<std::size_t>(part.instrument) % kColours.size()];
      const float boost = part.instrument == selected ? 1.0f : 0.7f;
      glUniform4f(u_color_, c[0] * boost, c[1] * boost, c[2] * boost, 1.0f);
      glDrawElements(GL_TRIANGLES, static_cast<GLsizei>(part.count), GL_UNSIGNED_INT,
                     reinterpret_cast<const void*>(part.first * sizeof(unsigned)));
    }
  }
  glEnable(GL_BLEND);
  glBlendFunc(GL_SRC_ALPHA, GL_ONE_MINUS_SRC_ALPHA);
  glDepthMask(GL_FALSE);
  glUniform4f(u_color_, 0.85f, 0.3f, 0.3f, 0.22f);
  glBindVertexArray(lumen_vao_);
  glDrawElements(GL_TRIANGLES, lumen_count_, GL_UNSIGNED_INT, nullptr);
  glDepthMask(GL_TRUE);
  glDisable(GL_BLEND);
  glDisable(GL_DEPTH_TEST);
  glBindVertexArray(0);
  glUseProgram(0);
  glBindFramebuffer(GL_FRAMEBUFFER, 0);
  glViewport(viewport[0], viewport[1], viewport[2], viewport[3]);
}

}  // namespace vcsim::trainer
