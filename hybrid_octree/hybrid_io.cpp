#include "hybrid_octree/hybrid_io.h"

#include <zlib.h>

#include <bit>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <functional>
#include <map>
#include <optional>
#include <ostream>
#include <span>

#include "hybrid_octree/knot_store.h"
#include "surface/mesh_ops.h"
#include "volume/core/error.h"
#include "volume/core/file_util.h"
#include "volume/core/memory_limit.h"
#include "volume/dicomweb.h"
#include "volume/reader_util.h"
#include "volume/volume_io.h"

namespace hyb {

namespace {

static_assert(std::endian::native == std::endian::little, "scene files are written in native little-endian order");

constexpr char kMagic[8] = {'H', 'Y', 'B', 'O', 'C', 'T', '\x1a', '\n'};
constexpr uint32_t tag(const char (&s)[5]) {
  return uint32_t(uint8_t(s[0])) | uint32_t(uint8_t(s[1])) << 8 | uint32_t(uint8_t(s[2])) << 16 | uint32_t(uint8_t(s[3])) << 24;
}
constexpr uint32_t kVolumeTag = tag("VOLM");
constexpr uint32_t kOctreeTag = tag("VOCT");
constexpr uint32_t kSurfaceTag = tag("SURF");
constexpr uint32_t kBlocksTag = tag("KDAT");
constexpr uint32_t kIndexTag = tag("KIDX");
constexpr uint32_t kAlignTag = tag("ALGN");  // padding: the octree's arrays start 8-byte aligned, to be mapped in place

// Appends plain values and arrays to a byte buffer.
class Writer {
 public:
  template <typename T>
  void put(const T& v) {
    static_assert(std::is_trivially_copyable_v<T>);
    append(&v, sizeof(T));
  }
  template <typename T>
  void putArray(const std::vector<T>& v) {
    static_assert(std::is_trivially_copyable_v<T>);
    put(uint64_t(v.size()));
    append(v.data(), v.size() * sizeof(T));
  }
  const std::vector<uint8_t>& bytes() const { return mBytes; }

 private:
  void append(const void* p, size_t n) {
    const size_t at = mBytes.size();
    mBytes.resize(at + n);
    if (n) std::memcpy(mBytes.data() + at, p, n);
  }
  std::vector<uint8_t> mBytes;
};

// Reads plain values and arrays from a byte range, throwing on overrun.
class Reader {
 public:
  Reader(const uint8_t* data, size_t size, std::string what) : mData(data), mSize(size), mWhat(std::move(what)) {}
  template <typename T>
  T get() {
    need(sizeof(T));
    T v;
    std::memcpy(&v, mData + mPos, sizeof(T));
    mPos += sizeof(T);
    return v;
  }
  /// Throws unless @p n items of @p each bytes remain.
  void needItems(uint64_t n, size_t each) {
    if (n > (mSize - mPos) / each) fail(n * each);
  }
  template <typename T>
  std::vector<T> getArray() {
    const uint64_t n = get<uint64_t>();
    needItems(n, sizeof(T));
    std::vector<T> v(static_cast<size_t>(n));
    std::memcpy(v.data(), mData + mPos, size_t(n) * sizeof(T));
    mPos += size_t(n) * sizeof(T);
    return v;
  }
  /// An array laid out as getArray reads it, left in place: where its items start, and how many.
  template <typename T>
  std::pair<const uint8_t*, size_t> skipArray() {
    const uint64_t n = get<uint64_t>();
    needItems(n, sizeof(T));
    const uint8_t* at = mData + mPos;
    mPos += size_t(n) * sizeof(T);
    return {at, size_t(n)};
  }
  size_t left() const { return mSize - mPos; }

