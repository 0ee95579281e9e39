#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "render/cut_plane.h"
#include "render/raycast.h"
#include "render_util.h"
#include "test_util.h"
#include "volume/volume_io.h"

namespace hyb {
namespace {

using test::constantTf;
using test::psnrOf;
using test::quadAt;

// Orthographic camera looking along -dir from outside the box centre.
Camera orthoAlong(const Volume& v, glm::dvec3 dir, int size = 8) {
  Camera c;
  c.center = 0.5 * v.extentMm();
  c.eye = c.center + glm::normalize(dir) * 100.0;
  c.up = std::abs(dir.z) > 0.9 ? glm::dvec3(0, 1, 0) : glm::dvec3(0, 0, 1);
  c.ortho = true;
  c.orthoHeight = 2.0;  // a small window around the centre ray
  c.width = c.height = size;
  return c;
}

glm::vec4 centre(const Image& img) { return img.at(img.width / 2, img.height / 2); }

constexpr float kTol = 1.0f / 255.0f;

TEST(Raycast, HomogeneousSlabMatchesClosedFormAtAnyStep) {
  // 21 x 21 x 11 voxels of 1 mm: 10 mm of material along z.
  const Volume v = test::makeVolume({21, 21, 11}, [](int, int, int) { return 0.5f; });
  const VolumeOctree t = VolumeOctree::build(v);
  const float a = 0.1f;
  const double D = 10.0;
  const float alpha = 1.0f - std::pow(1.0f - a, float(D));
  for (double step : {0.25, 0.5, 1.0}) {
    RaycastOptions o;
    o.stepVoxels = step;
    o.shading = false;
    const glm::vec4 p = centre(raycast(v, t, constantTf(a), orthoAlong(v, {0, 0, 1}), o));
    EXPECT_NEAR(p.a, alpha, kTol) << step;
    EXPECT_NEAR(p.r, 0.8f * alpha, kTol) << step;
    EXPECT_NEAR(p.b, 0.2f * alpha, kTol) << step;
  }
}

TEST(Raycast, TranslucentQuadInsideASlabAlongSeveralDirections) {
  const Volume v = test::makeVolume({21, 21, 11}, [](int, int, int) { return 0.5f; });
  const VolumeOctree t = VolumeOctree::build(v);
  const float a = 0.08f;
  const glm::vec4 surface(0.1f, 0.9f, 0.3f, 0.6f);
  const glm::vec3 c(0.8f, 0.5f, 0.2f);
  // Quad planes at a generic depth, exactly on a sample boundary (z = 4 mm with 0.25-voxel steps
  // from the entry at 10 mm), and at the slab's front face.
  for (double zq : {3.3, 4.0, 9.9}) {
    const TriangleMesh quad = quadAt(zq, -5, 25, -5, 25);
    const Bvh bvh(quad);
    for (const glm::dvec3 dir : {glm::dvec3(0, 0, 1), glm::dvec3(0.3, 0.2, 1), glm::dvec3(1, 1, 1), glm::dvec3(0, 1, 1)}) {
      const glm::dvec3 u = glm::normalize(dir);
      RaycastOptions o;
      o.shading = false;
      o.surface = &bvh;
      o.surfaceColor = surface;
      const glm::vec4 p = centre(raycast(v, t, constantTf(a), orthoAlong(v, dir), o));
      // Front part (z from 10 down to zq) and back part (zq down to 0), lengths along the ray.
      const double front = (10.0 - zq) / u.z, back = zq / u.z;
      const float a1 = 1.0f - std::pow(1.0f - a, float(front)), a2 = 1.0f - std::pow(1.0f - a, float(back));
      const float shade = float(0.25 + 0.75 * u.z);  // headlight on the quad's normal (0, 0, 1)
      const glm::vec3 expected = c * a1 + (1 - a1) * (glm::vec3(surface) * shade * surface.a + (1 - surface.a) * c * a2);
      const float expectedA = a1 + (1 - a1) * (surface.a + (1 - surface.a) * a2);
      EXPECT_NEAR(p.a, expectedA, kTol) << "zq " << zq << " dir " << dir.x << "," << dir.y << "," << dir.z;
      for (int k = 0; k < 3; ++k) EXPECT_NEAR(p[k], expected[k], kTol) << "zq " << zq << " channel " << k;
      // The quad composited behind all of the volume (a wrong depth order) is far from the pixel.
      const float av = 1.0f - std::pow(1.0f - a, float(front + back));
      const glm::vec3 behind = c * av + (1 - av) * glm::vec3(surface) * shade * surface.a;
      if (zq < 9.0) {
        EXPECT_GT(glm::length(glm::vec3(p) - behind), 3 * kTol);
      }
    }
  }
}

TEST(Raycast, OpaqueSurfaceEndsTheRayAndShadingUsesTheHeadlight) {
  const Volume v = test::makeVolume({11, 11, 11}, [](int, int, int) { return 0.5f; });
  const VolumeOctree t = VolumeOctree::build(v);
  const TriangleMesh quad = quadAt(5.0, -1, 11, -1, 11);
  const Bvh bvh(quad);
  RaycastOptions o;
  o.shading = false;
  o.surface = &bvh;
  o.surfaceColor = glm::vec4(0.2f, 0.4f, 0.6f, 1.0f);
  const float a = 0.05f, a1 = 1.0f - std::pow(1.0f - a, 5.0f);
  const glm::vec4 p = centre(raycast(v, t, constantTf(a), orthoAlong(v, {0, 0, 1}), o));
  EXPECT_NEAR(p.a, 1.0f, kTol);
  EXPECT_NEAR(p.b, 0.2f * a1 + (1 - a1) * 0.6f, kTol);  // nothing behind the opaque quad
}

TEST(Raycast, EmptySpaceSkippingDoesNotChangeTheImage) {
  const Volume v = test::sphereVolume({40, 36, 30}, 11.0);  // values > 0 inside
  const VolumeOctree t = VolumeOctree::build(v);
  const TransferFunction tf({{0.0f, {1, 1, 1}, 0.0f}, {2.0f, {1.0f, 0.6f, 0.3f}, 0.3f}, {12.0f, {1, 1, 1}, 0.6f}}, "sphere");
  const Camera cam = Camera::orbit(glm::dvec3(0.0), v.extentMm(), {35, 20, 30, false, 48, 40});
  RaycastOptions o;
  RaycastStats with, without;
  const Image a = raycast(v, t, tf, cam, o, &with);
  o.skipEmptySpace = false;
  const Image b = raycast(v, t, tf, cam, o, &without);
  EXPECT_EQ(toRgba8(a, glm::vec3(0)), toRgba8(b, glm::vec3(0)));
  EXPECT_GT(with.skippedLeaves, uint64_t(0));
  EXPECT_LT(with.samples, without.samples / 2);
}

// A progress callback that stops the frame part way is heard as an exception from raycast(),
// though the rays are traced on OpenMP's threads; the next frame is as before.
TEST(Raycast, AProgressCallbackThatThrowsStopsTheFrame) {
  const Volume v = test::sphereVolume({40, 36, 30}, 11.0);
  const VolumeOctree t = VolumeOctree::build(v);
  const TransferFunction tf({{0.0f, {1, 1, 1}, 0.0f}, {2.0f, {1.0f, 0.6f, 0.3f}, 0.3f}, {12.0f, {1, 1, 1}, 0.6f}}, "sphere");
  const Camera cam = Camera::orbit(glm::dvec3(0.0), v.extentMm(), {35, 20, 30, false, 48, 40});
  RaycastOptions o;
  const Image before = raycast(v, t, tf, cam, o);
  const Progress stop([](const std::string&, double fraction) {
    if (fraction >= 0.5 && fraction < 1.0) throw std::runtime_error("stopped");
  });
  o.progress = &stop;
  EXPECT_THROW(raycast(v, t, tf, cam, o), std::runtime_error);
  o.progress = nullptr;
  EXPECT_EQ(raycast(v, t, tf, cam, o).pixels, before.pixels);
}

TEST(Raycast, ProgressiveRefinementEndsWithTheExactImage) {
  // Levoy's progressive refinement with tolerance 0: the first level traces the grid 2^(L−1)
  // pixels apart (and the last row and column), each level traces more, the last every pixel, and
  // the last image is the plain reference's, pixel for pixel.
  const Volume v = test::sphereVolume({40, 36, 30}, 11.0);
  const VolumeOctree t = VolumeOctree::build(v);
  const TransferFunction tf({{0.0f, {1, 1, 1}, 0.0f}, {2.0f, {1.0f, 0.6f, 0.3f}, 0.3f}, {12.0f, {1, 1, 1}, 0.6f}}, "sphere");
  for (const glm::ivec2 size : {glm::ivec2(1, 1), glm::ivec2(2, 2), glm::ivec2(7, 5), glm::ivec2(33, 17), glm::ivec2(48, 40)}) {
    const Camera cam = Camera::orbit(glm::dvec3(0.0), v.extentMm(), {35, 20, 30, false, size.x, size.y});
    const Image exact = raycast(v, t, tf, cam, RaycastOptions{});
    for (int levels : {2, 3, 5}) {
      RaycastOptions o;
      o.refineLevels = levels;
      std::vector<std::pair<int, uint64_t>> seen;
      std::vector<double> psnrs;
      o.onLevel = [&](int level, const Image& image, uint64_t rays) {
        seen.push_back({level, rays});
        psnrs.push_back(psnrOf(image, exact));
      };
      RaycastStats st;
      const Image last = raycast(v, t, tf, cam, o, &st);
      const std::string where = std::to_string(size.x) + "x" + std::to_string(size.y) + ", " + std::to_string(levels) + " levels";
      EXPECT_EQ(last.pixels, exact.pixels) << where;
      ASSERT_EQ(seen.size(), size_t(levels)) << where;
      const int s = 1 << (levels - 1);
      auto gridPoints = [s](int n) { return (n - 1) / s + 1 + ((n - 1) % s != 0); };
      EXPECT_EQ(seen.front().second, uint64_t(gridPoints(size.x) * gridPoints(size.y))) << where;
      EXPECT_EQ(seen.back().second, uint64_t(size.x) * uint64_t(size.y)) << where;
      EXPECT_EQ(st.rays, uint64_t(size.x) * uint64_t(size.y)) << where;
      for (size_t k = 1; k < seen.size(); ++k) {
        EXPECT_EQ(seen[k].first, int(k) + 1);
        EXPECT_GE(seen[k].second, seen[k - 1].second) << where;
      }
      if (size.x >= 33 && levels >= 3) {
        EXPECT_GT(psnrs[levels - 2], 25.0) << where << ": the image before the last is a fair preview";
        EXPECT_GT(psnrs[levels - 2], psnrs[0]) << where;
      }
    }
  }
}

TEST(Raycast, AdaptiveRefinementTracesOnlyWhereColoursChange) {
  // A small sphere in a wide empty view: with a tolerance the background's squares stay
  // interpolated (black from black corners), the sphere's are refined; a fully transparent
  // volume needs the first grid alone.
  const Volume v = test::sphereVolume({40, 36, 30}, 11.0);
  const VolumeOctree t = VolumeOctree::build(v);
  const TransferFunction tf({{0.0f, {1, 1, 1}, 0.0f}, {2.0f, {1.0f, 0.6f, 0.3f}, 0.3f}, {12.0f, {1, 1, 1}, 0.6f}}, "sphere");
  const Camera cam = Camera::orbit(glm::dvec3(0.0), v.extentMm(), {35, 20, 60, false, 96, 96});
  const Image exact = raycast(v, t, tf, cam, RaycastOptions{});
  RaycastOptions o;
  o.refineLevels = 4;
  o.refineTolerance = 2.0f / 255.0f;
  RaycastStats st;
  const Image adaptive = raycast(v, t, tf, cam, o, &st);
  EXPECT_LT(st.rays, uint64_t(96 * 96 / 2));
  EXPECT_GT(psnrOf(adaptive, exact), 40.0);
  RaycastStats none;
  const Image black = raycast(v, t, constantTf(0.0f), cam, o, &none);
  EXPECT_EQ(none.rays, uint64_t(13 * 13));  // the grid 8 pixels apart: 0, 8, …, 88 and 95
  for (const glm::vec4& p : black.pixels) EXPECT_EQ(p, glm::vec4(0.0f));
}

TEST(Raycast, Extremes) {
  const Volume v = test::makeVolume({9, 9, 9}, [](int, int, int) { return 0.5f; });
  const VolumeOctree t = VolumeOctree::build(v);
  RaycastOptions o;
  o.shading = false;
  // Fully transparent: the background.
  EXPECT_EQ(centre(raycast(v, t, constantTf(0.0f), orthoAlong(v, {1, 2, 3}), o)), glm::vec4(0.0f));
  // Fully opaque: the material's colour, alpha 1.
  const glm::vec4 opaque = centre(raycast(v, t, constantTf(1.0f), orthoAlong(v, {1, 2, 3}), o));
  EXPECT_NEAR(opaque.a, 1.0f, 1e-6f);
  EXPECT_NEAR(opaque.r, 0.8f, 1e-6f);
  // Camera inside the volume: only the material in front of the eye counts (4 mm to the face).
  const glm::vec4 in = centre(raycast(v, t, constantTf(0.1f), test::insideCamera(), o));
  EXPECT_NEAR(in.a, 1.0f - std::pow(0.9f, 4.0f), kTol);
  // One voxel, a single slice, a 1x1 and a 4096x4096 image: no crash, finite pixels.
  const Volume one = test::makeVolume({1, 1, 1}, [](int, int, int) { return 0.5f; });
  const VolumeOctree tOne = VolumeOctree::build(one);
  EXPECT_EQ(raycast(one, tOne, constantTf(0.5f), orthoAlong(one, {0, 0, 1}, 1), o).pixels.size(), size_t(1));
  const Volume slice = test::randomVolume({16, 16, 1}, 2, 0.0f, 1.0f);
  const Image s = raycast(slice, VolumeOctree::build(slice), constantTf(0.5f), orthoAlong(slice, {0.2, 0.1, 1}), o);
  for (const glm::vec4& p : s.pixels) EXPECT_TRUE(std::isfinite(p.a) && p.a >= 0.0f && p.a <= 1.0f);
  Camera big = orthoAlong(v, {0, 0, 1}, 4096);
  big.orthoHeight = 40.0;
  const Image huge = raycast(v, t, constantTf(0.2f), big, o);
  EXPECT_EQ(huge.width, 4096);
  EXPECT_NEAR(centre(huge).a, 1.0f - std::pow(0.8f, 8.0f), kTol);
  EXPECT_EQ(huge.at(0, 0), glm::vec4(0.0f));  // outside the volume's footprint
}

TEST(RaycastCranium, RendersTheRealCtWithItsBoneSurface) {
  const Volume v = readVolume(kDefaultVolumePath);
  const VolumeOctree t = VolumeOctree::build(v);
  const Camera cam = Camera::orbit(glm::dvec3(0.0), v.extentMm(), {180, 10, 30, false, 64, 64});
  RaycastOptions o;
  const Image img = raycast(v, t, TransferFunction::preset("ct-bone"), cam, o);
  // The skull covers the middle of the frame and leaves the corners empty.
  EXPECT_GT(img.at(32, 32).a, 0.9f);
  EXPECT_EQ(img.at(0, 0).a, 0.0f);
  double covered = 0;
  for (const glm::vec4& p : img.pixels) covered += p.a > 0.5f;
  EXPECT_GT(covered / double(img.pixels.size()), 0.08);  // the frame also holds the head rest
  EXPECT_LT(covered / double(img.pixels.size()), 0.5);
}

}  // namespace
}  // namespace hyb
