#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <stdexcept>

#include "hybrid_octree/knot_source.h"
#include "hybrid_octree/surface_octree.h"
#include "render/gl_objects.h"
#include "render/patient_view.h"
#include "render/raycast.h"
#include "render/scene_renderer.h"
#include "render/slices.h"
#include "render_util.h"
#include "test_util.h"
#include "volume/core/error.h"
#include "volume/volume_io.h"

namespace hyb {
namespace {

using test::constantTf;
using test::gl;
using test::psnrOf;
using test::quadAt;

// An 8x8 orthographic view straight down -z onto a 4 mm window around @p centre.
Camera straightOn(const glm::dvec3& centre) { return test::orthoDown(centre, 4.0, 8); }

// Live GL objects of every kind, by name (whatever the driver's naming policy).
size_t liveGlObjects() {
  size_t n = 0;
  for (GLuint id = 1; id < 20000; ++id)
    n += glIsTexture(id) + glIsBuffer(id) + glIsVertexArray(id) + glIsFramebuffer(id) + glIsRenderbuffer(id) + glIsQuery(id) + glIsProgram(id);
  return n;
}

// A grid of n x n squares, two triangles each, over (u, v) in [0, 1]², placed by @p at.
template <class At>
TriangleMesh gridMesh(int n, At at) {
  TriangleMesh m;
  for (int j = 0; j <= n; ++j)
    for (int i = 0; i <= n; ++i) m.vertices.push_back(at(double(i) / n, double(j) / n));
  for (uint32_t j = 0; j < uint32_t(n); ++j)
    for (uint32_t i = 0; i < uint32_t(n); ++i) {
      const uint32_t a = j * (n + 1) + i;
      m.triangles.push_back({a, a + 1, a + n + 2});
      m.triangles.push_back({a, a + n + 2, a + n + 1});
    }
  return m;
}

TEST(Slices, ContextIsOpenGl45Core) { EXPECT_NE(gl().description().find("4.5"), std::string::npos) << gl().description(); }

TEST(Slices, MatchesTheReferenceOnASphereInBothProjections) {
  gl();
  const Volume v = test::sphereVolume(glm::ivec3(48, 44, 40), 15.0);
  const VolumeOctree t = VolumeOctree::build(v);
  const TransferFunction tf({{0.0f, {1, 1, 1}, 0.0f}, {2.0f, {1.0f, 0.6f, 0.3f}, 0.3f}, {15.0f, {0.3f, 0.6f, 1.0f}, 0.05f}}, "s");
  const Selection sel = selectNodes(t, SelectionParams{});
  for (bool ortho : {false, true}) {
    const Camera cam = Camera::orbit(glm::dvec3(0.0), v.extentMm(), {205, 20, 30, ortho, 96, 96});
    const Image a = renderSlices({v, t, sel}, tf, cam, SlicesOptions{});
    const Image b = raycast(v, t, tf, cam, RaycastOptions{});
    EXPECT_GE(psnrOf(a, b), 35.0) << "ortho " << ortho;
  }
}

// The lookup table spans the transfer function's domain, not the data's range: one padding voxel
// far below the data (CT's −3024 outside the scanned disc, here −10^6, in a corner brick the
// function makes transparent) must not coarsen it. Over the whole range an entry would span ~250
// units, wider than the function's features.
TEST(Slices, PaddingValuesDoNotCoarsenTheLookupTable) {
  gl();
  const Volume v = test::makeVolume({44, 44, 44}, [](int i, int j, int k) {
    return i + j + k == 0 ? -1e6 : 8.0 - glm::length(glm::dvec3(i, j, k) - glm::dvec3(30.0));
  });
  const VolumeOctree t = VolumeOctree::build(v);
  const TransferFunction tf({{0.0f, {1, 1, 1}, 0.0f}, {2.0f, {1.0f, 0.6f, 0.3f}, 0.3f}, {4.0f, {0.2f, 0.9f, 0.4f}, 0.05f},
                             {9.0f, {0.3f, 0.6f, 1.0f}, 0.5f}},
                            "narrow");
  const Selection sel = selectNodes(t, SelectionParams{});
  const Camera cam = Camera::orbit(glm::dvec3(0.0), v.extentMm(), {205, 20, 30, false, 96, 96});
  BrickTextureCache cache;
  SlicesOptions so;
  so.textures = &cache;
  const Image a = renderSlices({v, t, sel}, tf, cam, so);
  EXPECT_GE(psnrOf(a, raycast(v, t, tf, cam, RaycastOptions{})), 35.0);
  // Another transfer function with another domain (a shell outside the sphere), through the same
  // cache: the bricks' block ranges, kept as table entries, are rebuilt; read in the new table the
  // old entries would call the shell transparent and cut it away.
  const TransferFunction outer({{-5.0f, {1, 1, 1}, 0.0f}, {-3.0f, {0.9f, 0.5f, 0.2f}, 0.3f}, {-1.0f, {0.2f, 0.4f, 1.0f}, 0.0f}}, "outer");
  const Image b = renderSlices({v, t, sel}, outer, cam, so);
  EXPECT_GE(psnrOf(b, raycast(v, t, outer, cam, RaycastOptions{})), 35.0);
  // A transfer function of one point (the same colour and opacity everywhere: a table of one
  // value) still shades by the data's gradients.
  const TransferFunction constant({{5.0f, {0.9f, 0.7f, 0.5f}, 0.04f}}, "constant");
  const Image c = renderSlices({v, t, sel}, constant, cam, so);
  EXPECT_GE(psnrOf(c, raycast(v, t, constant, cam, RaycastOptions{})), 35.0);
}

// 8-bit texels keep 1/255 of a brick's range: soft tissue (0..60) inside air (−1000) around bone
// (2000) keeps ~12 units, coarse against a soft-tissue window. 16-bit texels resolve it; the cache
// drops 8-bit bricks when a frame asks for 16 bits.
TEST(Slices, SixteenBitTexelsResolveANarrowWindow) {
  gl();
  const Volume v = test::makeVolume({48, 48, 48}, [](int i, int j, int k) {
    const glm::dvec3 p(i, j, k);
    const double r = glm::length(p - glm::dvec3(24.0));
    if (r > 18.0) return -1000.0;
    if (glm::all(glm::lessThan(glm::abs(p - glm::dvec3(24.0)), glm::dvec3(4.0)))) return 2000.0;
    return 30.0 + 30.0 * std::sin(0.3 * i) * std::cos(0.25 * j + 0.2 * k);
  });
  const VolumeOctree t = VolumeOctree::build(v);
  const TransferFunction tf = TransferFunction::preset("ct-soft-tissue");
  const Selection sel = selectNodes(t, SelectionParams{});
  const Camera cam = Camera::orbit(glm::dvec3(0.0), v.extentMm(), {205, 20, 30, false, 96, 96});
  const Image reference = raycast(v, t, tf, cam, RaycastOptions{});
  BrickTextureCache cache;
  SlicesOptions so;
  so.textures = &cache;
  SlicesStats st8, st16;
  const double db8 = psnrOf(renderSlices({v, t, sel}, tf, cam, so, &st8), reference);
  so.texelBits = TexelBits::Sixteen;
  const double db16 = psnrOf(renderSlices({v, t, sel}, tf, cam, so, &st16), reference);
  EXPECT_GE(db16, 55.0);
  EXPECT_GE(db16, db8 + 8.0) << "8-bit " << db8 << " dB";
  EXPECT_EQ(st16.textureBytes, 2 * st8.textureBytes);
  SlicesOptions fresh;
  fresh.texelBits = TexelBits::Sixteen;
  EXPECT_GE(psnrOf(renderSlices({v, t, sel}, tf, cam, so), renderSlices({v, t, sel}, tf, cam, fresh)), 60.0);
}

TEST(Slices, CachedBrickTexturesGiveTheSameImage) {
  gl();
  // A curved field, so that coarse levels and blending change the texels.
  const Volume v = test::makeVolume({40, 36, 33}, [](int i, int j, int k) {
    return 8.0 + 7.0 * std::sin(0.35 * i) * std::cos(0.3 * j) + 0.2 * k;
  });
  const VolumeOctree t = VolumeOctree::build(v);
  const TransferFunction tf({{0.0f, {1, 1, 1}, 0.0f}, {2.0f, {1.0f, 0.6f, 0.3f}, 0.3f}, {15.0f, {0.3f, 0.6f, 1.0f}, 0.05f}}, "s");
  SelectionParams coarse, naive;
  coarse.texelBudget = naive.texelBudget = selectNodes(t, SelectionParams{}).texels / 4;  // bricks at several levels
  naive.blend = false;                    // the same bricks, none blended
  const Camera cam = Camera::orbit(glm::dvec3(0.0), v.extentMm(), {205, 20, 30, false, 64, 64});
  BrickTextureCache cache;
  SlicesOptions cached;
  cached.textures = &cache;
  ASSERT_GT(selectNodes(t, coarse).blendedBricks, 0u);
  for (const SelectionParams& params : {SelectionParams{}, naive, coarse}) {
    const Selection sel = selectNodes(t, params);
    SlicesStats st;
    const Image fresh = renderSlices({v, t, sel}, tf, cam, SlicesOptions{}, &st);
    const size_t before = cache.size();
    const Image first = renderSlices({v, t, sel}, tf, cam, cached), again = renderSlices({v, t, sel}, tf, cam, cached);
    EXPECT_LE(cache.size() - before, st.bricks);  // one texture a textured brick, none twice
    EXPECT_EQ(first.pixels, fresh.pixels);
    EXPECT_EQ(again.pixels, fresh.pixels);
  }
  EXPECT_GT(cache.size(), 0u);
  cache.clear();
  EXPECT_EQ(cache.size(), 0u);
}

// Textures are made as their bricks are drawn: a frame larger than the cache's limit keeps the
// bricks that fit (evicting earlier frames' for them), deletes the others after their draw, and
// draws what a frame without a cache draws.
TEST(Slices, AFrameLargerThanTheTextureLimitKeepsWhatFits) {
  gl();
  const Volume v = test::makeVolume({40, 36, 33}, [](int i, int j, int k) { return 8.0 + 7.0 * std::sin(0.35 * i) * std::cos(0.3 * j) + 0.2 * k; });
  const VolumeOctree t = VolumeOctree::build(v);
  const TransferFunction tf({{0.0f, {1, 1, 1}, 0.0f}, {2.0f, {1.0f, 0.6f, 0.3f}, 0.3f}, {15.0f, {0.3f, 0.6f, 1.0f}, 0.05f}}, "s");
  const Selection sel = selectNodes(t, SelectionParams{});
  SlicesStats st;
  const Image fresh = renderSlices({v, t, sel}, tf, Camera::orbit(glm::dvec3(0.0), v.extentMm(), {205, 20, 30, false, 64, 64}), SlicesOptions{}, &st);
  ASSERT_GT(st.bricks, 8u);
  const uint64_t limit = st.textureBytes / 3;
  BrickTextureCache cache(limit);
  SlicesOptions kept;
  kept.textures = &cache;
  const double azimuths[] = {205.0, 205.0, 120.0};  // a view, the same again, another
  for (int f = 0; f < 3; ++f) {
    const Camera cam = Camera::orbit(glm::dvec3(0.0), v.extentMm(), {azimuths[f], 20, 30, false, 64, 64});
    SlicesStats ks;
    const Image image = renderSlices({v, t, sel}, tf, cam, kept, &ks);
    EXPECT_EQ(image.pixels, renderSlices({v, t, sel}, tf, cam, SlicesOptions{}).pixels);
    EXPECT_LE(cache.bytes(), limit);  // not the whole frame's
    EXPECT_GT(cache.size(), 0u);
    if (f == 1) {
      EXPECT_GT(ks.uploadedBricks, 0u);  // what was not kept is made again
      EXPECT_LT(ks.uploadedBricks, ks.bricks);  // what was, is reused
    }
  }
}

TEST(Slices, VisibleBoxesCutOnlyTransparentSpace) {
  gl();
  // A shell of material around a transparent core, with a translucent quad through it, at full
  // resolution and with coarse, blended bricks: slicing only each brick's visible box must give
  // the image of whole bricks (to rounding of the interpolated positions) with fewer fragments.
  const Volume v = test::sphereVolume(glm::ivec3(48, 44, 40), 15.0);
  const VolumeOctree t = VolumeOctree::build(v);
  const TransferFunction tf({{-1.0f, {1, 1, 1}, 0.0f}, {0.0f, {1.0f, 0.6f, 0.3f}, 0.4f}, {2.0f, {0.3f, 0.6f, 1.0f}, 0.4f}, {3.0f, {1, 1, 1}, 0.0f}}, "shell");
  const TriangleMesh quad = quadAt(19.5, 2, 45, 2, 41);
  SelectionParams coarse;
  coarse.texelBudget = selectNodes(t, SelectionParams{}).texels / 4;
  ASSERT_GT(selectNodes(t, coarse).blendedBricks, 0u);
  const Camera cam = Camera::orbit(glm::dvec3(0.0), v.extentMm(), {205, 20, 30, false, 64, 64});
  for (const Proxy proxy : {Proxy::Planes, Proxy::Shells})
    for (const SelectionParams& params : {SelectionParams{}, coarse}) {
      const Selection sel = selectNodes(t, params);
      SlicesOptions boxes, whole;
      boxes.proxy = whole.proxy = proxy;
      boxes.surface = whole.surface = &quad;
      boxes.surfaceColor = whole.surfaceColor = glm::vec4(0.2f, 0.9f, 0.4f, 0.5f);
      whole.visibleBoxes = false;
      SlicesStats sb, sw;
      const std::vector<uint8_t> a = toRgba8(renderSlices({v, t, sel}, tf, cam, boxes, &sb), glm::vec3(0.0f));
      const std::vector<uint8_t> b = toRgba8(renderSlices({v, t, sel}, tf, cam, whole, &sw), glm::vec3(0.0f));
      const std::string what = std::string(proxy == Proxy::Shells ? "shells" : "planes") + ", budget " + std::to_string(params.texelBudget);
      EXPECT_EQ(sb.shellBricks > 0, proxy == Proxy::Shells) << what;
      int worst = 0;
      for (size_t k = 0; k < a.size(); ++k) worst = std::max(worst, std::abs(int(a[k]) - int(b[k])));
      EXPECT_LE(worst, 1) << what;
      EXPECT_EQ(sb.slabPolygonDraws, sw.slabPolygonDraws) << what;
      // Each slice or shell cut to the blocks it meets (measured at full resolution: 0.44 of the
      // fragments with planes, 0.43 with shells; shells cut to the brick's visible box alone 0.49).
      // Counted without the quad, whose triangles come whole in every slab they cover.
      boxes.surface = whole.surface = nullptr;
      renderSlices({v, t, sel}, tf, cam, boxes, &sb);
      renderSlices({v, t, sel}, tf, cam, whole, &sw);
      EXPECT_LT(double(sb.fragments), (params.texelBudget == 0 ? 0.47 : 0.8) * double(sw.fragments)) << what;
    }
}

// Every GL object a frame makes is owned: a frame that throws halfway (here its progress callback,
// after half the bricks) leaves no object behind, and the next frame in the same context renders
// the same image as before.
TEST(Slices, AFrameThatThrowsLeaksNothingAndTheNextOneRendersRight) {
  gl();
  const Volume v = test::sphereVolume(glm::ivec3(40, 36, 32), 13.0);
  const VolumeOctree t = VolumeOctree::build(v);
  const Selection sel = selectNodes(t, SelectionParams{});
  const TransferFunction tf({{0.0f, {1, 1, 1}, 0.0f}, {2.0f, {1.0f, 0.6f, 0.3f}, 0.3f}, {15.0f, {0.3f, 0.6f, 1.0f}, 0.05f}}, "s");
  const Camera cam = Camera::orbit(glm::dvec3(0.0), v.extentMm(), {205, 20, 30, false, 48, 48});
  const CutPlane cut{glm::dvec3(20, 18, 16), glm::dvec3(0.3, 1, 0)};
  SlicesOptions o;
  o.cut = &cut;
  const Image before = renderSlices({v, t, sel}, tf, cam, o);
  const size_t objects = liveGlObjects();
  const Progress stop([](const std::string&, double fraction) {
    if (fraction >= 0.5 && fraction < 1.0) throw std::runtime_error("stopped");
  });
  o.progress = &stop;
  EXPECT_THROW(renderSlices({v, t, sel}, tf, cam, o), std::runtime_error);
  EXPECT_EQ(liveGlObjects(), objects);
  o.progress = nullptr;
  EXPECT_EQ(renderSlices({v, t, sel}, tf, cam, o).pixels, before.pixels);
}

// A scene of hundreds of small bricks (leaves and bricks of 4), for the batched packing.
struct ManyBricks {
  Volume v = test::makeVolume({40, 36, 33}, [](int i, int j, int k) { return 8.0 + 7.0 * std::sin(0.35 * i) * std::cos(0.3 * j) + 0.2 * k; });
  VolumeOctree t = VolumeOctree::build(v, VolumeOctreeOptions{4, true, nullptr});
  TransferFunction tf{{{0.0f, {1, 1, 1}, 0.0f}, {2.0f, {1.0f, 0.6f, 0.3f}, 0.3f}, {15.0f, {0.3f, 0.6f, 1.0f}, 0.05f}}, "s"};
  Selection sel = [this] {
    SelectionParams params;
    params.maxBrickEdge = 4;
    return selectNodes(t, params);
  }();
};

// A frame packs its bricks a batch ahead of their draws: with batches of 16 bricks it holds at most
// two batches' packed texels while it makes hundreds of textures, and draws the image a frame that
// packs every brick first draws, with a cutting plane (the bricks it crosses are made before any
// draw, for the plane drawn first) and through a cache (a warm frame packs nothing).
TEST(Slices, BricksArePackedABatchAheadOfTheirDraws) {
  gl();
  const ManyBricks m;
  const auto& [v, t, tf, sel] = m;
  const Camera cam = Camera::orbit(glm::dvec3(0.0), v.extentMm(), {205, 20, 30, false, 64, 64});
  const CutPlane cut{glm::dvec3(20, 18, 16), glm::dvec3(0.3, 1, 0)};
  for (const CutPlane* plane : {static_cast<const CutPlane*>(nullptr), &cut}) {
    SlicesOptions batched, whole;
    batched.packBatch = 16;
    whole.packBatch = size_t(1) << 30;
    batched.cut = whole.cut = plane;
    SlicesStats sb, sw;
    const Image a = renderSlices({v, t, sel}, tf, cam, batched, &sb);
    const Image b = renderSlices({v, t, sel}, tf, cam, whole, &sw);
    const std::string what = plane ? "with the plane" : "without";
    EXPECT_EQ(a.pixels, b.pixels) << what;
    EXPECT_GT(sb.uploadedBricks, 20u * batched.packBatch) << what;
    EXPECT_EQ(sb.uploadedBricks, sb.bricks) << what;
    EXPECT_EQ(sb.uploadedBricks, sw.uploadedBricks) << what;
    EXPECT_EQ(sb.textureBytes, sw.textureBytes) << what;
    EXPECT_EQ(sb.fragments, sw.fragments) << what;
    EXPECT_EQ(sb.cutPolygons, sw.cutPolygons) << what;
    EXPECT_EQ(sb.cutPolygons > 0, plane != nullptr) << what;
    EXPECT_GT(sb.peakPackedBricks, 0u) << what;
    EXPECT_LE(sb.peakPackedBricks, 2 * batched.packBatch) << what;
    EXPECT_GE(sw.peakPackedBricks, (sw.uploadedBricks - sw.cutPolygons)) << what;  // one batch: all of them held at once
    // Through a cache: cold, the same image; warm, nothing packed.
    BrickTextureCache cache;
    batched.textures = &cache;
    SlicesStats cold, warm;
    EXPECT_EQ(renderSlices({v, t, sel}, tf, cam, batched, &cold).pixels, a.pixels) << what;
    EXPECT_EQ(cold.uploadedBricks, sb.uploadedBricks) << what;
    EXPECT_LE(cold.peakPackedBricks, 2 * batched.packBatch) << what;
    EXPECT_EQ(renderSlices({v, t, sel}, tf, cam, batched, &warm).pixels, a.pixels) << what;
    EXPECT_EQ(warm.uploadedBricks, 0u) << what;
    EXPECT_EQ(warm.peakPackedBricks, 0u) << what;
  }
}

// The knots of a volume in memory, failing once @p limit bricks' reads have been asked for: a
// paged store whose file turns out damaged partway through a frame.
class FailingKnots final : public KnotSource {
 public:
  FailingKnots(const Volume& v, const VolumeOctree& t, int limit) : mKnots(v, t), mLeft(limit) {}
  glm::ivec3 dims() const override { return mKnots.dims(); }
  glm::dvec3 spacing() const override { return mKnots.spacing(); }
  void read(int s, const glm::ivec3& lo, const glm::ivec3& count, float* values, glm::vec3* gradients) const override {
    if (mLeft.fetch_sub(1) <= 0) HYB_THROW(IoError, "damaged block");
    mKnots.read(s, lo, count, values, gradients);
  }

