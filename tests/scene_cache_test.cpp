#include "hybrid_octree/scene_cache.h"

#include <gtest/gtest.h>

#include <chrono>
#include <fstream>
#include <thread>

#include "test_util.h"
#include "volume/core/error.h"

namespace hyb {
namespace {

namespace fs = std::filesystem;

// A build that writes @p bytes to the path it is given and counts itself.
struct FakeBuild {
  int calls = 0;
  uint64_t bytes = 1000;
  void operator()(const std::string& path) {
    ++calls;
    std::ofstream(path, std::ios::binary) << std::string(bytes, 'x');
  }
  std::function<void(const std::string&)> fn() {
    return [this](const std::string& p) { (*this)(p); };
  }
};

TEST(SceneCache, ASeriesIsBuiltOnceAndAgainOnlyWhenItsInstancesChange) {
  test::TempDir dir;
  SceneCache cache(dir.path() / "scenes", 1 << 20);
  FakeBuild build;
  const std::vector<std::string> instances{"1.2.3.1", "1.2.3.2"};
  const std::string first = cache.scene("1.2.3", instances, build.fn());
  EXPECT_EQ(first, (dir.path() / "scenes" / "1.2.3.hoct").string());
  EXPECT_EQ(cache.scene("1.2.3", instances, build.fn()), first);
  EXPECT_EQ(build.calls, 1);
  cache.scene("1.2.3", {"1.2.3.1", "1.2.3.2", "1.2.3.3"}, build.fn());  // an instance added
  EXPECT_EQ(build.calls, 2);
  cache.scene("1.2.3", {"1.2.3.1", "1.2.3.9"}, build.fn());  // one replaced, the count the same
  EXPECT_EQ(build.calls, 3);
  EXPECT_EQ(cache.counts().hits, 1u);
  EXPECT_EQ(cache.counts().builds, 3u);
  // A cache opened again on the folder serves what it holds.
  SceneCache reopened(dir.path() / "scenes", 1 << 20);
  reopened.scene("1.2.3", {"1.2.3.1", "1.2.3.9"}, build.fn());
  EXPECT_EQ(build.calls, 3);
}

TEST(SceneCache, TheLeastRecentlyUsedGoFirstAndTheNewestStays) {
  test::TempDir dir;
  SceneCache cache(dir.path(), 2500);  // two scenes of 1000 bytes fit, not three
  FakeBuild build;
  const auto open = [&](const std::string& uid) { return cache.scene(uid, {uid + ".1"}, build.fn()); };
  open("1.1");
  std::this_thread::sleep_for(std::chrono::milliseconds(20));  // (the order is the files' times)
  open("1.2");
  std::this_thread::sleep_for(std::chrono::milliseconds(20));
  open("1.1");  // used again: 1.2 is now the least recently used
  std::this_thread::sleep_for(std::chrono::milliseconds(20));
  open("1.3");
  EXPECT_TRUE(fs::exists(dir.path() / "1.1.hoct"));
  EXPECT_FALSE(fs::exists(dir.path() / "1.2.hoct"));
  EXPECT_FALSE(fs::exists(dir.path() / "1.2.instances"));
  EXPECT_TRUE(fs::exists(dir.path() / "1.3.hoct"));
  EXPECT_EQ(cache.counts().evicted, 1u);
  // One scene larger than the bound is kept while it is the newest.
  build.bytes = 5000;
  EXPECT_TRUE(fs::exists(open("1.4")));
  EXPECT_FALSE(fs::exists(dir.path() / "1.1.hoct"));
  EXPECT_FALSE(fs::exists(dir.path() / "1.3.hoct"));
}

TEST(SceneCache, AFailedBuildLeavesNothingServedAndBadUidsAreRefused) {
  test::TempDir dir;
  SceneCache cache(dir.path(), 1 << 20);
  FakeBuild build;
  cache.scene("1.5", {"1.5.1"}, build.fn());
  // The instances changed and the build fails: the old scene is not served afterwards.
  EXPECT_THROW(cache.scene("1.5", {"1.5.1", "1.5.2"}, [](const std::string&) { throw IoError("archive gone"); }), IoError);
  EXPECT_FALSE(fs::exists(dir.path() / "1.5.instances"));
  cache.scene("1.5", {"1.5.1"}, build.fn());
  EXPECT_EQ(build.calls, 2);
  for (const char* bad : {"", "../etc/passwd", "1.2/3", "1.2.3a", "1111111111111111111111111111111111111111111111111111111111111111.1"}) {
    try {
      cache.scene(bad, {}, build.fn());
      ADD_FAILURE() << bad << " accepted";
    } catch (const ValueError& e) {
      EXPECT_NE(std::string(e.what()).find("expected digits and dots, at most 64"), std::string::npos) << e.what();
    }
  }
  EXPECT_EQ(build.calls, 2);
}

}  // namespace
}  // namespace hyb
