// Hybrid slice renderer: I. Boada, I. Navazo, "3D Texture-based Hybrid Visualizations", 2002, §4,
// with the view-aligned form of DESIGN 3.4 (slice polygons cut on the CPU, global slice planes).
#include "render/slices.h"

#define GL_GLEXT_PROTOTYPES
#include <GL/gl.h>
#include <GL/glext.h>

#include <glm/gtc/matrix_transform.hpp>
#include <glm/gtc/type_ptr.hpp>

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <deque>
#include <exception>
#include <limits>
#include <numeric>
#include <span>
#include <string>
#include <thread>
#include <utility>

#include "render/shaders.h"
#include "volume/error.h"

namespace hyb {

namespace {

GLuint compile(GLenum type, const char* src) {
  const GLuint s = glCreateShader(type);
  glShaderSource(s, 1, &src, nullptr);
  glCompileShader(s);
  GLint ok = 0;
  glGetShaderiv(s, GL_COMPILE_STATUS, &ok);
  if (!ok) {
    char log[2048];
    glGetShaderInfoLog(s, sizeof log, nullptr, log);
    HYB_THROW(RuntimeError, "shader compilation failed: ", log);
  }
  return s;
}

// A linked program, deleted with its owner.
struct Program {
  GLuint id = 0;
  Program(const char* vs, const char* fs) {
    const GLuint v = compile(GL_VERTEX_SHADER, vs), f = compile(GL_FRAGMENT_SHADER, fs);
    id = glCreateProgram();
    glAttachShader(id, v);
    glAttachShader(id, f);
    glLinkProgram(id);
    glDeleteShader(v);
    glDeleteShader(f);
    GLint ok = 0;
    glGetProgramiv(id, GL_LINK_STATUS, &ok);
    if (!ok) HYB_THROW(RuntimeError, "shader program failed to link");
  }
  Program(const Program&) = delete;
  Program& operator=(const Program&) = delete;
  ~Program() { glDeleteProgram(id); }
  // Hands the program over to a new owner.
  GLuint release() { return std::exchange(id, 0u); }
  GLint at(const char* name) const { return glGetUniformLocation(id, name); }
};

// A float colour (premultiplied) and depth render target, bound while it lives.
struct FloatTarget {
  GLuint fbo = 0, color = 0, depth = 0;
  FloatTarget(int w, int h) {
    glGenFramebuffers(1, &fbo);
    glBindFramebuffer(GL_FRAMEBUFFER, fbo);
    glGenTextures(1, &color);
    glBindTexture(GL_TEXTURE_2D, color);
    glTexImage2D(GL_TEXTURE_2D, 0, GL_RGBA32F, w, h, 0, GL_RGBA, GL_FLOAT, nullptr);
    glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, color, 0);
    glGenRenderbuffers(1, &depth);
    glBindRenderbuffer(GL_RENDERBUFFER, depth);
    glRenderbufferStorage(GL_RENDERBUFFER, GL_DEPTH_COMPONENT24, w, h);
    glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, depth);
    if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE) {
      release();
      HYB_THROW(RuntimeError, "OpenGL framebuffer incomplete for a ", w, "x", h, " float image");
    }
    glViewport(0, 0, w, h);
  }
  FloatTarget(const FloatTarget&) = delete;
  FloatTarget& operator=(const FloatTarget&) = delete;
  ~FloatTarget() { release(); }
  void release() {
    glDeleteRenderbuffers(1, &depth);
    glDeleteTextures(1, &color);
    glDeleteFramebuffers(1, &fbo);
    depth = color = fbo = 0;
  }
};