 private:
  void need(size_t n) {
    if (n > mSize - mPos) fail(n);
  }
  [[noreturn]] void fail(uint64_t n) {
    HYB_THROW(IoError, mWhat, ": section too short (needs ", n, " more bytes at offset ", mPos, " of ", mSize, ")");
  }
  const uint8_t* mData;
  size_t mSize;
  size_t mPos = 0;
  std::string mWhat;
};

// Surface nodes as encodeSurfaceNode lays them out, from a mapped section: its pages are given back
// every kReleaseBytes, so that the load holds the nodes and not the section's bytes too.
std::vector<SurfaceNode> getSurfaceNodes(Reader& r, const InputFile::Mapping& mapping) {
  constexpr size_t kReleaseBytes = size_t(64) << 20;
  const auto [at, n] = r.skipArray<std::array<uint8_t, kSurfaceNodeBytes>>();
  std::vector<SurfaceNode> nodes(n);
  for (size_t i = 0; i < n; ++i) {
    nodes[i] = decodeSurfaceNode(at + i * kSurfaceNodeBytes);
    if ((i + 1) % (kReleaseBytes / kSurfaceNodeBytes) == 0) mapping.release();
  }
  mapping.release();
  return nodes;
}

// A 64-bit content hash (murmur3's finaliser over 8-byte words; not cryptographic) of a byte
// sequence fed in pieces: the identity of the volume section that the octree sections were built from.
class ContentHash {
 public:
  explicit ContentHash(uint64_t size) : mH(kGolden ^ size) {}
  void update(const uint8_t* p, size_t n) {
    while (n) {
      if (mFill == 0 && n >= 8) {
        for (; n >= 8; p += 8, n -= 8) word(p);
        continue;
      }
      const size_t take = std::min(n, 8 - mFill);
      std::memcpy(mPending + mFill, p, take);
      mFill += take;
      p += take;
      n -= take;
      if (mFill == 8) {
        word(mPending);
        mFill = 0;
      }
    }
  }
  uint64_t finish() const {
    uint64_t tail = 0;
    std::memcpy(&tail, mPending, mFill);
    return mix(mH ^ tail);
  }

