#include "render/gl_objects.h"

#include <algorithm>

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

FloatTarget::FloatTarget(int width, int height)
    : mWidth(width), mHeight(height), mFramebuffer(Framebuffer::make()), mColor(Texture::make()), mDepth(Renderbuffer::make()) {
  glBindFramebuffer(GL_FRAMEBUFFER, mFramebuffer.id());
  glBindTexture(GL_TEXTURE_2D, mColor.id());
  glTexImage2D(GL_TEXTURE_2D, 0, GL_RGBA32F, width, height, 0, GL_RGBA, GL_FLOAT, nullptr);
  glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, mColor.id(), 0);
  glBindRenderbuffer(GL_RENDERBUFFER, mDepth.id());
  glRenderbufferStorage(GL_RENDERBUFFER, GL_DEPTH_COMPONENT24, width, height);
  glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, mDepth.id());
  if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE)
    HYB_THROW(RuntimeError, "OpenGL framebuffer incomplete for a ", width, "x", height, " float image");
  glViewport(0, 0, width, height);
}

void FloatTarget::bind() const {
  glBindFramebuffer(GL_FRAMEBUFFER, mFramebuffer.id());
  glViewport(0, 0, mWidth, mHeight);
}

FloatTarget& TargetCache::get(int width, int height) {
  const auto it = std::find_if(mTargets.begin(), mTargets.end(), [&](const auto& t) { return t->width() == width && t->height() == height; });
  if (it != mTargets.end()) {
    std::rotate(it, it + 1, mTargets.end());  // the most recently used last
    mTargets.back()->bind();
    return *mTargets.back();
  }
  if (mTargets.size() >= kKept) mTargets.erase(mTargets.begin());
  mTargets.push_back(std::make_unique<FloatTarget>(width, height));
  return *mTargets.back();
}

}  // namespace hyb::gl
