// The moving frames' ray tracer against the reference's: closed forms, the same image where only the
// work differs (empty space skipped, samples paged), and within a stated PSNR of the converged image
// where it trades accuracy for time.
#include "render/raycast_interactive.h"

#include <gtest/gtest.h>

#include <cmath>

#include "hybrid_octree/hybrid_io.h"
#include "render/patient_view.h"
#include "render/scene_renderer.h"
#include "render_util.h"
#include "test_util.h"

namespace hyb {
namespace {

using test::constantTf;
using test::psnrOf;

// The sphere's field (values above 0 inside) as warm CT-like tissue.
TransferFunction warm() { return TransferFunction({{0.0f, {1, 1, 1}, 0.0f}, {2.0f, {1.0f, 0.6f, 0.3f}, 0.3f}, {15.0f, {0.3f, 0.6f, 1.0f}, 0.05f}}, "warm"); }

// A moving frame's quality: ray-traced at @p step voxels by the interactive tracer (or the reference's).
Quality rays(double step, bool interactive = true) {
  Quality q;
  q.renderer = Renderer::Raycast;
  q.step = step;
  q.interactiveRays = interactive;
  return q;
}

// Every segment of the lattice, whatever a pixel's offset, covers the slab once: its opacity is the
// closed form at every step, in every pixel of the 2² squares of interleaved offsets.
TEST(RaycastInteractive, AHomogeneousSlabIsItsClosedFormInEveryPixelAtAnyStep) {
  const Volume v = test::makeVolume({21, 21, 11}, [](int, int, int) { return 0.5f; });
  const VolumeOctree t = VolumeOctree::build(v);
  const float a = 0.1f, alpha = 1.0f - std::pow(1.0f - a, 10.0f);  // 10 mm of material along z
  Camera c;
  c.center = 0.5 * v.extentMm();
  c.eye = c.center + glm::dvec3(0, 0, 100);
  c.ortho = true;
  c.orthoHeight = 4.0;
  c.width = c.height = 4;
  for (double step : {0.25, 0.7, 1.0, 1.5, 2.5}) {
    RaycastOptions o;
    o.stepVoxels = step;
    o.shading = false;
    const Image img = raycastInteractive(v, t, constantTf(a), c, o);
    for (const glm::vec4& p : img.pixels) {
      EXPECT_NEAR(p.a, alpha, 1.0f / 255.0f) << step;
      EXPECT_NEAR(p.r, 0.8f * alpha, 1.0f / 255.0f) << step;
    }
  }
}

// Skipping the nodes the transfer function makes transparent resumes on the same lattice: no pixel
// changes, and far fewer samples are taken.
TEST(RaycastInteractive, SkippingEmptySpaceChangesNoPixel) {
  const Volume v = test::sphereVolume({40, 36, 30}, 11.0);
  const VolumeOctree t = VolumeOctree::build(v);
  const Camera cam = Camera::orbit(glm::dvec3(0.0), v.extentMm(), {35, 20, {30, false, 48, 40}});
  RaycastOptions o;
  o.stepVoxels = 0.25;
  RaycastStats with, without;
  const Image a = raycastInteractive(v, t, warm(), cam, o, {.stats = &with});
  o.skipEmptySpace = false;
  const Image b = raycastInteractive(v, t, warm(), cam, o, {.stats = &without});
  EXPECT_EQ(toRgba8(a, glm::vec3(0)), toRgba8(b, glm::vec3(0)));
  EXPECT_GT(with.skippedLeaves, uint64_t(0));
  EXPECT_LT(with.samples, without.samples / 2);
  EXPECT_EQ(with.rays, uint64_t(48 * 40));
}

// A paged scene's samples are read in place from its blocks, or gathered across their borders: the
// image of the samples in memory, bit for bit, with a translucent surface and shading (a grid of
// several blocks a side, so that rays cross their borders).
TEST(RaycastInteractive, APagedSceneGivesTheImageOfItsSamplesInMemory) {
  test::TempDir dir;
  Scene scene;
  scene.volume = test::sphereVolume({75, 70, 66}, 24.0);
  scene.octree = VolumeOctree::build(scene.volume);
  saveScene(dir.file("s.hoct"), scene.volume, scene.octree);
  SceneRenderer paged(loadScene(dir.file("s.hoct"), SceneLoadOptions{false, 1 << 20})), memory(loadScene(dir.file("s.hoct")));
  ASSERT_FALSE(paged.volume().hasSamples());
  Look look;
  look.tf = warm();
  look.iso = 5.0f;
  look.surfaceColor = glm::vec4(0.9f, 0.8f, 0.7f, 0.5f);
  View view;
  view.camera = fitCamera(visiblePoints(memory.volume(), memory.octree(), look.tf), orbitDirection(25, 15), {30, false, 64, 64});
  for (const double step : {1.0, 2.5}) {
    const RenderedFrame p = paged.render(view, look, rays(step)), m = memory.render(view, look, rays(step));
    EXPECT_GT(m.stats.rays.surfaceHits, uint64_t(0));
    EXPECT_EQ(p.stats.rays.samples, m.stats.rays.samples) << step;
    EXPECT_EQ(p.image.pixels, m.image.pixels) << step;
  }
  EXPECT_FALSE(paged.volume().hasSamples());
}

// What the tracer does not draw (a cutting plane, a volume of interest, pre-integration, a band of
// rows...) goes to the reference's: the frame is the reference's, exactly.
TEST(RaycastInteractive, FramesItDoesNotServeAreTheReferences) {
  const Volume v = test::sphereVolume({40, 36, 30}, 11.0);
  RaycastOptions o;
  EXPECT_TRUE(interactiveRaysServe(v, o));
  const CutPlane cut{glm::dvec3(20, 18, 15), glm::dvec3(0, 1, 0)};
  const VolumeOfInterest voi{};
  const RegionBox region{};
  for (int k = 0; k < 5; ++k) {
    RaycastOptions n;
    if (k == 0) n.cut = &cut;
    if (k == 1) n.voi = &voi;
    if (k == 2) n.region = &region;
    if (k == 3) n.refineLevels = 3;
    if (k == 4) n.volume = false;
    EXPECT_FALSE(interactiveRaysServe(v, n)) << k;
  }
  EXPECT_FALSE(interactiveRaysServe(test::makeVolume({1, 8, 8}, [](int, int, int) { return 1.0f; }), o));

  SceneRenderer r(test::sphereScene());
  Look look;
  look.tf = warm();
  look.cut = CutPlane{glm::dvec3(20, 18, 16), glm::dvec3(0.3, 1, 0.2)};
  View view;
  view.camera = fitCamera(visiblePoints(r.volume(), r.octree(), look.tf), orbitDirection(30, 10), {30, false, 40, 40});
  EXPECT_EQ(r.render(view, look, rays(1.5)).image.pixels, r.render(view, look, rays(1.5, false)).image.pixels);
  Quality pre = rays(1.5);
  pre.classification = Classification::PreIntegrated;
  look.cut.reset();
  Quality refPre = pre;
  refPre.interactiveRays = false;
  EXPECT_EQ(r.render(view, look, pre).image.pixels, r.render(view, look, refPre).image.pixels);
}

// The speed-up's price, on the real CT with its translucent bone surface, as the viewer shows its
// moving frames (128² at 2.5 voxels and 192² at 1.5, magnified bilinearly to a 256² canvas):
// against the converged reference (the reference tracer at 0.25 voxel, at the canvas's size), a
// frame is no more than 0.2 dB below the reference tracer's at its size and spacing (the table,
// float arithmetic and the rays stopped at 0.99 lose about what the interleaved offsets gain back
// in the magnification), and it takes fewer samples.
TEST(RaycastInteractive, MovingFramesOfTheCraniumAreWithinAStatedPsnrOfTheReferences) {
  SceneRenderer r(test::craniumScene());
  Look look;
  look.tf = TransferFunction::preset("ct-skin-bone");
  look.iso = 400.0f;
  look.surfaceColor = glm::vec4(0.95f, 0.92f, 0.85f, 0.5f);
  r.adoptSurface(SceneRenderer::prepareSurface(r.scene(), 400.0f));
  View view;
  view.camera = fitCamera(visiblePoints(r.volume(), r.octree(), look.tf), orbitDirection(30, 10), {30, false, 256, 256});
  Quality converged;
  converged.renderer = Renderer::Raycast;
  const Image best = r.render(view, look, converged).image;
  for (const auto& [size, step] : {std::pair{128, 2.5}, std::pair{192, 1.5}}) {
    View small = view;
    small.camera.width = small.camera.height = size;
    const RenderedFrame fast = r.render(small, look, rays(step)), reference = r.render(small, look, rays(step, false));
    const double fastDb = psnrOf(best, resampled(fast.image, 256, 256)), referenceDb = psnrOf(best, resampled(reference.image, 256, 256));
    EXPECT_GT(fastDb, referenceDb - 0.2) << size;
    EXPECT_GT(fastDb, size == 128 ? 29.0 : 32.0) << size;
    EXPECT_LT(fast.stats.rays.samples, reference.stats.rays.samples) << size;
  }
}

}  // namespace
}  // namespace hyb
