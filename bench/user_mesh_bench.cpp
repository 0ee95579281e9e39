// A frame with a translucent user mesh of about 100 k triangles (an implant-sized sphere inside the
// cranium) against the same frame without it: the slice renderer's warm frame time, best of N
// (docs/user-geometry.md; target ≤ 1.2×), with the time to put the mesh in the grid frame cut to
// leaf cells, and the PSNR of both against the reference ray tracer.
//
//   hyb_user_mesh_bench [volume=the cranium] [runs=5] [size=512] [rings=158]
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <numbers>
#include <string>

#include "render/patient_view.h"
#include "render/scene_renderer.h"
#include "render/user_meshes.h"
#include "surface/scan_convert.h"
#include "volume/volume_io.h"

namespace {

using Clock = std::chrono::steady_clock;

// The fastest of @p runs warm frames (one cold frame first), in ms.
double bestMs(hyb::SceneRenderer& r, const hyb::View& view, const hyb::Look& look, int runs, hyb::RenderedFrame* last) {
  *last = r.render(view, look, hyb::Quality{});
  double best = 1e300;
  for (int k = 0; k < runs; ++k) {
    const auto t0 = Clock::now();
    *last = r.render(view, look, hyb::Quality{});
    best = std::min(best, std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
  }
  return best;
}

}  // namespace

int main(int argc, char** argv) {
  const std::string path = argc > 1 ? argv[1] : "/usr/share/doc/invesalius-examples/examples/Cranium.inv3";
  const int runs = argc > 2 ? std::max(1, std::atoi(argv[2])) : 5;
  const int size = argc > 3 ? std::max(16, std::atoi(argv[3])) : 512;
  const int rings = argc > 4 ? std::max(4, std::atoi(argv[4])) : 158;
  hyb::Scene scene;
  scene.volume = hyb::readVolume(path);
  scene.octree = hyb::VolumeOctree::build(scene.volume);
  hyb::Look look;
  look.tf = hyb::TransferFunction::preset("ct-bone");
  look.iso = 400.0f;
  look.surfaceColor = glm::vec4(0.95f, 0.92f, 0.85f, 0.5f);
  const std::vector<glm::dvec3> points = hyb::visiblePoints(scene.volume, scene.octree, look.tf);
  hyb::View view;
  view.camera = hyb::fitCamera(points, hyb::orbitDirection(30, 15), {30, false, size, size});
  // An implant-sized ball where the view sees it: from the volume's centre a third of its
  // diagonal towards the eye, across the bone.
  const glm::dvec3 middle = scene.volume.frame().toPatient(0.5 * scene.volume.extentMm());
  const glm::dvec3 centre = middle + glm::normalize(view.camera.eye - middle) * (glm::length(scene.volume.extentMm()) / 3.0);
  hyb::Look withMesh = look;
  withMesh.meshes.push_back({"sphere", std::make_shared<const hyb::TriangleMesh>(hyb::uvSphere(centre, 25.0, rings)), glm::vec4(0.3f, 0.6f, 1.0f, 0.5f), nullptr});
  const size_t triangles = withMesh.meshes[0].mesh->triangles.size();
  hyb::SceneRenderer r(std::move(scene));
  hyb::RenderedFrame plain, meshed;
  const double plainMs = bestMs(r, view, look, runs, &plain);
  const double meshMs = bestMs(r, view, withMesh, runs, &meshed);
  // The mesh put in the grid frame and cut anew (a new mesh each frame, as Python's arrays are).
  hyb::Look fresh = withMesh;
  fresh.meshes[0].mesh = std::make_shared<const hyb::TriangleMesh>(*withMesh.meshes[0].mesh);
  const hyb::RenderedFrame first = r.render(view, fresh, hyb::Quality{});
  hyb::Quality reference;
  reference.renderer = hyb::Renderer::Raycast;
  const double plainDb = hyb::psnr(hyb::toRgba8(plain.image, glm::vec3(0)), hyb::toRgba8(r.render(view, look, reference).image, glm::vec3(0)));
  const double meshDb = hyb::psnr(hyb::toRgba8(meshed.image, glm::vec3(0)), hyb::toRgba8(r.render(view, withMesh, reference).image, glm::vec3(0)));
  std::printf("%s, %dx%d, translucent surface iso 400 (%zu triangles placed), best of %d warm frames\n", path.c_str(), size, size,
              size_t(plain.stats.slices.surfaceTriangles), runs);
  std::printf("without the mesh : %8.1f ms, PSNR against the reference %.2f dB\n", plainMs, plainDb);
  std::printf("with the mesh    : %8.1f ms, PSNR against the reference %.2f dB (%zu triangles, %zu pieces' triangles placed more)\n", meshMs, meshDb,
              triangles, size_t(meshed.stats.slices.surfaceTriangles - plain.stats.slices.surfaceTriangles));
  const std::vector<uint8_t> a = hyb::toRgba8(plain.image, glm::vec3(0)), b = hyb::toRgba8(meshed.image, glm::vec3(0));
  size_t changed = 0;
  for (size_t p = 0; p < a.size(); p += 4) changed += std::abs(int(a[p]) - int(b[p])) + std::abs(int(a[p + 1]) - int(b[p + 1])) + std::abs(int(a[p + 2]) - int(b[p + 2])) > 6;
  std::printf("pixels the mesh changes (by more than 6/255 summed): %zu of %d\n", changed, size * size);
  std::printf("ratio            : %8.3f x\n", meshMs / plainMs);
  std::printf("mesh prepared    : %8.1f ms (grid frame, cut at the leaf cells; once per mesh)\n", first.stats.meshesMs);
  return 0;
}
