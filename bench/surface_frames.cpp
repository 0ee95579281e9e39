// hyb_surface_frames: the viewer's moving frames without the browser, stage by stage: a scripted
// orbit at the interactive quality the viewer asks for (image size, slice spacing, brick edge,
// screen-space level of detail, the simplified uncut surface), volume only and with a translucent
// isosurface. Reports the surface's preparation (reconstruction, simplification, triangles) and,
// per frame, the selection and render times, the triangles drawn and the PSNR against the
// reference ray tracer at the same size, for each surface simplification error in pixels.
//
// usage: hyb_surface_frames SCENE.hoct [--iso V] [--size N] [--frames K] [--step S]
//        (defaults: 400, 96 pixels, 24 frames 5 degrees apart, 2.5 voxels)
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include "apps/viewer/viewer_quality.h"
#include "hybrid_octree/hybrid_io.h"
#include "render/image.h"
#include "render/patient_view.h"
#include "render/scene_renderer.h"

namespace {

using Clock = std::chrono::steady_clock;
double msSince(Clock::time_point t0) { return std::chrono::duration<double, std::milli>(Clock::now() - t0).count(); }

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0.0 : v[v.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
  using namespace hyb;
  if (argc < 2) {
    std::fprintf(stderr, "usage: hyb_surface_frames SCENE.hoct [--iso V] [--size N] [--frames K] [--step S]\n");
    return 2;
  }
  const std::string path = argv[1];
  float iso = 400.0f;
  int size = 96, frames = 24;
  double step = 2.5;
  for (int i = 2; i + 1 < argc; i += 2) {
    if (!std::strcmp(argv[i], "--iso")) iso = std::stof(argv[i + 1]);
    else if (!std::strcmp(argv[i], "--size")) size = std::stoi(argv[i + 1]);
    else if (!std::strcmp(argv[i], "--frames")) frames = std::stoi(argv[i + 1]);
    else if (!std::strcmp(argv[i], "--step")) step = std::stod(argv[i + 1]);
    else {
      std::fprintf(stderr, "hyb_surface_frames: unknown option %s\n", argv[i]);
      return 2;
    }
  }
  try {
    SceneRenderer r(loadScene(path));  // whole, as the viewer loads it
    Look look;
    look.tf = TransferFunction::preset("ct-skin-bone");
    const std::vector<glm::dvec3> points = visiblePoints(r.volume(), r.octree(), look.tf, iso);
    auto t0 = Clock::now();
    auto prepared = SceneRenderer::prepareSurface(r.scene(), iso);
    const double reconstructMs = msSince(t0);
    t0 = Clock::now();
    prepared->simplified = SceneRenderer::simplifiedLevels(r.scene(), *prepared->smooth);
    const double simplifyMs = msSince(t0);
    std::printf("surface %g: %zu triangles, built and reconstructed in %.0f ms; simplified in %.0f ms to", iso, prepared->smooth->triangles.size(),
                reconstructMs, simplifyMs);
    for (const TriangleMesh& m : prepared->simplified) std::printf(" %zu", m.triangles.size());
    std::printf(" triangles\n");
    r.adoptSurface(std::move(prepared));

    Quality q;
    q.step = step;
    q.simplifiedSurface = true;
    q.cutToSlabs = false;
    q.maxBrickEdge = viewer::kInteractiveBrickEdge;
    q.lodPixels = viewer::kInteractiveLodPixels;
    Quality reference;
    reference.renderer = Renderer::Raycast;
    std::vector<View> views(static_cast<size_t>(frames));
    for (int f = 0; f < frames; ++f) views[size_t(f)].camera = fitCamera(points, orbitDirection(5.0 * f, 10.0), {30.0, false, size, size});
    // Volume only, then the surface at each simplification error (0: level 0 always); the PSNR of
    // every eighth frame against the reference at the same size.
    for (const double errorPixels : {-1.0, 0.0, 1.0, 2.0, 4.0}) {
      Look l = look;
      if (errorPixels >= 0.0) {
        l.iso = iso;
        l.surfaceColor = glm::vec4(0.95f, 0.92f, 0.85f, 0.5f);
        q.surfaceErrorPixels = errorPixels;
      }
      std::vector<double> select, render, db;
      size_t triangles = 0;
      double first = 0.0;
      for (int f = 0; f < frames; ++f) {
        const auto t = Clock::now();
        const RenderedFrame frame = r.render(views[size_t(f)], l, q);
        const double ms = msSince(t);
        if (f % 8 == 0) {
          const Image ref = r.render(views[size_t(f)], l, reference).image;
          db.push_back(psnr(toRgba8(ref, glm::vec3(0.0f)), toRgba8(frame.image, glm::vec3(0.0f))));
        }
        if (f == 0) {
          first = ms;
          continue;
        }
        select.push_back(frame.stats.selectMs);
        render.push_back(ms - frame.stats.selectMs);
        triangles = std::max(triangles, frame.stats.slices.surfaceTriangles);
      }
      if (errorPixels < 0.0)
        std::printf("volume only        ");
      else
        std::printf("surface, error %g px", errorPixels);
      std::printf(" %d² step %.1f: first frame %.0f ms, then median select %.1f ms, render %.1f ms; up to %zu triangles; PSNR", size,
                  step, first, median(select), median(render), triangles);
      for (double d : db) std::printf(" %.1f", d);
      std::printf(" dB\n");
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "hyb_surface_frames: %s\n", e.what());
    return 1;
  }
  return 0;
}
