#include "render/preintegration.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "volume/core/error.h"

namespace hyb {
namespace {

// The ray integral of a segment of @p mm along which the value goes linearly from @p sf to @p sb,
// by brute force: @p steps sub-segments composited front to back, each classified at its midpoint.
glm::dvec4 bruteForce(const TransferFunction& tf, double sf, double sb, double mm, int steps = 40000) {
  glm::dvec4 acc(0.0);
  for (int i = 0; i < steps; ++i) {
    const glm::vec4 c = tf.lookup(float(sf + (sb - sf) * (i + 0.5) / steps));
    const double a = c.a >= 1.0f ? 1.0 : -std::expm1(std::log1p(-double(c.a)) * mm / steps);
    acc += glm::dvec4(glm::dvec3(c) * a, a) * (1.0 - acc.a);
  }
  return acc;
}

double maxDiff(const glm::vec4& a, const glm::dvec4& b) {
  const glm::dvec4 d = glm::abs(glm::dvec4(a) - b);
  return std::max({d.r, d.g, d.b, d.a});
}

// A random piecewise-linear transfer function over [0, 1000] with @p n points.
TransferFunction randomTf(std::mt19937& rng, int n) {
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  std::vector<TransferFunction::Point> p;
  for (int i = 0; i < n; ++i)
    p.push_back({1000.0f * float(i) / float(n - 1), {u(rng), u(rng), u(rng)}, u(rng) < 0.2f ? 0.0f : u(rng)});
  return TransferFunction(p, "random");
}

TEST(PreIntegration, TableEqualsBruteForceIntegration) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> value(0.0, 1000.0), mm(0.05, 4.0);  // (the renderers' tables span the data's values)
  double worstOnBins = 0.0, worstBilinear = 0.0, worstRescaled = 0.0, worstAnywhere = 0.0;
  for (int t = 0; t < 6; ++t) {
    const TransferFunction tf = randomTf(rng, 4 + 2 * t);
    const PreIntegrationTable table(tf, 0.0f, 1000.0f, 0.05, 4.0);
    // Values on bins, thicknesses on layers: only the integration pieces' error.
    for (int i = 0; i < 40; ++i) {
      const int a = int(rng() % 256), b = int(rng() % 256);
      const int layer = table.firstLayer() + int(rng() % unsigned(table.layers()));
      const double d = PreIntegrationTable::layerMm(layer);
      const float sf = 1000.0f * float(a) / 255.0f, sb = 1000.0f * float(b) / 255.0f;
      worstOnBins = std::max(worstOnBins, maxDiff(table.lookup(sf, sb, d), bruteForce(tf, sf, sb, d)));
    }
    // Values between bins (bilinear) on layers, values on bins at any thickness (between layers),
    // and both.
    for (int i = 0; i < 40; ++i) {
      const double sf = value(rng), sb = value(rng), d = mm(rng);
      const int layer = table.firstLayer() + int(rng() % unsigned(table.layers()));
      const float bf = 1000.0f * float(rng() % 256) / 255.0f, bb = 1000.0f * float(rng() % 256) / 255.0f;
      const double onLayer = PreIntegrationTable::layerMm(layer);
      worstBilinear = std::max(worstBilinear, maxDiff(table.lookup(float(sf), float(sb), onLayer), bruteForce(tf, sf, sb, onLayer)));
      worstRescaled = std::max(worstRescaled, maxDiff(table.lookup(bf, bb, d), bruteForce(tf, bf, bb, d)));
      worstAnywhere = std::max(worstAnywhere, maxDiff(table.lookup(float(sf), float(sb), d), bruteForce(tf, sf, sb, d)));
    }
  }
  // The tolerances: the midpoint rule on kPieces pieces a bin; bilinear reads between bins; the
  // colours of the two layers around a thickness mixed; all below one 8-bit level (1/255).
  EXPECT_LT(worstOnBins, 1e-4);
  EXPECT_LT(worstBilinear, 2e-3);
  EXPECT_LT(worstRescaled, 3e-3);
  EXPECT_LT(worstAnywhere, 3e-3);
  RecordProperty("worst_on_bins", std::to_string(worstOnBins));
  RecordProperty("worst_anywhere", std::to_string(worstAnywhere));
  std::printf("table against brute force: %.2e on bins and layers, %.2e between bins, %.2e between layers, %.2e anywhere\n", worstOnBins,
              worstBilinear, worstRescaled, worstAnywhere);
}

TEST(PreIntegration, AHomogeneousSegmentsClosedFormHoldsAtAnyThickness) {
  std::mt19937 rng(3);
  const TransferFunction tf = randomTf(rng, 7);
  const PreIntegrationTable table(tf, 0.0f, 1000.0f, 0.5, 2.0);
  for (const int bin : {0, 17, 128, 255})
    for (const double d : {1e-3, 0.1, 0.7, 1.0, 3.3, 40.0}) {
      const float v = 1000.0f * float(bin) / 255.0f;
      const glm::vec4 c = tf.lookup(v);
      const double alpha = 1.0 - std::pow(1.0 - double(c.a), d);
      const glm::vec4 e = table.lookup(v, v, d);
      EXPECT_NEAR(e.a, alpha, 2e-6) << bin << " " << d;
      for (int k = 0; k < 3; ++k) EXPECT_NEAR(e[k], c[k] * alpha, 2e-6) << bin << " " << d;
      // A volume of interest's factor scales the optical depth: the same as a longer segment.
      const glm::vec4 twice = table.lookup(v, v, d, 2.0), longer = table.lookup(v, v, 2.0 * d);
      EXPECT_NEAR(twice.a, longer.a, 2e-6);
    }
}

TEST(PreIntegration, OrderMattersAndOpaqueIsOpaque) {
  // Red in front of opaque blue shows red, blue in front shows blue: the table keeps the order.
  const TransferFunction tf({{0, {1, 0, 0}, 0.5f}, {50, {1, 0, 0}, 0.5f}, {60, {0, 0, 1}, 1.0f}, {100, {0, 0, 1}, 1.0f}}, "order");
  const PreIntegrationTable table(tf, 0.0f, 100.0f, 1.0, 1.0);
  const glm::vec4 redFirst = table.lookup(0.0f, 100.0f, 1.0), blueFirst = table.lookup(100.0f, 0.0f, 1.0);
  EXPECT_FLOAT_EQ(redFirst.a, 1.0f);
  EXPECT_FLOAT_EQ(blueFirst.a, 1.0f);
  EXPECT_GT(redFirst.r, 0.2f);
  EXPECT_NEAR(blueFirst.b, 1.0f, 1e-3f);
  EXPECT_NEAR(blueFirst.r, 0.0f, 1e-3f);
  EXPECT_LT(maxDiff(redFirst, bruteForce(tf, 0.0, 100.0, 1.0)), 2e-3);
}

TEST(PreIntegration, ImpossibleTablesAreRejected) {
  const TransferFunction tf = TransferFunction::preset("ct-bone");
  EXPECT_THROW(PreIntegrationTable(tf, 0.0f, 1.0f, 1.0, 1.0, 1), ValueError);
  EXPECT_THROW(PreIntegrationTable(tf, 0.0f, 1.0f, 0.0, 1.0), ValueError);
  EXPECT_THROW(PreIntegrationTable(tf, 0.0f, 1.0f, 1.0, std::nan("")), ValueError);
  // A single value (a constant volume): every pair reads its homogeneous closed form.
  const PreIntegrationTable flat(tf, 500.0f, 500.0f, 1.0, 1.0);
  EXPECT_NEAR(flat.lookup(-1e6f, 1e6f, 1.0).a, tf.lookup(500.0f).a, 1e-6);
  EXPECT_EQ(PreIntegrationTable::layerOf(1.0), 0);
  EXPECT_EQ(PreIntegrationTable::layerOf(2.0), 2);
  EXPECT_EQ(PreIntegrationTable::layerOf(1.5), 1);
}

}  // namespace
}  // namespace hyb