// A 3D texture on unit 0 with trilinear filtering and clamped edges.
GLuint newVolumeTexture() {
  GLuint tex;
  glGenTextures(1, &tex);
  glActiveTexture(GL_TEXTURE0);
  glBindTexture(GL_TEXTURE_3D, tex);
  glTexParameteri(GL_TEXTURE_3D, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
  glTexParameteri(GL_TEXTURE_3D, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
  for (GLenum w : {GL_TEXTURE_WRAP_S, GL_TEXTURE_WRAP_T, GL_TEXTURE_WRAP_R}) glTexParameteri(GL_TEXTURE_3D, w, GL_CLAMP_TO_EDGE);
  glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
  return tex;
}

// The texels of a knot lattice (DESIGN 3.3): value(knot position) at each knot, with the overhanging
// last texel extrapolated so that uniform trilinear filtering reproduces the lattice's
// position-clamped trilinear field exactly.
template <class Value>
auto latticeTexels(const KnotLattice& L, const Value& value) {
  using T = decltype(value(glm::ivec3()));
  const glm::ivec3 d = L.dims;
  const int s = L.step;
  std::vector<T> out(size_t(L.count()));
  auto at = [&](int i, int j, int k) -> T& { return out[size_t(i) + size_t(d.x) * (size_t(j) + size_t(d.y) * size_t(k))]; };
  for (int k = 0; k < d.z; ++k)
    for (int j = 0; j < d.y; ++j)
      for (int i = 0; i < d.x; ++i) at(i, j, k) = value(glm::ivec3(L.knot(0, i), L.knot(1, j), L.knot(2, k)));
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
// Carmona et al.) and is the brick's own from halfway across. Carmona's ramp over the whole brick
// (1) pulled half of every blended brick towards the coarse data: with the budget spent where the
// image changes most, 0.3–2 dB of PSNR at 1/2 to 1/8 of the bytes on the cranium; at 2 the seam
// test's jump falls 6.2× instead of 9.2× (4× asked; 3 gives 4.7×).
constexpr float kBlendSteepness = 2.0f;

// Base slice spacings between a brick's slices when its texels are @p step voxels apart. Full
// resolution keeps the base spacing (half a voxel by default: twice a texel), two voxels a texel
// take three (4/3 a texel), coarser levels twice their step (once a texel by default, DESIGN 4's
// slab width: their knots hold the data smoothed by the lattice's tent). Coarser bricks' planes
// are a subset of finer ones', and their fragments cut the stretch they stand for to the brick's
// box (SEGMENTS in the slice shader), so a level change shows no seam of sampling. With every
// level at twice a texel a coarse brick cost half its region's fragments for an eighth of its
// texels, and a budget bought little speed (cranium, 512², 1/8 of the bytes: 2.4× faster than full
// resolution at 33.05 dB against the reference; now 3.1–4.1× at 32.4 dB; once a texel from two
// voxels on: 3.5–4.4×, 31.9 dB; 4/3 a texel at every coarse level: 2.8–3.1×, 32.7 dB). The price
// is the rings of sampling once a texel where a coarse brick holds a thin shell.
int slicePeriod(int step) { return step == 1 ? 1 : step == 2 ? 3 : 2 * step; }

// The texels of brick @p b, value and shading gradient: its lattice's knot values (samples, or
// prefiltered ones on coarse lattices) with the volume's own gradient at each knot
// (Volume::gradientAt, central differences one voxel apart) or, when a corner blends (Carmona et
// al.), mix(coarse field, own field, w) of both, with w from the corner weights over the node's box
// (kBlendSteepness). A coarse brick's gradients thus stay those of the full-resolution data at its
// knots, interpolated between them, like a simplified mesh that keeps its original normals: the
// gradient costs its three channels whatever it holds, and the coarse field's own differences
// shade a coarse brick wrongly where the data vary within a texel (cranium, 512², against the
// reference: 1/8 of the texture bytes 31.7 -> 33.05 dB, 1/4 32.2 -> 33.2).
std::vector<glm::vec4> brickTexels(const Volume& v, const VolumeOctree& t, const Brick& b) {
  const OctreeNode& n = t.nodes()[b.node];
  const KnotLattice fine = t.lattice(n, b.p);
  const KnotLattice coarse = b.coarseCorners ? t.coarseLattice(n, b.p) : fine;
  const glm::vec3 origin(n.origin);
  const float edge = float(t.edge(n));
  auto knot = [&](const KnotLattice& L, const glm::ivec3& p) { return glm::vec4(t.knotValue(v, L.step, p), v.gradientAt(p.x, p.y, p.z)); };
  // The coarse lattice's knots, read once (each serves up to eight of the brick's knots).
  std::vector<glm::vec4> low;
  if (b.coarseCorners) {
    low.reserve(size_t(coarse.count()));
    for (int k = 0; k < coarse.dims.z; ++k)
      for (int j = 0; j < coarse.dims.y; ++j)
        for (int i = 0; i < coarse.dims.x; ++i) low.push_back(knot(coarse, glm::ivec3(coarse.knot(0, i), coarse.knot(1, j), coarse.knot(2, k))));
  }
  auto lowAt = [&](const glm::ivec3& q) {
    glm::ivec3 j;
    for (int a = 0; a < 3; ++a) j[a] = q[a] >= coarse.last[a] ? coarse.dims[a] - 1 : (q[a] - coarse.origin[a]) / coarse.step;
    return low[size_t(j.x) + size_t(coarse.dims.x) * (size_t(j.y) + size_t(coarse.dims.y) * size_t(j.z))];
  };
  return latticeTexels(fine, [&](const glm::ivec3& p) {
    const glm::vec4 own = knot(fine, p);
    if (!b.coarseCorners) return own;
    const glm::vec3 u = glm::clamp((glm::vec3(p) - origin) / edge, 0.0f, 1.0f);
    float w = 0.0f;
    for (int c = 0; c < 8; ++c)
      if (!((b.coarseCorners >> c) & 1))
        w += (c & 1 ? u.x : 1 - u.x) * (c & 2 ? u.y : 1 - u.y) * (c & 4 ? u.z : 1 - u.z);
    w = std::min(1.0f, kBlendSteepness * w);
    return glm::mix(t.latticeField(coarse.step, glm::clamp(p, coarse.origin, coarse.last), lowAt), own, w);
  });
}

// @p value mapped to [0, 1] over @p brick's range.
float unitValue(const CachedBrick& brick, float value) {
  return std::clamp(0.5f + 0.5f * ((value - brick.valueOffset) / brick.valueScale), 0.0f, 1.0f);
}

// A brick ready for upload: its value mapping and texels (the CPU half of an upload, made on all
// cores before the frame's GL work).
struct PackedBrick {
  CachedBrick brick;  // texture not made yet
  std::vector<uint8_t> bytes;
};

// Packs @p texels for an RGBA8 or RGBA16 texture: the value mapped from its range to [0, 1] (the
// brick's offset and scale undo it: value = offset + scale·(2u − 1)), the gradient divided by its
// largest component and stored as the middle code + (2^(bits−1) − 1)·g (zero exact). Eight-bit
// formats take llvmpipe's fixed-point filtering path, which fetches about twice as fast as the
// float path every other format takes; the value then keeps 1/255 of the brick's range (a frame of
// the cranium loses 0.05–1.2 dB against the reference, 8 dB with ct-soft-tissue, still 48.6 dB).
// Cutting planes of 8-bit bricks read the value from a 16-bit texture of its own (cutTexture).
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

// Makes @p packed's texture and hands its brick over.
CachedBrick uploadBrick(PackedBrick&& packed, const glm::ivec3& dims, TexelBits bits) {
  packed.brick.texture = newVolumeTexture();
  const bool wide = bits == TexelBits::Sixteen;
  glTexImage3D(GL_TEXTURE_3D, 0, wide ? GL_RGBA16 : GL_RGBA8, dims.x, dims.y, dims.z, 0, GL_RGBA, wide ? GL_UNSIGNED_SHORT : GL_UNSIGNED_BYTE,
               packed.bytes.data());
  return std::move(packed.brick);
}

// Uploads @p brick's values alone at 16 bits (R16, same mapping as its RGBA8 texture): a cutting
// plane shows the data to 1/65535 of the brick's range.
void uploadCutTexture(const std::vector<glm::vec4>& texels, const glm::ivec3& dims, CachedBrick* brick) {
  std::vector<uint16_t> values;
  values.reserve(texels.size());
  for (const glm::vec4& t : texels) values.push_back(uint16_t(unitValue(*brick, t.x) * 65535.0f + 0.5f));
  brick->cutTexture = newVolumeTexture();
  glTexImage3D(GL_TEXTURE_3D, 0, GL_R16, dims.x, dims.y, dims.z, 0, GL_RED, GL_UNSIGNED_SHORT, values.data());
}

// The ranges of @p texels (a lattice of @p dims knots) over blocks of 2×2×2 cells.
BrickRanges texelRanges(const std::vector<glm::vec4>& texels, const glm::ivec3& dims, const LutLayout& lut) {
  BrickRanges r;
  r.blocks = (glm::max(dims - 1, 1) + 1) / 2;
  r.entries.reserve(size_t(r.blocks.x) * r.blocks.y * r.blocks.z);
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
        r.entries.push_back(lut.entries(least, greatest));
      }
  return r;
}

// Which spans of the transfer function's lookup table hold a non-zero opacity.
class LutSupport {
 public:
  explicit LutSupport(const std::vector<glm::vec4>& lut) : mPrefix(lut.size() + 1, 0) {
    for (size_t i = 0; i < lut.size(); ++i) mPrefix[i + 1] = mPrefix[i] + (lut[i].a > 0.0f);
  }
  bool anyVisible(const std::array<uint16_t, 2>& span) const { return mPrefix[size_t(span[1]) + 1] > mPrefix[span[0]]; }

 private:
  std::vector<int> mPrefix;
};

// Calls visit(block) for every block of @p r whose span @p support can make visible.
template <class Visit>
void forEachVisibleBlock(const BrickRanges& r, const LutSupport& support, const Visit& visit) {
  size_t index = 0;
  for (int bz = 0; bz < r.blocks.z; ++bz)
    for (int by = 0; by < r.blocks.y; ++by)
      for (int bx = 0; bx < r.blocks.x; ++bx, ++index)
        if (support.anyVisible(r.entries[index])) visit(glm::ivec3(bx, by, bz));
}

// The box (voxel units) of blocks @p b0 to @p b1 of lattice @p L (blocks are 2×2×2 cells).
void blockBox(const KnotLattice& L, const glm::ivec3& b0, const glm::ivec3& b1, glm::dvec3* lo, glm::dvec3* hi) {
  for (int a = 0; a < 3; ++a) {
    (*lo)[a] = L.knot(a, std::min(2 * b0[a], L.dims[a] - 1));
    (*hi)[a] = L.knot(a, std::min(2 * b1[a] + 2, L.dims[a] - 1));
  }
}

// The box (voxel units) of the cells of lattice @p L whose ranges @p support can make visible;
// false when there is none.
bool visibleBox(const BrickRanges& r, const KnotLattice& L, const LutSupport& support, glm::dvec3* lo, glm::dvec3* hi) {
  glm::ivec3 b0(std::numeric_limits<int>::max()), b1(-1);
  forEachVisibleBlock(r, support, [&](const glm::ivec3& b) {
    b0 = glm::min(b0, b);
    b1 = glm::max(b1, b);
  });
  if (b1.x < 0) return false;
  blockBox(L, b0, b1, lo, hi);
  return true;
}

// For proxies at depth k·delta, k in [kLo, kLo + boxes->size()): the box (mm) of the visible
// blocks each proxy meets (empty boxes have lo > hi). A block meets the proxies between the depths
// @p depthRange gives for its box (mm).
template <class DepthRange>
void proxyBoxes(const BrickRanges& r, const KnotLattice& L, const LutSupport& support, const glm::dvec3& spacing, const DepthRange& depthRange,
                double delta, long long kLo, std::vector<std::pair<glm::dvec3, glm::dvec3>>* boxes) {
  const long long count = (long long)boxes->size();
  std::fill(boxes->begin(), boxes->end(), std::pair{glm::dvec3(1e300), glm::dvec3(-1e300)});
  forEachVisibleBlock(r, support, [&](const glm::ivec3& b) {
    glm::dvec3 lo, hi;
    blockBox(L, b, b, &lo, &hi);
    lo *= spacing;
    hi *= spacing;
    const auto [near, far] = depthRange(lo, hi);
    const long long k0 = std::max((long long)std::ceil(near / delta) - kLo, 0LL);
    const long long k1 = std::min((long long)std::floor(far / delta) - kLo, count - 1);
    for (long long k = k0; k <= k1; ++k) {
      auto& [ulo, uhi] = (*boxes)[size_t(k)];
      ulo = glm::min(ulo, lo);
      uhi = glm::max(uhi, hi);
    }
  });
}

// Appends plane f·X = depth ∩ box [lo, hi] as a triangle fan (world mm) to @p out; returns whether
// the plane cuts the box in a polygon.
bool slicePolygon(const glm::dvec3& lo, const glm::dvec3& hi, const glm::dvec3& f, double depth, std::vector<float>* out) {
  std::vector<glm::dvec3> pts;
  pts.reserve(12);
  for (int axis = 0; axis < 3; ++axis)
    for (int c = 0; c < 4; ++c) {
      glm::dvec3 a, b;
      const int u = (axis + 1) % 3, v = (axis + 2) % 3;
      a[u] = b[u] = (c & 1) ? hi[u] : lo[u];
      a[v] = b[v] = (c & 2) ? hi[v] : lo[v];
      a[axis] = lo[axis];
      b[axis] = hi[axis];
      const double da = glm::dot(f, a) - depth, db = glm::dot(f, b) - depth;
      if ((da < 0) == (db < 0) && da != 0 && db != 0) continue;  // an endpoint on the plane counts
      const double t = da == db ? 0.0 : da / (da - db);
      pts.push_back(a + (b - a) * t);
    }
  const int n = int(pts.size());
  if (n < 3) return false;
  glm::dvec3 centre(0.0);
  for (int i = 0; i < n; ++i) centre += pts[i];
  centre /= double(n);
  const glm::dvec3 r = glm::normalize(std::abs(f.x) < 0.9 ? glm::cross(f, glm::dvec3(1, 0, 0)) : glm::cross(f, glm::dvec3(0, 1, 0)));
  const glm::dvec3 u = glm::cross(f, r);
  // Around the centre by angle, as atan2 orders them from −π, with a pseudo-angle: the "diamond"
  // angle in (−2, 2], monotonic in the true one.
  auto angle = [&](const glm::dvec3& p) {
    const double x = glm::dot(p - centre, r), y = glm::dot(p - centre, u), l = std::abs(x) + std::abs(y);
    if (l == 0.0) return 0.0;
    const double d = y >= 0 ? (x >= 0 ? y / l : 2.0 - y / l) : (x < 0 ? 2.0 - y / l : 4.0 + y / l);
    return d > 2.0 ? d - 4.0 : d;
  };
  std::sort(pts.begin(), pts.end(), [&](const glm::dvec3& p, const glm::dvec3& q) { return angle(p) < angle(q); });
  for (int i = 1; i + 1 < n; ++i)
    for (const glm::dvec3* p : {&pts[0], &pts[i], &pts[i + 1]})
      for (int k = 0; k < 3; ++k) out->insert(out->end(), {float((*p)[k])});
  return true;
}

// Draws the intersection of @p surface with the plane @p cut (n·x + w = 0) as lines on top: the
// plane is the nearest thing wherever it is drawn, everything in front of it being clipped away.
void drawCutLine(const TriangleMesh& surface, const glm::dvec4& cut, const glm::mat4& viewProj, const glm::vec4& color,
                 SlicesStats* st) {
  std::vector<float> lines;
  for (const glm::uvec3& t : surface.triangles) {
    glm::dvec3 p[3];
    double s[3];
    for (int k = 0; k < 3; ++k) {
      p[k] = glm::dvec3(surface.vertices[t[k]]);
      s[k] = glm::dot(glm::dvec3(cut), p[k]) + cut.w;
    }
    glm::dvec3 ends[3];
    int n = 0;
    for (int k = 0; k < 3; ++k) {
      const int j = (k + 1) % 3;
      if ((s[k] < 0) != (s[j] < 0)) ends[n++] = p[k] + (p[j] - p[k]) * (s[k] / (s[k] - s[j]));
    }
    if (n != 2) continue;
    for (int e = 0; e < 2; ++e) lines.insert(lines.end(), {float(ends[e].x), float(ends[e].y), float(ends[e].z), 0, 0, 0});
    ++st->cutLineSegments;
  }
  if (lines.empty()) return;
  static constexpr const char* kLineFragment = R"(#version 450 core
out vec4 fragColor;
uniform vec3 color;
void main() { fragColor = vec4(color, 1.0); }
)";
  const Program program(shaders::kWorldVertex, kLineFragment);
  glUseProgram(program.id);
  glUniformMatrix4fv(program.at("viewProj"), 1, GL_FALSE, glm::value_ptr(viewProj));
  glUniform4f(program.at("cutPlane"), 0, 0, 0, 1);
  glUniform3f(program.at("color"), color.r, color.g, color.b);
  GLuint buffer;
  glGenBuffers(1, &buffer);
  glBindBuffer(GL_ARRAY_BUFFER, buffer);
  glBufferData(GL_ARRAY_BUFFER, GLsizeiptr(lines.size() * sizeof(float)), lines.data(), GL_STREAM_DRAW);
  glVertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, 6 * sizeof(float), nullptr);
  glVertexAttribPointer(1, 3, GL_FLOAT, GL_FALSE, 6 * sizeof(float), reinterpret_cast<void*>(3 * sizeof(float)));
  glDisableVertexAttribArray(2);
  glDisable(GL_DEPTH_TEST);
  glBlendFunc(GL_ONE, GL_ZERO);
  glDrawArrays(GL_LINES, 0, GLsizei(lines.size() / 6));
  glBlendFunc(GL_ONE, GL_ONE_MINUS_SRC_ALPHA);
  glEnable(GL_DEPTH_TEST);
  glDeleteBuffers(1, &buffer);
}

