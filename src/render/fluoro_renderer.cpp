// The path-length renderer (OpenGL 3.3 core). For each pixel's ray from the source, the path
// length through a closed surface is the sum over its crossings of +t where the ray leaves
// (back faces) and -t where it enters (front faces), t the distance from the source. Additive
// blending into three RGBA32F targets gives one channel per material; a second pass reduces them
// to the line integral p = sum_k w_k L_k (one float per pixel) for readback. docs/rendering.md.
#define GL_GLEXT_PROTOTYPES
#include <GL/glcorearb.h>

#include <algorithm>
#include <array>
#include <cstdint>
#include <stdexcept>
#include <string>

#include "vcsim/render.h"

namespace vcsim {

namespace {

constexpr int kMaxGroups = 256;

const char* kAccumVs = R"(#version 330 core
layout(location = 0) in vec3 a_pos;
layout(location = 1) in float a_group;
uniform mat4 u_mvp;
out vec3 v_pos;
flat out int v_group;
void main() {
  v_pos = a_pos;
  v_group = int(a_group + 0.5);
  gl_Position = u_mvp * vec4(a_pos, 1.0);
}
)";

// Distance from the source, interpolated perspective-correctly through the world position (not
// the NDC depth, which is not linear in distance). Measured from a reference distance (the
// isocentre's) so that float sums of large opposite terms keep their precision.
// Two variants: LINE_INTEGRAL writes sum_k w_k L_k straight into one float target (the frame);
// otherwise one channel per material into three RGBA targets (inspection and tests).
const char* kAccumFs = R"(
in vec3 v_pos;
flat in int v_group;
uniform vec3 u_source;
uniform float u_ref;
uniform float u_conc[256];
uniform int u_use_groups;
#ifdef LINE_INTEGRAL
uniform float u_wplain, u_wgroup;
layout(location = 0) out float o;
#else
uniform vec4 u_plain0, u_plain1, u_plain2;
uniform vec4 u_group0, u_group1, u_group2;
layout(location = 0) out vec4 o0;
layout(location = 1) out vec4 o1;
layout(location = 2) out vec4 o2;
#endif
void main() {
  float d = distance(v_pos, u_source) - u_ref;
  float s = gl_FrontFacing ? -d : d;
  float c = u_use_groups != 0 ? u_conc[clamp(v_group, 0, 255)] : 0.0;
#ifdef LINE_INTEGRAL
  o = s * (u_wplain + c * u_wgroup);
#else
  o0 = s * (u_plain0 + c * u_group0);
  o1 = s * (u_plain1 + c * u_group1);
  o2 = s * (u_plain2 + c * u_group2);
#endif
}
)";

const char* kReduceVs = R"(#version 330 core
void main() {
  vec2 p = vec2(gl_VertexID == 1 ? 3.0 : -1.0, gl_VertexID == 2 ? 3.0 : -1.0);
  gl_Position = vec4(p, 0.0, 1.0);
}
)";

const char* kReduceFs = R"(#version 330 core
uniform sampler2D u_l0, u_l1, u_l2;
uniform vec4 u_w0, u_w1, u_w2;
layout(location = 0) out float o;
void main() {
  ivec2 ij = ivec2(gl_FragCoord.xy);
  o = dot(texelFetch(u_l0, ij, 0), u_w0) + dot(texelFetch(u_l1, ij, 0), u_w1) +
      dot(texelFetch(u_l2, ij, 0), u_w2);
}
)";

GLuint compile(GLenum type, const char* src) {
  GLuint s = glCreateShader(type);
  glShaderSource(s, 1, &src, nullptr);
  glCompileShader(s);
  GLint ok = 0;
  glGetShaderiv(s, GL_COMPILE_STATUS, &ok);
  if (!ok) {
    char log[2048];
    glGetShaderInfoLog(s, sizeof log, nullptr, log);
    glDeleteShader(s);
    throw std::runtime_error(std::string("render: shader compile failed: ") + log);
  }
  return s;
}

