// hyb_bench octree: Volume Octree build throughput and memory overhead on a real volume.
//
// Prints, best of N runs, the time to read every sample once from memory (the baseline: a parallel
// min/max pass), the octree build time, both as Mvoxels/s, their ratio, and the octree's memory as
// a fraction of the volume. Ratios measured in one run are what to compare across machines.
//
// usage: hyb_bench [VOLUME] [--runs N]      (VOLUME defaults to the Debian Cranium.inv3)
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <limits>
#include <string>

#include "hybrid_octree/selection.h"
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
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--runs") == 0 && i + 1 < argc)
      runs = std::max(1, std::atoi(argv[++i]));
    else
      path = argv[i];
  }
  try {
    const hyb::Volume v = hyb::readVolume(path);
    const double mvox = double(v.voxelCount()) / 1e6;

    // Baseline: read every sample once (parallel min/max), what the build cannot beat.
    float sink = 0;
    const double readMs = bestMs(runs, [&] {
      const float* s = v.samples().data();
      const size_t n = v.voxelCount();
      float lo = s[0], hi = s[0];
#pragma omp parallel for reduction(min : lo) reduction(max : hi)
      for (size_t i = 0; i < n; ++i) {
        lo = std::min(lo, s[i]);
        hi = std::max(hi, s[i]);
      }
      sink += lo + hi;
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
    std::printf("%-34s %9.2f %%\n", "overhead vs the float samples held", 100.0 * double(tree.bytesUsed()) / double(v.voxelCount() * 4));

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
    std::printf("runs %d (sink %g)\n", runs, double(sink));
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "hyb_bench: error: %s\n", e.what());
    return 2;
  }
}
