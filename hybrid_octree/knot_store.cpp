#include "hybrid_octree/knot_store.h"

#include <malloc.h>
#include <zlib.h>
#include <zstd.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cerrno>
#include <condition_variable>
#include <cstring>
#include <deque>
#include <filesystem>
#include <thread>
#include <unordered_set>

#include <unistd.h>

#include "volume/core/error.h"
#include "volume/core/parallel.h"
#include "volume/reader_util.h"

namespace hyb {

namespace {

// Evicting more than this at once hands the heap's free pages back (giveBackFreed).
constexpr uint64_t kTrimAfterBytes = uint64_t(16) << 20;

uint32_t crcOf(const uint8_t* p, size_t n) { return uint32_t(crc32_z(crc32_z(0L, Z_NULL, 0), p, n)); }

glm::ivec3 blockDims(const StoreLevel& l, const glm::ivec3& b) { return glm::min(glm::ivec3(kStoreBlock), l.counts - b * kStoreBlock); }

constexpr size_t kGradientBytes = 3 * sizeof(uint16_t);  // bfloat16 x, y, z

uint64_t blockKnots(const glm::ivec3& d) { return uint64_t(d.x) * uint64_t(d.y) * uint64_t(d.z); }

uint64_t rawBytes(const StoreLevel& l, const glm::ivec3& d) {
  return blockKnots(d) * (scalarSize(l.type) + (l.gradients ? kGradientBytes : 0));
}

// Byte planes (Blosc's shuffle): the k-th bytes of every @p width-byte element together, so that
// the high bytes of neighbouring samples, which barely vary, make long runs zstd compresses well.
// A block's values and its gradients are each shuffled by their own width.
void toPlanes(const uint8_t* from, size_t size, size_t width, uint8_t* to) {
  const size_t n = size / width;
  for (size_t i = 0; i < n; ++i)
    for (size_t b = 0; b < width; ++b) to[b * n + i] = from[i * width + b];
}
void fromPlanes(const uint8_t* from, size_t size, size_t width, uint8_t* to) {
  const size_t n = size / width;
  for (size_t i = 0; i < n; ++i)
    for (size_t b = 0; b < width; ++b) to[i * width + b] = from[b * n + i];
}
// Calls @p f(offset, bytes, width) for a block's values and its gradients.
template <class F>
void eachPart(const StoreLevel& l, size_t size, F&& f) {
  const size_t values = size / (scalarSize(l.type) + (l.gradients ? kGradientBytes : 0)) * scalarSize(l.type);
  f(size_t(0), values, scalarSize(l.type));
  f(values, size - values, sizeof(uint16_t));
}

// Values and indices as the index's bytes hold them.
template <class T>
void put(std::vector<uint8_t>* out, const T& v) {
  const size_t at = out->size();
  out->resize(at + sizeof(T));
  std::memcpy(out->data() + at, &v, sizeof(T));
}

// A block's bytes are not aligned to their type (a uint8 block's gradients start at its knot
// count, a row's blocks follow each other byte for byte): its values are copied, never cast.
template <class T>
void storeAt(uint8_t* bytes, size_t i, T v) {
  std::memcpy(bytes + i * sizeof(T), &v, sizeof(T));
}
template <class T>
T loadAt(const uint8_t* bytes, size_t i) {
  T v;
  std::memcpy(&v, bytes + i * sizeof(T), sizeof(T));
  return v;
}

// The value of knot @p i of a block's bytes, exactly as the in-memory source gives it.
template <class T>
float valueOf(const StoreLevel& l, const uint8_t* bytes, size_t i) {
  const T v = loadAt<T>(bytes, i);
  if constexpr (std::is_same_v<T, uint16_t>)
    if (l.coded) return l.offset + l.scale * float(v);
  return float(v);
}

}  // namespace

namespace detail {

SpoolFile::SpoolFile(const std::string& dir, std::string what) : mWhat(std::move(what)) {
  std::string name = (std::filesystem::path(dir.empty() ? "." : dir) / ".hyb-spool-XXXXXX").string();
  mFd = ::mkstemp(name.data());
  if (mFd < 0) HYB_THROW(IoError, dir, ": cannot create a temporary file for the ", mWhat, " (", std::strerror(errno), ")");
  ::unlink(name.c_str());
}

SpoolFile::~SpoolFile() { ::close(mFd); }

uint64_t SpoolFile::append(const uint8_t* bytes, size_t size) {
  const uint64_t at = mSize;
  for (size_t done = 0; done < size;) {
    const ssize_t n = ::write(mFd, bytes + done, size - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) HYB_THROW(IoError, mWhat, ": temporary file write failed (", std::strerror(errno), ")");
    done += size_t(n);
  }
  mSize += size;
  return at;
}

void SpoolFile::read(uint64_t offset, size_t size, uint8_t* out) const {
  for (size_t done = 0; done < size;) {
    const ssize_t n = ::pread(mFd, out + done, size - done, off_t(offset + done));
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) HYB_THROW(IoError, mWhat, ": temporary file read failed (", std::strerror(errno), ")");
    done += size_t(n);
  }
}

}  // namespace detail