GLuint link(const char* vs, const std::string& fs) {
  GLuint v = compile(GL_VERTEX_SHADER, vs), f = compile(GL_FRAGMENT_SHADER, fs.c_str());
  GLuint p = glCreateProgram();
  glAttachShader(p, v);
  glAttachShader(p, f);
  glLinkProgram(p);
  glDeleteShader(v);
  glDeleteShader(f);
  GLint ok = 0;
  glGetProgramiv(p, GL_LINK_STATUS, &ok);
  if (!ok) {
    char log[2048];
    glGetProgramInfoLog(p, sizeof log, nullptr, log);
    glDeleteProgram(p);
    throw std::runtime_error(std::string("render: shader link failed: ") + log);
  }
  return p;
}

GLuint float_texture(GLenum internal, GLenum format, int size) {
  GLuint t = 0;
  glGenTextures(1, &t);
  glBindTexture(GL_TEXTURE_2D, t);
  glTexImage2D(GL_TEXTURE_2D, 0, static_cast<GLint>(internal), size, size, 0, format, GL_FLOAT,
               nullptr);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
  return t;
}

void check_framebuffer(const char* what) {
  const GLenum st = glCheckFramebufferStatus(GL_FRAMEBUFFER);
  if (st != GL_FRAMEBUFFER_COMPLETE)
    throw std::runtime_error(std::string("render: ") + what + " framebuffer incomplete (status " +
                             std::to_string(st) + ")");
}

}  // namespace

struct FluoroRenderer::Impl {
  std::vector<float> scratch;  // vertex upload buffer
  struct GpuMesh {
    GLuint vao = 0, pos = 0, group = 0, ebo = 0;
    GLsizei count = 0;
    XrayMaterial material = XrayMaterial::kSoftTissue;
    float fill = 1.0f;
    bool groups = false;
    bool visible = true;
    bool is_static = false;  // drawn into the per-pose cache (kLineIntegral)
    // Index ranges of runs of triangles in one group (lumen segments are contiguous), so that
    // segments without contrast can be skipped when only their iodine would count.
    struct Range {
      int group = 0;
      GLsizei first = 0, count = 0;
    };
    std::vector<Range> ranges;
  };
  std::vector<GpuMesh> meshes;
  GLuint accum_prog = 0, line_prog = 0, reduce_prog = 0;
  GLuint accum_fbo = 0, reduce_fbo = 0, tex_l0 = 0, tex_l1 = 0, tex_l2 = 0, tex_p = 0,
         empty_vao = 0;
  // Line integral of the static meshes for the pose and energy it was drawn for.
  GLuint static_fbo = 0, tex_static = 0;
  bool static_valid = false;
  CArmPose static_pose;
  BeamEnergy static_energy = BeamEnergy::k60keV;
  std::array<float, kMaxGroups> conc{};
  // Uniform locations.
  // Uniform locations of the accumulation programs ([0] per material, [1] line integral).
  GLint u_mvp[2] = {-1, -1}, u_source[2] = {-1, -1}, u_ref[2] = {-1, -1}, u_conc[2] = {-1, -1},
        u_use_groups[2] = {-1, -1};
  GLint u_plain[3] = {-1, -1, -1}, u_group[3] = {-1, -1, -1}, u_wplain = -1, u_wgroup = -1;
  GLint u_w[3] = {-1, -1, -1}, u_l[3] = {-1, -1, -1};

  void upload(GpuMesh& g, const TriangleMesh& m, const std::vector<int>* groups) {
    std::vector<float> pos(3 * m.vertices.size());
    for (std::size_t i = 0; i < m.vertices.size(); ++i)
      for (int k = 0; k < 3; ++k) pos[3 * i + k] = static_cast<float>(m.vertices[i][k]);
    std::vector<unsigned> idx(3 * m.triangles.size());
    for (std::size_t t = 0; t < m.triangles.size(); ++t)
      for (int k = 0; k < 3; ++k) idx[3 * t + k] = static_cast<unsigned>(m.triangles[t][k]);
    glBindVertexArray(g.vao);
    glBindBuffer(GL_ARRAY_BUFFER, g.pos);
    glBufferData(GL_ARRAY_BUFFER, static_cast<GLsizeiptr>(pos.size() * sizeof(float)), pos.data(),
                 GL_DYNAMIC_DRAW);
    glVertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, 0, nullptr);
    glEnableVertexAttribArray(0);
    if (groups) {
      std::vector<float> gr(groups->begin(), groups->end());
      glBindBuffer(GL_ARRAY_BUFFER, g.group);
      glBufferData(GL_ARRAY_BUFFER, static_cast<GLsizeiptr>(gr.size() * sizeof(float)), gr.data(),
                   GL_STATIC_DRAW);
      glVertexAttribPointer(1, 1, GL_FLOAT, GL_FALSE, 0, nullptr);
      glEnableVertexAttribArray(1);
    } else if (!g.groups) {
      glDisableVertexAttribArray(1);
      glVertexAttrib1f(1, 0.0f);
    }
    glBindBuffer(GL_ELEMENT_ARRAY_BUFFER, g.ebo);
    glBufferData(GL_ELEMENT_ARRAY_BUFFER, static_cast<GLsizeiptr>(idx.size() * sizeof(unsigned)),
                 idx.data(), GL_DYNAMIC_DRAW);
    g.count = static_cast<GLsizei>(idx.size());
    glBindVertexArray(0);
  }
};

