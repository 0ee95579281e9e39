#include "hybrid_octree/knot_store.h"

#include <zlib.h>
#include <zstd.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cstring>

#include "volume/error.h"
#include "volume/parallel.h"
#include "volume/reader_util.h"

namespace hyb {

namespace {

uint32_t crcOf(const uint8_t* p, size_t n) { return uint32_t(crc32_z(crc32_z(0L, Z_NULL, 0), p, n)); }

glm::ivec3 blockDims(const StoreLevel& l, const glm::ivec3& b) { return glm::min(glm::ivec3(kStoreBlock), l.counts - b * kStoreBlock); }

constexpr size_t kGradientBytes = 3 * sizeof(uint16_t);  // bfloat16 x, y, z

uint64_t blockKnots(const glm::ivec3& d) { return uint64_t(d.x) * uint64_t(d.y) * uint64_t(d.z); }

uint64_t rawBytes(const StoreLevel& l, const glm::ivec3& d) {
  return blockKnots(d) * (scalarSize(l.type) + (l.gradients ? kGradientBytes : 0));
}

// The levels of a volume's store: spacing 1 up to the root's edge (a root brick at level 0).
std::vector<StoreLevel> storeLevels(const Volume& v, const VolumeOctree& t) {
  std::vector<StoreLevel> levels;
  uint64_t first = 0;
  for (int j = 0; j <= t.depth(); ++j) {
    StoreLevel l;
    l.spacing = 1 << j;
    l.counts = knotCounts(v.dims(), l.spacing);
    l.coded = l.spacing > 1 && t.prefilteredAt(l.spacing);
    l.type = l.coded ? ScalarType::UInt16 : v.storedType();
    if (l.coded) {
      l.offset = t.knots().offset(l.spacing);
      l.scale = t.knots().scale(l.spacing);
    }
    l.gradients = l.spacing > 1;
    l.firstBlock = first;
    first += l.blockCount();
    levels.push_back(l);
  }
  return levels;
}

// The raw bytes of block @p b of level @p l: its knots' values in the level's type, then for
// s ≥ 2 their gradients.
std::vector<uint8_t> rawBlock(const Volume& v, const VolumeOctree& t, const StoreLevel& l, const glm::ivec3& b) {
  const glm::ivec3 d = blockDims(l, b), lo = b * kStoreBlock, n = v.dims();
  std::vector<uint8_t> out(rawBytes(l, d));
  const int s = l.spacing;
  std::array<std::vector<int>, 3> at;  // the knots' voxel positions along each axis
  for (int a = 0; a < 3; ++a)
    for (int j = 0; j < d[a]; ++j) at[size_t(a)].push_back(knotPosition(lo[a] + j, s, n[a]));
  if (l.coded) {
    uint16_t* q = reinterpret_cast<uint16_t*>(out.data());
    for (int k = 0; k < d.z; ++k)
      for (int j = 0; j < d.y; ++j)
        for (int i = 0; i < d.x; ++i) *q++ = t.knots().code(s, lo + glm::ivec3(i, j, k));
  } else {
    v.visitSamples([&](const auto* data) {
      using T = std::remove_cv_t<std::remove_pointer_t<decltype(data)>>;
      T* q = reinterpret_cast<T*>(out.data());
      for (int k = 0; k < d.z; ++k)
        for (int j = 0; j < d.y; ++j)
          for (int i = 0; i < d.x; ++i) *q++ = data[v.index(at[0][size_t(i)], at[1][size_t(j)], at[2][size_t(k)])];
    });
  }
  if (l.gradients) {
    uint16_t* g = reinterpret_cast<uint16_t*>(out.data() + blockKnots(d) * scalarSize(l.type));
    for (int k = 0; k < d.z; ++k)
      for (int j = 0; j < d.y; ++j)
        for (int i = 0; i < d.x; ++i) {
          const glm::vec3 q = v.gradientAt(at[0][size_t(i)], at[1][size_t(j)], at[2][size_t(k)]);
          for (int a = 0; a < 3; ++a) *g++ = toBfloat16(q[a]);
        }
  }
  return out;
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

// The value of knot @p i of a block's bytes, exactly as the in-memory source gives it.
template <class T>
float valueOf(const StoreLevel& l, const uint8_t* bytes, size_t i) {
  T v;
  std::memcpy(&v, bytes + i * sizeof(T), sizeof(T));
  if constexpr (std::is_same_v<T, uint16_t>)
    if (l.coded) return l.offset + l.scale * float(v);
  return float(v);
}

}  // namespace

std::vector<uint8_t> writeKnotStore(const Volume& v, const VolumeOctree& t, std::ostream& out) {
  const std::vector<StoreLevel> levels = storeLevels(v, t);
  std::vector<StoreBlock> index(size_t(levels.back().firstBlock + levels.back().blockCount()));
  uint64_t offset = 0;
  for (auto l = levels.rbegin(); l != levels.rend(); ++l) {
    const glm::ivec3 nb = l->blocks();
    std::vector<glm::ivec3> order;
    for (int z = 0; z < nb.z; ++z)
      for (int y = 0; y < nb.y; ++y)
        for (int x = 0; x < nb.x; ++x) order.emplace_back(x, y, z);
    std::sort(order.begin(), order.end(), [](const glm::ivec3& a, const glm::ivec3& b) { return morton(a) < morton(b); });
    // Compressed on all cores a batch at a time, written in order: the bytes held are a batch's.
    constexpr size_t kBatch = 64;
    for (size_t first = 0; first < order.size(); first += kBatch) {
      const size_t count = std::min(kBatch, order.size() - first);
      std::vector<std::vector<uint8_t>> packed(count);
      ParallelFailure failure;
#pragma omp parallel for schedule(dynamic) if (count > 1)
      for (size_t k = 0; k < count; ++k)
        failure.run([&] {
          const std::vector<uint8_t> block = rawBlock(v, t, *l, order[first + k]);
          std::vector<uint8_t> raw(block.size());
          eachPart(*l, block.size(), [&](size_t at, size_t n, size_t width) { toPlanes(block.data() + at, n, width, raw.data() + at); });
          std::vector<uint8_t>& z = packed[k];
          z.resize(ZSTD_compressBound(raw.size()));
          const size_t n = ZSTD_compress(z.data(), z.size(), raw.data(), raw.size(), kStoreCompression);
          if (ZSTD_isError(n)) HYB_THROW(RuntimeError, "zstd: ", ZSTD_getErrorName(n));
          z.resize(n);
        });
      failure.rethrow();
      for (size_t k = 0; k < count; ++k) {
        const glm::ivec3 b = order[first + k];
        StoreBlock& e = index[size_t(l->blockIndex(b))];
        e = StoreBlock{offset, uint32_t(packed[k].size()), crcOf(packed[k].data(), packed[k].size())};
        out.write(reinterpret_cast<const char*>(packed[k].data()), std::streamsize(packed[k].size()));
        offset += packed[k].size();
      }
    }
  }
  std::vector<uint8_t> bytes;
  put(&bytes, uint32_t(kStoreBlock));
  put(&bytes, uint32_t(levels.size()));
  for (const StoreLevel& l : levels) {
    put(&bytes, int32_t(l.spacing));
    put(&bytes, l.counts);
    put(&bytes, uint32_t(l.type));
    put(&bytes, uint8_t(l.coded));
    put(&bytes, l.offset);
    put(&bytes, l.scale);
    put(&bytes, uint8_t(l.gradients));
  }
  put(&bytes, uint64_t(index.size()));
  for (const StoreBlock& e : index) {
    put(&bytes, e.offset);
    put(&bytes, e.size);
    put(&bytes, e.crc);
  }
  return bytes;
}

std::shared_ptr<KnotStore> KnotStore::open(const std::string& path, const glm::ivec3& dims, const glm::dvec3& spacing,
                                           const std::vector<uint8_t>& index, uint64_t dataOffset, uint64_t dataSize,
                                           uint64_t cacheBytes) {
  std::shared_ptr<KnotStore> s(new KnotStore(path));
  s->mDims = dims;
  s->mSpacing = spacing;
  s->mDataOffset = dataOffset;
  s->mDataSize = dataSize;
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
    if (e.offset > dataSize || e.size > dataSize - e.offset) bad("a block lies beyond the data section's ", dataSize, " bytes");
  }
  return s;
}

std::shared_ptr<const KnotStore::Block> KnotStore::load(size_t level, const glm::ivec3& b, uint64_t key) const {
  const StoreLevel& l = mLevels[level];
  const StoreBlock& e = mIndex[size_t(key)];
  auto where = [&] { return detail::concat(mFile.path(), ": knot store block ", b.x, ",", b.y, ",", b.z, " of spacing ", l.spacing); };
  std::vector<uint8_t> z(e.size);
  mFile.read(mDataOffset + e.offset, e.size, z.data());
  if (crcOf(z.data(), z.size()) != e.crc) HYB_THROW(IoError, where(), " is corrupt (checksum mismatch)");
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
  if (const auto it = mCache.find(k); it != mCache.end()) return it->second.block;  // another thread was first
  mOrder.push_back(k);
  mCache.emplace(k, Entry{made, std::prev(mOrder.end())});
  mStats.bytesHeld += made->bytes.size();
  while (mStats.limit && mStats.bytesHeld > mStats.limit && mOrder.size() > 1) {
    const auto victim = mCache.find(mOrder.front());
    mStats.bytesHeld -= victim->second.block->bytes.size();
    mCache.erase(victim);
    mOrder.pop_front();
    ++mStats.evicted;
  }
  return made;
}

void KnotStore::read(int s, const glm::ivec3& lo, const glm::ivec3& count, float* values, glm::vec3* gradients) const {
  HYB_DCHECK(std::has_single_bit(unsigned(s)) && size_t(std::countr_zero(unsigned(s))) < mLevels.size());
  const size_t level = size_t(std::countr_zero(unsigned(s)));
  const StoreLevel& l = mLevels[level];
  if (level == 0 && mSamples) {
    for (int z = 0; z < count.z; ++z)
      for (int y = 0; y < count.y; ++y, values += count.x) mSamples->readRow(lo.x, lo.y + y, lo.z + z, count.x, values);
    return;
  }
  HYB_DCHECK((gradients != nullptr) == l.gradients);
  const glm::ivec3 hi = lo + count - 1, b0 = lo / kStoreBlock, b1 = hi / kStoreBlock;
  for (int bz = b0.z; bz <= b1.z; ++bz)
    for (int by = b0.y; by <= b1.y; ++by)
      for (int bx = b0.x; bx <= b1.x; ++bx) {
        const glm::ivec3 b(bx, by, bz), base = b * kStoreBlock;
        const std::shared_ptr<const Block> blk = block(level, b);
        const glm::ivec3 from = glm::max(lo, base), to = glm::min(hi, base + blk->dims - 1);
        const uint8_t* bytes = blk->bytes.data();
        const uint16_t* g = reinterpret_cast<const uint16_t*>(bytes + blockKnots(blk->dims) * scalarSize(l.type));
        detail::withFileType(l.type, [&](auto zero) {
          using T = decltype(zero);
          for (int z = from.z; z <= to.z; ++z)
            for (int y = from.y; y <= to.y; ++y) {
              const size_t src = size_t(from.x - base.x) + size_t(blk->dims.x) * (size_t(y - base.y) + size_t(blk->dims.y) * size_t(z - base.z));
              const size_t dst = size_t(from.x - lo.x) + size_t(count.x) * (size_t(y - lo.y) + size_t(count.y) * size_t(z - lo.z));
              for (int x = 0; x <= to.x - from.x; ++x) values[dst + size_t(x)] = valueOf<T>(l, bytes, src + size_t(x));
              if (gradients)
                for (int x = 0; x <= to.x - from.x; ++x) {
                  const uint16_t* q = g + 3 * (src + size_t(x));
                  gradients[dst + size_t(x)] = glm::vec3(fromBfloat16(q[0]), fromBfloat16(q[1]), fromBfloat16(q[2]));
                }
            }
        });
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

void KnotStore::useSamples(const Volume& volume) {
  HYB_CHECK(volume.hasSamples() && volume.dims() == mDims && volume.storedType() == storedType());
  const std::lock_guard lock(mMutex);
  mSamples = &volume;
  const uint64_t finest = mLevels.size() > 1 ? mLevels[1].firstBlock : mIndex.size();
  for (auto it = mOrder.begin(); it != mOrder.end();) {
    if (*it >= finest) {
      ++it;
      continue;
    }
    const auto entry = mCache.find(*it);
    mStats.bytesHeld -= entry->second.block->bytes.size();
    mCache.erase(entry);
    it = mOrder.erase(it);
  }
}

void KnotStore::setCacheLimit(uint64_t bytes) {
  const std::lock_guard lock(mMutex);
  mStats.limit = bytes;
}

StoreCacheStats KnotStore::cacheStats() const {
  const std::lock_guard lock(mMutex);
  return mStats;
}

}  // namespace hyb
