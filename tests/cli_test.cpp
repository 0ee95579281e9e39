#include "apps/cli/cli.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <regex>

#include <signal.h>
#include <sys/resource.h>
#include <sys/stat.h>

#include <algorithm>
#include <cmath>
#include <csignal>
#include <filesystem>
#include <iomanip>
#include <sstream>

#include "apps/cli/bench.h"
#include "render/image.h"
#include "surface/mesh_io.h"
#include "cli_util.h"
#include "test_util.h"

namespace hyb {
namespace {

using ::testing::HasSubstr;
using ::testing::Not;

using test::CliRun;
using test::expectBadInput;
using test::lines;
using test::run;

std::string writeNrrd(const test::TempDir& dir, const std::string& name, const std::string& header, const std::vector<uint8_t>& raw) {
  test::writeBytes(dir.file(name + ".raw"), raw);
  test::writeText(dir.file(name + ".nhdr"), header + "data file: " + name + ".raw\n");
  return dir.file(name + ".nhdr");
}

const std::string kHeader =
    "NRRD0004\ntype: float\ndimension: 3\nsizes: 9 7 5\nspace: LPS\nspace directions: (1,0,0) (0,1,0) (0,0,2)\nendian: little\nencoding: raw\n";

// The number after "key": in a --stats JSON file, or -1 when the key is missing.
double jsonNumber(const std::string& file, const std::string& key) {
  const std::string text = test::readText(file);
  const size_t at = text.find("\"" + key + "\": ");
  return at == std::string::npos ? -1.0 : std::stod(text.substr(at + key.size() + 4));
}

std::vector<uint8_t> sphereBytes() {
  return test::toBytes(test::floatSamples(test::sphereVolume({9, 7, 5}, 3.0)));
}

TEST(Cli, InfoBuildAndSelect) {
  test::TempDir dir;
  const std::string nhdr = writeNrrd(dir, "s", kHeader, sphereBytes());
  CliRun r = run({"info", nhdr});
  EXPECT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("9 x 7 x 5"));
  EXPECT_THAT(r.out, HasSubstr("float32"));

  r = run({"build", nhdr, "-o", dir.file("s.hoct")});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_TRUE(std::filesystem::exists(dir.file("s.hoct")));
  EXPECT_THAT(r.out, HasSubstr("coarse knots prefiltered"));
  EXPECT_THAT(r.out, HasSubstr("streamed plane by plane"));
  r = run({"build", nhdr, "-o", dir.file("point.hoct"), "--prefilter", "off"});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("coarse knots point-subsampled"));
  // info reads a scene as it reads a volume, and says what the scene holds.
  r = run({"info", dir.file("s.hoct")});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("9 x 7 x 5"));
  EXPECT_THAT(r.out, HasSubstr("surface  none"));
  EXPECT_THAT(r.out, HasSubstr("store    4 spacings (1..8) in blocks of 32^3 knots, "));
  r = run({"build", nhdr, "--iso", "0.5", "-o", dir.file("iso.hoct")});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("streamed plane by plane"));  // the isosurface too, a slab of leaves at a time
  r = run({"info", dir.file("iso.hoct")});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("surface  iso 0.5: "));
  expectBadInput({"info", dir.file("iso.hoct"), "--series", "1.2.3"}, "--series");

  r = run({"render", dir.file("s.hoct"), "--epsilon", "0", "--stats", dir.file("st.json"), "-o", dir.file("r.png")});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("max nodal error used 0.00"));
  const auto json = test::readBytes(dir.file("st.json"));
  EXPECT_THAT(std::string(json.begin(), json.end()), HasSubstr("\"nodes_selected\": 1"));
  // Texture bytes follow the texels' precision: 4 bytes a texel by default, 8 with 16 bits.
  const double texels = jsonNumber(dir.file("st.json"), "texels");
  EXPECT_GT(texels, 0.0);
  EXPECT_EQ(jsonNumber(dir.file("st.json"), "texture_bytes"), 4.0 * texels);
  // A scene is read paged: the frame read its blocks through a cache of --memory MB, not the samples.
  r = run({"render", dir.file("s.hoct"), "--memory", "1", "--stats", dir.file("paged.json"), "-o", dir.file("r.png")});
  ASSERT_EQ(r.status, 0) << r.err;
  const std::string paged = test::readText(dir.file("paged.json"));
  // --memory holds the octree (the bytes info reports) and the cache: the cache gets the rest.
  r = run({"info", dir.file("s.hoct")});
  std::smatch octreeBytes;
  ASSERT_TRUE(std::regex_search(r.out, octreeBytes, std::regex("octree   [0-9]+ nodes, ([0-9]+) bytes"))) << r.out;
  EXPECT_EQ(jsonNumber(dir.file("paged.json"), "cache_limit"), 1048576.0 - std::stod(octreeBytes[1]));
  EXPECT_THAT(paged, Not(HasSubstr("\"blocks_read\": 0,")));
  expectBadInput({"render", dir.file("s.hoct"), "--memory", "0.5", "-o", dir.file("r.png")}, "--memory must be megabytes in [1, 1e9]");
  expectBadInput({"view", dir.file("s.hoct"), "--memory", "nan"}, "--memory must be megabytes in [1, 1e9]");  // the viewer pages too
  // bench says the same of its whole run.
  r = run({"bench", dir.file("s.hoct"), "--memory", "1", "--size", "16x16", "--epsilons", "0", "--budgets", "0.5", "--repeat", "1",
           "--rounds", "1", "--no-plot", "-o", dir.file("bench")});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_TRUE(std::regex_search(r.out, std::regex("store    [1-9][0-9]* blocks read \\([0-9.]+ MB compressed\\), [0-9]+ from the cache, "
                                                  "[0-9]+ evicted; the cache holds [0-9.]+ of [0-9.]+ MB\n")))
      << r.out;
  r = run({"render", dir.file("s.hoct"), "--texel-bits", "16", "--stats", dir.file("st16.json"), "-o", dir.file("r.png")});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(jsonNumber(dir.file("st16.json"), "texture_bytes"), 8.0 * texels);

  r = run({"render", nhdr, "--epsilon", "100", "-o", dir.file("r.png")});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("1 bricks, 8 texels"));
  // An isovalue the data never crosses renders, with one warning saying the surface is empty.
  r = run({"render", nhdr, "--iso", "50", "-o", dir.file("i.png")});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(lines(r.err), 1u) << r.err;
  EXPECT_THAT(r.err, HasSubstr("warning: --iso 50 is outside the data's crossing range"));
}

