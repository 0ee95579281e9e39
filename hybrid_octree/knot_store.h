// The paged knot store of a scene file: every knot a brick can read (each lattice spacing 1, 2, 4,
// … up to the root's edge), in blocks of kStoreBlock³ knots, each compressed with zstd and checked
// by its own CRC-32, read on demand through a least-recently-used cache of decompressed blocks
// bounded in bytes. A frame therefore reads what its selection needs, whatever the volume's size.
//
// Level s holds the knots of spacing s (docs/scale.md): at s = 1 the samples in their stored type;
// at s ≥ 2 the lattice's knot values (the samples at the knots, or the octree's prefiltered 16-bit
// codes with their level's offset and scale) and the volume's own gradient at each knot (bfloat16,
// what a coarse brick shades with; computing it needs the samples around the knot, which is what
// paging avoids reading). Values and gradients are stored as byte planes (Blosc's shuffle). Bricks of neighbouring nodes share their face knots, so a spacing's knots
// are stored once rather than brick by brick. Blocks lie level by level, coarsest first (a cold
// frame's coarse bricks are close together), each level in Morton order of its blocks (a subtree's
// blocks are contiguous).
#pragma once

#include <glm/glm.hpp>

#include <cstdint>
#include <functional>
#include <list>
#include <memory>
#include <mutex>
#include <ostream>
#include <string>
#include <unordered_map>
#include <vector>

#include "hybrid_octree/knot_source.h"
#include "volume/core/file_util.h"

namespace hyb {

namespace detail {

/// A temporary file gone from its directory from the start (nothing is left behind, whatever stops
/// the process): what a streamed build makes waits in it, in the order it is made, until it is
/// copied into the scene in the file's order.
class SpoolFile {
 public:
  /// In @p dir ("" = the working directory); @p what names it in messages ("knot store").
  /// @throw IoError naming @p dir when it cannot be created.
  SpoolFile(const std::string& dir, std::string what);
  ~SpoolFile();
  SpoolFile(const SpoolFile&) = delete;
  SpoolFile& operator=(const SpoolFile&) = delete;
  /// Appends @p size bytes and returns where they start. @throw IoError when the write fails.
  uint64_t append(const uint8_t* bytes, size_t size);
  /// Reads @p size bytes at @p offset into @p out. @throw IoError when the read fails.
  void read(uint64_t offset, size_t size, uint8_t* out) const;
  uint64_t size() const { return mSize; }

