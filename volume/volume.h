// A scalar volume on a regular grid: dims, spacing, and samples with x varying fastest.
//
// The grid frame is millimetres with voxel (i,j,k) centred at (i*sx, j*sy, k*sz); the data domain
// is the box spanned by the voxel centres (docs/renderer.md, Conventions). The volume's PatientFrame places that frame
// in the patient (LPS mm). Samples are held in the type they were read in where that type is 8 or
// 16 bits (a CT's Hounsfield units take two bytes a voxel, as on disk), else as float; every value
// converts to float exactly where it is read.
#pragma once

#include <glm/glm.hpp>

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <string>
#include <type_traits>
#include <utility>
#include <variant>
#include <vector>

#include "volume/core/error.h"
#include "volume/patient_frame.h"

namespace hyb {

/// Scalar types a volume file may store.
enum class ScalarType : uint8_t { UInt8, Int8, UInt16, Int16, UInt32, Int32, Float32, Float64 };

/// Bytes of one sample of @p t.
size_t scalarSize(ScalarType t);
/// Canonical lower-case name ("int16", "float32", ...).
const char* scalarName(ScalarType t);
/// Parses a canonical name; returns false when @p name is not one.
bool parseScalarName(const std::string& name, ScalarType* out);

/// Samples as a volume holds them: 8- and 16-bit integers in their own type, all else as float.
using SampleArray = std::variant<std::vector<uint8_t>, std::vector<int8_t>, std::vector<uint16_t>, std::vector<int16_t>, std::vector<float>>;
/// The type @p s holds (UInt8, Int8, UInt16, Int16 or Float32).
ScalarType storedType(const SampleArray& s);
/// Number of samples in @p s.
size_t sampleCount(const SampleArray& s);
/// The type samples of file type @p t are held in given their range [@p lo, @p hi]: 8- and 16-bit
/// types as they are; 32-bit integers in the narrowest 16-bit type that holds the range, else
/// float (exact to 2^24); float64 as float.
ScalarType storageTypeFor(ScalarType t, double lo, double hi);
/// Whether a sample type T holds @p v exactly: an integer within T's range, or any value for float.
template <class T>
bool holdsExactly(double v) {
  if constexpr (std::is_same_v<T, float>) return true;
  else return v >= double(std::numeric_limits<T>::min()) && v <= double(std::numeric_limits<T>::max()) && v == double(int64_t(v));
}

/// Central differences at voxel @p p of a grid of @p dims (data units per mm), one-sided on the
/// grid's faces, zero along an axis of one sample: @p at(i, j, k) reads a sample.
template <class At>
glm::vec3 centralDifferences(const glm::ivec3& p, const glm::ivec3& dims, const glm::dvec3& spacing, const At& at) {
  glm::vec3 g(0.0f);
  for (int a = 0; a < 3; ++a) {
    glm::ivec3 lo = p, hi = p;
    lo[a] = std::max(p[a] - 1, 0);
    hi[a] = std::min(p[a] + 1, dims[a] - 1);
    if (hi[a] > lo[a]) {
      const double v = (double(at(hi.x, hi.y, hi.z)) - double(at(lo.x, lo.y, lo.z))) / (double(hi[a] - lo[a]) * spacing[a]);
      g[a] = float(std::clamp(v, -double(std::numeric_limits<float>::max()), double(std::numeric_limits<float>::max())));
    }
  }
  return g;
}

/// Trilinear sample at @p p (voxel units, voxel centres at integers) of a grid of @p dims read
/// through @p at(i, j, k), clamped to the grid: what Volume::sample computes, for any sample store.
template <class At>
float trilinearSample(const glm::vec3& p, const glm::ivec3& dims, const At& at) {
  const glm::vec3 q = glm::clamp(p, glm::vec3(0.0f), glm::vec3(dims - 1));
  const glm::ivec3 i0 = glm::min(glm::ivec3(q), dims - 1);
  const glm::ivec3 i1 = glm::min(i0 + 1, dims - 1);
  const glm::vec3 t = q - glm::vec3(i0);
  auto lerp = [](float a, float b, float w) { return a + (b - a) * w; };
  const float c00 = lerp(at(i0.x, i0.y, i0.z), at(i1.x, i0.y, i0.z), t.x);
  const float c10 = lerp(at(i0.x, i1.y, i0.z), at(i1.x, i1.y, i0.z), t.x);
  const float c01 = lerp(at(i0.x, i0.y, i1.z), at(i1.x, i0.y, i1.z), t.x);
  const float c11 = lerp(at(i0.x, i1.y, i1.z), at(i1.x, i1.y, i1.z), t.x);
  return lerp(lerp(c00, c10, t.y), lerp(c01, c11, t.y), t.z);
}

/// The voxels' central differences interpolated trilinearly at @p p (Levoy 1988), clamped like
/// trilinearSample: what Volume::sampleGradient computes. Reads voxels i0 − 1 … i0 + 2 per axis.
template <class At>
glm::vec3 trilinearGradient(const glm::vec3& p, const glm::ivec3& dims, const glm::dvec3& spacing, const At& at) {
  const glm::vec3 q = glm::clamp(p, glm::vec3(0.0f), glm::vec3(dims - 1));
  const glm::ivec3 i0 = glm::min(glm::ivec3(q), dims - 1);
  const glm::ivec3 i1 = glm::min(i0 + 1, dims - 1);
  const glm::vec3 t = q - glm::vec3(i0);
  auto g = [&](int c) { return centralDifferences(glm::ivec3(c & 1 ? i1.x : i0.x, c & 2 ? i1.y : i0.y, c & 4 ? i1.z : i0.z), dims, spacing, at); };
  const glm::vec3 c00 = glm::mix(g(0), g(1), t.x), c10 = glm::mix(g(2), g(3), t.x);
  const glm::vec3 c01 = glm::mix(g(4), g(5), t.x), c11 = glm::mix(g(6), g(7), t.x);
  return glm::mix(glm::mix(c00, c10, t.y), glm::mix(c01, c11, t.y), t.z);
}

/// Largest accepted extent along one axis; keeps octree coordinates in 16 bits.
inline constexpr int kMaxDim = 32768;
/// Largest accepted sample count (8 GiB of int16 samples).
inline constexpr uint64_t kMaxVoxels = uint64_t(1) << 32;

/// Checks dims for positivity, the per-axis limit and overflow of the sample count.
/// @throw ValueError naming @p what (a file or flag) with the offending dims.
void validateDims(const glm::ivec3& dims, const std::string& what);
/// Smallest and largest accepted spacing, mm: a nanometre to a kilometre.
inline constexpr double kMinSpacingMm = 1e-6;
inline constexpr double kMaxSpacingMm = 1e6;
/// Checks spacing for finite positive values within [kMinSpacingMm, kMaxSpacingMm].
/// @throw ValueError naming @p what.
void validateSpacing(const glm::dvec3& spacing, const std::string& what);

/// A volume's grid and sample types: what Volume::borrowing and Volume::withoutSamples check and
/// keep besides the samples.
struct SampleLayout {
  glm::ivec3 dims{0};                         ///< samples per axis
  glm::dvec3 spacing{1.0};                    ///< mm between neighbouring voxel centres, per axis
  ScalarType sourceType = ScalarType::Float32;  ///< the samples' type in the file they came from
  ScalarType storedType = ScalarType::Float32;  ///< the type they are held in
};

/// Immutable scalar volume.
class Volume {
 public:
  Volume() = default;
  /// Takes ownership of @p samples (x fastest, then y, then z), held in their own type.
  /// @throw ValueError when dims/spacing are invalid, the sample count does not match, or a sample
  ///        is NaN or infinite; the message starts with @p source (file name or description).
  Volume(glm::ivec3 dims, glm::dvec3 spacing, ScalarType sourceType, SampleArray samples, const std::string& source = "volume");
  /// Float samples (analytic volumes), held as float.
  Volume(glm::ivec3 dims, glm::dvec3 spacing, ScalarType sourceType, std::vector<float> samples,
         const std::string& source = "volume")
      : Volume(dims, spacing, sourceType, SampleArray(std::move(samples)), source) {}

