// Helpers of the readers whose samples lie raw, compressed or as text after a header (NRRD,
// MetaImage, raw, InVesalius): sizes checked against the file before anything is allocated.
// Internal to volume/.
#pragma once

#include <glm/glm.hpp>

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <sstream>
#include <string>
#include <vector>

#include "volume/core/file_util.h"
#include "volume/volume.h"

namespace hyb::detail {

// Parses exactly @p n whitespace-separated numbers from @p text.
template <typename T>
bool parseNumbers(const std::string& text, int n, T* out) {
  std::istringstream s(text);
  for (int i = 0; i < n; ++i)
    if (!(s >> out[i])) return false;
  std::string rest;
  return !(s >> rest);
}

// Bytes of the samples of @p dims in type @p t.
uint64_t expectedBytes(const glm::ivec3& dims, ScalarType t);

// Checks that exactly @p expected bytes of samples are present, with messages naming the file.
void checkByteCount(const std::string& file, uint64_t expected, uint64_t actual, const glm::ivec3& dims,
                    ScalarType t);

// "4x3x5 int16", for messages.
std::string layoutName(const glm::ivec3& dims, ScalarType t);

// Checks memory for @p extra bytes of file data held while decoding plus the samples as a Volume holds them.
void checkSampleMemory(const std::string& file, uint64_t extra, const glm::ivec3& dims, ScalarType t);

// Where raw samples start: from byte offset on, skip bytes are skipped first (-1: the samples are
// the file's last bytes); field names the skip in messages.
struct RawStart {
  uint64_t offset = 0;
  long long skip = 0;
  const char* field = "header";
};
// The raw samples of @p f from @p start on; exactly the samples must remain. Sizes are checked
// against the file before anything is allocated.
SampleArray readRawSamples(const InputFile& f, const RawStart& start, const glm::ivec3& dims, ScalarType t, bool bigEndian);

// The samples of the gzip or zlib stream that makes up @p f from byte @p offset on, after
// @p skip decompressed bytes; inflation is capped at what the header declares.
SampleArray readCompressedSamples(const InputFile& f, uint64_t offset, long long skip, const glm::ivec3& dims, ScalarType t,
                                         bool bigEndian);

// Whitespace- or comma-separated ASCII samples of @p f from byte @p offset on.
SampleArray readAsciiSamples(const InputFile& f, uint64_t offset, const glm::ivec3& dims, ScalarType t);

// The offset just past @p lines line ends in @p f from @p offset on (NRRD "line skip").
uint64_t skipLines(const InputFile& f, uint64_t offset, long long lines);

// Longest text header and header line accepted (NRRD, MetaImage): real ones are a few KB.
inline constexpr uint64_t kMaxHeaderBytes = uint64_t(1) << 20;
inline constexpr size_t kMaxHeaderLine = size_t(64) << 10;

// The header lines of @p f up to the line @p last accepts (NRRD: the blank line, dropped;
// MetaImage: ElementDataFile, kept) or the end of the file, with the offset of the data after
// them. '\r' before '\n' is dropped. Read within kMaxHeaderBytes and kMaxHeaderLine.
template <class Last>
std::vector<std::string> readHeaderLines(const InputFile& f, const Last& last, uint64_t* dataOffset) {
  const uint64_t n = std::min(f.size(), kMaxHeaderBytes);
  std::vector<uint8_t> head(static_cast<size_t>(n));
  f.read(0, n, head.data());
  std::vector<std::string> lines;
  size_t pos = 0;
  while (pos < head.size()) {
    const uint8_t* nl = static_cast<const uint8_t*>(std::memchr(head.data() + pos, '\n', head.size() - pos));
    if (!nl && f.size() > n)
      HYB_THROW(IoError, f.path(), ": header is longer than ", kMaxHeaderBytes, " bytes (expected a text header that ends before the data)");
    const size_t end = nl ? size_t(nl - head.data()) : head.size();
    if (end - pos > kMaxHeaderLine)
      HYB_THROW(IoError, f.path(), ": header line ", lines.size() + 1, " is longer than ", kMaxHeaderLine, " bytes (expected a text header)");
    std::string line(reinterpret_cast<const char*>(head.data() + pos), end - pos);
    if (!line.empty() && line.back() == '\r') line.pop_back();
    pos = nl ? end + 1 : end;
    bool keep = true;
    if (last(line, &keep)) {
      if (keep) lines.push_back(std::move(line));
      *dataOffset = pos;
      return lines;
    }
    lines.push_back(std::move(line));
  }
  *dataOffset = f.size();
  return lines;
}

// Three sample counts from header field @p field, each in 1..kMaxDim, with a product in range.
glm::ivec3 parseDims(const std::string& text, const char* field, const std::string& path);

}  // namespace hyb::detail
