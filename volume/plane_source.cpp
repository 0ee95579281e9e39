#include "volume/plane_source.h"

#include <zlib.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>

#include "volume/core/file_util.h"
#include "volume/inflate.h"
#include "volume/reader_util.h"
#include "volume/text_reader.h"

namespace hyb {

namespace {

// @p v without its samples, its range unknown.
Volume describe(const Volume& v) {
  return detail::placedAs(Volume::withoutSamples(v.layout(), 0.0f, 0.0f, "volume"), v);
}

// The planes of a volume in memory, copied out in its own type.
class MemoryPlanes final : public PlaneSource {
 public:
  MemoryPlanes(const Volume& v, std::string name, std::shared_ptr<const Volume> owned = nullptr)
      : PlaneSource(describe(v), std::move(name)),
        mVolume(v),
        mOwned(std::move(owned)) {}
  bool whole() const override { return true; }
  void rewind() override { mNext = 0; }
  void read(int count, SampleArray* out, size_t first) override {
    const size_t n = size_t(count) * planeSize();
    HYB_CHECK(mNext + n <= mVolume.voxelCount() && first + n <= sampleCount(*out));
    mVolume.visitSamples([&](const auto* from) {
      using T = std::remove_cv_t<std::remove_pointer_t<decltype(from)>>;
      std::copy_n(from + mNext, n, std::get<std::vector<T>>(*out).data() + first);
    });
    mNext += n;
  }

 private:
  const Volume& mVolume;
  std::shared_ptr<const Volume> mOwned;  // a volume read whole for this source
  size_t mNext = 0;
};

// Planes decoded from a file's raw or deflated bytes, a bounded piece at a time.
class StreamedPlanes final : public PlaneSource {
 public:
  StreamedPlanes(const detail::SampleData& data, Volume description, const std::string& path)
      : PlaneSource(std::move(description), path), mFile(data.path), mData(data) {
    const glm::ivec3 n = dims();
    mExpected = detail::expectedBytes(n, data.type);
    const uint64_t present = mFile.size() - std::min(data.offset, mFile.size());
    if (data.compressed) {
      if (data.skip < 0) HYB_THROW(IoError, mFile.path(), ": byte skip ", data.skip, " invalid for compressed data (expected 0 or more)");
      const uint64_t total = mExpected + uint64_t(data.skip);
      if (detail::maxInflatedBytes(present) < total)
        HYB_THROW(IoError, mFile.path(), ": ", present, " bytes of compressed data cannot hold the ", total, " bytes of ",
                  detail::layoutName(n, data.type), " samples the header declares (expected at least ",
                  (total - 1024) / detail::kMaxDeflateRatio, " bytes: deflate inflates at most ", detail::kMaxDeflateRatio, ":1)");
      mStart = data.offset;
      if (inflateInit2(&mZ, 15 + 32) != Z_OK) HYB_THROW(RuntimeError, mFile.path(), ": zlib initialisation failed");
      mInflating = true;
    } else {
      uint64_t offset = data.offset;
      if (data.skip == -1) {
        if (present < mExpected) detail::checkByteCount(mFile.path(), mExpected, present, n, data.type);
        offset = mFile.size() - mExpected;
      } else if (data.skip < 0 || uint64_t(data.skip) > present) {
        HYB_THROW(IoError, mFile.path(), ": ", data.skipField, " ", data.skip, " invalid for the ", present, " bytes of data (expected 0 to ",
                  present, ", or -1)");
      } else {
        offset += uint64_t(data.skip);
      }
      detail::checkByteCount(mFile.path(), mExpected, mFile.size() - offset, n, data.type);
      mStart = offset;
    }
    try {
      rewind();  // (a compressed stream's skip is inflated here: it may be cut short)
    } catch (...) {
      if (mInflating) inflateEnd(&mZ);  // no destructor runs for a constructor that throws
      throw;
    }
  }
  ~StreamedPlanes() override {
    if (mInflating) inflateEnd(&mZ);
  }

  void rewind() override {
    mDone = 0;
    mIn = mStart;
    if (!mInflating) return;
    inflateReset(&mZ);
    mZ.avail_in = 0;
    std::vector<uint8_t> skipped(size_t(std::min<long long>(mData.skip, 1 << 20)));
    for (uint64_t left = uint64_t(mData.skip); left > 0;) {
      const size_t n = size_t(std::min<uint64_t>(left, skipped.size()));
      inflateInto(skipped.data(), n);
      left -= n;
    }
  }