  /// Borrows @p data (the volume's samples of @p layout's storedType, one of the SampleArray
  /// types, x fastest) without copying them: @p owner keeps them alive and unchanged as long as
  /// this volume and its copies (a numpy array a Python scene holds). Checked as the constructor
  /// checks them.
  /// @throw ValueError as the constructor, or for a stored type no SampleArray holds.
  static Volume borrowing(const SampleLayout& layout, const void* data, std::shared_ptr<const void> owner,
                          const std::string& source = "volume");

  /// A volume whose samples are not in memory (a scene read through its knot store): its grid,
  /// types and range only. Reading a sample before attachSamples() is a caller error.
  /// @throw ValueError as the constructor, or for a range that is not finite.
  static Volume withoutSamples(const SampleLayout& layout, float minValue, float maxValue, const std::string& source = "volume");
  /// This volume without samples with the range [@p minValue, @p maxValue] (a streamed volume's,
  /// known once its samples were read), checked as the constructor checks it. Requires !hasSamples().
  /// @throw ValueError naming @p source.
  Volume withRange(float minValue, float maxValue, const std::string& source) const;
  /// Whether the samples are in memory.
  bool hasSamples() const { return mData != nullptr; }
  /// Gives a volume made withoutSamples() its samples.
  /// @throw ValueError naming @p source when their count, type or range differs from the volume's.
  void attachSamples(SampleArray samples, const std::string& source);

