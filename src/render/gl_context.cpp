// A headless OpenGL 3.3 core context through EGL: no display server, no window, no GPU needed
// (Mesa's llvmpipe). eglGetDisplay(EGL_DEFAULT_DISPLAY) fails without a display server, so the
// display comes from an EGL device (EGL_EXT_platform_device) or Mesa's surfaceless platform.
#include <EGL/egl.h>
#include <EGL/eglext.h>

#define GL_GLEXT_PROTOTYPES
#include <GL/glcorearb.h>

#include <stdexcept>
#include <string>
#include <vector>

#include "vcsim/render.h"

namespace vcsim {

struct HeadlessGlContext::Impl {
  EGLDisplay display = EGL_NO_DISPLAY;
  EGLContext context = EGL_NO_CONTEXT;
};

namespace {

std::string egl_error_text() {
  char buf[32];
  std::snprintf(buf, sizeof buf, "0x%04x", static_cast<unsigned>(eglGetError()));
  return buf;
}

// Initialises a display, binds desktop OpenGL and makes a 3.3 core context current without a
// surface. Returns the context or EGL_NO_CONTEXT, with `why` set.
EGLContext try_display(EGLDisplay dpy, std::string& why) {
  EGLint major = 0, minor = 0;
  if (dpy == EGL_NO_DISPLAY || !eglInitialize(dpy, &major, &minor)) {
    why = "eglInitialize failed (" + egl_error_text() + ")";
    return EGL_NO_CONTEXT;
  }
  const char* ext = eglQueryString(dpy, EGL_EXTENSIONS);
  if (!ext || !(std::string(ext).find("EGL_KHR_surfaceless_context") != std::string::npos)) {
    why = "no EGL_KHR_surfaceless_context";
    eglTerminate(dpy);
    return EGL_NO_CONTEXT;
  }
  if (!eglBindAPI(EGL_OPENGL_API)) {
    why = "eglBindAPI(EGL_OPENGL_API) failed (" + egl_error_text() + ")";
    eglTerminate(dpy);
    return EGL_NO_CONTEXT;
  }
  const EGLint config_attribs[] = {EGL_RENDERABLE_TYPE, EGL_OPENGL_BIT, EGL_SURFACE_TYPE, 0,
                                   EGL_NONE};
  EGLConfig config = nullptr;
  EGLint n = 0;
  // No surface type needed (we draw into framebuffer objects); some drivers want one anyway.
  if (!eglChooseConfig(dpy, config_attribs, &config, 1, &n) || n < 1) {
    const EGLint pbuffer_attribs[] = {EGL_RENDERABLE_TYPE, EGL_OPENGL_BIT, EGL_SURFACE_TYPE,
                                      EGL_PBUFFER_BIT, EGL_NONE};
    if (!eglChooseConfig(dpy, pbuffer_attribs, &config, 1, &n) || n < 1) {
      why = "no EGL config for desktop OpenGL";
      eglTerminate(dpy);
      return EGL_NO_CONTEXT;
    }
  }
  const EGLint ctx_attribs[] = {EGL_CONTEXT_MAJOR_VERSION,
                                3,
                                EGL_CONTEXT_MINOR_VERSION,
                                3,
                                EGL_CONTEXT_OPENGL_PROFILE_MASK,
                                EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT,
                                EGL_NONE};
  EGLContext ctx = eglCreateContext(dpy, config, EGL_NO_CONTEXT, ctx_attribs);
  if (ctx == EGL_NO_CONTEXT) {
    why = "eglCreateContext for OpenGL 3.3 core failed (" + egl_error_text() + ")";
    eglTerminate(dpy);
    return EGL_NO_CONTEXT;
  }
  if (!eglMakeCurrent(dpy, EGL_NO_SURFACE, EGL_NO_SURFACE, ctx)) {
    why = "eglMakeCurrent without a surface failed (" + egl_error_text() + ")";
    eglDestroyContext(dpy, ctx);
    eglTerminate(dpy);
    return EGL_NO_CONTEXT;
  }
  return ctx;
}

}  // namespace

HeadlessGlContext::HeadlessGlContext() : impl_(std::make_unique<Impl>()) {
  std::string log;
  auto attempt = [&](EGLDisplay dpy, const std::string& what) {
    std::string why;
    EGLContext ctx = try_display(dpy, why);
    if (ctx != EGL_NO_CONTEXT) {
      impl_->display = dpy;
      impl_->context = ctx;
      return true;
    }
    log += "; " + what + ": " + why;
    return false;
  };
  const char* client_ext = eglQueryString(EGL_NO_DISPLAY, EGL_EXTENSIONS);
  const std::string cext = client_ext ? client_ext : "";
  auto get_platform_display = reinterpret_cast<PFNEGLGETPLATFORMDISPLAYEXTPROC>(
      eglGetProcAddress("eglGetPlatformDisplayEXT"));
  auto query_devices =
      reinterpret_cast<PFNEGLQUERYDEVICESEXTPROC>(eglGetProcAddress("eglQueryDevicesEXT"));
  bool ok = false;
  if (get_platform_display && query_devices &&
      (cext.find("EGL_EXT_platform_device") != std::string::npos)) {
    EGLDeviceEXT devices[16];
    EGLint num = 0;
    if (query_devices(16, devices, &num)) {
      for (EGLint i = 0; i < num && !ok; ++i)
        ok = attempt(get_platform_display(EGL_PLATFORM_DEVICE_EXT, devices[i], nullptr),
                     "EGL device " + std::to_string(i));
    } else {
      log += "; eglQueryDevicesEXT failed";
    }
  } else {
    log += "; no EGL_EXT_platform_device";
  }
  if (!ok && get_platform_display &&
      (cext.find("EGL_MESA_platform_surfaceless") != std::string::npos))
    ok = attempt(get_platform_display(EGL_PLATFORM_SURFACELESS_MESA, EGL_DEFAULT_DISPLAY, nullptr),
                 "surfaceless platform");
  if (!ok)
    throw std::runtime_error("render: no headless OpenGL 3.3 core context could be made" + log);
  const auto* r = reinterpret_cast<const char*>(glGetString(GL_RENDERER));
  renderer_ = r ? r : "unknown";
}

HeadlessGlContext::~HeadlessGlContext() {
  if (impl_->display != EGL_NO_DISPLAY) {
    eglMakeCurrent(impl_->display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
    if (impl_->context != EGL_NO_CONTEXT) eglDestroyContext(impl_->display, impl_->context);
    eglTerminate(impl_->display);
  }
}

}  // namespace vcsim
