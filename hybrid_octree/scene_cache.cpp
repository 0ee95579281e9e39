#include "hybrid_octree/scene_cache.h"

#include <algorithm>
#include <fstream>
#include <sstream>
#include <system_error>

#include "volume/core/error.h"
#include "volume/core/file_util.h"

namespace hyb {

namespace fs = std::filesystem;

namespace {

std::string instancesText(const std::vector<std::string>& instances) {
  std::string text;
  for (const std::string& i : instances) text += i + "\n";
  return text;
}

std::string fileText(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return in ? s.str() : std::string();
}

void checkUid(const std::string& seriesUid) {
  if (seriesUid.empty() || seriesUid.size() > 64 || seriesUid.find_first_not_of("0123456789.") != std::string::npos)
    HYB_THROW(ValueError, "series UID '", seriesUid.substr(0, 80), "' invalid (expected digits and dots, at most 64)");
}

}  // namespace

SceneCache::SceneCache(fs::path dir, uint64_t limitBytes) : mDir(std::move(dir)), mLimit(limitBytes) {
  std::error_code ec;
  fs::create_directories(mDir, ec);
  if (ec || !fs::is_directory(mDir)) HYB_THROW(IoError, mDir.string(), ": cannot make the scene cache's folder (", ec.message(), ")");
}

bool SceneCache::holds(const std::string& seriesUid, const std::vector<std::string>& instances) const {
  checkUid(seriesUid);
  const std::lock_guard<std::mutex> lock(mMutex);
  std::error_code ec;
  return fs::is_regular_file(mDir / (seriesUid + ".hoct"), ec) && fileText(mDir / (seriesUid + ".instances")) == instancesText(instances);
}

std::string SceneCache::scene(const std::string& seriesUid, const std::vector<std::string>& instances,
                              const std::function<void(const std::string& path)>& build) {
  checkUid(seriesUid);
  const std::lock_guard<std::mutex> lock(mMutex);
  const fs::path file = mDir / (seriesUid + ".hoct"), listed = mDir / (seriesUid + ".instances");
  const std::string key = instancesText(instances);
  std::error_code ec;
  if (fs::is_regular_file(file, ec) && fileText(listed) == key) {
    fs::last_write_time(file, fs::file_time_type::clock::now(), ec);  // its use, for the eviction's order
    ++mCounts.hits;
    return file.string();
  }
  fs::remove(listed, ec);  // (a scene without its list is never served)
  build(file.string());
  writeFileAtomically(listed.string(), [&](std::ostream& s) { s << key; });
  ++mCounts.builds;
  evict(file);
  return file.string();
}

void SceneCache::evict(const fs::path& keep) {
  struct Entry {
    fs::path file;
    fs::file_time_type used;
    uint64_t bytes;
  };
  std::vector<Entry> entries;
  uint64_t total = 0;
  std::error_code ec;
  for (const fs::directory_entry& e : fs::directory_iterator(mDir, ec)) {
    if (e.path().extension() != ".hoct" || !e.is_regular_file(ec)) continue;
    const uint64_t bytes = e.file_size(ec);
    entries.push_back({e.path(), e.last_write_time(ec), bytes});
    total += bytes;
  }
  std::sort(entries.begin(), entries.end(), [](const Entry& a, const Entry& b) { return a.used < b.used; });
  for (const Entry& e : entries) {
    if (total <= mLimit) break;
    if (e.file == keep) continue;
    fs::path listed = e.file;
    listed.replace_extension(".instances");
    fs::remove(listed, ec);  // the list first: a scene left without it is never served
    fs::remove(e.file, ec);
    total -= e.bytes;
    ++mCounts.evicted;
  }
}

SceneCache::Counts SceneCache::counts() const {
  const std::lock_guard<std::mutex> lock(mMutex);
  return mCounts;
}

}  // namespace hyb
