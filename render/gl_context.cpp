#include "render/gl_context.h"

#define GL_GLEXT_PROTOTYPES
#include <GL/osmesa.h>
#include <GL/gl.h>

#include <vector>

#include "volume/core/error.h"

namespace hyb {

struct GlContext::Impl {
  OSMesaContext context = nullptr;
  std::vector<unsigned char> buffer = std::vector<unsigned char>(4);
};

GlContext::GlContext() : GlContext(nullptr) {}

GlContext::GlContext(const GlContext* share) : mImpl(std::make_unique<Impl>()) {
  const int attribs[] = {OSMESA_FORMAT, OSMESA_RGBA, OSMESA_DEPTH_BITS, 24, OSMESA_PROFILE, OSMESA_CORE_PROFILE,
                         OSMESA_CONTEXT_MAJOR_VERSION, 4, OSMESA_CONTEXT_MINOR_VERSION, 5, 0};
  mImpl->context = OSMesaCreateContextAttribs(attribs, share ? share->mImpl->context : nullptr);
  if (!mImpl->context) HYB_THROW(RuntimeError, "OSMesa could not create an OpenGL 4.5 core context (is libosmesa6 installed?)");
  if (!OSMesaMakeCurrent(mImpl->context, mImpl->buffer.data(), GL_UNSIGNED_BYTE, 1, 1)) {
    OSMesaDestroyContext(mImpl->context);
    HYB_THROW(RuntimeError, "OSMesa could not make the OpenGL context current");
  }
}

void GlContext::makeCurrent() {
  if (OSMesaGetCurrentContext() == mImpl->context) return;
  if (!OSMesaMakeCurrent(mImpl->context, mImpl->buffer.data(), GL_UNSIGNED_BYTE, 1, 1))
    HYB_THROW(RuntimeError, "OSMesa could not make the OpenGL context current");
}

GlContext::~GlContext() {
  if (!mImpl || !mImpl->context) return;
  if (OSMesaGetCurrentContext() == mImpl->context) OSMesaMakeCurrent(nullptr, nullptr, 0, 0, 0);
  OSMesaDestroyContext(mImpl->context);
}

std::string GlContext::description() const {
  const auto* r = reinterpret_cast<const char*>(glGetString(GL_RENDERER));
  const auto* v = reinterpret_cast<const char*>(glGetString(GL_VERSION));
  return std::string(r ? r : "?") + ", OpenGL " + (v ? v : "?");
}

}  // namespace hyb
