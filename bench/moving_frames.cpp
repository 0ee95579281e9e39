// hyb_moving_frames: the viewer's moving frames without the browser, each way of making them
// against the others at fixed sizes: the sliced frames of the ladders (simplified uncut surface,
// 32-texel bricks, screen-space level of detail), the reference ray tracer and the interactive
// one, at several image sizes and spacings. Each frame is measured as the page paints it: JPEG 95
// (4:4:4) sent, decoded, magnified to the canvas bilinearly, against the reference ray tracer at
// the canvas's size and the same camera. Times are wall-clock and process CPU (all threads: less
// sensitive to a loaded machine than the wall clock, run with OMP_WAIT_POLICY=passive; with
// OMP_NUM_THREADS=1 LP_NUM_THREADS=0 a frame's work on one core), each frame's best of R rounds.
//
// usage: hyb_moving_frames VOLUME|SCENE.hoct [--iso V | --volume-only] [--canvas N] [--views K] [--frames F]
//                          [--rounds R] [--refs DIR] [--dump DIR] [--methods LIST] [--reuse DEG:SIZE:STEP]
//   LIST: comma-separated METHOD:SIZE:STEP, METHOD one of slices, rays, rayspre (pre-integrated), fast
//   (the interactive tracer), e.g. fast:256:1.5; default: the ladders' rungs around 128² and the
//   interactive tracer from 128² to 320².
//   --refs DIR keeps the reference images between runs (a reference at 512² takes seconds); --dump DIR
//   writes each view's first frame as sent (after the JPEG); --reuse measures reprojection's best case
//   (reuse()).
#include <turbojpeg.h>
#include <time.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "apps/viewer/viewer_quality.h"
#include "render/image.h"
#include "render/patient_view.h"
#include "render/raycast_interactive.h"
#include "render/scene_renderer.h"
#include "volume/core/error.h"