TEST(Cli, InfoPrintsThePatientFrameAndExactPercentiles) {
  test::TempDir dir;
  const std::string nhdr = writeNrrd(dir, "r",
                                     "NRRD0004\ntype: float\ndimension: 3\nsizes: 9 7 5\nspace: right-anterior-superior\n"
                                     "space directions: (1,0,0) (0,0,-1.5) (0,2,0)\nspace origin: (10,20,30)\nendian: little\nencoding: raw\n",
                                     sphereBytes());
  const CliRun r = run({"info", nhdr});
  ASSERT_EQ(r.status, 0) << r.err;
  // In LPS: i towards the right, j towards inferior, k towards anterior; the origin's x and y negated.
  EXPECT_THAT(r.out, HasSubstr("origin   -10, -20, 30 mm"));
  EXPECT_THAT(r.out, HasSubstr("direction  -1.000000   0.000000   0.000000"));
  EXPECT_THAT(r.out, HasSubstr("            0.000000   0.000000  -1.000000"));
  EXPECT_THAT(r.out, HasSubstr("            0.000000  -1.000000   0.000000"));
  EXPECT_THAT(r.out, HasSubstr("orient   RIA"));
  EXPECT_THAT(r.out, HasSubstr("spacing  1 x 1.5 x 2 mm"));
  // The percentiles are samples of the data (nearest rank), not bin centres.
  const std::vector<float> s = test::floatSamples(test::sphereVolume({9, 7, 5}, 3.0));
  std::vector<float> sorted = s;
  std::sort(sorted.begin(), sorted.end());
  std::ostringstream median;
  median << std::fixed << std::setprecision(2) << "median " << sorted[size_t(std::ceil(0.5 * double(s.size()))) - 1];
  EXPECT_THAT(r.out, HasSubstr(median.str()));
}

TEST(Cli, CameraRecordedByStatsRendersTheSameImageAgain) {
  test::TempDir dir;
  const std::string nhdr = writeNrrd(dir, "s", kHeader, sphereBytes());
  CliRun r = run({"render", nhdr, "--orbit", "30,20", "--zoom", "1.5", "--size", "32x24", "--iso", "0.5", "-o", dir.file("a.png"),
                  "--stats", dir.file("a.json"), "--marker", "on"});
  ASSERT_EQ(r.status, 0) << r.err;
  r = run({"render", nhdr, "--camera-file", dir.file("a.json"), "--iso", "0.5", "-o", dir.file("b.png"), "--marker", "on"});
  ASSERT_EQ(r.status, 0) << r.err;
  int w = 0, h = 0;
  EXPECT_EQ(readPng(dir.file("a.png"), &w, &h), readPng(dir.file("b.png"), &w, &h));
  EXPECT_EQ(w, 32);
  EXPECT_EQ(h, 24);
  // A camera file that is not one is refused naming the field.
  test::writeText(dir.file("bad.json"), "{\"camera\": {\"eye\": [0, 0], \"center\": [0, 0, 0]}}");
  expectBadInput({"render", nhdr, "--camera-file", dir.file("bad.json"), "-o", dir.file("c.png")}, "camera field 'eye'");
  test::writeText(dir.file("text.json"), "not json");
  expectBadInput({"render", nhdr, "--camera-file", dir.file("text.json"), "-o", dir.file("c.png")}, "text.json: not a JSON object");
}

TEST(Cli, BudgetInPercentOfTheFullResolutionBytes) {
  test::TempDir dir;
  const std::string header = "NRRD0004\ntype: float\ndimension: 3\nsizes: 33 33 33\nspacings: 1 1 1\nendian: little\nencoding: raw\n";
  const std::string nhdr = writeNrrd(dir, "b", header, test::toBytes(test::floatSamples(test::sphereVolume({33, 33, 33}, 12.0))));
  auto texels = [&](const std::string& budget, std::string* out) {
    std::vector<std::string> args{"render", nhdr, "--size", "16x16", "--max-brick", "4", "--stats", dir.file("t.json"), "-o", dir.file("t.png")};
    if (!budget.empty()) args.insert(args.end(), {"--budget", budget});
    const CliRun r = run(args);
    EXPECT_EQ(r.status, 0) << r.err;
    if (out) *out = r.out;
    return jsonNumber(dir.file("t.json"), "texels");
  };
  const double full = texels("", nullptr);
  ASSERT_GT(full, 1000.0);
  std::string out;
  const double quarter = texels("25%", &out);
  EXPECT_THAT(out, HasSubstr("25 % of the full-resolution"));
  EXPECT_LE(quarter, 0.25 * full);
  EXPECT_GT(quarter, 0.0);
  EXPECT_EQ(texels("100%", nullptr), full);
  EXPECT_LT(texels("3%", nullptr), quarter);
  EXPECT_EQ(texels("1e30", nullptr), full);  // more megabytes than texels can count: no limit
}

TEST(Cli, CompareMeasuresAnImageAgainstAReference) {
  test::TempDir dir;
  Image black(24, 16), one(24, 16), small(8, 8);
  for (Image* img : {&black, &one, &small})
    for (glm::vec4& p : img->pixels) p = glm::vec4(0.0f, 0.0f, 0.0f, 1.0f);
  one.at(5, 3) = glm::vec4(0.2f, 0.0f, 0.0f, 1.0f);  // red 51 of 255 at one pixel
  writePng(dir.file("black.png"), black, glm::vec3(0.0f));
  writePng(dir.file("one.png"), one, glm::vec3(0.0f));
  writePng(dir.file("small.png"), small, glm::vec3(0.0f));

  CliRun r = run({"compare", dir.file("black.png"), dir.file("black.png")});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("identical"));
  r = run({"compare", dir.file("black.png"), dir.file("one.png"), "--diff", dir.file("d.png")});
  ASSERT_EQ(r.status, 0) << r.err;
  // MSE over the RGB values: 51² / (24·16·3); PSNR = 10·log10(255² / MSE) = 35.60 dB.
  const double mse = 51.0 * 51.0 / (24.0 * 16.0 * 3.0);
  std::ostringstream expected;
  expected << "PSNR " << std::fixed << std::setprecision(2) << 10.0 * std::log10(255.0 * 255.0 / mse) << " dB";
  EXPECT_THAT(r.out, HasSubstr(expected.str()));
  EXPECT_THAT(r.out, HasSubstr("largest difference 29.4/255 (RMS over RGB) at pixel 5,3"));
  int w = 0, h = 0;
  const std::vector<uint8_t> d = readPng(dir.file("d.png"), &w, &h);
  ASSERT_EQ(d.size(), size_t(24 * 16 * 4));
  EXPECT_EQ(d[(3 * 24 + 5) * 4], 236);  // 8 · 29.44 of 255
  EXPECT_EQ(d[0], 0);

  expectBadInput({"compare", dir.file("black.png"), dir.file("small.png")}, "small.png");
  expectBadInput({"compare", dir.file("black.png")}, "compare");
  expectBadInput({"compare", dir.file("black.png"), dir.file("missing.png")}, "missing.png: cannot open (No such file or directory");
  expectBadInput({"compare", dir.file("black.png"), dir.file("one.png"), "--diff", dir.file("d.jpg")}, "--diff");
}