KnotStoreWriter::KnotStoreWriter(const glm::ivec3& dims, ScalarType storedType, const std::string& spoolDir, uint64_t rowBytes)
    : mDims(dims), mStored(storedType), mRowBytes(std::max<uint64_t>(rowBytes, 1)), mSpool(std::make_unique<detail::SpoolFile>(spoolDir, "knot store")) {}

KnotStoreWriter::~KnotStoreWriter() = default;

void KnotStoreWriter::begin(const KnotPyramid& knots, int depth) {
  mKnots = &knots;
  uint64_t first = 0;
  for (int j = 0; j <= depth; ++j) {  // spacing 1 up to the root's edge (a root brick at level 0)
    StoreLevel l;
    l.spacing = 1 << j;
    l.counts = knotCounts(mDims, l.spacing);
    l.coded = l.spacing > 1 && knots.covers(l.spacing);
    l.type = l.coded ? ScalarType::UInt16 : mStored;
    if (l.coded) {
      l.offset = knots.offset(l.spacing);
      l.scale = knots.scale(l.spacing);
    }
    l.gradients = l.spacing > 1;
    l.firstBlock = first;
    first += l.blockCount();
    mLevels.push_back(l);
  }
  mRows.resize(mLevels.size());
  mSpooled.resize(size_t(first));
  uint64_t rowBytes = 0;  // every level's widest row
  for (const StoreLevel& l : mLevels) rowBytes += rawBytes(l, glm::ivec3(l.counts.x, l.counts.y, std::min(kStoreBlock, l.counts.z)));
  mPasses = int(std::min<uint64_t>((rowBytes + mRowBytes - 1) / mRowBytes, uint64_t(mLevels.front().blocks().y)));
}

void KnotStoreWriter::strip(const StoreLevel& l, int* first, int* end) const {
  const int nb = l.blocks().y;
  *first = int(int64_t(nb) * mPass / mPasses);
  *end = int(int64_t(nb) * (mPass + 1) / mPasses);
}

