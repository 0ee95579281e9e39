#include "hybrid_octree/hybrid_io.h"

#include <zlib.h>

#include <bit>
#include <cstring>
#include <fstream>
#include <map>
#include <ostream>

#include "volume/error.h"
#include "volume/file_util.h"

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

std::vector<SurfaceNode> getSurfaceNodes(Reader& r) {
  constexpr size_t kBytes = 6 + 2 + 1 + std::tuple_size_v<decltype(SurfaceNode::planes)> * 5 + 4 + 4;  // as putSurfaceNodes writes one
  const uint64_t n = r.get<uint64_t>();
  r.needItems(n, kBytes);
  std::vector<SurfaceNode> nodes(static_cast<size_t>(n));
  for (SurfaceNode& s : nodes) {
    s.origin = r.get<glm::u16vec3>();
    s.edge = r.get<uint16_t>();
    s.planeCount = r.get<uint8_t>();
    for (GeoPlane& p : s.planes) {
      p.orientation = r.get<int8_t>();
      p.d = r.get<int32_t>();
    }
    s.inside = r.get<uint32_t>();
    s.occurs = r.get<uint32_t>();
  }
  return nodes;
}

uint32_t crc(const std::vector<uint8_t>& b) { return uint32_t(crc32(0L, b.data(), uInt(b.size()))); }

// A 64-bit content hash (murmur3's finaliser over 8-byte words; not cryptographic): the identity of
// the volume section that the octree sections were built from.
uint64_t contentHash(const std::vector<uint8_t>& b) {
  const auto mix = [](uint64_t h) {
    h ^= h >> 33;
    h *= 0xff51afd7ed558ccdULL;
    h ^= h >> 33;
    h *= 0xc4ceb9fe1a85ec53ULL;
    return h ^ (h >> 33);
  };
  uint64_t h = 0x9e3779b97f4a7c15ULL ^ b.size();
  size_t i = 0;
  for (; i + 8 <= b.size(); i += 8) {
    uint64_t w;
    std::memcpy(&w, b.data() + i, 8);
    h = mix(h ^ w) + 0x9e3779b97f4a7c15ULL;
  }
  uint64_t tail = 0;
  if (i < b.size()) std::memcpy(&tail, b.data() + i, b.size() - i);
  return mix(h ^ tail);
}

// Surface nodes field by field: the struct's padding would make the file's bytes differ between
// two saves of the same scene.
void putSurfaceNodes(Writer* w, const std::vector<SurfaceNode>& nodes) {
  w->put(uint64_t(nodes.size()));
  for (const SurfaceNode& n : nodes) {
    w->put(n.origin);
    w->put(n.edge);
    w->put(n.planeCount);
    for (const GeoPlane& p : n.planes) {
      w->put(p.orientation);
      w->put(p.d);
    }
    w->put(n.inside);
    w->put(n.occurs);
  }
}

}  // namespace

void saveScene(const std::string& path, const Volume& volume, const VolumeOctree& octree, const SurfaceOctree* surface) {
  Writer vol;
  vol.put(volume.dims());
  vol.put(volume.spacing());
  vol.put(uint32_t(volume.sourceType()));
  vol.putArray(volume.samples());
  vol.put(volume.frame().direction);
  vol.put(volume.frame().origin);
  vol.put(uint64_t(volume.info().size()));
  for (const auto& [key, value] : volume.info()) {
    vol.putArray(std::vector<char>(key.begin(), key.end()));
    vol.putArray(std::vector<char>(value.begin(), value.end()));
  }
  const uint64_t volumeHash = contentHash(vol.bytes());
  Writer oct;
  oct.put(volumeHash);
  oct.put(int32_t(octree.leafEdge()));
  oct.put(uint32_t(octree.prefiltered()));
  oct.putArray(octree.nodes());
  oct.putArray(octree.errorData());
  std::vector<std::pair<uint32_t, const Writer*>> sections = {{kVolumeTag, &vol}, {kOctreeTag, &oct}};
  Writer surf;
  if (surface) {
    surf.put(volumeHash);
    surf.put(surface->isovalue());
    surf.put(uint64_t(surface->cellCount()));
    surf.put(int32_t(surface->mergeEdge()));
    putSurfaceNodes(&surf, surface->nodes());
    sections.push_back({kSurfaceTag, &surf});
  }
  writeFileAtomically(path, [&](std::ostream& out) {
    out.write(kMagic, sizeof kMagic);
    const uint32_t header[2] = {kSceneVersion, uint32_t(sections.size())};
    out.write(reinterpret_cast<const char*>(header), sizeof header);
    for (const auto& [t, w] : sections) {
      const uint64_t size = w->bytes().size();
      const uint32_t c = crc(w->bytes());
      out.write(reinterpret_cast<const char*>(&t), 4);
      out.write(reinterpret_cast<const char*>(&size), 8);
      out.write(reinterpret_cast<const char*>(&c), 4);
      out.write(reinterpret_cast<const char*>(w->bytes().data()), std::streamsize(size));
    }
  });
}

bool isSceneFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  char m[8] = {};
  return in.read(m, 8) && std::memcmp(m, kMagic, 8) == 0;
}