 private:
  int mFd = -1;
  uint64_t mSize = 0;
  std::string mWhat;
};

}  // namespace detail

/// Whether scene files' checksums (sections and store blocks) are verified: not in a fuzzing build
/// (HYB_FUZZ), where a mutated file would stop at them, while a hostile file can carry valid ones.
#ifdef FUZZING_BUILD_MODE_UNSAFE_FOR_PRODUCTION
inline constexpr bool kVerifyChecksums = false;
#else
inline constexpr bool kVerifyChecksums = true;
#endif

/// Knots per axis of a store block (64 KB of int16 samples): large enough for zstd to find the
/// samples' redundancy, small enough that a 17³-knot brick reads little besides itself.
inline constexpr int kStoreBlock = 32;
static_assert(kStoreBlock == kSampleBlock, "a sampler's table keys blocks of kSampleBlock voxels");
/// Largest decompressed block: float values and bfloat16 gradients. The cache keeps the block a
/// read needs even when it alone exceeds the cache's bound.
inline constexpr uint64_t kMaxStoreBlockBytes = uint64_t(kStoreBlock) * kStoreBlock * kStoreBlock * (4 + 6);
/// zstd's compression level for the blocks (docs/scale.md compares levels and codecs).
inline constexpr int kStoreCompression = 1;

/// One spacing's knots in the store.
struct StoreLevel {
  int spacing = 1;
  glm::ivec3 counts{0};                         ///< knots per axis (knotCounts(dims, spacing))
  ScalarType type = ScalarType::Int16;          ///< values' type: the stored sample type, or UInt16 codes
  bool coded = false;                           ///< value = offset + scale · code (prefiltered levels)
  float offset = 0.0f, scale = 1.0f;
  bool gradients = false;                       ///< each block also holds three bfloat16 a knot
  uint64_t firstBlock = 0;                      ///< index of its first block (x fastest, then y, z)
  glm::ivec3 blocks() const { return (counts + kStoreBlock - 1) / kStoreBlock; }
  uint64_t blockCount() const {
    const glm::ivec3 b = blocks();
    return uint64_t(b.x) * uint64_t(b.y) * uint64_t(b.z);
  }
  /// Where block @p b lies in the store's index.
  uint64_t blockIndex(const glm::ivec3& b) const {
    const glm::ivec3 nb = blocks();
    return firstBlock + uint64_t(b.x) + uint64_t(nb.x) * (uint64_t(b.y) + uint64_t(nb.y) * uint64_t(b.z));
  }
};

/// Where one compressed block lies in the data section.
struct StoreBlock {
  uint64_t offset = 0;  ///< from the data section's start
  uint32_t size = 0;    ///< compressed bytes
  uint32_t crc = 0;     ///< CRC-32 of the compressed bytes
};

/// Bytes of raw blocks a KnotStoreWriter holds at most, summed over its levels' rows.
inline constexpr uint64_t kStoreRowBytes = uint64_t(128) << 20;

/// Makes a volume's store from its planes, as a streamed build's second pass reads them (a
/// PlaneVisitor of VolumeOctree::build): a level's block row is compressed (on all cores) once its
/// last knot plane is in, and waits in a temporary file beside the scene (gone from its directory
/// from the start) until finish() copies every block into the scene in the store's order. What it
/// holds is a block row per level; where the rows of a wide volume would hold more than
/// kStoreRowBytes, each pass over the planes makes a strip of them (along y), so as many passes.
class KnotStoreWriter final : public PlaneVisitor {
 public:
  /// A store for a volume of @p dims whose samples are held as @p storedType; the temporary file
  /// goes in @p spoolDir; the rows held stay within @p rowBytes.
  KnotStoreWriter(const glm::ivec3& dims, ScalarType storedType, const std::string& spoolDir, uint64_t rowBytes = kStoreRowBytes);
  ~KnotStoreWriter() override;
  /// @p knots must live until finish().
  void begin(const KnotPyramid& knots, int depth) override;
  int passes() const override { return mPasses; }
  void beginPass(int pass) override { mPass = pass; }
  void plane(const SampleWindow& window, int z) override;
  /// Writes the blocks to @p out, levels coarsest first and each in Morton order, and returns the
  /// store's index: the bytes KnotStore::open reads back. Deterministic: the same volume gives the
  /// same bytes. Every plane must have been seen.
  std::vector<uint8_t> finish(std::ostream& out);

 private:
  void spoolRow(size_t level, int row);
  /// The block rows (along y) of level @p l that the current pass makes: [*first, *end).
  void strip(const StoreLevel& l, int* first, int* end) const;

  glm::ivec3 mDims;
  ScalarType mStored;
  const KnotPyramid* mKnots = nullptr;
  uint64_t mRowBytes;
  int mPasses = 1, mPass = 0;
  std::vector<StoreLevel> mLevels;
  struct Row {  // a level's raw blocks of the row being filled, one after the other
    std::vector<uint8_t> bytes;
    std::vector<size_t> offsets;  // block b: [offsets[b], offsets[b + 1])
    bool open = false;
  };
  std::vector<Row> mRows;  // per level
  std::vector<StoreBlock> mSpooled;                      // per block: where it waits in the spool
  std::unique_ptr<detail::SpoolFile> mSpool;
};

/// Writes the store of @p volume and @p octree to @p out (a KnotStoreWriter fed the volume's
/// planes, its temporary file in @p spoolDir), and returns its index.
std::vector<uint8_t> writeKnotStore(const Volume& volume, const VolumeOctree& octree, std::ostream& out, const std::string& spoolDir);

/// Counters of a store's cache.
struct StoreCacheStats {
  uint64_t hits = 0, misses = 0;   ///< block requests served from memory, and read from the file
  uint64_t bytesRead = 0;          ///< compressed bytes read from the file
  uint64_t bytesHeld = 0;          ///< decompressed bytes the cache holds now
  uint64_t limit = 0;              ///< its bound: bytesHeld ≤ limit + kMaxStoreBlockBytes
  uint64_t evicted = 0;            ///< blocks dropped to stay within it
};

/// A scene's knot store, read through its cache. Thread-safe.
class KnotStore final : public KnotSource {
 public:
  /// Where a store's blocks lie in its file.
  struct Bytes {
    uint64_t offset = 0, size = 0;
  };
  /// Opens the store whose index is @p index and whose blocks are @p data of @p path, for a
  /// volume of @p dims and @p spacing; its cache holds at most @p cacheBytes of decompressed
  /// blocks (a block a read needs stays while it is copied).
  /// @throw IoError naming @p path when the index is inconsistent with the volume or the file.
  static std::shared_ptr<KnotStore> open(const std::string& path, const glm::ivec3& dims, const glm::dvec3& spacing,
                                         const std::vector<uint8_t>& index, const Bytes& data, uint64_t cacheBytes);