// Sutherland–Hodgman: clips the convex polygon @p poly to the box [lo, hi].
void clipToBox(const glm::dvec3& lo, const glm::dvec3& hi, std::vector<glm::dvec3>* poly) {
  std::vector<glm::dvec3> out;
  for (int axis = 0; axis < 3; ++axis)
    for (int side = 0; side < 2; ++side) {
      if (poly->empty()) return;
      // Inside: x[axis] >= lo[axis] (side 0) or x[axis] <= hi[axis] (side 1).
      auto dist = [&](const glm::dvec3& p) { return side == 0 ? p[axis] - lo[axis] : hi[axis] - p[axis]; };
      out.clear();
      for (size_t i = 0; i < poly->size(); ++i) {
        const glm::dvec3 &a = (*poly)[i], &b = (*poly)[(i + 1) % poly->size()];
        const double da = dist(a), db = dist(b);
        if (da >= 0) out.push_back(a);
        if ((da >= 0) != (db >= 0)) out.push_back(a + (b - a) * (da / (da - db)));
      }
      poly->swap(out);
    }
}

// Directions from the eye to a box, as gnomonic coordinates (s, t) around the axis a towards the
// box's centre: d ∝ a + s·e1 + t·e2. False when the box is too wide seen from the eye (or holds it).
struct ShellFrame {
  glm::dvec3 a, e1, e2;
  double s0, s1, t0, t1;
};
bool shellFrame(const glm::dvec3& lo, const glm::dvec3& hi, const glm::dvec3& eye, ShellFrame* fr) {
  fr->a = glm::normalize(0.5 * (lo + hi) - eye);
  fr->e1 = glm::normalize(glm::cross(fr->a, std::abs(fr->a.x) < 0.9 ? glm::dvec3(1, 0, 0) : glm::dvec3(0, 1, 0)));
  fr->e2 = glm::cross(fr->a, fr->e1);
  fr->s0 = fr->t0 = 1e300;
  fr->s1 = fr->t1 = -1e300;
  for (int c = 0; c < 8; ++c) {
    const glm::dvec3 d = glm::dvec3((c & 1) ? hi.x : lo.x, (c & 2) ? hi.y : lo.y, (c & 4) ? hi.z : lo.z) - eye;
    const double da = glm::dot(d, fr->a);
    if (da <= 0.5 * glm::length(d)) return false;  // more than 60 degrees off the axis
    const double s = glm::dot(d, fr->e1) / da, t = glm::dot(d, fr->e2) / da;
    fr->s0 = std::min(fr->s0, s);
    fr->s1 = std::max(fr->s1, s);
    fr->t0 = std::min(fr->t0, t);
    fr->t1 = std::max(fr->t1, t);
  }
  return true;
}

// Appends the sphere |x − eye| = r inside the box [lo, hi] as triangles (world mm): an n×n grid of
// chords over the box's directions, each clipped to the box. Returns whether anything was appended.
bool shellPolygon(const glm::dvec3& lo, const glm::dvec3& hi, const glm::dvec3& eye, const ShellFrame& fr, double r, int n,
                  std::vector<float>* out) {
  const size_t before = out->size();
  auto at = [&](int i, int j) {
    const double s = fr.s0 + (fr.s1 - fr.s0) * i / n, t = fr.t0 + (fr.t1 - fr.t0) * j / n;
    return eye + r * glm::normalize(fr.a + s * fr.e1 + t * fr.e2);
  };
  std::vector<glm::dvec3> poly;
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i)
      for (int half = 0; half < 2; ++half) {
        poly = half == 0 ? std::vector<glm::dvec3>{at(i, j), at(i + 1, j), at(i + 1, j + 1)}
                         : std::vector<glm::dvec3>{at(i, j), at(i + 1, j + 1), at(i, j + 1)};
        clipToBox(lo, hi, &poly);
        for (size_t k = 1; k + 1 < poly.size(); ++k)
          for (const glm::dvec3* p : {&poly[0], &poly[k], &poly[k + 1]})
            for (int c = 0; c < 3; ++c) out->push_back(float((*p)[c]));
      }
  return out->size() > before;
}

// Distance from @p p to the triangle (a, b, c) (Ericson, Real-Time Collision Detection, 5.1.5).
double distanceToTriangle(const glm::dvec3& p, const glm::dvec3& a, const glm::dvec3& b, const glm::dvec3& c) {
  const glm::dvec3 ab = b - a, ac = c - a, ap = p - a;
  const double d1 = glm::dot(ab, ap), d2 = glm::dot(ac, ap);
  if (d1 <= 0 && d2 <= 0) return glm::length(ap);
  const glm::dvec3 bp = p - b;
  const double d3 = glm::dot(ab, bp), d4 = glm::dot(ac, bp);
  if (d3 >= 0 && d4 <= d3) return glm::length(bp);
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return glm::length(p - (a + ab * (d1 / (d1 - d3))));
  const glm::dvec3 cp = p - c;
  const double d5 = glm::dot(ab, cp), d6 = glm::dot(ac, cp);
  if (d6 >= 0 && d5 <= d6) return glm::length(cp);
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return glm::length(p - (a + ac * (d2 / (d2 - d6))));
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) return glm::length(p - (b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)))));
  const double denom = 1.0 / (va + vb + vc);
  return glm::length(p - (a + ab * (vb * denom) + ac * (vc * denom)));
}

// Draws @p surface opaque with depth writes, headlight-shaded (by its vertex normals when it has
// them), clipped by @p cutPlane.
void drawOpaqueSurface(const TriangleMesh& surface, const glm::mat4& viewProj, const Camera& camera, const glm::vec3& color,
                       const glm::vec4& cutPlane) {
  const Program surf(shaders::kWorldVertex, shaders::kSurfaceFragment);
  glUseProgram(surf.id);
  std::vector<float> data;
  data.reserve(surface.triangles.size() * 18);
  for (const glm::uvec3& t : surface.triangles) {
    const glm::vec3 a = surface.vertices[t.x], b = surface.vertices[t.y], c = surface.vertices[t.z];
    const glm::vec3 face = glm::normalize(glm::cross(b - a, c - a));
    for (int k = 0; k < 3; ++k) {
      const glm::vec3 p = surface.vertices[t[k]], n = surface.normals.empty() ? face : surface.normals[t[k]];
      data.insert(data.end(), {p.x, p.y, p.z, n.x, n.y, n.z});
    }
  }
  const glm::vec3 f(camera.forward());
  glBufferData(GL_ARRAY_BUFFER, GLsizeiptr(data.size() * sizeof(float)), data.data(), GL_STATIC_DRAW);
  glEnableVertexAttribArray(0);
  glVertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, 6 * sizeof(float), nullptr);
  glEnableVertexAttribArray(1);
  glVertexAttribPointer(1, 3, GL_FLOAT, GL_FALSE, 6 * sizeof(float), reinterpret_cast<void*>(3 * sizeof(float)));
  glUniformMatrix4fv(surf.at("viewProj"), 1, GL_FALSE, glm::value_ptr(viewProj));
  glUniform3f(surf.at("eye"), float(camera.eye.x), float(camera.eye.y), float(camera.eye.z));
  glUniform3fv(surf.at("forward"), 1, glm::value_ptr(f));
  glUniform1i(surf.at("ortho"), camera.ortho ? 1 : 0);
  glUniform3fv(surf.at("color"), 1, glm::value_ptr(color));
  glUniform4fv(surf.at("cutPlane"), 1, glm::value_ptr(cutPlane));
  glDrawArrays(GL_TRIANGLES, 0, GLsizei(data.size() / 6));
}