 private:
  static constexpr uint64_t kGolden = 0x9e3779b97f4a7c15ULL;
  static uint64_t mix(uint64_t h) {
    h ^= h >> 33;
    h *= 0xff51afd7ed558ccdULL;
    h ^= h >> 33;
    h *= 0xc4ceb9fe1a85ec53ULL;
    return h ^ (h >> 33);
  }
  void word(const uint8_t* p) {
    uint64_t w;
    std::memcpy(&w, p, 8);
    mH = mix(mH ^ w) + kGolden;
  }
  uint64_t mH;
  uint8_t mPending[8] = {};
  size_t mFill = 0;
};

// A section's payload as the pieces it is written from (the samples are not copied).
struct Section {
  uint32_t tag = 0;
  std::vector<std::pair<const uint8_t*, size_t>> pieces;
  uint64_t size() const {
    uint64_t n = 0;
    for (const auto& piece : pieces) n += piece.second;
    return n;
  }
  uint32_t crc() const {
    uLong c = crc32_z(0L, Z_NULL, 0);
    for (const auto& piece : pieces) c = crc32_z(c, piece.first, piece.second);
    return uint32_t(c);
  }
  uint64_t hash() const {
    ContentHash h(size());
    for (const auto& piece : pieces) h.update(piece.first, piece.second);
    return h.finish();
  }
};

// The hash the octree sections carry of the volume they were built from: its header and the
// store's index, which holds every block's CRC.
uint64_t volumeHashOf(const std::vector<uint8_t>& volume, const std::vector<uint8_t>& index) {
  return Section{0, {{volume.data(), volume.size()}, {index.data(), index.size()}}}.hash();
}

// What a SURF section is written from: its header's fields and its nodes, encoded a piece at a
// time (an octree in memory, or one whose nodes wait in a temporary file).
struct SurfaceSection {
  float iso = 0;
  uint64_t cells = 0;
  int32_t mergeEdge = 0;
  uint64_t nodeCount = 0;
  std::function<void(const SurfaceNodeSink&)> encodeNodes;
};

template <class Octree>
SurfaceSection surfaceSectionOf(const Octree& so) {
  return {so.isovalue(), uint64_t(so.cellCount()), int32_t(so.mergeEdge()), uint64_t(so.nodeCount()),
          [&so](const SurfaceNodeSink& sink) { so.encodeNodes(sink); }};
}

std::optional<SurfaceSection> optionalSurfaceSection(const SurfaceOctree* so) { return so ? std::optional(surfaceSectionOf(*so)) : std::nullopt; }

}  // namespace

namespace {

// The scene of @p volume (its header: samples need not be held), whose knot store @p writeStore
// writes to the stream and returns the index of.
void writeScene(const std::string& path, const Volume& volume, const VolumeOctree& octree, const SurfaceSection* surface,
                const std::function<std::vector<uint8_t>(std::ostream&)>& writeStore) {
  Writer vol;
  vol.put(volume.dims());
  vol.put(volume.spacing());
  vol.put(uint32_t(volume.sourceType()));
  vol.put(uint32_t(volume.storedType()));
  vol.put(uint64_t(volume.voxelCount()));
  vol.put(volume.minValue());
  vol.put(volume.maxValue());
  vol.put(volume.frame().direction);
  vol.put(volume.frame().origin);
  vol.put(uint8_t(volume.frame().assumed));
  vol.put(uint64_t(volume.info().size()));
  for (const auto& [key, value] : volume.info()) {
    vol.putArray(std::vector<char>(key.begin(), key.end()));
    vol.putArray(std::vector<char>(value.begin(), value.end()));
  }
  writeFileAtomically(path, [&](std::ostream& out) {
    auto sectionHeader = [&](uint32_t t, uint64_t size, uint32_t c) {
      out.write(reinterpret_cast<const char*>(&t), 4);
      out.write(reinterpret_cast<const char*>(&size), 8);
      out.write(reinterpret_cast<const char*>(&c), 4);
    };
    auto writeSection = [&](const Section& section) {
      sectionHeader(section.tag, section.size(), section.crc());
      for (const auto& [data, size] : section.pieces) out.write(reinterpret_cast<const char*>(data), std::streamsize(size));
    };
    auto write = [&](uint32_t t, const std::vector<uint8_t>& bytes) { writeSection(Section{t, {{bytes.data(), bytes.size()}}}); };
    out.write(kMagic, sizeof kMagic);
    const uint32_t header[2] = {kSceneVersion, surface ? 6u : 5u};  // VOLM, KDAT, KIDX, ALGN, VOCT and SURF
    out.write(reinterpret_cast<const char*>(header), sizeof header);
    write(kVolumeTag, vol.bytes());
    // The blocks stream out as they are compressed; their section's size is known at its end.
    const std::streampos sizeAt = out.tellp() + std::streamoff(4);
    sectionHeader(kBlocksTag, 0, 0);
    const std::streampos start = out.tellp();
    const std::vector<uint8_t> indexBytes = writeStore(out);
    const uint64_t blocksSize = uint64_t(out.tellp() - start);
    out.seekp(sizeAt);
    out.write(reinterpret_cast<const char*>(&blocksSize), 8);
    out.seekp(0, std::ios::end);
    write(kIndexTag, indexBytes);
    const uint64_t volumeHash = volumeHashOf(vol.bytes(), indexBytes);
    // The octree section's header and arrays start at multiples of 8 (its header is 16 bytes, an
    // array's count 8, a node 24), so that a reader maps them in place.
    const std::vector<uint8_t> padding(size_t((8 - (uint64_t(out.tellp()) + 16) % 8) % 8), 0);
    write(kAlignTag, padding);
    // The node and error arrays are written from where they lie (the phantom's are 390 MB): the
    // section is its header fields, then each array as Writer::putArray lays it out.
    Writer oct, nodeCount, errorCount;
    oct.put(volumeHash);
    oct.put(int32_t(octree.leafEdge()));
    oct.put(uint32_t(octree.prefiltered()));
    nodeCount.put(uint64_t(octree.nodes().size()));
    errorCount.put(uint64_t(octree.errorData().size()));
    writeSection(Section{kOctreeTag,
                         {{oct.bytes().data(), oct.bytes().size()},
                          {nodeCount.bytes().data(), nodeCount.bytes().size()},
                          {reinterpret_cast<const uint8_t*>(octree.nodes().data()), octree.nodes().size() * sizeof(OctreeNode)},
                          {errorCount.bytes().data(), errorCount.bytes().size()},
                          {reinterpret_cast<const uint8_t*>(octree.errorData().data()), octree.errorData().size() * sizeof(float)}}});
    if (surface) {  // streamed: its size and CRC are known at its end
      Writer head;
      head.put(volumeHash);
      head.put(surface->iso);
      head.put(surface->cells);
      head.put(surface->mergeEdge);
      head.put(surface->nodeCount);
      const std::streampos headerAt = out.tellp();
      sectionHeader(kSurfaceTag, 0, 0);
      uint64_t size = head.bytes().size();
      uLong crc = crc32_z(crc32_z(0L, Z_NULL, 0), head.bytes().data(), head.bytes().size());
      out.write(reinterpret_cast<const char*>(head.bytes().data()), std::streamsize(head.bytes().size()));
      surface->encodeNodes([&](std::span<const uint8_t> bytes) {
        crc = crc32_z(crc, bytes.data(), bytes.size());
        size += bytes.size();
        out.write(reinterpret_cast<const char*>(bytes.data()), std::streamsize(bytes.size()));
      });
      HYB_CHECK(size == head.bytes().size() + surface->nodeCount * kSurfaceNodeBytes);
      out.seekp(headerAt);
      sectionHeader(kSurfaceTag, size, uint32_t(crc));
      out.seekp(0, std::ios::end);
    }
  });
}

// The directory a scene is written in, where its store's blocks wait.
std::string directoryOf(const std::string& path) { return std::filesystem::path(path).parent_path().string(); }

}  // namespace

void saveScene(const std::string& path, const Volume& volume, const VolumeOctree& octree, const SurfaceOctree* surface) {
  const std::optional<SurfaceSection> section = optionalSurfaceSection(surface);
  writeScene(path, volume, octree, section ? &*section : nullptr, [&](std::ostream& out) { return writeKnotStore(volume, octree, out, directoryOf(path)); });
}

void saveScene(const std::string& path, const Volume& description, const VolumeOctree& octree, KnotStoreWriter& store,
               const SurfaceOctree* surface) {
  const std::optional<SurfaceSection> section = optionalSurfaceSection(surface);
  writeScene(path, description, octree, section ? &*section : nullptr, [&](std::ostream& out) { return store.finish(out); });
}

void saveScene(const std::string& path, const Volume& description, const VolumeOctree& octree, KnotStoreWriter& store,
               const SpooledSurfaceOctree& surface) {
  const SurfaceSection section = surfaceSectionOf(surface);
  writeScene(path, description, octree, &section, [&](std::ostream& out) { return store.finish(out); });
}

std::string spoolDirectoryFor(const std::string& path) { return directoryOf(path); }

KnotStoreWriter storeWriterFor(const std::string& path, const PlaneSource& planes) {
  return KnotStoreWriter(planes.dims(), planes.storedType(), directoryOf(path));
}

bool isSceneFile(const std::string& path) {
  // Through InputFile: a FIFO named like a volume must be refused by its reader, not block here.
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) return false;
  try {
    const InputFile file(path);
    uint8_t m[8] = {};
    if (file.size() < 8) return false;
    file.read(0, 8, m);
    return std::memcmp(m, kMagic, 8) == 0;
  } catch (const IoError&) {
    return false;
  }
}

