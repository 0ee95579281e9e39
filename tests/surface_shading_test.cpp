// Smooth isosurfaces: the exact DiscMC / Surface Octree geometry shaded by the volume's gradient
// at its vertices, against the closed-form shading of a sphere, in both renderers.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <string>

#include "hybrid_octree/surface_octree.h"
#include "render/bvh.h"
#include "render/patient_view.h"
#include "render/raycast.h"
#include "render/slices.h"
#include "render_util.h"
#include "surface/dmc.h"
#include "surface/mesh_ops.h"
#include "volume/volume_io.h"
#include "test_util.h"

namespace hyb {
namespace {

struct ShadingError {
  double mean = 0, worst = 0;
};

// The opaque white sphere of radius R seen straight down: a headlight gives 0.25 + 0.75·n_z, and
// n_z = sqrt(1 − r²/R²) at distance r from the centre. Compared inside 0.85 R, off the silhouette.
ShadingError againstClosedForm(const Image& image, const Camera& cam, const glm::dvec3& centre, double radius, double scale = 1.0) {
  ShadingError e;
  int n = 0;
  for (int y = 0; y < image.height; ++y)
    for (int x = 0; x < image.width; ++x) {
      const double px = ((x + 0.5) / image.width - 0.5) * cam.orthoHeight, py = (0.5 - (y + 0.5) / image.height) * cam.orthoHeight;
      const double r = std::hypot(px + cam.center.x - centre.x, py + cam.center.y - centre.y);
      if (r > 0.85 * radius) continue;
      const double expected = 0.25 + 0.75 * std::sqrt(1.0 - r * r / (radius * radius));
      const double d = std::abs(double(image.at(x, y).r) / scale - expected);
      e.mean += d;
      e.worst = std::max(e.worst, d);
      ++n;
    }
  e.mean /= std::max(n, 1);
  return e;
}

TEST(SurfaceShading, GradientNormalsMatchTheSpheresClosedFormShading) {
  test::gl();
  const double radius = 17.0;
  const Volume v = test::sphereVolume({48, 48, 48}, radius);  // centre (23.5, 23.5, 23.5)
  const glm::dvec3 centre(23.5);
  const VolumeOctree t = VolumeOctree::build(v);
  const SurfaceOctree so = SurfaceOctree::build(v, t, 0.0f);
  TriangleMesh facet = fineMeshToTriangles(so.reconstruct(), v.spacing()), smooth = facet;
  setGradientNormals(v, &smooth);
  const Camera cam = test::orthoDown(centre, 40.0, 96);
  // A volume too faint to see (1e-6 of opacity a mm) keeps the bricks visible, so the translucent
  // surface goes through the SlabPolygon lists and is cut at the slabs.
  const TransferFunction faint({{-100.0f, {0, 0, 0}, 1e-6f}, {100.0f, {0, 0, 0}, 1e-6f}}, "faint");
  const Selection sel = selectNodes(t, SelectionParams{});
  for (const float alpha : {1.0f, 0.5f})
    for (const bool gradient : {true, false}) {
      const TriangleMesh& mesh = gradient ? smooth : facet;
      const Bvh bvh(mesh);
      RaycastOptions ro;
      ro.surface = &bvh;
      ro.surfaceColor = glm::vec4(1, 1, 1, alpha);
      SlicesOptions sopt;
      sopt.surface = &mesh;
      sopt.surfaceColor = ro.surfaceColor;
      // Translucent: the front and the back crossing shade alike, premultiplied a + a(1 − a).
      const double scale = alpha + alpha * (1.0 - alpha);
      const ShadingError ray = againstClosedForm(raycast(v, t, faint, cam, ro), cam, centre, radius, scale);
      const ShadingError slices = againstClosedForm(renderSlices({v, t, sel}, faint, cam, sopt), cam, centre, radius, scale);
      std::printf("sphere shading, %s normals, alpha %.1f: reference mean %.4f worst %.4f; slices mean %.4f worst %.4f\n",
                  gradient ? "gradient" : "facet", alpha, ray.mean, ray.worst, slices.mean, slices.worst);
      if (gradient) {
        // The surface lies within half a voxel of the sphere, its normals within a few degrees.
        EXPECT_LT(ray.mean, 0.006);
        EXPECT_LT(ray.worst, 0.03);
        EXPECT_LT(slices.mean, 0.006);
        EXPECT_LT(slices.worst, 0.03);
      } else {
        // Facets take only DiscMC's 13 orientations: terraces ten times the gradient's error.
        EXPECT_GT(ray.mean, 0.05);
        EXPECT_GT(slices.mean, 0.05);
      }
    }
}

// On the cranium's bone the facets' terraces show as bands the gradient removes: against classic
// marching cubes shaded by the same gradients (the smoothest mesh of the same data), through the
// reference renderer.
TEST(SurfaceShading, TerracesOfTheCraniumAreGone) {
  const Volume v = readVolume(kDefaultVolumePath);
  const VolumeOctree t = VolumeOctree::build(v);
  const SurfaceOctree so = SurfaceOctree::build(v, t, 400.0f);
  TriangleMesh facet = fineMeshToTriangles(so.reconstruct(), v.spacing()), smooth = facet;
  setGradientNormals(v, &smooth);
  TriangleMesh mc = extractMarchingCubes(v, 400.0f, isoBlocks(t, 400.0f));
  scaleToMillimetres(&mc, v.spacing());
  setGradientNormals(v, &mc);
  const TransferFunction clear({{-2000.0f, {0, 0, 0}, 0.0f}, {4000.0f, {0, 0, 0}, 0.0f}}, "clear");
  std::vector<double> db;
  for (const ViewDirection& d : {viewDirection(AnatomicalView::Anterior), orbitDirection(60, 25)}) {
    const Camera cam = toGridCamera(fitCamera(visiblePoints(v, t, clear, 400.0f), d, {30.0, false, 160, 160}), v.frame());
    auto image = [&](const TriangleMesh& mesh) {
      const Bvh bvh(mesh);
      RaycastOptions ro;
      ro.surface = &bvh;
      ro.volume = false;
      return raycast(v, t, clear, cam, ro);
    };
    const Image reference = image(mc);
    const double gradient = test::psnrOf(image(smooth), reference), faceted = test::psnrOf(image(facet), reference);
    std::printf("cranium bone against MC with gradient normals: gradient %.2f dB, facet %.2f dB\n", gradient, faceted);
    EXPECT_GT(gradient, faceted + 5.0);
    EXPECT_GT(gradient, 24.0);  // what remains is geometry: DiscMC's midpoint vertices against MC's interpolated ones
    if (const char* dir = std::getenv("HYB_SHADING_IMAGES")) {
      const std::string at = std::string(dir) + "/cranium_" + std::to_string(db.size());
      writePng(at + "_mc.png", reference, glm::vec3(0.0f));
      writePng(at + "_gradient.png", image(smooth), glm::vec3(0.0f));
      writePng(at + "_facet.png", image(facet), glm::vec3(0.0f));
    }
    db.push_back(gradient);
  }
}

}  // namespace
}  // namespace hyb