// The bricks (nodes with brickOf ≥ 0) in back-to-front octree order: the octant farthest from the
// eye first, then those one, two and three flips towards it (valid for perspective too).
std::vector<uint32_t> bricksBackToFront(const VolumeOctree& octree, const std::vector<int>& brickOf, const glm::dvec3& eyeVoxel) {
  std::vector<uint32_t> order;
  std::vector<uint32_t> stack{0};
  while (!stack.empty()) {
    const uint32_t i = stack.back();
    stack.pop_back();
    if (brickOf[i] >= 0) {
      order.push_back(i);
      continue;
    }
    const OctreeNode& n = octree.nodes()[i];
    const glm::dvec3 mid = glm::dvec3(n.origin) + 0.5 * octree.edge(n);
    const int far = (eyeVoxel.x < mid.x) | (eyeVoxel.y < mid.y) << 1 | (eyeVoxel.z < mid.z) << 2;
    for (int k : {7, 6, 5, 3, 4, 2, 1, 0}) {  // pushed in reverse, popped far first
      const int slot = far ^ k;
      if (n.childMask & (1u << slot)) stack.push_back(childIndex(n, slot));
    }
  }
  return order;
}

// The surface's planar polygons (triangle ranges starts[p] .. starts[p + 1]) by brick (the brick
// holding the polygon's centroid; Surface Octree polygons lie inside one volume leaf, hence one
// brick), as one list in brick order: brick b's polygons are list[offsets[b] .. offsets[b + 1]).
// A grid of leaves says which brick holds each.
struct BrickPolygons {
  std::vector<uint32_t> offsets, list;
  std::span<const uint32_t> of(size_t b) const { return {list.data() + offsets[b], list.data() + offsets[b + 1]}; }
};
BrickPolygons polygonsByBrick(const Volume& volume, const VolumeOctree& octree, const Selection& selection, const TriangleMesh& surface,
                              const std::vector<uint32_t>& starts) {
  const glm::ivec3 cells = glm::max(volume.dims() - 1, glm::ivec3(1));
  const int leaf = octree.leafEdge();
  const glm::ivec3 grid = (cells + leaf - 1) / leaf;
  std::vector<uint32_t> brickAt(size_t(grid.x) * size_t(grid.y) * size_t(grid.z), 0);
  for (size_t b = 0; b < selection.bricks.size(); ++b) {
    const OctreeNode& n = octree.nodes()[selection.bricks[b].node];
    const glm::ivec3 lo = glm::ivec3(n.origin) / leaf, hi = glm::min((glm::ivec3(n.origin) + octree.edge(n) + leaf - 1) / leaf, grid);
    for (int z = lo.z; z < hi.z; ++z)
      for (int y = lo.y; y < hi.y; ++y)
        for (int x = lo.x; x < hi.x; ++x) brickAt[size_t(x) + size_t(grid.x) * (size_t(y) + size_t(grid.y) * size_t(z))] = uint32_t(b);
  }
  BrickPolygons out;
  out.offsets.assign(selection.bricks.size() + 1, 0);
  const size_t polygons = starts.size() - 1;
  std::vector<uint32_t> brickOf(polygons);
  for (size_t pi = 0; pi < polygons; ++pi) {
    glm::dvec3 c(0.0);
    for (uint32_t ti = starts[pi]; ti < starts[pi + 1]; ++ti)
      for (int k = 0; k < 3; ++k) c += glm::dvec3(surface.vertices[surface.triangles[ti][k]]);
    c /= 3.0 * double(std::max(starts[pi + 1] - starts[pi], 1u)) * volume.spacing();
    const glm::ivec3 g = glm::clamp(glm::ivec3(glm::floor(c)), glm::ivec3(0), cells - 1) / leaf;
    brickOf[pi] = brickAt[size_t(g.x) + size_t(grid.x) * (size_t(g.y) + size_t(grid.y) * size_t(g.z))];
    ++out.offsets[brickOf[pi] + 1];
  }
  for (size_t b = 0; b < selection.bricks.size(); ++b) out.offsets[b + 1] += out.offsets[b];
  out.list.resize(polygons);
  std::vector<uint32_t> next(out.offsets.begin(), out.offsets.end() - 1);
  for (size_t pi = 0; pi < polygons; ++pi) out.list[next[brickOf[pi]]++] = uint32_t(pi);
  return out;
}

}  // namespace