// Plane z's knots of every level that has a knot plane there go into their block row's raw
// blocks (values, then for s ≥ 2 gradients); a row is compressed and spooled once its last knot
// plane is in.
void KnotStoreWriter::plane(const SampleWindow& w, int z) {
  const glm::ivec3 n = mDims;
  for (size_t li = 0; li < mLevels.size(); ++li) {
    const StoreLevel& l = mLevels[li];
    const int s = l.spacing;
    const int k = knotIndexAt(z, s, n.z);  // the level's knot plane here, if any
    if (k < 0) continue;
    const glm::ivec3 nb = l.blocks();
    int by0, by1;
    strip(l, &by0, &by1);
    if (by0 == by1) continue;
    Row& row = mRows[li];
    const int r = k / kStoreBlock, kk = k - r * kStoreBlock;
    if (!row.open) {  // one buffer a level, kept from row to row (no churn of a thousand blocks' allocations)
      row.offsets.assign(1, 0);
      for (int by = by0; by < by1; ++by)
        for (int bx = 0; bx < nb.x; ++bx) row.offsets.push_back(row.offsets.back() + rawBytes(l, blockDims(l, glm::ivec3(bx, by, r))));
      row.bytes.resize(row.offsets.back());
      row.open = true;
    }
    std::vector<int> px(size_t(l.counts.x)), py(size_t(l.counts.y));  // the knots' voxel positions
    for (int i = 0; i < l.counts.x; ++i) px[size_t(i)] = knotPosition(i, s, n.x);
    for (int j = 0; j < l.counts.y; ++j) py[size_t(j)] = knotPosition(j, s, n.y);
    w.visitPlane(z, [&](const auto* plane) {
      using T = std::remove_cv_t<std::remove_pointer_t<decltype(plane)>>;
#pragma omp parallel for schedule(dynamic, 1) if (nb.x * (by1 - by0) > 1)
      for (int b = 0; b < nb.x * (by1 - by0); ++b) {
        const glm::ivec3 bi(b % nb.x, by0 + b / nb.x, r), d = blockDims(l, bi), lo = bi * kStoreBlock;
        uint8_t* out = row.bytes.data() + row.offsets[size_t(b)];
        const size_t first = size_t(kk) * size_t(d.x) * size_t(d.y);
        size_t q = first;
        if (l.coded) {
          for (int j = 0; j < d.y; ++j)
            for (int i = 0; i < d.x; ++i) storeAt<uint16_t>(out, q++, mKnots->code(s, glm::ivec3(lo.x + i, lo.y + j, k)));
        } else {
          for (int j = 0; j < d.y; ++j)
            for (int i = 0; i < d.x; ++i) storeAt<T>(out, q++, plane[size_t(px[size_t(lo.x + i)]) + size_t(n.x) * size_t(py[size_t(lo.y + j)])]);
        }
        if (l.gradients) {
          uint8_t* g = out + blockKnots(d) * scalarSize(l.type);
          size_t at = 3 * first;
          for (int j = 0; j < d.y; ++j)
            for (int i = 0; i < d.x; ++i) {
              const glm::vec3 grad = w.gradientAt(px[size_t(lo.x + i)], py[size_t(lo.y + j)], z);
              for (int a = 0; a < 3; ++a) storeAt<uint16_t>(g, at++, toBfloat16(grad[a]));
            }
        }
      }
    });
    if (kk == blockDims(l, glm::ivec3(0, 0, r)).z - 1) spoolRow(li, r);
  }
  if (z == n.z - 1)  // the pass's end: the rows' buffers go before the octree is assembled
    for (Row& row : mRows) std::vector<uint8_t>().swap(row.bytes);
}

// Compresses the raw blocks of level @p li's block row @p r on all cores, a batch at a time, and
// appends them to the spool.
void KnotStoreWriter::spoolRow(size_t li, int r) {
  const StoreLevel& l = mLevels[li];
  Row& row = mRows[li];
  const glm::ivec3 nb = l.blocks();
  int by0, by1;
  strip(l, &by0, &by1);
  const size_t blocks = row.offsets.size() - 1;
  constexpr size_t kBatch = 64;
  std::vector<std::vector<uint8_t>> packed(kBatch);
  for (size_t first = 0; first < blocks; first += kBatch) {
    const size_t count = std::min(kBatch, blocks - first);
    ParallelFailure failure;
#pragma omp parallel for schedule(dynamic) if (count > 1)
    for (size_t k = 0; k < count; ++k)
      failure.run([&] {
        const uint8_t* block = row.bytes.data() + row.offsets[first + k];
        const size_t size = row.offsets[first + k + 1] - row.offsets[first + k];
        thread_local std::vector<uint8_t> raw;
        raw.resize(size);
        eachPart(l, size, [&](size_t at, size_t n, size_t width) { toPlanes(block + at, n, width, raw.data() + at); });
        std::vector<uint8_t>& z = packed[k];
        z.resize(ZSTD_compressBound(raw.size()));
        const size_t n = ZSTD_compress(z.data(), z.size(), raw.data(), raw.size(), kStoreCompression);
        if (ZSTD_isError(n)) HYB_THROW(RuntimeError, "zstd: ", ZSTD_getErrorName(n));
        z.resize(n);
      });
    failure.rethrow();
    for (size_t k = 0; k < count; ++k) {
      const size_t b = first + k;
      const glm::ivec3 bi(int(b % size_t(nb.x)), by0 + int(b / size_t(nb.x)), r);
      mSpooled[size_t(l.blockIndex(bi))] =
          StoreBlock{mSpool->append(packed[k].data(), packed[k].size()), uint32_t(packed[k].size()), crcOf(packed[k].data(), packed[k].size())};
    }
  }
  row.open = false;
}