TEST(Cli, RawInput) {
  test::TempDir dir;
  test::writeBytes(dir.file("v.bin"), sphereBytes());
  const CliRun r = run({"info", dir.file("v.bin"), "--raw-dims", "9,7,5", "--raw-type", "float32", "--raw-spacing", "1,1,2"});
  EXPECT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("1 x 1 x 2 mm"));
  expectBadInput({"info", dir.file("v.bin"), "--raw-dims", "9,7", "--raw-type", "float32"}, "--raw-dims");
  expectBadInput({"info", dir.file("v.bin"), "--raw-dims", "9,7,5", "--raw-type", "complex"}, "--raw-type");
  expectBadInput({"info", dir.file("v.bin"), "--raw-dims", "9,7,6", "--raw-type", "float32"}, "v.bin");
  expectBadInput({"info", dir.file("v.bin"), "--raw-dims", "9,7,5"}, "--raw-type");
  expectBadInput({"info", dir.file("v.bin"), "--raw-dims", "nan,7,5"}, "--raw-dims 'nan,7,5' invalid");  // before the missing type
  expectBadInput({"info", dir.file("v.nhdr"), "--raw-dims", "9,7,5", "--raw-type", "int16"}, "v.nhdr: a .nhdr file carries its own layout");
  expectBadInput({"info", dir.path().string(), "--raw-dims", "9,7,5", "--raw-type", "int16"}, "a directory (DICOM) carries its own layout");
  expectBadInput({"info", dir.file("v.bin"), "--raw-dims", "9,7,5", "--raw-type", "float32", "--raw-endian", "middle"},
                 "--raw-endian");
}

TEST(Cli, MalformedInputExitsTwoWithOneLine) {
  test::TempDir dir;
  const auto raw = sphereBytes();
  expectBadInput({"info", writeNrrd(dir, "trunc", kHeader, std::vector<uint8_t>(raw.begin(), raw.end() - 4))}, "trunc.raw");
  expectBadInput({"info", writeNrrd(dir, "long", kHeader, [&] { auto b = raw; b.push_back(0); return b; }())}, "long.raw");
  expectBadInput({"info", writeNrrd(dir, "zero", "NRRD0004\ntype: float\ndimension: 3\nsizes: 9 0 5\nendian: little\nencoding: raw\n", raw)},
                 "zero.nhdr");
  expectBadInput({"info", writeNrrd(dir, "neg", "NRRD0004\ntype: float\ndimension: 3\nsizes: 9 -7 5\nendian: little\nencoding: raw\n", raw)},
                 "neg.nhdr");
  expectBadInput({"info", writeNrrd(dir, "ovf", "NRRD0004\ntype: float\ndimension: 3\nsizes: 32768 32768 32768\nendian: little\nencoding: raw\n", raw)},
                 "ovf.nhdr");
  expectBadInput({"info", writeNrrd(dir, "type", "NRRD0004\ntype: int128\ndimension: 3\nsizes: 9 7 5\nendian: little\nencoding: raw\n", raw)},
                 "type.nhdr");
  auto nanRaw = raw;
  const float nan = std::nanf("");
  std::memcpy(&nanRaw[40], &nan, 4);
  expectBadInput({"info", writeNrrd(dir, "nan", kHeader, nanRaw)}, "nan.nhdr");
  test::writeText(dir.file("nofile.nhdr"), kHeader + "data file: gone.raw\n");
  expectBadInput({"info", dir.file("nofile.nhdr")}, "gone.raw");
  expectBadInput({"info", dir.file("absent.nrrd")}, "absent.nrrd");
  expectBadInput({"render", dir.file("absent.hoct"), "-o", dir.file("a.png")}, "absent.hoct");
}

TEST(Cli, BadFlagsExitTwo) {
  test::TempDir dir;
  const std::string nhdr = writeNrrd(dir, "s", kHeader, sphereBytes());
  const std::string png = dir.file("o.png");
  expectBadInput({"render", nhdr}, "-o missing");  // nothing to write: refused, not a silent no-op
  expectBadInput({"render", nhdr, "-o", png, "--epsilon", "-1"}, "--epsilon");
  expectBadInput({"render", nhdr, "-o", png, "--epsilon", "abc"}, "--epsilon");
  expectBadInput({"render", nhdr, "-o", png, "--focus", "1,2"}, "--focus");
  expectBadInput({"render", nhdr, "-o", png, "--orbit", "10"}, "azimuth,elevation");
  expectBadInput({"render", nhdr, "-o", png, "--texel-bits", "12"}, "--texel-bits");
  expectBadInput({"render", nhdr, "-o", png, "--max-brick", "3"}, "--max-brick '3' invalid (expected a whole number in [1, 256] texels; a power of two)");
  expectBadInput({"bench", nhdr, "-o", dir.file("b"), "--max-brick", "512"}, "--max-brick '512' invalid");
  expectBadInput({"render", nhdr, "-o", png, "--orbit", "10,20,30"}, "azimuth,elevation");
  expectBadInput({"render", nhdr, "-o", png, "--up", "0,1,0"}, "--center and --up need --eye");  // an orbit would ignore it
  expectBadInput({"render", nhdr, "-o", png, "--center", "1,2,3"}, "--center and --up need --eye");
  expectBadInput({"render", nhdr, "-o", png, "--eye", "1,2,3", "--orbit", "10,20"}, "--orbit");
  expectBadInput({"render", nhdr, "-o", png, "--budget", "-3"}, "--budget");
  for (const char* budget : {"0%", "150%", "x%", "5%%", "%"}) expectBadInput({"render", nhdr, "-o", png, "--budget", budget}, "--budget");
  expectBadInput({"render", nhdr, "-o", png, "--no-such-flag"}, "--no-such-flag");
  expectBadInput({"build", nhdr}, "-o");
  expectBadInput({"build", nhdr, "-o", dir.file("b.hoct"), "--prefilter", "maybe"}, "--prefilter");
  expectBadInput({"build", nhdr, "-o", dir.file("x.hoct"), "--leaf-edge", "6"}, "--leaf-edge");
  expectBadInput({"render", nhdr, "-o", png, "--cut", "1,2,3,0,0,0"}, "--cut");
  expectBadInput({"render", nhdr, "-o", png, "--cut", "1,2,3"}, "--cut");
  expectBadInput({"render", nhdr, "-o", png, "--voi", "5,5,5,1,9,9"}, "--voi");
  expectBadInput({"render", nhdr, "-o", png, "--voi-outside", "-1"}, "--voi-outside");
  expectBadInput({"render", nhdr, "-o", png, "--blend", "maybe"}, "--blend");
  expectBadInput({"render", nhdr, "-o", png, "--prefilter", "yes"}, "--prefilter");
  expectBadInput({"build", nhdr, "-o", dir.file("x.hoct"), "--prefilter", "1"}, "--prefilter");
  expectBadInput({"render", nhdr, "-o", png, "--progressive", "9"}, "--progressive");
  expectBadInput({"render", nhdr, "-o", png, "--view", "frontal"}, "--view 'frontal' invalid");
  expectBadInput({"render", nhdr, "-o", png, "--view", "left", "--orbit", "10,20"}, "--orbit");
  expectBadInput({"render", nhdr, "-o", png, "--zoom", "0"}, "--zoom");
  expectBadInput({"render", nhdr, "-o", png, "--marker", "yes"}, "--marker");
  expectBadInput({"render", nhdr, "-o", png, "--camera-file", dir.file("none.json")}, "none.json");
  expectBadInput({"render", nhdr, "-o", png, "--camera-file", dir.file("none.json"), "--view", "left"}, "--camera-file");
  expectBadInput({"render", nhdr, "--progressive", "0", "-o", dir.file("a.png")}, "--progressive");
  expectBadInput({"render", nhdr, "-o", png, "--repeat", "0"}, "--repeat");
  expectBadInput({"render", nhdr, "-o", dir.file("image.txt")}, ".png");
  expectBadInput({"render", nhdr, "-o", png, "--adaptive", "2"}, "--adaptive");  // the slice renderer has no rays to refine
  for (const char* t : {"-1", "300", "nan"}) expectBadInput({"render", nhdr, "-o", png, "--renderer", "raycast", "--adaptive", t}, "--adaptive");
  EXPECT_FALSE(std::filesystem::exists(dir.file("image.txt")));
  EXPECT_FALSE(std::filesystem::exists(png));
  expectBadInput({"bench", nhdr}, "-o");
  expectBadInput({"bench", nhdr, "-o", dir.file("b"), "--budgets", "0.5,2"}, "--budgets");
  expectBadInput({"bench", nhdr, "-o", dir.file("b"), "--epsilons", "1,x"}, "--epsilons");
  expectBadInput({"bench", nhdr, "-o", dir.file("b"), "--rounds", "0"}, "--rounds");
  EXPECT_FALSE(std::filesystem::exists(dir.file("b")));  // bad lists leave no output directory
  // An output whose directory does not exist is refused before any work, naming the flag.
  const std::string missing = dir.file("no/such/dir");
  expectBadInput({"render", nhdr, "-o", missing + "/a.png"}, "-o '" + missing + "/a.png': directory");
  expectBadInput({"render", nhdr, "-o", png, "--stats", missing + "/s.json"}, "--stats");
  expectBadInput({"build", nhdr, "-o", missing + "/s.hoct"}, "does not exist");
  expectBadInput({"export", nhdr, "--iso", "0.5", "-o", missing + "/m.ply"}, "does not exist");
  expectBadInput({"compare", nhdr, nhdr, "--diff", missing + "/d.png"}, "--diff");
  expectBadInput({"frobnicate"}, "frobnicate");
  expectBadInput({}, "subcommand");
  const CliRun help = run({"--help"});
  EXPECT_EQ(help.status, 0);
  EXPECT_THAT(help.out, HasSubstr("render"));
}