Image renderSlices(const Volume& volume, const VolumeOctree& octree, const Selection& selection, const TransferFunction& tf,
                   const Camera& camera, const SlicesOptions& options, SlicesStats* stats) {
  const int W = camera.width, H = camera.height;
  const glm::dvec3 spacing = volume.spacing();
  const glm::dvec3 f = camera.forward();
  const double baseDelta = options.stepVoxels * std::min({spacing.x, spacing.y, spacing.z});
  SlicesStats st;

  // Framebuffer: float colour (premultiplied), depth for opaque surfaces.
  const FloatTarget target(W, H);
  glDepthMask(GL_TRUE);  // a previous frame may have left depth writes off, which would skip the clear
  glDisable(GL_BLEND);
  glClearColor(0, 0, 0, 0);
  glClearDepth(1.0);
  glClear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);

  // Camera matrices with near/far around the volume.
  const glm::dvec3 boxHi = volume.extentMm();
  double dmin = 1e300, dmax = -1e300;
  for (int c = 0; c < 8; ++c) {
    const glm::dvec3 p((c & 1) ? boxHi.x : 0, (c & 2) ? boxHi.y : 0, (c & 4) ? boxHi.z : 0);
    dmin = std::min(dmin, glm::dot(p - camera.eye, f));
    dmax = std::max(dmax, glm::dot(p - camera.eye, f));
  }
  const double diag = std::max(1e-3, glm::length(boxHi));
  // Slab indices (depth / spacing, depth along f or from the eye) are kept in 32 bits.
  if ((glm::length(camera.eye) + diag) / baseDelta >= double(1 << 30))
    HYB_THROW(ValueError, "slice spacing ", baseDelta, " mm is too small for a scene ", glm::length(camera.eye) + diag, " mm deep (at most 2^30 slabs)");
  const double zNear = camera.ortho ? dmin - 0.01 * diag : std::max(dmin - 0.01 * diag, 1e-4 * diag);
  const double zFar = dmax + 0.01 * diag;
  const double aspect = double(W) / double(H);
  // A mirrored camera flips the image's x axis (no face culling: winding does not matter).
  const glm::dmat4 view = glm::scale(glm::dmat4(1.0), glm::dvec3(camera.mirrored ? -1.0 : 1.0, 1.0, 1.0)) *
                          glm::lookAt(camera.eye, camera.center, camera.up);
  const glm::dmat4 proj = camera.ortho ? glm::ortho(-0.5 * camera.orthoHeight * aspect, 0.5 * camera.orthoHeight * aspect,
                                                    -0.5 * camera.orthoHeight, 0.5 * camera.orthoHeight, zNear, zFar)
                                       : glm::perspective(glm::radians(camera.fovDeg), aspect, zNear, zFar);
  const glm::mat4 viewProj(proj * view);

  GLuint vao, vbo;
  glGenVertexArrays(1, &vao);
  glBindVertexArray(vao);
  glGenBuffers(1, &vbo);
  glBindBuffer(GL_ARRAY_BUFFER, vbo);
  glEnable(GL_DEPTH_TEST);
  glDepthFunc(GL_LESS);
  // The cutting plane's kept side (everything kept without a plane).
  const glm::dvec4 cut = options.cut ? options.cut->keptSide(camera) : glm::dvec4(0, 0, 0, 1);
  const glm::vec4 cutPlane(cut);
  if (options.cut) glEnable(GL_CLIP_DISTANCE0);

  // Opaque surface first, writing depth.
  const bool withTriangles = options.surface && !options.surface->triangles.empty();
  const bool translucent = withTriangles && options.surfaceColor.a < 1.0f;
  if (withTriangles && !translucent)
    drawOpaqueSurface(*options.surface, viewProj, camera, glm::vec3(options.surfaceColor), cutPlane);

  // Transfer function lookup table.
  const LutLayout layout(volume.minValue(), volume.maxValue(), tf);
  if (options.textures) options.textures->setLayout(layout.vmin, layout.vmax, options.texelBits);
  std::vector<glm::vec4> lut(LutLayout::kSize);
  for (int i = 0; i < LutLayout::kSize; ++i) lut[size_t(i)] = tf.lookup(layout.value(i));
  GLuint tfTex;
  glGenTextures(1, &tfTex);
  glActiveTexture(GL_TEXTURE1);
  glBindTexture(GL_TEXTURE_1D, tfTex);
  glTexImage1D(GL_TEXTURE_1D, 0, GL_RGBA32F, LutLayout::kSize, 0, GL_RGBA, GL_FLOAT, lut.data());
  const LutSupport support(lut);
  // Read with texelFetch; a filter without mipmaps keeps the texture complete.
  glTexParameteri(GL_TEXTURE_1D, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
  glTexParameteri(GL_TEXTURE_1D, GL_TEXTURE_MAG_FILTER, GL_NEAREST);

  std::string defines = "#version 450 core\n";
  for (const auto& [name, on] : {std::pair{"SHADING", options.shading}, {"SURFACE", translucent}, {"CUT", bool(options.cut)},
                                 {"SHELLS", options.proxy == Proxy::Shells && !camera.ortho}, {"VOI", bool(options.voi)}, {"ORTHO", camera.ortho},
                                 {"TEXEL16", options.texelBits == TexelBits::Sixteen},
                                 {"SMOOTH", translucent && !options.surface->normals.empty()}})
    defines += std::string("#define ") + name + (on ? " 1\n" : " 0\n");
  // The slice program, kept with the brick textures across frames when there is a cache: llvmpipe
  // compiles a new program's shaders again at its first draw (~5 % of a volume-only frame).
  std::deque<Program> ownPrograms;  // a deque: Program does not move
  auto programFor = [&](const std::string& key, const std::string& vertex, const std::string& fragment) {
    GLuint id = options.textures ? options.textures->program(key) : 0;
    if (!id) {
      id = ownPrograms.emplace_back(vertex.c_str(), fragment.c_str()).id;
      if (options.textures) options.textures->insertProgram(key, ownPrograms.back().release());
    }
    return id;
  };
  // Uniforms of kClassify and the camera, the same in the slice and cutting-plane programs.
  auto setShared = [&](GLuint id) {
    glUseProgram(id);
    glUniformMatrix4fv(glGetUniformLocation(id, "viewProj"), 1, GL_FALSE, glm::value_ptr(viewProj));
    glUniform1i(glGetUniformLocation(id, "tfTex"), 1);
    glUniform1f(glGetUniformLocation(id, "tfMin"), layout.vmin);
    glUniform1f(glGetUniformLocation(id, "tfScale"), layout.scale);
    glUniform1f(glGetUniformLocation(id, "tfSize"), float(LutLayout::kSize));
  };
  // The slice program, in two variants: bricks sliced at the base spacing, and bricks sliced
  // coarser, whose fragments cut their segment to the brick's box (SEGMENTS; 6–14 % of a fragment's
  // time, which full resolution need not pay: its planes tile every ray across bricks already).
  struct SliceProgram {
    GLuint id = 0;
    GLint fineScale, fineOffset, valueOffset, valueScale, sliceSpacing, shells, boxLo, boxHi;
  };
  std::array<SliceProgram, 2> slicePrograms;
  auto sliceProgram = [&](bool segments) -> const SliceProgram& {
    SliceProgram& p = slicePrograms[segments];
    if (p.id) return p;
    const std::string head = defines + "#define SEGMENTS " + (segments ? "1\n" : "0\n");
    p.id = programFor(head, head + shaders::kStreamVertex, head + shaders::kClassify + shaders::kSliceFragment);
    auto uniform = [&](const char* name) { return glGetUniformLocation(p.id, name); };
    setShared(p.id);
    glUniform1i(uniform("volumeTex"), 0);
    glUniform3f(uniform("eye"), float(camera.eye.x), float(camera.eye.y), float(camera.eye.z));
    glUniform3f(uniform("forward"), float(f.x), float(f.y), float(f.z));
    glUniform4fv(uniform("surfaceColor"), 1, glm::value_ptr(options.surfaceColor));
    glUniform4fv(uniform("cutPlane"), 1, glm::value_ptr(cutPlane));
    if (options.voi) {
      const glm::vec3 centre(0.5 * (options.voi->lo + options.voi->hi)), half(0.5 * (options.voi->hi - options.voi->lo));
      glUniform3fv(uniform("voiCentre"), 1, glm::value_ptr(centre));
      glUniform3fv(uniform("voiHalf"), 1, glm::value_ptr(half));
      const glm::mat3 toBox(options.voi->toBox);
      const glm::vec3 offset(options.voi->offset);
      glUniformMatrix3fv(uniform("voiToBox"), 1, GL_FALSE, glm::value_ptr(toBox));
      glUniform3fv(uniform("voiOffset"), 1, glm::value_ptr(offset));
      glUniform1f(uniform("voiInside"), float(options.voi->inside));
      glUniform1f(uniform("voiOutside"), float(options.voi->outside));
      glUniform1f(uniform("voiRamp"), float(options.voi->ramp));
    }
    p.fineScale = uniform("fineScale"), p.fineOffset = uniform("fineOffset"), p.valueOffset = uniform("valueOffset");
    p.valueScale = uniform("valueScale"), p.sliceSpacing = uniform("sliceSpacing"), p.shells = uniform("shells");
    p.boxLo = uniform("boxLo"), p.boxHi = uniform("boxHi");
    return p;
  };
  glEnableVertexAttribArray(0);
  glEnableVertexAttribArray(1);
  glEnableVertexAttribArray(2);
  glDepthMask(GL_FALSE);
  // Only the opaque surface and the cutting plane write depth; without them every fragment passes
  // (llvmpipe would still read and compare the depth of every one: ~1.5 % of a volume-only frame).
  if (!(withTriangles && !translucent) && !options.cut) glDisable(GL_DEPTH_TEST);
  glEnable(GL_BLEND);
  glBlendFunc(GL_ONE, GL_ONE_MINUS_SRC_ALPHA);  // premultiplied "over", back to front

  // Bricks back to front, and the surface triangles each brick holds.
  std::vector<int> brickOf(octree.nodes().size(), -1);
  for (size_t b = 0; b < selection.bricks.size(); ++b) brickOf[selection.bricks[b].node] = int(b);
  const glm::dvec3 eyeVoxel = (camera.ortho ? camera.eye - f * 1e9 * diag : camera.eye) / spacing;
  const std::vector<uint32_t> order = bricksBackToFront(octree, brickOf, eyeVoxel);
  HYB_CHECK(order.size() == selection.bricks.size());
  // The surface's planar polygons as triangle ranges (each triangle its own when the mesh does not
  // say): a polygon's triangles never overlap one another, so they go into a slab as one unit.
  std::vector<uint32_t> polygonStarts;
  // And the boundaries of the convex ones, which a slab cuts whole.
  static const std::vector<uint32_t> kNone;
  const std::vector<uint32_t>& loopStarts = options.surface ? options.surface->loopStarts : kNone;
  const std::vector<uint32_t>& loops = options.surface ? options.surface->loops : kNone;
  if (withTriangles) {
    polygonStarts = options.surface->polygonStarts;
    if (polygonStarts.empty()) {
      polygonStarts.resize(options.surface->triangles.size() + 1);
      std::iota(polygonStarts.begin(), polygonStarts.end(), 0u);
    }
    HYB_CHECK(polygonStarts.front() == 0 && polygonStarts.back() == options.surface->triangles.size());
    HYB_CHECK(loopStarts.empty() || (loopStarts.size() == polygonStarts.size() && loopStarts.back() == loops.size()));
  }
  const BrickPolygons polygonsOf = withTriangles ? polygonsByBrick(volume, octree, selection, *options.surface, polygonStarts) : BrickPolygons{};

  GLuint query;
  glGenQueries(1, &query);
  glBeginQuery(GL_FRAGMENT_SHADER_INVOCATIONS_ARB, query);
  // A texture object per brick: re-specifying one shared texture would make llvmpipe wait for the
  // previous brick's draws before every upload.
  std::vector<GLuint> textures, buffers;

  // What one brick draws: planned on this thread (textures are GL work), its vertex stream built
  // by a worker thread while this one submits the bricks before it to llvmpipe, whose vertex
  // processing runs on the submitting thread: the two halves of the per-brick work overlap.
  struct BrickDraw {
    uint32_t brick = 0;  // index into selection.bricks
    bool visible = false, sliced = false, shell = false;
    GLuint texture = 0, cutTexture = 0;
    std::vector<float> cutPolygon;  // the cutting plane's piece in this brick
    glm::vec3 fineScale{0.0f}, fineOffset{0.0f};
    float valueOffset = 0.0f, valueScale = 1.0f;
    double delta = 0.0;
    glm::dvec3 blo{0.0}, bhi{0.0}, slo{0.0}, shi{0.0};
    ShellFrame frame{};
    const BrickRanges* ranges = nullptr;  // each slice or shell is cut from the box of the blocks it meets
    KnotLattice lattice{};
    // Built by the worker:
    std::vector<float> stream;  // 9 floats a vertex: position, normal, kind and slab
    SlicesStats counts;  // slices, surface triangles, slab polygon draws
  };
  // Hidden (transparent or culled) bricks cost no texels; their surface triangles are still drawn.
  auto textured = [&](uint32_t node) {
    const OctreeNode& n = octree.nodes()[node];
    return !selection.bricks[size_t(brickOf[node])].hidden && tf.maxAlpha(n.minValue, n.maxValue) > 0.0f;
  };
  // Bricks without a texture yet are packed on all cores first: their texels are most of a first
  // frame's work. Warm frames (nothing to pack) do not open the parallel region: its threads would
  // spin for a while after it (libgomp's default wait policy), taking a core from llvmpipe's
  // rasterizer threads (a volume-only frame of the cranium, --step 1.6: ~10 % slower).
  std::vector<uint32_t> toPack;
  std::vector<int32_t> packedOf(octree.nodes().size(), -1);
  for (uint32_t i : order)
    if (textured(i) && !(options.textures && options.textures->find(selection.bricks[size_t(brickOf[i])]))) {
      packedOf[i] = int32_t(toPack.size());
      toPack.push_back(i);
    }
  std::vector<PackedBrick> packed(toPack.size());
#pragma omp parallel for schedule(dynamic) if (toPack.size() > 1)
  for (size_t k = 0; k < toPack.size(); ++k) {
    const uint32_t i = toPack[k];
    const Brick& b = selection.bricks[size_t(brickOf[i])];
    const std::vector<glm::vec4> texels = brickTexels(volume, octree, b);
    packed[k] = packBrick(texels, options.texelBits);
    packed[k].brick.ranges = texelRanges(texels, octree.lattice(octree.nodes()[i], b.p).dims, layout);
  }

  std::vector<BrickDraw> draws;
  std::deque<BrickRanges> frameRanges;  // block ranges of bricks no cache keeps
  uint64_t cutTexels = 0;  // of the 16-bit value textures the cutting plane reads
  draws.reserve(order.size());
  for (uint32_t i : order) {
    const Brick& b = selection.bricks[size_t(brickOf[i])];
    const OctreeNode& n = octree.nodes()[i];
    BrickDraw d;
    d.visible = textured(i);
    d.brick = uint32_t(brickOf[i]);
    const bool holdsTriangles = withTriangles && !polygonsOf.of(d.brick).empty();
    if (!d.visible && !(translucent && holdsTriangles)) continue;
    glm::ivec3 lo, hi;
    octree.voxelBox(n, &lo, &hi);
    d.blo = d.slo = glm::dvec3(lo) * spacing;
    d.bhi = d.shi = glm::dvec3(hi) * spacing;
    d.shell = options.proxy == Proxy::Shells && !camera.ortho && shellFrame(d.blo, d.bhi, camera.eye, &d.frame);
    const KnotLattice fine = octree.lattice(n, b.p);
    // Slices cover only the box of cells the transfer function can make visible (empty-space
    // skipping inside the brick; the fragments cut away would all be discarded).
    d.sliced = d.visible;
    if (d.visible) {
      CachedBrick* cached = options.textures ? options.textures->find(b) : nullptr;
      CachedBrick made;
      if (!cached) {
        made = uploadBrick(std::move(packed[size_t(packedOf[i])]), fine.dims, options.texelBits);
        if (options.textures)
          cached = &options.textures->insert(b, std::move(made));
        else
          textures.push_back(made.texture);
      }
      CachedBrick& brick = cached ? *cached : made;
      if (options.cut && slicePolygon(d.blo, d.bhi, glm::dvec3(cut), -cut.w, &d.cutPolygon)) {
        if (options.texelBits == TexelBits::Sixteen) {
          d.cutTexture = brick.texture;  // its value is 16 bits already
        } else {
          if (!brick.cutTexture) {
            uploadCutTexture(brickTexels(volume, octree, b), fine.dims, &brick);
            if (!options.textures) textures.push_back(brick.cutTexture);
          }
          d.cutTexture = brick.cutTexture;
          cutTexels += fine.count();
        }
      }
      d.texture = brick.texture;
      d.valueOffset = brick.valueOffset;
      d.valueScale = brick.valueScale;
      st.texels += fine.count();
      ++st.bricks;
      st.blendedBricks += b.coarseCorners != 0;
      if (options.visibleBoxes) {
        glm::dvec3 vlo(0.0), vhi(0.0);
        d.sliced = visibleBox(brick.ranges, fine, support, &vlo, &vhi);
        d.slo = glm::max(d.blo, vlo * spacing);
        d.shi = glm::min(d.bhi, vhi * spacing);
        if (d.sliced) {
          d.ranges = cached ? &cached->ranges : &frameRanges.emplace_back(std::move(made.ranges));
          d.lattice = fine;
        }
      }
      // The texture coordinates are affine in world mm: uv = x·scale + offset.
      const glm::dvec3 dims(fine.dims);
      d.fineScale = glm::vec3(1.0 / (spacing * double(fine.step) * dims));
      d.fineOffset = glm::vec3((0.5 - glm::dvec3(fine.origin) / double(fine.step)) / dims);
    }
    // Slices every slicePeriod base spacings: each level is sampled at its own rate (LaMar 1999) and
    // the shader corrects the opacity for it; the planes stay a subset of the global ones. A brick
    // holding surface polygons is too, its slabs between its own slices (as in the paper, where a
    // slab is a texel wide), where its level approximates the field (an error, or blending: the
    // user's ε or budget made it coarse): a polygon's depth against the volume is then quantised to
    // that slab. Where the level is exact (ε = 0 on uniform data, say) such a brick keeps the base
    // spacing, so the surface is composited exactly; so does a brick holding the eye, so that the
    // near plane cuts the volume at the finest depth resolution.
    const bool holdsEye = !camera.ortho && glm::all(glm::greaterThanEqual(camera.eye, d.blo)) && glm::all(glm::lessThanEqual(camera.eye, d.bhi));
    const bool exactWithSurface = holdsTriangles && b.error == 0.0f && b.coarseCorners == 0;
    // At least four planes across the brick's box (a node the grid crops, or a small one at a
    // coarse level): a ray's stretch in the brick that meets none of its planes is lost.
    const double across = std::min({d.bhi.x - d.blo.x, d.bhi.y - d.blo.y, d.bhi.z - d.blo.z});
    const int period = std::clamp(int(across / (4.0 * baseDelta)), 1, slicePeriod(fine.step));
    d.delta = baseDelta * (d.sliced && !holdsEye && !exactWithSurface ? period : 1);
    st.shellBricks += d.shell && d.sliced;
    draws.push_back(std::move(d));
  }

  // A slab instance of a translucent polygon: sort key (the polygon's centroid depth, clamped to
  // the slab), slab, and the polygon's index in the brick's list (16 bytes: sorting is a frame's cost).
  struct Instance {
    double depth;
    int32_t slab;
    uint32_t polygon;
  };
  // What building one brick's stream needs, kept by the worker across bricks.
  struct Scratch {
    std::vector<Instance> instances;
    std::vector<uint32_t> polygons;                    // the brick's polygons (mesh indices)
    std::vector<std::array<int32_t, 2>> polygonSpans;  // per polygon of the brick: the slabs it covers
    std::vector<uint32_t> firstSpan;                   // per polygon of the brick: its first triangle's span
    std::vector<std::array<int32_t, 2>> spans;         // the slabs each of those triangles covers
    std::vector<std::pair<glm::dvec3, glm::vec3>> piece, kept;  // a piece being cut to its slab: positions, normals
    std::vector<float> one;
    std::vector<std::pair<glm::dvec3, glm::dvec3>> boxes;
  };
  // Builds brick @p d's vertex stream: slices far to near with each SlabPolygon list before the
  // slice that closes its slab.
  auto buildStream = [&](BrickDraw& d, Scratch& scratch) {
    std::vector<Instance>& instances = scratch.instances;
    std::vector<float>& one = scratch.one;
    std::vector<float>& poly = d.stream;
    // One vertex: position, normal, kind (0 slice, 1 surface triangle), slab.
    auto put = [&](const glm::vec3& p, const glm::vec3& n, float kind, float lo, float hi) {
      const size_t at = poly.size();
      poly.resize(at + 9);
      float* v = &poly[at];
      v[0] = p.x, v[1] = p.y, v[2] = p.z, v[3] = n.x, v[4] = n.y, v[5] = n.z, v[6] = kind, v[7] = lo, v[8] = hi;
    };
    // A slice polygon (a triangle list, xyz a vertex).
    auto emitSlice = [&](const std::vector<float>& polygon) {
      for (size_t v = 0; v < polygon.size(); v += 3) put(glm::vec3(polygon[v], polygon[v + 1], polygon[v + 2]), glm::vec3(0.0f), 0.0f, -1e30f, 1e30f);
    };
    // Between planes a translucent piece is cut to its slab here, not by llvmpipe's clipper
    // (gl_ClipDistance), which was the costliest step of drawing slab triangles (~0.3 µs a clipped
    // triangle); shell slabs are clipped per fragment. The convex planar piece in scratch.piece is
    // cut to slab [slab·delta, (slab+1)·delta) (Sutherland and Hodgman, two parallel planes; it
    // stays convex) and fanned.
    auto emitClipped = [&](int32_t slab) {
      auto& piece = scratch.piece;
      auto& kept = scratch.kept;
      const double lo = double(slab) * d.delta, hi = double(slab + 1) * d.delta;
      for (const auto& [sign, bound] : {std::pair{1.0, lo}, std::pair{-1.0, -hi}}) {  // depth ≥ lo, then −depth ≥ −hi
        kept.clear();
        for (size_t v = 0; v < piece.size(); ++v) {
          const auto &[p, np] = piece[v];
          const auto &[q, nq] = piece[(v + 1) % piece.size()];
          const double dp = sign * glm::dot(f, p) - bound, dq = sign * glm::dot(f, q) - bound;
          if (dp >= 0) kept.push_back(piece[v]);
          if ((dp >= 0) != (dq >= 0)) {
            const double t = dp / (dp - dq);
            kept.emplace_back(p + (q - p) * t, np + (nq - np) * float(t));
          }
        }
        piece.swap(kept);
      }
      for (size_t v = 1; v + 1 < piece.size(); ++v)
        for (const auto& [p, n] : {piece[0], piece[v], piece[v + 1]}) put(glm::vec3(p), n, 1.0f, -1e30f, 1e30f);
    };
    auto faceNormal = [&](uint32_t triangle) {
      const glm::uvec3 tr = options.surface->triangles[triangle];
      const glm::vec3 a = options.surface->vertices[tr.x], b = options.surface->vertices[tr.y], c = options.surface->vertices[tr.z];
      return glm::normalize(glm::cross(b - a, c - a));
    };
    // The shading normal of vertex @p v of a triangle whose own normal is @p face.
    const bool smooth = withTriangles && !options.surface->normals.empty();
    auto vertexNormal = [&](uint32_t v, const glm::vec3& face) { return smooth ? options.surface->normals[v] : face; };
    // A triangle in one slab, cut to it when it covers more than one.
    auto emitTriangle = [&](uint32_t triangle, int32_t slab, bool clip) {
      const glm::uvec3 tr = options.surface->triangles[triangle];
      const glm::vec3 n = faceNormal(triangle);
      ++d.counts.slabPolygonDraws;
      if (!clip || d.shell) {
        const float lo = clip ? float(double(slab) * d.delta) : -1e30f, hi = clip ? float(double(slab + 1) * d.delta) : 1e30f;
        for (int k = 0; k < 3; ++k) put(options.surface->vertices[tr[k]], vertexNormal(tr[k], n), 1.0f, lo, hi);
        return;
      }
      scratch.piece.clear();
      for (int k = 0; k < 3; ++k) scratch.piece.emplace_back(glm::dvec3(options.surface->vertices[tr[k]]), vertexNormal(tr[k], n));
      emitClipped(slab);
    };
    // A polygon's part in one slab: a convex polygon that covers several slabs is cut to the slab
    // whole (one piece, fanned); otherwise each of its triangles that reaches the slab goes in, cut
    // to it when the triangle covers more than one.
    auto emitPolygon = [&](const Instance& in) {
      const uint32_t pi = scratch.polygons[in.polygon];
      const auto [p0, p1] = scratch.polygonSpans[in.polygon];
      if (p1 > p0 && !d.shell && pi + 1 < loopStarts.size() && loopStarts[pi + 1] > loopStarts[pi]) {
        ++d.counts.slabPolygonDraws;
        scratch.piece.clear();
        const glm::vec3 n = faceNormal(polygonStarts[pi]);
        for (uint32_t l = loopStarts[pi]; l < loopStarts[pi + 1]; ++l)
          scratch.piece.emplace_back(glm::dvec3(options.surface->vertices[loops[l]]), vertexNormal(loops[l], n));
        emitClipped(in.slab);
        return;
      }
      size_t j = scratch.firstSpan[in.polygon];
      for (uint32_t ti = polygonStarts[pi]; ti < polygonStarts[pi + 1]; ++ti, ++j) {
        const auto [k0, k1] = scratch.spans[j];
        if (in.slab >= k0 && in.slab <= k1) emitTriangle(ti, in.slab, k1 > k0);
      }
    };
    // Proxies: global planes f·X = k·delta, or shells |X − eye| = k·delta (LaMar 1999); "depth"
    // below is f·X or |X − eye| accordingly. The depths a box [lo, hi] spans: planes between its
    // nearest and farthest corners, shells between its nearest point and farthest corner.
    const glm::dvec3 nearSide(glm::greaterThan(f, glm::dvec3(0.0)));  // 1 where a box's nearest corner takes lo
    auto depthRange = [&](const glm::dvec3& lo, const glm::dvec3& hi) {
      if (!d.shell) {
        const glm::dvec3 nearCorner = glm::mix(hi, lo, nearSide);
        return std::pair{glm::dot(f, nearCorner), glm::dot(f, lo + hi - nearCorner)};
      }
      double far = 0.0;
      for (int c = 0; c < 8; ++c) far = std::max(far, glm::length(glm::dvec3(c & 1 ? hi.x : lo.x, c & 2 ? hi.y : lo.y, c & 4 ? hi.z : lo.z) - camera.eye));
      return std::pair{glm::length(camera.eye - glm::clamp(camera.eye, lo, hi)), far};
    };
    // This brick owns the proxies with depth in [bmin, bmax).
    const auto [bmin, bmax] = depthRange(d.blo, d.bhi);
    // Shell tessellation: chords whose sagitta stays below a quarter of the spacing.
    auto shellCells = [&](double r) {
      const double theta = 2.0 * std::acos(std::max(-1.0, 1.0 - d.delta / (4.0 * r)));
      return std::clamp(int(std::ceil(std::max(d.frame.s1 - d.frame.s0, d.frame.t1 - d.frame.t0) / theta)), 1, 32);
    };
    // SlabPolygon list: slab k = [k·delta, (k+1)·delta); a polygon goes into every slab its depth
    // range covers (emitPolygon cuts it there).
    instances.clear();
    scratch.polygons.clear();
    scratch.polygonSpans.clear();
    scratch.firstSpan.clear();
    scratch.spans.clear();
    long long kLo = (long long)std::floor(bmin / d.delta) - 1, kHi = (long long)std::ceil(bmax / d.delta);
    if (translucent)
      for (uint32_t pi : polygonsOf.of(d.brick)) {
        const uint32_t local = uint32_t(scratch.polygons.size());
        scratch.polygons.push_back(pi);
        scratch.firstSpan.push_back(uint32_t(scratch.spans.size()));
        long long p0 = std::numeric_limits<long long>::max(), p1 = std::numeric_limits<long long>::min();
        double centroid = 0;
        for (uint32_t ti = polygonStarts[pi]; ti < polygonStarts[pi + 1]; ++ti) {
          const glm::uvec3 tr = options.surface->triangles[ti];
          double dmn = 1e300, dmx = -1e300, sum = 0;
          for (int k = 0; k < 3; ++k) {
            const glm::dvec3 p(options.surface->vertices[tr[k]]);
            const double depth = d.shell ? glm::length(p - camera.eye) : glm::dot(f, p);
            dmn = std::min(dmn, depth);
            dmx = std::max(dmx, depth);
            sum += depth;
          }
          if (d.shell)  // the nearest point of a triangle to the eye may lie inside it
            dmn = distanceToTriangle(camera.eye, glm::dvec3(options.surface->vertices[tr.x]), glm::dvec3(options.surface->vertices[tr.y]),
                                     glm::dvec3(options.surface->vertices[tr.z]));
          // A brick without slices needs no slabs: its polygons are only sorted back to front.
          const long long k0 = d.sliced ? (long long)std::floor(dmn / d.delta) : 0, k1 = d.sliced ? (long long)std::floor(dmx / d.delta) : 0;
          scratch.spans.push_back({int32_t(k0), int32_t(k1)});
          p0 = std::min(p0, k0);
          p1 = std::max(p1, k1);
          centroid += sum / 3;
          ++d.counts.surfaceTriangles;
        }
        centroid /= double(polygonStarts[pi + 1] - polygonStarts[pi]);
        scratch.polygonSpans.push_back({int32_t(p0), int32_t(p1)});
        for (long long k = p0; k <= p1; ++k)
          instances.push_back({d.sliced ? std::clamp(centroid, double(k) * d.delta, double(k + 1) * d.delta) : centroid, int32_t(k), local});
        if (d.sliced && p0 <= p1) {
          kLo = std::min(kLo, p0);
          kHi = std::max(kHi, p1);
        }
      }
    // Far to near: by slab, then by depth inside a slab.
    std::sort(instances.begin(), instances.end(), [](const Instance& x, const Instance& y) {
      return x.slab != y.slab ? x.slab > y.slab : x.depth > y.depth;
    });
    std::vector<std::pair<glm::dvec3, glm::dvec3>>& boxes = scratch.boxes;
    if (d.ranges) {
      boxes.resize(size_t(kHi - kLo + 1));
      proxyBoxes(*d.ranges, d.lattice, support, spacing, depthRange, d.delta, kLo, &boxes);
    }
    size_t next = 0;
    for (long long k = kHi; k >= kLo; --k) {
      if (options.slabOrder)
        for (; next < instances.size() && instances[next].slab >= k; ++next) emitPolygon(instances[next]);
      const double plane = double(k) * d.delta;
      one.clear();
      glm::dvec3 lo = d.slo, hi = d.shi;
      if (d.ranges) {
        lo = glm::max(lo, boxes[size_t(k - kLo)].first);
        hi = glm::min(hi, boxes[size_t(k - kLo)].second);
      }
      if (d.sliced && plane >= bmin && plane < bmax && glm::all(glm::lessThanEqual(lo, hi)) &&
          (d.shell ? plane > 0.0 && shellPolygon(lo, hi, camera.eye, d.frame, plane, shellCells(plane), &one)
                   : slicePolygon(lo, hi, f, plane, &one))) {
        emitSlice(one);
        ++d.counts.slices;
      }
    }
    for (; next < instances.size(); ++next) emitPolygon(instances[next]);
  };

  // The cutting plane first, opaque and writing depth, from each crossed brick's 16-bit values:
  // what is kept of the volume lies behind it, so slices fail the depth test where it is opaque.
  if (options.cut) {
    const GLuint cutProgram = programFor("cut", shaders::kWorldVertex, std::string("#version 450 core\n") + shaders::kClassify + shaders::kCutFragment);
    setShared(cutProgram);
    auto at = [&](const char* name) { return glGetUniformLocation(cutProgram, name); };
    glUniform1i(at("cutTex"), 0);
    glUniform4f(at("cutPlane"), 0.0f, 0.0f, 0.0f, 1.0f);  // the plane is not clipped by itself
    std::vector<float> pieces;
    for (const BrickDraw& d : draws) pieces.insert(pieces.end(), d.cutPolygon.begin(), d.cutPolygon.end());
    buffers.emplace_back();
    glGenBuffers(1, &buffers.back());
    glBindBuffer(GL_ARRAY_BUFFER, buffers.back());
    glBufferData(GL_ARRAY_BUFFER, GLsizeiptr(pieces.size() * sizeof(float)), pieces.data(), GL_STREAM_DRAW);
    glVertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, 3 * sizeof(float), nullptr);
    glDisableVertexAttribArray(1);
    glDisableVertexAttribArray(2);
    glDepthMask(GL_TRUE);
    glActiveTexture(GL_TEXTURE0);
    GLint first = 0;
    for (const BrickDraw& d : draws) {
      if (d.cutPolygon.empty()) continue;
      glBindTexture(GL_TEXTURE_3D, d.cutTexture);
      glUniform3fv(at("fineScale"), 1, glm::value_ptr(d.fineScale));
      glUniform3fv(at("fineOffset"), 1, glm::value_ptr(d.fineOffset));
      glUniform1f(at("valueOffset"), d.valueOffset);
      glUniform1f(at("valueScale"), d.valueScale);
      const GLsizei count = GLsizei(d.cutPolygon.size() / 3);
      glDrawArrays(GL_TRIANGLES, first, count);
      first += count;
      ++st.cutPolygons;
    }
    glDepthMask(GL_FALSE);
    glEnableVertexAttribArray(1);
    glEnableVertexAttribArray(2);
  }
  GLuint bound = 0;  // the slice program in use
  // The worker builds the streams in draw order and publishes how many are done.
  std::atomic<size_t> built{0};
  std::exception_ptr failure;
  std::thread worker([&] {
    Scratch scratch;
    try {
      for (BrickDraw& d : draws) {
        buildStream(d, scratch);
        built.fetch_add(1, std::memory_order_release);
        built.notify_one();
      }
    } catch (...) {
      failure = std::current_exception();
      built.store(draws.size(), std::memory_order_release);
      built.notify_one();
    }
  });
  for (size_t j = 0; j < draws.size(); ++j) {
    for (size_t seen = built.load(std::memory_order_acquire); seen <= j; seen = built.load(std::memory_order_acquire)) built.wait(seen);
    if (failure) break;
    BrickDraw& d = draws[j];
    st.slices += d.counts.slices;
    st.surfaceTriangles += d.counts.surfaceTriangles;
    st.slabPolygonDraws += d.counts.slabPolygonDraws;
    if (d.stream.empty()) continue;
    const SliceProgram& sp = sliceProgram(d.delta > baseDelta);
    if (sp.id != bound) glUseProgram(bound = sp.id);
    if (d.visible) {
      glActiveTexture(GL_TEXTURE0);
      glBindTexture(GL_TEXTURE_3D, d.texture);
      glUniform3fv(sp.fineScale, 1, glm::value_ptr(d.fineScale));
      glUniform3fv(sp.fineOffset, 1, glm::value_ptr(d.fineOffset));
      glUniform1f(sp.valueOffset, d.valueOffset);
      glUniform1f(sp.valueScale, d.valueScale);
      glUniform3f(sp.boxLo, float(d.blo.x), float(d.blo.y), float(d.blo.z));
      glUniform3f(sp.boxHi, float(d.bhi.x), float(d.bhi.y), float(d.bhi.z));
    }
    glUniform1f(sp.sliceSpacing, float(d.delta));
    glUniform1i(sp.shells, d.shell ? 1 : 0);
    buffers.emplace_back();
    glGenBuffers(1, &buffers.back());
    glBindBuffer(GL_ARRAY_BUFFER, buffers.back());
    glBufferData(GL_ARRAY_BUFFER, GLsizeiptr(d.stream.size() * sizeof(float)), d.stream.data(), GL_STREAM_DRAW);
    glVertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, 9 * sizeof(float), nullptr);
    glVertexAttribPointer(1, 3, GL_FLOAT, GL_FALSE, 9 * sizeof(float), reinterpret_cast<void*>(3 * sizeof(float)));
    glVertexAttribPointer(2, 3, GL_FLOAT, GL_FALSE, 9 * sizeof(float), reinterpret_cast<void*>(6 * sizeof(float)));
    glDrawArrays(GL_TRIANGLES, 0, GLsizei(d.stream.size() / 9));
    std::vector<float>().swap(d.stream);
  }
  worker.join();
  if (failure) std::rethrow_exception(failure);
  if (options.cut && options.cutLine && options.surface) drawCutLine(*options.surface, cut, viewProj, options.surfaceColor, &st);
  st.textureBytes = st.texels * bytesPerTexel(options.texelBits) + cutTexels * kBytesPerCutTexel;
  glEndQuery(GL_FRAGMENT_SHADER_INVOCATIONS_ARB);
  GLuint fragments = 0;  // libOSMesa exports only the 32-bit getter; frames stay below 2^32 fragments
  glGetQueryObjectuiv(query, GL_QUERY_RESULT, &fragments);
  glDeleteQueries(1, &query);
  st.fragments = fragments;

  Image image(W, H);
  std::vector<float> rgba(size_t(W) * H * 4);
  glReadPixels(0, 0, W, H, GL_RGBA, GL_FLOAT, rgba.data());
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      const float* p = &rgba[(size_t(H - 1 - y) * W + x) * 4];
      image.at(x, y) = glm::vec4(p[0], p[1], p[2], p[3]);
    }
  const GLenum err = glGetError();
  glDisable(GL_CLIP_DISTANCE0);
  glDeleteTextures(GLsizei(textures.size()), textures.data());
  glDeleteBuffers(GLsizei(buffers.size()), buffers.data());
  glDeleteTextures(1, &tfTex);
  glDeleteBuffers(1, &vbo);
  glDeleteVertexArrays(1, &vao);
  if (err != GL_NO_ERROR) HYB_THROW(RuntimeError, "OpenGL error 0x", std::hex, err, " while rendering slices");
  if (stats) *stats = st;
  return image;
}

