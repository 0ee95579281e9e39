// The moving frames' ray tracer: render/raycast.cpp's rays, made cheap where a moving frame allows.
#include "render/raycast_interactive.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <limits>
#include <optional>
#include <type_traits>

#include "volume/core/error.h"
#include "volume/core/parallel.h"

namespace hyb {

namespace {

// What every sample calls: inlined whatever the size of the loop it lands in (GCC leaves these
// small helpers as calls inside the tracer's large loop: a fifth of a frame).
#define HYB_HOT [[gnu::always_inline]] inline

// One entry of the transfer function's table: a full segment's premultiplied colour and opacity,
// and the straight colour and optical depth per mm for shorter ones.
struct Entry {
  glm::vec4 full;
  glm::vec3 color;
  float tau;
};

// Samples of type T from @p base, x fastest, rows sy and planes sz samples apart: the trilinear
// value and Levoy's gradient (the voxels' central differences interpolated trilinearly, before
// their division by twice the spacing) in the cell whose first corner is sample @p c, at @p t
// within it; the gradient reads one sample beyond the cell on each side.
template <class T>
struct Lattice {
  const char* base;
  size_t sy, sz;

  HYB_HOT float at(size_t i) const {
    T x;  // (a paged store's blocks are bytes: copied, not aliased)
    std::memcpy(&x, base + i * sizeof(T), sizeof(T));
    return float(x);
  }
  HYB_HOT size_t index(const glm::ivec3& i) const { return size_t(i.x) + sy * size_t(i.y) + sz * size_t(i.z); }

  HYB_HOT static float lerp(float a, float b, float w) { return a + (b - a) * w; }
  HYB_HOT float value(size_t c, const glm::vec3& t) const {
    const float c00 = lerp(at(c), at(c + 1), t.x), c10 = lerp(at(c + sy), at(c + sy + 1), t.x);
    const float c01 = lerp(at(c + sz), at(c + sz + 1), t.x), c11 = lerp(at(c + sz + sy), at(c + sz + sy + 1), t.x);
    return lerp(lerp(c00, c10, t.y), lerp(c01, c11, t.y), t.z);
  }

  // The central differences along stride s at the row's two corners r and r + s, mixed by ts.
  HYB_HOT float row(size_t r, size_t s, float ts) const { return lerp(at(r + s) - at(r - s), at(r + 2 * s) - at(r), ts); }
  // The strides of one gradient component: s along it, u and v across it.
  struct Strides {
    size_t s, u, v;
  };
  // One component: the rows of stride a.s at the cell's four corners across a.u and a.v, mixed by
  // t = (along s, along u, along v).
  HYB_HOT float along(size_t c, Strides a, const glm::vec3& t) const {
    return lerp(lerp(row(c, a.s, t.x), row(c + a.u, a.s, t.x), t.y), lerp(row(c + a.v, a.s, t.x), row(c + a.v + a.u, a.s, t.x), t.y), t.z);
  }
  HYB_HOT glm::vec3 differences(size_t c, const glm::vec3& t) const {
    return glm::vec3(along(c, {1, sy, sz}, t), along(c, {sy, 1, sz}, glm::vec3(t.y, t.x, t.z)), along(c, {sz, 1, sy}, glm::vec3(t.z, t.x, t.y)));
  }
};

// The cell of voxel-space point @p p in a grid of @p dims (≥ 2 a side): its first corner, and where
// @p p lies in it; clamped to the grid as Volume::sample clamps. (Per axis in scalars: glm's
// component-wise min and max are calls the compiler does not inline here, a tenth of a frame.)
HYB_HOT glm::ivec3 cellOf(const glm::vec3& p, const glm::ivec3& dims, glm::vec3* t) {
  glm::ivec3 i;
  for (int a = 0; a < 3; ++a) {
    const float q = std::clamp(p[a], 0.0f, float(dims[a] - 1));
    i[a] = std::min(int(q), dims[a] - 2);
    (*t)[a] = q - float(i[a]);
  }
  return i;
}

// Whether Levoy's stencil around cell @p i (voxels i − 1 … i + 2) lies inside a grid of @p dims.
inline bool stencilInside(const glm::ivec3& i, const glm::ivec3& dims) {
  return i.x > 0 && i.y > 0 && i.z > 0 && i.x + 2 < dims.x && i.y + 2 < dims.y && i.z + 2 < dims.z;
}

// The samples of a volume in memory, of type T: Volume::sample and sampleGradient's numbers, read
// without their per-read clamps inside the grid.
template <class T>
struct MemoryField {
  Lattice<T> lattice;
  glm::ivec3 dims;
  glm::dvec3 spacing;
  glm::vec3 inv2s;  // 1 / (2 · spacing)