FluoroRenderer::FluoroRenderer(int size) : impl_(std::make_unique<Impl>()), size_(size) {
  if (size < 16 || size > 4096)
    throw InputError("render", "size", "expected 16 to 4096 pixels, got " + std::to_string(size));
  Impl& m = *impl_;
  m.accum_prog = link(kAccumVs, std::string("#version 330 core\n") + kAccumFs);
  m.line_prog =
      link(kAccumVs, std::string("#version 330 core\n#define LINE_INTEGRAL\n") + kAccumFs);
  m.reduce_prog = link(kReduceVs, kReduceFs);
  auto loc = [](GLuint p, const char* n) { return glGetUniformLocation(p, n); };
  for (int k = 0; k < 2; ++k) {
    const GLuint prog = k == 0 ? m.accum_prog : m.line_prog;
    m.u_mvp[k] = loc(prog, "u_mvp");
    m.u_source[k] = loc(prog, "u_source");
    m.u_ref[k] = loc(prog, "u_ref");
    m.u_conc[k] = loc(prog, "u_conc");
    m.u_use_groups[k] = loc(prog, "u_use_groups");
  }
  for (int t = 0; t < 3; ++t) {
    const std::string i = std::to_string(t);
    m.u_plain[t] = loc(m.accum_prog, ("u_plain" + i).c_str());
    m.u_group[t] = loc(m.accum_prog, ("u_group" + i).c_str());
    m.u_w[t] = loc(m.reduce_prog, ("u_w" + i).c_str());
    m.u_l[t] = loc(m.reduce_prog, ("u_l" + i).c_str());
  }
  m.u_wplain = loc(m.line_prog, "u_wplain");
  m.u_wgroup = loc(m.line_prog, "u_wgroup");

  m.tex_l0 = float_texture(GL_RGBA32F, GL_RGBA, size);
  m.tex_l1 = float_texture(GL_RGBA32F, GL_RGBA, size);
  m.tex_l2 = float_texture(GL_RGBA32F, GL_RGBA, size);
  m.tex_p = float_texture(GL_R32F, GL_RED, size);
  glGenFramebuffers(1, &m.accum_fbo);
  glBindFramebuffer(GL_FRAMEBUFFER, m.accum_fbo);
  glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, m.tex_l0, 0);
  glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT1, GL_TEXTURE_2D, m.tex_l1, 0);
  glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT2, GL_TEXTURE_2D, m.tex_l2, 0);
  const GLenum bufs[3] = {GL_COLOR_ATTACHMENT0, GL_COLOR_ATTACHMENT1, GL_COLOR_ATTACHMENT2};
  glDrawBuffers(3, bufs);
  check_framebuffer("path-length");
  glGenFramebuffers(1, &m.reduce_fbo);
  glBindFramebuffer(GL_FRAMEBUFFER, m.reduce_fbo);
  glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, m.tex_p, 0);
  check_framebuffer("line-integral");
  m.tex_static = float_texture(GL_R32F, GL_RED, size);
  glGenFramebuffers(1, &m.static_fbo);
  glBindFramebuffer(GL_FRAMEBUFFER, m.static_fbo);
  glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, m.tex_static, 0);
  check_framebuffer("static line-integral");
  glBindFramebuffer(GL_FRAMEBUFFER, 0);
  glGenVertexArrays(1, &m.empty_vao);
}

