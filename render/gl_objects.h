// OpenGL objects that delete themselves: a frame that throws leaks nothing, and the next frame in
// the same context starts clean. Each wraps one name; moving transfers it, copying is not allowed.
// Their owner must destroy them while the GlContext that made them is current.
#pragma once

#define GL_GLEXT_PROTOTYPES
#include <GL/gl.h>
#include <GL/glext.h>

#include <memory>
#include <string>
#include <vector>
#include <utility>

namespace hyb {
class GlContext;
}

namespace hyb::gl {

/// One OpenGL name of a kind (Traits::create/destroy), deleted with its owner.
template <class Traits>
class Object {
 public:
  Object() = default;
  /// Makes a new object.
  static Object make() {
    Object o;
    o.mId = Traits::create();
    return o;
  }
  /// Takes ownership of @p id (0: none).
  explicit Object(GLuint id) : mId(id) {}
  Object(Object&& o) noexcept : mId(std::exchange(o.mId, 0u)) {}
  Object& operator=(Object&& o) noexcept {
    if (this != &o) {
      reset();
      mId = std::exchange(o.mId, 0u);
    }
    return *this;
  }
  Object(const Object&) = delete;
  Object& operator=(const Object&) = delete;
  ~Object() { reset(); }

  GLuint id() const { return mId; }
  explicit operator bool() const { return mId != 0; }
  /// Hands the name over without deleting it.
  GLuint release() { return std::exchange(mId, 0u); }
  void reset() {
    if (mId) Traits::destroy(mId);
    mId = 0;
  }

 private:
  GLuint mId = 0;
};

struct TextureTraits {
  static GLuint create() { GLuint id = 0; glGenTextures(1, &id); return id; }
  static void destroy(GLuint id) { glDeleteTextures(1, &id); }
};
struct BufferTraits {
  static GLuint create() { GLuint id = 0; glGenBuffers(1, &id); return id; }
  static void destroy(GLuint id) { glDeleteBuffers(1, &id); }
};
struct VertexArrayTraits {
  static GLuint create() { GLuint id = 0; glGenVertexArrays(1, &id); return id; }
  static void destroy(GLuint id) { glDeleteVertexArrays(1, &id); }
};
struct FramebufferTraits {
  static GLuint create() { GLuint id = 0; glGenFramebuffers(1, &id); return id; }
  static void destroy(GLuint id) { glDeleteFramebuffers(1, &id); }
};
struct RenderbufferTraits {
  static GLuint create() { GLuint id = 0; glGenRenderbuffers(1, &id); return id; }
  static void destroy(GLuint id) { glDeleteRenderbuffers(1, &id); }
};
struct QueryTraits {
  static GLuint create() { GLuint id = 0; glGenQueries(1, &id); return id; }
  static void destroy(GLuint id) { glDeleteQueries(1, &id); }
};
struct ProgramTraits {
  static GLuint create() { return glCreateProgram(); }
  static void destroy(GLuint id) { glDeleteProgram(id); }
};
struct ShaderTraits {
  static void destroy(GLuint id) { glDeleteShader(id); }
};

using Texture = Object<TextureTraits>;
using Buffer = Object<BufferTraits>;
using VertexArray = Object<VertexArrayTraits>;
using Framebuffer = Object<FramebufferTraits>;
using Renderbuffer = Object<RenderbufferTraits>;
using Query = Object<QueryTraits>;
using Program = Object<ProgramTraits>;
using Shader = Object<ShaderTraits>;

/// Compiles @p type shader @p source. @throw RuntimeError with the compiler's log.
Shader compileShader(GLenum type, const std::string& source);
/// Links a program of a vertex and a fragment shader. @throw RuntimeError when either fails.
Program linkProgram(const std::string& vertex, const std::string& fragment);
/// A 3D texture on unit 0, bound, with trilinear filtering and clamped edges.
Texture volumeTexture();

/// A float colour (premultiplied RGBA32F) and 24-bit depth render target, bound and its
/// viewport set while it lives.
class FloatTarget {
 public:
  /// @throw RuntimeError when the framebuffer is incomplete.
  FloatTarget(int width, int height);
  /// The same of a colour texture and depth renderbuffer made by colorTexture and depthBuffer (in
  /// a context sharing this one's objects).
  FloatTarget(int width, int height, Texture color, Renderbuffer depth);
  static Texture colorTexture(int width, int height);
  static Renderbuffer depthBuffer(int width, int height);
  /// Binds it and sets the viewport to it again.
  void bind() const;
  int width() const { return mWidth; }
  int height() const { return mHeight; }

 private:
  int mWidth, mHeight;
  Framebuffer mFramebuffer;
  Texture mColor;
  Renderbuffer mDepth;
};

/// The float targets of the last few sizes drawn, kept across frames: llvmpipe zeroes a target's
/// memory when it is made (80 MB for 2048², most of a 2048² frame's narrow band), and a large
/// frame's bands alternate with other clients' smaller frames.
class TargetCache {
 public:
  TargetCache();
  TargetCache(const TargetCache&) = delete;
  TargetCache& operator=(const TargetCache&) = delete;
  /// Waits for a target on its way (its owner's context current).
  ~TargetCache();
  /// A target of @p width x @p height, bound (the least recently used one is let go beyond kKept).
  FloatTarget& get(int width, int height);
  /// Starts making a target of @p width x @p height on a thread of its own, in a context sharing
  /// @p context's objects, unless it is kept or another is on its way: made by get() on the render
  /// thread, a 2048² target's memory holds that thread for its page faults, and the other clients'
  /// frames with it (docs/viewer.md). @p context must be current (a target made ahead
  /// before may be taken into the cache). @throw std::system_error when no thread can start.
  void prepare(int width, int height, const GlContext& context);
  /// Targets get() returned that prepare() had made.
  size_t madeAhead() const { return mMadeAhead; }

 private:
  struct Prepared;
  /// Takes the target made by prepare() into the cache, when it is done or (@p wait) once it is,
  /// as the most recently used when waited for, else as the least; whether it did (one whose
  /// making failed is dropped: get() makes its own).
  bool adoptPrepared(bool wait);
  void keep(std::unique_ptr<FloatTarget> target, bool recent);
  /// The kept target of @p width x @p height, or mTargets.end().
  std::vector<std::unique_ptr<FloatTarget>>::iterator kept(int width, int height);
  static constexpr size_t kKept = 3;
  std::vector<std::unique_ptr<FloatTarget>> mTargets;  // the most recently used last
  std::unique_ptr<Prepared> mPrepared;
  size_t mMadeAhead = 0;
};

}  // namespace hyb::gl
