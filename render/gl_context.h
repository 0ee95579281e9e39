// RAII off-screen OpenGL 4.5 core context (OSMesa, llvmpipe). The only place OSMesa appears.
#pragma once

#include <memory>
#include <string>

namespace hyb {

/// An OpenGL 4.5 core context current on this thread for its lifetime. Rendering goes to
/// framebuffer objects; the OSMesa buffer itself is a 1x1 placeholder.
class GlContext {
 public:
  /// @throw RuntimeError when no 4.5 core context can be created.
  GlContext();
  ~GlContext();
  GlContext(const GlContext&) = delete;
  GlContext& operator=(const GlContext&) = delete;

  /// GL_RENDERER and GL_VERSION.
  std::string description() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> mImpl;
};

}  // namespace hyb
