// hyb_final_steps: the frames a viewer shows after the motion stops, against the final frame they
// lead to. Each rung of the surface's ladder from the full size down to half of it is drawn as the
// viewer draws it (frameParts): as a refining frame (the moving frames' bricks, the simplified
// surface uncut) and as the sharper step before a slow final frame (the final frame's bricks and
// surface); each frame's time (best of 3 warm) and its PSNR, magnified to the final frame's size
// as the page paints it, against the final frame and against the reference ray tracer.
//
// usage: hyb_final_steps SCENE.hoct [--iso V] [--size N] [--view K]
//        (defaults: 400, 512 pixels, view 0: the scene's first anatomical view)
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <string>
#include <variant>
#include <vector>

#include <nlohmann/json.hpp>

#include "apps/viewer/frame_scheduler.h"
#include "apps/viewer/viewer_protocol.h"
#include "apps/viewer/viewer_quality.h"
#include "hybrid_octree/hybrid_io.h"
#include "render/image.h"
#include "render/scene_pool.h"
#include "render/scene_renderer.h"

namespace {

using Clock = std::chrono::steady_clock;
double msSince(Clock::time_point t) { return std::chrono::duration<double, std::milli>(Clock::now() - t).count(); }

}  // namespace

int main(int argc, char** argv) {
  using namespace hyb;
  using namespace hyb::viewer;
  if (argc < 2) {
    std::fprintf(stderr, "usage: hyb_final_steps SCENE.hoct [--iso V] [--size N] [--view K]\n");
    return 2;
  }
  const std::string path = argv[1];
  float iso = 400.0f;
  int size = 512, viewIndex = 0;
  for (int i = 2; i + 1 < argc; i += 2) {
    if (!std::strcmp(argv[i], "--iso")) iso = std::stof(argv[i + 1]);
    else if (!std::strcmp(argv[i], "--size")) size = std::stoi(argv[i + 1]);
    else if (!std::strcmp(argv[i], "--view")) viewIndex = std::clamp(std::stoi(argv[i + 1]), 0, 5);
    else {
      std::fprintf(stderr, "hyb_final_steps: unknown option %s\n", argv[i]);
      return 2;
    }
  }
  try {
    SceneRenderer r(loadScene(path));  // whole, as the viewer loads it
    const SceneSummary summary = summarizeScene(r.scene(), "bench", path, "", "bench");
    auto prepared = SceneRenderer::prepareSurface(r.scene(), iso);
    prepared->simplified = SceneRenderer::simplifiedLevels(r.scene(), *prepared->smooth);
    r.adoptSurface(std::move(prepared));
    // The page's request for the final frame of the view (its camera as the scene's info gives it).
    const Camera& c = summary.views[size_t(viewIndex)];
    const nlohmann::json ask = {{"type", "frame"},           {"seq", 1},           {"interacting", false},
                                {"eye", {c.eye.x, c.eye.y, c.eye.z}}, {"center", {c.center.x, c.center.y, c.center.z}},
                                {"up", {c.up.x, c.up.y, c.up.z}},      {"fov", c.fovDeg},     {"size", {size, size}},
                                {"preset", "ct-skin-bone"},  {"iso", iso},         {"surface_color", {0.95, 0.92, 0.85, 0.5}}};
    const FrameRequest request = std::get<FrameRequest>(parseRequest(ask.dump()));
    UserGeometryMemo memo;
    auto draw = [&](const FrameRung& rung, double* ms) {
      const FrameSetup parts = frameParts(request, r.scene(), rung, iso, memo);
      Image image;
      *ms = 1e300;
      for (int k = 0; k < 4; ++k) {  // the first frame uploads its bricks: not timed
        const auto t = Clock::now();
        image = r.render(parts.view, parts.look, parts.quality).image;
        if (k > 0) *ms = std::min(*ms, msSince(t));
      }
      return image.width == size ? image : resampled(image, size, size);
    };
    double finalMs = 0.0;
    const std::vector<uint8_t> final = toRgba8(draw({kSurfaceLadder[0], 0, false}, &finalMs), glm::vec3(0.0f));
    FrameSetup refParts = frameParts(request, r.scene(), {kSurfaceLadder[0], 0, false}, iso, memo);
    refParts.quality.renderer = Renderer::Raycast;
    const std::vector<uint8_t> reference = toRgba8(r.render(refParts.view, refParts.look, refParts.quality).image, glm::vec3(0.0f));
    std::printf("%s, view %d, %d², surface %g translucent; PSNR of each frame magnified to %d² as painted\n", path.c_str(), viewIndex, size, iso, size);
    std::printf("%-40s %8s %14s %16s\n", "frame", "ms", "against final", "against reference");
    std::printf("%-40s %8.0f %14s %13.2f dB\n", ("final: " + kSurfaceLadder[0].describe()).c_str(), finalMs, "-", psnr(reference, final));
    for (int level = 1; level < int(kSurfaceLadder.size()) && kSurfaceLadder[size_t(level)].scale >= 0.5; ++level)
      for (const bool sharper : {true, false}) {
        double ms = 0.0;
        const std::vector<uint8_t> image = toRgba8(draw({kSurfaceLadder[size_t(level)], level, sharper}, &ms), glm::vec3(0.0f));
        const std::string name = std::string(sharper ? "sharper step: " : "refining: ") + kSurfaceLadder[size_t(level)].describe();
        std::printf("%-40s %8.0f %11.2f dB %13.2f dB\n", name.c_str(), ms, psnr(final, image), psnr(reference, image));
      }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "hyb_final_steps: %s\n", e.what());
    return 1;
  }
  return 0;
}
