// Headless OpenGL: an EGL context with no window (Mesa's surfaceless platform, or an EGL device),
// current on the calling thread, with the GL 4.5 core entry points loaded through glad.
//
// Context creation is kept apart from drawing (renderer.h) so the window mode can make its own
// context with GLFW and reuse the same renderer.
#pragma once

#include <string>

namespace dvx {

// The EGL handles of one headless context. Plain void* handles so that including this header does
// not pull in <EGL/egl.h> (which drags X11 headers and their macros in on Linux).
//
// One display is shared by every context of a process (EGL returns the same handle for the same
// platform), so destroy_egl_context releases its context but never terminates the display:
// terminating would destroy the other contexts on it, and unload the driver (a reload costs the
// next context tens of milliseconds, and the driver's allocations then show as leaks under LSan).
// The display lives until the process exits. A context is current on one thread at a time: create
// it on the thread that renders.
struct EglContext {
  void* display = nullptr;  // EGLDisplay
  void* config = nullptr;   // EGLConfig
  void* context = nullptr;  // EGLContext (EGL_NO_CONTEXT = nullptr)
  std::string platform;     // "surfaceless" or "device"
  std::string gl_renderer;  // GL_RENDERER, e.g. "llvmpipe (LLVM 15.0.6, 256 bits)"
  std::string gl_version;   // GL_VERSION
};

// Creates a GL 4.5 core context with no surface, makes it current on this thread and loads GL
// with glad. Tries EGL_PLATFORM_SURFACELESS_MESA first, then the first EGL device. Returns false
// with a one-line reason (and `ctx` left empty) when EGL or GL 4.5 is not available; never aborts.
bool create_egl_context(EglContext& ctx, std::string& error);

// Releases the context (made not current first when it is current on this thread); safe on an
// empty or half-made context, and twice.
void destroy_egl_context(EglContext& ctx);

}  // namespace dvx
