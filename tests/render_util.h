// Scene pieces shared by the renderer tests (the ray tracer's and the slice renderer's).
#pragma once

#include <algorithm>
#include <cmath>
#include <vector>

#include "hybrid_octree/hybrid_io.h"
#include "render/camera.h"
#include "render/gl_context.h"
#include "render/image.h"
#include "render/transfer_function.h"
#include "surface/mesh.h"
#include "test_util.h"
#include "volume/volume_io.h"

namespace hyb::test {

/// One OpenGL context for the tests that draw directly (creating one costs a few milliseconds on
/// llvmpipe), made current again on each call: a scene renderer makes (and destroys) its own.
inline GlContext& gl() {
  static GlContext context;
  context.makeCurrent();
  return context;
}

/// A scene of the analytic sphere (radius 13 voxels in 40×36×32 unless told) with its Volume Octree.
inline Scene sphereScene(glm::ivec3 dims = {40, 36, 32}, double radius = 13.0) {
  Scene s;
  s.volume = sphereVolume(dims, radius);
  s.octree = VolumeOctree::build(s.volume);
  return s;
}

/// A scene of the real CT (InVesalius' cranium, kDefaultVolumePath) with its Volume Octree.
inline Scene craniumScene() {
  Scene s;
  s.volume = readVolume(kDefaultVolumePath);
  s.octree = VolumeOctree::build(s.volume);
  return s;
}

/// PSNR of two float images composited over black, in dB.
inline double psnrOf(const Image& a, const Image& b) { return psnr(toRgba8(a, glm::vec3(0)), toRgba8(b, glm::vec3(0))); }

/// Isolated black pixels of @p image composited over black (x, y): a pixel whose brightest channel
/// is at most a tenth of the dimmest of its 8 neighbours', those at least 30/255 (a darker pixel
/// among bright ones is aliasing, not a hole), or whose colour is not finite. A pixel also dark in @p reference (the same view's ray-traced image, when given) is
/// content, not a speck, and is not counted.
inline std::vector<glm::ivec2> isolatedBlackPixels(const Image& image, const Image* reference = nullptr) {
  auto brightest = [](const Image& im, int x, int y) {
    const glm::vec4 p = im.at(std::clamp(x, 0, im.width - 1), std::clamp(y, 0, im.height - 1));
    return std::max({p.r, p.g, p.b});
  };
  auto dark = [&](const Image& im, int x, int y) {
    const glm::vec4 p = im.at(x, y);
    if (!(std::isfinite(p.r) && std::isfinite(p.g) && std::isfinite(p.b) && std::isfinite(p.a))) return true;
    float around = 1e30f;
    for (int dy = -1; dy <= 1; ++dy)
      for (int dx = -1; dx <= 1; ++dx)
        if (dx || dy) around = std::min(around, brightest(im, x + dx, y + dy));
    return around >= 30.0f / 255.0f && brightest(im, x, y) <= 0.1f * around;
  };
  std::vector<glm::ivec2> out;
  for (int y = 0; y < image.height; ++y)
    for (int x = 0; x < image.width; ++x)
      if (dark(image, x, y) && !(reference && dark(*reference, x, y))) out.emplace_back(x, y);
  return out;
}

/// One material for every value in [0, 2]: colour (0.8, 0.5, 0.2), opacity @p a per mm.
inline TransferFunction constantTf(float a) {
  return TransferFunction({{0.0f, {0.8f, 0.5f, 0.2f}, a}, {2.0f, {0.8f, 0.5f, 0.2f}, a}}, "constant");
}

/// Two triangles forming the square z = zq over [x0, x1] x [y0, y1], mm, facing +z.
inline TriangleMesh quadAt(double zq, double x0, double x1, double y0, double y1) {
  TriangleMesh m;
  m.vertices = {{x0, y0, zq}, {x1, y0, zq}, {x1, y1, zq}, {x0, y1, zq}};
  m.triangles = {{0, 1, 2}, {0, 2, 3}};
  return m;
}

/// An orthographic camera looking straight down -z at @p centre (from 60 mm above it), @p height mm
/// tall, @p pixels square: pixel (x, y) sees centre + ((x + ½)/pixels − ½, ½ − (y + ½)/pixels)·height.
inline Camera orthoDown(const glm::dvec3& centre, double height, int pixels) {
  Camera c;
  c.center = centre;
  c.eye = centre + glm::dvec3(0, 0, 60);
  c.up = glm::dvec3(0, 1, 0);
  c.ortho = true;
  c.orthoHeight = height;
  c.width = c.height = pixels;
  return c;
}

/// A square perspective camera at @p eye looking at @p centre.
inline Camera perspective(const glm::dvec3& eye, const glm::dvec3& centre, const glm::dvec3& up, double fovDeg, int pixels) {
  Camera c;
  c.eye = eye;
  c.center = centre;
  c.up = up;
  c.fovDeg = fovDeg;
  c.width = c.height = pixels;
  return c;
}

/// A 3x3 perspective camera at (4, 4, 4) looking down -z: inside a volume that spans z = 0…8.
inline Camera insideCamera() {
  Camera c;
  c.eye = glm::dvec3(4, 4, 4);
  c.center = glm::dvec3(4, 4, 0);
  c.up = glm::dvec3(0, 1, 0);
  c.width = c.height = 3;
  return c;
}

}  // namespace hyb::test
