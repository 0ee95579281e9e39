// hyb_bench: speed next to quality, best of N runs, ratios measured in one run.
//
// Volume Octree: build throughput against a pass that reads every sample once, and memory overhead.
// Surface: classic MC (baseline), DiscMC and the Surface Octree at each isovalue, single thread:
// triangles and time, with the Surface Octree's triangles and time as ratios of MC's.
// Rendering: 512x512 frames against the reference ray tracer; slice frames are the best of warm
// frames (brick textures uploaded by the first and kept).
//
// usage: hyb_bench [VOLUME] [--runs N] [--iso V]... [--surface-only]
//        (defaults: the Debian Cranium.inv3, 400 and -500; --surface-only stops after the surfaces)
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <limits>
#include <string>
#include <vector>

#include <omp.h>

#include "bench/plain_quads.h"
#include "hybrid_octree/selection.h"
#include "hybrid_octree/surface_octree.h"
#include "render/raycast.h"
#include "render/slices.h"
#include "surface/dmc.h"
#include "hybrid_octree/volume_octree.h"
#include "volume/volume_io.h"

namespace {

using Clock = std::chrono::steady_clock;

template <typename F>
double bestMs(int runs, F&& f) {
  double best = std::numeric_limits<double>::max();
  for (int r = 0; r < runs; ++r) {
    const auto t0 = Clock::now();
    f();
    best = std::min(best, std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
  }
  return best;
}

}  // namespace

int main(int argc, char** argv) {
  std::string path = hyb::kDefaultVolumePath;
  int runs = 7;
  std::vector<float> isovalues;
  bool surfaceOnly = false;
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--runs") == 0 && i + 1 < argc)
      runs = std::max(1, std::atoi(argv[++i]));
    else if (std::strcmp(argv[i], "--iso") == 0 && i + 1 < argc)
      isovalues.push_back(float(std::atof(argv[++i])));
    else if (std::strcmp(argv[i], "--surface-only") == 0)
      surfaceOnly = true;
    else
      path = argv[i];
  }
  if (isovalues.empty()) isovalues = {400.0f, -500.0f};
  try {
    const hyb::Volume v = hyb::readVolume(path);
    const double mvox = double(v.voxelCount()) / 1e6;

    // Baseline: read every sample once (parallel min/max), what the build cannot beat.
    float sink = 0;
    const double readMs = bestMs(runs, [&] {
      v.visitSamples([&](const auto* s) {
        const size_t n = v.voxelCount();
        float lo = float(s[0]), hi = float(s[0]);
#pragma omp parallel for reduction(min : lo) reduction(max : hi)
        for (size_t i = 0; i < n; ++i) {
          lo = std::min(lo, float(s[i]));
          hi = std::max(hi, float(s[i]));
        }
        sink += lo + hi;
      });
    });

    hyb::VolumeOctree tree;
    const double buildMs = bestMs(runs, [&] { tree = hyb::VolumeOctree::build(v); });

    std::printf("volume   %s\n         %d x %d x %d %s, %.2f Mvoxels, %.2f MB\n", path.c_str(), v.dims().x, v.dims().y,
                v.dims().z, hyb::scalarName(v.sourceType()), mvox, double(v.sourceBytes()) / 1048576.0);
    std::printf("\n%-34s %10s %12s %10s\n", "Volume Octree build (best of N)", "ms", "Mvoxels/s", "vs read");
    std::printf("%-34s %10.2f %12.1f %10.2f\n", "read every sample once (baseline)", readMs, mvox / readMs * 1e3, 1.0);
    std::printf("%-34s %10.2f %12.1f %10.2f\n", "build: min/max + nodal errors", buildMs, mvox / buildMs * 1e3, buildMs / readMs);
    std::printf("\n%-34s %10zu nodes, %zu errors, %zu bytes\n", "octree memory", tree.nodes().size(), tree.errorData().size(),
                tree.bytesUsed());
    std::printf("%-34s %9.2f %%   (target <= 15 %%)\n", "overhead vs the source volume", 100.0 * double(tree.bytesUsed()) / double(v.sourceBytes()));
    std::printf("%-34s %9.2f %%\n", "overhead vs the samples held", 100.0 * double(tree.bytesUsed()) / double(v.bytesUsed()));

    std::printf("\n%-12s %10s %10s %14s %14s\n", "epsilon", "select ms", "bricks", "texels", "max error");
    for (float eps : {0.0f, 10.0f, 50.0f, 200.0f, 1000.0f}) {
      hyb::SelectionParams params;
      params.epsilon = eps;
      params.spacing = v.spacing();
      hyb::Selection sel;
      const double ms = bestMs(runs, [&] { sel = hyb::selectNodes(tree, params); });
      std::printf("%-12.1f %10.3f %10zu %14llu %14.2f\n", double(eps), ms, sel.bricks.size(), (unsigned long long)sel.texels,
                  double(sel.maxError));
    }

    // Surfaces, single thread: the baselines (our MC, VTK flying edges) are single-thread codes.
    omp_set_num_threads(1);
    std::printf("\n%-30s %10s %10s %10s %10s\n", "surface (single thread)", "polygons", "triangles", "ms", "vs MC");
    for (float iso : isovalues) {
      const std::vector<hyb::VoxelBlock> blocks = hyb::isoBlocks(tree, iso);
      hyb::TriangleMesh mc;
      const double mcMs = bestMs(runs, [&] { mc = hyb::extractMarchingCubes(v, iso, blocks); });
      hyb::DiscreteMesh dmc;
      const double dmcMs = bestMs(runs, [&] { dmc = hyb::extractDiscMC(v, iso, blocks); });
      hyb::SurfaceOctree so;
      const double soMs = bestMs(runs, [&] { so = hyb::SurfaceOctree::build(v, tree, iso); });
      hyb::DiscreteMesh rec, whole;
      const double recMs = bestMs(std::max(1, runs / 3), [&] { rec = so.reconstruct(); });
      const double wholeMs = bestMs(std::max(1, runs / 3), [&] { whole = so.reconstruct(hyb::kMaxDim); });
      const size_t recTris = hyb::fineMeshToTriangles(rec, v.spacing()).triangles.size();
      const size_t wholeTris = hyb::fineMeshToTriangles(whole, v.spacing()).triangles.size();
      const double mcT = double(mc.triangles.size());
      std::printf("iso %-26g\n", double(iso));
      std::printf("  %-28s %10zu %10zu %10.1f %10s\n", "classic MC", mc.triangles.size(), mc.triangles.size(), mcMs, "1.00");
      std::printf("  %-28s %10zu %10zu %10.1f %10.2f\n", "DiscMC (cell polygons)", dmc.faceCount(), dmc.triangleCount(), dmcMs, dmcMs / mcMs);
      std::printf("  %-28s %10zu %10s %10.1f %10.2f   (%zu cells -> %zu nodes)\n", "Surface Octree build", so.nodes().size(), "",
                  soMs, soMs / mcMs, so.cellCount(), so.nodes().size());
      std::printf("  %-28s %10zu %10zu %10.1f %10.2f   triangles %.3f x MC\n", "SO polygons, per brick",
                  rec.faceCount(), recTris, recMs, recMs / mcMs, double(recTris) / mcT);
      std::printf("  %-28s %10zu %10zu %10.1f %10.2f   triangles %.3f x MC (target <= 0.5)\n", "SO polygons, export (whole)",
                  whole.faceCount(), wholeTris, wholeMs, wholeMs / mcMs, double(wholeTris) / mcT);
    }

    if (surfaceOnly) return 0;

    // Rendering: 512x512, translucent volume (ct-skin-bone) with the translucent 400 HU surface.
    omp_set_num_threads(2);
    {
      const hyb::TransferFunction tf = hyb::TransferFunction::preset("ct-skin-bone");
      const hyb::Camera cam = hyb::Camera::orbit(glm::dvec3(0.0), v.extentMm(), {180, 10, 30, false, 512, 512});
      const hyb::SurfaceOctree so = hyb::SurfaceOctree::build(v, tree, 400.0f);
      const hyb::TriangleMesh mesh = hyb::fineMeshToTriangles(so.reconstruct(), v.spacing());
      const hyb::Bvh bvh(mesh);
      const glm::vec4 color(0.95f, 0.92f, 0.85f, 0.5f);
      hyb::RaycastOptions ro;
      ro.surface = &bvh;
      ro.surfaceColor = color;
      hyb::Image reference;
      const double refMs = bestMs(1, [&] { reference = hyb::raycast(v, tree, tf, cam, ro); });
      const auto ref8 = hyb::toRgba8(reference, glm::vec3(0));
      hyb::RaycastOptions volumeOnly;
      const double refVolMs = bestMs(1, [&] { hyb::raycast(v, tree, tf, cam, volumeOnly); });
      std::printf("\n%-34s %10s %14s %12s %10s\n", "render 512x512 (2 threads)", "ms", "texture bytes", "slab draws", "PSNR dB");
      std::printf("%-34s %10.0f %14s %12s %10s\n", "reference ray tracer, + surface", refMs, "-", "-", "ref");
      std::printf("%-34s %10.0f %14s %12s %10s\n", "reference ray tracer, volume only", refVolMs, "-", "-", "-");
      const hyb::GlContext gl;
      // The first frame uploads the brick textures; the best of the warm ones after it counts.
      const int warmFrames = 1 + std::max(3, runs / 2);
      for (float eps : {0.0f, 50.0f, 200.0f, 1000.0f}) {
        hyb::SelectionParams params;
        params.epsilon = eps;
        params.spacing = v.spacing();
        const hyb::Selection sel = hyb::selectNodes(tree, params);
        hyb::BrickTextureCache textures;  // frames after the first reuse the brick textures, as VTK's do
        hyb::SlicesOptions opt;
        opt.surface = &mesh;
        opt.surfaceColor = color;
        opt.textures = &textures;
        hyb::SlicesStats st;
        hyb::Image img;
        const double ms = bestMs(warmFrames, [&] { img = hyb::renderSlices({v, tree, sel}, tf, cam, opt, &st); });
        char label[64];
        std::snprintf(label, sizeof label, "slices eps %g, + surface", double(eps));
        std::printf("%-34s %10.0f %14llu %12llu %10.2f\n", label, ms, (unsigned long long)st.textureBytes,
                    (unsigned long long)st.slabPolygonDraws, hyb::psnr(hyb::toRgba8(img, glm::vec3(0)), ref8));
      }
      hyb::SelectionParams exact;
      const hyb::Selection sel = hyb::selectNodes(tree, exact);
      hyb::Image img;
      hyb::SlicesStats vst;
      hyb::BrickTextureCache textures;
      hyb::SlicesOptions noSurface;
      noSurface.textures = &textures;
      const double volMs = bestMs(warmFrames, [&] { img = hyb::renderSlices({v, tree, sel}, tf, cam, noSurface, &vst); });
      std::printf("%-34s %10.0f %14s %12s %10s\n", "slices eps 0, volume only", volMs, "", "", "");
      // Fragment throughput against plain full-screen quads sampling a float 3D texture (the
      // target's baseline) and the bricks' RGBA8 format (what the format alone costs).
      const double slicesRate = double(vst.fragments) / (volMs / 1e3) / 1e6;
      auto plainRate = [&](bool brickFormat, const char* label) {
        uint64_t plainFragments = 0;
        double plainS = 1e300;
        for (int r = 0; r < std::max(1, runs / 3); ++r)
          plainS = std::min(plainS, hyb::bench::plainQuadSeconds(v, 512, 512, 200, &plainFragments, brickFormat));
        const double rate = double(plainFragments) / plainS / 1e6;
        std::printf("%-34s %10.1f M fragments/s (%llu fragments)\n", label, rate, (unsigned long long)plainFragments);
        return rate;
      };
      std::printf("\n");
      const double floatRate = plainRate(false, "plain quads, R32F texture"), brickRate = plainRate(true, "plain quads, RGBA8 texture");
      std::printf("%-34s %10.1f M fragments/s (%llu fragments), %.0f %% of plain R32F (target >= 70 %%), %.0f %% of plain RGBA8\n",
                  "slices, volume only", slicesRate, (unsigned long long)vst.fragments, 100.0 * slicesRate / floatRate, 100.0 * slicesRate / brickRate);
    }
    std::printf("runs %d (sink %g)\n", runs, double(sink));
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "hyb_bench: error: %s\n", e.what());
    return 2;
  }
}