  MemoryField(const T* data, const glm::ivec3& n, const glm::dvec3& s)
      : lattice{reinterpret_cast<const char*>(data), size_t(n.x), size_t(n.x) * size_t(n.y)}, dims(n), spacing(s), inv2s(glm::vec3(0.5 / s)) {}

  HYB_HOT float value(const glm::vec3& p) const {
    glm::vec3 t;
    return lattice.value(lattice.index(cellOf(p, dims, &t)), t);
  }

  // One-sided at the grid's faces, where Volume's own code computes it.
  glm::vec3 gradient(const glm::vec3& p) const {
    glm::vec3 t;
    const glm::ivec3 i = cellOf(p, dims, &t);
    if (!stencilInside(i, dims))
      return trilinearGradient(p, dims, spacing, [this](int x, int y, int z) { return lattice.at(lattice.index({x, y, z})); });
    return lattice.differences(lattice.index(i), t) * inv2s;
  }
};

// A paged scene's samples of type T through a sampler of its cached blocks (one a thread): read in
// place from the block holding a sample's cell (its stencil, for a gradient), else from the cell's
// corners (its stencil) gathered from their blocks; a gradient at the grid's faces through the
// sampler (KnotSampler's numbers, Volume's).
template <class T>
struct PagedField {
  static constexpr ScalarType kType = std::is_same_v<T, uint8_t> ? ScalarType::UInt8 : std::is_same_v<T, int8_t> ? ScalarType::Int8
                                    : std::is_same_v<T, uint16_t> ? ScalarType::UInt16 : std::is_same_v<T, int16_t> ? ScalarType::Int16
                                                                                                                     : ScalarType::Float32;
  KnotSampler sampler;
  glm::ivec3 dims;
  glm::vec3 inv2s;
  const SampleBlock* block = nullptr;  // the sampler's last block, or none since its last other call
  T around[64];  // voxels i − 1 … i + 2 of the cell last gathered, x fastest
  static constexpr size_t kAroundCorner = 1 + 4 + 16;  // the cell's first corner in it

  explicit PagedField(const KnotSource& source) : sampler(source), dims(source.dims()), inv2s(glm::vec3(0.5 / source.spacing())) {}

  // Whether block @p b holds voxel @p v (SampleBlock::holds, inlined: it is asked at every sample).
  HYB_HOT static bool holds(const SampleBlock& b, const glm::ivec3& v) {
    return v.x >= b.lo.x && v.y >= b.lo.y && v.z >= b.lo.z && v.x < b.lo.x + b.dims.x && v.y < b.lo.y + b.dims.y && v.z < b.lo.z + b.dims.z;
  }
  // The block holding voxels lo … hi in type T, or none.
  HYB_HOT const SampleBlock* holding(const glm::ivec3& lo, const glm::ivec3& hi) {
    if (!block || !holds(*block, lo)) block = &sampler.blockAt(lo);
    return holds(*block, hi) && block->type == kType ? block : nullptr;
  }
  static Lattice<T> latticeOf(const SampleBlock& b) {
    return {static_cast<const char*>(b.samples), size_t(b.dims.x), size_t(b.dims.x) * size_t(b.dims.y)};
  }
  // Gathers voxels lo … hi of cell @p i's stencil (inside the grid: the cell's corners, or the whole
  // stencil) into `around`, a block at a time; false when a block does not hold type T.
  bool gather(const glm::ivec3& i, const glm::ivec3& lo, const glm::ivec3& hi) {
    block = nullptr;
    for (glm::ivec3 v = lo; v.z <= hi.z;) {
      const SampleBlock& b = sampler.blockAt(v);
      if (b.type != kType) return false;
      const glm::ivec3 end = glm::min(hi, b.lo + b.dims - 1);
      const Lattice<T> l = latticeOf(b);
      for (int z = v.z; z <= end.z; ++z)
        for (int y = v.y; y <= end.y; ++y) {
          const char* from = l.base + l.index(glm::ivec3(v.x, y, z) - b.lo) * sizeof(T);
          T* to = &around[size_t(v.x - i.x + 1) + 4 * size_t(y - i.y + 1) + 16 * size_t(z - i.z + 1)];
          for (int x = 0; x <= end.x - v.x; ++x) std::memcpy(to + x, from + size_t(x) * sizeof(T), sizeof(T));
        }
      // The next block: along x, then y, then z.
      if (end.x < hi.x) {
        v.x = end.x + 1;
      } else if (end.y < hi.y) {
        v = {lo.x, end.y + 1, v.z};
      } else {
        v = {lo.x, lo.y, end.z + 1};
      }
    }
    return true;
  }
  Lattice<T> gathered() const { return {reinterpret_cast<const char*>(around), 4, 16}; }

