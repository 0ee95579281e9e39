#include "render/image.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include "test_util.h"

namespace hyb {
namespace {

TEST(Image, PngRoundTripAndPsnr) {
  test::TempDir dir;
  Image img(5, 3);
  img.at(1, 2) = glm::vec4(0.5f, 0.25f, 0.0f, 0.5f);  // premultiplied
  writePng(dir.file("a.png"), img, glm::vec3(0.0f, 0.0f, 1.0f));
  int w = 0, h = 0;
  const std::vector<uint8_t> back = readPng(dir.file("a.png"), &w, &h);
  EXPECT_EQ(w, 5);
  EXPECT_EQ(h, 3);
  EXPECT_EQ(back, toRgba8(img, glm::vec3(0.0f, 0.0f, 1.0f)));
  const size_t px = (2 * 5 + 1) * 4;
  EXPECT_EQ(back[px + 0], 128);  // 0.5 + 0.5 * 0
  EXPECT_EQ(back[px + 2], 128);  // 0 + 0.5 * 1 (background blue)
  EXPECT_EQ(back[px + 3], 255);
  EXPECT_TRUE(std::isinf(psnr(back, back)));
  std::vector<uint8_t> off = back;
  off[0] = uint8_t(off[0] + 10);
  EXPECT_NEAR(psnr(back, off), 10 * std::log10(255.0 * 255.0 / (100.0 / 45.0)), 1e-9);
  EXPECT_THROW(writePng(dir.file("no/dir/a.png"), img, glm::vec3(0)), IoError);
}

TEST(Image, SsimOfIdenticalConstantAndNoisyImages) {
  std::vector<uint8_t> a(16 * 16 * 4, 100), b = a;
  EXPECT_DOUBLE_EQ(ssim(a, a, 16, 16), 1.0);
  for (size_t i = 0; i < b.size(); ++i) b[i] = 120;
  // Constant windows: only the luminance term, (2·100·120 + C1) / (100² + 120² + C1).
  const double c1 = 2.55 * 2.55;
  EXPECT_NEAR(ssim(a, b, 16, 16), (2 * 100.0 * 120.0 + c1) / (100.0 * 100.0 + 120.0 * 120.0 + c1), 1e-12);
  std::mt19937 rng(3);
  for (uint8_t& x : b) x = uint8_t(rng() % 256);
  EXPECT_LT(ssim(a, b, 16, 16), 0.2);
  EXPECT_DOUBLE_EQ(ssim(std::vector<uint8_t>(3 * 2 * 4, 7), std::vector<uint8_t>(3 * 2 * 4, 7), 3, 2), 1.0);  // smaller than a window
}

}  // namespace
}  // namespace hyb

namespace hyb {
namespace {

// Bilinear magnification with aligned pixel centres reproduces a linear ramp exactly between the
// outer source centres, and a constant everywhere.
TEST(Image, ResampledRampsAreExactBetweenTheOuterCentres) {
  Image ramp(8, 6);
  for (int y = 0; y < 6; ++y)
    for (int x = 0; x < 8; ++x) ramp.at(x, y) = glm::vec4(0.1f * float(x), 0.05f * float(y), 0.5f, 0.25f + 0.02f * float(x + y));
  const Image big = resampled(ramp, 32, 24);
  ASSERT_EQ(big.width, 32);
  ASSERT_EQ(big.height, 24);
  for (int y = 0; y < 24; ++y)
    for (int x = 0; x < 32; ++x) {
      // The source position of this pixel's centre, clamped to the outer centres.
      const float sx = std::clamp((float(x) + 0.5f) / 4.0f - 0.5f, 0.0f, 7.0f), sy = std::clamp((float(y) + 0.5f) / 4.0f - 0.5f, 0.0f, 5.0f);
      const glm::vec4 want(0.1f * sx, 0.05f * sy, 0.5f, 0.25f + 0.02f * (sx + sy));
      for (int c = 0; c < 4; ++c) EXPECT_NEAR(big.at(x, y)[c], want[c], 1e-6f) << x << "," << y;
    }
  const Image same = resampled(ramp, 8, 6);
  for (size_t i = 0; i < same.pixels.size(); ++i) EXPECT_EQ(same.pixels[i], ramp.pixels[i]);
}

}  // namespace
}  // namespace hyb
