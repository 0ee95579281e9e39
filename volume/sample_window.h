// The last few planes of a volume read plane by plane (PlaneSource): what a streamed build reads
// its samples from, with a volume's own accessors over the planes it holds.
#pragma once

#include <glm/glm.hpp>

#include <algorithm>
#include <cmath>
#include <cstdint>

#include "volume/core/memory_limit.h"
#include "volume/plane_source.h"
#include "volume/reader_util.h"
#include "volume/volume.h"

namespace hyb {

class SampleWindow {
 public:
  /// Holds @p planes planes of @p source's grid.
  /// @throw IoError naming the source when they exceed the readers' memory limit.
  SampleWindow(const PlaneSource& source, int planes)
      : mDims(source.dims()), mSpacing(source.description().spacing()), mPlanes(planes), mPlaneSize(source.planeSize()) {
    checkMemory(source.name(), mPlaneSize * uint64_t(planes) * scalarSize(source.storedType()),
                detail::concat(planes, " planes of ", mDims.x, "x", mDims.y, " samples"));
    mSamples = detail::allocateSamples(source.storedType(), mPlaneSize * size_t(planes));
  }
  /// Reads the next plane of @p source (plane next()) over the oldest one held.
  void load(PlaneSource& source) {
    HYB_CHECK(mNext < mDims.z);
    source.read(1, &mSamples, slot(mNext));
    // A streamed float plane is checked as a volume read whole is (Volume's range must be finite).
    if (const auto* plane = std::get_if<std::vector<float>>(&mSamples)) {
      const float* d = plane->data() + slot(mNext);
      const float* bad = std::find_if(d, d + mPlaneSize, [](float v) { return !std::isfinite(v); });
      if (const size_t i = size_t(bad - d); i < mPlaneSize)
        HYB_THROW(IoError, source.name(), ": sample (", i % size_t(mDims.x), ",", i / size_t(mDims.x), ",", mNext, ") is ", *bad,
                  "; expected finite values");
    }
    ++mNext;
  }
  /// The plane load() reads next: the window holds planes next() − planes … next() − 1.
  int next() const { return mNext; }
  bool holds(int z) const { return z < mNext && z >= mNext - mPlanes && z >= 0; }
  const glm::ivec3& dims() const { return mDims; }
  const glm::dvec3& spacing() const { return mSpacing; }

  /// The samples of plane @p z (held) in their stored type: f(const T*), x fastest then y.
  template <class F>
  decltype(auto) visitPlane(int z, F&& f) const {
    HYB_DCHECK(holds(z));
    return std::visit([&](const auto& s) -> decltype(auto) { return f(s.data() + slot(z)); }, mSamples);
  }
  /// The @p n samples from voxel (i, j, k) on along x, as float (plane k held).
  void readRow(int i, int j, int k, int n, float* out) const {
    visitPlane(k, [&](const auto* d) {
      const auto* row = d + size_t(i) + size_t(mDims.x) * size_t(j);
      for (int x = 0; x < n; ++x) out[x] = float(row[x]);
    });
  }
  /// Volume::gradientAt at voxel (i, j, k): planes k − 1 … k + 1 within the grid must be held.
  glm::vec3 gradientAt(int i, int j, int k) const {
    return std::visit(
        [&](const auto& s) {
          return centralDifferences(glm::ivec3(i, j, k), mDims, mSpacing, [&](int x, int y, int z) {
            HYB_DCHECK(holds(z));
            return float(s[slot(z) + size_t(x) + size_t(mDims.x) * size_t(y)]);
          });
        },
        mSamples);
  }

 private:
  size_t slot(int z) const { return size_t(z % mPlanes) * mPlaneSize; }

  glm::ivec3 mDims;
  glm::dvec3 mSpacing;
  int mPlanes;
  size_t mPlaneSize;
  SampleArray mSamples;
  int mNext = 0;
};

}  // namespace hyb
