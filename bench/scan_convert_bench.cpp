// Filtered 3D scan-conversion speed: geodesic spheres of ~100 k and ~1 M triangles onto a 512³
// grid, as a solid (box filter, uint8), as a 1 mm sheet, and as the sheet with each band voxel's
// normal (what the renderers' geometry channel asks for); best of N runs, triangles/s, band voxels/s
// and grid voxels/s, and the peak memory (docs/scan-conversion.md).
//
//   hyb_scan_convert_bench [runs=3] [dim=512]
#include <sys/resource.h>

#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "surface/scan_convert.h"

namespace {

// User + system CPU seconds of the process so far: the work, apart from what other load takes of the cores.
double cpuSeconds() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return double(u.ru_utime.tv_sec + u.ru_stime.tv_sec) + 1e-6 * double(u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}

double peakRssMiB() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return double(u.ru_maxrss) / 1024.0;
}

}  // namespace

int main(int argc, char** argv) {
  const int runs = argc > 1 ? std::max(1, std::atoi(argv[1])) : 3;
  const int dim = argc > 2 ? std::max(16, std::atoi(argv[2])) : 512;
  const hyb::VoxelGrid grid{glm::ivec3(dim), glm::dvec3(1.0), {}};
  const glm::dvec3 centre(0.5 * (dim - 1) + 0.31, 0.5 * (dim - 1) - 0.17, 0.5 * (dim - 1) + 0.07);
  std::printf("grid %d^3 (%.0f M voxels), %d threads, best of %d\n", dim, double(dim) * dim * dim * 1e-6, omp_get_max_threads(), runs);
  std::printf("%-10s %-7s %10s %8s %8s %10s %10s %12s %12s %10s\n", "triangles", "mode", "band vox", "seconds", "cpu s", "Mtri/s", "Mband/s",
              "Mgrid vox/s", "vol error", "peak MiB");
  for (const int frequency : {71, 224}) {  // 20·f² triangles: 100 820 and 1 003 520
    const double radius = 0.45 * (dim - 1);
    const hyb::TriangleMesh mesh = hyb::geodesicSphere(centre, radius, frequency);
    const double polyhedron = hyb::enclosedVolume(mesh);
    for (const int mode : {0, 1, 2}) {  // solid, sheet, sheet with normals
      const bool sheet = mode > 0;
      hyb::ScanOptions o;
      o.space = hyb::ScanSpace::Grid;
      o.thickness = sheet ? 1.0 : 0.0;
      o.normals = mode == 2;
      double best = 1e30, bestCpu = 1e30, volume = 0.0;
      size_t band = 0;
      for (int r = 0; r < runs; ++r) {
        const auto t0 = std::chrono::steady_clock::now();
        const double c0 = cpuSeconds();
        const hyb::ScanResult result = hyb::scanConvertMesh(mesh, grid, o);
        best = std::min(best, std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
        bestCpu = std::min(bestCpu, cpuSeconds() - c0);
        band = result.bandVoxels;
        if (!sheet && r == 0) {
          double sum = 0.0;
          result.coverage.visitSamples([&](const auto* s) {
            for (size_t n = 0; n < result.coverage.voxelCount(); ++n) sum += double(s[n]);
          });
          volume = sum / 255.0;
        }
      }
      const double n = double(mesh.triangles.size());
      const std::string error = sheet ? "-" : std::to_string((volume - polyhedron) / polyhedron);
      std::printf("%-10.0f %-7s %10zu %8.3f %8.3f %10.2f %10.1f %12.1f %12s %10.0f\n", n, mode == 0 ? "solid" : (mode == 1 ? "sheet" : "sheet+n"), band, best, bestCpu, n / best * 1e-6,
                  double(band) / best * 1e-6, double(dim) * dim * dim / best * 1e-6, error.c_str(), peakRssMiB());
    }
  }
  return 0;
}