FluoroRenderer::~FluoroRenderer() {
  Impl& m = *impl_;
  for (auto& g : m.meshes) {
    glDeleteVertexArrays(1, &g.vao);
    GLuint b[3] = {g.pos, g.group, g.ebo};
    glDeleteBuffers(3, b);
  }
  glDeleteVertexArrays(1, &m.empty_vao);
  GLuint fbos[3] = {m.accum_fbo, m.reduce_fbo, m.static_fbo};
  glDeleteFramebuffers(3, fbos);
  GLuint tex[5] = {m.tex_l0, m.tex_l1, m.tex_l2, m.tex_p, m.tex_static};
  glDeleteTextures(5, tex);
  glDeleteProgram(m.accum_prog);
  glDeleteProgram(m.line_prog);
  glDeleteProgram(m.reduce_prog);
}

int FluoroRenderer::add_mesh(const XrayMesh& x) {
  Impl::GpuMesh g;
  glGenVertexArrays(1, &g.vao);
  GLuint b[3];
  glGenBuffers(3, b);
  g.pos = b[0];
  g.group = b[1];
  g.ebo = b[2];
  g.material = x.material;
  g.fill = x.fill;
  g.groups = !x.vertex_group.empty();
  if (g.groups && x.vertex_group.size() != x.mesh.vertices.size())
    throw std::invalid_argument("render: vertex_group must have one entry per vertex");
  impl_->upload(g, x.mesh, g.groups ? &x.vertex_group : nullptr);
  if (g.groups)
    for (int t = 0; t < x.mesh.num_triangles(); ++t) {
      const int grp = x.vertex_group[static_cast<std::size_t>(x.mesh.triangles[t][0])];
      if (g.ranges.empty() || g.ranges.back().group != grp)
        g.ranges.push_back({grp, static_cast<GLsizei>(3 * t), 0});
      g.ranges.back().count += 3;
    }
  impl_->meshes.push_back(g);
  return static_cast<int>(impl_->meshes.size()) - 1;
}

void FluoroRenderer::set_static(int id, bool is_static) {
  impl_->meshes.at(static_cast<std::size_t>(id)).is_static = is_static;
  impl_->static_valid = false;
}

void FluoroRenderer::update_mesh(int id, const TriangleMesh& mesh) {
  auto& g = impl_->meshes.at(static_cast<std::size_t>(id));
  if (g.is_static) impl_->static_valid = false;
  if (g.groups) throw std::invalid_argument("render: update_mesh on a grouped mesh");
  impl_->upload(g, mesh, nullptr);
}

void FluoroRenderer::update_vertices(int id, std::span<const Vec3> vertices) {
  auto& g = impl_->meshes.at(static_cast<std::size_t>(id));
  if (g.is_static) impl_->static_valid = false;
  std::vector<float>& pos = impl_->scratch;
  pos.resize(3 * vertices.size());
  for (std::size_t i = 0; i < vertices.size(); ++i)
    for (int k = 0; k < 3; ++k) pos[3 * i + k] = static_cast<float>(vertices[i][k]);
  GLint bytes = 0;
  glBindBuffer(GL_ARRAY_BUFFER, g.pos);
  glGetBufferParameteriv(GL_ARRAY_BUFFER, GL_BUFFER_SIZE, &bytes);
  if (static_cast<std::size_t>(bytes) != pos.size() * sizeof(float)) {
    glBindBuffer(GL_ARRAY_BUFFER, 0);
    throw std::invalid_argument("render: update_vertices with a different vertex count");
  }
  glBufferSubData(GL_ARRAY_BUFFER, 0, bytes, pos.data());
  glBindBuffer(GL_ARRAY_BUFFER, 0);
}

void FluoroRenderer::set_visible(int id, bool visible) {
  auto& g = impl_->meshes.at(static_cast<std::size_t>(id));
  if (g.is_static && g.visible != visible) impl_->static_valid = false;
  g.visible = visible;
}

void FluoroRenderer::set_fill(int id, float fill) {
  auto& g = impl_->meshes.at(static_cast<std::size_t>(id));
  if (g.is_static && g.fill != fill) impl_->static_valid = false;
  g.fill = fill;
}

void FluoroRenderer::set_group_concentration(std::span<const float> c) {
  impl_->conc.fill(0.0f);
  std::copy_n(c.begin(), std::min<std::size_t>(c.size(), kMaxGroups), impl_->conc.begin());
}

