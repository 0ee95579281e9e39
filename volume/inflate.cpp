#include "volume/inflate.h"

#include <zlib.h>

#include <algorithm>
#include <memory>

#include "volume/core/error.h"
#include "volume/core/memory_limit.h"

namespace hyb::detail {

namespace {

// Feeds zlib at most 4 GiB of input at a time (avail_in is 32-bit).
void feed(z_stream* z, const uint8_t** next, size_t* left) {
  const size_t chunk = std::min<size_t>(*left, UINT32_MAX);
  z->next_in = const_cast<uint8_t*>(*next);
  z->avail_in = static_cast<uInt>(chunk);
  *next += chunk;
  *left -= chunk;
}

}  // namespace

std::vector<uint8_t> inflateExactly(const uint8_t* data, size_t size, uint64_t expected, const std::string& file) {
  if (maxInflatedBytes(size) < expected)
    HYB_THROW(IoError, file, ": ", size, " bytes of compressed data cannot hold the ", expected, " bytes the header declares (expected at least ",
              (expected - 1024) / kMaxDeflateRatio, " compressed bytes: deflate inflates at most ", kMaxDeflateRatio, ":1)");
  checkMemory(file, expected, "its decompressed data");
  z_stream z{};
  if (inflateInit2(&z, 15 + 32) != Z_OK) HYB_THROW(RuntimeError, file, ": zlib initialisation failed");
  const std::unique_ptr<z_stream, int (*)(z_stream*)> guard(&z, inflateEnd);
  const uint8_t* next = data;
  size_t left = size;
  feed(&z, &next, &left);
  // Grow with the stream, not with the claim: a stream that stops short allocates what it holds.
  std::vector<uint8_t> out(size_t(std::min<uint64_t>(expected, uint64_t(1) << 20)));
  uint64_t produced = 0;
  for (;;) {
    if (produced == out.size() && out.size() < expected) out.resize(size_t(std::min<uint64_t>(expected, uint64_t(out.size()) * 2)));
    uint8_t spill;  // one byte past the claim proves the stream is longer than declared
    const bool full = produced == expected;
    z.next_out = full ? &spill : out.data() + produced;
    z.avail_out = full ? 1u : static_cast<uInt>(std::min<uint64_t>(out.size() - produced, UINT32_MAX));
    const uInt before = z.avail_out;
    const int rc = inflate(&z, Z_NO_FLUSH);
    const uInt made = before - z.avail_out;
    if (full && made > 0)
      HYB_THROW(IoError, file, ": compressed data inflates past the ", expected, " bytes the header declares (expected exactly ", expected, ")");
    produced += made;
    if (rc == Z_STREAM_END) {
      // Another gzip member may follow (concatenated streams).
      if (z.avail_in == 0 && left > 0) feed(&z, &next, &left);
      if (z.avail_in == 0 || produced == expected) break;
      if (inflateReset(&z) != Z_OK) HYB_THROW(IoError, file, ": corrupt compressed data after byte ", produced);
      continue;
    }
    if (rc == Z_BUF_ERROR && z.avail_in == 0 && left > 0) {
      feed(&z, &next, &left);
      continue;
    }
    if (rc == Z_BUF_ERROR && z.avail_in == 0)
      HYB_THROW(IoError, file, ": truncated compressed data: stream ends after ", produced, " bytes (expected the ", expected,
                " bytes the header declares)");
    if (rc != Z_OK && rc != Z_BUF_ERROR)
      HYB_THROW(IoError, file, ": corrupt compressed data (", z.msg ? z.msg : "unknown error", ") after ", produced, " bytes (expected ",
                expected, ")");
  }
  if (produced < expected)
    HYB_THROW(IoError, file, ": compressed data stops short after ", produced, " bytes (expected the ", expected, " bytes the header declares)");
  return out;
}

}  // namespace hyb::detail