namespace {

// Refuses a scene file version this build does not read, saying what to do about it.
void checkSceneVersion(uint32_t version, const std::string& path) {
  if (version > 0 && version < 3)
    HYB_THROW(IoError, path, ": scene file version ", version, " has no patient orientation (this build reads version ", kSceneVersion,
              "); build the scene again from its volume with hybrid-octree build");
  if (version == 3)
    HYB_THROW(IoError, path, ": scene file version 3 does not tie its octrees to its volume (this build reads version ", kSceneVersion,
              "); build the scene again from its volume with hybrid-octree build");
  if (version == 4)
    HYB_THROW(IoError, path, ": scene file version 4 holds its samples as float (this build reads version ", kSceneVersion,
              ", samples in their own type); build the scene again from its volume with hybrid-octree build");
  if (version == 5)
    HYB_THROW(IoError, path, ": scene file version 5 has no knot store (this build reads version ", kSceneVersion,
              ", which pages its bricks); build the scene again from its volume with hybrid-octree build");
  if (version != kSceneVersion)
    HYB_THROW(IoError, path, ": scene file version ", version, " unsupported (this build reads version ", kSceneVersion, ")");
}

// A scene file's sections, by tag (a repeated tag: the last one), each checked as it is read.
struct SceneSections {
  struct Entry {
    uint64_t offset = 0, size = 0;
    uint32_t crc = 0, index = 0;
  };
  const InputFile& file;
  const std::string& path;
  std::map<uint32_t, Entry> entries;