CachedBrick* BrickTextureCache::find(const Brick& b) {
  const auto it = mTextures.find(key(b));
  return it == mTextures.end() ? nullptr : &it->second;
}

CachedBrick& BrickTextureCache::insert(const Brick& b, CachedBrick brick) {
  CachedBrick& slot = mTextures[key(b)];
  glDeleteTextures(1, &slot.texture);
  glDeleteTextures(1, &slot.cutTexture);
  return slot = std::move(brick);
}

void BrickTextureCache::setLayout(float lutMin, float lutMax, TexelBits bits) {
  if (lutMin == mLutMin && lutMax == mLutMax && bits == mBits) return;
  clearBricks();
  mLutMin = lutMin;
  mLutMax = lutMax;
  mBits = bits;
}

unsigned BrickTextureCache::program(const std::string& key) const {
  const auto it = mPrograms.find(key);
  return it == mPrograms.end() ? 0 : it->second;
}

void BrickTextureCache::insertProgram(const std::string& key, unsigned program) { mPrograms[key] = program; }

void BrickTextureCache::clearBricks() {
  for (const auto& [k, brick] : mTextures) {
    glDeleteTextures(1, &brick.texture);
    glDeleteTextures(1, &brick.cutTexture);
  }
  mTextures.clear();
}

