// DICOM as a hospital hands it out, measured: the headers of a patient CD's folder tree scanned
// (files a second), and the data for bench/dicom_bench.sh, which reads a gantry-tilted series
// against the same series acquired untilted, each read in a process of its own (--read). The data
// are written first (tests/dicom_writer): a clinical-size head phantom (skull, brain, air) with
// noise of 12 HU, 512x512 slices.
//   hyb_dicom_bench DIR [--files N] [--slices N] [--size N]
//   hyb_dicom_bench --read whole|streamed SERIES_DIR      prints CPU and wall seconds
#include <sys/resource.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <random>
#include <string>

#include "tests/dicom_writer.h"
#include "volume/plane_source.h"
#include "volume/plane_stack.h"
#include "volume/reader_util.h"
#include "volume/volume_io.h"

namespace {

using Clock = std::chrono::steady_clock;
double secondsSince(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }
// The process's CPU seconds (user and system): on a shared machine steadier than the wall clock.
double cpuSeconds() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return double(u.ru_utime.tv_sec + u.ru_stime.tv_sec) + 1e-6 * double(u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}

// A head: an ellipsoid of brain (40 HU) in a 7 mm skull (1000 HU), air around, noise σ 12 HU.
double head(const glm::dvec3& p, std::mt19937& rng) {
  static std::normal_distribution<double> noise(0.0, 12.0);
  const glm::dvec3 q = p / glm::dvec3(75.0, 95.0, 80.0);
  const double r = glm::length(q);
  const double hu = r > 1.0 ? -1000.0 : r > 0.92 ? 1000.0 : 40.0;
  return hu + noise(rng);
}

// A series of @p slices of @p size² pixels of 0.5 mm, the table advancing 0.625 mm a slice, the
// image plane tilted by @p tiltDeg about the patient's x axis.
void writeHeadSeries(const std::string& dir, int size, int slices, double tiltDeg, const std::string& seriesUid) {
  if (std::filesystem::exists(dir)) return;
  hyb::test::DicomImage model;
  model.size = {size, size};
  model.spacing = {0.5, 0.5};
  model.seriesUid = seriesUid;
  const double t = tiltDeg * M_PI / 180.0;
  const double cosines[6] = {1, 0, 0, 0, std::cos(t), std::sin(t)};
  std::copy(std::begin(cosines), std::end(cosines), model.cosines);
  model.tilt = tiltDeg;
  std::vector<glm::dvec3> positions;
  for (int k = 0; k < slices; ++k) positions.push_back({-0.25 * size, -0.25 * size, -0.3125 * slices + 0.625 * k});
  std::mt19937 rng(7);
  hyb::test::writeSeries(dir, "I", hyb::test::DicomStudy{}, model, positions, [&](const glm::dvec3& p) { return head(p, rng); });
}

// A CD's tree of @p files images: series of 100 slices, each in its folder, as CD writers lay them out.
void writeCdTree(const std::string& dir, int files, int size) {
  if (std::filesystem::exists(dir)) return;
  std::mt19937 rng(3);
  for (int s = 0; s * 100 < files; ++s) {
    hyb::test::DicomImage model;
    model.size = {size, size};
    model.spacing = {0.5, 0.5};
    model.seriesUid = "1.2.826.0.1.3680043.8.498.7." + std::to_string(s);
    std::vector<glm::dvec3> positions;
    for (int k = 0; k < 100 && s * 100 + k < files; ++k) positions.push_back({-0.25 * size, -0.25 * size, 1.0 * k});
    hyb::test::writeSeries(dir + "/S" + std::to_string(1000 + s / 10) + "/S" + std::to_string(2000 + s), "I", hyb::test::DicomStudy{}, model, positions,
                           [&](const glm::dvec3& p) { return head(p, rng); });
  }
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: hyb_dicom_bench DIR [--files N] [--slices N] [--size N]\n       hyb_dicom_bench --read whole|streamed SERIES_DIR\n");
    return 2;
  }
  if (std::string(argv[1]) == "--read" && argc == 4) {  // one read in a process of its own (bench/dicom_bench.sh)
    const bool whole = std::string(argv[2]) == "whole";
    const double t = cpuSeconds();
    const auto w = Clock::now();
    if (whole) {
      (void)hyb::readVolume(argv[3]);
    } else {
      const std::unique_ptr<hyb::PlaneSource> planes = hyb::openPlanes(argv[3]);
      hyb::SampleArray plane = hyb::detail::allocateSamples(planes->storedType(), planes->planeSize());
      for (int z = 0; z < planes->dims().z; ++z) planes->read(1, &plane, 0);
    }
    std::printf("%.3f %.3f\n", cpuSeconds() - t, secondsSince(w));
    return 0;
  }
  const std::string dir = argv[1];
  int files = 2000, slices = 300, size = 512;
  for (int a = 2; a + 1 < argc; a += 2) {
    const std::string flag = argv[a];
    const int v = std::atoi(argv[a + 1]);
    if (flag == "--files") files = v;
    else if (flag == "--slices") slices = v;
    else if (flag == "--size") size = v;
  }
  std::filesystem::create_directories(dir);
  const std::string cd = dir + "/cd" + std::to_string(files), straight = dir + "/straight" + std::to_string(slices),
                    tilted = dir + "/tilted" + std::to_string(slices);
  auto t = Clock::now();
  writeCdTree(cd, files, size);
  writeHeadSeries(straight, size, slices, 0.0, "1.2.826.0.1.3680043.8.498.20");
  writeHeadSeries(tilted, size, slices, 18.5, "1.2.826.0.1.3680043.8.498.21");
  std::printf("data written in %.1f s\n", secondsSince(t));
  // The scan: the second of two (the page cache warm, as after a CD is copied or browsed).
  for (int pass = 0; pass < 2; ++pass) {
    t = Clock::now();
    const hyb::DicomListing l = hyb::listDicomSeries(cd);
    const double s = secondsSince(t);
    std::printf("scan %s: %zu files, %zu series in %.3f s: %.0f files/s%s\n", cd.c_str(), l.files, l.series.size(), s, double(l.files) / s,
                pass == 0 ? " (first pass)" : "");
  }
  return 0;
}