 private:
  VolumeKnots mKnots;
  mutable std::atomic<int> mLeft;
};

// A packing that fails while the frame draws (the third batch of 16 bricks reads a damaged block)
// stops the frame with the packing's error, the stream worker joined and no GL object left behind;
// the next frame renders right.
TEST(Slices, APackingThatFailsMidFrameStopsItCleanly) {
  gl();
  const ManyBricks m;
  const auto& [v, t, tf, sel] = m;
  const Camera cam = Camera::orbit(glm::dvec3(0.0), v.extentMm(), {205, 20, 30, false, 48, 48});
  SlicesOptions o;
  o.packBatch = 16;
  const Image before = renderSlices({v, t, sel}, tf, cam, o);
  const size_t objects = liveGlObjects();
  const FailingKnots failing(v, t, 40);  // full-resolution bricks read once each: the third batch fails
  o.knots = &failing;
  double reached = 0.0;
  const Progress heard([&](const std::string&, double fraction) { reached = std::max(reached, fraction < 1.0 ? fraction : 0.0); });
  o.progress = &heard;
  EXPECT_THROW(renderSlices({v, t, sel}, tf, cam, o), IoError);
  EXPECT_GT(reached, 0.0);  // some bricks were drawn before it failed
  EXPECT_EQ(liveGlObjects(), objects);
  o.knots = nullptr;
  o.progress = nullptr;
  EXPECT_EQ(renderSlices({v, t, sel}, tf, cam, o).pixels, before.pixels);
}

TEST(Slices, OpacityDoesNotDependOnTheSliceSpacing) {
  gl();
  // A homogeneous block viewed straight on: every slice spacing gives the same colour.
  const Volume v = test::makeVolume({17, 17, 17}, [](int, int, int) { return 1.0f; });
  const VolumeOctree t = VolumeOctree::build(v);
  const TransferFunction tf = constantTf(0.07f);
  const Selection sel = selectNodes(t, SelectionParams{});
  const Camera cam = straightOn(glm::dvec3(8.0));
  std::vector<glm::vec4> centres;
  for (double step : {0.25, 0.5, 1.0}) {
    SlicesOptions o;
    o.stepVoxels = step;
    o.shading = false;
    const Image img = renderSlices({v, t, sel}, tf, cam, o);
    centres.push_back(img.at(4, 4));
  }
  const float expected = 1.0f - std::pow(0.93f, 16.0f);
  for (const glm::vec4& c : centres) {
    EXPECT_NEAR(c.a, expected, 1.0f / 255.0f);
    EXPECT_NEAR(c.r, 0.8f * expected, 1.0f / 255.0f);
    EXPECT_NEAR(c.a, centres[0].a, 1.0f / 255.0f);
  }
}

// The viewer's moving frames space their planes 1.0-2.5 voxels apart. A coarse brick keeps about
// its own spacing in voxels there (a plane every 1.5 voxels at two voxels a texel), not the same
// multiple of the frame's (every 4.5 voxels at 1.5: woodgrain on a shell the transfer function
// draws narrow): at three times the default spacing such a brick's planes are the default's, and so
// is the image.
TEST(Slices, CoarseBricksKeepTheirSpacingInVoxelsAtAWideBaseSpacing) {
  gl();
  const Volume v = test::sphereVolume({33, 33, 33}, 11.0);
  const VolumeOctree t = VolumeOctree::build(v);
  // A shell a voxel and a half thick at radius 11, oblique to every plane of an oblique view.
  const TransferFunction tf({{-1.0f, {0.8f, 0.5f, 0.2f}, 0.0f}, {0.0f, {0.8f, 0.5f, 0.2f}, 0.5f}, {0.5f, {0.8f, 0.5f, 0.2f}, 0.0f}}, "shell");
  SelectionParams coarse;
  coarse.epsilon = 1.0f;
  const Selection sel = selectNodes(t, coarse);
  int finest = 1 << 30;
  for (const Brick& b : sel.bricks)
    if (!b.hidden) finest = std::min(finest, t.lattice(t.nodes()[b.node], b.p).step);
  ASSERT_EQ(finest, 2) << "the sphere's error should select bricks of two voxels a texel";
  Camera cam;
  cam.center = glm::dvec3(16.0);
  cam.eye = cam.center + 80.0 * glm::normalize(glm::dvec3(0.3, 0.5, 1.0));
  cam.up = glm::dvec3(0, 1, 0);
  cam.ortho = true;
  cam.orthoHeight = 34.0;
  cam.width = cam.height = 64;
  SlicesOptions o;
  o.shading = false;
  SlicesStats atDefault, atWide;
  const Image base = renderSlices({v, t, sel}, tf, cam, o, &atDefault);
  o.stepVoxels = 1.5;
  const Image wide = renderSlices({v, t, sel}, tf, cam, o, &atWide);
  EXPECT_EQ(atWide.slices, atDefault.slices);
  EXPECT_GE(psnrOf(base, wide), 60.0);
}

TEST(Slices, OpaqueSurfaceHidesTheVolumeBehindIt) {
  gl();
  const Volume v = test::makeVolume({11, 11, 11}, [](int, int, int) { return 1.0f; });
  const VolumeOctree t = VolumeOctree::build(v);
  const TransferFunction tf = constantTf(0.05f);
  const TriangleMesh quad = quadAt(5.0, -1, 11, -1, 11);
  const Camera cam = straightOn(glm::dvec3(5.0));
  SlicesOptions o;
  o.shading = false;
  o.surface = &quad;
  o.surfaceColor = glm::vec4(0.2f, 0.4f, 0.6f, 1.0f);
  const glm::vec4 p = renderSlices({v, t, selectNodes(t, SelectionParams{})}, tf, cam, o).at(4, 4);
  const float a1 = 1.0f - std::pow(0.95f, 5.0f);  // the 5 mm in front of the quad
  EXPECT_NEAR(p.a, 1.0f, 1.0f / 255.0f);
  EXPECT_NEAR(p.b, 0.2f * a1 + (1 - a1) * 0.6f, 2.0f / 255.0f);
}

// An opaque plane of 80,000 triangles a tenth of a pixel wide, seen straight on (8x8 pixels of
// 0.5 mm): nearly every triangle lies between pixel centres and is left out, and still every pixel
// shows the plane, opaque (a triangle left out wrongly would leave a pixel on the material behind).
TEST(Slices, AnOpaqueSurfaceLeavesOutTrianglesBetweenPixelCentresAndNoPixel) {
  gl();
  const Volume v = test::makeVolume({11, 11, 11}, [](int, int, int) { return 1.0f; });
  const VolumeOctree t = VolumeOctree::build(v);
  const TriangleMesh plane = gridMesh(200, [](double gu, double gv) { return glm::vec3(-1.0 + 12.0 * gu, -1.0 + 12.0 * gv, 5.0); });
  SlicesOptions o;
  o.shading = false;
  o.surface = &plane;
  o.surfaceColor = glm::vec4(0.2f, 0.4f, 0.6f, 1.0f);
  SlicesStats st;
  const Image image = renderSlices({v, t, selectNodes(t, SelectionParams{})}, constantTf(0.05f), straightOn(glm::dvec3(5.0)), o, &st);
  EXPECT_GT(st.unseenTriangles, 78000u);
  const float a1 = 1.0f - std::pow(0.95f, 5.0f);  // the 5 mm in front of the plane
  for (int y = 0; y < image.height; ++y)
    for (int x = 0; x < image.width; ++x) {
      EXPECT_NEAR(image.at(x, y).a, 1.0f, 1.0f / 255.0f) << x << "," << y;
      EXPECT_NEAR(image.at(x, y).b, 0.2f * a1 + (1 - a1) * 0.6f, 2.0f / 255.0f) << x << "," << y;
    }
}

// Leaving out the triangles between pixel centres, and drawing those whose covered centres lie in
// one slab there alone, changes no pixel: a sphere's surface (its triangles about a pixel wide at
// 40²) inside a shell of material, translucent and opaque, in perspective with planes and with
// shells, orthographic, and in a band of rows.
TEST(Slices, TrianglesLeftOutBetweenPixelCentresChangeNoPixel) {
  gl();
  const Volume v = test::sphereVolume(glm::ivec3(48, 44, 40), 15.0);
  const VolumeOctree t = VolumeOctree::build(v);
  const TriangleMesh mesh = fineMeshToTriangles(SurfaceOctree::build(v, t, 3.0f).reconstruct(), v.spacing());
  const TransferFunction tf({{-1.0f, {1, 1, 1}, 0.0f}, {0.0f, {1.0f, 0.6f, 0.3f}, 0.2f}, {2.0f, {0.3f, 0.6f, 1.0f}, 0.2f}, {3.0f, {1, 1, 1}, 0.0f}}, "shell");
  const Selection sel = selectNodes(t, SelectionParams{});
  for (const float alpha : {0.5f, 1.0f})
    for (int view = 0; view < 4; ++view) {
      SlicesOptions o;
      o.surface = &mesh;
      o.surfaceColor = glm::vec4(0.9f, 0.8f, 0.6f, alpha);
      o.proxy = view == 1 ? Proxy::Shells : Proxy::Planes;
      if (view == 3) o.rows = glm::ivec2(13, 29);
      const Camera cam = Camera::orbit(glm::dvec3(0.0), v.extentMm(), {205, 20, 30, view == 2, 40, 40});
      SlicesStats left, all;
      const Image a = renderSlices({v, t, sel}, tf, cam, o, &left);
      o.leaveOutUnseen = false;
      const Image b = renderSlices({v, t, sel}, tf, cam, o, &all);
      const std::string what = "alpha " + std::to_string(alpha) + ", view " + std::to_string(view);
      EXPECT_GT(left.unseenTriangles, mesh.triangles.size() / 10) << what;
      EXPECT_EQ(all.unseenTriangles, 0u) << what;
      if (alpha < 1.0f) {
        EXPECT_LT(left.slabPolygonDraws, all.slabPolygonDraws) << what;
      }
      size_t differing = 0;
      for (int y = 0; y < a.height; ++y)
        for (int x = 0; x < a.width; ++x) differing += a.at(x, y) != b.at(x, y);
      EXPECT_EQ(differing, 0u) << what;
    }
}

TEST(Slices, TranslucentQuadLandsInTheRightSlab) {
  gl();
  // A 10 mm slab of material with a translucent quad inside, at a generic depth, exactly on a slice
  // plane, and at the front face; axis-aligned, tilted and diagonal views. The centre pixel must
  // match the closed form; drawing the quad after its brick's slices (no slab order) must not.
  // The quad goes in as two triangles and as one planar polygon of two (a slab then takes the
  // polygon's triangles that reach it, each keeping its fragments in the slab where it covers more
  // than one).
  const Volume v = test::makeVolume({21, 21, 11}, [](int, int, int) { return 1.0f; });
  const VolumeOctree t = VolumeOctree::build(v);
  const float a = 0.08f;
  const glm::vec3 c(0.8f, 0.5f, 0.2f);
  const TransferFunction tf = constantTf(a);
  const Selection sel = selectNodes(t, SelectionParams{});
  const glm::vec4 surface(0.1f, 0.9f, 0.3f, 0.6f);
  for (double zq : {3.3, 4.0, 9.9}) {
    TriangleMesh quad = quadAt(zq, -5, 25, -5, 25);
    quad.triangles = {{0, 1, 3}, {1, 2, 3}};  // seen tilted, the two triangles cover different slabs
    TriangleMesh polygon = quad;
    polygon.polygonStarts = {0, 2};
    for (const glm::dvec3 dir : {glm::dvec3(0, 0, 1), glm::dvec3(0.3, 0.2, 1), glm::dvec3(1, 1, 1)}) {
      const glm::dvec3 u = glm::normalize(dir);
      Camera cam;
      cam.center = glm::dvec3(10, 10, 5);
      cam.eye = cam.center + u * 80.0;
      cam.up = std::abs(u.z) > 0.9 ? glm::dvec3(0, 1, 0) : glm::dvec3(0, 0, 1);
      cam.ortho = true;
      cam.orthoHeight = 2.0;
      cam.width = cam.height = 8;
      const double front = (10.0 - zq) / u.z, back = zq / u.z;
      const float a1 = 1.0f - std::pow(1.0f - a, float(front)), a2 = 1.0f - std::pow(1.0f - a, float(back));
      const float shade = float(0.25 + 0.75 * u.z);
      const glm::vec3 expected = c * a1 + (1 - a1) * (glm::vec3(surface) * shade * surface.a + (1 - surface.a) * c * a2);
      uint64_t draws[2] = {0, 0};
      const TriangleMesh* meshes[2] = {&quad, &polygon};
      for (int kind = 0; kind < 2; ++kind)
        for (bool slabOrder : {true, false}) {
          SlicesOptions o;
          o.stepVoxels = 0.25;
          o.shading = false;
          o.surface = meshes[kind];
          o.surfaceColor = surface;
          o.slabOrder = slabOrder;
          SlicesStats st;
          const glm::vec4 p = renderSlices({v, t, sel}, tf, cam, o, &st).at(4, 4);
          const float error = glm::length(glm::vec3(p) - expected);
          const std::string where = "zq " + std::to_string(zq) + (kind == 0 ? " as triangles" : " as a polygon") +
                                    " dir " + std::to_string(dir.x) + "," + std::to_string(dir.y) + "," + std::to_string(dir.z);
          if (slabOrder) {
            EXPECT_LE(error, 2.0f / 255.0f) << where;
            EXPECT_GE(st.slabPolygonDraws, st.surfaceTriangles) << where;
            draws[kind] = st.slabPolygonDraws;
          } else if (zq < 9.0) {
            EXPECT_GT(error, 10.0f / 255.0f) << "the wrong order went unnoticed at " << where;
          }
        }
      EXPECT_EQ(draws[0], draws[1]) << "a polygon's triangles go to the slabs they reach, as on their own";
    }
  }
}

// A translucent plane tilted through 24 slabs, made of 800 triangles whose shared edges cross the
// slab planes everywhere, over nearly transparent material: each triangle comes once per slab it
// covers and keeps only that slab's fragments, so every pixel the plane covers gets the surface's
// opacity exactly once (a crack would leave about 0, a pixel drawn twice 0.75).
TEST(Slices, ATranslucentSurfaceAcrossManySlabsCoversEachPixelOnce) {
  gl();
  const Volume v = test::makeVolume({21, 21, 11}, [](int, int, int) { return 1.0f; });
  const VolumeOctree t = VolumeOctree::build(v);
  const TriangleMesh plane = gridMesh(20, [](double gu, double gv) { return glm::vec3(10.0 * gu, 10.0 * gv, 2.0 + 6.0 * gu); });  // z = 2 + 0.6 x
  Camera cam;
  cam.center = glm::dvec3(5, 5, 5);
  cam.eye = cam.center + glm::normalize(glm::dvec3(0.3, 0.2, 1)) * 80.0;
  cam.up = glm::dvec3(0, 1, 0);
  cam.ortho = true;
  cam.orthoHeight = 14.0;
  cam.width = cam.height = 64;
  SlicesOptions o;
  o.stepVoxels = 0.25;
  o.shading = false;
  o.surface = &plane;
  o.surfaceColor = glm::vec4(0.1f, 0.9f, 0.3f, 0.5f);
  SlicesStats st;
  const Image image = renderSlices({v, t, selectNodes(t, SelectionParams{})}, constantTf(1e-4f), cam, o, &st);
  EXPECT_GT(st.slabPolygonDraws, 2 * st.surfaceTriangles);
  int inside = 0;
  for (int y = 0; y < image.height; ++y)
    for (int x = 0; x < image.width; ++x) {
      glm::dvec3 origin, dir;
      cam.ray(x + 0.5, y + 0.5, &origin, &dir);
      // Where the ray meets z = 2 + 0.6 x: (origin + s dir).z = 2 + 0.6 (origin + s dir).x.
      const double s = (2.0 + 0.6 * origin.x - origin.z) / (dir.z - 0.6 * dir.x);
      const glm::dvec3 hit = origin + s * dir;
      if (hit.x < 0.3 || hit.x > 9.7 || hit.y < 0.3 || hit.y > 9.7) continue;  // a pixel's width inside the edges
      ++inside;
      EXPECT_NEAR(image.at(x, y).a, 0.5f, 0.01f) << "pixel " << x << "," << y;
    }
  EXPECT_GT(inside, 1200);
}

TEST(Slices, TranslucentQuadKeepsItsOrderInCoarseBricks) {
  gl();
  // A smooth field that the transfer function classifies as one material: the image has the closed
  // form of a homogeneous slab, but coarse levels approximate the field, so ε selects bricks two
  // voxels a texel. Those are sliced at their own rate, also where they hold the quad (their slabs
  // follow their slices, as Boada's SlabPolygon lists): the quad keeps its order between the
  // slices, its depth quantised to a slab (tolerance: a slab's opacity), and it is cut into fewer
  // slab pieces than at full resolution. Where a level is exact (ε = 0) the base spacing stays.
  const Volume v = test::makeVolume({17, 17, 17}, [](int x, int y, int z) {  // one node: the quad lies in one brick
    return float(1.0 + 0.4 * std::sin(x / 3.0) * std::sin(y / 3.0) * std::cos(z / 4.0));
  });
  const VolumeOctree t = VolumeOctree::build(v);
  const float a = 0.08f;
  const glm::vec3 c(0.8f, 0.5f, 0.2f);
  const TransferFunction tf = constantTf(a);
  const glm::vec4 surface(0.1f, 0.9f, 0.3f, 0.6f);
  SelectionParams coarse;
  coarse.epsilon = 0.15f;
  const Selection fine = selectNodes(t, SelectionParams{}), sel = selectNodes(t, coarse);
  int steps = 1;
  for (const Brick& b : sel.bricks)
    if (!b.hidden) steps = std::max(steps, t.lattice(t.nodes()[b.node], b.p).step);
  ASSERT_EQ(steps, 2) << "the field's error should select bricks two voxels a texel";
  const double stepVoxels = 0.25, slab = stepVoxels * steps;  // mm (unit spacing)
  const float tolerance = 1.0f - std::pow(1.0f - a, float(slab)) + 2.0f / 255.0f;
  for (double zq : {5.3, 8.0}) {
    const TriangleMesh quad = quadAt(zq, -5, 21, -5, 21);
    for (const glm::dvec3 dir : {glm::dvec3(0, 0, 1), glm::dvec3(0.3, 0.2, 1)}) {
      const glm::dvec3 u = glm::normalize(dir);
      Camera cam;
      cam.center = glm::dvec3(8, 8, 8);
      cam.eye = cam.center + u * 80.0;
      cam.up = glm::dvec3(0, 1, 0);
      cam.ortho = true;
      cam.orthoHeight = 2.0;
      cam.width = cam.height = 8;
      const double front = (16.0 - zq) / u.z, back = zq / u.z;
      const float a1 = 1.0f - std::pow(1.0f - a, float(front)), a2 = 1.0f - std::pow(1.0f - a, float(back));
      const glm::vec3 expected = c * a1 + (1 - a1) * (glm::vec3(surface) * float(0.25 + 0.75 * u.z) * surface.a + (1 - surface.a) * c * a2);
      const std::string where = "zq " + std::to_string(zq) + " dir " + std::to_string(dir.x) + "," + std::to_string(dir.z);
      SlicesOptions o;
      o.stepVoxels = stepVoxels;
      o.shading = false;
      o.surface = &quad;
      o.surfaceColor = surface;
      SlicesStats atFine, atCoarse, unordered;
      EXPECT_LE(glm::length(glm::vec3(renderSlices({v, t, fine}, tf, cam, o, &atFine).at(4, 4)) - expected), 2.0f / 255.0f) << where;
      EXPECT_LE(glm::length(glm::vec3(renderSlices({v, t, sel}, tf, cam, o, &atCoarse).at(4, 4)) - expected), tolerance) << where;
      o.slabOrder = false;
      EXPECT_GT(glm::length(glm::vec3(renderSlices({v, t, sel}, tf, cam, o, &unordered).at(4, 4)) - expected), 3.0f * tolerance)
          << "the wrong order went unnoticed at " << where;
      EXPECT_LT(atCoarse.slices, atFine.slices) << where;
      if (dir.x != 0.0) {
        EXPECT_LT(atCoarse.slabPolygonDraws, atFine.slabPolygonDraws) << where;
      }
    }
  }
}

TEST(Slices, QuadSeenEdgeOnLeavesThePureSlab) {
  gl();
  // Viewing along x, the quad z = 3.3 is edge-on (perpendicular to every slice): the centre ray at
  // z = 5 meets only the 20 mm of material along x.
  const Volume v = test::makeVolume({21, 21, 11}, [](int, int, int) { return 1.0f; });
  const VolumeOctree t = VolumeOctree::build(v);
  const TransferFunction tf = constantTf(0.05f);
  const TriangleMesh quad = quadAt(3.3, -5, 25, -5, 25);
  Camera cam;
  cam.center = glm::dvec3(10, 10, 5);
  cam.eye = cam.center + glm::dvec3(80, 0, 0);
  cam.up = glm::dvec3(0, 0, 1);
  cam.ortho = true;
  cam.orthoHeight = 1.0;
  cam.width = cam.height = 8;
  SlicesOptions o;
  o.shading = false;
  o.surface = &quad;
  o.surfaceColor = glm::vec4(0.1f, 0.9f, 0.3f, 0.6f);
  const glm::vec4 p = renderSlices({v, t, selectNodes(t, SelectionParams{})}, tf, cam, o).at(4, 4);
  EXPECT_NEAR(p.a, 1.0f - std::pow(0.95f, 20.0f), 2.0f / 255.0f);
  EXPECT_NEAR(p.g, 0.5f * p.a, 2.0f / 255.0f);  // no green from the quad
}

TEST(Slices, Extremes) {
  gl();
  const Volume v = test::makeVolume({9, 9, 9}, [](int, int, int) { return 1.0f; });
  const VolumeOctree t = VolumeOctree::build(v);
  const Selection sel = selectNodes(t, SelectionParams{});
  SlicesOptions o;
  o.shading = false;
  // Fully transparent: the background; fully opaque: the material's colour.
  EXPECT_EQ(renderSlices({v, t, sel}, constantTf(0.0f), straightOn(glm::dvec3(4.0)), o).at(4, 4), glm::vec4(0.0f));
  const glm::vec4 opaque = renderSlices({v, t, sel}, constantTf(1.0f), straightOn(glm::dvec3(4.0)), o).at(4, 4);
  EXPECT_NEAR(opaque.a, 1.0f, 1e-5f);
  EXPECT_NEAR(opaque.r, 0.8f, 1e-5f);
  // Camera inside the volume, looking down -z from z = 4: the 4 mm in front count, less at most one
  // slice spacing (0.5 mm) next to the eye, whose slice lies on the near plane.
  const float in = renderSlices({v, t, sel}, constantTf(0.1f), test::insideCamera(), o).at(1, 1).a;
  EXPECT_GE(in, 1.0f - std::pow(0.9f, 3.5f) - 1e-4f);
  EXPECT_LE(in, 1.0f - std::pow(0.9f, 4.0f) + 1e-4f);
  // One voxel and a single slice: no volume to slice, no crash, an empty image.
  for (const glm::ivec3 dims : {glm::ivec3(1, 1, 1), glm::ivec3(16, 16, 1)}) {
    const Volume thin = test::makeVolume(dims, [](int, int, int) { return 1.0f; });
    const VolumeOctree tt = VolumeOctree::build(thin);
    const Image img = renderSlices({thin, tt, selectNodes(tt, SelectionParams{})}, constantTf(0.5f), straightOn(glm::dvec3(0.5)), o);
    for (const glm::vec4& p : img.pixels) EXPECT_EQ(p, glm::vec4(0.0f));
  }
  // A 1x1 image and a 4096x4096 image.
  Camera tiny = straightOn(glm::dvec3(4.0));
  tiny.width = tiny.height = 1;
  EXPECT_NEAR(renderSlices({v, t, sel}, constantTf(0.1f), tiny, o).at(0, 0).a, 1.0f - std::pow(0.9f, 8.0f), 2.0f / 255.0f);
  Camera big = straightOn(glm::dvec3(4.0));
  big.width = big.height = 4096;
  big.orthoHeight = 40.0;
  const Image huge = renderSlices({v, t, sel}, constantTf(0.1f), big, o);
  EXPECT_NEAR(huge.at(2048, 2048).a, 1.0f - std::pow(0.9f, 8.0f), 2.0f / 255.0f);
  EXPECT_EQ(huge.at(0, 0), glm::vec4(0.0f));
  // Values near the float range's ends: finite images from both renderers.
  const Volume wild = test::makeVolume({9, 9, 9}, [](int i, int j, int k) { return ((i + j + k) % 2 ? 1.0f : -1.0f) * 1e37f; });
  const VolumeOctree wt = VolumeOctree::build(wild);
  const TransferFunction wtf({{-1e37f, {1, 1, 1}, 0.1f}, {1e37f, {0.5f, 0.5f, 1}, 0.3f}}, "wild");
  SlicesOptions shaded;
  for (const Image& img : {renderSlices({wild, wt, selectNodes(wt, SelectionParams{})}, wtf, straightOn(glm::dvec3(4.0)), shaded),
                           raycast(wild, wt, wtf, straightOn(glm::dvec3(4.0)), RaycastOptions{})}) {
    for (const glm::vec4& p : img.pixels) ASSERT_TRUE(std::isfinite(p.r) && std::isfinite(p.a));
    EXPECT_GT(img.at(4, 4).a, 0.5f);
  }
  // A spacing that would need more than 2^30 slabs is refused with a message, not wrapped.
  SlicesOptions fine = o;
  fine.stepVoxels = 1e-9;
  EXPECT_THROW(renderSlices({v, t, sel}, constantTf(0.1f), straightOn(glm::dvec3(4.0)), fine), ValueError);
}

TEST(SlicesCranium, MatchesTheReferenceAtFullResolution) {
  gl();
  const Volume v = readVolume(kDefaultVolumePath);
  const VolumeOctree t = VolumeOctree::build(v);
  const TransferFunction tf = TransferFunction::preset("ct-skin-bone");
  const Selection sel = selectNodes(t, SelectionParams{});
  for (bool ortho : {false, true}) {
    const Camera cam = Camera::orbit(glm::dvec3(0.0), v.extentMm(), {205, 20, 30, ortho, 128, 128});
    const double db = psnrOf(renderSlices({v, t, sel}, tf, cam, SlicesOptions{}), raycast(v, t, tf, cam, RaycastOptions{}));
    EXPECT_GE(db, 35.0) << "ortho " << ortho;
  }
  // With the translucent bone surface inside, through the SlabPolygon lists.
  const SurfaceOctree so = SurfaceOctree::build(v, t, 400.0f);
  const TriangleMesh mesh = fineMeshToTriangles(so.reconstruct(), v.spacing());
  const Bvh bvh(mesh);
  const glm::vec4 color(0.95f, 0.92f, 0.85f, 0.5f);
  SlicesOptions so2;
  so2.surface = &mesh;
  so2.surfaceColor = color;
  RaycastOptions ro;
  ro.surface = &bvh;
  ro.surfaceColor = color;
  const Camera cam = Camera::orbit(glm::dvec3(0.0), v.extentMm(), {180, 10, 30, false, 128, 128});
  EXPECT_GE(psnrOf(renderSlices({v, t, sel}, tf, cam, so2), raycast(v, t, tf, cam, ro)), 35.0);
}

// The translucent surface's views have no isolated black pixel where the reference has none. The
// specks were NaN colours: llvmpipe rasterises a slab piece of zero area (fanned across collinear
// vertices) once its float corners snap apart, and interpolates its attributes through the
// reciprocal of that area. Each frame that shows candidates is checked against the reference.
void expectNoSpecks(SceneRenderer& r, const Look& look, const Quality& quality, const std::vector<std::pair<std::string, ViewDirection>>& views,
                    int pixels) {
  const std::vector<glm::dvec3> points = visiblePoints(r.volume(), r.octree(), look.tf, look.iso);
  for (const auto& [name, direction] : views) {
    View view;
    view.camera = fitCamera(points, direction, {30.0, false, pixels, pixels});
    const Image image = r.render(view, look, quality).image;
    std::vector<glm::ivec2> specks = test::isolatedBlackPixels(image);
    if (!specks.empty()) {
      Quality reference;
      reference.renderer = Renderer::Raycast;
      const Image truth = r.render(view, look, reference).image;
      specks = test::isolatedBlackPixels(image, &truth);
    }
    EXPECT_TRUE(specks.empty()) << name << ": " << specks.size() << " isolated black pixels, the first at (" << (specks.empty() ? 0 : specks[0].x)
                                << ", " << (specks.empty() ? 0 : specks[0].y) << ")";
  }
}

std::vector<std::pair<std::string, ViewDirection>> sixViewsAndTwoOrbits() {
  std::vector<std::pair<std::string, ViewDirection>> views;
  for (const char* name : {"anterior", "posterior", "left", "right", "superior", "inferior"}) {
    AnatomicalView v;
    EXPECT_TRUE(parseAnatomicalView(name, &v));
    views.emplace_back(name, viewDirection(v));
  }
  views.emplace_back("orbit 30,15", orbitDirection(30, 15));
  views.emplace_back("orbit -120,40", orbitDirection(-120, 40));
  return views;
}

// Frames as the viewer draws them while the view moves: the simplified surface (here the levels
// within a pixel; the viewer allows two), whole in its slabs, in larger bricks (slices a voxel
// apart: coarser ones alias the skin's edges into dark pixels).
Quality moving() {
  Quality q;
  q.simplifiedSurface = true;
  q.cutToSlabs = false;
  q.maxBrickEdge = kSimplifiedBlockVoxels;
  q.step = 1.0;
  return q;
}

TEST(SlicesCranium, NoIsolatedBlackPixelsOnTheTranslucentSurface) {
  SceneRenderer r(test::craniumScene());
  Look look;
  look.tf = TransferFunction::defaultFor(r.volume().minValue(), r.volume().maxValue());
  look.iso = 400.0f;
  look.surfaceColor = glm::vec4(0.95f, 0.92f, 0.85f, 0.5f);
  expectNoSpecks(r, look, Quality{}, sixViewsAndTwoOrbits(), 512);
  expectNoSpecks(r, look, moving(), sixViewsAndTwoOrbits(), 256);
  look.normals = SurfaceNormals::Facet;  // (the left view held five with either normals)
  expectNoSpecks(r, look, Quality{}, {{"left, facet normals", viewDirection(AnatomicalView::Left)}}, 512);
}

// A sphere (300) inside a shell (100), the sphere's surface translucent inside the shell's volume.
TEST(Slices, NoIsolatedBlackPixelsOnASphereInAShell) {
  Scene scene;
  scene.volume = test::makeVolume({80, 80, 80}, [](int i, int j, int k) {
    const double r = glm::length(glm::dvec3(i, j, k) - glm::dvec3(39.5));
    return 100.0 * std::clamp(1.0 - std::abs(r - 33.0) / 4.0, 0.0, 1.0) + 300.0 * std::clamp((25.0 - r) / 2.0, 0.0, 1.0);
  });
  scene.octree = VolumeOctree::build(scene.volume);
  SceneRenderer r(std::move(scene));
  Look look;
  look.tf = TransferFunction({{0, {0, 0, 0}, 0}, {40, {0.8f, 0.5f, 0.4f}, 0.02f}, {100, {0.9f, 0.6f, 0.5f}, 0.08f}, {300, {1, 1, 1}, 0.3f}}, "shell");
  look.iso = 150.0f;
  look.surfaceColor = glm::vec4(0.95f, 0.92f, 0.85f, 0.5f);
  expectNoSpecks(r, look, Quality{}, sixViewsAndTwoOrbits(), 384);
  expectNoSpecks(r, look, moving(), sixViewsAndTwoOrbits(), 256);
}

}  // namespace
}  // namespace hyb
