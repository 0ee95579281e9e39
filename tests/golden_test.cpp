// Golden images: fixed scenes rendered through the command line and compared with PNGs the
// renderers made before (tests/data/golden). They guard restructurings that must not change the
// images. Raw inputs carry no orientation, so their patient frame is the grid's and the explicit
// cameras below stay the same whatever the readers learn about patient space.
// HYB_WRITE_GOLDEN=1 rewrites the PNGs instead of comparing.
#include <gtest/gtest.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include "cli_util.h"
#include "render/image.h"
#include "test_util.h"
#include "volume/volume_io.h"

namespace hyb {
namespace {

const std::string kGoldenDir = std::string(HYB_SOURCE_DIR) + "/tests/data/golden/";

// The cranium and an analytic sphere as raw files (identity patient frame), made once.
struct Inputs {
  test::TempDir dir;
  std::vector<std::string> cranium, sphere;
  Inputs() {
    const Volume v = readVolume(kDefaultVolumePath);
    const std::vector<float> values = test::floatSamples(v);
    std::vector<int16_t> samples(values.begin(), values.end());
    test::writeBytes(dir.file("cranium.raw"), test::toBytes(samples));
    cranium = {dir.file("cranium.raw"), "--raw-dims", "256,256,108", "--raw-type", "int16", "--raw-spacing", "0.9570312,0.9570312,1.5"};
    test::writeBytes(dir.file("sphere.raw"), test::toBytes(test::floatSamples(test::sphereVolume({40, 36, 32}, 13.0))));
    sphere = {dir.file("sphere.raw"), "--raw-dims", "40,36,32", "--raw-type", "float32", "--raw-spacing", "1,1,1.25"};
  }
};
const Inputs& inputs() {
  static const Inputs in;
  return in;
}

// A camera in front of the cranium, slightly above it (as --orbit 180,10 was).
const std::vector<std::string> kCraniumCamera = {"--eye", "122,680,178", "--center", "122,122,80", "--up", "0,0,1", "--size", "96x96"};
const std::vector<std::string> kSphereCamera = {"--eye", "-40,-70,60", "--center", "19.5,17.5,19.4", "--up", "0,0,1", "--size", "80x80"};

// Renders @p args into @p name's image and compares it with the golden one (or writes it).
void expectGolden(const std::string& name, std::vector<std::string> input, const std::vector<std::string>& args) {
  test::TempDir out;
  std::vector<std::string> cmd = {"render"};
  cmd.insert(cmd.end(), input.begin(), input.end());
  cmd.insert(cmd.end(), args.begin(), args.end());
  // The goldens predate gradient normals: facet shading must stay as it was.
  cmd.insert(cmd.end(), {"-o", out.file("image.png"), "--surface-normals", "facet"});
  const test::CliRun r = test::run(cmd);
  ASSERT_EQ(r.status, 0) << r.err;
  const std::string golden = kGoldenDir + name + ".png";
  if (std::getenv("HYB_WRITE_GOLDEN")) {
    std::filesystem::copy_file(out.file("image.png"), golden, std::filesystem::copy_options::overwrite_existing);
    return;
  }
  int w = 0, h = 0, gw = 0, gh = 0;
  const std::vector<uint8_t> image = readPng(out.file("image.png"), &w, &h), expected = readPng(golden, &gw, &gh);
  ASSERT_EQ(w, gw);
  ASSERT_EQ(h, gh);
  size_t differing = 0;
  int largest = 0;
  for (size_t i = 0; i < image.size(); ++i) {
    differing += image[i] != expected[i];
    largest = std::max(largest, std::abs(int(image[i]) - int(expected[i])));
  }
  // Bit-identical here; llvmpipe on another CPU may round a few channels differently.
  if (differing) std::printf("golden %s: %zu channels differ, largest by %d\n", name.c_str(), differing, largest);
  EXPECT_LE(double(differing) / double(image.size()), 0.002) << name << ": " << differing << " channels differ, largest by " << largest;
  EXPECT_LE(largest, 3) << name;
}

const std::vector<std::string> kBone = {"--iso", "400", "--surface-color", "0.95,0.92,0.85,0.5", "--preset", "ct-skin-bone"};

std::vector<std::string> join(std::vector<std::string> a, const std::vector<std::string>& b) {
  a.insert(a.end(), b.begin(), b.end());
  return a;
}

TEST(Golden, CraniumSlicesWithTranslucentBone) { expectGolden("cranium_slices", inputs().cranium, join(kBone, kCraniumCamera)); }

TEST(Golden, CraniumReferenceWithTranslucentBone) {
  expectGolden("cranium_raycast", inputs().cranium, join(join(kBone, kCraniumCamera), {"--renderer", "raycast"}));
}

TEST(Golden, CraniumSlicesAtAnEighthOfTheBytes) {
  expectGolden("cranium_budget", inputs().cranium, join(join(kBone, kCraniumCamera), {"--budget", "12.5%"}));
}

TEST(Golden, CraniumSlicesCutAndVolumeOfInterest) {
  expectGolden("cranium_cut_voi", inputs().cranium,
               join(join(kBone, kCraniumCamera), {"--cut", "122,140,80,0,1,0.3", "--voi", "60,60,40,180,180,120"}));
}

TEST(Golden, CraniumShellsVolumeOnlyWithAnEpsilon) {
  expectGolden("cranium_shells", inputs().cranium, join(kCraniumCamera, {"--proxy", "shells", "--epsilon", "200", "--preset", "ct-bone"}));
}

TEST(Golden, SphereOpaqueSurfaceBothRenderers) {
  for (const char* renderer : {"slices", "raycast"})
    expectGolden(std::string("sphere_opaque_") + renderer, inputs().sphere, join(kSphereCamera, {"--iso", "0", "--surface-color", "0.9,0.8,0.6,1", "--renderer", renderer}));
}

TEST(Golden, SphereTranslucentSurfaceBothRenderers) {
  for (const char* renderer : {"slices", "raycast"})
    expectGolden(std::string("sphere_translucent_") + renderer, inputs().sphere,
                 join(kSphereCamera, {"--iso", "4", "--surface-color", "0.4,0.7,0.9,0.45", "--renderer", renderer}));
}

}  // namespace
}  // namespace hyb