  /// Samples per axis.
  const glm::ivec3& dims() const { return mDims; }
  /// Millimetres between neighbouring voxel centres, per axis.
  const glm::dvec3& spacing() const { return mSpacing; }
  /// Type the samples had in the file they came from.
  ScalarType sourceType() const { return mSourceType; }
  /// Type the samples are held in (storedType of samples()).
  ScalarType storedType() const { return mStored; }
  /// Grid and types together (what withoutSamples() takes).
  SampleLayout layout() const { return {mDims, mSpacing, mSourceType, mStored}; }
  /// Number of samples.
  size_t voxelCount() const { return mCount; }
  /// Bytes the samples occupy in the source type (the size users know the data by).
  size_t sourceBytes() const { return voxelCount() * scalarSize(mSourceType); }
  /// Bytes held in memory by this object.
  size_t bytesUsed() const { return (hasSamples() ? mCount * scalarSize(mStored) : 0) + sizeof(*this); }
  /// Smallest and largest sample.
  float minValue() const { return mMin; }
  float maxValue() const { return mMax; }
  /// All samples, x fastest, in the stored type (shared by copies of this volume). Not of a
  /// borrowing volume (visitSamples reads either).
  const SampleArray& samples() const {
    HYB_CHECK(mSamples != nullptr);
    return *mSamples;
  }
  /// Calls @p f with a pointer to the samples in their stored type (const T*, T one of the
  /// SampleArray types): a loop over many samples converts each where it reads it.
  template <class F>
  decltype(auto) visitSamples(F&& f) const {
    switch (mStored) {
      case ScalarType::UInt8: return f(static_cast<const uint8_t*>(mData));
      case ScalarType::Int8: return f(static_cast<const int8_t*>(mData));
      case ScalarType::UInt16: return f(static_cast<const uint16_t*>(mData));
      case ScalarType::Int16: return f(static_cast<const int16_t*>(mData));
      default: return f(static_cast<const float*>(mData));
    }
  }
  bool empty() const { return mCount == 0; }

  /// Linear index of voxel (i,j,k); no bounds check beyond a debug assertion.
  size_t index(int i, int j, int k) const {
    HYB_DCHECK(i >= 0 && j >= 0 && k >= 0 && i < mDims.x && j < mDims.y && k < mDims.z);
    return size_t(i) + size_t(mDims.x) * (size_t(j) + size_t(mDims.y) * size_t(k));
  }
  /// Sample number @p n (x fastest) as float, exactly.
  float value(size_t n) const {
    HYB_DCHECK(n < mCount);
    switch (mStored) {
      case ScalarType::UInt8: return static_cast<const uint8_t*>(mData)[n];
      case ScalarType::Int8: return static_cast<const int8_t*>(mData)[n];
      case ScalarType::UInt16: return static_cast<const uint16_t*>(mData)[n];
      case ScalarType::Int16: return static_cast<const int16_t*>(mData)[n];
      default: return static_cast<const float*>(mData)[n];
    }
  }
  /// Sample at voxel (i,j,k), which must be inside the grid.
  float at(int i, int j, int k) const { return value(index(i, j, k)); }
  /// The @p n samples from voxel (i,j,k) on along x, as float, into @p out.
  void readRow(int i, int j, int k, int n, float* out) const;
  /// Sample at voxel (i,j,k) with indices clamped to the grid (the logical padding of the octree).
  float atClamped(int i, int j, int k) const {
    return at(clampIndex(i, mDims.x), clampIndex(j, mDims.y), clampIndex(k, mDims.z));
  }
  /// Trilinear sample at a position in voxel units (voxel centres at integers), clamped to the grid.
  float sample(const glm::vec3& p) const;
  /// Gradient at voxel (i,j,k) in data units per mm: central differences, one-sided on the grid's
  /// faces, zero along an axis of one sample.
  glm::vec3 gradientAt(int i, int j, int k) const;
  /// Gradient at a position in voxel units: the voxel gradients interpolated trilinearly (Levoy
  /// 1988), clamped to the grid like sample().
  glm::vec3 sampleGradient(const glm::vec3& p) const;

