// A folder of scene files built from an archive's series, so that a series opened before opens
// from its scene file (read paged) instead of being retrieved and built again. Each is keyed by the
// Series Instance UID and the SOP Instance UIDs of its instances: a series whose instances the
// archive changed is built again. The folder is bounded in bytes, least recently used first out.
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <mutex>
#include <string>
#include <vector>

namespace hyb {

class SceneCache {
 public:
  /// @p dir is made when missing; @p limitBytes bounds its scene files (one larger than the bound
  /// is kept until the next is made). @throw IoError naming @p dir when it cannot be made.
  SceneCache(std::filesystem::path dir, uint64_t limitBytes);

  struct Counts {
    uint64_t hits = 0, builds = 0, evicted = 0;
  };

  /// The scene file of the series @p seriesUid whose instances are @p instances (sorted): the one
  /// cached when it was built of exactly these instances, else the one @p build writes (it is given
  /// the path to write, atomically). The folder is then brought within its bound, the file returned
  /// kept. @throw ValueError for a UID that is not one (digits and dots, at most 64); what @p build throws.
  std::string scene(const std::string& seriesUid, const std::vector<std::string>& instances,
                    const std::function<void(const std::string& path)>& build);

  /// Whether scene() would return a cached file for these instances (no build).
  bool holds(const std::string& seriesUid, const std::vector<std::string>& instances) const;

  Counts counts() const;
  const std::filesystem::path& dir() const { return mDir; }

 private:
  void evict(const std::filesystem::path& keep);

  std::filesystem::path mDir;
  uint64_t mLimit;
  mutable std::mutex mMutex;  // one build at a time; the counts
  Counts mCounts;
};

}  // namespace hyb