  HYB_HOT float value(const glm::vec3& p) {
    glm::vec3 t;
    const glm::ivec3 i = cellOf(p, dims, &t);
    if (const SampleBlock* b = holding(i, i + 1)) {
      const Lattice<T> l = latticeOf(*b);
      return l.value(l.index(i - b->lo), t);
    }
    if (gather(i, i, i + 1)) return gathered().value(kAroundCorner, t);
    block = nullptr;
    return sampler.sample(p);
  }
  glm::vec3 gradient(const glm::vec3& p) {
    glm::vec3 t;
    const glm::ivec3 i = cellOf(p, dims, &t);
    if (stencilInside(i, dims)) {
      if (const SampleBlock* b = holding(i - 1, i + 2)) {
        const Lattice<T> l = latticeOf(*b);
        return l.differences(l.index(i - b->lo), t) * inv2s;
      }
      if (gather(i, i - 1, i + 2)) return gathered().differences(kAroundCorner, t) * inv2s;
    }
    block = nullptr;
    return sampler.sampleGradient(p);
  }
};

// What every ray of a frame reads, made once: the table, where the transfer function leaves the
// volume empty, the ray march's constants.
struct Frame {
  const Camera& camera;
  const RaycastOptions& options;
  LutLayout layout;
  std::vector<Entry> table;
  std::vector<uint8_t> visible;  // table[e].full.a > 0: most samples read this small table alone
  glm::vec3 invSpacing;
  glm::dvec3 boxHi;
  glm::ivec3 cells;
  double dt;  // mm
  // The octree's leaves as a grid: for each, log2 of the edge (cells) of the largest node holding
  // it that the transfer function makes transparent, or kVisible. A region is then found by one
  // read rather than a descent from the root (most of a ray's empty-space queries).
  static constexpr uint8_t kVisible = 0xff;
  int leafShift;
  glm::ivec3 leaves;
  std::vector<uint8_t> leafSkip;

  Frame(const Volume& volume, const VolumeOctree& octree, const TransferFunction& tf, const Camera& c, const RaycastOptions& opt)
      : camera(c), options(opt), layout(volume.minValue(), volume.maxValue(), tf), table(LutLayout::kSize), visible(LutLayout::kSize),
        invSpacing(glm::vec3(1.0 / volume.spacing())), boxHi(volume.extentMm()), cells(glm::max(volume.dims() - 1, glm::ivec3(1))),
        dt(opt.stepVoxels * std::min({volume.spacing().x, volume.spacing().y, volume.spacing().z})),
        leafShift(std::countr_zero(unsigned(octree.leafEdge()))), leaves((cells + octree.leafEdge() - 1) >> leafShift),
        leafSkip(size_t(leaves.x) * size_t(leaves.y) * size_t(leaves.z), kVisible) {
    for (int e = 0; e < LutLayout::kSize; ++e) {
      const glm::vec4 v = tf.lookup(layout.value(e));
      const float a = TransferFunction::segmentAlpha(v.a, float(dt));
      table[size_t(e)] = {glm::vec4(glm::vec3(v) * a, a), glm::vec3(v), v.a >= 1.0f ? std::numeric_limits<float>::infinity() : -std::log1p(-v.a)};
      visible[size_t(e)] = a > 0.0f;
    }
    if (!opt.skipEmptySpace) return;
    // The transparent nodes nearest the root, their leaves marked with their edge.
    const auto nodes = octree.nodes();
    std::vector<uint32_t> stack{0};
    while (!stack.empty()) {
      const OctreeNode& n = nodes[stack.back()];
      stack.pop_back();
      if (tf.maxAlpha(n.minValue, n.maxValue) <= 0.0f) {
        const int edge = octree.edge(n);
        const glm::ivec3 lo = glm::ivec3(n.origin) >> leafShift, hi = glm::min((glm::ivec3(n.origin) + edge + octree.leafEdge() - 1) >> leafShift, leaves);
        for (int z = lo.z; z < hi.z; ++z)
          for (int y = lo.y; y < hi.y; ++y)
            std::fill_n(leafSkip.begin() + std::ptrdiff_t(leafIndex({lo.x, y, z})), hi.x - lo.x, uint8_t(std::countr_zero(unsigned(edge))));
        continue;
      }
      for (int slot = 0; slot < 8; ++slot)
        if (n.childMask & (1u << slot)) stack.push_back(childIndex(n, slot));
    }
  }

