// An open-addressing hash map from 64-bit keys to 32-bit values, for the mesh builders' vertex and
// edge maps: linear probing in a power-of-two table, no allocation per entry (node-based
// std::unordered_map made the Surface Octree's reconstruction twice as slow).
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <vector>

#include <glm/glm.hpp>

#include "volume/core/error.h"

namespace hyb {

/// A key for FlatMap from a grid point whose coordinates lie in [0, 2^21): 21 bits an axis, so
/// distinct points never collide (and the key is never ~0).
inline uint64_t gridKey(const glm::ivec3& p) {
  HYB_DCHECK(p.x >= 0 && p.y >= 0 && p.z >= 0 && p.x < (1 << 21) && p.y < (1 << 21) && p.z < (1 << 21));
  return (uint64_t(p.x) << 42) | (uint64_t(p.y) << 21) | uint64_t(p.z);
}

/// The grid point of gridKey @p key.
inline glm::ivec3 gridPoint(uint64_t key) {
  constexpr uint64_t kMask = (uint64_t(1) << 21) - 1;
  return {int(key >> 42), int((key >> 21) & kMask), int(key & kMask)};
}

/// Map from keys (never ~0) to values. References and pointers into it are invalidated by inserts.
class FlatMap {
 public:
  explicit FlatMap(size_t expected) { rehash(std::max<size_t>(1024, roundUp(2 * expected))); }

  /// The value stored for @p key, or the result of @p make() stored now.
  template <typename Make>
  uint32_t findOrInsert(uint64_t key, Make&& make) {
    Slot& slot = mSlots[probeForInsert(key)];
    if (slot.key == key) return slot.value;
    slot.key = key;
    ++mCount;
    return slot.value = make();
  }
  /// The value of @p key, inserted as 0 when absent.
  uint32_t& operator[](uint64_t key) {
    Slot& slot = mSlots[probeForInsert(key)];
    if (slot.key != key) {
      slot = {key, 0};
      ++mCount;
    }
    return slot.value;
  }
  /// The value of @p key, or nullptr.
  const uint32_t* find(uint64_t key) const {
    for (size_t i = hash(key) & (mSlots.size() - 1); mSlots[i].key != kEmpty; i = (i + 1) & (mSlots.size() - 1))
      if (mSlots[i].key == key) return &mSlots[i].value;
    return nullptr;
  }

 private:
  static constexpr uint64_t kEmpty = ~uint64_t(0);
  static size_t roundUp(size_t n) {
    size_t c = 1;
    while (c < n) c <<= 1;
    return c;
  }
  static size_t hash(uint64_t k) {  // murmur3 finaliser
    k ^= k >> 33;
    k *= 0xff51afd7ed558ccdULL;
    k ^= k >> 33;
    return size_t(k);
  }
  // The slot holding @p key, or the empty slot where it goes (growing first if needed).
  size_t probeForInsert(uint64_t key) {
    HYB_DCHECK(key != kEmpty);
    if (2 * (mCount + 1) > mSlots.size()) rehash(mSlots.size() * 2);
    size_t i = hash(key) & (mSlots.size() - 1);
    while (mSlots[i].key != kEmpty && mSlots[i].key != key) i = (i + 1) & (mSlots.size() - 1);
    return i;
  }
  void rehash(size_t capacity) {
    std::vector<Slot> slots(capacity);
    for (const Slot& s : mSlots)
      if (s.key != kEmpty) {
        size_t h = hash(s.key) & (capacity - 1);
        while (slots[h].key != kEmpty) h = (h + 1) & (capacity - 1);
        slots[h] = s;
      }
    mSlots.swap(slots);
  }
  struct Slot {  // key and value side by side: one cache line per probe
    uint64_t key = kEmpty;
    uint32_t value = 0;
  };
  std::vector<Slot> mSlots;
  size_t mCount = 0;
};

}  // namespace hyb