TEST(Cli, ProgressiveCutAndVolumeOfInterest) {
  test::TempDir dir;
  const std::string nhdr = writeNrrd(dir, "s", kHeader, sphereBytes());
  CliRun r = run({"render", nhdr, "--size", "24x24", "--progressive", "3", "-o", dir.file("p.png"), "--cut", "4,3,4,1,0,0.2",
                  "--voi", "1,1,1,6,5,7", "--iso", "0.5", "--stats", dir.file("p.json")});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("progressive 2/3"));
  int w = 0, h = 0;
  for (const char* name : {"p_1.png", "p_2.png", "p_3.png", "p.png"}) {
    EXPECT_EQ(readPng(dir.file(name), &w, &h).size(), size_t(24 * 24 * 4)) << name;
  }
  EXPECT_EQ(readPng(dir.file("p_3.png"), &w, &h), readPng(dir.file("p.png"), &w, &h));  // the last is the requested image

  // A sequence longer than the octree has levels (its first budgets are below one texel) starts at
  // the coarsest selection instead of failing, and the memory never falls from one image to the next.
  r = run({"render", nhdr, "--size", "24x24", "--progressive", "7", "--budget", "0.01", "-o", dir.file("q.png")});
  ASSERT_EQ(r.status, 0) << r.err;
  std::istringstream lines(r.out);
  double previous = -1.0;
  int images = 0;
  for (std::string line; std::getline(lines, line);) {
    if (line.rfind("progressive ", 0) != 0) continue;
    const double mb = std::stod(line.substr(line.find(": ") + 2));
    EXPECT_GE(mb, previous) << line;
    previous = mb;
    ++images;
  }
  EXPECT_EQ(images, 6);
  EXPECT_EQ(readPng(dir.file("q_1.png"), &w, &h).size(), size_t(24 * 24 * 4));

  // --repeat: frames after the first reuse the brick textures; the image is the same.
  r = run({"render", nhdr, "--size", "24x24", "--iso", "0.5", "--surface-color", "1,1,1,0.5", "--repeat", "3", "-o", dir.file("r.png"),
           "--stats", dir.file("r.json")});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("best of 3"));
  EXPECT_THAT(test::readText(dir.file("r.json")), HasSubstr("\"first_render_ms\""));
  EXPECT_THAT(test::readText(dir.file("r.json")), HasSubstr("\"surface_polygons_ms\""));
  EXPECT_THAT(r.out, HasSubstr("polygons ("));  // where a surface frame's set-up time goes
  EXPECT_THAT(test::readText(dir.file("r.json")), Not(HasSubstr("\"fragments\": 0,")));  // shader invocations counted
  ASSERT_EQ(run({"render", nhdr, "--size", "24x24", "--iso", "0.5", "--surface-color", "1,1,1,0.5", "-o", dir.file("r1.png")}).status, 0);
  EXPECT_EQ(readPng(dir.file("r.png"), &w, &h), readPng(dir.file("r1.png"), &w, &h));
  // --lod-pixels: a frame whose pixels span voxels draws the surface clustered by cubes as wide
  // along every axis (here 2 mm along z: cubes of 2 voxels are 4 mm).
  r = run({"render", nhdr, "--size", "6x6", "--iso", "0.5", "--lod-pixels", "3", "-o", dir.file("l.png"), "--stats", dir.file("l.json")});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("clustered by cubes of 2 voxels (--lod-pixels)"));
  EXPECT_EQ(jsonNumber(dir.file("l.json"), "surface_spacing"), 2.0);
  // --classification: the table's making is reported once (the repeated frame keeps it), in both
  // renderers; an unknown one is refused naming the flag.
  for (const char* renderer : {"slices", "raycast"}) {
    r = run({"render", nhdr, "--size", "12x12", "--renderer", renderer, "--classification", "preintegrated", "--repeat", "2", "-o", dir.file("p.png"),
             "--stats", dir.file("p.json")});
    ASSERT_EQ(r.status, 0) << r.err;
    EXPECT_THAT(r.out, HasSubstr("classify pre-integrated, table made in "));
    EXPECT_THAT(test::readText(dir.file("p.json")), HasSubstr("\"classification\": \"preintegrated\""));
    EXPECT_GT(jsonNumber(dir.file("p.json"), "preintegration_ms"), 0.0);
  }
  r = run({"render", nhdr, "--classification", "pre", "-o", dir.file("x.png")});
  EXPECT_NE(r.status, 0);
  EXPECT_THAT(r.err, HasSubstr("--classification"));

  // The reference refines its rays progressively (Levoy): the previews trace a growing share of the
  // pixels and the last image is the plain reference's; --adaptive interpolates where colours agree.
  r = run({"render", nhdr, "--size", "24x24", "--renderer", "raycast", "--progressive", "3", "-o", dir.file("t.png"), "--stats",
           dir.file("t.json")});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("progressive 1/3: 49 rays"));  // the grid 4 pixels apart: 0, 4, …, 20 and 23
  EXPECT_THAT(r.out, HasSubstr("576 rays (100.0 % of the pixels)"));
  EXPECT_EQ(readPng(dir.file("t_1.png"), &w, &h).size(), size_t(24 * 24 * 4));
  ASSERT_EQ(run({"render", nhdr, "--size", "24x24", "--renderer", "raycast", "-o", dir.file("t1.png")}).status, 0);
  EXPECT_EQ(readPng(dir.file("t.png"), &w, &h), readPng(dir.file("t1.png"), &w, &h));
  EXPECT_EQ(readPng(dir.file("t_3.png"), &w, &h), readPng(dir.file("t1.png"), &w, &h));
  EXPECT_THAT(test::readText(dir.file("t.json")), HasSubstr("\"rays\": 576"));
  r = run({"render", nhdr, "--size", "24x24", "--renderer", "raycast", "--adaptive", "2", "-o", dir.file("u.png")});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.out, Not(HasSubstr("576 rays")));
}

