// Multiresolution rendering: level blending, surface invariance, the speed/accuracy trade.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "hybrid_octree/selection.h"
#include "hybrid_octree/surface_octree.h"
#include "render/brick_error.h"
#include "render/slices/brick_textures.h"
#include "render/raycast.h"
#include "render/slices.h"
#include "render_util.h"
#include "test_util.h"
#include "volume/volume_io.h"

namespace hyb {
namespace {

using test::gl;

// Bricks at p = 3 on the nodes whose edge is edgeFor(node): a hand-made cut with forced levels.
Selection cutAt(const VolumeOctree& t, const std::function<int(const OctreeNode&)>& edgeFor) {
  Selection sel;
  std::vector<uint32_t> stack{0};
  while (!stack.empty()) {
    const uint32_t i = stack.back();
    stack.pop_back();
    const OctreeNode& n = t.nodes()[i];
    if (t.edge(n) <= edgeFor(n) || n.isLeaf()) {
      Brick b;
      b.node = i;
      b.p = 3;
      b.texels = t.texelDims(n, 3);
      sel.bricks.push_back(b);
      continue;
    }
    for (int slot = 7; slot >= 0; --slot)
      if (n.childMask & (1u << slot)) stack.push_back(childIndex(n, slot));
  }
  for (const Brick& b : sel.bricks) sel.texels += b.texelCount();
  return sel;
}

// Largest change between neighbouring pixel columns of the red channel, over columns [x0, x1).
float largestColumnJump(const Image& img, int x0, int x1) {
  float jump = 0.0f;
  for (int y = 2; y < img.height - 2; ++y)
    for (int x = x0; x < x1; ++x) jump = std::max(jump, std::abs(img.at(x + 1, y).r - img.at(x, y).r));
  return jump;
}

// Mean |pixel − mean of its 4 neighbours| (red) over the inner disc of radius @p r around the
// image's centre: the high-frequency content of an image of a smooth object there.
double roughness(const Image& img, double r) {
  double sum = 0.0;
  int count = 0;
  for (int y = 1; y + 1 < img.height; ++y)
    for (int x = 1; x + 1 < img.width; ++x) {
      if (std::hypot(x + 0.5 - 0.5 * img.width, y + 0.5 - 0.5 * img.height) > r) continue;
      const float c = img.at(x, y).r, l = img.at(x - 1, y).r, rr = img.at(x + 1, y).r, d = img.at(x, y - 1).r, u = img.at(x, y + 1).r;
      sum += std::abs(c - 0.25 * (l + rr + d + u));
      ++count;
    }
  return count ? sum / count : 0.0;
}

// The cranium at 128x128x108: a 2x2 in-plane box average of the Debian CT (as CI-sized data).
Volume halfCranium() {
  const Volume full = readVolume(kDefaultVolumePath);
  const glm::ivec3 d(full.dims().x / 2, full.dims().y / 2, full.dims().z);
  std::vector<float> s(size_t(d.x) * d.y * d.z);
  for (int k = 0; k < d.z; ++k)
    for (int j = 0; j < d.y; ++j)
      for (int i = 0; i < d.x; ++i)
        s[size_t(i) + size_t(d.x) * (j + size_t(d.y) * k)] =
            0.25f * (full.at(2 * i, 2 * j, k) + full.at(2 * i + 1, 2 * j, k) + full.at(2 * i, 2 * j + 1, k) + full.at(2 * i + 1, 2 * j + 1, k));
  return Volume(d, full.spacing() * glm::dvec3(2, 2, 1), ScalarType::Float32, std::move(s), "half cranium");
}

// The closed form of a homogeneous block [0, size]³ (colour (0.8, 0.5, 0.2), 0.05 per mm, unshaded)
// with a translucent quad across it at z = quadZ, seen by perspective camera @p cam from above:
// compares each image's pixels on a grid @p every apart whose rays enter at the top and leave at
// the bottom face, within @p tolerance. Returns how many pixels were compared.
int expectBlockWithQuad(const Camera& cam, double size, double quadZ, const glm::vec4& surface, int every, float tolerance,
                        const std::vector<std::pair<const Image*, std::string>>& images) {
  int checked = 0;
  for (int y = every / 2; y < cam.height; y += every)
    for (int x = every / 2; x < cam.width; x += every) {
      glm::dvec3 o, d;
      cam.ray(x + 0.5, y + 0.5, &o, &d);
      const double tTop = (size - o.z) / d.z, tQuad = (quadZ - o.z) / d.z, tBottom = (0.0 - o.z) / d.z;
      const glm::dvec3 top = o + d * tTop, bottom = o + d * tBottom;
      if (glm::any(glm::lessThan(glm::dvec2(top), glm::dvec2(0.0))) || glm::any(glm::greaterThan(glm::dvec2(top), glm::dvec2(size))) ||
          glm::any(glm::lessThan(glm::dvec2(bottom), glm::dvec2(0.0))) || glm::any(glm::greaterThan(glm::dvec2(bottom), glm::dvec2(size))))
        continue;
      const double front = 1.0 - std::pow(0.95, tQuad - tTop), back = 1.0 - std::pow(0.95, tBottom - tQuad);
      const double shade = 0.25 + 0.75 * std::abs(d.z), q = surface.a;
      const glm::dvec3 material(0.8, 0.5, 0.2);
      const glm::dvec3 rgb = material * front + (1.0 - front) * (glm::dvec3(surface) * shade * q + (1.0 - q) * material * back);
      const double alpha = front + (1.0 - front) * (q + (1.0 - q) * back);
      const glm::vec4 expected{glm::vec3(rgb), float(alpha)};
      for (const auto& [img, name] : images)
        for (int k = 0; k < 4; ++k) EXPECT_NEAR(img->at(x, y)[k], expected[k], tolerance) << "pixel " << x << "," << y << " " << name;
      ++checked;
    }
  return checked;
}

// Length of the ray (o, unit d) inside the box [0, size]³, or 0.
double pathInCube(const glm::dvec3& o, const glm::dvec3& d, double size) {
  double t0 = 0.0, t1 = 1e300;
  for (int a = 0; a < 3; ++a) {
    if (std::abs(d[a]) < 1e-12) {
      if (o[a] < 0.0 || o[a] > size) return 0.0;
      continue;
    }
    const double ta = (0.0 - o[a]) / d[a], tb = (size - o[a]) / d[a];
    t0 = std::max(t0, std::min(ta, tb));
    t1 = std::min(t1, std::max(ta, tb));
  }
  return std::max(0.0, t1 - t0);
}

TEST(Multires, BlendingRemovesTheSeamAtALevelChange) {
  gl();
  // A smooth field along y only; x < 32 at one texel per voxel, x >= 32 at one per two voxels.
  const Volume v = test::makeVolume({65, 33, 9}, [](int, int j, int) { return 100.0 + 80.0 * std::sin(2.0 * M_PI * j / 10.0); });
  const VolumeOctree t = VolumeOctree::build(v);
  const Selection naive = cutAt(t, [](const OctreeNode& n) { return n.origin.x < 32 ? 8 : 16; });
  Selection blended = naive;
  assignBlendCorners(t, &blended);
  ASSERT_TRUE(isRestricted(t, blended));
  ASSERT_GT(blended.blendedBricks, 0u);
  const TransferFunction tf({{0.0f, {0, 0, 0}, 0.2f}, {200.0f, {1, 1, 1}, 0.2f}}, "grey");
  // Orthographic, straight down -z, 0.5 mm a pixel, the level change between columns 31 and 32.
  const Camera cam = test::orthoDown(glm::dvec3(32, 16, 4), 32.0, 64);
  SlicesOptions o;
  o.shading = false;
  const Image a = renderSlices({v, t, naive}, tf, cam, o), b = renderSlices({v, t, blended}, tf, cam, o);
  // Within one level the columns are equal (the field does not vary along x): the jumps around the
  // level change are the seam. Blending spreads it over the fine bricks next to the coarse ones.
  const float seamNaive = largestColumnJump(a, 20, 44), seamBlended = largestColumnJump(b, 20, 44);
  EXPECT_GT(seamNaive, 10.0f / 255.0f);
  EXPECT_LE(seamBlended * 4.0f, seamNaive) << "naive " << seamNaive << ", blended " << seamBlended;
  // Far from the change, both show the fine data unchanged.
  for (int y = 0; y < 64; ++y) EXPECT_NEAR(a.at(4, y).r, b.at(4, y).r, 1e-6f);
  // The seam blending removes, in data units: on the face x = 32 the fine bricks' knots at odd y
  // against the coarse side's field there, the mean of the samples either side.
  auto f = [](int j) { return 100.0 + 80.0 * std::sin(2.0 * M_PI * j / 10.0); };
  double expected = 0.0;
  for (int j = 1; j < 32; j += 2) expected = std::max(expected, std::abs(f(j) - 0.5 * (f(j - 1) + f(j + 1))));
  const VolumeKnots knots(v, t);
  float seam = 0.0f;
  for (const Brick& brick : blended.bricks) {
    const float h = seamHeight(knots, t, brick);
    EXPECT_TRUE(brick.coarseCorners || h == 0.0f);
    seam = std::max(seam, h);
  }
  EXPECT_NEAR(seam, expected, 1e-3);  // 14.5: 80·(1 − cos 36°)·sin 108°
}

TEST(Multires, CoarseBricksShadeWithTheDatasOwnGradients) {
  gl();
  // A ramp along z and a ripple along x: the knots of a lattice two voxels apart (even x) see the
  // ramp alone, but the data's gradient there leans 45° in x, one way or the other.
  const Volume v = test::makeVolume({17, 17, 17}, [](int i, int, int k) { return 1.0 + 0.02 * (k - 8) + 0.02 * std::sin(M_PI * i / 2.0); });
  const VolumeOctree t = VolumeOctree::build(v);
  const Selection coarse = cutAt(t, [](const OctreeNode&) { return 16; });
  ASSERT_EQ(coarse.bricks.size(), 1u);
  ASSERT_EQ(t.lattice(t.nodes()[coarse.bricks[0].node], coarse.bricks[0].p).step, 2);
  const TransferFunction tf = test::constantTf(0.05f);  // one colour and opacity: only the shading varies
  const Camera cam = test::orthoDown(glm::dvec3(8, 8, 8), 16.0, 32);
  const Image ref = raycast(v, t, tf, cam, RaycastOptions{});
  const Image img = renderSlices({v, t, coarse}, tf, cam, SlicesOptions{});
  // Looking down z the headlight gives 0.25 + 0.75 cos 45° at even x and 1 at odd x, in the
  // reference and in the coarse brick's interpolated gradients alike; the coarse field's own
  // differences would shade every column as 1 (0.1 brighter at even x).
  float ripple = 0.0f, worst = 0.0f;
  for (int y = 2; y < 30; ++y)
    for (int x = 2; x < 30; ++x) {
      ripple = std::max(ripple, std::abs(ref.at(x + 1, y).r - ref.at(x, y).r));
      for (int c = 0; c < 3; ++c) worst = std::max(worst, std::abs(img.at(x, y)[c] - ref.at(x, y)[c]));
    }
  EXPECT_GT(ripple, 0.04f);
  EXPECT_LE(worst, 3.0f / 255.0f);
}

TEST(Multires, PrefilteredCoarseLevelsDoNotAliasAThinShell) {
  gl();
  // A spherical shell 1.5 voxels thick: knots 4 voxels apart that take the samples catch it at
  // some knots and miss it at others (blotches and rings); prefiltered knots show it smoothed.
  const Volume v = test::makeVolume({65, 65, 65}, [](int i, int j, int k) {
    const double r = glm::length(glm::dvec3(i, j, k) - glm::dvec3(32.3, 31.7, 32.1));
    return 100.0 * std::max(0.0, 1.0 - std::abs(r - 24.0) / 1.5);
  });
  const TransferFunction tf({{10.0f, {1.0f, 0.8f, 0.6f}, 0.0f}, {100.0f, {1.0f, 0.8f, 0.6f}, 0.3f}}, "shell");
  const Camera cam = Camera::orbit(glm::dvec3(0.0), v.extentMm(), {30, 20, 30, false, 96, 96});
  const VolumeOctree point = VolumeOctree::build(v, VolumeOctreeOptions{8, false}), smooth = VolumeOctree::build(v);
  SlicesOptions o;
  o.shading = false;  // the shell's own shading varies smoothly; what is left is the aliasing
  // Of the knots: sampled twice a texel (the default step samples coarse levels once a texel,
  // whose rings on a shell this thin would add to the roughness measured below: 2.2× the reference).
  o.stepVoxels = 0.25;
  RaycastOptions ro;
  ro.shading = false;
  const Image reference = raycast(v, point, tf, cam, ro);
  // The shell's inner disc on screen, away from its rim (seen edge-on, bright and sharp).
  int covered = 0;
  for (const glm::vec4& p : reference.pixels) covered += p.a > 0.05f;
  const double inner = 0.6 * std::sqrt(covered / M_PI);
  ASSERT_GT(inner, 10.0);
  const double truth = roughness(reference, inner);
  // Bricks at p = 3: nodes of edge 32 hold a texel every 4 voxels, nodes of edge 8 every voxel.
  const Selection coarse = cutAt(point, [](const OctreeNode&) { return 32; });
  const double aliased = roughness(renderSlices({v, point, coarse}, tf, cam, o), inner);
  const double filtered = roughness(renderSlices({v, smooth, coarse}, tf, cam, o), inner);
  // Measured: the reference 0.0063, point-subsampled knots 5× that, prefiltered ones 1.5×.
  const std::string what = "reference " + std::to_string(truth) + ", point-subsampled " + std::to_string(aliased) +
                           ", prefiltered " + std::to_string(filtered);
  EXPECT_GT(aliased, 4.0 * truth) << what;
  EXPECT_LT(filtered, 2.0 * truth) << what;
  EXPECT_GT(aliased, 2.5 * filtered) << what;
  // At one texel per voxel there is nothing to filter: the same image.
  const Selection fine = cutAt(point, [](const OctreeNode&) { return 8; });
  EXPECT_EQ(renderSlices({v, point, fine}, tf, cam, o).pixels, renderSlices({v, smooth, fine}, tf, cam, o).pixels);
}

TEST(Multires, SurfaceDoesNotMoveWithTheVolumeLevel) {
  gl();
  // A sphere (values up to 95, isosurface at 50, transparent) left, a smooth blob (down to −300,
  // visible below −150) right.
  const Volume v = test::makeVolume({64, 32, 32}, [](int i, int j, int k) {
    const double r1 = glm::length(glm::dvec3(i, j, k) - glm::dvec3(14, 16, 16)), r2 = glm::length(glm::dvec3(i, j, k) - glm::dvec3(48, 16, 16));
    if (r2 < 12.0) return -300.0 * std::exp(-(r2 / 6.0) * (r2 / 6.0));
    return std::max(0.0, 50.0 + 5.0 * (9.0 - r1));
  });
  const VolumeOctree t = VolumeOctree::build(v);
  const SurfaceOctree so = SurfaceOctree::build(v, t, 50.0f);
  const TriangleMesh mesh = fineMeshToTriangles(so.reconstruct(), v.spacing());
  ASSERT_GT(mesh.triangles.size(), 100u);
  const TransferFunction tf({{-300.0f, {0.9f, 0.4f, 0.2f}, 0.3f}, {-160.0f, {0.2f, 0.4f, 0.9f}, 0.3f}, {-150.0f, {0.2f, 0.4f, 0.9f}, 0.0f}}, "blob");
  const Camera cam = Camera::orbit(glm::dvec3(0.0), v.extentMm(), {20, 15, 30, false, 96, 96});
  SelectionParams exact, coarse;
  for (SelectionParams* p : {&exact, &coarse}) {
    p->maxBrickEdge = 4;  // leaves (edge 8) reach one texel per voxel only when ε_u asks for it
    p->opacity = [&tf](float lo, float hi) { return tf.maxAlpha(lo, hi); };
  }
  coarse.epsilon = 40.0f;
  const Selection fine = selectNodes(t, exact), rough = selectNodes(t, coarse);
  ASSERT_GT(rough.maxError, 10.0f);
  // An opaque surface: what lies behind it cannot show through.
  SlicesOptions o;
  o.surface = &mesh;
  o.surfaceColor = glm::vec4(0.9f, 0.9f, 0.8f, 1.0f);
  const Image a = renderSlices({v, t, fine}, tf, cam, o), b = renderSlices({v, t, rough}, tf, cam, o);
  // The surface's pixels: those a surface-only image covers.
  const TransferFunction clear({{0.0f, {0, 0, 0}, 0.0f}, {1.0f, {0, 0, 0}, 0.0f}}, "clear");
  const Image s = renderSlices({v, t, fine}, clear, cam, o);
  int surfacePixels = 0, volumeDiffers = 0;
  for (size_t i = 0; i < s.pixels.size(); ++i) {
    if (s.pixels[i].a > 0.0f) {
      ++surfacePixels;
      EXPECT_EQ(a.pixels[i], b.pixels[i]) << "pixel " << i;
    } else if (glm::length(a.pixels[i] - b.pixels[i]) > 1e-3f) {
      ++volumeDiffers;
    }
  }
  EXPECT_GT(surfacePixels, 300);
  EXPECT_GT(volumeDiffers, 50);  // the volume did change with ε_u
}

TEST(MultiresCranium, AccuracyAndBytesFallAsEpsilonGrowsOrTheBudgetShrinks) {
  gl();
  const Volume v = halfCranium();
  const VolumeOctree t = VolumeOctree::build(v);
  const TransferFunction tf = TransferFunction::preset("ct-skin-bone");
  const Camera cam = Camera::orbit(glm::dvec3(0.0), v.extentMm(), {180, 10, 30, false, 128, 128});
  const std::vector<uint8_t> reference = toRgba8(raycast(v, t, tf, cam, RaycastOptions{}), glm::vec3(0));
  SelectionParams base;
  base.spacing = v.spacing();
  base.eye = cam.eye;
  base.opacity = [&tf](float lo, float hi) { return tf.maxAlpha(lo, hi); };
  base.distortion = [&tf](float lo, float hi, float error) { return tf.distortion(lo, hi, error); };
  base.inView = [&cam](const glm::dvec3& lo, const glm::dvec3& hi) { return cam.seesBox(lo, hi); };
  BrickImageError imageError(v, t, tf, cam);  // as the render command spends budgets
  base.brickError = [&imageError](uint32_t node, int p) { return imageError(node, p); };
  base.prefetchBrickErrors = [&imageError](const std::vector<std::pair<uint32_t, int>>& bricks) { imageError.prefetch(bricks); };
  struct Result {
    double db;
    uint64_t bytes;
  };
  auto run = [&](const SelectionParams& params) {
    SlicesStats st;
    const Image img = renderSlices({v, t, selectNodes(t, params)}, tf, cam, SlicesOptions{}, &st);
    return Result{psnr(toRgba8(img, glm::vec3(0)), reference), st.textureBytes};
  };
  auto expectFalling = [](const std::vector<Result>& r, const char* what) {
    for (size_t i = 1; i < r.size(); ++i) {
      EXPECT_LE(r[i].db, r[i - 1].db + 0.2) << what << " step " << i;
      EXPECT_LE(r[i].bytes, r[i - 1].bytes) << what << " step " << i;
    }
    EXPECT_LT(r.back().db, r.front().db - 3.0) << what << ": the sweep must reach a visibly coarser image";
  };
  std::vector<Result> byEpsilon;
  for (float eps : {0.0f, 100.0f, 300.0f, 500.0f, 800.0f, 1500.0f}) {
    SelectionParams p = base;
    p.epsilon = eps;
    byEpsilon.push_back(run(p));
  }
  EXPECT_GE(byEpsilon.front().db, 35.0);
  expectFalling(byEpsilon, "epsilon");
  std::vector<Result> byBudget{byEpsilon.front()};
  for (double fraction : {0.5, 0.25, 0.125, 0.0625}) {
    SelectionParams p = base;
    p.texelBudget = uint64_t(fraction * double(byEpsilon.front().bytes) / double(bytesPerTexel(TexelBits::Eight)));
    byBudget.push_back(run(p));
    EXPECT_LE(byBudget.back().bytes, p.texelBudget * bytesPerTexel(TexelBits::Eight));
  }
  expectFalling(byBudget, "budget");
}

TEST(Multires, AxisAlignedCutShowsTheDataSliceThroughTheTransferFunction) {
  gl();
  const Volume v = test::makeVolume({33, 33, 33}, [](int i, int j, int k) { return 2.0 * i + 1.5 * j + k + 0.05 * i * j; });
  const VolumeOctree t = VolumeOctree::build(v);
  const TransferFunction tf({{0.0f, {0.1f, 0.2f, 0.9f}, 0.2f}, {60.0f, {0.9f, 0.8f, 0.1f}, 0.05f}, {140.0f, {1.0f, 0.3f, 0.3f}, 0.5f}}, "ramp");
  const CutPlane cut{glm::dvec3(16.0, 16.0, 12.3), glm::dvec3(0.0, 0.0, 1.0)};
  // Orthographic, straight down -z: pixel (x, y) sees (x + 0.5, 31.5 - y) on the plane.
  const Camera cam = test::orthoDown(glm::dvec3(16.0, 16.0, 12.3), 32.0, 32);
  RaycastOptions ro;
  ro.cut = &cut;
  const Image b = raycast(v, t, tf, cam, ro);
  for (TexelBits bits : {TexelBits::Eight, TexelBits::Sixteen}) {
    SlicesOptions so;
    so.cut = &cut;
    so.texelBits = bits;
    SlicesStats st;
    const Image a = renderSlices({v, t, selectNodes(t, SelectionParams{})}, tf, cam, so, &st);
    EXPECT_GT(st.cutPolygons, 0u);
    const uint64_t bytes = st.texels * bytesPerTexel(bits);
    if (bits == TexelBits::Eight) {
      // 16-bit values only for the bricks the plane crosses (z = 12.3: the lower half of the volume).
      EXPECT_GT(st.textureBytes, bytes);
      EXPECT_LT(st.textureBytes, bytes + st.texels * kBytesPerCutTexel);
    } else {
      EXPECT_EQ(st.textureBytes, bytes);  // the plane reads the bricks' own 16-bit values
    }
    for (int y = 0; y < 32; ++y)
      for (int x = 0; x < 32; ++x) {
        const glm::vec4 c = tf.lookup(v.sample(glm::vec3(x + 0.5f, 31.5f - y, 12.3f)));
        const glm::vec4 expected(glm::vec3(c), 1.0f);
        for (const Image* img : {&a, &b})
          for (int k = 0; k < 4; ++k)
            ASSERT_NEAR(img->at(x, y)[k], expected[k], 1.0f / 255.0f)
                << "pixel " << x << "," << y << (img == &a ? " slices" : " raycast") << ", " << int(bits) << "-bit texels";
      }
  }
}

TEST(Multires, VolumeOfInterestScalesOpacitySmoothly) {
  gl();
  const Volume v = test::makeVolume({33, 33, 33}, [](int, int, int) { return 1.0; });
  const VolumeOctree t = VolumeOctree::build(v);
  const TransferFunction tf = test::constantTf(0.05f);
  VolumeOfInterest voi;  // the slab 8 <= x <= 24, fully opaque inside, removed outside, 4 mm ramp
  voi.lo = glm::dvec3(8, -10, -10);
  voi.hi = glm::dvec3(24, 50, 50);
  voi.outside = 0.0;
  voi.ramp = 4.0;
  // Orthographic, straight down -z through all 32 mm: pixel column x sees x + 0.5 mm.
  const Camera cam = test::orthoDown(glm::dvec3(16, 16, 16), 32.0, 32);
  SlicesOptions so;
  so.shading = false;
  so.voi = &voi;
  RaycastOptions ro;
  ro.shading = false;
  ro.voi = &voi;
  const Image a = renderSlices({v, t, selectNodes(t, SelectionParams{})}, tf, cam, so), b = raycast(v, t, tf, cam, ro);
  for (int x = 0; x < 32; ++x) {
    const double factor = voi.factor(glm::dvec3(x + 0.5, 16, 16));
    const float expected = 1.0f - std::pow(1.0f - 0.05f * float(factor), 32.0f);
    EXPECT_NEAR(a.at(x, 16).a, expected, 2.0f / 255.0f) << "slices, column " << x;
    EXPECT_NEAR(b.at(x, 16).a, expected, 2.0f / 255.0f) << "raycast, column " << x;
  }
  // Closed-form factors: 0 beyond the ramp, 1/2 on the surface, 1 deep inside.
  EXPECT_EQ(voi.factor(glm::dvec3(5.9, 0, 0)), 0.0);
  EXPECT_DOUBLE_EQ(voi.factor(glm::dvec3(8, 0, 0)), 0.5);
  EXPECT_EQ(voi.factor(glm::dvec3(16, 0, 0)), 1.0);
  EXPECT_TRUE(voi.hides(glm::dvec3(0, 0, 0), glm::dvec3(5.9, 8, 8)));
  EXPECT_FALSE(voi.hides(glm::dvec3(0, 0, 0), glm::dvec3(6.1, 8, 8)));
}

TEST(Multires, ShellsAndPlanesComposeTheClosedFormInPerspective) {
  gl();
  // A homogeneous block (0.05 per mm) with a translucent quad across it at z = 13.
  const Volume v = test::makeVolume({33, 33, 33}, [](int, int, int) { return 1.0; });
  const VolumeOctree t = VolumeOctree::build(v);
  const TransferFunction tf = test::constantTf(0.05f);
  const TriangleMesh quad = test::quadAt(13.0, -1.0, 33.0, -1.0, 33.0);
  const Camera cam = test::perspective(glm::dvec3(20, 12, 70), glm::dvec3(16, 16, 16), glm::dvec3(0, 1, 0), 30, 48);
  const glm::vec4 surface(0.2f, 0.6f, 0.9f, 0.4f);
  SlicesOptions so;
  so.shading = false;
  so.surface = &quad;
  so.surfaceColor = surface;
  const Bvh bvh(quad);
  RaycastOptions ro;
  ro.shading = false;
  ro.surface = &bvh;
  ro.surfaceColor = surface;
  const Selection sel = selectNodes(t, SelectionParams{});
  SlicesStats st;
  so.proxy = Proxy::Shells;
  const Image shells = renderSlices({v, t, sel}, tf, cam, so, &st);
  EXPECT_GT(st.shellBricks, 0u);
  so.proxy = Proxy::Planes;
  const Image planes = renderSlices({v, t, sel}, tf, cam, so), reference = raycast(v, t, tf, cam, ro);
  // Entry at the top face z = 32 and the quad at z = 13.
  EXPECT_GE(expectBlockWithQuad(cam, 32.0, 13.0, surface, 8, 2.5f / 255.0f, {{&shells, "shells"}, {&planes, "planes"}, {&reference, "reference"}}), 9);
}

// The same closed form where ε made the brick coarse (a smooth field the transfer function
// classifies as one material, two voxels a texel): shells and planes slot the quad between the
// brick's own slices (a slab's opacity off at most), and fewer of them than at full resolution.
TEST(Multires, CoarseBricksComposeTheClosedFormInPerspective) {
  gl();
  const Volume v = test::makeVolume({17, 17, 17}, [](int x, int y, int z) {  // one node: the quad lies in one brick
    return float(1.0 + 0.4 * std::sin(x / 3.0) * std::sin(y / 3.0) * std::cos(z / 4.0));
  });
  const VolumeOctree t = VolumeOctree::build(v);
  const TransferFunction tf = test::constantTf(0.05f);
  const TriangleMesh quad = test::quadAt(6.5, -1.0, 17.0, -1.0, 17.0);
  const Camera cam = test::perspective(glm::dvec3(10, 6, 40), glm::dvec3(8, 8, 8), glm::dvec3(0, 1, 0), 30, 32);
  const glm::vec4 surface(0.2f, 0.6f, 0.9f, 0.4f);
  SlicesOptions so;
  so.shading = false;
  so.surface = &quad;
  so.surfaceColor = surface;
  SelectionParams coarse;
  coarse.epsilon = 0.15f;
  const Selection sel = selectNodes(t, coarse);
  ASSERT_EQ(sel.bricks.size(), size_t(1));
  ASSERT_EQ(t.lattice(t.nodes()[sel.bricks[0].node], sel.bricks[0].p).step, 2);
  const float tolerance = float(1.0 - std::pow(0.95, 2 * so.stepVoxels)) + 2.5f / 255.0f;  // a slab's opacity
  for (const Proxy proxy : {Proxy::Shells, Proxy::Planes}) {
    so.proxy = proxy;
    SlicesStats st, full;
    const Image img = renderSlices({v, t, sel}, tf, cam, so, &st);
    renderSlices({v, t, selectNodes(t, SelectionParams{})}, tf, cam, so, &full);
    EXPECT_EQ(st.shellBricks, proxy == Proxy::Shells ? 1u : 0u);
    EXPECT_LT(st.slabPolygonDraws, full.slabPolygonDraws);
    EXPECT_GE(expectBlockWithQuad(cam, 16.0, 6.5, surface, 4, tolerance, {{&img, proxy == Proxy::Shells ? "shells" : "planes"}}), 9);
  }
}

TEST(Multires, CoarseBricksIntegrateExactlyTheirStretchOfEveryRay) {
  gl();
  // A homogeneous block (0.05 per mm), x < 32 at a texel per two voxels, sliced 1.5 voxels
  // apart, x >= 32 at one per four voxels, sliced four apart: planes whose stretch a face cuts
  // short must count only what lies in their brick, at the level change and on the volume's faces
  // (full resolution keeps the error of the base spacing there, up to 1 - 0.95^0.5).
  const Volume v = test::makeVolume({65, 65, 65}, [](int, int, int) { return 1.0; });
  const VolumeOctree t = VolumeOctree::build(v);
  const Selection sel = cutAt(t, [](const OctreeNode& n) { return n.origin.x < 32 ? 16 : 32; });
  const TransferFunction tf = test::constantTf(0.05f);
  const Camera cam = test::perspective(glm::dvec3(150, 75, 110), glm::dvec3(32, 32, 32), glm::dvec3(0, 0, 1), 40, 64);
  SlicesOptions so;
  so.shading = false;
  for (const Proxy proxy : {Proxy::Planes, Proxy::Shells}) {
    so.proxy = proxy;
    SlicesStats st;
    const Image img = renderSlices({v, t, sel}, tf, cam, so, &st);
    ASSERT_EQ(st.shellBricks > 0, proxy == Proxy::Shells);
    int checked = 0, off = 0;
    double worst = 0.0;
    for (int y = 0; y < cam.height; ++y)
      for (int x = 0; x < cam.width; ++x) {
        glm::dvec3 o, d;
        bool inside = true;  // the pixel's corners' rays too: no silhouette pixels
        for (const glm::dvec2 c : {glm::dvec2(0, 0), glm::dvec2(1, 0), glm::dvec2(0, 1), glm::dvec2(1, 1)}) {
          cam.ray(x + c.x, y + c.y, &o, &d);
          inside = inside && pathInCube(o, glm::normalize(d), 64.0) > 0.0;
        }
        if (!inside) continue;
        cam.ray(x + 0.5, y + 0.5, &o, &d);
        const double alpha = 1.0 - std::pow(0.95, pathInCube(o, glm::normalize(d), 64.0));
        const double error = std::max(std::abs(img.at(x, y).a - alpha), std::abs(img.at(x, y).r - 0.8 * alpha));
        off += error > 2.0 / 255.0;
        worst = std::max(worst, error);
        ++checked;
      }
    // What is left: rays that graze a brick's edge, whose short stretch in it meets none of its
    // planes (measured: 2 % of the pixels with planes, 5 % with shells; without the cut segments 36 %).
    const std::string what = std::string(proxy == Proxy::Shells ? "shells" : "planes") + ": " + std::to_string(off) + " of " +
                             std::to_string(checked) + " pixels off, worst " + std::to_string(worst);
    EXPECT_GT(checked, 2000) << what;
    EXPECT_LT(off * 12, checked) << what;
    EXPECT_LT(worst, 1.0 - std::pow(0.95, 4.0)) << what;  // less than a coarse plane's stretch
  }
}

TEST(Multires, ExtremesGiveFiniteImages) {
  gl();
  const Volume v = test::sphereVolume({40, 36, 30}, 12.0);
  const VolumeOctree t = VolumeOctree::build(v);
  const TransferFunction tf({{-5.0f, {1, 1, 1}, 0.0f}, {0.0f, {1, 0.5f, 0.2f}, 0.4f}, {12.0f, {0.2f, 0.5f, 1}, 0.1f}}, "s");
  const SurfaceOctree so = SurfaceOctree::build(v, t, 4.0f);
  const TriangleMesh mesh = fineMeshToTriangles(so.reconstruct(), v.spacing());
  Camera inside;  // perspective from inside the sphere
  inside.eye = glm::dvec3(19, 17, 14);
  inside.center = glm::dvec3(30, 17, 14);
  inside.up = glm::dvec3(0, 0, 1);
  inside.width = inside.height = 24;
  const Camera outside = Camera::orbit(glm::dvec3(0.0), v.extentMm(), {30, 20, 30, false, 24, 24});
  const CutPlane away{glm::dvec3(500, 0, 0), glm::dvec3(1, 0, 0)};  // misses the volume
  const CutPlane through{glm::dvec3(20, 18, 15), glm::dvec3(0.3, 1, 0.2)};
  VolumeOfInterest voi;
  voi.lo = glm::dvec3(100);  // outside the volume: everything fades to `outside`
  voi.hi = glm::dvec3(110);
  voi.outside = 0.0;
  for (const Camera* cam : {static_cast<const Camera*>(&inside), &outside})
    for (uint64_t budget : {uint64_t(0), uint64_t(8), uint64_t(3000)})
      for (Proxy proxy : {Proxy::Planes, Proxy::Shells})
        for (const CutPlane* cut : {static_cast<const CutPlane*>(nullptr), &away, &through}) {
          SelectionParams params;
          params.texelBudget = budget;
          params.maxBrickEdge = 8;
          params.eye = cam->eye;
          const Selection sel = selectNodes(t, params);
          if (budget > 0) {
            EXPECT_LE(sel.texels, budget);
          }
          SlicesOptions o;
          o.proxy = proxy;
          o.cut = cut;
          o.surface = &mesh;
          o.surfaceColor = glm::vec4(0.9f, 0.9f, 0.9f, 0.5f);
          for (bool withVoi : {false, true}) {
            o.voi = withVoi ? &voi : nullptr;
            const Image img = renderSlices({v, t, sel}, tf, *cam, o);
            for (const glm::vec4& p : img.pixels)
              for (int k = 0; k < 4; ++k) ASSERT_TRUE(std::isfinite(p[k]) && p[k] >= -1e-6f && p[k] <= 1.0f + 1e-5f);
          }
        }
}

TEST(Multires, TrianglesOfBricksWithoutSlicesAreNotSplitIntoSlabs) {
  gl();
  // Nothing of the volume is visible, so every brick is hidden: its triangles need no slabs (one
  // instance each, sorted back to front) and the two quads composite over each other.
  const Volume v = test::makeVolume({17, 17, 17}, [](int, int, int) { return 1.0; });
  const VolumeOctree t = VolumeOctree::build(v);
  const TransferFunction clear({{0.0f, {0, 0, 0}, 0.0f}, {2.0f, {0, 0, 0}, 0.0f}}, "clear");
  SelectionParams params;
  params.opacity = [&clear](float lo, float hi) { return clear.maxAlpha(lo, hi); };
  const Selection sel = selectNodes(t, params);
  ASSERT_TRUE(std::all_of(sel.bricks.begin(), sel.bricks.end(), [](const Brick& b) { return b.hidden; }));
  TriangleMesh quads = test::quadAt(5.0, 1, 15, 1, 15);  // the far one (the eye looks down -z)
  const TriangleMesh near = test::quadAt(11.0, 1, 15, 1, 15);
  for (const glm::uvec3& tr : near.triangles) quads.triangles.push_back(tr + glm::uvec3(4));
  quads.vertices.insert(quads.vertices.end(), near.vertices.begin(), near.vertices.end());
  SlicesOptions o;
  o.surface = &quads;
  o.surfaceColor = glm::vec4(0.2f, 0.6f, 1.0f, 0.5f);
  SlicesStats st;
  const glm::vec4 p = renderSlices({v, t, sel}, clear, test::orthoDown(glm::dvec3(8, 8, 8), 4.0, 8), o, &st).at(4, 4);
  EXPECT_EQ(st.slabPolygonDraws, 4u);  // one instance a triangle: no slabs without slices
  const float a = 0.5f;  // each quad faces the eye: shade 1
  EXPECT_NEAR(p.a, a + (1 - a) * a, 1e-5f);
  EXPECT_NEAR(p.b, 1.0f * a + (1 - a) * 1.0f * a, 1e-5f);
}

}  // namespace
}  // namespace hyb
