#include "bench/plain_quads.h"

#include <gtest/gtest.h>

#include "render_util.h"
#include "test_util.h"

namespace hyb {
namespace {

TEST(PlainQuads, BaselineShadesEveryPixelOfEveryQuad) {
  test::gl();
  // llvmpipe counts shader invocations by 4x4 block, so the blocks along each quad's diagonal
  // (two triangles) count twice: between one and two invocations a pixel, the same in both formats.
  const Volume v = test::sphereVolume(glm::ivec3(12, 10, 8), 4.0);
  uint64_t floatFragments = 0, brickFragments = 0;
  EXPECT_GT(bench::plainQuadSeconds(v, 32, 16, 5, &floatFragments, false), 0.0);
  EXPECT_GT(bench::plainQuadSeconds(v, 32, 16, 5, &brickFragments, true), 0.0);
  EXPECT_GE(floatFragments, uint64_t(32 * 16 * 5));
  EXPECT_LE(floatFragments, uint64_t(2 * 32 * 16 * 5));
  EXPECT_EQ(brickFragments, floatFragments);
}

}  // namespace
}  // namespace hyb