TEST(Cli, BenchNamesEveryStepWhereTheTradeIsNotMonotonic) {
  EXPECT_TRUE(app::monotonicityBreaks({{"full", 47.7, 1000}, {"epsilon 100", 40.1, 990}, {"epsilon 200", 40.2, 990}}).empty());
  const std::vector<std::string> breaks =
      app::monotonicityBreaks({{"full", 47.7, 1000}, {"epsilon 200", 31.6, 700}, {"epsilon 401", 33.0, 300}, {"epsilon 800", 30.0, 310}});
  ASSERT_EQ(breaks.size(), 2u);
  EXPECT_EQ(breaks[0], "epsilon 200 -> epsilon 401: PSNR +1.40 dB");
  EXPECT_EQ(breaks[1], "epsilon 401 -> epsilon 800: texture bytes +10");
}

TEST(Cli, BenchWritesTheTableThePlotAndTheImages) {
  test::TempDir dir;
  const std::string nhdr = writeNrrd(dir, "s", kHeader, sphereBytes());
  const CliRun r = run({"bench", nhdr, "--size", "32x32", "--epsilons", "0,0.5", "--budgets", "0.5", "--max-brick", "2", "-o",
                        dir.file("bench")});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("[4/4]"));
  EXPECT_THAT(r.out, HasSubstr("  monotonic: PSNR and texture bytes fall"));
  EXPECT_TRUE(std::regex_search(r.out, std::regex("blending costs [-0-9.]+ % frame time, [-0-9.]+ % texture bytes, [-0-9.]+ dB, and removes "
                                                  "steps of up to [0-9.]+ between levels")))
      << r.out;
  const std::string csv = test::readText(dir.file("bench/trade.csv"));
  EXPECT_EQ(lines(csv), size_t(5));  // header, full, one epsilon, the budget with and without blending
  EXPECT_THAT(csv, HasSubstr("budget,0,0.5,"));
  int w = 0, h = 0;
  EXPECT_GT(readPng(dir.file("bench/trade.png"), &w, &h).size(), 0u);
  EXPECT_EQ(readPng(dir.file("bench/full.png"), &w, &h).size(), size_t(32 * 32 * 4));
  EXPECT_EQ(readPng(dir.file("bench/reference.png"), &w, &h).size(), size_t(32 * 32 * 4));
}

// Without --epsilons the sweep takes the smallest nodal errors at which the view's selection halves:
// every point selects fewer texture bytes than the one before.
TEST(Cli, BenchsDefaultEpsilonsEachSelectLess) {
  test::TempDir dir;
  const std::string nhdr = writeNrrd(dir, "s", kHeader, sphereBytes());
  const CliRun r = run({"bench", nhdr, "--size", "16x16", "--budgets", "0.5", "--max-brick", "2", "--repeat", "1", "--rounds", "1", "--no-plot",
                        "-o", dir.file("bench")});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("the smallest nodal errors whose selection holds at most 1/2, 1/4"));
  std::istringstream csv(test::readText(dir.file("bench/trade.csv")));
  std::string row;
  std::getline(csv, row);
  std::vector<double> bytes;  // full resolution, then each epsilon
  while (std::getline(csv, row)) {
    std::vector<std::string> cells;
    std::istringstream fields(row);
    for (std::string c; std::getline(fields, c, ',');) cells.push_back(c);
    if (cells[0] == "full" || cells[0] == "epsilon") bytes.push_back(std::stod(cells[8]));
  }
  ASSERT_GE(bytes.size(), 3u);
  for (size_t i = 1; i < bytes.size(); ++i) EXPECT_LT(bytes[i], bytes[i - 1]) << i;
}

// Frame times: the first frame (uploads included) in a column of its own, the best warm frame as
// frame_ms, each the fastest over the rounds; with --repeat 1 both are the one frame. An epsilon that selects what full resolution
// does shares its label in the plot instead of printing over it.
TEST(Cli, BenchSeparatesFirstFramesAndMergesCoincidingLabels) {
  test::TempDir dir;
  const std::string nhdr = writeNrrd(dir, "s", kHeader, sphereBytes());
  const CliRun r = run({"bench", nhdr, "--size", "16x16", "--epsilons", "0,1e-7", "--budgets", "0.5", "--max-brick", "2", "--repeat", "1",
                        "--rounds", "2", "-o", dir.file("bench")});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("round 2/2:"));
  EXPECT_EQ(r.out.find("round 3/"), std::string::npos);
  std::istringstream csv(test::readText(dir.file("bench/trade.csv")));
  std::string header, row;
  std::getline(csv, header);
  EXPECT_THAT(header, HasSubstr(",frame_ms,first_frame_ms,psnr_db,"));
  int rows = 0;
  while (std::getline(csv, row)) {
    std::vector<std::string> cells;
    std::istringstream fields(row);
    for (std::string c; std::getline(fields, c, ',');) cells.push_back(c);
    ASSERT_EQ(cells.size(), size_t(16)) << row;
    EXPECT_EQ(cells[11], cells[12]) << row;  // one frame: it is both the first and the best
    EXPECT_GT(std::stod(cells[11]), 0.0);
    ++rows;
  }
  EXPECT_EQ(rows, 4);
  const std::string gp = test::readText(dir.file("bench/trade.gp"));
  size_t merged = 0;
  for (size_t at = gp.find("set label '0-1e-07'"); at != std::string::npos; at = gp.find("set label '0-1e-07'", at + 1)) ++merged;
  EXPECT_EQ(merged, size_t(2)) << gp;  // one in each panel
  EXPECT_EQ(gp.find("set label '1e-07'"), std::string::npos) << gp;
}

