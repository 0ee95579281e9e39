#include "render/gl_objects.h"

#include <algorithm>
#include <atomic>
#include <exception>
#include <thread>

#include "render/gl_context.h"

#include "volume/core/error.h"

namespace hyb::gl {

Shader compileShader(GLenum type, const std::string& source) {
  Shader s(glCreateShader(type));
  const char* text = source.c_str();
  glShaderSource(s.id(), 1, &text, nullptr);
  glCompileShader(s.id());
  GLint ok = 0;
  glGetShaderiv(s.id(), GL_COMPILE_STATUS, &ok);
  if (!ok) {
    char log[2048];
    glGetShaderInfoLog(s.id(), sizeof log, nullptr, log);
    HYB_THROW(RuntimeError, "shader compilation failed: ", log);
  }
  return s;
}

Program linkProgram(const std::string& vertex, const std::string& fragment) {
  const Shader v = compileShader(GL_VERTEX_SHADER, vertex), f = compileShader(GL_FRAGMENT_SHADER, fragment);
  Program p = Program::make();
  glAttachShader(p.id(), v.id());
  glAttachShader(p.id(), f.id());
  glLinkProgram(p.id());
  GLint ok = 0;
  glGetProgramiv(p.id(), GL_LINK_STATUS, &ok);
  if (!ok) HYB_THROW(RuntimeError, "shader program failed to link");
  return p;
}

Texture volumeTexture() {
  Texture tex = Texture::make();
  glActiveTexture(GL_TEXTURE0);
  glBindTexture(GL_TEXTURE_3D, tex.id());
  glTexParameteri(GL_TEXTURE_3D, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
  glTexParameteri(GL_TEXTURE_3D, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
  for (GLenum w : {GL_TEXTURE_WRAP_S, GL_TEXTURE_WRAP_T, GL_TEXTURE_WRAP_R}) glTexParameteri(GL_TEXTURE_3D, w, GL_CLAMP_TO_EDGE);
  glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
  return tex;
}

Texture FloatTarget::colorTexture(int width, int height) {
  Texture color = Texture::make();
  glBindTexture(GL_TEXTURE_2D, color.id());
  glTexImage2D(GL_TEXTURE_2D, 0, GL_RGBA32F, width, height, 0, GL_RGBA, GL_FLOAT, nullptr);
  return color;
}

Renderbuffer FloatTarget::depthBuffer(int width, int height) {
  Renderbuffer depth = Renderbuffer::make();
  glBindRenderbuffer(GL_RENDERBUFFER, depth.id());
  glRenderbufferStorage(GL_RENDERBUFFER, GL_DEPTH_COMPONENT24, width, height);
  return depth;
}

FloatTarget::FloatTarget(int width, int height) : FloatTarget(width, height, colorTexture(width, height), depthBuffer(width, height)) {}

FloatTarget::FloatTarget(int width, int height, Texture color, Renderbuffer depth)
    : mWidth(width), mHeight(height), mFramebuffer(Framebuffer::make()), mColor(std::move(color)), mDepth(std::move(depth)) {
  glBindFramebuffer(GL_FRAMEBUFFER, mFramebuffer.id());
  glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, mColor.id(), 0);
  glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, mDepth.id());
  if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE)
    HYB_THROW(RuntimeError, "OpenGL framebuffer incomplete for a ", width, "x", height, " float image");
  glViewport(0, 0, width, height);
}

void FloatTarget::bind() const {
  glBindFramebuffer(GL_FRAMEBUFFER, mFramebuffer.id());
  glViewport(0, 0, mWidth, mHeight);
}

struct TargetCache::Prepared {
  int width = 0, height = 0;
  Texture color;
  Renderbuffer depth;
  std::exception_ptr error;
  std::atomic<bool> done{false};
  std::thread thread;
};

TargetCache::TargetCache() = default;

TargetCache::~TargetCache() {
  if (mPrepared) mPrepared->thread.join();
}

void TargetCache::keep(std::unique_ptr<FloatTarget> target, bool recent) {
  if (mTargets.size() >= kKept) mTargets.erase(mTargets.begin());
  mTargets.insert(recent ? mTargets.end() : mTargets.begin(), std::move(target));
}

bool TargetCache::adoptPrepared(bool wait) {
  if (!mPrepared || (!wait && !mPrepared->done)) return false;
  mPrepared->thread.join();
  const std::unique_ptr<Prepared> p = std::move(mPrepared);
  if (p->error) return false;  // (get() makes its own, and says why when it cannot)
  try {
    keep(std::make_unique<FloatTarget>(p->width, p->height, std::move(p->color), std::move(p->depth)), wait);
  } catch (const RuntimeError&) {
    return false;
  }
  return true;
}

std::vector<std::unique_ptr<FloatTarget>>::iterator TargetCache::kept(int width, int height) {
  return std::find_if(mTargets.begin(), mTargets.end(), [&](const auto& t) { return t->width() == width && t->height() == height; });
}

FloatTarget& TargetCache::get(int width, int height) {
  const bool ahead = mPrepared && mPrepared->width == width && mPrepared->height == height;
  mMadeAhead += adoptPrepared(ahead) && ahead;
  if (const auto it = kept(width, height); it != mTargets.end()) {
    std::rotate(it, it + 1, mTargets.end());  // the most recently used last
    mTargets.back()->bind();
    return *mTargets.back();
  }
  keep(std::make_unique<FloatTarget>(width, height), true);
  return *mTargets.back();
}

void TargetCache::prepare(int width, int height, const GlContext& context) {
  adoptPrepared(false);
  if (mPrepared || kept(width, height) != mTargets.end()) return;
  auto p = std::make_unique<Prepared>();
  p->width = width;
  p->height = height;
  p->thread = std::thread([p = p.get(), &context] {
    try {
      const GlContext own(&context);
      p->color = FloatTarget::colorTexture(p->width, p->height);
      p->depth = FloatTarget::depthBuffer(p->width, p->height);
      glFinish();  // (the texture and renderbuffer outlive this context: the other one shares them)
    } catch (...) {
      p->error = std::current_exception();
    }
    p->done = true;
  });
  mPrepared = std::move(p);  // (only once its thread runs: the destructor joins it)
}

}  // namespace hyb::gl
