// Brick textures: knot lattices as textures, Carmona et al.'s blend bake, packing, and the cache.
#include "render/slices/brick_textures.h"

#include <algorithm>
#include <limits>

namespace hyb {

namespace {

// The texels of a knot lattice (docs/volume-octree.md, Nodal errors): value(knot index, knot position) at each knot, with
// the overhanging last texel extrapolated so that uniform trilinear filtering reproduces the
// lattice's position-clamped trilinear field exactly.
template <class Value>
auto latticeTexels(const KnotLattice& L, const Value& value) {
  using T = decltype(value(glm::ivec3(), glm::ivec3()));
  const glm::ivec3 d = L.dims;
  const int s = L.step;
  std::vector<T> out(size_t(L.count()));
  auto at = [&](int i, int j, int k) -> T& { return out[size_t(i) + size_t(d.x) * (size_t(j) + size_t(d.y) * size_t(k))]; };
  for (int k = 0; k < d.z; ++k)
    for (int j = 0; j < d.y; ++j)
      for (int i = 0; i < d.x; ++i) at(i, j, k) = value(glm::ivec3(i, j, k), glm::ivec3(L.knot(0, i), L.knot(1, j), L.knot(2, k)));
  for (int a = 0; a < 3; ++a) {
    const int m = d[a] - 1;
    if (m < 1 || L.origin[a] + m * s <= L.last[a]) continue;  // the last knot sits where a uniform texel would
    const float scale = float(s) / float(L.last[a] - (L.origin[a] + (m - 1) * s));
    for (int k = 0; k < d.z; ++k)
      for (int j = 0; j < d.y; ++j)
        for (int i = 0; i < d.x; ++i) {
          glm::ivec3 q(i, j, k);
          if (q[a] != m) continue;
          glm::ivec3 r = q;
          r[a] = m - 1;
          T& last = at(q.x, q.y, q.z);
          const T prev = at(r.x, r.y, r.z);
          last = prev + (last - prev) * scale;
        }
  }
  return out;
}

// How fast a blended brick reaches its own data: w = min(1, kBlendSteepness · trilinear corner
// weight), so the field agrees with the coarser neighbour on their shared face (w = 0 there, as in
// Carmona et al.) and is the brick's own from halfway across (Carmona's ramp over the whole brick,
// 1, pulls half of every blended brick towards the coarse data; docs/multires.md measures both).
constexpr float kBlendSteepness = 2.0f;

// @p value mapped to [0, 1] over @p brick's range.
float unitValue(const CachedBrick& brick, float value) {
  return std::clamp(0.5f + 0.5f * ((value - brick.valueOffset) / brick.valueScale), 0.0f, 1.0f);
}

// Texels at T's precision. Eight-bit formats take llvmpipe's fixed-point filtering path, about
// twice as fast a fetch as the float path of every other format (docs/renderer.md).
template <class T>
void packTexels(const std::vector<glm::vec4>& texels, float toGradient, PackedBrick* out) {
  constexpr float kTop = float(std::numeric_limits<T>::max()), kZero = float(std::numeric_limits<T>::max() / 2 + 1);
  // Rounded by truncating x + 0.5 (x >= 0 here): std::lround was a fifth of a first frame.
  auto gradient = [&](float g) { return T(kZero + 0.5f + std::clamp(g * toGradient, 1.0f - kZero, kZero - 1.0f)); };
  out->bytes.resize(texels.size() * 4 * sizeof(T));
  T* q = reinterpret_cast<T*>(out->bytes.data());
  for (const glm::vec4& t : texels) {
    *q++ = T(unitValue(out->brick, t.x) * kTop + 0.5f);
    *q++ = gradient(t.y);
    *q++ = gradient(t.z);
    *q++ = gradient(t.w);
  }
}

}  // namespace

std::vector<KnotBox> brickKnotBoxes(const VolumeOctree& t, const Brick& b) {
  const OctreeNode& n = t.nodes()[b.node];
  std::vector<KnotBox> boxes{latticeKnotBox(t.dims(), t.lattice(n, b.p))};
  if (b.coarseCorners) boxes.push_back(latticeKnotBox(t.dims(), t.coarseLattice(n, b.p)));
  return boxes;
}

namespace {

// What a brick that blends (Carmona et al.) is made of: its lattice's knots, the coarser lattice's,
// and the trilinear weight of its corners that touch no coarser brick at each position (0 on a
// face shared with a coarser brick, 1 where every corner is its own).
struct BlendParts {
  KnotLattice fine, coarse;
  std::vector<glm::vec4> own, low;
  BlendParts(const KnotSource& source, const VolumeOctree& t, const Brick& b)
      : fine(t.lattice(t.nodes()[b.node], b.p)), coarse(t.coarseLattice(t.nodes()[b.node], b.p)), own(latticeKnots(source, fine)),
        low(latticeKnots(source, coarse)) {}
  glm::vec4 ownAt(const glm::ivec3& j) const { return own[size_t(j.x) + size_t(fine.dims.x) * (size_t(j.y) + size_t(fine.dims.y) * size_t(j.z))]; }
  // The coarse lattice's field at voxel @p p.
  glm::vec4 coarseAt(const VolumeOctree& t, const glm::ivec3& p) const {
    auto lowAt = [&](const glm::ivec3& q) {
      glm::ivec3 j;
      for (int a = 0; a < 3; ++a) j[a] = q[a] >= coarse.last[a] ? coarse.dims[a] - 1 : (q[a] - coarse.origin[a]) / coarse.step;
      return low[size_t(j.x) + size_t(coarse.dims.x) * (size_t(j.y) + size_t(coarse.dims.y) * size_t(j.z))];
    };
    return t.latticeField(coarse.step, glm::clamp(p, coarse.origin, coarse.last), lowAt);
  }
};

float ownCornerWeight(const VolumeOctree& t, const Brick& b, const glm::ivec3& p) {
  const OctreeNode& n = t.nodes()[b.node];
  const glm::vec3 u = glm::clamp((glm::vec3(p) - glm::vec3(n.origin)) / float(t.edge(n)), 0.0f, 1.0f);
  float w = 0.0f;
  for (int c = 0; c < 8; ++c)
    if (!((b.coarseCorners >> c) & 1)) w += (c & 1 ? u.x : 1 - u.x) * (c & 2 ? u.y : 1 - u.y) * (c & 4 ? u.z : 1 - u.z);
  return w;
}

}  // namespace

// The coarse field is read from the coarse lattice's knots once (each serves up to eight of the
// brick's); a coarse brick keeps the full-resolution gradients at its knots, interpolated between
// them, as a simplified mesh keeps its original normals (docs/multires.md).
std::vector<glm::vec4> brickTexels(const KnotSource& source, const VolumeOctree& t, const Brick& b) {
  if (!b.coarseCorners) {
    const KnotLattice fine = t.lattice(t.nodes()[b.node], b.p);
    const std::vector<glm::vec4> own = latticeKnots(source, fine);
    return latticeTexels(fine, [&](const glm::ivec3& j, const glm::ivec3&) {
      return own[size_t(j.x) + size_t(fine.dims.x) * (size_t(j.y) + size_t(fine.dims.y) * size_t(j.z))];
    });
  }
  const BlendParts parts(source, t, b);
  return latticeTexels(parts.fine, [&](const glm::ivec3& j, const glm::ivec3& p) {
    return glm::mix(parts.coarseAt(t, p), parts.ownAt(j), std::min(1.0f, kBlendSteepness * ownCornerWeight(t, b, p)));
  });
}

float seamHeight(const KnotSource& source, const VolumeOctree& t, const Brick& b) {
  if (!b.coarseCorners) return 0.0f;
  const BlendParts parts(source, t, b);
  float height = 0.0f;
  for (int k = 0; k < parts.fine.dims.z; ++k)
    for (int j = 0; j < parts.fine.dims.y; ++j)
      for (int i = 0; i < parts.fine.dims.x; ++i) {
        const glm::ivec3 p(parts.fine.knot(0, i), parts.fine.knot(1, j), parts.fine.knot(2, k));
        if (ownCornerWeight(t, b, p) == 0.0f) height = std::max(height, std::abs(parts.ownAt(glm::ivec3(i, j, k)).x - parts.coarseAt(t, p).x));
      }
  return height;
}

PackedBrick packBrick(const std::vector<glm::vec4>& texels, TexelBits bits) {
  float lo = std::numeric_limits<float>::max(), hi = std::numeric_limits<float>::lowest(), gmax = 0.0f;
  for (const glm::vec4& t : texels) {
    lo = std::min(lo, t.x);
    hi = std::max(hi, t.x);
    gmax = std::max({gmax, std::abs(t.y), std::abs(t.z), std::abs(t.w)});
  }
  PackedBrick out;
  out.brick.valueOffset = 0.5f * lo + 0.5f * hi;  // halves first: no overflow near the float range's ends
  out.brick.valueScale = hi > lo ? 0.5f * hi - 0.5f * lo : 1.0f;
  const float unit = gmax > 0.0f ? 1.0f / gmax : 0.0f;
  if (bits == TexelBits::Sixteen)
    packTexels<uint16_t>(texels, 32767.0f * unit, &out);
  else
    packTexels<uint8_t>(texels, 127.0f * unit, &out);
  return out;
}

uint64_t heldTextureBytes(const glm::ivec3& dims, uint64_t texelBytes) {
  auto padded = [](uint64_t n, uint64_t to) { return (n + to - 1) / to * to; };
  const uint64_t row = padded(padded(uint64_t(dims.x), 4) * texelBytes, 64);
  return row * padded(uint64_t(dims.y), 4) * uint64_t(dims.z);
}

CachedBrick uploadBrick(PackedBrick&& packed, const glm::ivec3& dims, TexelBits bits) {
  packed.brick.texture = gl::volumeTexture();
  const bool wide = bits == TexelBits::Sixteen;
  glTexImage3D(GL_TEXTURE_3D, 0, wide ? GL_RGBA16 : GL_RGBA8, dims.x, dims.y, dims.z, 0, GL_RGBA, wide ? GL_UNSIGNED_SHORT : GL_UNSIGNED_BYTE,
               packed.bytes.data());
  packed.brick.bytes = heldTextureBytes(dims, bytesPerTexel(bits));
  return std::move(packed.brick);
}

void uploadCutTexture(const std::vector<glm::vec4>& texels, const glm::ivec3& dims, CachedBrick* brick) {
  std::vector<uint16_t> values;
  values.reserve(texels.size());
  for (const glm::vec4& t : texels) values.push_back(uint16_t(unitValue(*brick, t.x) * 65535.0f + 0.5f));
  brick->cutTexture = gl::volumeTexture();
  glTexImage3D(GL_TEXTURE_3D, 0, GL_R16, dims.x, dims.y, dims.z, 0, GL_RED, GL_UNSIGNED_SHORT, values.data());
  brick->bytes += heldTextureBytes(dims, kBytesPerCutTexel);
}

BrickRanges texelRanges(const std::vector<glm::vec4>& texels, const glm::ivec3& dims) {
  BrickRanges r;
  r.blocks = (glm::max(dims - 1, 1) + 1) / 2;
  r.values.reserve(size_t(r.blocks.x) * r.blocks.y * r.blocks.z);
  for (int bz = 0; bz < r.blocks.z; ++bz)
    for (int by = 0; by < r.blocks.y; ++by)
      for (int bx = 0; bx < r.blocks.x; ++bx) {
        const glm::ivec3 lo = 2 * glm::ivec3(bx, by, bz), hi = glm::min(lo + 2, dims - 1);
        float least = std::numeric_limits<float>::max(), greatest = std::numeric_limits<float>::lowest();
        for (int k = lo.z; k <= hi.z; ++k)
          for (int j = lo.y; j <= hi.y; ++j)
            for (int i = lo.x; i <= hi.x; ++i) {
              const float t = texels[size_t(i) + size_t(dims.x) * (size_t(j) + size_t(dims.y) * size_t(k))].x;
              least = std::min(least, t);
              greatest = std::max(greatest, t);
            }
        r.values.push_back({least, greatest});
      }
  return r;
}

void BrickTextureCache::touch(Entry& e, uint64_t k) {
  e.frame = mFrame;
  mOrder.erase(e.age);
  e.age = mOrder.insert(mOrder.end(), k);
}

CachedBrick* BrickTextureCache::find(const Brick& b) {
  const uint64_t k = key(b);
  const auto it = mEntries.find(k);
  if (it == mEntries.end()) return nullptr;
  touch(it->second, k);
  return &it->second.brick;
}

CachedBrick& BrickTextureCache::insert(const Brick& b, CachedBrick brick) {
  const uint64_t k = key(b);
  auto [it, fresh] = mEntries.try_emplace(k);
  Entry& e = it->second;
  if (fresh) {
    e.age = mOrder.insert(mOrder.end(), k);
  } else {
    mBytes -= e.brick.bytes;
    touch(e, k);
  }
  e.frame = mFrame;
  e.brick = std::move(brick);
  mBytes += e.brick.bytes;
  return e.brick;
}

void BrickTextureCache::grew(const Brick& b, uint64_t bytes) {
  if (mEntries.count(key(b))) mBytes += bytes;
}

void BrickTextureCache::evict() { makeRoom(0); }

bool BrickTextureCache::makeRoom(uint64_t bytes) {
  while (mLimit > 0 && mBytes + bytes > mLimit && !mOrder.empty()) {
    const auto it = mEntries.find(mOrder.front());
    if (it->second.frame == mFrame) break;  // the rest are this frame's
    mBytes -= it->second.brick.bytes;
    mOrder.pop_front();
    mEntries.erase(it);
    ++mEvicted;
  }
  return mLimit == 0 || mBytes + bytes <= mLimit;
}

void BrickTextureCache::setBits(TexelBits bits) {
  if (bits == mBits) return;
  clearBricks();
  mBits = bits;
}

GLuint BrickTextureCache::program(const std::string& key) const {
  const auto it = mPrograms.find(key);
  return it == mPrograms.end() ? 0 : it->second.id();
}

void BrickTextureCache::insertProgram(const std::string& key, gl::Program program) { mPrograms[key] = std::move(program); }

GLuint BrickTextureCache::tableTexture(uint64_t tableId, const std::function<gl::Texture()>& make) {
  if (tableId != mTableId || !mTable) {
    mTable = make();
    mTableId = tableId;
  }
  return mTable.id();
}

void BrickTextureCache::clearBricks() {
  mEntries.clear();
  mOrder.clear();
  mBytes = 0;
}

void BrickTextureCache::clear() {
  mPrograms.clear();
  mTable = gl::Texture();
  mTableId = 0;
  clearBricks();
}

}  // namespace hyb