TEST(Cli, ExportWritesMeshesAndRejectsBadFlags) {
  test::TempDir dir;
  // A sphere that fits inside its volume, so its surface is closed.
  const std::string nhdr = writeNrrd(dir, "s", "NRRD0004\ntype: float\ndimension: 3\nsizes: 11 11 11\nspacings: 1 1 1\nendian: little\nencoding: raw\n",
                                     test::toBytes(test::floatSamples(test::sphereVolume(glm::ivec3(11), 3.5))));
  CliRun r = run({"export", nhdr, "--iso", "0", "-o", dir.file("s.off"), "--check"});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("manifold yes, closed yes"));
  EXPECT_THAT(r.out, HasSubstr("self-intersections no"));
  {  // DiscMC within half a unit cell's diagonal of MC; the exact upper end adds at most a triangle's
     // enclosing radius (less than a cell's diagonal); the sampled statement for a patch of one voxel
    const size_t at = r.out.find("Hausdorff distance to mc ");
    ASSERT_NE(at, std::string::npos) << r.out;
    double lower = -1, upper = -1;
    unsigned long long samples = 0;
    ASSERT_EQ(std::sscanf(r.out.c_str() + at, "Hausdorff distance to mc at least %lf mm (exact: the farthest of every vertex and %llu sampled points), at most %lf",
                          &lower, &samples, &upper),
              3)
        << r.out;
    EXPECT_GT(lower, 0.1);
    EXPECT_LE(lower, 0.5 * std::sqrt(3.0) + 1e-4);  // printed to four digits
    EXPECT_GE(upper, lower);
    EXPECT_LT(upper, 1.5 * std::sqrt(3.0));
    EXPECT_GT(samples, 0u);
    EXPECT_THAT(r.out, HasSubstr("check    sampled, 99.9 % confidence: less than 3.142 mm² of either surface (a disc of one voxel's radius, 1.000 mm) "
                                 "lies farther than "));
  }
  EXPECT_TRUE(std::filesystem::exists(dir.file("s.off")));
  r = run({"build", nhdr, "--iso", "0", "-o", dir.file("s.hoct")});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("terminal nodes"));
  r = run({"export", dir.file("s.hoct"), "--iso", "0", "-o", dir.file("o.obj"), "--surface", "octree", "--check"});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("(from the scene)"));
  EXPECT_THAT(r.out, HasSubstr("manifold yes, closed yes"));
  // A scene's Surface Octree surface is extracted through its cache, a leaf at a time: the same file
  // as from its samples loaded whole (--check loads them), within a memory limit the samples exceed.
  r = run({"build", nhdr, "-o", dir.file("p.hoct")});
  ASSERT_EQ(r.status, 0) << r.err;
  r = run({"--memory-limit", "0.004", "export", dir.file("p.hoct"), "--iso", "0", "--surface", "octree", "--normals", "--memory", "1", "-o",
           dir.file("paged.ply")});
  ASSERT_EQ(r.status, 0) << r.err;
  expectBadInput({"--memory-limit", "0.004", "export", dir.file("p.hoct"), "--iso", "0", "--surface", "octree", "--check", "-o", dir.file("w.ply")},
                 "more than the memory limit");
  r = run({"export", dir.file("p.hoct"), "--iso", "0", "--surface", "octree", "--normals", "--check", "-o", dir.file("whole.ply")});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(test::readText(dir.file("paged.ply")), test::readText(dir.file("whole.ply")));
  std::filesystem::copy_file(dir.file("p.hoct"), dir.file("p.bin"));  // known by its magic, whatever its name
  expectBadInput({"info", dir.file("p.bin"), "--raw-dims", "9,7,5", "--raw-type", "int16"}, "p.bin: a scene file carries its own layout");
  EXPECT_THAT(r.out, HasSubstr("vs mc    "));  // made for --check
  r = run({"export", nhdr, "--iso", "0", "-o", dir.file("s.stl"), "--surface", "mc", "--check"});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("triangles ratio 1.000"));
  r = run({"export", nhdr, "--iso", "0", "-o", dir.file("d.ply")});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.out, Not(HasSubstr("vs mc")));  // classic Marching Cubes is made only to be compared with
  r = run({"export", nhdr, "--iso", "1000", "-o", dir.file("empty.ply")});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(lines(r.err), 2u) << r.err;  // the file's missing orientation, and the isovalue
  EXPECT_THAT(r.err, HasSubstr("no 'space directions': orientation unknown"));
  EXPECT_THAT(r.err, HasSubstr("warning: --iso 1000 is outside the data's crossing range"));
  EXPECT_THAT(r.err, HasSubstr("the surface is empty"));
  expectBadInput({"export", nhdr, "-o", dir.file("x.ply")}, "--iso");
  expectBadInput({"export", nhdr, "--iso", "0", "-o", dir.file("x.vtk")}, "x.vtk");
  expectBadInput({"export", nhdr, "--iso", "0"}, "-o");
  expectBadInput({"export", nhdr, "--iso", "0", "-o", dir.file("x.ply"), "--surface", "voxels"}, "--surface");
  expectBadInput({"export", nhdr, "--iso", "nan", "-o", dir.file("x.ply")}, "--iso");
}

// Exported meshes hold patient coordinates, use every vertex they list, and with --closed are
// capped into printable solids; on the cranium's bone that is closed, manifold, outward and free
// of self-intersections.
TEST(Cli, ExportsArePatientSpaceCompactAndClosedOnTheCranium) {
  test::TempDir dir;
  // A RAS volume: i towards the right, so the mesh's x runs negative from the origin's.
  const std::string nhdr = writeNrrd(dir, "r",
                                     "NRRD0004\ntype: float\ndimension: 3\nsizes: 11 11 11\nspace: right-anterior-superior\n"
                                     "space directions: (1,0,0) (0,1,0) (0,0,1)\nspace origin: (100,0,0)\nendian: little\nencoding: raw\n",
                                     test::toBytes(test::floatSamples(test::sphereVolume(glm::ivec3(11), 3.5))));
  for (const char* surface : {"dmc", "octree", "mc"})
    for (const char* ext : {".ply", ".obj", ".stl", ".off"}) {
      const std::string path = dir.file(std::string(surface) + ext);
      const CliRun r = run({"export", nhdr, "--iso", "0", "--surface", surface, "-o", path});
      ASSERT_EQ(r.status, 0) << r.err;
      const TriangleMesh m = readMesh(path);
      ASSERT_FALSE(m.triangles.empty());
      std::vector<bool> used(m.vertices.size(), false);
      for (const glm::uvec3& t : m.triangles)
        for (int k = 0; k < 3; ++k) used[t[k]] = true;
      EXPECT_EQ(std::count(used.begin(), used.end(), false), 0) << surface << ext;
      float lo = 1e9f, hi = -1e9f;
      for (const glm::vec3& p : m.vertices) lo = std::min(lo, p.x), hi = std::max(hi, p.x);
      EXPECT_NEAR(0.5f * (lo + hi), -105.0f, 0.1f) << surface << ext;  // LPS x of the sphere's centre: −(100 + 5)
    }
  const CliRun r = run({"export", "--iso", "400", "--surface", "octree", "--closed", "--check", "-o", dir.file("bone.ply")});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(r.err, "");  // no library chatter
  EXPECT_THAT(r.out, HasSubstr("check    manifold yes, closed yes (0 boundary edges), self-intersections no, outward yes"));
  const TriangleMesh bone = readMesh(dir.file("bone.ply"));
  std::vector<bool> used(bone.vertices.size(), false);
  for (const glm::uvec3& t : bone.triangles)
    for (int k = 0; k < 3; ++k) used[t[k]] = true;
  EXPECT_EQ(std::count(used.begin(), used.end(), false), 0);
  expectBadInput({"export", nhdr, "--iso", "0", "--normals", "-o", dir.file("n.stl")}, "--normals");
}