Scene loadScene(const std::string& path) {
  const std::vector<uint8_t> bytes = readFileBytes(path);
  if (bytes.size() < 16 || std::memcmp(bytes.data(), kMagic, 8) != 0)
    HYB_THROW(IoError, path, ": not a hybrid-octree scene file (expected magic HYBOCT)");
  Reader header(bytes.data() + 8, bytes.size() - 8, path);
  const uint32_t version = header.get<uint32_t>();
  const uint32_t count = header.get<uint32_t>();
  if (version > 0 && version < 3)
    HYB_THROW(IoError, path, ": scene file version ", version, " has no patient orientation (this build reads version ", kSceneVersion,
              "); build the scene again from its volume with hybrid-octree build");
  if (version == 3)
    HYB_THROW(IoError, path, ": scene file version 3 does not tie its octrees to its volume (this build reads version ", kSceneVersion,
              "); build the scene again from its volume with hybrid-octree build");
  if (version != kSceneVersion)
    HYB_THROW(IoError, path, ": scene file version ", version, " unsupported (this build reads version ", kSceneVersion, ")");
  std::map<uint32_t, std::vector<uint8_t>> sections;
  size_t pos = 16;
  for (uint32_t s = 0; s < count; ++s) {
    if (bytes.size() - pos < 16)
      HYB_THROW(IoError, path, ": truncated scene file (section ", s, " of ", count, " header missing)");
    uint32_t t, c;
    uint64_t size;
    std::memcpy(&t, &bytes[pos], 4);
    std::memcpy(&size, &bytes[pos + 4], 8);
    std::memcpy(&c, &bytes[pos + 12], 4);
    pos += 16;
    if (size > bytes.size() - pos)
      HYB_THROW(IoError, path, ": truncated scene file (section ", s, " needs ", size, " bytes, ", bytes.size() - pos, " left)");
    std::vector<uint8_t> payload(bytes.begin() + ptrdiff_t(pos), bytes.begin() + ptrdiff_t(pos + size));
    pos += size_t(size);
    if (crc(payload) != c) HYB_THROW(IoError, path, ": corrupt scene file (checksum mismatch in section ", s, ")");
    sections[t] = std::move(payload);
  }
  auto section = [&](uint32_t t, const char* name) -> const std::vector<uint8_t>& {
    const auto it = sections.find(t);
    if (it == sections.end()) HYB_THROW(IoError, path, ": scene file lacks the ", name, " section");
    return it->second;
  };
  Scene scene;
  const uint64_t volumeHash = contentHash(section(kVolumeTag, "volume"));
  // Sections spliced from another scene of the same size would otherwise load and show the wrong data.
  const auto sameVolume = [&](Reader& r, const char* name) {
    if (r.get<uint64_t>() != volumeHash)
      HYB_THROW(IoError, path, ": the ", name, " section was built from another volume than the scene's (content hash mismatch)");
  };
  {
    const auto& b = section(kVolumeTag, "volume");
    Reader r(b.data(), b.size(), path);
    const glm::ivec3 dims = r.get<glm::ivec3>();
    const glm::dvec3 spacing = r.get<glm::dvec3>();
    const uint32_t type = r.get<uint32_t>();
    if (type > uint32_t(ScalarType::Float64)) HYB_THROW(IoError, path, ": unknown sample type code ", type);
    validateDims(dims, path);
    scene.volume = Volume(dims, spacing, ScalarType(type), r.getArray<float>(), path);
    const glm::dmat3 direction = r.get<glm::dmat3>();
    const glm::dvec3 origin = r.get<glm::dvec3>();
    const PatientFrame frame = makePatientFrame(direction, origin, path);
    if (glm::length(frame.direction[0] - direction[0]) + glm::length(frame.direction[1] - direction[1]) +
            glm::length(frame.direction[2] - direction[2]) > 1e-9)
      HYB_THROW(IoError, path, ": corrupt scene file (the volume's direction matrix is not orthonormal)");
    scene.volume.setFrame(frame);
    const uint64_t entries = r.get<uint64_t>();
    for (uint64_t e = 0; e < entries; ++e) {
      const std::vector<char> key = r.getArray<char>(), value = r.getArray<char>();
      scene.volume.addInfo(std::string(key.begin(), key.end()), std::string(value.begin(), value.end()));
    }
  }
  {
    const auto& b = section(kOctreeTag, "volume octree");
    Reader r(b.data(), b.size(), path);
    sameVolume(r, "volume octree");
    const int32_t leafEdge = r.get<int32_t>();
    const uint32_t prefiltered = r.get<uint32_t>();
    if (prefiltered > 1) HYB_THROW(IoError, path, ": octree knot mode ", prefiltered, " unknown (expected 0 or 1)");
    std::vector<OctreeNode> nodes = r.getArray<OctreeNode>();
    std::vector<float> errors = r.getArray<float>();
    scene.octree = VolumeOctree::fromParts(scene.volume.dims(), leafEdge, std::move(nodes), std::move(errors), path,
                                           prefiltered ? &scene.volume : nullptr);
    scene.octree.validateAgainst(scene.volume, path);
  }
  if (const auto it = sections.find(kSurfaceTag); it != sections.end()) {
    Reader r(it->second.data(), it->second.size(), path);
    sameVolume(r, "surface octree");
    const float iso = r.get<float>();
    const uint64_t cells = r.get<uint64_t>();
    const int32_t mergeEdge = r.get<int32_t>();
    scene.surface = SurfaceOctree::fromParts(scene.volume.dims(), iso, size_t(cells), mergeEdge, getSurfaceNodes(r), path);
  }
  return scene;
}

}  // namespace hyb