  HYB_HOT size_t leafIndex(const glm::ivec3& l) const { return size_t(l.x) + size_t(leaves.x) * (size_t(l.y) + size_t(leaves.y) * size_t(l.z)); }

  // The region holding voxel-space point @p q: the largest transparent node holding it, else its
  // leaf; its box in voxels. True when transparent.
  HYB_HOT bool region(const glm::vec3& q, glm::vec3* lo, glm::vec3* hi) const {
    glm::ivec3 c;
    for (int a = 0; a < 3; ++a) c[a] = std::min(int(std::max(q[a], 0.0f)), cells[a] - 1);
    const uint8_t skip = leafSkip[leafIndex(c >> leafShift)];
    const int shift = skip == kVisible ? leafShift : skip;
    for (int a = 0; a < 3; ++a) {
      const int first = (c[a] >> shift) << shift;
      (*lo)[a] = float(first);
      (*hi)[a] = float(std::min(first + (1 << shift), cells[a]));
    }
    return skip != kVisible;
  }
};

// One thread's rays over the samples of @p Field.
template <class Field>
class Tracer {
 public:
  Tracer(const Frame& f, Field field) : mF(f), mField(std::move(field)) {}

  glm::vec4 trace(int x, int y) {
    glm::dvec3 o, d;
    mF.camera.ray(x + 0.5, y + 0.5, &o, &d);
    mAcc = glm::vec4(0.0f);
    mHalf = kNever;
    mO = o;
    mD = d;
    mDir = glm::vec3(d);
    mHit.reset();
    if (mF.options.surface) mHit = mF.options.surface->firstHit(o, d, 0.0, 1e300);
    double t0 = 0.0, t1 = 0.0;
    // Interleaved sampling (Keller and Heidrich 2001): the four pixels of each 2² square start their
    // samples a quarter step apart, so the bilinear magnification of a small frame mixes four
    // lattices and the wood-grain of one (the slices' aliasing at a wide step) averages out.
    constexpr double kOffsets[4] = {0.0, 0.5, 0.75, 0.25};
    const double off = kOffsets[(x & 1) | (y & 1) << 1] * mF.dt;
    if (raySlab(o, d, glm::dvec3(0.0), mF.boxHi, &t0, &t1) && std::max(t0, 0.0) < t1) march(o, d, std::max(t0, 0.0), t1, off);
    surfaceUntil(1e300);
    return mAcc;
  }

  // Where the last ray's opacity reached ½ (mm from the eye), or kNever.
  float half() const { return mHalf; }
  static constexpr float kNever = std::numeric_limits<float>::infinity();
  uint64_t samples = 0, skipped = 0, crossings = 0;

 private:
  // Composites the crossings before distance @p t, each found when the one before it is passed
  // (Bvh::firstHit: a ray stopped once opaque never looks for those beyond).
  void surfaceUntil(double t) {
    const glm::vec4& c = mF.options.surfaceColor;
    while (mHit && mHit->t <= t && mAcc.a < kInteractiveOpaqueAlpha) {
      const float shade = 0.25f + 0.75f * std::abs(glm::dot(glm::vec3(mHit->normal), mDir));
      add(glm::vec4(glm::vec3(c) * shade * c.a, c.a), float(mHit->t));
      ++crossings;
      // (crossings at the same distance to float's precision, a ray through an edge shared by two
      // triangles, count once, as in allHits)
      const double after = mHit->t + 1e-6 * (1.0 + std::abs(mHit->t));
      mHit = mF.options.surface->firstHit(mO, mD, after, 1e300);
    }
  }
  bool crossingBefore(double t) const { return mHit && mHit->t < t; }