  // The header and the table of sections of @p file.
  SceneSections(const InputFile& f, const std::string& p) : file(f), path(p) {
    uint8_t top[16] = {};
    if (file.size() < 16) HYB_THROW(IoError, path, ": not a hybrid-octree scene file (expected magic HYBOCT)");
    file.read(0, 16, top);
    if (std::memcmp(top, kMagic, 8) != 0) HYB_THROW(IoError, path, ": not a hybrid-octree scene file (expected magic HYBOCT)");
    Reader header(top + 8, 8, path);
    const uint32_t version = header.get<uint32_t>();
    const uint32_t count = header.get<uint32_t>();
    checkSceneVersion(version, path);
    uint64_t pos = 16;
    for (uint32_t s = 0; s < count; ++s) {
      if (file.size() - pos < 16) HYB_THROW(IoError, path, ": truncated scene file (section ", s, " of ", count, " header missing)");
      uint8_t h[16];
      file.read(pos, 16, h);
      uint32_t t;
      Entry e;
      std::memcpy(&t, h, 4);
      std::memcpy(&e.size, h + 4, 8);
      std::memcpy(&e.crc, h + 12, 4);
      e.offset = pos + 16;
      e.index = s;
      if (e.size > file.size() - e.offset)
        HYB_THROW(IoError, path, ": truncated scene file (section ", s, " needs ", e.size, " bytes, ", file.size() - e.offset, " left)");
      entries[t] = e;
      pos = e.offset + e.size;
    }
  }
  const Entry& entry(uint32_t t, const char* name) const {
    const auto it = entries.find(t);
    if (it == entries.end()) HYB_THROW(IoError, path, ": scene file lacks the ", name, " section");
    return it->second;
  }
  [[noreturn]] void corrupt(const Entry& e) const { HYB_THROW(IoError, path, ": corrupt scene file (checksum mismatch in section ", e.index, ")"); }
  // A section other than the store's blocks: read whole and checked.
  std::vector<uint8_t> payload(const Entry& e) const {
    std::vector<uint8_t> bytes = file.bytes(e.offset, e.size);
    if (kVerifyChecksums && Section{0, {{bytes.data(), bytes.size()}}}.crc() != e.crc) corrupt(e);
    return bytes;
  }
  // Sections spliced from another scene of the same size would otherwise load and show the wrong data.
  void checkSameVolume(uint64_t hash, uint64_t volumeHash, const char* name) const {
    if (hash != volumeHash)
      HYB_THROW(IoError, path, ": the ", name, " section was built from another volume than the scene's (content hash mismatch)");
  }
};

// The volume section and the knot store into @p scene (their samples too when asked); returns the
// volume's content hash, which the octrees' sections must carry.
uint64_t loadVolumeSection(const SceneSections& sections, const SceneLoadOptions& options, Scene* scene) {
  const std::string& path = sections.path;
  const std::vector<uint8_t> vb = sections.payload(sections.entry(kVolumeTag, "volume"));
  Reader r(vb.data(), vb.size(), path);
  const glm::ivec3 dims = r.get<glm::ivec3>();
  const glm::dvec3 spacing = r.get<glm::dvec3>();
  const uint32_t type = r.get<uint32_t>(), stored = r.get<uint32_t>();
  const uint64_t samples = r.get<uint64_t>();
  const float lo = r.get<float>(), hi = r.get<float>();
  if (type > uint32_t(ScalarType::Float64)) HYB_THROW(IoError, path, ": unknown sample type code ", type);
  const ScalarType storedType = ScalarType(stored);
  if (stored > uint32_t(ScalarType::Float64) || storageTypeFor(storedType, 0, 0) != storedType)
    HYB_THROW(IoError, path, ": stored sample type code ", stored, " invalid (expected uint8, int8, uint16, int16 or float32)");
  validateDims(dims, path);
  if (samples != uint64_t(dims.x) * uint64_t(dims.y) * uint64_t(dims.z))
    HYB_THROW(IoError, path, ": volume section holds ", samples, " samples for dims ", dims.x, "x", dims.y, "x", dims.z);
  scene->volume = Volume::withoutSamples({dims, spacing, ScalarType(type), storedType}, lo, hi, path);
  const glm::dmat3 direction = r.get<glm::dmat3>();
  const glm::dvec3 origin = r.get<glm::dvec3>();
  PatientFrame frame = makePatientFrame(direction, origin, path);
  if (glm::length(frame.direction[0] - direction[0]) + glm::length(frame.direction[1] - direction[1]) +
          glm::length(frame.direction[2] - direction[2]) > 1e-9)
    HYB_THROW(IoError, path, ": corrupt scene file (the volume's direction matrix is not orthonormal)");
  const uint8_t assumed = r.get<uint8_t>();
  if (assumed > 1) HYB_THROW(IoError, path, ": orientation flag ", int(assumed), " invalid (expected 0 or 1)");
  frame.assumed = assumed == 1;
  scene->volume.setFrame(frame);
  const uint64_t infoCount = r.get<uint64_t>();
  for (uint64_t i = 0; i < infoCount; ++i) {
    const std::vector<char> key = r.getArray<char>(), value = r.getArray<char>();
    scene->volume.addInfo(std::string(key.begin(), key.end()), std::string(value.begin(), value.end()));
  }
  // The knot store: its index is checked here, each block when it is read.
  const SceneSections::Entry& blocks = sections.entry(kBlocksTag, "knot store data");
  const std::vector<uint8_t> index = sections.payload(sections.entry(kIndexTag, "knot store index"));
  const uint64_t volumeHash = volumeHashOf(vb, index);
  scene->knots = KnotStore::open(path, dims, spacing, index, {blocks.offset, blocks.size}, options.memoryBytes);
  if (scene->knots->storedType() != storedType)
    HYB_THROW(IoError, path, ": the knot store holds ", scalarName(scene->knots->storedType()), " samples for a volume of ", scalarName(storedType));
  if (options.samples) {
    checkMemory(path, samples * scalarSize(storedType), "the scene's samples");
    try {
      scene->volume.attachSamples(scene->knots->samples(), path);
    } catch (const ValueError& e) {
      HYB_THROW(IoError, e.what(), " (corrupt scene file: its knot store disagrees with its volume section)");
    }
    scene->knots.reset();
  }
  return volumeHash;
}

// The Volume Octree's section into @p scene. Mapped, not read (390 MB on the phantom): the
// checksum and the checks read it through the mapping, then its pages are given back, so that a
// frame holds only the nodes it reads (the kernel pages them in from the file, and may drop them
// again). Arrays off their alignment (a scene written before its octree was aligned) are copied.
void loadOctreeSection(const SceneSections& sections, uint64_t volumeHash, Scene* scene) {
  const std::string& path = sections.path;
  const SceneSections::Entry& e = sections.entry(kOctreeTag, "volume octree");
  const auto mapping = sections.file.map(e.offset, e.size);
  if (kVerifyChecksums && Section{0, {{mapping->data(), size_t(e.size)}}}.crc() != e.crc) sections.corrupt(e);
  Reader r(mapping->data(), size_t(e.size), path);
  const uint64_t hash = r.get<uint64_t>();
  const int32_t leafEdge = r.get<int32_t>();
  const uint32_t prefiltered = r.get<uint32_t>();
  const auto [nodesAt, nodeCount] = r.skipArray<OctreeNode>();
  const auto [errorsAt, errorCount] = r.skipArray<float>();
  if (r.left() != 0) sections.corrupt(e);  // a count its checksum would have refused
  sections.checkSameVolume(hash, volumeHash, "volume octree");
  if (prefiltered > 1) HYB_THROW(IoError, path, ": octree knot mode ", prefiltered, " unknown (expected 0 or 1)");
  // Paged, the octree's prefiltered knots are the store's; in memory they are rebuilt, and the
  // octree is checked against the samples.
  const bool inMemory = scene->volume.hasSamples();
  const Volume* knotsFrom = prefiltered && inMemory ? &scene->volume : nullptr;
  if (reinterpret_cast<uintptr_t>(nodesAt) % alignof(OctreeNode) == 0 && reinterpret_cast<uintptr_t>(errorsAt) % alignof(float) == 0) {
    const VolumeOctree::MappedParts parts{{reinterpret_cast<const OctreeNode*>(nodesAt), nodeCount}, {reinterpret_cast<const float*>(errorsAt), errorCount}, mapping};
    scene->octree = VolumeOctree::fromParts(scene->volume.dims(), leafEdge, parts, path, knotsFrom);
  } else {
    std::vector<OctreeNode> nodes(nodeCount);
    std::vector<float> errors(errorCount);
    std::memcpy(nodes.data(), nodesAt, nodeCount * sizeof(OctreeNode));
    std::memcpy(errors.data(), errorsAt, errorCount * sizeof(float));
    scene->octree = VolumeOctree::fromParts(scene->volume.dims(), leafEdge, std::move(nodes), std::move(errors), path, knotsFrom);
  }
  if (inMemory) scene->octree.validateAgainst(scene->volume, path);
  scene->octree.releasePages();
  // Bricks read the spacings 1 … the root's edge: the store must hold each.
  if (scene->knots && scene->knots->levels().size() != size_t(scene->octree.depth()) + 1)
    HYB_THROW(IoError, path, ": the knot store holds ", scene->knots->levels().size(), " spacings for an octree of depth ", scene->octree.depth(),
              " (expected ", scene->octree.depth() + 1, ")");
}

}  // namespace