namespace {

using namespace hyb;
using Clock = std::chrono::steady_clock;

double msSince(Clock::time_point t0) { return std::chrono::duration<double, std::milli>(Clock::now() - t0).count(); }
double cpuMs() {
  timespec t{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return double(t.tv_sec) * 1e3 + double(t.tv_nsec) * 1e-6;
}
double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0.0 : v[v.size() / 2];
}

struct Method {
  std::string kind;  // slices, rays, fast
  int size = 128;
  double step = 2.5;
};

// A frame's pixels after the trip to the page: JPEG 95 with full chroma (the viewer's), decoded.
std::vector<uint8_t> throughJpeg(const std::vector<uint8_t>& rgba, int w, int h) {
  tjhandle c = tjInitCompress(), d = tjInitDecompress();
  unsigned char* jpeg = nullptr;
  unsigned long bytes = 0;
  std::vector<uint8_t> out(rgba.size());
  if (tjCompress2(c, rgba.data(), w, 0, h, TJPF_RGBA, &jpeg, &bytes, TJSAMP_444, 95, TJFLAG_FASTDCT) != 0 ||
      tjDecompress2(d, jpeg, bytes, out.data(), w, 0, h, TJPF_RGBA, 0) != 0)
    HYB_THROW(RuntimeError, "JPEG: ", tjGetErrorStr());
  tjFree(jpeg);
  tjDestroy(c);
  tjDestroy(d);
  return out;
}

// 8-bit RGBA as an opaque Image, to magnify.
Image fromRgba8(const std::vector<uint8_t>& rgba, int w, int h) {
  Image im(w, h);
  for (size_t i = 0; i < im.pixels.size(); ++i) im.pixels[i] = glm::vec4(rgba[4 * i] / 255.0f, rgba[4 * i + 1] / 255.0f, rgba[4 * i + 2] / 255.0f, 1.0f);
  return im;
}


// Reprojection's best case: each view's frame made of the exact image of a camera @p deg degrees of
// orbit before it (the reference tracer's, as if the frame before had converged), moved to this
// camera by the depth at which each pixel of a new small frame (the interactive tracer's, @p size²
// at @p step) reaches half its opacity, where the exact image's own depth there agrees within
// 3 mm; elsewhere (what the old camera did not see, or a translucent layer moved by parallax) the
// new frame magnified. Printed against the new frame alone, both as painted.
void reuse(SceneRenderer& r, const Look& look, const TriangleMesh* surface, const std::vector<std::vector<View>>& views,
           const std::vector<glm::dvec3>& points, const std::vector<std::vector<uint8_t>>& reference, const std::string& refs,
           const std::string& path, int canvas, double deg, int size, double step) {
  const Bvh bvh = surface ? Bvh(*surface) : Bvh();
  auto trace = [&](const Camera& patient, double s, std::vector<float>* depth) {
    RaycastOptions o;
    o.stepVoxels = s;
    o.surface = surface ? &bvh : nullptr;
    o.surfaceColor = look.surfaceColor;
    return raycastInteractive(r.volume(), r.octree(), look.tf, toGridCamera(patient, r.volume().frame()), o, {.depth = depth});
  };
  std::printf("reuse of a converged frame %g degrees before, moved by a %d² frame's depth at step %g:\n", deg, size, step);
  const int n = int(views.size());
  for (int v = 0; v < n; ++v) {
    const double az = -45.0 + 90.0 * (n > 1 ? double(v) / (n - 1) : 0.5), el = (v % 2 ? -8.0 : 8.0);
    const Camera now = toGridCamera(views[size_t(v)][0].camera, r.volume().frame());
    View before;
    before.camera = fitCamera(points, orbitDirection(az - deg, el), {30.0, false, canvas, canvas});
    const Camera then = toGridCamera(before.camera, r.volume().frame());
    // The old frame: the reference's image, and its depths (the interactive tracer's at 0.5 voxel).
    const std::string name = refs.empty() ? "" : refs + "/" + std::filesystem::path(path).stem().string() + "-before-" + std::to_string(deg) + "-" +
                                                    std::to_string(canvas) + "-" + std::to_string(v) + ".png";
    Image old;
    if (!name.empty() && std::filesystem::exists(name)) {
      int w = 0, h = 0;
      old = fromRgba8(readPng(name, &w, &h), w, h);
    } else {
      Quality q;
      q.renderer = Renderer::Raycast;
      old = fromRgba8(toRgba8(r.render(before, look, q).image, glm::vec3(0.0f)), canvas, canvas);
      if (!name.empty()) writePng(name, old, glm::vec3(0.0f));
    }
    std::vector<float> oldDepth, newDepth;
    trace(before.camera, 0.5, &oldDepth);
    View small = views[size_t(v)][0];
    small.camera.width = small.camera.height = size;
    const Image fresh = trace(small.camera, step, &newDepth);
    const Image alone = resampled(fromRgba8(throughJpeg(toRgba8(fresh, glm::vec3(0.0f)), size, size), size, size), canvas, canvas);
    Image moved = alone;
    size_t kept = 0;
    const glm::dvec3 f = then.forward(), right = then.right(), up = then.trueUp();
    const double t = std::tan(glm::radians(then.fovDeg) * 0.5);
    for (int y = 0; y < canvas; ++y)
      for (int x = 0; x < canvas; ++x) {
        const float d = newDepth[size_t((y * size) / canvas) * size_t(size) + size_t((x * size) / canvas)];
        if (!std::isfinite(d)) continue;
        glm::dvec3 o, dir;
        now.ray(x + 0.5, y + 0.5, &o, &dir);
        const glm::dvec3 p = o + dir * double(d), rel = p - then.eye;
        const double z = glm::dot(rel, f);
        if (z <= 0.0) continue;
        const double px = (glm::dot(rel, right) / (z * t) + 1.0) * 0.5 * canvas, py = (1.0 - glm::dot(rel, up) / (z * t)) * 0.5 * canvas;
        const int ix = int(px), iy = int(py);
        if (ix < 0 || iy < 0 || ix >= canvas || iy >= canvas) continue;
        if (std::abs(double(oldDepth[size_t(iy) * size_t(canvas) + size_t(ix)]) - glm::length(rel)) > 3.0) continue;
        const double fx = std::clamp(px - 0.5, 0.0, canvas - 1.0), fy = std::clamp(py - 0.5, 0.0, canvas - 1.0);
        const int x0 = int(fx), y0 = int(fy), x1 = std::min(x0 + 1, canvas - 1), y1 = std::min(y0 + 1, canvas - 1);
        const float tx = float(fx - x0), ty = float(fy - y0);
        moved.at(x, y) = glm::mix(glm::mix(old.at(x0, y0), old.at(x1, y0), tx), glm::mix(old.at(x0, y1), old.at(x1, y1), tx), ty);
        ++kept;
      }
    std::printf("  view %d: the new frame alone %.2f dB, with the old frame moved %.2f dB (%.0f %% of the pixels reused)\n", v,
                psnr(reference[size_t(v)], toRgba8(alone, glm::vec3(0.0f))), psnr(reference[size_t(v)], toRgba8(moved, glm::vec3(0.0f))),
                100.0 * double(kept) / double(canvas * canvas));
  }
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: hyb_moving_frames VOLUME|SCENE.hoct [--iso V | --volume-only] [--canvas N] [--views K] [--frames F] [--rounds R]"
                         " [--refs DIR] [--dump DIR] [--methods LIST] [--reuse DEG:SIZE:STEP]\n");
    return 2;
  }
  try {
    const std::string path = argv[1];
    float iso = 400.0f;
    bool surface = true;
    int canvas = 512, viewCount = 4, frames = 4, rounds = 2;
    std::string refs, methodList, dump;
    double reuseDeg = 0.0, reuseStep = 2.5;
    int reuseSize = 128;
    for (int i = 2; i < argc; ++i) {
      const std::string a = argv[i];
      auto next = [&] {
        if (i + 1 >= argc) HYB_THROW(ValueError, a, " needs a value");
        return std::string(argv[++i]);
      };
      if (a == "--iso") iso = std::stof(next());
      else if (a == "--volume-only") surface = false;
      else if (a == "--canvas") canvas = std::stoi(next());
      else if (a == "--views") viewCount = std::stoi(next());
      else if (a == "--frames") frames = std::stoi(next());
      else if (a == "--rounds") rounds = std::stoi(next());
      else if (a == "--refs") refs = next();
      else if (a == "--methods") methodList = next();
      else if (a == "--dump") dump = next();
      else if (a == "--reuse") {
        const std::string v = next();
        if (std::sscanf(v.c_str(), "%lf:%d:%lf", &reuseDeg, &reuseSize, &reuseStep) != 3 || !(reuseDeg > 0.0) || reuseSize < 16 || !(reuseStep > 0.0))
          HYB_THROW(ValueError, "--reuse ", v, ": expected DEG:SIZE:STEP (degrees > 0, pixels >= 16, voxels > 0)");
      } else {
        HYB_THROW(ValueError, "unknown option ", a);
      }
    }
    if (canvas < 16 || viewCount < 1 || frames < 1 || rounds < 1) HYB_THROW(ValueError, "--canvas (>= 16), --views, --frames and --rounds (>= 1) out of range");
    std::vector<Method> methods;
    if (methodList.empty())  // (docs/renderer.md's tables)
      methodList = surface ? "slices:128:2.5,slices:160:2.5,rays:128:2.5,rays:160:2.5,fast:128:2.5,fast:160:2,fast:192:1.5,fast:224:1.5,fast:256:1.5,fast:320:2"
                           : "slices:128:1.3,slices:160:1.3,slices:192:1.3,slices:256:1,fast:128:2,fast:192:1.5,fast:256:1.5";
    {
      std::istringstream in(methodList);
      for (std::string item; std::getline(in, item, ',');) {
        Method m;
        char kind[16] = {};
        if (std::sscanf(item.c_str(), "%15[a-z]:%d:%lf", kind, &m.size, &m.step) != 3 || m.size < 16 || !(m.step > 0.0))
          HYB_THROW(ValueError, "--methods ", item, ": expected METHOD:SIZE:STEP (pixels >= 16, voxels > 0)");
        m.kind = kind;
        if (m.kind != "slices" && m.kind != "rays" && m.kind != "rayspre" && m.kind != "fast")
          HYB_THROW(ValueError, "--methods ", item, ": METHOD is slices, rays, rayspre or fast");
        methods.push_back(m);
      }
    }
    SceneSource source;
    source.path = path;
    OpenedScene opened = openScene(source, {}, SceneLoadOptions{false, 0});
    SceneRenderer r(std::move(opened.scene));
    Look look;
    look.tf = TransferFunction::preset("ct-skin-bone");
    std::shared_ptr<const TriangleMesh> smooth;  // the surface the reference draws (grid frame)
    if (surface) {
      look.iso = iso;
      look.surfaceColor = glm::vec4(0.9490196f, 0.9215686f, 0.8509804f, 0.5f);  // the page's bone white at α 0.5
      auto prepared = SceneRenderer::prepareSurface(r.scene(), iso);
      prepared->simplified = SceneRenderer::simplifiedLevels(r.scene(), *prepared->smooth);
      smooth = prepared->smooth;
      r.adoptSurface(std::move(prepared));
    }
    const std::vector<glm::dvec3> points =
        visiblePoints(r.volume(), r.octree(), look.tf, std::nullopt, r.volume().hasSamples() ? nullptr : r.scene().knots.get());
    // The page's orbit swings ±56° about the anterior view and ±10° up and down: views spread over it,
    // each the first of frames 3° apart (a moving frame's camera is new each time).
    std::vector<std::vector<View>> views(static_cast<size_t>(viewCount));
    for (int v = 0; v < viewCount; ++v)
      for (int f = 0; f < frames; ++f) {
        const double az = -45.0 + 90.0 * (viewCount > 1 ? double(v) / (viewCount - 1) : 0.5) + 3.0 * f, el = (v % 2 ? -8.0 : 8.0);
        View view;
        view.camera = fitCamera(points, orbitDirection(az, el), {30.0, false, canvas, canvas});
        views[size_t(v)].push_back(view);
      }
    // The references: the ray tracer at its default spacing, at the canvas's size.
    std::vector<std::vector<uint8_t>> reference;
    for (int v = 0; v < viewCount; ++v) {
      const std::string name = refs.empty() ? "" :
          refs + "/" + std::filesystem::path(path).stem().string() + (surface ? "-surface-" : "-volume-") + std::to_string(canvas) + "-" +
              std::to_string(viewCount) + "-" + std::to_string(v) + ".png";
      if (!name.empty() && std::filesystem::exists(name)) {
        int w = 0, h = 0;
        reference.push_back(readPng(name, &w, &h));
        continue;
      }
      Quality q;
      q.renderer = Renderer::Raycast;
      const Image ref = r.render(views[size_t(v)][0], look, q).image;
      reference.push_back(toRgba8(ref, glm::vec3(0.0f)));
      if (!name.empty()) writePng(name, ref, glm::vec3(0.0f));
    }
    std::printf("%s, %s, canvas %d², %d views × %d frames, best of %d rounds\n", path.c_str(), surface ? "translucent surface" : "volume only",
                canvas, viewCount, frames, rounds);
    std::printf("%-8s %5s %5s  %9s %9s  %s\n", "method", "size", "step", "wall ms", "cpu ms", "PSNR as painted (each view), dB");
    // Each round renders every method's frames in turn, so that a change in the machine's load
    // falls on all of them; a frame's time is its best over the rounds.
    struct Measured {
      std::vector<double> wall, cpu, db;
      double samples = 0.0;
    };
    std::vector<Measured> measured(methods.size());
    for (int round = 0; round < rounds; ++round)
      for (size_t k = 0; k < methods.size(); ++k) {
        const Method& m = methods[k];
        Measured& out = measured[k];
        Quality q;
        q.renderer = m.kind == "slices" ? Renderer::Slices : Renderer::Raycast;
        q.interactiveRays = m.kind == "fast";
        if (m.kind == "rayspre") q.classification = Classification::PreIntegrated;
        // As the viewer's frames before the final one (apps/viewer/frame_scheduler.cpp, frameParts).
        q.step = m.step;
        q.reuseViewErrors = true;
        q.simplifiedSurface = true;
        q.surfaceErrorPixels = viewer::kInteractiveSurfaceErrorPixels;
        q.cutToSlabs = false;
        q.maxBrickEdge = viewer::kInteractiveBrickEdge;
        q.lodPixels = viewer::kInteractiveLodPixels;
        q.waitForSurface = false;
        size_t i = 0;
        for (int v = 0; v < viewCount; ++v)
          for (int f = 0; f < frames; ++f, ++i) {
            View view = views[size_t(v)][size_t(f)];
            view.camera.width = view.camera.height = m.size;
            const double c0 = cpuMs();
            const auto t0 = Clock::now();
            const RenderedFrame frame = r.render(view, look, q);
            const double ms = msSince(t0), cms = cpuMs() - c0;
            if (round == 0) {
              out.wall.push_back(ms);
              out.cpu.push_back(cms);
              out.samples += double(frame.stats.rays.samples) / double(viewCount * frames);
            } else {
              out.wall[i] = std::min(out.wall[i], ms);
              out.cpu[i] = std::min(out.cpu[i], cms);
            }
            if (round == 0 && f == 0) {
              const std::vector<uint8_t> sent = throughJpeg(toRgba8(frame.image, glm::vec3(0.0f)), m.size, m.size);
              if (!dump.empty())
                writePng(dump + "/" + m.kind + "-" + std::to_string(m.size) + "-" + std::to_string(m.step) + "-" + std::to_string(v) + ".png",
                         fromRgba8(sent, m.size, m.size), glm::vec3(0.0f));
              const Image painted = resampled(fromRgba8(sent, m.size, m.size), canvas, canvas);
              out.db.push_back(psnr(reference[size_t(v)], toRgba8(painted, glm::vec3(0.0f))));
            }
          }
      }
    for (size_t k = 0; k < methods.size(); ++k) {
      const Method& m = methods[k];
      const Measured& out = measured[k];
      // (the first frame, which makes textures or the BVH, left out)
      const std::vector<double> wall(out.wall.begin() + 1, out.wall.end()), cpu(out.cpu.begin() + 1, out.cpu.end());
      std::printf("%-8s %5d %5.2f  %9.1f %9.1f ", m.kind.c_str(), m.size, m.step, median(wall), median(cpu));
      double mean = 0.0;
      for (const double d : out.db) {
        std::printf(" %5.2f", d);
        mean += d / double(out.db.size());
      }
      std::printf("  (mean %.2f)", mean);
      if (m.kind != "slices") std::printf("  %.2f M samples", out.samples * 1e-6);
      std::printf("\n");
    }
    if (reuseDeg > 0.0) reuse(r, look, smooth.get(), views, points, reference, refs, path, canvas, reuseDeg, reuseSize, reuseStep);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "hyb_moving_frames: %s\n", e.what());
    return 1;
  }
  return 0;
}