  // The segments of [t0, t1] between the lattice points t0 − off + k·dt (raycast's lattice, offset),
  // split at surface crossings; a region's query at the segment that enters it, every segment
  // starting inside a visible one sampled.
  void march(const glm::dvec3& o, const glm::dvec3& d, double t0, double t1, double off) {
    const double dt = mF.dt;
    mQo = glm::vec3(o) * mF.invSpacing;
    mQd = glm::vec3(d) * mF.invSpacing;
    if (off > 0.0) {  // the first segment, cut short where the ray enters the volume
      const double tb = std::min(t0 + dt - off, t1);
      segment(t0, tb);
      t0 = tb;
    }
    for (double ta = t0; ta < t1 && mAcc.a < kInteractiveOpaqueAlpha;) {
      glm::vec3 lo, hi;
      const bool clear = mF.region(mQo + mQd * float(ta), &lo, &hi);
      double te = exit(lo, hi, ta);
      if (clear) {
        // Resumes at the segment the ray leaves the node in (sampled: its middle may lie beyond).
        const double resume = t0 + std::floor((std::max(te, ta) - t0) / dt + 1e-9) * dt;
        if (resume > ta) {
          surfaceUntil(std::min(resume, t1));
          ++skipped;
          ta = resume;
          continue;
        }
        te = ta;  // the node ends within this segment: sample it, then ask again
      }
      // Every segment starting before te; those a crossing splits or the volume's end cuts short
      // take the reference's path, the others the table's full segment.
      const double end = std::min(te, t1);
      do {
        const double tb = std::min(ta + dt, t1);
        if (tb < ta + dt || crossingBefore(tb))
          segment(ta, tb);
        else
          sampleFull(float(ta + 0.5 * dt));
        ta = tb;
      } while (ta < end && mAcc.a < kInteractiveOpaqueAlpha);
    }
  }

  // The segment [ta, tb], split at the crossings in it, each part sampled at its middle.
  void segment(double ta, double tb) {
    for (double s = ta; s < tb && mAcc.a < kInteractiveOpaqueAlpha;) {
      const double e = crossingBefore(tb) ? std::max(mHit->t, s) : tb;
      if (e > s) sample(s, e);
      s = e;
      surfaceUntil(s);
    }
  }

  // Where the ray leaves the voxel-space box [lo, hi], from distance @p t inside it.
  HYB_HOT double exit(const glm::vec3& lo, const glm::vec3& hi, double t) const {
    double e = 1e300;
    for (int k = 0; k < 3; ++k) {
      if (mQd[k] > 0.0f)
        e = std::min(e, double((hi[k] - mQo[k]) / mQd[k]));
      else if (mQd[k] < 0.0f)
        e = std::min(e, double((lo[k] - mQo[k]) / mQd[k]));
    }
    return std::max(e, t);
  }

  // The field at distance @p t; @p q receives where that is in voxels.
  HYB_HOT float valueAt(float t, glm::vec3* q) {
    *q = mQo + mQd * t;
    ++samples;
    return mField.value(*q);
  }

  // Composites a segment dt long sampled at distance @p t.
  HYB_HOT void sampleFull(float t) {
    glm::vec3 q;
    const size_t e = size_t(mF.layout.entry(valueAt(t, &q)));
    if (mF.visible[e]) composite(q, mF.table[e].full, t);
  }

  // Composites the volume's segment [s, e], shorter than dt, sampled at its middle.
  void sample(double s, double e) {
    glm::vec3 q;
    const size_t i = size_t(mF.layout.entry(valueAt(float(0.5 * (s + e)), &q)));
    if (!mF.visible[i]) return;
    const Entry& entry = mF.table[i];
    const float a = 1.0f - std::exp(-entry.tau * float(e - s));
    composite(q, glm::vec4(entry.color * a, a), float(0.5 * (s + e)));
  }

  // Composites premultiplied @p c sampled at @p q, distance @p t, shaded by the gradient there.
  void composite(const glm::vec3& q, glm::vec4 c, float t) {
    if (mF.options.shading) {
      const glm::vec3 g = mField.gradient(q);
      const float len2 = glm::dot(g, g);
      if (len2 > 1e-12f) c = glm::vec4(glm::vec3(c) * (0.25f + 0.75f * std::abs(glm::dot(g, mDir)) / std::sqrt(len2)), c.a);
    }
    add(c, t);
  }
  void add(const glm::vec4& c, float t) {
    mAcc += c * (1.0f - mAcc.a);
    if (mAcc.a >= 0.5f && !(mHalf < kNever)) mHalf = t;
  }

