#include "render/egl_context.h"

// No X11 types in the EGL headers: this file needs none and X11's macros break other code.
#define EGL_NO_X11
#define MESA_EGL_NO_X11_HEADERS
#include <EGL/egl.h>
#include <EGL/eglext.h>
#include <glad/gl.h>

#include <cstdio>
#include <cstring>

namespace dvx {

namespace {

// Name of an EGL error code for messages.
const char* egl_error_name(EGLint code) {
  switch (code) {
    case EGL_SUCCESS: return "EGL_SUCCESS";
    case EGL_NOT_INITIALIZED: return "EGL_NOT_INITIALIZED";
    case EGL_BAD_ACCESS: return "EGL_BAD_ACCESS";
    case EGL_BAD_ALLOC: return "EGL_BAD_ALLOC";
    case EGL_BAD_ATTRIBUTE: return "EGL_BAD_ATTRIBUTE";
    case EGL_BAD_CONFIG: return "EGL_BAD_CONFIG";
    case EGL_BAD_CONTEXT: return "EGL_BAD_CONTEXT";
    case EGL_BAD_DISPLAY: return "EGL_BAD_DISPLAY";
    case EGL_BAD_MATCH: return "EGL_BAD_MATCH";
    case EGL_BAD_PARAMETER: return "EGL_BAD_PARAMETER";
    case EGL_BAD_SURFACE: return "EGL_BAD_SURFACE";
    default: return "unknown EGL error";
  }
}

// Whether a space-separated extension list names `name` exactly.
bool has_extension(const char* list, const char* name) {
  if (!list) return false;
  const size_t n = std::strlen(name);
  for (const char* p = list; (p = std::strstr(p, name)) != nullptr; p += n) {
    const bool starts = p == list || p[-1] == ' ';
    const bool ends = p[n] == '\0' || p[n] == ' ';
    if (starts && ends) return true;
  }
  return false;
}

// Opens and initialises a display on `platform` with `native`; EGL_NO_DISPLAY on failure.
EGLDisplay open_display(PFNEGLGETPLATFORMDISPLAYEXTPROC get_platform_display, EGLenum platform,
                        void* native) {
  EGLDisplay display = get_platform_display(platform, native, nullptr);
  if (display == EGL_NO_DISPLAY) return EGL_NO_DISPLAY;
  EGLint major = 0, minor = 0;
  if (!eglInitialize(display, &major, &minor)) return EGL_NO_DISPLAY;
  return display;
}

}  // namespace

bool create_egl_context(EglContext& ctx, std::string& error) {
  ctx = EglContext{};
  // Client extensions: which platforms this libEGL (and its vendors) can open without a window system.
  const char* client = eglQueryString(EGL_NO_DISPLAY, EGL_EXTENSIONS);
  auto get_platform_display =
      reinterpret_cast<PFNEGLGETPLATFORMDISPLAYEXTPROC>(eglGetProcAddress("eglGetPlatformDisplayEXT"));
  if (!client || !get_platform_display || !has_extension(client, "EGL_EXT_platform_base")) {
    error = "EGL: no platform display support (is libegl-mesa0 installed?)";
    return false;
  }

  // Mesa's surfaceless platform first: it needs no device node, no X and no Wayland.
  EGLDisplay display = EGL_NO_DISPLAY;
  if (has_extension(client, "EGL_MESA_platform_surfaceless")) {
    display = open_display(get_platform_display, EGL_PLATFORM_SURFACELESS_MESA, EGL_DEFAULT_DISPLAY);
    if (display != EGL_NO_DISPLAY) ctx.platform = "surfaceless";
  }
  // Otherwise the first EGL device (e.g. a driver without the Mesa platform).
  if (display == EGL_NO_DISPLAY && has_extension(client, "EGL_EXT_platform_device")) {
    auto query_devices = reinterpret_cast<PFNEGLQUERYDEVICESEXTPROC>(eglGetProcAddress("eglQueryDevicesEXT"));
    EGLDeviceEXT devices[8];
    EGLint count = 0;
    if (query_devices && query_devices(8, devices, &count) && count > 0) {
      display = open_display(get_platform_display, EGL_PLATFORM_DEVICE_EXT, devices[0]);
      if (display != EGL_NO_DISPLAY) ctx.platform = "device";
    }
  }
  if (display == EGL_NO_DISPLAY) {
    error = "EGL: no surfaceless display (is libegl-mesa0 installed?)";
    return false;
  }
  ctx.display = display;

  // Any config that can render desktop GL: drawing goes to our own framebuffer objects, so the
  // config's surface types and colour buffer do not matter.
  const EGLint config_attribs[] = {EGL_RENDERABLE_TYPE, EGL_OPENGL_BIT, EGL_SURFACE_TYPE, 0, EGL_NONE};
  EGLConfig config = nullptr;
  EGLint config_count = 0;
  if (!eglChooseConfig(display, config_attribs, &config, 1, &config_count) || config_count < 1) {
    error = "EGL: no config with desktop OpenGL on the " + ctx.platform + " display";
    destroy_egl_context(ctx);
    return false;
  }
  ctx.config = config;

  // A GL 4.5 core context, current without a surface (EGL_KHR_surfaceless_context).
  if (!eglBindAPI(EGL_OPENGL_API)) {
    error = std::string("EGL: cannot bind the OpenGL API (") + egl_error_name(eglGetError()) + ")";
    destroy_egl_context(ctx);
    return false;
  }
  const EGLint context_attribs[] = {EGL_CONTEXT_MAJOR_VERSION, 4, EGL_CONTEXT_MINOR_VERSION, 5,
                                    EGL_CONTEXT_OPENGL_PROFILE_MASK, EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT,
                                    EGL_NONE};
  EGLContext context = eglCreateContext(display, config, EGL_NO_CONTEXT, context_attribs);
  if (context == EGL_NO_CONTEXT) {
    error = std::string("EGL: cannot create an OpenGL 4.5 core context (") + egl_error_name(eglGetError()) + ")";
    destroy_egl_context(ctx);
    return false;
  }
  ctx.context = context;
  if (!eglMakeCurrent(display, EGL_NO_SURFACE, EGL_NO_SURFACE, context)) {
    error = std::string("EGL: cannot make the context current without a surface (") +
            egl_error_name(eglGetError()) + ")";
    destroy_egl_context(ctx);
    return false;
  }

  // GL entry points through glad, then check what we got.
  const int version = gladLoadGL(reinterpret_cast<GLADloadfunc>(eglGetProcAddress));
  if (version == 0 || GLAD_VERSION_MAJOR(version) * 10 + GLAD_VERSION_MINOR(version) < 45) {
    char buf[128];
    std::snprintf(buf, sizeof buf, "GL: loading OpenGL 4.5 failed (got %d.%d)", GLAD_VERSION_MAJOR(version),
                  GLAD_VERSION_MINOR(version));
    error = buf;
    destroy_egl_context(ctx);
    return false;
  }
  const GLubyte* renderer = glGetString(GL_RENDERER);
  const GLubyte* gl_version = glGetString(GL_VERSION);
  ctx.gl_renderer = renderer ? reinterpret_cast<const char*>(renderer) : "";
  ctx.gl_version = gl_version ? reinterpret_cast<const char*>(gl_version) : "";
  return true;
}

void destroy_egl_context(EglContext& ctx) {
  // The context goes; the display stays initialised (see EglContext).
  if (ctx.display) {
    EGLDisplay display = static_cast<EGLDisplay>(ctx.display);
    if (ctx.context) {
      if (eglGetCurrentContext() == static_cast<EGLContext>(ctx.context))
        eglMakeCurrent(display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
      eglDestroyContext(display, static_cast<EGLContext>(ctx.context));
    }
    eglReleaseThread();
  }
  ctx = EglContext{};
}

}  // namespace dvx