  void read(int count, SampleArray* out, size_t first) override {
    const size_t size = scalarSize(mData.type);
    const uint64_t bytes = uint64_t(count) * planeSize() * size;
    HYB_CHECK(mDone + bytes <= mExpected);
    constexpr uint64_t kPiece = uint64_t(16) << 20;  // a multiple of every sample size
    for (uint64_t done = 0; done < bytes; done += kPiece) {
      mPiece.resize(size_t(std::min(kPiece, bytes - done)));
      if (mInflating) {
        inflateInto(mPiece.data(), mPiece.size());
      } else {
        mFile.read(mIn, mPiece.size(), mPiece.data());
        mIn += mPiece.size();
      }
      detail::decodeInto(mPiece.data(), mPiece.size() / size, mData.type, mData.bigEndian, out, first + size_t(done / size));
    }
    if (auto* f = std::get_if<std::vector<float>>(out))  // float data: the checks a Volume makes of its samples
      for (size_t i = first; i < first + size_t(bytes / size); ++i)
        if (!std::isfinite((*f)[i])) {
          const uint64_t at = mDone / size + (i - first), nx = uint64_t(dims().x), ny = uint64_t(dims().y);
          HYB_THROW(ValueError, name(), ": sample (", at % nx, ",", at / nx % ny, ",", at / (nx * ny), ") is ", (*f)[i],
                    "; expected finite values");
        }
    mDone += bytes;
    if (mInflating && mDone == mExpected) checkStreamEnds();
  }

 private:
  // Inflates exactly @p n more bytes into @p to.
  void inflateInto(uint8_t* to, size_t n) {
    mZ.next_out = to;
    mZ.avail_out = uInt(n);
    while (mZ.avail_out > 0) {
      if (mZ.avail_in == 0) refill();
      const uint64_t before = mZ.avail_out;
      const int rc = inflate(&mZ, Z_NO_FLUSH);
      if (rc == Z_STREAM_END) {
        if (mZ.avail_in == 0) refill();
        if (mZ.avail_in == 0 && mZ.avail_out > 0) truncated(n - mZ.avail_out);
        inflateReset(&mZ);  // another gzip member may follow (concatenated streams)
        continue;
      }
      if (rc == Z_BUF_ERROR && mZ.avail_in == 0 && before == mZ.avail_out) truncated(n - mZ.avail_out);
      if (rc != Z_OK && rc != Z_BUF_ERROR)
        HYB_THROW(IoError, mFile.path(), ": corrupt compressed data (", mZ.msg ? mZ.msg : "unknown error", ") after ",
                  mDone + n - mZ.avail_out, " bytes (expected ", mExpected, ")");
    }
  }
  void refill() {
    const uint64_t left = mFile.size() - mIn;
    mCompressed.resize(size_t(std::min<uint64_t>(left, 1 << 20)));
    if (!mCompressed.empty()) mFile.read(mIn, mCompressed.size(), mCompressed.data());
    mIn += mCompressed.size();
    mZ.next_in = mCompressed.data();
    mZ.avail_in = uInt(mCompressed.size());
  }
  [[noreturn]] void truncated(uint64_t got) {
    HYB_THROW(IoError, mFile.path(), " (compressed data): truncated compressed data: stream ends after ", uint64_t(mData.skip) + mDone + got,
              " bytes (expected the ", mExpected + uint64_t(mData.skip), " bytes the header declares)");
  }
  // After the last plane: the stream must end there, as the whole-file reader requires.
  void checkStreamEnds() {
    uint8_t spill;
    mZ.next_out = &spill;
    mZ.avail_out = 1;
    for (;;) {
      if (mZ.avail_in == 0) refill();
      if (mZ.avail_in == 0) return;
      const int rc = inflate(&mZ, Z_NO_FLUSH);
      if (mZ.avail_out == 0)
        HYB_THROW(IoError, mFile.path(), " (compressed data): compressed data inflates past the ", mExpected + uint64_t(mData.skip),
                  " bytes the header declares (expected exactly ", mExpected + uint64_t(mData.skip), ")");
      if (rc == Z_STREAM_END || rc != Z_OK) return;  // trailing garbage after the stream is not samples
    }
  }

  InputFile mFile;
  detail::SampleData mData;
  uint64_t mExpected = 0, mStart = 0, mIn = 0, mDone = 0;
  bool mInflating = false;
  z_stream mZ{};
  std::vector<uint8_t> mPiece, mCompressed;
};

}  // namespace

std::unique_ptr<PlaneSource> planesOf(const Volume& volume) { return std::make_unique<MemoryPlanes>(volume, "volume"); }

namespace detail {

SampleArray readSampleData(const SampleData& d, const glm::ivec3& dims) {
  const InputFile file(d.path);
  return d.compressed ? readCompressedSamples(file, d.offset, d.skip, dims, d.type, d.bigEndian)
                      : readRawSamples(file, {d.offset, d.skip, d.skipField}, dims, d.type, d.bigEndian);
}

std::unique_ptr<PlaneSource> streamedPlanes(const SampleData& data, Volume description, const std::string& path) {
  return std::make_unique<StreamedPlanes>(data, std::move(description), path);
}

}  // namespace detail

std::unique_ptr<PlaneSource> openPlanes(const std::string& path, const RawLayout* raw, const std::string& series, const Progress* progress) {
  if (std::unique_ptr<PlaneSource> s = detail::openStreamedPlanes(path, raw, series, progress)) return s;
  auto v = std::make_shared<const Volume>(readVolume(path, raw, series, progress));
  const Volume& volume = *v;
  return std::make_unique<MemoryPlanes>(volume, path, std::move(v));
}

}  // namespace hyb