Scene loadScene(const std::string& path, const SceneLoadOptions& options) {
  const InputFile file(path);
  const SceneSections sections(file, path);
  Scene scene;
  const uint64_t volumeHash = loadVolumeSection(sections, options, &scene);
  loadOctreeSection(sections, volumeHash, &scene);
  if (const auto it = sections.entries.find(kSurfaceTag); it != sections.entries.end()) {
    const auto mapping = file.map(it->second.offset, it->second.size);
    if (kVerifyChecksums) {  // a piece at a time, each piece's pages given back
      constexpr size_t kPiece = size_t(64) << 20;
      uLong crc = crc32_z(0L, Z_NULL, 0);
      for (uint64_t at = 0; at < it->second.size; at += kPiece) {
        crc = crc32_z(crc, mapping->data() + at, size_t(std::min<uint64_t>(kPiece, it->second.size - at)));
        mapping->release();
      }
      if (uint32_t(crc) != it->second.crc) sections.corrupt(it->second);
    }
    Reader r(mapping->data(), size_t(it->second.size), path);
    sections.checkSameVolume(r.get<uint64_t>(), volumeHash, "surface octree");
    const float iso = r.get<float>();
    const uint64_t cells = r.get<uint64_t>();
    const int32_t mergeEdge = r.get<int32_t>();
    if (scene.knots) {  // paged: the nodes stay in the file, read a region at a time
      const auto [at, n] = r.skipArray<std::array<uint8_t, kSurfaceNodeBytes>>();
      scene.surface = SurfaceOctree::fromMapped(scene.volume.dims(), iso, size_t(cells), mergeEdge, {mapping, at, n}, path);
    } else {
      scene.surface = SurfaceOctree::fromParts(scene.volume.dims(), iso, size_t(cells), mergeEdge, getSurfaceNodes(r, *mapping), path);
    }
  }
  if (scene.knots)  // the octrees count against the scene's memory: the cache gets what they leave
    scene.knots->setCacheLimit(sceneCacheBytes(options.memoryBytes, scene.octree.bytesUsed() + (scene.surface ? scene.surface->bytesUsed() : 0)));
  return scene;
}