std::vector<uint8_t> KnotStoreWriter::finish(std::ostream& out) {
  for (const Row& row : mRows) HYB_CHECK(!row.open);  // every plane was seen
  for (const StoreBlock& b : mSpooled) HYB_CHECK(b.size > 0);  // in every pass
  mRows.clear();
  std::vector<StoreBlock> index(mSpooled.size());
  uint64_t offset = 0;
  std::vector<uint8_t> bytes;
  for (auto l = mLevels.rbegin(); l != mLevels.rend(); ++l) {  // coarsest first, each level in Morton order
    const glm::ivec3 nb = l->blocks();
    std::vector<glm::ivec3> order;
    for (int z = 0; z < nb.z; ++z)
      for (int y = 0; y < nb.y; ++y)
        for (int x = 0; x < nb.x; ++x) order.emplace_back(x, y, z);
    std::sort(order.begin(), order.end(), [](const glm::ivec3& a, const glm::ivec3& b) { return morton(a) < morton(b); });
    for (const glm::ivec3& b : order) {
      const size_t i = size_t(l->blockIndex(b));
      const StoreBlock& from = mSpooled[i];
      bytes.resize(from.size);
      mSpool->read(from.offset, from.size, bytes.data());
      out.write(reinterpret_cast<const char*>(bytes.data()), std::streamsize(bytes.size()));
      index[i] = StoreBlock{offset, from.size, from.crc};
      offset += from.size;
    }
  }
  std::vector<uint8_t> result;
  put(&result, uint32_t(kStoreBlock));
  put(&result, uint32_t(mLevels.size()));
  for (const StoreLevel& l : mLevels) {
    put(&result, int32_t(l.spacing));
    put(&result, l.counts);
    put(&result, uint32_t(l.type));
    put(&result, uint8_t(l.coded));
    put(&result, l.offset);
    put(&result, l.scale);
    put(&result, uint8_t(l.gradients));
  }
  put(&result, uint64_t(index.size()));
  for (const StoreBlock& e : index) {
    put(&result, e.offset);
    put(&result, e.size);
    put(&result, e.crc);
  }
  return result;
}

std::vector<uint8_t> writeKnotStore(const Volume& v, const VolumeOctree& t, std::ostream& out, const std::string& spoolDir) {
  KnotStoreWriter writer(v.dims(), v.storedType(), spoolDir);
  writer.begin(t.knots(), t.depth());
  const std::unique_ptr<PlaneSource> planes = planesOf(v);
  visitPlanes(*planes, writer, 0);
  return writer.finish(out);
}

// The prefetch thread's queue: blocks (level, block) to load, front first.
struct KnotStore::Prefetch {
  std::mutex mutex;
  std::condition_variable wake, idle;
  std::deque<std::pair<size_t, glm::ivec3>> queue;
  bool busy = false, stop = false;
  std::function<void()> done;
  std::thread thread;
};

KnotStore::KnotStore(const std::string& path) : mFile(path), mPrefetch(std::make_unique<Prefetch>()) {}

KnotStore::~KnotStore() {
  {
    const std::lock_guard lock(mPrefetch->mutex);
    mPrefetch->stop = true;
  }
  mPrefetch->wake.notify_all();
  if (mPrefetch->thread.joinable()) mPrefetch->thread.join();
}

