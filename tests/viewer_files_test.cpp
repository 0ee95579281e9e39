#include "apps/viewer/viewer_files.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <sys/stat.h>
#include <unistd.h>

#include <filesystem>
#include <set>

#include "dicom_writer.h"
#include "test_util.h"
#include "volume/core/error.h"

namespace hyb::viewer {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

TEST(ViewerFiles, TokensQueriesAndCookies) {
  const std::string a = makeToken(), b = makeToken();
  EXPECT_EQ(a.size(), 32u);
  EXPECT_EQ(a.find_first_not_of("0123456789abcdef"), std::string::npos);
  EXPECT_NE(a, b);
  EXPECT_TRUE(tokenMatches(a, a));
  EXPECT_FALSE(tokenMatches(b, a));
  EXPECT_FALSE(tokenMatches(a.substr(0, 31), a));
  EXPECT_FALSE(tokenMatches("", ""));  // no token is never a match
  EXPECT_EQ(targetPath("/api/mesh?iso=1"), "/api/mesh");
  EXPECT_EQ(queryParam("/x?a=1&token=ab%20c+d&z", "token"), "ab c d");
  EXPECT_EQ(queryParam("/x?a=1&z", "z"), "");
  EXPECT_FALSE(queryParam("/x?a=1", "token"));
  EXPECT_FALSE(queryParam("/x?token=%zz", "token"));  // bad encoding: no value
  EXPECT_EQ(cookieValue("a=1; hyb_token=xyz; b=2", "hyb_token"), "xyz");
  EXPECT_FALSE(cookieValue("a=1; xhyb_token=xyz", "hyb_token"));
}

TEST(ViewerFiles, OnlyThePagesOwnAssetsAreServed) {
  const Asset* index = findAsset("/");
  ASSERT_NE(index, nullptr);
  EXPECT_EQ(index->path, "/index.html");
  EXPECT_THAT(std::string(index->contentType), HasSubstr("text/html"));
  EXPECT_THAT(std::string(index->bytes), HasSubstr("viewer.js"));
  ASSERT_NE(findAsset("/viewer.js"), nullptr);
  ASSERT_NE(findAsset("/viewer.css"), nullptr);
  for (const char* path : {"/../CMakeLists.txt", "/%2e%2e/CMakeLists.txt", "//etc/passwd", "/web/index.html", "index.html", "/etc/passwd"})
    EXPECT_EQ(findAsset(path), nullptr) << path;
}

TEST(ViewerFiles, NoPathLeavesTheDataDirectory) {
  test::TempDir tmp;
  const fs::path data = fs::path(tmp.file("data")), outside = fs::path(tmp.file("outside"));
  fs::create_directories(data / "ct");
  fs::create_directories(outside);
  test::writeText((data / "ct" / "head.nrrd").string(), "NRRD0004\n");
  test::writeText((data / "notes.txt").string(), "not a volume\n");
  test::writeText((outside / "secret.nrrd").string(), "NRRD0004\n");
  fs::create_symlink(outside / "secret.nrrd", data / "link-out.nrrd");
  fs::create_symlink(outside, data / "dir-out");
  fs::create_symlink(data / "ct" / "head.nrrd", data / "link-in.nrrd");
  EXPECT_EQ(resolveInDataDir(data, "ct/head.nrrd"), fs::canonical(data / "ct" / "head.nrrd"));
  EXPECT_EQ(resolveInDataDir(data, "link-in.nrrd"), fs::canonical(data / "ct" / "head.nrrd"));
  const std::pair<std::string, std::string> refused[] = {
      {"../outside/secret.nrrd", "'..'"},
      {"ct/../../outside/secret.nrrd", "'..'"},
      {(outside / "secret.nrrd").string(), "relative"},
      {"/etc/passwd", "relative"},
      {"link-out.nrrd", "leaves the data directory"},
      {"dir-out/secret.nrrd", "leaves the data directory"},
      {"%2e%2e/outside/secret.nrrd", "no such file"},  // not decoded: a name like any other
      {"ct/missing.nrrd", "no such file"},
      {"", "relative"},
  };
  for (const auto& [path, expected] : refused) {
    try {
      resolveInDataDir(data, path);
      ADD_FAILURE() << path << " was accepted";
    } catch (const ValueError& e) {
      EXPECT_THAT(e.what(), HasSubstr(expected)) << path;
    }
  }
  // The listing holds the volumes inside, a link inside included, nothing that leads out.
  std::set<std::string> listed;
  for (const DataEntry& e : listDataDir(data)) listed.insert(e.path);
  EXPECT_EQ(listed, (std::set<std::string>{"ct/head.nrrd", "link-in.nrrd"}));
}

// DICOM in the data directory: a patient CD (DICOMDIR over nested extensionless files, with a report
// and a non-DICOM file in its folders) lists its image series once each under the CD's folder, with
// study and description; a plain series folder lists its series; a FIFO named like a slice is not
// opened; nothing that is not an image series is listed.
TEST(ViewerFiles, DicomFoldersAndCdsListTheirImageSeriesOnce) {
  test::TempDir dir;
  const fs::path data = dir.path() / "data";
  test::DicomStudy study;
  test::DicomImage image;
  image.size = {8, 8};
  const auto air = [](const glm::dvec3&) { return -1000.0; };
  test::writeSeries((data / "cd/S1/S2").string(), "I", study, image, {{0, 0, 0}, {0, 0, 2}, {0, 0, 4}}, air);
  test::writeStructuredReport((data / "cd/S1/S3/I1").string(), study, "1.2.3.77");
  test::writeBytes((data / "cd/S1/S2/DIRFILE").string(), std::vector<uint8_t>(200, 0x41));
  test::writeDicomdir((data / "cd").string(), {"S1/S2/I1", "S1/S2/I2", "S1/S2/I3", "S1/S3/I1"});
  test::DicomImage other = image;
  other.seriesUid = "1.2.3.88";
  other.seriesDescription = "BONE";
  test::writeSeries((data / "plain").string(), "s", study, other, {{0, 0, 0}, {0, 0, 1}}, air);
  ASSERT_EQ(::mkfifo((data / "plain/pipe").c_str(), 0600), 0);
  alarm(60);
  const std::vector<DataEntry> listed = listDataDir(data);
  alarm(0);
  ASSERT_EQ(listed.size(), 2u);
  EXPECT_EQ(listed[0].path, "cd");
  EXPECT_EQ(listed[0].series, image.seriesUid);
  EXPECT_EQ(listed[0].label, "cd/ 20240301 CT HEAD: HEAD 2.5 (CT, 3 slices)");
  EXPECT_EQ(listed[1].path, "plain");
  EXPECT_EQ(listed[1].label, "plain/ 20240301 CT HEAD: BONE (CT, 2 slices)");
}

}  // namespace
}  // namespace hyb::viewer