uint64_t sceneCacheBytes(uint64_t memoryBytes, uint64_t octreeBytes) {
  return std::max(memoryBytes / 4, memoryBytes > octreeBytes ? memoryBytes - octreeBytes : 0);
}

SurfaceOctree sceneSurface(const Scene& scene, float iso, const Progress* progress) {
  if (scene.surface && scene.surface->isovalue() == iso) return *scene.surface;
  SurfaceOctreeOptions options;
  options.progress = progress;
  if (scene.volume.hasSamples()) return SurfaceOctree::build(scene.volume, scene.octree, iso, options);
  HYB_CHECK(scene.knots);
  return SurfaceOctree::build(*scene.knots, scene.octree, iso, options);
}

void setSceneNormals(const Scene& scene, TriangleMesh* mesh) {
  if (scene.volume.hasSamples()) return setGradientNormals(scene.volume, mesh);
  HYB_CHECK(scene.knots);
  const KnotStore& knots = *scene.knots;
  setGradientNormals(scene.volume.spacing(), [&](std::span<const glm::vec3> points, glm::vec3* gradients) { sampleGradients(knots, points, gradients); },
                     mesh);
}

void checkSceneGrid(const glm::ivec3& d, const std::string& what) {
  if (glm::any(glm::lessThan(d, glm::ivec3(2))))
    HYB_THROW(ValueError, what, ": a volume of ", d.x, "x", d.y, "x", d.z,
              " samples (expected at least 2 along each axis to render or mesh; a single image, such as a localizer: choose another series)");
}

OpenedScene openScene(const SceneSource& source, const VolumeOctreeOptions& options, const SceneLoadOptions& load) {
  using Clock = std::chrono::steady_clock;
  const auto msSince = [](Clock::time_point t) { return std::chrono::duration<double, std::milli>(Clock::now() - t).count(); };
  const auto t0 = Clock::now();
  OpenedScene o;
  if (!source.raw && isSceneFile(source.path)) {
    o.scene = loadScene(source.path, load);
    o.loaded = true;
    o.readMs = msSince(t0);
    return o;
  }
  o.scene.volume = readVolume(source.path, source.raw, source.series, source.progress);
  o.readMs = msSince(t0);
  checkSceneGrid(o.scene.volume.dims(), redactUrl(source.path));
  const auto t1 = Clock::now();
  VolumeOctreeOptions withProgress = options;
  withProgress.progress = source.progress;
  o.scene.octree = VolumeOctree::build(o.scene.volume, withProgress);
  o.buildMs = msSince(t1);
  return o;
}

}  // namespace hyb
