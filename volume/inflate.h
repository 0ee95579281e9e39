// Bounded inflation of the gzip and zlib streams volume files carry.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace hyb::detail {

/// Deflate's largest ratio of inflated to compressed bytes (zlib's technical details: 1032:1).
inline constexpr uint64_t kMaxDeflateRatio = 1032;

/// The most bytes a deflate stream of @p compressedBytes can inflate to.
inline uint64_t maxInflatedBytes(uint64_t compressedBytes) { return compressedBytes * kMaxDeflateRatio + 1024; }

/// Inflates the gzip or zlib stream (detected from its header; concatenated gzip members are
/// joined) in @p data to exactly @p expected bytes, the size the file's header declares. Refused
/// before allocating when @p size compressed bytes cannot hold @p expected or @p expected exceeds
/// memoryLimit(); the output grows with what the stream really yields, and inflation stops as
/// soon as it would pass @p expected.
/// @throw IoError naming @p file when the stream is corrupt, stops short or inflates past @p expected.
std::vector<uint8_t> inflateExactly(const uint8_t* data, size_t size, uint64_t expected, const std::string& file);

}  // namespace hyb::detail