void FluoroRenderer::render(const CArmPose& pose, FluoroOutput output) {
  Impl& m = *impl_;
  const CArmFrame f = carm_frame(pose);
  // A near plane close to the source: clipping a closed mesh would break its path-length sum.
  const Eigen::Matrix4f mvp =
      (carm_projection_matrix(pose, 0.01, 2.0 * pose.sid + 1.0) * carm_view_matrix(pose))
          .cast<float>();
  const bool per_material = output == FluoroOutput::kPathLengths;
  const int k = per_material ? 0 : 1;
  const auto w = line_integral_weights(energy_);
  std::array<float, 12> w12{};  // the weights in three vec4s
  std::copy(w.begin(), w.end(), w12.begin());
  const int iodine = static_cast<int>(XrayMaterial::kIodine);

  glViewport(0, 0, size_, size_);
  glClearColor(0.0f, 0.0f, 0.0f, 0.0f);
  glDisable(GL_DEPTH_TEST);
  glDisable(GL_CULL_FACE);
  glBlendEquation(GL_FUNC_ADD);
  glBlendFunc(GL_ONE, GL_ONE);
  // The view is a mirror (the image as seen from the detector), so outward counter-clockwise
  // triangles appear clockwise on screen where the ray enters.
  glFrontFace(GL_CW);
  glUseProgram(per_material ? m.accum_prog : m.line_prog);
  glUniformMatrix4fv(m.u_mvp[k], 1, GL_FALSE, mvp.data());
  glUniform3f(m.u_source[k], static_cast<float>(f.source.x()), static_cast<float>(f.source.y()),
              static_cast<float>(f.source.z()));
  glUniform1f(m.u_ref[k], static_cast<float>(pose.sod));
  glUniform1fv(m.u_conc[k], kMaxGroups, m.conc.data());
  // Draws the visible meshes whose static flag is `statics` (all of them for `all`).
  auto draw = [&](bool all, bool statics) {
    for (const auto& g : m.meshes) {
      if (!g.visible || g.count == 0 || (!all && g.is_static != statics)) continue;
      const int mat = static_cast<int>(g.material);
      if (per_material) {
        float plain[12] = {}, grouped[12] = {};
        plain[mat] = g.fill;
        if (g.groups) grouped[iodine] = g.fill;
        for (int t = 0; t < 3; ++t) {
          glUniform4fv(m.u_plain[t], 1, plain + 4 * t);
          glUniform4fv(m.u_group[t], 1, grouped + 4 * t);
        }
      } else {
        if (w[mat] == 0.0f && !g.groups) continue;
        glUniform1f(m.u_wplain, g.fill * w[mat]);
        glUniform1f(m.u_wgroup, g.groups ? g.fill * w[iodine] : 0.0f);
      }
      glUniform1i(m.u_use_groups[k], g.groups ? 1 : 0);
      glBindVertexArray(g.vao);
      if (!per_material && g.groups && w[mat] == 0.0f) {
        // Blood adds nothing over soft tissue (w = 0): only groups holding contrast count.
        for (const auto& r : g.ranges) {
          const float c = r.group >= 0 && r.group < kMaxGroups ? m.conc[r.group] : 0.0f;
          if (c != 0.0f)
            glDrawElements(GL_TRIANGLES, r.count, GL_UNSIGNED_INT,
                           reinterpret_cast<const void*>(static_cast<std::uintptr_t>(r.first) *
                                                         sizeof(unsigned)));
        }
        continue;
      }
      glDrawElements(GL_TRIANGLES, g.count, GL_UNSIGNED_INT, nullptr);
    }
  };
  glEnable(GL_BLEND);
  if (per_material) {
    glBindFramebuffer(GL_FRAMEBUFFER, m.accum_fbo);
    glClear(GL_COLOR_BUFFER_BIT);
    draw(true, false);
  } else {
    // Static meshes (the body) are drawn once per pose and energy; each frame starts from them.
    const bool any_static = std::any_of(m.meshes.begin(), m.meshes.end(),
                                        [](const auto& g) { return g.is_static && g.visible; });
    if (any_static) {
      const CArmPose& sp = m.static_pose;
      const bool same = m.static_valid && energy_ == m.static_energy &&
                        sp.primary_deg == pose.primary_deg &&
                        sp.secondary_deg == pose.secondary_deg && sp.sid == pose.sid &&
                        sp.sod == pose.sod && sp.fov == pose.fov && sp.isocentre == pose.isocentre;
      if (!same) {
        glBindFramebuffer(GL_FRAMEBUFFER, m.static_fbo);
        glClear(GL_COLOR_BUFFER_BIT);
        draw(false, true);
        m.static_pose = pose;
        m.static_energy = energy_;
        m.static_valid = true;
      }
      glBindFramebuffer(GL_READ_FRAMEBUFFER, m.static_fbo);
      glBindFramebuffer(GL_DRAW_FRAMEBUFFER, m.reduce_fbo);
      glBlitFramebuffer(0, 0, size_, size_, 0, 0, size_, size_, GL_COLOR_BUFFER_BIT, GL_NEAREST);
      glBindFramebuffer(GL_FRAMEBUFFER, m.reduce_fbo);
    } else {
      glBindFramebuffer(GL_FRAMEBUFFER, m.reduce_fbo);
      glClear(GL_COLOR_BUFFER_BIT);
    }
    draw(false, false);
  }
  glDisable(GL_BLEND);

  if (per_material) {
    // Reduction of the channels to the line integral.
    glBindFramebuffer(GL_FRAMEBUFFER, m.reduce_fbo);
    glUseProgram(m.reduce_prog);
    const GLuint tex[3] = {m.tex_l0, m.tex_l1, m.tex_l2};
    for (int t = 0; t < 3; ++t) {
      glUniform4fv(m.u_w[t], 1, w12.data() + 4 * t);
      glActiveTexture(static_cast<GLenum>(GL_TEXTURE0 + t));
      glBindTexture(GL_TEXTURE_2D, tex[t]);
      glUniform1i(m.u_l[t], t);
    }
    glActiveTexture(GL_TEXTURE0);
    glBindVertexArray(m.empty_vao);
    glDrawArrays(GL_TRIANGLES, 0, 3);
  }
  glBindVertexArray(0);
  glBindFramebuffer(GL_FRAMEBUFFER, 0);
  const GLenum err = glGetError();
  if (err != GL_NO_ERROR) throw std::runtime_error("render: GL error " + std::to_string(err));
}