TEST(Cli, UnwritableOutputLeavesNothing) {
  test::TempDir dir;
  const std::string nhdr = writeNrrd(dir, "s", kHeader, sphereBytes());
  expectBadInput({"build", nhdr, "-o", dir.file("missing/dir/s.hoct")}, "missing/dir/s.hoct");
  test::writeText(dir.file("bad.hoct"), "HYBOCT\x1a\ntruncated");
  expectBadInput({"render", dir.file("bad.hoct"), "-o", dir.file("b.png")}, "bad.hoct");
  EXPECT_FALSE(std::filesystem::exists(dir.file("b.png")));
}

TEST(Cli, AFailedWriteLeavesNoFileBehind) {
  test::TempDir dir;
  const std::string nhdr = writeNrrd(dir, "s", kHeader, sphereBytes());
  const std::vector<std::string> inputs = test::namesIn(dir);
  {  // a mesh larger than the disk takes: exit 2, one line naming the file and the reason, no file
    const test::FileSizeLimit full(2048);
    const CliRun r = run({"export", nhdr, "--iso", "0.5", "-o", dir.file("m.ply")});
    EXPECT_EQ(r.status, 2);
    EXPECT_EQ(lines(r.err), size_t(1)) << r.err;
    EXPECT_THAT(r.err, HasSubstr("m.ply: write failed (File too large)"));
  }
  EXPECT_EQ(test::namesIn(dir), inputs);
  {  // a PNG larger than the disk takes
    const test::FileSizeLimit full(64);
    const CliRun r = run({"render", nhdr, "--size", "16x16", "-o", dir.file("p.png")});
    EXPECT_EQ(r.status, 2);
    EXPECT_EQ(lines(r.err), size_t(1)) << r.err;
    EXPECT_THAT(r.err, HasSubstr("p.png: "));  // at the last row or at the close: the stream is buffered
    EXPECT_THAT(r.err, HasSubstr(" failed (File too large)"));
  }
  EXPECT_EQ(test::namesIn(dir), inputs);
  // render: the PNGs fit, --stats does not; none of the images is left.
  const std::vector<std::string> args = {"render", nhdr, "--size", "16x16", "--progressive", "2", "-o", dir.file("r.png"), "--stats", dir.file("r.json")};
  CliRun r = run(args);
  ASSERT_EQ(r.status, 0) << r.err;
  const auto png = std::filesystem::file_size(dir.file("r.png")), json = std::filesystem::file_size(dir.file("r.json"));
  ASSERT_LT(png, json);
  for (const char* f : {"r.png", "r_1.png", "r_2.png", "r.json"}) std::filesystem::remove(dir.file(f));
  {
    const test::FileSizeLimit full((png + json) / 2);
    r = run(args);
  }
  EXPECT_EQ(r.status, 2);
  EXPECT_EQ(lines(r.err), size_t(1)) << r.err;
  EXPECT_THAT(r.err, HasSubstr("r.json: write failed"));
  EXPECT_EQ(test::namesIn(dir), inputs);
}

TEST(Cli, OutputsNeverReplaceInputsDevicesOrEachOther) {
  test::TempDir dir;
  const std::string nhdr = writeNrrd(dir, "s", kHeader, sphereBytes());
  ASSERT_EQ(run({"build", nhdr, "-o", dir.file("s.hoct")}).status, 0);
  const std::vector<uint8_t> scene = test::readBytes(dir.file("s.hoct"));
  expectBadInput({"build", dir.file("s.hoct"), "-o", dir.file("s.hoct")}, "-o '" + dir.file("s.hoct") + "' is the input");
  std::filesystem::create_symlink(dir.file("s.hoct"), dir.file("link.hoct"));
  expectBadInput({"build", dir.file("s.hoct"), "-o", dir.file("link.hoct")}, "is the input");
  expectBadInput({"export", dir.file("s.raw"), "--raw-dims", "9,7,5", "--raw-type", "float32", "--iso", "0", "-o", dir.file("s.raw")}, "-o");
  EXPECT_EQ(test::readBytes(dir.file("s.hoct")), scene);
  // A FIFO and a link to a device, under each command's extension.
  for (const char* ext : {".png", ".hoct", ".ply", ".json"}) {
    ASSERT_EQ(::mkfifo(dir.file(std::string("fifo") + ext).c_str(), 0600), 0);
    std::filesystem::create_symlink("/dev/null", dir.file(std::string("null") + ext));
  }
  for (const char* device : {"fifo", "null"}) {
    const std::string d = dir.file(device);
    expectBadInput({"render", nhdr, "-o", d + ".png"}, "-o '" + d + ".png' is a device, FIFO or socket, not a regular file");
    expectBadInput({"build", nhdr, "-o", d + ".hoct"}, "not a regular file");
    expectBadInput({"export", nhdr, "--iso", "0", "-o", d + ".ply"}, "not a regular file");
    expectBadInput({"render", nhdr, "-o", dir.file("a.png"), "--stats", d + ".json"}, "--stats");
  }
  expectBadInput({"render", nhdr, "-o", dir.file("a.png"), "--stats", dir.file("a.png")}, "--stats '" + dir.file("a.png") + "' is also -o's file");
  expectBadInput({"render", nhdr, "-o", dir.file("d")}, "-o");
  std::filesystem::create_directory(dir.file("d.png"));
  expectBadInput({"render", nhdr, "-o", dir.file("d.png")}, "is a directory");
}