std::shared_ptr<KnotStore> KnotStore::open(const std::string& path, const glm::ivec3& dims, const glm::dvec3& spacing,
                                           const std::vector<uint8_t>& index, const Bytes& data, uint64_t cacheBytes) {
  std::shared_ptr<KnotStore> s(new KnotStore(path));
  s->mDims = dims;
  s->mSpacing = spacing;
  s->mDataOffset = data.offset;
  s->mDataSize = data.size;
  s->mStats.limit = cacheBytes;
  size_t pos = 0;
  auto get = [&]<class T>(T*) {
    if (index.size() - pos < sizeof(T)) HYB_THROW(IoError, path, ": knot store index too short (", index.size(), " bytes)");
    T v;
    std::memcpy(&v, index.data() + pos, sizeof(T));
    pos += sizeof(T);
    return v;
  };
  auto bad = [&](auto... what) { HYB_THROW(IoError, path, ": knot store index invalid (", what..., ")"); };
  if (const uint32_t edge = get((uint32_t*)nullptr); edge != uint32_t(kStoreBlock)) bad("block edge ", edge, ", expected ", kStoreBlock);
  const uint32_t levels = get((uint32_t*)nullptr);
  if (levels < 1 || levels > 16) bad(levels, " levels, expected 1 to 16");
  uint64_t blocks = 0;
  for (uint32_t j = 0; j < levels; ++j) {
    StoreLevel l;
    l.spacing = get((int32_t*)nullptr);
    l.counts = get((glm::ivec3*)nullptr);
    const uint32_t type = get((uint32_t*)nullptr);
    const uint8_t coded = get((uint8_t*)nullptr);
    l.offset = get((float*)nullptr);
    l.scale = get((float*)nullptr);
    const uint8_t gradients = get((uint8_t*)nullptr);
    if (l.spacing != 1 << j || l.counts != knotCounts(dims, l.spacing)) bad("level ", j, " has spacing ", l.spacing, " and other knot counts than the volume's");
    if (type > uint32_t(ScalarType::Float64) || storageTypeFor(ScalarType(type), 0, 0) != ScalarType(type) || coded > 1 || gradients != (j > 0) ||
        (coded && ScalarType(type) != ScalarType::UInt16) || !std::isfinite(l.offset) || !std::isfinite(l.scale))
      bad("level ", j, " has an impossible value type, code mapping or gradient flag");
    l.type = ScalarType(type);
    l.coded = coded == 1;
    l.gradients = gradients == 1;
    if (j > 0 && l.type != s->mLevels.front().type && !l.coded) bad("level ", j, " holds samples of another type than level 0");
    l.firstBlock = blocks;
    blocks += l.blockCount();
    s->mLevels.push_back(l);
  }
  if (get((uint64_t*)nullptr) != blocks) bad("block count differs from the levels' ", blocks);
  if ((index.size() - pos) / 16 != blocks || (index.size() - pos) % 16) bad("index holds ", index.size() - pos, " bytes for ", blocks, " blocks");
  s->mIndex.resize(size_t(blocks));
  for (StoreBlock& e : s->mIndex) {
    e.offset = get((uint64_t*)nullptr);
    e.size = get((uint32_t*)nullptr);
    e.crc = get((uint32_t*)nullptr);
    if (e.offset > data.size || e.size > data.size - e.offset) bad("a block lies beyond the data section's ", data.size, " bytes");
  }
  return s;
}

std::shared_ptr<const KnotStore::Block> KnotStore::load(size_t level, const glm::ivec3& b, uint64_t key) const {
  const StoreLevel& l = mLevels[level];
  const StoreBlock& e = mIndex[size_t(key)];
  auto where = [&] { return detail::concat(mFile.path(), ": knot store block ", b.x, ",", b.y, ",", b.z, " of spacing ", l.spacing); };
  std::vector<uint8_t> z(e.size);
  mFile.read(mDataOffset + e.offset, e.size, z.data());
  if (kVerifyChecksums && crcOf(z.data(), z.size()) != e.crc) HYB_THROW(IoError, where(), " is corrupt (checksum mismatch)");
  auto made = std::make_shared<Block>();
  made->dims = blockDims(l, b);
  std::vector<uint8_t> planes(rawBytes(l, made->dims));
  const size_t n = ZSTD_decompress(planes.data(), planes.size(), z.data(), z.size());
  if (ZSTD_isError(n) || n != planes.size()) HYB_THROW(IoError, where(), " does not decompress to its ", planes.size(), " bytes");
  made->bytes.resize(planes.size());
  eachPart(l, planes.size(), [&](size_t at, size_t size, size_t width) { fromPlanes(planes.data() + at, size, width, made->bytes.data() + at); });
  const std::lock_guard lock(mMutex);
  ++mStats.misses;
  mStats.bytesRead += e.size;
  return made;
}