void FluoroRenderer::read_line_integral(std::vector<float>& out) const {
  const std::size_t n = static_cast<std::size_t>(size_);
  out.resize(n * n);
  glBindFramebuffer(GL_READ_FRAMEBUFFER, impl_->reduce_fbo);
  glReadBuffer(GL_COLOR_ATTACHMENT0);
  glPixelStorei(GL_PACK_ALIGNMENT, 4);
  glReadPixels(0, 0, size_, size_, GL_RED, GL_FLOAT, out.data());
  glBindFramebuffer(GL_READ_FRAMEBUFFER, 0);
  // GL rows start at the bottom; images start at the top.
  for (std::size_t r = 0; r < n / 2; ++r)
    std::swap_ranges(out.begin() + static_cast<std::ptrdiff_t>(r * n),
                     out.begin() + static_cast<std::ptrdiff_t>((r + 1) * n),
                     out.begin() + static_cast<std::ptrdiff_t>((n - 1 - r) * n));
}

void FluoroRenderer::read_path_lengths(std::vector<float>& out) const {
  const std::size_t n = static_cast<std::size_t>(size_);
  std::array<std::vector<float>, 3> a;
  glBindFramebuffer(GL_READ_FRAMEBUFFER, impl_->accum_fbo);
  for (int t = 0; t < 3; ++t) {
    a[t].resize(n * n * 4);
    glReadBuffer(static_cast<GLenum>(GL_COLOR_ATTACHMENT0 + t));
    glReadPixels(0, 0, size_, size_, GL_RGBA, GL_FLOAT, a[t].data());
  }
  glBindFramebuffer(GL_READ_FRAMEBUFFER, 0);
  out.resize(n * n * kNumXrayMaterials);
  for (std::size_t r = 0; r < n; ++r)
    for (std::size_t c = 0; c < n; ++c) {
      const std::size_t src = ((n - 1 - r) * n + c) * 4, dst = (r * n + c) * kNumXrayMaterials;
      for (int k = 0; k < kNumXrayMaterials; ++k) out[dst + k] = a[k / 4][src + k % 4];
    }
}

}  // namespace vcsim
