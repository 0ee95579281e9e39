#include "volume/text_reader.h"

#include <cctype>
#include <cstdlib>

#include "volume/core/memory_limit.h"
#include "volume/inflate.h"
#include "volume/reader_util.h"

namespace hyb::detail {

uint64_t expectedBytes(const glm::ivec3& dims, ScalarType t) {
  return uint64_t(dims.x) * uint64_t(dims.y) * uint64_t(dims.z) * scalarSize(t);
}

void checkByteCount(const std::string& file, uint64_t expected, uint64_t actual, const glm::ivec3& dims,
                    ScalarType t) {
  if (actual == expected) return;
  const std::string layout = layoutName(dims, t);
  if (actual < expected)
    HYB_THROW(IoError, file, ": truncated data: expected ", expected, " bytes for ", layout, ", found ", actual);
  HYB_THROW(IoError, file, ": header/data size mismatch: expected ", expected, " bytes for ", layout, ", found ",
            actual);
}

std::string layoutName(const glm::ivec3& dims, ScalarType t) {
  return detail::concat(dims.x, "x", dims.y, "x", dims.z, " ", scalarName(t));
}

void checkSampleMemory(const std::string& file, uint64_t extra, const glm::ivec3& dims, ScalarType t) {
  const uint64_t count = uint64_t(dims.x) * uint64_t(dims.y) * uint64_t(dims.z);
  const uint64_t held = scalarSize(t) <= 2 ? scalarSize(t) : sizeof(float);  // what a Volume holds a sample in, at most
  checkMemory(file, extra + count * held, layoutName(dims, t) + " samples");
}

SampleArray readRawSamples(const InputFile& f, const RawStart& start, const glm::ivec3& dims, ScalarType t, bool bigEndian) {
  uint64_t offset = start.offset;
  const long long skip = start.skip;
  const char* const field = start.field;
  const uint64_t expected = expectedBytes(dims, t);
  const uint64_t present = f.size() - std::min(offset, f.size());
  if (skip == -1) {
    if (present < expected) checkByteCount(f.path(), expected, present, dims, t);
    offset = f.size() - expected;
  } else if (skip < 0 || uint64_t(skip) > present) {
    HYB_THROW(IoError, f.path(), ": ", field, " ", skip, " invalid for the ", present, " bytes of data (expected 0 to ", present, ", or -1)");
  } else {
    offset += uint64_t(skip);
  }
  checkByteCount(f.path(), expected, f.size() - offset, dims, t);
  // Read in pieces straight into the samples: a volume never sits in memory twice.
  constexpr uint64_t kPiece = uint64_t(16) << 20;  // a multiple of every sample size
  checkSampleMemory(f.path(), std::min(expected, kPiece), dims, t);
  const uint64_t size = scalarSize(t);
  std::vector<uint8_t> piece;
  return decodePieces(t, bigEndian, size_t(expected / size), [&](const auto& use) {
    for (uint64_t done = 0; done < expected; done += kPiece) {
      piece.resize(size_t(std::min(kPiece, expected - done)));
      f.read(offset + done, piece.size(), piece.data());
      use(piece.data(), size_t(done / size), piece.size() / size_t(size));
    }
  });
}

SampleArray readCompressedSamples(const InputFile& f, uint64_t offset, long long skip, const glm::ivec3& dims, ScalarType t,
                                         bool bigEndian) {
  if (skip < 0) HYB_THROW(IoError, f.path(), ": byte skip ", skip, " invalid for compressed data (expected 0 or more)");
  const uint64_t expected = expectedBytes(dims, t), total = expected + uint64_t(skip);
  const uint64_t compressed = f.size() - std::min(offset, f.size());
  if (detail::maxInflatedBytes(compressed) < total)
    HYB_THROW(IoError, f.path(), ": ", compressed, " bytes of compressed data cannot hold the ", total, " bytes of ", layoutName(dims, t),
              " samples the header declares (expected at least ", (total - 1024) / detail::kMaxDeflateRatio,
              " bytes: deflate inflates at most ", detail::kMaxDeflateRatio, ":1)");
  checkSampleMemory(f.path(), compressed + total, dims, t);
  const std::vector<uint8_t> packed = f.bytes(offset, compressed);
  const std::vector<uint8_t> raw = detail::inflateExactly(packed.data(), packed.size(), total, f.path() + " (compressed data)");
  return decodeSamples(raw.data() + skip, size_t(expected / scalarSize(t)), t, bigEndian);
}

SampleArray readAsciiSamples(const InputFile& f, uint64_t offset, const glm::ivec3& dims, ScalarType t) {
  const uint64_t count = uint64_t(dims.x) * uint64_t(dims.y) * uint64_t(dims.z);
  const uint64_t present = f.size() - std::min(offset, f.size());
  if (present < 2 * count - 1)  // a digit each, separated
    HYB_THROW(IoError, f.path(), ": truncated ASCII data: ", present, " bytes cannot hold the ", count, " samples of ", layoutName(dims, t),
              " (expected at least ", 2 * count - 1, " bytes)");
  checkSampleMemory(f.path(), present, dims, t);
  const std::vector<uint8_t> text = f.bytes(offset, present);
  const char* p = reinterpret_cast<const char*>(text.data());
  const char* end = p + text.size();
  std::vector<float> out;
  out.reserve(size_t(count));
  auto separator = [](char c) { return std::isspace(static_cast<unsigned char>(c)) || c == ','; };
  while (p < end) {
    while (p < end && separator(*p)) ++p;
    if (p >= end) break;
    const std::string token(p, std::find_if(p, end, separator));
    char* next = nullptr;
    const double v = std::strtod(token.c_str(), &next);
    if (next == token.c_str() || *next) HYB_THROW(IoError, f.path(), ": expected a number in ASCII data, found ", quotedExcerpt(token));
    if (out.size() == count) HYB_THROW(IoError, f.path(), ": ASCII data holds more than the ", count, " samples the header declares");
    out.push_back(float(v));
    p += token.size();
  }
  if (out.size() != count) HYB_THROW(IoError, f.path(), ": ASCII data holds ", out.size(), " samples, expected ", count);
  return samplesOfType(std::move(out), t);
}

uint64_t skipLines(const InputFile& f, uint64_t offset, long long lines) {
  uint8_t buf[1 << 16];
  for (long long l = 0; l < lines;) {
    if (offset >= f.size()) HYB_THROW(IoError, f.path(), ": cannot skip ", lines, " lines (file too short)");
    const uint64_t n = std::min<uint64_t>(sizeof buf, f.size() - offset);
    f.read(offset, n, buf);
    uint64_t i = 0;
    for (; i < n && l < lines; ++i)
      if (buf[i] == '\n') ++l;
    offset += i;
  }
  return offset;
}

glm::ivec3 parseDims(const std::string& text, const char* field, const std::string& path) {
  long long sizes[3];
  if (!parseNumbers(text, 3, sizes))
    HYB_THROW(IoError, path, ": ", field, " ", quotedExcerpt(text), " malformed (expected three integers)");
  for (long long s : sizes)
    if (s <= 0 || s > kMaxDim) HYB_THROW(IoError, path, ": ", field, " ", quotedExcerpt(text), " invalid (expected 1..", kMaxDim, " per axis)");
  const glm::ivec3 dims{int(sizes[0]), int(sizes[1]), int(sizes[2])};
  validateDims(dims, path);
  return dims;
}

}  // namespace hyb::detail