std::shared_ptr<const KnotStore::Block> KnotStore::block(size_t level, const glm::ivec3& b) const {
  const uint64_t k = mLevels[level].blockIndex(b);
  {
    const std::lock_guard lock(mMutex);
    if (const auto it = mCache.find(k); it != mCache.end()) {
      mOrder.splice(mOrder.end(), mOrder, it->second.age);
      ++mStats.hits;
      return it->second.block;
    }
  }
  // Read and decompressed outside the lock: other threads' blocks go on.
  std::shared_ptr<const Block> made = load(level, b, k);
  const std::lock_guard lock(mMutex);
  return insert(k, std::move(made));
}

std::shared_ptr<const KnotStore::Block> KnotStore::insert(uint64_t k, std::shared_ptr<const Block> made) const {
  if (const auto it = mCache.find(k); it != mCache.end()) return it->second.block;  // another thread was first
  mOrder.push_back(k);
  mCache.emplace(k, Entry{made, std::prev(mOrder.end())});
  mStats.bytesHeld += made->bytes.size();
  evictToLimit(1);
  return made;
}

void KnotStore::evictToLimit(size_t keep) const {
  while (mStats.limit && mStats.bytesHeld > mStats.limit && mOrder.size() > keep) {
    const auto victim = mCache.find(mOrder.front());
    mStats.bytesHeld -= victim->second.block->bytes.size();
    mCache.erase(victim);
    mOrder.pop_front();
    ++mStats.evicted;
  }
}

namespace {

// Calls @p f(level, block) for each block of @p box.
template <class F>
void forEachBlock(const KnotBox& box, F&& f) {
  const size_t level = size_t(std::countr_zero(unsigned(box.s)));
  const glm::ivec3 b0 = box.lo / kStoreBlock, b1 = (box.lo + box.count - 1) / kStoreBlock;
  for (int bz = b0.z; bz <= b1.z; ++bz)
    for (int by = b0.y; by <= b1.y; ++by)
      for (int bx = b0.x; bx <= b1.x; ++bx) f(level, glm::ivec3(bx, by, bz));
}

}  // namespace

bool KnotStore::cached(const KnotBox& box) const {
  const std::lock_guard lock(mMutex);
  bool all = true;
  forEachBlock(box, [&](size_t level, const glm::ivec3& b) { all = all && mCache.contains(mLevels[level].blockIndex(b)); });
  return all;
}

int KnotStore::coarseSpacing(uint64_t bytes) const {
  size_t level = mLevels.size() - 1;
  uint64_t held = 0;
  for (size_t j = mLevels.size(); j-- > 0;) {
    const StoreLevel& l = mLevels[j];
    held += rawBytes(l, l.counts);
    if (held > bytes) break;
    level = j;
  }
  return mLevels[level].spacing;
}

void KnotStore::prefetch(const std::vector<KnotBox>& boxes) {
  std::deque<std::pair<size_t, glm::ivec3>> queue;
  {
    const std::lock_guard lock(mMutex);
    std::unordered_set<uint64_t> asked;
    uint64_t bytes = 0;
    for (const KnotBox& box : boxes)
      forEachBlock(box, [&](size_t level, const glm::ivec3& b) {
        const StoreLevel& l = mLevels[level];
        const uint64_t k = l.blockIndex(b);
        if (mCache.contains(k) || !asked.insert(k).second) return;
        bytes += rawBytes(l, blockDims(l, b));
        if (!mStats.limit || 2 * bytes <= mStats.limit) queue.emplace_back(level, b);
      });
  }
  Prefetch& p = *mPrefetch;
  {
    const std::lock_guard lock(p.mutex);
    p.queue = std::move(queue);
    if (!p.thread.joinable() && !p.queue.empty()) p.thread = std::thread([this] { prefetchLoop(); });
  }
  p.wake.notify_all();
}

