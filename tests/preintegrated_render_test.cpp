// Both renderers with pre-integrated classification, against closed forms and the reference.
#include <gtest/gtest.h>

#include <cmath>

#include "hybrid_octree/surface_octree.h"
#include "render/preintegration.h"
#include "render/raycast.h"
#include "render/patient_view.h"
#include "render/scene_renderer.h"
#include "render/slices.h"
#include "render_util.h"
#include "test_util.h"
#include "volume/volume_io.h"

namespace hyb {
namespace {

using test::constantTf;
using test::gl;
using test::psnrOf;

constexpr float kTol = 2.0f / 255.0f;

// An orthographic camera looking along +x through the middle of @p v, 8 pixels over 2 mm.
Camera alongX(const Volume& v) {
  Camera c;
  c.center = 0.5 * v.extentMm();
  c.eye = c.center - glm::dvec3(100, 0, 0);
  c.up = glm::dvec3(0, 0, 1);
  c.ortho = true;
  c.orthoHeight = 2.0;
  c.width = c.height = 8;
  return c;
}

// Every renderer's frame of @p v at @p step voxels, classified as @p how: the slices' and the
// reference's centre pixels.
std::vector<glm::vec4> centres(const Volume& v, const TransferFunction& tf, const Camera& cam, double step, Classification how) {
  const VolumeOctree t = VolumeOctree::build(v);
  const double mm = step * std::min({v.spacing().x, v.spacing().y, v.spacing().z});
  const PreIntegrationTable table = preintegrationFor(tf, v.minValue(), v.maxValue(), 0.125 * mm, 64.0 * mm);
  const PreIntegrationTable* pre = how == Classification::PreIntegrated ? &table : nullptr;
  SlicesOptions so;
  so.stepVoxels = step;
  so.shading = false;
  so.preintegrated = pre;
  RaycastOptions ro;
  ro.stepVoxels = step;
  ro.shading = false;
  ro.preintegrated = pre;
  const Image slices = renderSlices({v, t, selectNodes(t, SelectionParams{})}, tf, cam, so);
  const Image rays = raycast(v, t, tf, cam, ro);
  return {slices.at(cam.width / 2, cam.height / 2), rays.at(cam.width / 2, cam.height / 2)};
}

TEST(PreIntegrated, AHomogeneousBlocksClosedFormHoldsAtAnySlabThickness) {
  gl();
  // 16 mm of one material, straight on and (perspective) obliquely: every step, in both renderers.
  const Volume v = test::makeVolume({17, 17, 17}, [](int, int, int) { return 1.0f; });
  const float a = 0.07f;
  const float straight = 1.0f - std::pow(1.0f - a, 16.0f);
  for (const double step : {0.25, 0.5, 1.0, 1.7, 3.0})
    for (const glm::vec4& c : centres(v, constantTf(a), test::orthoDown(glm::dvec3(8.0), 4.0, 8), step, Classification::PreIntegrated)) {
      EXPECT_NEAR(c.a, straight, kTol) << step;
      EXPECT_NEAR(c.r, 0.8f * straight, kTol) << step;
      EXPECT_NEAR(c.b, 0.2f * straight, kTol) << step;
    }
  // A perspective ray through the block's middle from a corner's side: the same material over the
  // ray's own length inside the box.
  Camera cam = test::perspective(glm::dvec3(40, 30, 50), glm::dvec3(8.0), glm::dvec3(0, 0, 1), 10.0, 9);
  glm::dvec3 o, d;
  cam.ray(4.5, 4.5, &o, &d);
  double t0 = -1e300, t1 = 1e300;
  for (int k = 0; k < 3; ++k) {
    const double ta = (0.0 - o[k]) / d[k], tb = (16.0 - o[k]) / d[k];
    t0 = std::max(t0, std::min(ta, tb));
    t1 = std::min(t1, std::max(ta, tb));
  }
  const float oblique = 1.0f - std::pow(1.0f - a, float(t1 - t0));
  for (const double step : {0.5, 1.7})
    for (const glm::vec4& c : centres(v, constantTf(a), cam, step, Classification::PreIntegrated)) EXPECT_NEAR(c.a, oblique, kTol) << step;
}

TEST(PreIntegrated, ANarrowSpikeBetweenSamplesIsFound) {
  gl();
  // Values rise 10 a millimetre along x; the transfer function is a tent of opacity A per mm over
  // 100 ± w. A ray along x crosses it in 2w/10 mm: its optical depth is
  // (2/10)·∫₀^w −ln(1 − A·t/w) dt = (2w/(10·A))·((1 − A)·ln(1 − A) + A).
  const Volume v = test::makeVolume({65, 9, 9}, [](int i, int, int) { return 10.0f * float(i); });
  const float A = 0.9f, w = 3.0f;
  const glm::vec3 color(0.8f, 0.5f, 0.2f);
  const TransferFunction tf({{0, color, 0}, {100 - w, color, 0}, {100, color, A}, {100 + w, color, 0}, {200, color, 0}}, "spike");
  const double depth = 2.0 * w / (10.0 * A) * ((1.0 - A) * std::log(1.0 - A) + A);
  const float alpha = float(1.0 - std::exp(-depth));
  // Samples two voxels (20 units) apart: post-classification misses the tent, or lands on its peak.
  for (const glm::vec4& c : centres(v, tf, alongX(v), 2.0, Classification::Post)) EXPECT_GT(std::abs(c.a - alpha), 0.1f);
  for (const double step : {2.0, 3.0})
    for (const glm::vec4& c : centres(v, tf, alongX(v), step, Classification::PreIntegrated)) {
      EXPECT_NEAR(c.a, alpha, kTol) << step;
      EXPECT_NEAR(c.g, 0.5f * alpha, kTol) << step;
    }
}

TEST(PreIntegrated, VisibleBoxesLeaveTheImageAsItIs) {
  gl();
  // Slicing only the cells the transfer function can make visible draws what slicing whole bricks
  // does: a slice outside them whose segment reaches into them is kept. A tent the rays cross
  // obliquely, at spacings where slices fall on either side of it.
  const Volume v = test::makeVolume({65, 33, 33}, [](int i, int j, int k) { return 10.0f * float(i) + 0.7f * float(j) + 0.3f * float(k); });
  const VolumeOctree t = VolumeOctree::build(v);
  const glm::vec3 color(0.8f, 0.5f, 0.2f);
  const TransferFunction tf({{0, color, 0}, {197, color, 0}, {200, color, 0.9f}, {203, color, 0}, {400, color, 0}}, "spike");
  const Selection sel = selectNodes(t, SelectionParams{});
  const Camera cam = test::perspective(glm::dvec3(-30, 40, 50), glm::dvec3(20, 16, 16), glm::dvec3(0, 0, 1), 40.0, 48);
  for (const double step : {1.5, 2.0, 3.0, 5.0}) {
    const PreIntegrationTable table = preintegrationFor(tf, v.minValue(), v.maxValue(), 0.25 * step, 64.0 * step);
    SlicesOptions o;
    o.stepVoxels = step;
    o.preintegrated = &table;
    o.visibleBoxes = false;
    const Image whole = renderSlices({v, t, sel}, tf, cam, o);
    o.visibleBoxes = true;
    EXPECT_GE(psnrOf(renderSlices({v, t, sel}, tf, cam, o), whole), 60.0) << step;
  }
}

TEST(PreIntegrated, TheKeptTableTextureFollowsTheTable) {
  gl();
  // Frames through one texture cache with two tables in turn draw what frames without it draw.
  const Volume v = test::makeVolume({17, 17, 17}, [](int i, int j, int k) { return 0.1f * float(i + j + k); });
  const VolumeOctree t = VolumeOctree::build(v);
  const Selection sel = selectNodes(t, SelectionParams{});
  const Camera cam = test::perspective(glm::dvec3(40, 30, 50), glm::dvec3(8.0), glm::dvec3(0, 0, 1), 30.0, 16);
  BrickTextureCache cache;
  const TransferFunction a = constantTf(0.1f), b({{0.0f, {0.2f, 0.9f, 0.3f}, 0.0f}, {4.8f, {1, 1, 1}, 0.3f}}, "ramp");
  for (const TransferFunction* tf : {&a, &b, &a}) {
    const PreIntegrationTable table = preintegrationFor(*tf, v.minValue(), v.maxValue(), 0.25, 32.0);
    SlicesOptions o;
    o.preintegrated = &table;
    const Image alone = renderSlices({v, t, sel}, *tf, cam, o);
    o.textures = &cache;
    const Image cached = renderSlices({v, t, sel}, *tf, cam, o);
    EXPECT_EQ(toRgba8(cached, glm::vec3(0.0f)), toRgba8(alone, glm::vec3(0.0f)));
  }
  cache.clear();
}

TEST(PreIntegratedCranium, MatchesTheReferenceWithTheSurfaceAndACutAndTheBudget) {
  // The scene renderer's frames in both classifications: the slices against the (post-classified)
  // reference at full resolution, with the translucent bone surface through the SlabPolygon
  // lists, with a cutting plane, and under a budget (coarse bricks, blended) where pre-integration
  // is no worse than post-classification.
  Volume v = readVolume(kDefaultVolumePath);
  VolumeOctree octree = VolumeOctree::build(v);
  Look look;
  look.tf = TransferFunction::preset("ct-skin-bone");
  const std::vector<glm::dvec3> points = visiblePoints(v, octree, look.tf);
  SceneRenderer r(Scene{std::move(v), std::move(octree), std::nullopt, nullptr});
  View view;
  view.camera = fitCamera(points, orbitDirection(30, 15), {30, false, 128, 128});
  glm::dvec3 middle(0.0);
  for (const glm::dvec3& p : points) middle += p / double(points.size());
  auto psnr = [&](const Look& l, Quality q, Classification how) {
    Quality truth;
    truth.renderer = Renderer::Raycast;
    q.classification = how;
    return psnrOf(r.render(view, l, q).image, r.render(view, l, truth).image);
  };
  const Quality full;
  Quality budget;
  budget.budgetPercent = 10.0;
  for (const Classification how : {Classification::Post, Classification::PreIntegrated}) {
    Look surface = look;
    surface.iso = 400.0f;
    surface.surfaceColor = glm::vec4(0.95f, 0.92f, 0.85f, 0.5f);
    Look cut = look;
    cut.cut = CutPlane{middle, glm::dvec3(0.3, 1.0, 0.2)};
    const double volumeDb = psnr(look, full, how), surfaceDb = psnr(surface, full, how), cutDb = psnr(cut, full, how);
    std::printf("%s: volume %.2f dB, surface %.2f, cut %.2f\n", how == Classification::Post ? "post" : "pre-integrated", volumeDb, surfaceDb, cutDb);
    EXPECT_GE(volumeDb, 35.0);
    EXPECT_GE(surfaceDb, 35.0);
    EXPECT_GE(cutDb, 35.0);
  }
  const double prePsnr = psnr(look, budget, Classification::PreIntegrated), postPsnr = psnr(look, budget, Classification::Post);
  std::printf("budget 10 %%: %.2f dB pre-integrated, %.2f post-classified\n", prePsnr, postPsnr);
  EXPECT_GE(prePsnr, postPsnr - 0.5);
  // The reference itself pre-integrated converges to the same integral.
  Quality preRays;
  preRays.renderer = Renderer::Raycast;
  preRays.classification = Classification::PreIntegrated;
  Quality truth;
  truth.renderer = Renderer::Raycast;
  EXPECT_GE(psnrOf(r.render(view, look, preRays).image, r.render(view, look, truth).image), 50.0);
}

}  // namespace
}  // namespace hyb