  /// Grid-frame (mm) extent of the data domain: the box spanned by the voxel centres.
  glm::dvec3 extentMm() const { return glm::dvec3(mDims - 1) * mSpacing; }

  /// Where the grid lies in the patient (identity when the file does not say).
  const PatientFrame& frame() const { return mFrame; }
  void setFrame(const PatientFrame& frame) { mFrame = frame; }
  /// What the file says of the acquisition, in reading order (e.g. "modality" -> "CT").
  const std::vector<std::pair<std::string, std::string>>& info() const { return mInfo; }
  void addInfo(const std::string& key, const std::string& value) { mInfo.emplace_back(key, value); }
  /// The value of info @p key, or "".
  std::string infoValue(const std::string& key) const;
  /// What the reader had to assume or could not use, one sentence each (e.g. a file without
  /// orientation read as RAS); the command line prints them as warnings.
  const std::vector<std::string>& warnings() const { return mWarnings; }
  void addWarning(const std::string& warning) { mWarnings.push_back(warning); }

  /// Multi-line description: dims, spacing, type, range, patient frame.
  std::string toString() const;

 private:
  static int clampIndex(int i, int n) { return i < 0 ? 0 : (i >= n ? n - 1 : i); }

  glm::ivec3 mDims{0};
  glm::dvec3 mSpacing{1.0};
  ScalarType mSourceType = ScalarType::Float32;
  /// Checks the samples at mData (count, finite values) and sets the range.
  void scanSamples(const std::string& source);

  std::shared_ptr<const SampleArray> mSamples;  // immutable, so copies share it; none when borrowing
  std::shared_ptr<const void> mOwner;           // what keeps borrowed samples alive
  ScalarType mStored = ScalarType::Float32;
  const void* mData = nullptr;  // the samples (mSamples' or borrowed), for value()'s switch
  size_t mCount = 0;
  float mMin = 0.0f;
  float mMax = 0.0f;
  PatientFrame mFrame;
  std::vector<std::pair<std::string, std::string>> mInfo;
  std::vector<std::string> mWarnings;
};

/// @p v with one sample of @p value added on each of its six faces, placed so that every old
/// sample keeps its patient position (the frame's origin moves one voxel back along each axis).
/// An isosurface of the padded volume at an isovalue above @p value is closed.
Volume paddedVolume(const Volume& v, float value);

/// @p v averaged over blocks of @p factor voxels, held as float, each average at its block's centre
/// in the patient: the same anatomy on a coarser grid (a preview of a study). A block cut short at
/// the far faces averages the voxels it has and stands where a whole block's centre would.
/// @throw ValueError for a factor below 1.
Volume boxAveraged(const Volume& v, const glm::ivec3& factor);

/// Value histogram with summary statistics, for `hybrid-octree info`.
struct Histogram {
  double minValue = 0, maxValue = 0, mean = 0, stddev = 0;
  double p01 = 0, p50 = 0, p99 = 0;  ///< 1st, 50th and 99th percentiles: samples of the volume (nearest rank)
  std::vector<uint64_t> counts;      ///< equal-width bins over [minValue, maxValue]
};

/// Histogram of @p v with @p bins equal-width bins (bins >= 1).
Histogram computeHistogram(const Volume& v, int bins);
/// Passes a set of values, in pieces, to the function it is given; called as often as needed.
using ValuePieces = std::function<void(const std::function<void(const float* values, size_t n)>&)>;
/// Histogram of the @p count values in [@p lo, @p hi] that @p pieces passes (once, or twice for
/// percentiles between distinct values closer than 1/65536 of the range), with @p bins
/// equal-width bins (bins >= 1): a volume whose samples are read a piece at a time (a scene's store).
Histogram computeHistogram(uint64_t count, float lo, float hi, int bins, const ValuePieces& pieces);

/// Text report of a histogram, one line per bin with a proportional bar.
std::string formatHistogram(const Histogram& h);

}  // namespace hyb