// A block the prefetch thread cannot read is left to the frame that reads it, which names it.
void KnotStore::prefetchLoop() {
  Prefetch& p = *mPrefetch;
  std::unique_lock lock(p.mutex);
  for (;;) {
    p.wake.wait(lock, [&] { return p.stop || !p.queue.empty(); });
    if (p.stop) return;
    const size_t level = p.queue.front().first;
    const glm::ivec3 b = p.queue.front().second;
    p.queue.pop_front();
    p.busy = true;
    lock.unlock();
    const uint64_t k = mLevels[level].blockIndex(b);
    bool have;
    {
      const std::lock_guard cacheLock(mMutex);
      have = mCache.contains(k);
    }
    if (!have) {
      try {
        std::shared_ptr<const Block> made = load(level, b, k);
        const std::lock_guard cacheLock(mMutex);
        insert(k, std::move(made));
      } catch (const std::exception&) {
      }
    }
    lock.lock();
    p.busy = false;
    if (p.queue.empty()) {
      p.idle.notify_all();
      if (p.done) {
        const std::function<void()> done = p.done;
        lock.unlock();
        done();
        lock.lock();
      }
    }
  }
}

size_t KnotStore::prefetchPending() const {
  const std::lock_guard lock(mPrefetch->mutex);
  return mPrefetch->queue.size() + (mPrefetch->busy ? 1 : 0);
}

void KnotStore::waitForPrefetch() const {
  std::unique_lock lock(mPrefetch->mutex);
  mPrefetch->idle.wait(lock, [&] { return mPrefetch->queue.empty() && !mPrefetch->busy; });
}

void KnotStore::onPrefetched(std::function<void()> done) {
  const std::lock_guard lock(mPrefetch->mutex);
  mPrefetch->done = std::move(done);
}

void KnotStore::read(int s, const glm::ivec3& lo, const glm::ivec3& count, float* values, glm::vec3* gradients) const {
  HYB_DCHECK(std::has_single_bit(unsigned(s)) && size_t(std::countr_zero(unsigned(s))) < mLevels.size());
  const size_t level = size_t(std::countr_zero(unsigned(s)));
  const StoreLevel& l = mLevels[level];
  HYB_DCHECK(gradients == nullptr || l.gradients);
  const glm::ivec3 hi = lo + count - 1, b0 = lo / kStoreBlock, b1 = hi / kStoreBlock;
  for (int bz = b0.z; bz <= b1.z; ++bz)
    for (int by = b0.y; by <= b1.y; ++by)
      for (int bx = b0.x; bx <= b1.x; ++bx) {
        const glm::ivec3 b(bx, by, bz), base = b * kStoreBlock;
        const std::shared_ptr<const Block> blk = block(level, b);
        const glm::ivec3 from = glm::max(lo, base), to = glm::min(hi, base + blk->dims - 1);
        const uint8_t* bytes = blk->bytes.data();
        const uint8_t* g = bytes + blockKnots(blk->dims) * scalarSize(l.type);
        detail::withFileType(l.type, [&](auto zero) {
          using T = decltype(zero);
          for (int z = from.z; z <= to.z; ++z)
            for (int y = from.y; y <= to.y; ++y) {
              const size_t src = size_t(from.x - base.x) + size_t(blk->dims.x) * (size_t(y - base.y) + size_t(blk->dims.y) * size_t(z - base.z));
              const size_t dst = size_t(from.x - lo.x) + size_t(count.x) * (size_t(y - lo.y) + size_t(count.y) * size_t(z - lo.z));
              for (int x = 0; x <= to.x - from.x; ++x) values[dst + size_t(x)] = valueOf<T>(l, bytes, src + size_t(x));
              if (gradients)
                for (int x = 0; x <= to.x - from.x; ++x) {
                  const size_t at = 3 * (src + size_t(x));
                  gradients[dst + size_t(x)] =
                      glm::vec3(fromBfloat16(loadAt<uint16_t>(g, at)), fromBfloat16(loadAt<uint16_t>(g, at + 1)), fromBfloat16(loadAt<uint16_t>(g, at + 2)));
                }
            }
        });
      }
}

SampleBlock KnotStore::sampleBlock(const glm::ivec3& v) const {
  const StoreLevel& l = mLevels.front();
  HYB_DCHECK(!l.coded && glm::all(glm::greaterThanEqual(v, glm::ivec3(0))) && glm::all(glm::lessThan(v, mDims)));
  const glm::ivec3 b = v / kStoreBlock;
  std::shared_ptr<const Block> blk = block(0, b);
  SampleBlock out;
  out.lo = b * kStoreBlock;
  out.dims = blk->dims;
  out.type = l.type;
  out.samples = blk->bytes.data();
  out.keep = std::move(blk);
  return out;
}

