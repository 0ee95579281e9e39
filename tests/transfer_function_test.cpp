#include "render/transfer_function.h"

#include <gtest/gtest.h>

#include <set>
#include <string>

#include "test_util.h"

namespace hyb {
namespace {

// One preset table, one default decision: every preset is valid and named once, and the data's
// range picks CT's default where air and bone are both present (a study reaching only 250 HU gets
// it as well: the viewer used its own thresholds and offered a "ramp" holding CT's points).
TEST(TransferFunction, OnePresetTableAndOneDefault) {
  std::set<std::string> names;
  for (const TransferFunction::Preset& p : TransferFunction::presets()) {
    EXPECT_TRUE(names.insert(p.name).second) << p.name;
    EXPECT_EQ(TransferFunction::preset(p.name).points().size(), p.points.size());
    EXPECT_GT(std::string(p.shows).size(), 2u);
  }
  EXPECT_EQ(TransferFunction::presetNames().size(), names.size());
  EXPECT_EQ(TransferFunction::defaultPresetFor(-1024, 3071), "ct-skin-bone");
  EXPECT_EQ(TransferFunction::defaultPresetFor(-950, 250), "ct-skin-bone");
  EXPECT_EQ(TransferFunction::defaultPresetFor(-850, 3000), "");
  EXPECT_EQ(TransferFunction::defaultPresetFor(-1024, 150), "");
  EXPECT_EQ(TransferFunction::defaultPresetFor(0, 255), "");
  EXPECT_EQ(TransferFunction::defaultFor(-950, 250).points().size(), TransferFunction::preset("ct-skin-bone").points().size());
}

TEST(TransferFunction, LookupFilesPresetsAndSegments) {
  const TransferFunction tf({{0, {0, 0, 0}, 0.0f}, {10, {1, 0.5f, 0}, 0.5f}}, "t");
  EXPECT_EQ(tf.lookup(5).a, 0.25f);
  EXPECT_EQ(tf.lookup(-3).a, 0.0f);
  EXPECT_EQ(tf.lookup(30).a, 0.5f);
  EXPECT_EQ(tf.maxAlpha(-5, 5), 0.25f);
  EXPECT_EQ(tf.maxAlpha(-5, 50), 0.5f);
  EXPECT_FLOAT_EQ(TransferFunction::segmentAlpha(0.5f, 2.0f), 0.75f);
  EXPECT_FLOAT_EQ(TransferFunction::segmentAlpha(0.5f, 0.5f) * 2 - TransferFunction::segmentAlpha(0.5f, 0.5f) * TransferFunction::segmentAlpha(0.5f, 0.5f),
                  0.5f);  // two half-millimetre samples compose to one millimetre
  EXPECT_EQ(TransferFunction::segmentAlpha(1.0f, 0.01f), 1.0f);
  EXPECT_EQ(TransferFunction::segmentAlpha(0.0f, 100.0f), 0.0f);
  for (const std::string& name : TransferFunction::presetNames()) EXPECT_NO_THROW(TransferFunction::preset(name));
  // Defaults: CT ranges get the CT preset; other data a ramp over their own range.
  EXPECT_EQ(TransferFunction::defaultFor(-1024, 3000).points().size(), TransferFunction::preset("ct-skin-bone").points().size());
  const TransferFunction ramp = TransferFunction::defaultFor(0, 255);
  EXPECT_EQ(ramp.lookup(50).a, 0.0f);
  EXPECT_FLOAT_EQ(ramp.lookup(255).a, 0.1f);
  EXPECT_GT(ramp.maxAlpha(0, 255), 0.0f);
  EXPECT_THROW(TransferFunction::preset("ct-lungs"), ValueError);
  test::TempDir dir;
  test::writeText(dir.file("ok.tf"), "# bone\n100 1 1 1 0\n\n400 1 0.9 0.8 0.3 # ramp\n");
  EXPECT_EQ(TransferFunction::fromFile(dir.file("ok.tf")).points().size(), size_t(2));
  test::writeText(dir.file("bad.tf"), "100 1 1 1\n");
  EXPECT_THROW(TransferFunction::fromFile(dir.file("bad.tf")), IoError);
  test::writeText(dir.file("range.tf"), "100 1 1 1 2\n");
  EXPECT_THROW(TransferFunction::fromFile(dir.file("range.tf")), ValueError);
  test::writeText(dir.file("order.tf"), "100 1 1 1 0.5\n50 1 1 1 0.5\n");
  EXPECT_THROW(TransferFunction::fromFile(dir.file("order.tf")), ValueError);
}

}  // namespace
}  // namespace hyb
