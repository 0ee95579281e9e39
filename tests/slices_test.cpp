#include <gtest/gtest.h>

#include <cmath>

#include "render/raycast.h"
#include "render/slices.h"
#include "test_util.h"
#include "volume/volume_io.h"

namespace hyb {
namespace {

// One OpenGL context for the whole suite (creating one costs a few milliseconds on llvmpipe).
GlContext& gl() {
  static GlContext context;
  return context;
}

double psnrOf(const Image& a, const Image& b) { return psnr(toRgba8(a, glm::vec3(0)), toRgba8(b, glm::vec3(0))); }

TEST(Slices, ContextIsOpenGl45Core) { EXPECT_NE(gl().description().find("4.5"), std::string::npos) << gl().description(); }

TEST(Slices, MatchesTheReferenceOnASphereInBothProjections) {
  gl();
  const Volume v = test::sphereVolume(glm::ivec3(48, 44, 40), 15.0);
  const VolumeOctree t = VolumeOctree::build(v);
  const TransferFunction tf({{0.0f, {1, 1, 1}, 0.0f}, {2.0f, {1.0f, 0.6f, 0.3f}, 0.3f}, {15.0f, {0.3f, 0.6f, 1.0f}, 0.05f}}, "s");
  const Selection sel = selectNodes(t, SelectionParams{});
  for (bool ortho : {false, true}) {
    const Camera cam = Camera::orbit(glm::dvec3(0.0), v.extentMm(), 205, 20, 30, ortho, 96, 96);
    const Image a = renderSlices(v, t, sel, tf, cam, SlicesOptions{});
    const Image b = raycast(v, t, tf, cam, RaycastOptions{});
    EXPECT_GE(psnrOf(a, b), 35.0) << "ortho " << ortho;
  }
}

TEST(Slices, OpacityDoesNotDependOnTheSliceSpacing) {
  gl();
  // A homogeneous block viewed straight on: every slice spacing gives the same colour.
  const Volume v = test::makeVolume({17, 17, 17}, [](int, int, int) { return 1.0f; });
  const VolumeOctree t = VolumeOctree::build(v);
  const TransferFunction tf({{0.0f, {0.8f, 0.5f, 0.2f}, 0.07f}, {2.0f, {0.8f, 0.5f, 0.2f}, 0.07f}}, "block");
  const Selection sel = selectNodes(t, SelectionParams{});
  Camera cam;
  cam.center = glm::dvec3(8.0);
  cam.eye = cam.center + glm::dvec3(0, 0, 60);
  cam.up = glm::dvec3(0, 1, 0);
  cam.ortho = true;
  cam.orthoHeight = 4.0;
  cam.width = cam.height = 8;
  std::vector<glm::vec4> centres;
  for (double step : {0.25, 0.5, 1.0}) {
    SlicesOptions o;
    o.stepVoxels = step;
    o.shading = false;
    const Image img = renderSlices(v, t, sel, tf, cam, o);
    centres.push_back(img.at(4, 4));
  }
  const float expected = 1.0f - std::pow(0.93f, 16.0f);
  for (const glm::vec4& c : centres) {
    EXPECT_NEAR(c.a, expected, 1.0f / 255.0f);
    EXPECT_NEAR(c.r, 0.8f * expected, 1.0f / 255.0f);
    EXPECT_NEAR(c.a, centres[0].a, 1.0f / 255.0f);
  }
}

TEST(Slices, OpaqueSurfaceHidesTheVolumeBehindIt) {
  gl();
  const Volume v = test::makeVolume({11, 11, 11}, [](int, int, int) { return 1.0f; });
  const VolumeOctree t = VolumeOctree::build(v);
  const TransferFunction tf({{0.0f, {0.8f, 0.5f, 0.2f}, 0.05f}, {2.0f, {0.8f, 0.5f, 0.2f}, 0.05f}}, "block");
  TriangleMesh quad;
  quad.vertices = {{-1, -1, 5}, {11, -1, 5}, {11, 11, 5}, {-1, 11, 5}};
  quad.triangles = {{0, 1, 2}, {0, 2, 3}};
  Camera cam;
  cam.center = glm::dvec3(5.0);
  cam.eye = cam.center + glm::dvec3(0, 0, 60);
  cam.up = glm::dvec3(0, 1, 0);
  cam.ortho = true;
  cam.orthoHeight = 4.0;
  cam.width = cam.height = 8;
  SlicesOptions o;
  o.shading = false;
  o.surface = &quad;
  o.surfaceColor = glm::vec3(0.2f, 0.4f, 0.6f);
  const glm::vec4 p = renderSlices(v, t, selectNodes(t, SelectionParams{}), tf, cam, o).at(4, 4);
  const float a1 = 1.0f - std::pow(0.95f, 5.0f);  // the 5 mm in front of the quad
  EXPECT_NEAR(p.a, 1.0f, 1.0f / 255.0f);
  EXPECT_NEAR(p.b, 0.2f * a1 + (1 - a1) * 0.6f, 2.0f / 255.0f);
}

TEST(SlicesCranium, MatchesTheReferenceAtFullResolution) {
  gl();
  const Volume v = readVolume(kDefaultVolumePath);
  const VolumeOctree t = VolumeOctree::build(v);
  const TransferFunction tf = TransferFunction::preset("ct-skin-bone");
  const Selection sel = selectNodes(t, SelectionParams{});
  for (bool ortho : {false, true}) {
    const Camera cam = Camera::orbit(glm::dvec3(0.0), v.extentMm(), 205, 20, 30, ortho, 128, 128);
    const double db = psnrOf(renderSlices(v, t, sel, tf, cam, SlicesOptions{}), raycast(v, t, tf, cam, RaycastOptions{}));
    EXPECT_GE(db, 35.0) << "ortho " << ortho;
  }
}

}  // namespace
}  // namespace hyb