void KnotStore::forEachValue(int s, const std::function<void(const float* values, size_t n)>& use) const {
  HYB_CHECK(std::has_single_bit(unsigned(s)) && size_t(std::countr_zero(unsigned(s))) < mLevels.size());
  const size_t level = size_t(std::countr_zero(unsigned(s)));
  const StoreLevel& l = mLevels[level];
  const glm::ivec3 nb = l.blocks();
  const uint64_t count = l.blockCount();
  // Read and decoded on all cores a batch at a time, passed on in the index's order.
  constexpr uint64_t kBatch = 64;
  std::vector<std::vector<float>> values(kBatch);
  for (uint64_t first = 0; first < count; first += kBatch) {
    const size_t n = size_t(std::min(kBatch, count - first));
    ParallelFailure failure;
#pragma omp parallel for schedule(dynamic) if (n > 1)
    for (size_t k = 0; k < n; ++k)
      failure.run([&] {
        const uint64_t i = first + k;
        const glm::ivec3 b(int(i % uint64_t(nb.x)), int(i / uint64_t(nb.x) % uint64_t(nb.y)), int(i / (uint64_t(nb.x) * uint64_t(nb.y))));
        const std::shared_ptr<const Block> blk = load(level, b, l.blockIndex(b));
        values[k].resize(size_t(blockKnots(blk->dims)));
        detail::withFileType(l.type, [&](auto zero) {
          for (size_t j = 0; j < values[k].size(); ++j) values[k][j] = valueOf<decltype(zero)>(l, blk->bytes.data(), j);
        });
      });
    failure.rethrow();
    for (size_t k = 0; k < n; ++k) use(values[k].data(), values[k].size());
  }
}

SampleArray KnotStore::samples() const {
  const StoreLevel& l = mLevels.front();
  SampleArray out = detail::allocateSamples(l.type, size_t(blockKnots(mDims)));
  uint8_t* data = std::visit([](auto& v) { return reinterpret_cast<uint8_t*>(v.data()); }, out);
  const size_t size = scalarSize(l.type);
  const glm::ivec3 nb = l.blocks();
  // Past the cache (it would hold them all, or evict what the frames use), on all cores.
  ParallelFailure failure;
#pragma omp parallel for schedule(dynamic) collapse(2)
  for (int bz = 0; bz < nb.z; ++bz)
    for (int by = 0; by < nb.y; ++by)
      failure.run([&] {
        for (int bx = 0; bx < nb.x; ++bx) {
          const glm::ivec3 b(bx, by, bz), base = b * kStoreBlock;
          const std::shared_ptr<const Block> blk = load(0, b, l.blockIndex(b));
          for (int z = 0; z < blk->dims.z; ++z)
            for (int y = 0; y < blk->dims.y; ++y) {
              const size_t src = size_t(blk->dims.x) * (size_t(y) + size_t(blk->dims.y) * size_t(z));
              const size_t dst = size_t(base.x) + size_t(mDims.x) * (size_t(base.y + y) + size_t(mDims.y) * size_t(base.z + z));
              std::memcpy(data + dst * size, blk->bytes.data() + src * size, size * size_t(blk->dims.x));
            }
        }
      });
  failure.rethrow();
  return out;
}

uint64_t KnotStore::setCacheLimit(uint64_t bytes) {
  uint64_t freed = 0;
  {
    const std::lock_guard lock(mMutex);
    mStats.limit = bytes;
    const uint64_t held = mStats.bytesHeld;
    evictToLimit(0);
    freed = held - mStats.bytesHeld;
  }
  return freed;
}

void KnotStore::giveBackFreed(uint64_t freed) {
  // The blocks' frees leave the heap's pages resident though unused, and what takes their room
  // (a surface's large arrays) is mapped afresh: handed back, the process follows the bound.
  if (freed > kTrimAfterBytes) malloc_trim(0);
}

StoreCacheStats KnotStore::cacheStats() const {
  const std::lock_guard lock(mMutex);
  return mStats;
}

}  // namespace hyb
