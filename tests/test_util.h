// Analytic fixtures shared by the tests: volumes built from closed-form fields, temporary
// directories, byte helpers, and an independent brute-force nodal error.
#pragma once

#include <gtest/gtest.h>
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <csignal>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <vector>

#include "hybrid_octree/volume_octree.h"
#include "volume/volume.h"

namespace hyb::test {

/// Volume whose sample (i,j,k) is f(i,j,k).
template <typename F>
Volume makeVolume(glm::ivec3 dims, F f, glm::dvec3 spacing = glm::dvec3(1.0), ScalarType type = ScalarType::Float32) {
  std::vector<float> s(size_t(dims.x) * dims.y * dims.z);
  for (int k = 0; k < dims.z; ++k)
    for (int j = 0; j < dims.y; ++j)
      for (int i = 0; i < dims.x; ++i) s[size_t(i) + size_t(dims.x) * (j + size_t(dims.y) * k)] = float(f(i, j, k));
  return Volume(dims, spacing, type, std::move(s), "test volume");
}

/// All samples of @p v as float, x fastest.
inline std::vector<float> floatSamples(const Volume& v) {
  std::vector<float> out(v.voxelCount());
  for (size_t i = 0; i < out.size(); ++i) out[i] = v.value(i);
  return out;
}

/// Signed distance-like sphere: radius − |x − centre| (positive inside), in voxels.
inline Volume sphereVolume(glm::ivec3 dims, double radius) {
  const glm::dvec3 c = glm::dvec3(dims - 1) * 0.5;
  return makeVolume(dims, [&](int i, int j, int k) { return radius - glm::length(glm::dvec3(i, j, k) - c); });
}

/// Box of value @p inside on [lo, hi] (voxel indices, inclusive), @p outside elsewhere.
inline Volume boxVolume(glm::ivec3 dims, glm::ivec3 lo, glm::ivec3 hi, float inside, float outside) {
  return makeVolume(dims, [&](int i, int j, int k) {
    const bool in = i >= lo.x && i <= hi.x && j >= lo.y && j <= hi.y && k >= lo.z && k <= hi.z;
    return in ? inside : outside;
  });
}

/// Two materials split by the plane x = split: @p a below, @p b at and above.
inline Volume twoMaterials(glm::ivec3 dims, int split, float a, float b) {
  return makeVolume(dims, [&](int i, int, int) { return i < split ? a : b; });
}

/// A general trilinear field (every term of a + bx + cy + dz + exy + fyz + gxz + hxyz).
inline double trilinearField(double x, double y, double z) {
  return 3.0 + 2.0 * x - 1.5 * y + 0.5 * z + 0.25 * x * y - 0.125 * y * z + 0.0625 * x * z + 0.01 * x * y * z;
}

/// Uniform random samples in [lo, hi) with a fixed seed.
inline Volume randomVolume(glm::ivec3 dims, uint32_t seed, float lo = -100.0f, float hi = 100.0f) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(lo, hi);
  return makeVolume(dims, [&](int, int, int) { return u(rng); });
}

/// A fresh directory removed with its contents at scope exit.
class TempDir {
 public:
  TempDir() {
    static std::atomic<int> counter{0};
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    mPath = std::filesystem::temp_directory_path() /
            ("hyb_" + std::to_string(::getpid()) + "_" + std::to_string(counter++) + "_" + (info ? info->name() : "x"));
    std::filesystem::remove_all(mPath);
    std::filesystem::create_directories(mPath);
  }
  ~TempDir() {
    std::error_code ec;
    std::filesystem::remove_all(mPath, ec);
  }
  std::string file(const std::string& name) const { return (mPath / name).string(); }
  const std::filesystem::path& path() const { return mPath; }

 private:
  std::filesystem::path mPath;
};

