#include "volume/volume.h"

#include <algorithm>
#include <functional>
#include <array>
#include <limits>
#include <cmath>
#include <iomanip>
#include <sstream>
#include <type_traits>

namespace hyb {

namespace {

// Differences of samples (nodal errors, gradients, the lookup table's scale) must stay finite.
void checkRange(float lo, float hi, const std::string& source) {
  if (!std::isfinite(hi - lo))
    HYB_THROW(ValueError, source, ": samples span [", lo, ", ", hi, "]; expected a range (max - min) below ",
              std::numeric_limits<float>::max(), " so that differences of samples stay finite");
}

}  // namespace

size_t scalarSize(ScalarType t) {
  switch (t) {
    case ScalarType::UInt8:
    case ScalarType::Int8: return 1;
    case ScalarType::UInt16:
    case ScalarType::Int16: return 2;
    case ScalarType::UInt32:
    case ScalarType::Int32:
    case ScalarType::Float32: return 4;
    case ScalarType::Float64: return 8;
  }
  return 0;
}

namespace {
constexpr const char* kScalarNames[] = {"uint8", "int8", "uint16", "int16", "uint32", "int32", "float32", "float64"};
}

const char* scalarName(ScalarType t) { return kScalarNames[static_cast<int>(t)]; }

bool parseScalarName(const std::string& name, ScalarType* out) {
  for (int i = 0; i < 8; ++i)
    if (name == kScalarNames[i]) {
      *out = static_cast<ScalarType>(i);
      return true;
    }
  return false;
}

void validateDims(const glm::ivec3& dims, const std::string& what) {
  if (dims.x <= 0 || dims.y <= 0 || dims.z <= 0)
    HYB_THROW(ValueError, what, ": dims ", dims.x, "x", dims.y, "x", dims.z, " must all be positive");
  if (dims.x > kMaxDim || dims.y > kMaxDim || dims.z > kMaxDim)
    HYB_THROW(ValueError, what, ": dims ", dims.x, "x", dims.y, "x", dims.z, " exceed the limit of ",
              kMaxDim, " samples per axis");
  const uint64_t n = uint64_t(dims.x) * uint64_t(dims.y) * uint64_t(dims.z);
  if (n > kMaxVoxels)
    HYB_THROW(ValueError, what, ": dims ", dims.x, "x", dims.y, "x", dims.z, " give ", n,
              " samples, more than the limit of ", kMaxVoxels);
}

void validateSpacing(const glm::dvec3& s, const std::string& what) {
  for (int a = 0; a < 3; ++a)
    if (!std::isfinite(s[a]) || s[a] <= 0.0)
      HYB_THROW(ValueError, what, ": spacing ", s.x, ",", s.y, ",", s.z, " must be finite and positive");
  // Positions, gradients and distances divide by the spacing and hold it in float: beyond this
  // range they overflow (a reciprocal of 1e-320 mm is infinite) or lose every digit.
  for (int a = 0; a < 3; ++a)
    if (s[a] < kMinSpacingMm || s[a] > kMaxSpacingMm)
      HYB_THROW(ValueError, what, ": spacing ", s.x, ",", s.y, ",", s.z, " out of range (expected ", kMinSpacingMm, " to ",
                kMaxSpacingMm, " mm per axis, a spacing whose reciprocal is finite in float)");
}

ScalarType storedType(const SampleArray& s) {
  constexpr ScalarType kTypes[] = {ScalarType::UInt8, ScalarType::Int8, ScalarType::UInt16, ScalarType::Int16, ScalarType::Float32};
  return kTypes[s.index()];
}

size_t sampleCount(const SampleArray& s) {
  return std::visit([](const auto& v) { return v.size(); }, s);
}

ScalarType storageTypeFor(ScalarType t, double lo, double hi) {
  switch (t) {
    case ScalarType::UInt32:
    case ScalarType::Int32:
      if (lo >= std::numeric_limits<int16_t>::min() && hi <= std::numeric_limits<int16_t>::max()) return ScalarType::Int16;
      if (lo >= 0 && hi <= std::numeric_limits<uint16_t>::max()) return ScalarType::UInt16;
      return ScalarType::Float32;
    case ScalarType::Float64: return ScalarType::Float32;
    default: return t;
  }
}

Volume::Volume(glm::ivec3 dims, glm::dvec3 spacing, ScalarType sourceType, SampleArray samples, const std::string& source)
    : mDims(dims), mSpacing(spacing), mSourceType(sourceType) {
  validateDims(dims, source);
  validateSpacing(spacing, source);
  const size_t expected = size_t(dims.x) * size_t(dims.y) * size_t(dims.z);
  if (sampleCount(samples) != expected)
    HYB_THROW(ValueError, source, ": expected ", expected, " samples for dims ", dims.x, "x", dims.y, "x", dims.z, ", got ",
              sampleCount(samples));
  mSamples = std::make_shared<const SampleArray>(std::move(samples));
  mStored = hyb::storedType(*mSamples);
  mCount = expected;
  mData = std::visit([](const auto& d) { return static_cast<const void*>(d.data()); }, *mSamples);
  scanSamples(source);
}

Volume Volume::borrowing(const SampleLayout& layout, const void* data, std::shared_ptr<const void> owner, const std::string& source) {
  const ScalarType storedType = layout.storedType;
  if (!(storedType == ScalarType::UInt8 || storedType == ScalarType::Int8 || storedType == ScalarType::UInt16 || storedType == ScalarType::Int16 ||
        storedType == ScalarType::Float32))
    HYB_THROW(ValueError, source, ": samples of type ", scalarName(storedType), " are held as float32 (expected uint8, int8, uint16, int16 or float32 to borrow)");
  HYB_CHECK(data != nullptr);
  Volume v = withoutSamples(layout, 0.0f, 0.0f, source);  // the grid, checked; the range scanned below
  v.mOwner = std::move(owner);
  v.mData = data;
  v.scanSamples(source);
  return v;
}

void Volume::scanSamples(const std::string& source) {
  const size_t expected = mCount;
  const glm::ivec3 dims = mDims;
  float lo = std::numeric_limits<float>::max(), hi = -lo;
  bool finite = true;
  visitSamples([&](const auto* d) {
    using T = std::remove_cv_t<std::remove_pointer_t<decltype(d)>>;
    if constexpr (std::is_integral_v<T>) {
      // Integers are finite, and their own min and max vectorise (a 512³ uint8 coverage: 8× faster).
      T a = std::numeric_limits<T>::max(), b = std::numeric_limits<T>::lowest();
#pragma omp parallel for reduction(min : a) reduction(max : b)
      for (size_t i = 0; i < expected; ++i) {
        a = std::min(a, d[i]);
        b = std::max(b, d[i]);
      }
      lo = float(a);
      hi = float(b);
    } else {
#pragma omp parallel for reduction(min : lo) reduction(max : hi) reduction(&& : finite)
      for (size_t i = 0; i < expected; ++i) {
        const float v = float(d[i]);
        finite = finite && std::isfinite(v);
        lo = std::min(lo, v);
        hi = std::max(hi, v);
      }
    }
  });
  if (!finite) {
    size_t bad = 0;
    while (std::isfinite(value(bad))) ++bad;
    const size_t i = bad % dims.x, j = (bad / dims.x) % dims.y, k = bad / (size_t(dims.x) * dims.y);
    HYB_THROW(ValueError, source, ": sample (", i, ",", j, ",", k, ") is ", value(bad), "; expected finite values");
  }
  checkRange(lo, hi, source);
  mMin = lo;
  mMax = hi;
}

Volume Volume::withoutSamples(const SampleLayout& layout, float minValue, float maxValue, const std::string& source) {
  const glm::ivec3 dims = layout.dims;
  const glm::dvec3 spacing = layout.spacing;
  validateDims(dims, source);
  validateSpacing(spacing, source);
  if (!(std::isfinite(minValue) && std::isfinite(maxValue) && minValue <= maxValue && std::isfinite(maxValue - minValue)))
    HYB_THROW(ValueError, source, ": sample range [", minValue, ", ", maxValue, "] invalid (expected finite min <= max)");
  Volume v;
  v.mDims = dims;
  v.mSpacing = spacing;
  v.mSourceType = layout.sourceType;
  v.mStored = layout.storedType;
  v.mCount = size_t(dims.x) * size_t(dims.y) * size_t(dims.z);
  v.mMin = minValue;
  v.mMax = maxValue;
  return v;
}

Volume Volume::withRange(float minValue, float maxValue, const std::string& source) const {
  HYB_CHECK(!hasSamples() && std::isfinite(minValue) && std::isfinite(maxValue) && minValue <= maxValue);
  checkRange(minValue, maxValue, source);
  Volume v = *this;
  v.mMin = minValue;
  v.mMax = maxValue;
  return v;
}

void Volume::attachSamples(SampleArray samples, const std::string& source) {
  const Volume full(mDims, mSpacing, mSourceType, std::move(samples), source);
  if (full.mStored != mStored || full.mMin != mMin || full.mMax != mMax)
    HYB_THROW(ValueError, source, ": samples of type ", scalarName(full.mStored), " in [", full.mMin, ", ", full.mMax, "] for a volume of type ",
              scalarName(mStored), " in [", mMin, ", ", mMax, "]");
  mSamples = full.mSamples;
  mOwner.reset();
  mData = full.mData;
}

void Volume::readRow(int i, int j, int k, int n, float* out) const {
  HYB_DCHECK(n >= 0 && i + n <= mDims.x);
  const size_t first = index(i, j, k);
  visitSamples([&](const auto* d) {
    for (int x = 0; x < n; ++x) out[x] = float(d[first + size_t(x)]);
  });
}

namespace {

// A typed sample pointer read as float: a call dispatches on the type once, not once a sample.
template <class T>
auto readerOf(const T* d, const glm::ivec3& dims) {
  return [d, dims](int i, int j, int k) { return float(d[size_t(i) + size_t(dims.x) * (size_t(j) + size_t(dims.y) * size_t(k))]); };
}

}  // namespace

float Volume::sample(const glm::vec3& p) const {
  return visitSamples([&](const auto* d) { return trilinearSample(p, mDims, readerOf(d, mDims)); });
}

glm::vec3 Volume::gradientAt(int i, int j, int k) const {
  return visitSamples([&](const auto* d) { return centralDifferences(glm::ivec3(i, j, k), mDims, mSpacing, readerOf(d, mDims)); });
}

glm::vec3 Volume::sampleGradient(const glm::vec3& p) const {
  return visitSamples([&](const auto* d) { return trilinearGradient(p, mDims, mSpacing, readerOf(d, mDims)); });
}

std::string Volume::infoValue(const std::string& key) const {
  for (const auto& [k, v] : mInfo)
    if (k == key) return v;
  return "";
}

std::string Volume::toString() const {
  std::ostringstream s;
  s << "dims     " << mDims.x << " x " << mDims.y << " x " << mDims.z << " (" << voxelCount() << " voxels)\n";
  s << std::setprecision(7) << "spacing  " << mSpacing.x << " x " << mSpacing.y << " x " << mSpacing.z << " mm\n";
  const glm::dvec3 e = extentMm();
  s << "extent   " << e.x << " x " << e.y << " x " << e.z << " mm\n";
  // The samples as held (what memory and the scene store); the file's own pixel type where it differs.
  s << "type     " << scalarName(mStored) << " (" << voxelCount() * scalarSize(mStored) << " bytes"
    << (mSourceType != mStored ? std::string("; the file holds ") + scalarName(mSourceType) : std::string()) << ")\n";
  s << "range    " << mMin << " .. " << mMax << "\n";
  const glm::dvec3 o = mFrame.origin;
  s << "origin   " << o.x << ", " << o.y << ", " << o.z << " mm (LPS: the centre of voxel 0,0,0)\n";
  const glm::dmat3& d = mFrame.direction;
  for (int row = 0; row < 3; ++row) {
    s << (row == 0 ? "direction" : "         ");
    for (int c = 0; c < 3; ++c) s << " " << std::setw(10) << std::fixed << std::setprecision(6) << (d[c][row] == 0.0 ? 0.0 : d[c][row]);
    s << (row == 0 ? "   (columns: the i, j, k axes in LPS)" : "") << "\n";
  }
  s.unsetf(std::ios::floatfield);
  glm::dvec3 lo(1e300), hi(-1e300);
  for (int c = 0; c < 8; ++c) {
    const glm::dvec3 p = mFrame.toPatient(glm::dvec3(c & 1 ? e.x : 0.0, c & 2 ? e.y : 0.0, c & 4 ? e.z : 0.0));
    lo = glm::min(lo, p);
    hi = glm::max(hi, p);
  }
  s << std::setprecision(7) << "bounds   x " << lo.x << " .. " << hi.x << ", y " << lo.y << " .. " << hi.y << ", z " << lo.z << " .. " << hi.z
    << " mm (LPS: x towards the patient's left, y posterior, z superior)\n";
  s << "orient   " << orientationCode(d) << (mFrame.assumed ? " (orientation unknown: the file carries none; the reader's convention)" : "")
    << " (each index increases towards: L/R left/right, P/A posterior/anterior, S/I superior/inferior)\n";
  for (const auto& [k, v] : mInfo) s << std::left << std::setw(8) << k << std::right << " " << v << "\n";
  return s.str();
}

Volume paddedVolume(const Volume& v, float value) {
  const glm::ivec3 d = v.dims() + 2;
  const size_t count = size_t(d.x) * size_t(d.y) * size_t(d.z);
  SampleArray samples = v.visitSamples([&](const auto* src) -> SampleArray {
    using T = std::remove_const_t<std::remove_pointer_t<decltype(src)>>;
    // The padding value in the stored type when it is one of its values, else everything as float.
    const bool fits = holdsExactly<T>(value);
    auto copy = [&](auto pad) {
      using U = decltype(pad);
      std::vector<U> out(count, pad);
      for (int k = 0; k < v.dims().z; ++k)
        for (int j = 0; j < v.dims().y; ++j)
          std::copy_n(src + v.index(0, j, k), size_t(v.dims().x), &out[size_t(1) + size_t(d.x) * (size_t(j + 1) + size_t(d.y) * size_t(k + 1))]);
      return SampleArray(std::move(out));
    };
    return fits ? copy(T(value)) : copy(value);
  });
  Volume out(d, v.spacing(), v.sourceType(), std::move(samples), "padded volume");
  PatientFrame frame = v.frame();
  frame.origin = v.frame().toPatient(-v.spacing());
  out.setFrame(frame);
  return out;
}

Volume boxAveraged(const Volume& v, const glm::ivec3& factor) {
  if (glm::any(glm::lessThan(factor, glm::ivec3(1)))) HYB_THROW(ValueError, "block factor ", factor.x, "x", factor.y, "x", factor.z, " invalid (expected at least 1 per axis)");
  const glm::ivec3 d = (v.dims() + factor - 1) / factor;
  std::vector<float> out(size_t(d.x) * size_t(d.y) * size_t(d.z));
  std::vector<float> row(size_t(v.dims().x));
  std::vector<double> sums(size_t(d.x));
  std::vector<int> counts(size_t(d.x));
  for (int k = 0; k < d.z; ++k)
    for (int j = 0; j < d.y; ++j) {
      std::fill(sums.begin(), sums.end(), 0.0);
      std::fill(counts.begin(), counts.end(), 0);
      for (int z = k * factor.z; z < std::min(v.dims().z, (k + 1) * factor.z); ++z)
        for (int y = j * factor.y; y < std::min(v.dims().y, (j + 1) * factor.y); ++y) {
          v.readRow(0, y, z, v.dims().x, row.data());
          for (int x = 0; x < v.dims().x; ++x) {
            sums[size_t(x / factor.x)] += row[size_t(x)];
            ++counts[size_t(x / factor.x)];
          }
        }
      float* o = &out[size_t(d.x) * (size_t(j) + size_t(d.y) * size_t(k))];
      for (int i = 0; i < d.x; ++i) o[i] = float(sums[size_t(i)] / counts[size_t(i)]);
    }
  Volume result(d, v.spacing() * glm::dvec3(factor), v.sourceType(), std::move(out), "averaged volume");
  PatientFrame frame = v.frame();
  frame.origin = v.frame().toPatient(glm::dvec3(factor - 1) * 0.5 * v.spacing());
  result.setFrame(frame);
  return result;
}

Histogram computeHistogram(uint64_t count, float lo, float hi, int bins, const ValuePieces& pieces) {
  HYB_CHECK(bins >= 1);
  Histogram h;
  h.minValue = lo;
  h.maxValue = hi;
  h.counts.assign(size_t(bins), 0);
  const double width = (h.maxValue - h.minValue) / bins;
  // Exact percentiles (nearest rank: the smallest sample with at least q·n samples at or below it):
  // a fine histogram finds the bin holding the rank, then only that bin's samples are ordered.
  const int fineBins = 1 << 16;
  const double fineWidth = (h.maxValue - h.minValue) / fineBins;
  auto fineBin = [&](float x) { return fineWidth > 0 ? std::min(fineBins - 1, int((x - h.minValue) / fineWidth)) : 0; };
  std::vector<uint64_t> fine(size_t(fineBins), 0);
  std::vector<float> fineLo(size_t(fineBins), std::numeric_limits<float>::max()), fineHi(size_t(fineBins), -std::numeric_limits<float>::max());
  double sum = 0, sum2 = 0;
  pieces([&](const float* values, size_t n) {
    for (size_t i = 0; i < n; ++i) {
      const float x = values[i];
      const int b = width > 0 ? std::min(bins - 1, int((x - h.minValue) / width)) : 0;
      ++h.counts[size_t(b)];
      const size_t f = size_t(fineBin(x));
      ++fine[f];
      fineLo[f] = std::min(fineLo[f], x);
      fineHi[f] = std::max(fineHi[f], x);
      sum += x;
      sum2 += double(x) * x;
    }
  });
  const double n = double(std::max<uint64_t>(1, count));
  h.mean = sum / n;
  h.stddev = std::sqrt(std::max(0.0, sum2 / n - h.mean * h.mean));
  const std::array<double, 3> qs = {0.01, 0.50, 0.99};
  std::array<uint64_t, 3> rank{}, below{};
  std::array<int, 3> bin{};
  std::array<std::vector<float>, 3> in;
  for (size_t k = 0; k < qs.size(); ++k) {
    rank[k] = std::max<uint64_t>(1, uint64_t(std::ceil(qs[k] * double(count))));  // 1-based
    while (below[k] + fine[size_t(bin[k])] < rank[k]) below[k] += fine[size_t(bin[k]++)];
  }
  // A bin of one value (integer samples: every bin) needs no second pass.
  auto single = [&](size_t k) { return fineLo[size_t(bin[k])] == fineHi[size_t(bin[k])]; };
  if (!single(0) || !single(1) || !single(2))
    pieces([&](const float* values, size_t m) {
      for (size_t i = 0; i < m; ++i) {
        const int b = fineBin(values[i]);
        for (size_t k = 0; k < qs.size(); ++k)
          if (b == bin[k] && !single(k)) in[k].push_back(values[i]);
      }
    });
  std::array<double, 3> at{};
  for (size_t k = 0; k < qs.size(); ++k) {
    if (single(k)) {
      at[k] = double(fineLo[size_t(bin[k])]);
      continue;
    }
    std::nth_element(in[k].begin(), in[k].begin() + ptrdiff_t(rank[k] - below[k] - 1), in[k].end());
    at[k] = double(in[k][size_t(rank[k] - below[k] - 1)]);
  }
  h.p01 = at[0];
  h.p50 = at[1];
  h.p99 = at[2];
  return h;
}

Histogram computeHistogram(const Volume& v, int bins) {
  return computeHistogram(v.voxelCount(), v.minValue(), v.maxValue(), bins, [&](const std::function<void(const float*, size_t)>& use) {
    std::vector<float> piece(size_t(std::min<uint64_t>(v.voxelCount(), 1 << 16)));
    for (size_t first = 0; first < v.voxelCount(); first += piece.size()) {
      const size_t n = std::min(piece.size(), v.voxelCount() - first);
      for (size_t i = 0; i < n; ++i) piece[i] = v.value(first + i);
      use(piece.data(), n);
    }
  });
}

std::string formatHistogram(const Histogram& h) {
  std::ostringstream s;
  s << std::fixed << std::setprecision(2) << "mean " << h.mean << "  stddev " << h.stddev << "  p1 " << h.p01
    << "  median " << h.p50 << "  p99 " << h.p99 << "\n";
  const uint64_t peak = std::max<uint64_t>(1, *std::max_element(h.counts.begin(), h.counts.end()));
  const double width = (h.maxValue - h.minValue) / double(h.counts.size());
  for (size_t b = 0; b < h.counts.size(); ++b) {
    const int bar = int(std::lround(40.0 * double(h.counts[b]) / double(peak)));
    s << std::setw(10) << std::setprecision(1) << h.minValue + double(b) * width << " .. " << std::setw(10)
      << h.minValue + double(b + 1) * width << "  " << std::setw(10) << h.counts[b] << "  "
      << std::string(size_t(bar), '#') << "\n";
  }
  return s.str();
}

}  // namespace hyb
