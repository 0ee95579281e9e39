#include "bench/plain_quads.h"

#include <chrono>
#include <vector>

#include "render/slices/brick_textures.h"
#include "render/gl_objects.h"

namespace hyb::bench {

double plainQuadSeconds(const Volume& volume, int width, int height, int quads, uint64_t* fragments, bool brickFormat) {
  static constexpr const char* kVertex = R"(#version 450 core
layout(location = 0) in vec2 position;
uniform float layer;
out vec3 uvw;
void main() { uvw = vec3(position * 0.5 + 0.5, layer); gl_Position = vec4(position, 0.0, 1.0); }
)";
  static constexpr const char* kFragment = R"(#version 450 core
in vec3 uvw;
out vec4 fragColor;
uniform sampler3D tex;
void main() { float v = texture(tex, uvw).r; fragColor = vec4(v, v, v, 1.0) * 0.001; }
)";
  const gl::FloatTarget target(width, height);
  glDisable(GL_DEPTH_TEST);
  glEnable(GL_BLEND);
  glBlendFunc(GL_ONE, GL_ONE_MINUS_SRC_ALPHA);
  const glm::ivec3 d = volume.dims();
  gl::Texture tex;
  if (brickFormat) {
    std::vector<glm::vec4> texels;
    texels.reserve(volume.voxelCount());
    for (size_t i = 0; i < volume.voxelCount(); ++i) texels.emplace_back(volume.value(i), 0.0f, 0.0f, 0.0f);
    tex = uploadBrick(packBrick(texels, TexelBits::Eight), d, TexelBits::Eight).texture;
  } else {
    tex = gl::volumeTexture();
    std::vector<float> values(volume.voxelCount());  // the baseline uploads the whole volume as float
    for (size_t i = 0; i < values.size(); ++i) values[i] = volume.value(i);
    glTexImage3D(GL_TEXTURE_3D, 0, GL_R32F, d.x, d.y, d.z, 0, GL_RED, GL_FLOAT, values.data());
  }
  const gl::Program program = gl::linkProgram(kVertex, kFragment);
  glUseProgram(program.id());
  const float quad[] = {-1, -1, 1, -1, 1, 1, -1, -1, 1, 1, -1, 1};
  const gl::VertexArray vao = gl::VertexArray::make();
  glBindVertexArray(vao.id());
  const gl::Buffer vbo = gl::Buffer::make();
  glBindBuffer(GL_ARRAY_BUFFER, vbo.id());
  glBufferData(GL_ARRAY_BUFFER, sizeof quad, quad, GL_STATIC_DRAW);
  glEnableVertexAttribArray(0);
  glVertexAttribPointer(0, 2, GL_FLOAT, GL_FALSE, 0, nullptr);
  float pixel[4];
  glReadPixels(0, 0, 1, 1, GL_RGBA, GL_FLOAT, pixel);  // the upload is done before timing
  const gl::Query query = gl::Query::make();
  const auto t0 = std::chrono::steady_clock::now();
  glBeginQuery(GL_FRAGMENT_SHADER_INVOCATIONS_ARB, query.id());
  const GLint layer = glGetUniformLocation(program.id(), "layer");
  for (int q = 0; q < quads; ++q) {
    glUniform1f(layer, (float(q) + 0.5f) / float(quads));
    glDrawArrays(GL_TRIANGLES, 0, 6);
  }
  glEndQuery(GL_FRAGMENT_SHADER_INVOCATIONS_ARB);
  glReadPixels(0, 0, 1, 1, GL_RGBA, GL_FLOAT, pixel);  // waits for the quads
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  GLuint count = 0;
  glGetQueryObjectuiv(query.id(), GL_QUERY_RESULT, &count);
  *fragments = count;
  return seconds;
}

}  // namespace hyb::bench