  glm::ivec3 dims() const override { return mDims; }
  glm::dvec3 spacing() const override { return mSpacing; }
  /// @throw IoError naming the file, level and block when a block is corrupt.
  void read(int s, const glm::ivec3& lo, const glm::ivec3& count, float* values, glm::vec3* gradients) const override;
  /// The cached block of samples holding voxel @p v, in place (read into the cache when it is not).
  SampleBlock sampleBlock(const glm::ivec3& v) const override;
  /// Every sample (level 1) as the array a Volume holds.
  SampleArray samples() const;
  /// Passes the knots of spacing @p s (values, a block at a time, read past the cache) to @p use.
  /// @throw IoError naming the file and the block when a block is corrupt.
  void forEachValue(int s, const std::function<void(const float* values, size_t n)>& use) const;
  /// The scene file.
  const std::string& path() const { return mFile.path(); }
  /// Type the samples are stored in.
  ScalarType storedType() const { return mLevels.front().type; }
  const std::vector<StoreLevel>& levels() const { return mLevels; }
  /// Compressed bytes of all blocks.
  uint64_t compressedBytes() const { return mDataSize; }

  /// Bounds the cache to @p bytes of decompressed blocks (0: no bound), evicting the least recently
  /// used at once. Returns the bytes evicted (for giveBackFreed, which a caller holding a lock
  /// calls after letting it go).
  uint64_t setCacheLimit(uint64_t bytes);
  /// Hands the heap's free pages back to the system when @p freed bytes were evicted at once.
  static void giveBackFreed(uint64_t freed);
  StoreCacheStats cacheStats() const;

  /// Whether every block @p box covers is cached: a read of it would not touch the file.
  bool cached(const KnotBox& box) const;
  /// The finest spacing whose level and the coarser ones hold at most @p bytes of decompressed
  /// blocks (the root's spacing when even its level holds more): small enough to read whenever a
  /// frame asks, cached or not.
  int coarseSpacing(uint64_t bytes) const;
  /// Loads the blocks of @p boxes that are not cached, in order, on the store's prefetch thread
  /// (Carmona et al. 3.5) while frames draw from what is; replaces what an earlier call asked for
  /// and was not loaded yet. Asks for at most half the cache's bound (more would evict itself).
  void prefetch(const std::vector<KnotBox>& boxes);
  /// Blocks the prefetch thread has still to load (the one it is loading included).
  size_t prefetchPending() const;
  /// Waits until the prefetch thread has loaded all it was asked for.
  void waitForPrefetch() const;
  /// Called on the prefetch thread whenever it has loaded all it was asked for.
  void onPrefetched(std::function<void()> done);

  ~KnotStore() override;

 private:
  struct Block {
    std::vector<uint8_t> bytes;  // values, then gradients
    glm::ivec3 dims{0};
  };
  explicit KnotStore(const std::string& path);
  /// Reads, checks and decompresses a block (not cached).
  std::shared_ptr<const Block> load(size_t level, const glm::ivec3& b, uint64_t key) const;
  /// The block through the cache.
  std::shared_ptr<const Block> block(size_t level, const glm::ivec3& b) const;
  /// Caches @p made as block @p key (its index position), evicting to stay within the bound;
  /// returns the cached block (another thread's when it was first). Needs mMutex held.
  std::shared_ptr<const Block> insert(uint64_t key, std::shared_ptr<const Block> made) const;
  /// Evicts the least recently used blocks but the @p keep most recent while the cache is over its
  /// bound. Needs mMutex held.
  void evictToLimit(size_t keep) const;
  struct Prefetch;
  void prefetchLoop();

  InputFile mFile;
  glm::ivec3 mDims{0};
  glm::dvec3 mSpacing{1.0};
  std::vector<StoreLevel> mLevels;
  std::vector<StoreBlock> mIndex;
  uint64_t mDataOffset = 0, mDataSize = 0;

  mutable std::mutex mMutex;
  struct Entry {
    std::shared_ptr<const Block> block;
    std::list<uint64_t>::iterator age;
  };
  mutable std::unordered_map<uint64_t, Entry> mCache;  // by index position
  mutable std::list<uint64_t> mOrder;                  // least recently used first
  mutable StoreCacheStats mStats;
  std::unique_ptr<Prefetch> mPrefetch;  // its thread starts at the first prefetch()
};

}  // namespace hyb