/// Writes beyond @p bytes fail with EFBIG while it lives, as they would on a full disk.
class FileSizeLimit {
 public:
  explicit FileSizeLimit(rlim_t bytes) : mSignal(std::signal(SIGXFSZ, SIG_IGN)) {
    ::getrlimit(RLIMIT_FSIZE, &mOld);
    rlimit l = mOld;
    l.rlim_cur = bytes;
    ::setrlimit(RLIMIT_FSIZE, &l);
  }
  ~FileSizeLimit() {
    ::setrlimit(RLIMIT_FSIZE, &mOld);
    std::signal(SIGXFSZ, mSignal);
  }
  FileSizeLimit(const FileSizeLimit&) = delete;
  FileSizeLimit& operator=(const FileSizeLimit&) = delete;

 private:
  rlimit mOld{};
  void (*mSignal)(int);
};

/// The names in @p dir, sorted.
inline std::vector<std::string> namesIn(const TempDir& dir) {
  std::vector<std::string> names;
  for (const auto& e : std::filesystem::directory_iterator(dir.path())) names.push_back(e.path().filename().string());
  std::sort(names.begin(), names.end());
  return names;
}

inline void writeBytes(const std::string& path, const void* data, size_t size) {
  std::ofstream out(path, std::ios::binary);
  out.write(static_cast<const char*>(data), std::streamsize(size));
}
inline void writeBytes(const std::string& path, const std::vector<uint8_t>& b) { writeBytes(path, b.data(), b.size()); }
inline void writeText(const std::string& path, const std::string& s) { writeBytes(path, s.data(), s.size()); }

inline std::vector<uint8_t> readBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::vector<uint8_t>(std::istreambuf_iterator<char>(in), {});
}

inline std::string readText(const std::string& path) {
  const std::vector<uint8_t> b = readBytes(path);
  return std::string(b.begin(), b.end());
}

/// Serialises @p values as bytes in the given byte order.
template <typename T>
std::vector<uint8_t> toBytes(const std::vector<T>& values, bool bigEndian = false) {
  std::vector<uint8_t> out(values.size() * sizeof(T));
  for (size_t i = 0; i < values.size(); ++i) {
    uint8_t b[sizeof(T)];
    std::memcpy(b, &values[i], sizeof(T));
    if (bigEndian) std::reverse(b, b + sizeof(T));
    std::memcpy(&out[i * sizeof(T)], b, sizeof(T));
  }
  return out;
}

/// ε_p of the node with @p origin and @p edge straight from the definition: every sample of the
/// node's box cut at the grid, full 8-corner trilinear weights in double, knots o + j·s with the
/// last one moved onto the grid's last sample, holding the values @p t's lattices hold there
/// (samples, or prefiltered values).
inline float bruteForceNodalError(const Volume& v, const VolumeOctree& octree, glm::ivec3 origin, int edge, int p) {
  const int s = edge >> p, cells = 1 << p;
  const glm::ivec3 last = v.dims() - 1;
  const glm::ivec3 hi = glm::min(origin + edge, last);
  double worst = 0.0;
  for (int z = origin.z; z <= hi.z; ++z)
    for (int y = origin.y; y <= hi.y; ++y)
      for (int x = origin.x; x <= hi.x; ++x) {
        const glm::ivec3 pos(x, y, z);
        glm::ivec3 l, r;
        glm::dvec3 w;
        for (int a = 0; a < 3; ++a) {
          const int j = std::min((pos[a] - origin[a]) / s, cells - 1);
          l[a] = origin[a] + j * s;
          r[a] = std::min(l[a] + s, last[a]);
          w[a] = r[a] > l[a] ? double(pos[a] - l[a]) / double(r[a] - l[a]) : 0.0;
        }
        double t = 0.0;
        for (int c = 0; c < 8; ++c) {
          const glm::ivec3 q((c & 1) ? r.x : l.x, (c & 2) ? r.y : l.y, (c & 4) ? r.z : l.z);
          const double weight = ((c & 1) ? w.x : 1 - w.x) * ((c & 2) ? w.y : 1 - w.y) * ((c & 4) ? w.z : 1 - w.z);
          t += weight * octree.knotValue(v, s, q);
        }
        worst = std::max(worst, std::fabs(double(v.at(x, y, z)) - t));
      }
  return float(worst);
}

}  // namespace hyb::test
