#include "apps/viewer_files.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <set>

#include "test_util.h"
#include "volume/error.h"

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

}  // namespace
}  // namespace hyb::viewer
