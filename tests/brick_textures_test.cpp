#include "render/slices/brick_textures.h"

#include <gtest/gtest.h>
#include <malloc.h>

#include <vector>

#include "render_util.h"
#include "test_util.h"

namespace hyb {
namespace {

Brick brick(uint32_t node) {
  Brick b;
  b.node = node;
  return b;
}
CachedBrick of(uint64_t bytes) {
  CachedBrick c;
  c.bytes = bytes;
  return c;
}

TEST(BrickTextures, CacheEvictsTheLeastRecentlyUsedBricksOfEarlierFrames) {
  BrickTextureCache cache(250);
  cache.beginFrame();
  cache.insert(brick(1), of(100));
  cache.insert(brick(2), of(100));
  cache.insert(brick(3), of(100));
  cache.evict();
  EXPECT_EQ(cache.size(), 3u);  // all three are this frame's: kept while it draws
  EXPECT_EQ(cache.bytes(), 300u);
  cache.beginFrame();
  ASSERT_NE(cache.find(brick(1)), nullptr);  // the oldest, used again
  cache.evict();
  EXPECT_EQ(cache.size(), 2u);  // brick 2 went: the least recently used
  EXPECT_EQ(cache.find(brick(2)), nullptr);
  EXPECT_NE(cache.find(brick(3)), nullptr);
  EXPECT_EQ(cache.bytes(), 200u);
  EXPECT_EQ(cache.evicted(), 1u);
  cache.grew(brick(3), 120);  // a cut texture made for it
  cache.beginFrame();
  cache.evict();
  EXPECT_EQ(cache.bytes(), 220u);  // brick 1 (older) went, brick 3 with its cut texture stays
  EXPECT_EQ(cache.find(brick(1)), nullptr);
  cache.setBits(TexelBits::Sixteen);  // another precision: nothing kept fits
  EXPECT_EQ(cache.size(), 0u);
  BrickTextureCache unlimited;
  for (uint32_t n = 0; n < 10; ++n) unlimited.insert(brick(n), of(1 << 20));
  unlimited.beginFrame();
  unlimited.evict();
  EXPECT_EQ(unlimited.size(), 10u);
}

TEST(BrickTextures, RoomIsMadeFromEarlierFramesOnly) {
  BrickTextureCache cache(250);
  cache.beginFrame();
  EXPECT_TRUE(cache.makeRoom(100));
  cache.insert(brick(1), of(100));
  EXPECT_TRUE(cache.makeRoom(100));
  cache.insert(brick(2), of(100));
  EXPECT_FALSE(cache.makeRoom(100));  // only this frame's bricks to give up: the third is not kept
  EXPECT_EQ(cache.size(), 2u);
  cache.beginFrame();
  ASSERT_NE(cache.find(brick(2)), nullptr);
  EXPECT_FALSE(cache.makeRoom(200));  // brick 1, of the frame before, goes; brick 2 is this frame's
  EXPECT_TRUE(cache.makeRoom(150));
  EXPECT_EQ(cache.find(brick(1)), nullptr);
  EXPECT_EQ(cache.bytes(), 100u);
  EXPECT_EQ(cache.evicted(), 1u);
  EXPECT_TRUE(BrickTextureCache().makeRoom(uint64_t(1) << 40));  // no limit
}

// The cache counts what llvmpipe allocates for a brick's texture, its rows padded to a cache line
// (a brick of 33³ RGBA8 texels holds 1.58 times its texels' bytes): the formula, and the heap's
// growth as 64 such textures are made.
TEST(BrickTextures, TheMemoryATextureHoldsIsLlvmpipes) {
  EXPECT_EQ(heldTextureBytes({33, 33, 33}, 4), 192u * 36u * 33u);  // rows of 36 texels, 144 bytes, padded to 192
  EXPECT_EQ(heldTextureBytes({33, 33, 33}, 8), 320u * 36u * 33u);
  EXPECT_EQ(heldTextureBytes({33, 33, 33}, 2), 128u * 36u * 33u);
  EXPECT_EQ(heldTextureBytes({16, 16, 16}, 4), 64u * 16u * 16u);  // nothing to pad
  EXPECT_EQ(heldTextureBytes({9, 5, 3}, 4), 64u * 8u * 3u);
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
  GTEST_SKIP() << "the sanitizer's allocator does not report the heap through mallinfo2";
#endif
  test::gl();
  const glm::ivec3 dims(33, 33, 33);
  auto heap = [] {
    const struct mallinfo2 m = mallinfo2();
    return double(m.uordblks + m.hblkhd);
  };
  std::vector<gl::Texture> textures;
  const double before = heap();
  for (int i = 0; i < 64; ++i) {
    PackedBrick p;
    p.bytes.assign(size_t(dims.x) * dims.y * dims.z * 4, uint8_t(i));
    textures.push_back(std::move(uploadBrick(std::move(p), dims, TexelBits::Eight).texture));
  }
  const double each = (heap() - before) / 64.0;
  EXPECT_NEAR(each, double(heldTextureBytes(dims, 4)), 0.05 * double(heldTextureBytes(dims, 4)));  // (not 143,748: the texels)
}

TEST(BrickTextures, RangesAreTheTexelsValuesOverBlocksOfTwoCells) {
  // A 5x3x2 lattice whose value is its x knot: blocks of 2x2x2 cells, x blocks [0,2] and [2,4].
  const glm::ivec3 dims(5, 3, 2);
  std::vector<glm::vec4> texels;
  for (int k = 0; k < dims.z; ++k)
    for (int j = 0; j < dims.y; ++j)
      for (int i = 0; i < dims.x; ++i) texels.emplace_back(float(i) + 10.0f * float(j), 0, 0, 0);
  const BrickRanges r = texelRanges(texels, dims);
  EXPECT_EQ(r.blocks, glm::ivec3(2, 1, 1));
  ASSERT_EQ(r.values.size(), 2u);
  EXPECT_EQ(r.values[0], (std::array<float, 2>{0.0f, 22.0f}));
  EXPECT_EQ(r.values[1], (std::array<float, 2>{2.0f, 24.0f}));
}

TEST(BrickTextures, PackingKeepsTheRangeAndTheGradientsDirection) {
  const std::vector<glm::vec4> texels = {{-100, 2, 0, 0}, {300, 0, -4, 1}, {100, 1, 1, 1}};
  const PackedBrick p = packBrick(texels, TexelBits::Eight);
  EXPECT_EQ(p.brick.valueOffset, 100.0f);
  EXPECT_EQ(p.brick.valueScale, 200.0f);
  ASSERT_EQ(p.bytes.size(), 12u);
  EXPECT_EQ(p.bytes[0], 0);    // the smallest value
  EXPECT_EQ(p.bytes[4], 255);  // the largest
  EXPECT_EQ(p.bytes[1], 128 + 64);  // +2 of the largest gradient component 4: half the positive codes
  EXPECT_EQ(p.bytes[6], 128 - 127);  // -4: the lowest code
  EXPECT_EQ(p.bytes[2], 128);        // zero exact
}

}  // namespace
}  // namespace hyb