void BrickTextureCache::clear() {
  for (const auto& [k, program] : mPrograms) glDeleteProgram(program);
  mPrograms.clear();
  clearBricks();
}

double plainQuadSeconds(const Volume& volume, int width, int height, int quads, uint64_t* fragments, bool brickFormat) {
  static constexpr const char* kVertex = R"(#version 450 core
layout(location = 0) in vec2 position;
uniform float layer;
out vec3 uvw;
void main() { uvw = vec3(position * 0.5 + 0.5, layer); gl_Position = vec4(position, 0.0, 1.0); }
)";
  static constexpr const char* kFragment = R"(#version 450 core
in vec3 uvw;
out vec4 fragColor;
uniform sampler3D tex;
void main() { float v = texture(tex, uvw).r; fragColor = vec4(v, v, v, 1.0) * 0.001; }
)";
  const FloatTarget target(width, height);
  glDisable(GL_DEPTH_TEST);
  glEnable(GL_BLEND);
  glBlendFunc(GL_ONE, GL_ONE_MINUS_SRC_ALPHA);
  const glm::ivec3 d = volume.dims();
  GLuint tex;
  if (brickFormat) {
    std::vector<glm::vec4> texels;
    texels.reserve(volume.voxelCount());
    for (float v : volume.samples()) texels.emplace_back(v, 0.0f, 0.0f, 0.0f);
    tex = uploadBrick(packBrick(texels, TexelBits::Eight), d, TexelBits::Eight).texture;
  } else {
    tex = newVolumeTexture();
    glTexImage3D(GL_TEXTURE_3D, 0, GL_R32F, d.x, d.y, d.z, 0, GL_RED, GL_FLOAT, volume.samples().data());
  }
  Program program(kVertex, kFragment);
  glUseProgram(program.id);
  const float quad[] = {-1, -1, 1, -1, 1, 1, -1, -1, 1, 1, -1, 1};
  GLuint vao, vbo;
  glGenVertexArrays(1, &vao);
  glBindVertexArray(vao);
  glGenBuffers(1, &vbo);
  glBindBuffer(GL_ARRAY_BUFFER, vbo);
  glBufferData(GL_ARRAY_BUFFER, sizeof quad, quad, GL_STATIC_DRAW);
  glEnableVertexAttribArray(0);
  glVertexAttribPointer(0, 2, GL_FLOAT, GL_FALSE, 0, nullptr);
  float pixel[4];
  glReadPixels(0, 0, 1, 1, GL_RGBA, GL_FLOAT, pixel);  // the upload is done before timing
  GLuint query;
  glGenQueries(1, &query);
  const auto t0 = std::chrono::steady_clock::now();
  glBeginQuery(GL_FRAGMENT_SHADER_INVOCATIONS_ARB, query);
  for (int q = 0; q < quads; ++q) {
    glUniform1f(program.at("layer"), (float(q) + 0.5f) / float(quads));
    glDrawArrays(GL_TRIANGLES, 0, 6);
  }
  glEndQuery(GL_FRAGMENT_SHADER_INVOCATIONS_ARB);
  glReadPixels(0, 0, 1, 1, GL_RGBA, GL_FLOAT, pixel);  // waits for the quads
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  GLuint count = 0;
  glGetQueryObjectuiv(query, GL_QUERY_RESULT, &count);
  *fragments = count;
  glDeleteQueries(1, &query);
  glDeleteBuffers(1, &vbo);
  glDeleteVertexArrays(1, &vao);
  glDeleteTextures(1, &tex);
  return seconds;
}

}  // namespace hyb
