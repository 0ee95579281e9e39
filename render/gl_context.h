// RAII off-screen OpenGL 4.5 core context (OSMesa, llvmpipe). The only place OSMesa appears.
#pragma once

#include <memory>
#include <string>

namespace hyb {

/// An OpenGL 4.5 core context, made current on this thread when it is created. Rendering goes to
/// framebuffer objects; the OSMesa buffer itself is a 1x1 placeholder. With several contexts on one
/// thread, makeCurrent() before drawing with one (a destroyed context leaves none current).
class GlContext {
 public:
  /// @throw RuntimeError when no 4.5 core context can be created.
  GlContext();
  /// A context sharing @p share's textures, buffers and renderbuffers, current on the calling
  /// thread: what it makes there, @p share's thread can use once it is made (glFinish).
  explicit GlContext(const GlContext* share);
  ~GlContext();
  GlContext(const GlContext&) = delete;
  GlContext& operator=(const GlContext&) = delete;

  /// Makes this context current on the calling thread. @throw RuntimeError when OSMesa refuses.
  void makeCurrent();
  /// GL_RENDERER and GL_VERSION.
  std::string description() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> mImpl;
};

}  // namespace hyb