  const Frame& mF;
  Field mField;
  std::optional<Hit> mHit;  // the next crossing, not composited yet
  glm::dvec3 mO{0.0}, mD{0.0};  // the ray
  glm::vec4 mAcc{0.0f};
  float mHalf = kNever;
  glm::vec3 mDir{0.0f}, mQo{0.0f}, mQd{0.0f};  // the ray's direction (mm), origin and direction in voxels
};

// Traces every pixel in squares of 8² (neighbouring rays read the same samples while at hand) on
// all cores, each thread with the field @p makeField() gives it.
template <class MakeField>
void traceAll(const Frame& f, const MakeField& makeField, Image* out, std::vector<float>* depth, RaycastStats* stats) {
  constexpr int kSquare = 8;
  const int W = f.camera.width, H = f.camera.height;
  const int across = (W + kSquare - 1) / kSquare, squares = across * ((H + kSquare - 1) / kSquare);
  uint64_t samples = 0, skipped = 0, crossings = 0;
  ParallelFailure failure;  // a block that cannot be read
#pragma omp parallel reduction(+ : samples, skipped, crossings)
  {
    Tracer tracer(f, makeField());
#pragma omp for schedule(dynamic, 1)
    for (int s = 0; s < squares; ++s) {
      failure.run([&] {
        const int x0 = (s % across) * kSquare, y0 = (s / across) * kSquare;
        for (int y = y0; y < std::min(y0 + kSquare, H); ++y)
          for (int x = x0; x < std::min(x0 + kSquare, W); ++x) {
            out->at(x, y) = tracer.trace(x, y);
            if (depth) (*depth)[size_t(y) * size_t(W) + size_t(x)] = tracer.half();
          }
      });
    }
    samples += tracer.samples;
    skipped += tracer.skipped;
    crossings += tracer.crossings;
  }
  failure.rethrow();
  stats->samples += samples;
  stats->skippedLeaves += skipped;
  stats->surfaceHits += crossings;
  stats->rays += uint64_t(W) * uint64_t(H);
}

}  // namespace

bool interactiveRaysServe(const Volume& volume, const RaycastOptions& o) {
  return o.volume && !o.cut && !o.voi && !o.meshes && !o.geometry && !o.preintegrated && !o.region && o.refineLevels == 1 && !o.rows &&
         glm::all(glm::greaterThanEqual(volume.dims(), glm::ivec3(2))) && (o.knots || volume.hasSamples());
}

Image raycastInteractive(const Volume& volume, const VolumeOctree& octree, const TransferFunction& tf, const Camera& camera,
                         const RaycastOptions& options, InteractiveOutputs out) {
  RaycastStats* stats = out.stats;
  std::vector<float>* depth = out.depth;
  HYB_CHECK(interactiveRaysServe(volume, options));
  if (!withinCameraRange(camera.eye) || !withinCameraRange(camera.center))
    HYB_THROW(ValueError, "camera eye and center must lie within ", kMaxCameraMm, " mm of the origin");
  RaycastStats counts;
  Image image(camera.width, camera.height);
  const Frame f(volume, octree, tf, camera, options);
  if (depth) depth->assign(size_t(camera.width) * size_t(camera.height), 0.0f);
  if (options.knots) {
    // Blocks hold the volume's stored type (a type they do not hold is read through the sampler).
    auto paged = [&](auto zero) { traceAll(f, [&] { return PagedField<decltype(zero)>(*options.knots); }, &image, depth, &counts); };
    switch (volume.storedType()) {
      case ScalarType::UInt8: paged(uint8_t()); break;
      case ScalarType::Int8: paged(int8_t()); break;
      case ScalarType::UInt16: paged(uint16_t()); break;
      case ScalarType::Int16: paged(int16_t()); break;
      default: paged(float()); break;
    }
  } else
    volume.visitSamples([&](const auto* data) {
      using T = std::remove_cv_t<std::remove_pointer_t<decltype(data)>>;
      traceAll(f, [&] { return MemoryField<T>(data, volume.dims(), volume.spacing()); }, &image, depth, &counts);
    });
  if (stats) *stats = counts;
  return image;
}

#undef HYB_HOT

}  // namespace hyb
