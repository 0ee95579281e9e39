// The packed Volume Octree node and its child-index arithmetic (OpenVDB-style child slots).
#pragma once

#include <glm/glm.hpp>

#include <array>
#include <bit>
#include <cstdint>

namespace hyb {

/// Set bits of each 8-bit child mask: a table read, since Debian's baseline x86-64 has no popcnt
/// instruction and std::popcount became a libgcc call (8 % of a small ray-traced frame's time,
/// in the descents of empty-space skipping).
inline constexpr auto kChildMaskBits = [] {
  std::array<uint8_t, 256> t{};
  for (int m = 0; m < 256; ++m) t[size_t(m)] = uint8_t(std::popcount(unsigned(m)));
  return t;
}();

/// One node of the flattened Volume Octree. Nodes live in one array in breadth-first order; the
/// existing children of a node are contiguous, in slot order, starting at firstChild.
struct OctreeNode {
  float minValue = 0;        ///< smallest sample in the node's closed box [origin, origin+edge] ∩ grid
  float maxValue = 0;        ///< largest sample in the same box
  uint32_t firstChild = 0;   ///< index of the first existing child; meaningless when childMask == 0
  uint32_t errorOffset = 0;  ///< index of ε_0 in the octree's flat error array
  glm::u16vec3 origin{0};    ///< voxel index of the node's minimum corner
  uint8_t level = 0;         ///< 0 at the root
  uint8_t childMask = 0;     ///< bit s set when child slot s exists (slot bits: x | y<<1 | z<<2)

  bool isLeaf() const { return childMask == 0; }
  int childCount() const { return kChildMaskBits[childMask]; }
};
static_assert(sizeof(OctreeNode) == 24, "OctreeNode is meant to pack into 24 bytes");

/// Child slot of voxel position @p p below a node whose children have edge 2^@p shift.
inline int childSlot(const glm::ivec3& p, int shift) {
  return ((p.x >> shift) & 1) | (((p.y >> shift) & 1) << 1) | (((p.z >> shift) & 1) << 2);
}

/// Array index of child @p slot of @p n, which must exist.
inline uint32_t childIndex(const OctreeNode& n, int slot) {
  return n.firstChild + uint32_t(kChildMaskBits[n.childMask & ((1u << slot) - 1u)]);
}

/// Offset of child @p slot's origin from its parent's, for children of edge @p childEdge.
inline glm::ivec3 childOffset(int slot, int childEdge) {
  return glm::ivec3(slot & 1, (slot >> 1) & 1, (slot >> 2) & 1) * childEdge;
}

/// Morton (Z-order) code of a grid point with coordinates in [0, 2^21): the bits of x, y and z
/// interleaved, x lowest. Points sorted by it put every aligned power-of-two box contiguously.
inline uint64_t morton(const glm::ivec3& c) {
  auto spread = [](uint64_t v) {
    v &= 0x1fffff;  // 21 bits an axis
    v = (v | (v << 32)) & 0x1f00000000ffffULL;
    v = (v | (v << 16)) & 0x1f0000ff0000ffULL;
    v = (v | (v << 8)) & 0x100f00f00f00f00fULL;
    v = (v | (v << 4)) & 0x10c30c30c30c30c3ULL;
    v = (v | (v << 2)) & 0x1249249249249249ULL;
    return v;
  };
  return spread(uint64_t(c.x)) | spread(uint64_t(c.y)) << 1 | spread(uint64_t(c.z)) << 2;
}

}  // namespace hyb
