#include "render/slices/cut_plane_pass.h"

#include <glm/gtc/type_ptr.hpp>

#include "render/slices/shaders.h"

namespace hyb {

uint64_t drawCutPlane(GLuint program, const std::vector<CutPiece>& pieces) {
  auto at = [&](const char* name) { return glGetUniformLocation(program, name); };
  glUseProgram(program);
  glUniform1i(at("cutTex"), 0);
  glUniform4f(at("cutPlane"), 0.0f, 0.0f, 0.0f, 1.0f);  // the plane is not clipped by itself
  std::vector<float> all;
  for (const CutPiece& p : pieces) all.insert(all.end(), p.polygon.begin(), p.polygon.end());
  const gl::Buffer buffer = gl::Buffer::make();
  glBindBuffer(GL_ARRAY_BUFFER, buffer.id());
  glBufferData(GL_ARRAY_BUFFER, GLsizeiptr(all.size() * sizeof(float)), all.data(), GL_STREAM_DRAW);
  glVertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, 3 * sizeof(float), nullptr);
  glDisableVertexAttribArray(1);
  glDisableVertexAttribArray(2);
  glDepthMask(GL_TRUE);
  glActiveTexture(GL_TEXTURE0);
  GLint first = 0;
  uint64_t drawn = 0;
  for (const CutPiece& p : pieces) {
    if (p.polygon.empty()) continue;
    glBindTexture(GL_TEXTURE_3D, p.texture);
    glUniform3fv(at("fineScale"), 1, glm::value_ptr(p.fineScale));
    glUniform3fv(at("fineOffset"), 1, glm::value_ptr(p.fineOffset));
    glUniform1f(at("valueOffset"), p.valueOffset);
    glUniform1f(at("valueScale"), p.valueScale);
    const GLsizei count = GLsizei(p.polygon.size() / 3);
    glDrawArrays(GL_TRIANGLES, first, count);
    first += count;
    ++drawn;
  }
  glDepthMask(GL_FALSE);
  glEnableVertexAttribArray(1);
  glEnableVertexAttribArray(2);
  return drawn;
}

uint64_t drawCutLine(const TriangleMesh& surface, const glm::dvec4& cut, const glm::mat4& viewProj, const glm::vec4& color) {
  std::vector<float> lines;
  uint64_t segments = 0;
  for (const glm::uvec3& t : surface.triangles) {
    glm::dvec3 p[3];
    double s[3];
    for (int k = 0; k < 3; ++k) {
      p[k] = glm::dvec3(surface.vertices[t[k]]);
      s[k] = glm::dot(glm::dvec3(cut), p[k]) + cut.w;
    }
    glm::dvec3 ends[3];
    int n = 0;
    for (int k = 0; k < 3; ++k) {
      const int j = (k + 1) % 3;
      if ((s[k] < 0) != (s[j] < 0)) ends[n++] = p[k] + (p[j] - p[k]) * (s[k] / (s[k] - s[j]));
    }
    if (n != 2) continue;
    for (int e = 0; e < 2; ++e) lines.insert(lines.end(), {float(ends[e].x), float(ends[e].y), float(ends[e].z), 0, 0, 0});
    ++segments;
  }
  if (lines.empty()) return 0;
  static constexpr const char* kLineFragment = R"(#version 450 core
out vec4 fragColor;
uniform vec3 color;
void main() { fragColor = vec4(color, 1.0); }
)";
  const gl::Program program = gl::linkProgram(shaders::kWorldVertex, kLineFragment);
  glUseProgram(program.id());
  glUniformMatrix4fv(glGetUniformLocation(program.id(), "viewProj"), 1, GL_FALSE, glm::value_ptr(viewProj));
  glUniform4f(glGetUniformLocation(program.id(), "cutPlane"), 0, 0, 0, 1);
  glUniform3f(glGetUniformLocation(program.id(), "color"), color.r, color.g, color.b);
  const gl::Buffer buffer = gl::Buffer::make();
  glBindBuffer(GL_ARRAY_BUFFER, buffer.id());
  glBufferData(GL_ARRAY_BUFFER, GLsizeiptr(lines.size() * sizeof(float)), lines.data(), GL_STREAM_DRAW);
  glVertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, 6 * sizeof(float), nullptr);
  glVertexAttribPointer(1, 3, GL_FLOAT, GL_FALSE, 6 * sizeof(float), reinterpret_cast<void*>(3 * sizeof(float)));
  glDisableVertexAttribArray(2);
  glDisable(GL_DEPTH_TEST);
  glBlendFunc(GL_ONE, GL_ZERO);
  glDrawArrays(GL_LINES, 0, GLsizei(lines.size() / 6));
  glBlendFunc(GL_ONE, GL_ONE_MINUS_SRC_ALPHA);
  glEnable(GL_DEPTH_TEST);
  return segments;
}

}  // namespace hyb