// A FIFO named as a volume (raw with its flags, a self-describing format, a scene) is refused by
// every command at once: none opens it for reading, which would wait for a writer.
TEST(Cli, EveryCommandRefusesAFifoVolumeAtOnce) {
  test::TempDir dir;
  for (const char* name : {"vol.raw", "vol.nrrd", "vol.hoct"}) ASSERT_EQ(::mkfifo(dir.file(name).c_str(), 0600), 0) << name;
  alarm(60);  // a command that blocks must fail the run, not hang it
  const std::vector<std::string> raw = {"--raw-dims", "20,18,16", "--raw-type", "int16"};
  for (const char* name : {"vol.raw", "vol.nrrd", "vol.hoct"}) {
    const std::string v = dir.file(name);
    const bool isRaw = std::string(name) == "vol.raw";
    auto with = [&](std::vector<std::string> args) {
      if (isRaw) args.insert(args.begin() + 2, raw.begin(), raw.end());
      return args;
    };
    expectBadInput(with({"info", v}), "FIFO");
    expectBadInput(with({"build", v, "-o", dir.file("s.hoct")}), "FIFO");
    expectBadInput(with({"render", v, "-o", dir.file("a.png")}), "FIFO");
    expectBadInput(with({"export", v, "--iso", "0", "-o", dir.file("m.ply")}), "FIFO");
  }
  alarm(0);
  EXPECT_EQ(test::namesIn(dir), (std::vector<std::string>{"vol.hoct", "vol.nrrd", "vol.raw"}));
}

// An output directory where no file can be created (read-only) is refused before the work.
TEST(Cli, AnOutputDirectoryThatTakesNoFilesIsRefusedBeforeTheWork) {
  test::TempDir dir;
  const std::string nhdr = writeNrrd(dir, "s", kHeader, sphereBytes());
  const std::string ro = dir.file("ro");
  std::filesystem::create_directory(ro);
  // A read-only bind would need privileges; a directory without write permission stops non-root users,
  // and root is stopped by a file system mounted read-only: /proc holds no new files for anyone.
  const std::string target = ::geteuid() == 0 ? std::string("/proc") : ro;
  std::filesystem::permissions(ro, std::filesystem::perms::owner_read | std::filesystem::perms::owner_exec);
  expectBadInput({"render", nhdr, "-o", target + "/a.png"}, "cannot create files in directory '" + target + "'");
  expectBadInput({"render", nhdr, "-o", dir.file("a.png"), "--stats", target + "/a.json"}, "--stats");
  expectBadInput({"build", nhdr, "-o", target + "/s.hoct"}, "-o '" + target + "/s.hoct': cannot create files");
  expectBadInput({"export", nhdr, "--iso", "0", "--check", "-o", target + "/m.ply"}, "cannot create files");
  expectBadInput({"bench", nhdr, "-o", target + "/trade"}, "cannot create files");
  std::filesystem::permissions(ro, std::filesystem::perms::owner_all);
  EXPECT_EQ(test::namesIn(dir), (std::vector<std::string>{"ro", "s.nhdr", "s.raw"}));
}

TEST(Cli, ExtremeNumbersAreRefusedNamingTheirFlagOrRenderSanely) {
  test::TempDir dir;
  const std::string nhdr = writeNrrd(dir, "s", kHeader, sphereBytes());
  const std::string png = dir.file("x.png");
  expectBadInput({"render", nhdr, "--fov", "1e-6", "-o", png}, "--fov '1e-6' invalid (expected a number in [0.1, 179) degrees)");
  expectBadInput({"render", nhdr, "--eye", "1e30,0,0", "-o", png}, "--eye '1e30,0,0' invalid (expected x,y,z: 3 numbers, each in [-1e+06, 1e+06] mm)");
  expectBadInput({"render", nhdr, "--eye", "0,-50,0", "--center", "0,0,1e300", "-o", png}, "--center");
  expectBadInput({"render", nhdr, "--eye", "0,-50,0", "--center", "0,-50,0", "-o", png}, "--eye and --center must differ");
  expectBadInput({"render", nhdr, "--eye", "0,-50,0", "--center", "0,0,0", "--up", "0,1,0", "-o", png}, "--up must be non-zero and not parallel");
  expectBadInput({"render", nhdr, "--focus", "1e7,0,0", "-o", png}, "--focus");
  expectBadInput({"render", nhdr, "--cut", "0,0,1e7,0,0,1", "-o", png}, "--cut");
  expectBadInput({"render", nhdr, "--voi", "-1e300,0,0,1,1,1", "-o", png}, "--voi");
  expectBadInput({"render", nhdr, "--iso", "1e39", "-o", png}, "--iso '1e39' invalid (expected a number in [-3.4e+38, 3.4e+38] data units)");
  expectBadInput({"export", nhdr, "--iso", "-1e39", "-o", dir.file("m.ply")}, "--iso");
  expectBadInput({"build", nhdr, "--iso", "1e39", "-o", dir.file("s.hoct")}, "--iso");
  expectBadInput({"render", nhdr, "--epsilon", "1e39", "-o", png}, "--epsilon");
  expectBadInput({"render", nhdr, "--zoom", "1e-300", "-o", png}, "--zoom 1e-300 makes a field of view of 180 degrees");
  expectBadInput({"render", nhdr, "--zoom", "1000", "--fov", "1", "-o", png}, "--zoom 1000 makes a field of view of");
  expectBadInput({"render", nhdr, "--budget", "1e-300", "-o", png}, "--budget 1e-300 MB is smaller than one texel");
  expectBadInput({"render", nhdr, "--size", "16384x16384", "-o", png}, "--size '16384x16384' invalid (expected WxH, each a whole number in [1, 8192] pixels)");
  test::writeText(dir.file("cam.json"),
                  R"({"eye": [1e300, 0, 0], "center": [0, 0, 0], "up": [0, 0, 1], "fov_deg": 30, "ortho": false, "ortho_height": 1, "width": 16, "height": 16})");
  expectBadInput({"render", nhdr, "--camera-file", dir.file("cam.json"), "-o", png}, "cam.json: camera field 'eye' '1e+300,0,0' invalid (expected x,y,z: 3 numbers, each in [-1e+06, 1e+06] mm)");
  // At the limits, both renderers make an image (the volume a few pixels across, or none).
  for (const char* renderer : {"slices", "raycast"}) {
    const CliRun r = run({"render", nhdr, "--renderer", renderer, "--eye", "0,-1e6,0", "--fov", "0.1", "--size", "16x16", "-o", png});
    EXPECT_EQ(r.status, 0) << renderer << ": " << r.err;
  }
}

TEST(Cli, MemoryLimitRefusesAFileClaimingMore) {
  test::TempDir dir;
  const std::string nhdr = writeNrrd(dir, "s", kHeader, sphereBytes());  // 9x7x5 float: 1,260 bytes
  expectBadInput({"--memory-limit", "0.001", "info", nhdr}, "more than the memory limit of");
  expectBadInput({"--memory-limit", "-1", "info", nhdr}, "--memory-limit must be megabytes");
  // The limit holds for its own run only.
  EXPECT_EQ(run({"info", nhdr}).status, 0);
}

}  // namespace
}  // namespace hyb
