// Sort-last regions: the split of a selection, the regions' order from an eye, the surface cut to
// a region, and frames rendered region by region and composited front to back against the whole.
#include "render/regions.h"

#include <gtest/gtest.h>

#include <random>

#include "render/patient_view.h"
#include "render/scene_renderer.h"
#include "render_util.h"
#include "test_util.h"

namespace hyb {
namespace {

// Shells of values around the centre of a 72×64×56 grid: a translucent material outside radius
// 18 (value 6 at the centre, falling 0.25 a voxel), so bricks of every level are visible.
Scene shellScene() {
  Scene s;
  s.volume = test::makeVolume({72, 64, 56}, [](double x, double y, double z) {
    return float(6.0 - 0.25 * std::sqrt((x - 35.5) * (x - 35.5) + (y - 31.0) * (y - 31.0) + (z - 27.0) * (z - 27.0)) + 0.3 * std::sin(0.7 * x));
  });
  s.octree = VolumeOctree::build(s.volume);
  return s;
}

TransferFunction shellTf() {
  return TransferFunction({{-6.0f, {1, 1, 1}, 0.0f}, {-3.0f, {0.9f, 0.5f, 0.3f}, 0.04f}, {2.0f, {0.3f, 0.6f, 1.0f}, 0.08f}, {6.0f, {1, 1, 0.8f}, 0.3f}},
                          "shells");
}

View cameraFrom(const Volume& v, double azimuth, bool ortho) {
  View view;
  view.camera = fitCamera(visiblePoints(v, VolumeOctree::build(v), shellTf()), orbitDirection(azimuth, 25), {30, ortho, 96, 96}, 0.05);
  return view;
}

// Front-to-back "over" of premultiplied images.
Image composite(const std::vector<Image>& images, const std::vector<int>& order) {
  Image out(images.front().width, images.front().height);
  for (const int r : order)
    for (size_t i = 0; i < out.pixels.size(); ++i) out.pixels[i] += images[size_t(r)].pixels[i] * (1.0f - out.pixels[i].a);
  return out;
}

TEST(Regions, SplitsTheBricksIntoBoxesOfWholeBricksBalancedByCost) {
  SceneRenderer r(shellScene());
  Look look;
  look.tf = shellTf();
  const View view = cameraFrom(r.volume(), 30, false);
  const Selection sel = r.select(view, look, Quality{});
  ASSERT_GT(sel.bricks.size(), 20u);
  double total = 0.0;
  for (const Brick& b : sel.bricks) total += regionCost(b);
  const glm::dvec3 spacing = r.volume().spacing();
  for (const int parts : {1, 2, 3, 4, 7}) {
    SCOPED_TRACE(parts);
    const Regions regions = splitSelection(r.octree(), spacing, sel, parts);
    ASSERT_EQ(regions.boxes.size(), size_t(parts));
    ASSERT_EQ(regions.brickRegion.size(), sel.bricks.size());
    std::vector<double> cost(size_t(parts), 0.0);
    for (size_t b = 0; b < sel.bricks.size(); ++b) {
      const OctreeNode& n = r.octree().nodes()[sel.bricks[b].node];
      const glm::dvec3 lo = glm::dvec3(n.origin) * spacing, hi = glm::min(glm::dvec3(glm::ivec3(n.origin) + r.octree().edge(n)), glm::dvec3(r.volume().dims() - 1)) * spacing;
      // The brick's box is inside its region's closed box and no other region holds its centre.
      const uint32_t in = regions.brickRegion[b];
      EXPECT_TRUE(glm::all(glm::lessThanEqual(regions.boxes[in].lo, lo)) && glm::all(glm::lessThanEqual(hi, regions.boxes[in].hi))) << b;
      int holders = 0;
      for (const RegionBox& box : regions.boxes) holders += box.contains(0.5 * (lo + hi));
      EXPECT_EQ(holders, 1) << b;
      cost[in] += regionCost(sel.bricks[b]);
    }
    for (int k = 0; k < parts; ++k) EXPECT_DOUBLE_EQ(cost[size_t(k)], regions.cost[size_t(k)]);
    // Every point of space lies in exactly one region.
    std::mt19937 rng(parts);
    std::uniform_real_distribution<double> u(-20.0, 90.0);
    for (int i = 0; i < 500; ++i) {
      const glm::dvec3 p(u(rng), u(rng), u(rng));
      int holders = 0;
      for (const RegionBox& box : regions.boxes) holders += box.contains(p);
      EXPECT_EQ(holders, 1);
    }
    // Balanced: the costliest region within 1.3 of the mean for two and four.
    if (parts == 2 || parts == 4) {
      EXPECT_LE(*std::max_element(cost.begin(), cost.end()), 1.3 * total / parts);
    }
  }
  EXPECT_THROW(splitSelection(r.octree(), spacing, sel, 0), ValueError);
}

TEST(Regions, FrontToBackPutsTheEyesSideOfEverySeparatingPlaneFirst) {
  SceneRenderer r(shellScene());
  Look look;
  look.tf = shellTf();
  const Selection sel = r.select(cameraFrom(r.volume(), 0, false), look, Quality{});
  const Regions regions = splitSelection(r.octree(), r.volume().spacing(), sel, 6);
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-100.0, 170.0);
  for (int i = 0; i < 200; ++i) {
    const glm::dvec3 eye(u(rng), u(rng), u(rng));
    const std::vector<int> order = regions.frontToBack(eye);
    ASSERT_EQ(order.size(), 6u);
    for (size_t a = 0; a < order.size(); ++a)
      for (size_t b = a + 1; b < order.size(); ++b) {
        // Some plane separates the two with the eye on the earlier one's side: no ray from the
        // eye meets the later one before the earlier one.
        const RegionBox &front = regions.boxes[size_t(order[a])], &back = regions.boxes[size_t(order[b])];
        if (front.empty() || back.empty()) continue;
        bool separated = false;
        for (int k = 0; k < 3; ++k)
          separated |= (front.hi[k] <= back.lo[k] && eye[k] < back.lo[k]) || (back.hi[k] <= front.lo[k] && eye[k] >= back.hi[k]);
        EXPECT_TRUE(separated) << "eye " << eye.x << "," << eye.y << "," << eye.z << ": region " << order[a] << " before " << order[b];
      }
  }
}

double area(const TriangleMesh& m) {
  double s = 0.0;
  for (const glm::uvec3& t : m.triangles)
    s += 0.5 * glm::length(glm::cross(glm::dvec3(m.vertices[t.y] - m.vertices[t.x]), glm::dvec3(m.vertices[t.z] - m.vertices[t.x])));
  return s;
}

TEST(Regions, TheSurfaceCutToTheRegionsIsTheWholeSurfaceOnce) {
  SceneRenderer r(shellScene());
  const TriangleMesh& mesh = r.surface(2.0f, SurfaceNormals::Gradient);
  ASSERT_GT(mesh.triangles.size(), 1000u);
  // Planes through the surface, off the grid (crossing polygons) and on it (polygons in a face).
  for (const double at : {30.3, 32.0}) {
    SCOPED_TRACE(at);
    RegionBox below, above;
    below.hi.x = above.lo.x = at;
    const TriangleMesh a = cutMeshToRegion(mesh, below), b = cutMeshToRegion(mesh, above);
    EXPECT_NEAR(area(a) + area(b), area(mesh), 1e-5 * area(mesh));
    for (const glm::vec3& p : a.vertices) EXPECT_LE(p.x, float(at));
    for (const glm::vec3& p : b.vertices) EXPECT_GE(p.x, float(at));
    EXPECT_EQ(a.normals.size(), a.vertices.size());
    ASSERT_FALSE(a.polygonStarts.empty());
    EXPECT_EQ(a.polygonStarts.back(), a.triangles.size());
    EXPECT_EQ(b.polygonStarts.back(), b.triangles.size());
  }
  // Boxes on all three axes, and an empty one.
  const Regions split = [&] {
    Look look;
    look.tf = shellTf();
    return splitSelection(r.octree(), r.volume().spacing(), r.select(cameraFrom(r.volume(), 0, false), look, Quality{}), 5);
  }();
  double sum = 0.0;
  for (const RegionBox& box : split.boxes) sum += area(cutMeshToRegion(mesh, box));
  EXPECT_NEAR(sum, area(mesh), 1e-5 * area(mesh));
  RegionBox none;
  none.lo.x = none.hi.x = 10.0;
  EXPECT_TRUE(cutMeshToRegion(mesh, none).triangles.empty());
}

// Regions rendered apart and composited front to back give the whole frame's image.
void expectRegionsMakeTheFrame(Renderer renderer, bool ortho, bool cut, Classification classification) {
  SCOPED_TRACE(testing::Message() << (renderer == Renderer::Slices ? "slices" : "raycast") << (ortho ? " ortho" : " perspective") << (cut ? " cut" : "")
                                  << (classification == Classification::PreIntegrated ? " pre-integrated" : ""));
  test::gl();
  SceneRenderer r(shellScene());
  Look look;
  look.tf = shellTf();
  look.iso = 2.0f;
  look.surfaceColor = glm::vec4(0.95f, 0.9f, 0.8f, 0.45f);
  if (cut) look.cut = CutPlane{r.volume().frame().toPatient(glm::dvec3(40.0, 30.0, 27.0)), glm::normalize(glm::dvec3(1.0, 0.3, 0.2))};
  Quality quality;
  quality.renderer = renderer;
  quality.step = 0.5;
  quality.classification = classification;
  const View view = cameraFrom(r.volume(), 35, ortho);
  const Image whole = r.render(view, look, quality).image;
  for (const int parts : {2, 4}) {
    const SceneRenderer::SortLast split = r.sortLast(view, look, quality, parts);
    std::vector<Image> images;
    for (int k = 0; k < parts; ++k) {
      Quality q = quality;
      q.region = split.regions.boxes[size_t(k)];
      images.push_back(r.render(view, look, q).image);
    }
    const Image made = composite(images, split.frontToBack);
    EXPECT_GE(test::psnrOf(made, whole), 50.0) << parts << " regions";
    // In the wrong order the images do not make the frame: the test sees the order.
    std::vector<int> reversed(split.frontToBack.rbegin(), split.frontToBack.rend());
    EXPECT_LT(test::psnrOf(composite(images, reversed), whole), 40.0) << parts << " regions, reversed";
  }
}

TEST(Regions, SliceFramesRegionByRegionCompositeIntoTheWholeFrame) {
  for (const bool ortho : {false, true}) expectRegionsMakeTheFrame(Renderer::Slices, ortho, false, Classification::Post);
  expectRegionsMakeTheFrame(Renderer::Slices, false, true, Classification::Post);
  expectRegionsMakeTheFrame(Renderer::Slices, false, false, Classification::PreIntegrated);
}

TEST(Regions, ReferenceFramesRegionByRegionCompositeIntoTheWholeFrame) {
  for (const bool ortho : {false, true}) expectRegionsMakeTheFrame(Renderer::Raycast, ortho, false, Classification::Post);
  expectRegionsMakeTheFrame(Renderer::Raycast, false, true, Classification::Post);
}

TEST(Regions, ARegionFrameCannotBeProgressive) {
  SceneRenderer r(shellScene());
  Look look;
  look.tf = shellTf();
  Quality q;
  q.region = RegionBox{};
  q.progressive = 2;
  EXPECT_THROW(r.render(cameraFrom(r.volume(), 0, false), look, q), ValueError);
}

}  // namespace
}  // namespace hyb
