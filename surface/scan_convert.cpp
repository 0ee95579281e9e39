// Filtered 3D scan-conversion (Levoy 1989; docs/scan-conversion.md). A mesh is converted in
// z-slabs, one thread each: (1) the solid's voxels by scanline parity along x, each triangle's
// projection on the (y, z) rows rasterised with a top-left rule so that a row through a shared edge
// or vertex crosses the surface exactly once; (2) the narrow band, each triangle visiting the voxels
// within the filter's reach of its plane in the rows within reach of its outline, their distances
// taken four at a time (SSE), and keeping the closest triangle per voxel; (3) each band voxel's box
// fraction of the tangent plane at its closest point.
#include "surface/scan_convert.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <limits>
#include <memory>
#include <numbers>
#include <utility>

#include "surface/closest_point.h"
#include "volume/core/error.h"
#include "volume/core/huge_pages.h"
#include "volume/core/parallel.h"

#ifdef __SSE2__
#include <immintrin.h>
#endif

namespace hyb {

namespace {

// z-planes per slab: small enough that two threads balance on a sphere, large enough that a
// triangle rarely falls into more than one.
constexpr int kSlabPlanes = 4;

double cube(double x) { return x * x * x; }  // (std::pow(x, 3) is a call)

// Fraction of the unit cube [0, 1]³ where m·v ≤ t, for m1 ≥ m2 ≥ m3 ≥ 0, m1 > 0. Piecewise
// polynomial (the inclusion–exclusion over the cube's corners), each piece written so that no term
// divides by a component smaller than the piece's width: stable as m3 or m2 tend to 0.
double sortedCubeFraction(double m1, double m2, double m3, double t) {
  const double total = m1 + m2 + m3;
  if (t <= 0.0) return 0.0;
  if (t >= total) return 1.0;
  if (t > 0.5 * total) return 1.0 - sortedCubeFraction(m1, m2, m3, total - t);
  // The plane cuts only the four edges along the first axis: the average of its position.
  if (t >= m2 + m3) return (t - 0.5 * (m2 + m3)) / m1;
  // t < m2 + m3 ≤ total / 2 here, so (t − m2)⁺ and (t − m1)⁺ are below m3.
  const double denom = 6.0 * m1 * m2;
  double v = t <= m3 ? t * t * t / (denom * m3) : (3.0 * t * t - 3.0 * t * m3 + m3 * m3) / denom;
  if (t > m2) v -= cube(t - m2) / (denom * m3);
  if (t > m1) v -= cube(t - m1) / (denom * m3);
  return std::clamp(v, 0.0, 1.0);
}

// |m| sorted largest first.
glm::dvec3 sortedMagnitudes(const glm::dvec3& m) {
  glm::dvec3 a = glm::abs(m);
  if (a.x < a.y) std::swap(a.x, a.y);
  if (a.y < a.z) std::swap(a.y, a.z);
  if (a.x < a.y) std::swap(a.x, a.y);
  return a;
}

// boxHalfSpaceFraction for @p a = sortedMagnitudes(m).
double sortedBoxFraction(const glm::dvec3& a, double t) {
  if (a.x == 0.0) return t >= 0.0 ? 1.0 : 0.0;
  // Centred cube → unit cube: m·u ≤ t with u = v − ½ is m·v ≤ t + Σm/2.
  return sortedCubeFraction(a.x, a.y, a.z, t + 0.5 * (a.x + a.y + a.z));
}

// Sheet coverage: the box fraction between the planes at distances −τ/2 and τ/2 from a surface
// point at distance d (unsigned) along the unit direction whose box-scaled components are m.
double sheetFraction(const glm::dvec3& m, double d, double halfThickness) {
  const glm::dvec3 a = sortedMagnitudes(m);
  return sortedBoxFraction(a, halfThickness - d) - sortedBoxFraction(a, -halfThickness - d);
}

void checkOptions(const ScanOptions& o, bool sheet) {
  if (!std::isfinite(o.width) || o.width <= 0.0) HYB_THROW(ValueError, "scan conversion: width ", o.width, " must be a positive number of voxels");
  if (!std::isfinite(o.thickness) || o.thickness < 0.0)
    HYB_THROW(ValueError, "scan conversion: thickness ", o.thickness, " must be a number of mm ≥ 0");
  if (sheet && o.thickness <= 0.0) HYB_THROW(ValueError, "scan conversion: a plane or polygon needs a thickness > 0 mm (got ", o.thickness, ")");
}

void checkGrid(const VoxelGrid& grid) {
  validateDims(grid.dims, "scan conversion grid");
  validateSpacing(grid.spacing, "scan conversion grid");
}

bool finite(const glm::dvec3& v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); }

// floor(v) and ceil(v) as an index clamped to [lo − 1, hi + 1] (a far-away vertex must not overflow
// an int): clamped first, then truncated and corrected, which is cheaper than std::floor without SSE4.1.
template <class Real>
int floorIndex(Real v, int lo, int hi) {
  v = std::clamp(v, Real(lo - 1), Real(hi + 1));
  const int i = int(v);
  return i - (Real(i) > v);
}
template <class Real>
int ceilIndex(Real v, int lo, int hi) {
  v = std::clamp(v, Real(lo - 1), Real(hi + 1));
  const int i = int(v);
  return i + (Real(i) < v);
}

// A point of @p space in the grid frame (mm).
glm::dvec3 toGridPoint(const glm::dvec3& p, ScanSpace space, const VoxelGrid& grid) {
  switch (space) {
    case ScanSpace::Index: return p * grid.spacing;
    case ScanSpace::Grid: return p;
    case ScanSpace::Patient: return grid.frame.toGrid(p);
  }
  return p;
}
// A normal of @p space in the grid frame (not unit): index-space normals scale by 1 / spacing.
glm::dvec3 toGridNormal(const glm::dvec3& n, ScanSpace space, const VoxelGrid& grid) {
  switch (space) {
    case ScanSpace::Index: return n / grid.spacing;
    case ScanSpace::Grid: return n;
    case ScanSpace::Patient: return grid.frame.vectorToGrid(n);
  }
  return n;
}

// The coverage voxels being written, x fastest: one buffer on huge pages, left uninitialised so that
// the threads writing each slab touch its pages first. Every voxel is written once.
struct CoverageStore {
  std::shared_ptr<void> buffer;
  uint8_t* u8 = nullptr;
  float* f32 = nullptr;
  bool bytes = true;

  CoverageStore(const glm::ivec3& dims, CoverageType type) : bytes(type == CoverageType::UInt8) {
    const size_t n = size_t(dims.x) * size_t(dims.y) * size_t(dims.z);
    buffer = hugePageBuffer(n * (bytes ? 1 : sizeof(float)));
    if (bytes) u8 = static_cast<uint8_t*>(buffer.get());
    else f32 = static_cast<float*>(buffer.get());
  }
  void set(size_t n, double v) {
    if (bytes) u8[n] = uint8_t(v * 255.0 + 0.5);  // v in [0, 1]: rounded half up
    else f32[n] = float(v);
  }
  void fill(size_t n, size_t count, bool one) {
    if (bytes) std::fill_n(u8 + n, count, uint8_t(one ? 255 : 0));
    else std::fill_n(f32 + n, count, one ? 1.0f : 0.0f);
  }
  bool one(size_t n) const { return bytes ? u8[n] == 255 : f32[n] == 1.0f; }
};

ScanResult makeResult(const VoxelGrid& grid, CoverageStore&& store, std::vector<std::string> warnings, size_t band, size_t inside) {
  ScanResult r;
  const ScalarType type = store.bytes ? ScalarType::UInt8 : ScalarType::Float32;
  const void* data = store.buffer.get();
  r.coverage = Volume::borrowing({grid.dims, grid.spacing, type, type}, data, std::move(store.buffer), "coverage");
  r.coverage.setFrame(grid.frame);
  r.coverage.addInfo("coverage", store.bytes ? "fraction x 255" : "fraction");
  r.warnings = std::move(warnings);
  r.bandVoxels = band;
  r.insideVoxels = inside;
  return r;
}

// The box's sides in mm, halved diagonal: no voxel farther than this from a plane is cut by it.
glm::dvec3 boxSides(const VoxelGrid& grid, const ScanOptions& o) { return grid.spacing * o.width; }
double boxReach(const VoxelGrid& grid, const ScanOptions& o) {
  return o.filter == ScanFilter::None ? 0.0 : 0.5 * glm::length(boxSides(grid, o));
}

// Runs @p value(p) (grid mm → coverage) over every voxel, z-planes on all cores, and counts the
// voxels partly (band) and wholly (inside) covered.
template <class Value>
void forEachVoxel(const VoxelGrid& grid, CoverageStore* store, size_t* band, size_t* inside, const Value& value) {
  const glm::ivec3 d = grid.dims;
  size_t bandCount = 0, insideCount = 0;
#pragma omp parallel for schedule(dynamic, 1) reduction(+ : bandCount, insideCount)
  for (int k = 0; k < d.z; ++k)
    for (int j = 0; j < d.y; ++j) {
      const size_t row = size_t(d.x) * (size_t(j) + size_t(d.y) * size_t(k));
      for (int i = 0; i < d.x; ++i) {
        const double v = value(glm::dvec3(i, j, k) * grid.spacing);
        if (v >= 1.0) ++insideCount;
        else if (v > 0.0) ++bandCount;
        store->set(row + size_t(i), std::clamp(v, 0.0, 1.0));
      }
    }
  *band = bandCount;
  *inside = insideCount;
}

// ---- Meshes ----

// A triangle's corners in the grid frame (mm).
struct Tri {
  glm::vec3 a, b, c;
  // Its unit normal, the way its corners turn counter-clockwise; zero for a triangle without area.
  glm::vec3 normal() const {
    const glm::vec3 cr = glm::cross(b - a, c - a);
    const float len = glm::length(cr);
    return len > 0.0f && std::isfinite(len) ? cr / len : glm::vec3(0.0f);
  }
};

// Voxels near one triangle whose distances are being taken, gathered row by row and measured
// about kCandidateBatch at a time: the offset from corner a of each, its components in the order
// of the triangle's rows (TriangleDistance), and its index in the slab. Measured before a row that
// would take them past the batch, so that the room past it holds the longest row (a thick sheet's
// may span the grid), and a lane's worth more for the lanes measured past the count.
constexpr int kCandidateBatch = 256;
struct Candidates {
  std::vector<float> buffer;  // u, v, w and dist2, `room` each
  std::vector<uint32_t> atBuffer;
  float *u = nullptr, *v = nullptr, *w = nullptr, *dist2 = nullptr;
  uint32_t* at = nullptr;
  int count = 0;
  // Room for a batch and the longest row of @p longestRow voxels.
  void allocate(int longestRow) {
    const size_t room = size_t(kCandidateBatch + longestRow + 3);
    buffer.assign(4 * room, 0.0f);
    atBuffer.assign(room, 0);
    u = buffer.data(), v = u + room, w = v + room, dist2 = w + room, at = atBuffer.data();
  }
};

float minf(float a, float b) { return b < a ? b : a; }
float maxf(float a, float b) { return b > a ? b : a; }

// The squared distance from a point to a triangle, without a branch, so that a batch of points
// runs in vector lanes (voxels near a triangle fall in its regions unpredictably): the plane's
// where the point projects inside the triangle (its barycentric weights, linear in ab·ap and
// ac·ap, all ≥ 0), else the least of the three edges' distances, each to the point's projection
// on the edge clamped to its ends. Every dot product but those with ap is taken once per triangle;
// the vectors are in the (u, v, w) order of the triangle's rows.
struct TriangleDistance {
  glm::vec3 ab, ac, n;             // b − a, c − a, the unit normal
  float d11, d12, d22, ee, area2;  // ab·ab, ab·ac, ac·ac, bc·bc, |ab × ac|² (−∞ for a sliver)
  float inv11, inv22, invEe;
  TriangleDistance(const Tri& t, const glm::vec3& normal, const glm::ivec3& order)
      : ab(swizzle(t.b - t.a, order)), ac(swizzle(t.c - t.a, order)), n(swizzle(normal, order)), d11(glm::dot(ab, ab)), d12(glm::dot(ab, ac)),
        d22(glm::dot(ac, ac)), ee(d11 + d22 - 2.0f * d12), area2(d11 * d22 - d12 * d12), inv11(1.0f / d11), inv22(1.0f / d22), invEe(1.0f / ee) {
    // A sliver (an angle under about 0.06°) is taken as its edges, within a thousandth of its
    // length: the rounding of its area would put points beside it inside, at its plane's distance.
    if (!(area2 > 1e-6f * d11 * d22)) area2 = -std::numeric_limits<float>::infinity();
  }
  static glm::vec3 swizzle(const glm::vec3& q, const glm::ivec3& order) { return {q[order.x], q[order.y], q[order.z]}; }

  // The squared distance of the point at offset (pu, pv, pw) from corner a.
  float squared(float pu, float pv, float pw) const {
    const float d1 = (ab.x * pu + ab.y * pv) + ab.z * pw, d2 = (ac.x * pu + ac.y * pv) + ac.z * pw;
    const float aa = (pu * pu + pv * pv) + pw * pw, plane = (n.x * pu + n.y * pv) + n.z * pw;
    const float vb = d22 * d1 - d12 * d2, vc = d11 * d2 - d12 * d1;  // the weights of b and c, times area2
    const float e = ((d2 - d12) - d1) + d11;                          // bc·bp
    const float tab = minf(maxf(d1 * inv11, 0.0f), 1.0f), tac = minf(maxf(d2 * inv22, 0.0f), 1.0f), tbc = minf(maxf(e * invEe, 0.0f), 1.0f);
    const float qab = aa - tab * (2.0f * d1 - tab * d11), qac = aa - tac * (2.0f * d2 - tac * d22);
    const float qbc = ((aa - 2.0f * d1) + d11) - tbc * (2.0f * e - tbc * ee);  // |bp|² = |ap|² − 2 ab·ap + |ab|²
    const float inside = minf(minf(vb, vc), (area2 - vb) - vc);  // ≥ 0 where ap projects inside
    return inside >= 0.0f ? plane * plane : maxf(minf(qab, minf(qac, qbc)), 0.0f);
  }

  // The squared distance of every candidate; four at a time in SSE lanes (the same operations as
  // squared(), so the same results), the lanes past the count measured and ignored.
  void measure(Candidates* c) const {
    int i = 0;
#ifdef __SSE2__
    const __m128 abu = _mm_set1_ps(ab.x), abv = _mm_set1_ps(ab.y), abw = _mm_set1_ps(ab.z);
    const __m128 acu = _mm_set1_ps(ac.x), acv = _mm_set1_ps(ac.y), acw = _mm_set1_ps(ac.z);
    const __m128 nu = _mm_set1_ps(n.x), nv = _mm_set1_ps(n.y), nw = _mm_set1_ps(n.z);
    const __m128 s11 = _mm_set1_ps(d11), s12 = _mm_set1_ps(d12), s22 = _mm_set1_ps(d22), see = _mm_set1_ps(ee), sArea = _mm_set1_ps(area2);
    const __m128 i11 = _mm_set1_ps(inv11), i22 = _mm_set1_ps(inv22), iEe = _mm_set1_ps(invEe);
    const __m128 zero = _mm_setzero_ps(), one = _mm_set1_ps(1.0f), two = _mm_set1_ps(2.0f);
    auto dot = [](__m128 x, __m128 y, __m128 z, __m128 pu, __m128 pv, __m128 pw) {
      return _mm_add_ps(_mm_add_ps(_mm_mul_ps(x, pu), _mm_mul_ps(y, pv)), _mm_mul_ps(z, pw));
    };
    auto clamp01 = [&](__m128 t) { return _mm_min_ps(_mm_max_ps(t, zero), one); };
    // |p − q|² for q the point at t along an edge: len2 is |p − edge start|², pe its dot with the edge.
    auto edgeSquared = [&](__m128 len2, __m128 t, __m128 pe, __m128 ee2) {
      return _mm_sub_ps(len2, _mm_mul_ps(t, _mm_sub_ps(_mm_mul_ps(two, pe), _mm_mul_ps(t, ee2))));
    };
    for (; i < c->count; i += 4) {
      const __m128 pu = _mm_loadu_ps(c->u + i), pv = _mm_loadu_ps(c->v + i), pw = _mm_loadu_ps(c->w + i);
      const __m128 d1 = dot(abu, abv, abw, pu, pv, pw), d2 = dot(acu, acv, acw, pu, pv, pw);
      const __m128 aa = dot(pu, pv, pw, pu, pv, pw), plane = dot(nu, nv, nw, pu, pv, pw);
      const __m128 vb = _mm_sub_ps(_mm_mul_ps(s22, d1), _mm_mul_ps(s12, d2)), vc = _mm_sub_ps(_mm_mul_ps(s11, d2), _mm_mul_ps(s12, d1));
      const __m128 e = _mm_add_ps(_mm_sub_ps(_mm_sub_ps(d2, s12), d1), s11);
      const __m128 tab = clamp01(_mm_mul_ps(d1, i11)), tac = clamp01(_mm_mul_ps(d2, i22)), tbc = clamp01(_mm_mul_ps(e, iEe));
      const __m128 qab = edgeSquared(aa, tab, d1, s11), qac = edgeSquared(aa, tac, d2, s22);
      const __m128 qbc = edgeSquared(_mm_add_ps(_mm_sub_ps(aa, _mm_mul_ps(two, d1)), s11), tbc, e, see);
      const __m128 inside = _mm_cmpge_ps(_mm_min_ps(_mm_min_ps(vb, vc), _mm_sub_ps(_mm_sub_ps(sArea, vb), vc)), zero);
      const __m128 edge = _mm_max_ps(_mm_min_ps(qab, _mm_min_ps(qac, qbc)), zero);
      _mm_storeu_ps(c->dist2 + i, _mm_or_ps(_mm_and_ps(inside, _mm_mul_ps(plane, plane)), _mm_andnot_ps(inside, edge)));
    }
#endif
    for (; i < c->count; ++i) c->dist2[i] = squared(c->u[i], c->v[i], c->w[i]);
  }
};

// 2D edge function of the (y, z) projection, computed from the edge's endpoints in one canonical
// order so that the two triangles sharing an edge get exactly opposite values.
double edgeFunction(const glm::dvec2& a, const glm::dvec2& b, const glm::dvec2& q) {
  const bool ordered = a.x < b.x || (a.x == b.x && a.y < b.y);
  const glm::dvec2& s = ordered ? a : b;
  const glm::dvec2& e = ordered ? b : a;
  const double v = (e.x - s.x) * (q.y - s.y) - (e.y - s.y) * (q.x - s.x);
  return ordered ? v : -v;
}
// Top-left rule for an edge of direction @p d in a counter-clockwise triangle: a point on it
// belongs to exactly one of the two triangles sharing it.
bool ownsEdge(const glm::dvec2& d) { return d.y < 0.0 || (d.y == 0.0 && d.x > 0.0); }

constexpr uint32_t kNone = std::numeric_limits<uint32_t>::max();

// What one slab's thread keeps between slabs.
struct SlabScratch {
  struct Closest {
    float dist2;     // squared distance to the closest triangle so far (mm²)
    uint32_t owner;  // that triangle, or kNone
  };
  // Per voxel of the slab (8 MiB for 512² × 4), on 2 MiB pages; the two side by side, in one cache line.
  std::vector<Closest, HugePageAllocator<Closest>> closest;
  // Voxels (in slab) whose owner is set, for stage 3 and the reset: the first touchedCount of room
  // for one more than the slab's voxels (the branch-free update writes one past them), uninitialised
  // so that only the pages used are touched.
  std::shared_ptr<void> touchedBuffer;
  uint32_t* touched = nullptr;
  size_t touchedCount = 0;
  std::vector<std::pair<uint32_t, float>> crossings;  // (row in slab, x mm)
  VoxelNormals normals;                               // the band voxels' (ScanOptions::normals), this thread's slabs'
  Candidates candidates;
};

// Everything the stages of one mesh conversion share.
struct MeshScan {
  const VoxelGrid& grid;
  const ScanOptions& options;
  const glm::vec3* points = nullptr;  // the vertices in the grid frame (mm)
  const glm::uvec3* faces = nullptr;  // the mesh's triangles
  std::vector<uint32_t> slabStart, slabTris;  // triangles of slab s: slabTris[slabStart[s] .. slabStart[s + 1])
  bool solid = true;
  double reach = 0.0;  // mm from the surface within which a voxel is filtered
  CoverageStore* store = nullptr;

  int slabCount() const { return (grid.dims.z + kSlabPlanes - 1) / kSlabPlanes; }
  Tri tri(uint32_t t) const { return {points[faces[t].x], points[faces[t].y], points[faces[t].z]}; }

  // Stage 1: inside runs of every row of slab planes [k0, k1) by parity of the crossings; counts the
  // voxels filled, and the rows crossed an odd number of times (the mesh is open along them; their
  // last run is dropped).
  void fillSolid(int k0, int k1, std::span<const uint32_t> list, SlabScratch* scratch, size_t* filled, size_t* oddRows) const {
    const glm::ivec3 d = grid.dims;
    const glm::dvec3 s = grid.spacing;
    auto& crossings = scratch->crossings;
    crossings.clear();
    for (const uint32_t t : list) {
      const Tri tri = this->tri(t);
      const glm::dvec2 a(tri.a.y, tri.a.z), b(tri.b.y, tri.b.z), c(tri.c.y, tri.c.z);
      const double area = edgeFunction(a, b, c);
      if (area == 0.0) continue;  // seen edge-on: its neighbours' edges stand in for it
      const double sign = area > 0.0 ? 1.0 : -1.0;
      const glm::dvec2 lo = glm::min(a, glm::min(b, c)), hi = glm::max(a, glm::max(b, c));
      const int j0 = std::max(0, ceilIndex(lo.x / s.y, 0, d.y)), j1 = std::min(d.y - 1, floorIndex(hi.x / s.y, 0, d.y));
      const int kk0 = std::max(k0, ceilIndex(lo.y / s.z, k0, k1)), kk1 = std::min(k1 - 1, floorIndex(hi.y / s.z, k0, k1));
      const glm::dvec2 dab = (b - a) * sign, dbc = (c - b) * sign, dca = (a - c) * sign;
      for (int k = kk0; k <= kk1; ++k)
        for (int j = j0; j <= j1; ++j) {
          const glm::dvec2 q(j * s.y, k * s.z);
          const double wc = edgeFunction(a, b, q) * sign, wa = edgeFunction(b, c, q) * sign, wb = edgeFunction(c, a, q) * sign;
          if (wa < 0.0 || wb < 0.0 || wc < 0.0) continue;
          if ((wc == 0.0 && !ownsEdge(dab)) || (wa == 0.0 && !ownsEdge(dbc)) || (wb == 0.0 && !ownsEdge(dca))) continue;
          const double sum = wa + wb + wc;
          const double x = sum > 0.0 ? (wa * tri.a.x + wb * tri.b.x + wc * tri.c.x) / sum : tri.a.x;
          crossings.emplace_back(uint32_t(size_t(k - k0) * size_t(d.y) + size_t(j)), float(x));
        }
    }
    std::sort(crossings.begin(), crossings.end());
    for (size_t n = 0; n < crossings.size();) {
      size_t e = n;
      while (e < crossings.size() && crossings[e].first == crossings[n].first) ++e;
      if ((e - n) % 2) ++*oddRows;
      const size_t rowStart = size_t(d.x) * (size_t(crossings[n].first) + size_t(k0) * size_t(d.y));
      for (size_t m = n; m + 1 < e; m += 2) {
        // Voxels whose centre lies strictly between an entry and the next exit.
        const int i0 = std::max(0, floorIndex(double(crossings[m].second) / s.x, 0, d.x) + 1);
        const int i1 = std::min(d.x - 1, ceilIndex(double(crossings[m + 1].second) / s.x, 0, d.x) - 1);
        if (i1 >= i0) {
          store->fill(rowStart + size_t(i0), size_t(i1 - i0 + 1), true);
          *filled += size_t(i1 - i0 + 1);
        }
      }
      n = e;
    }
  }

  // Stage 2: the closest triangle of every voxel of planes [k0, k1) within `reach` of the surface.
  void closestTriangles(int k0, int k1, std::span<const uint32_t> list, SlabScratch* scratch) const {
    const glm::ivec3 d = grid.dims;
    const glm::vec3 s(grid.spacing), inv = 1.0f / s;
    const float r = float(reach);
    for (const uint32_t t : list) {
      const Tri tri = this->tri(t);
      const glm::vec3 normal = tri.normal();
      if (normal == glm::vec3(0.0f)) continue;
      const glm::vec3 lo = (glm::min(tri.a, glm::min(tri.b, tri.c)) - r) * inv, hi = (glm::max(tri.a, glm::max(tri.b, tri.c)) + r) * inv;
      const glm::ivec3 first(std::max(0, ceilIndex(lo.x, 0, d.x)), std::max(0, ceilIndex(lo.y, 0, d.y)), std::max(k0, ceilIndex(lo.z, k0, k1)));
      const glm::ivec3 last(std::min(d.x - 1, floorIndex(hi.x, 0, d.x)), std::min(d.y - 1, floorIndex(hi.y, 0, d.y)),
                            std::min(k1 - 1, floorIndex(hi.z, k0, k1)));
      if (glm::any(glm::lessThan(last, first))) continue;
      // Rows along the axis w the plane is steepest across (n_w·s_w largest), so that each row
      // holds only the few voxels within the reach of the plane.
      const glm::vec3 mag = glm::abs(normal * s);
      const Box box{first, last - first + 1};
      if (mag.x >= mag.y && mag.x >= mag.z) closestAlong<0>(t, tri, normal, box, k0, scratch);
      else if (mag.y >= mag.z) closestAlong<1>(t, tri, normal, box, k0, scratch);
      else closestAlong<2>(t, tri, normal, box, k0, scratch);
    }
  }

  // Voxels [lo, lo + size) of the grid.
  struct Box {
    glm::ivec3 lo, size;
  };

  // Stage 2 for triangle @p t over the voxels of @p box (slab planes from k0), in rows along axis
  // W: the voxels within the reach of the triangle's plane in each row whose (u, v) is within the
  // reach of the triangle's projection, their distances taken kCandidateBatch at a time.
  template <int W>
  void closestAlong(uint32_t t, const Tri& tri, const glm::vec3& normal, const Box& box, int k0, SlabScratch* scratch) const {
    constexpr int U = W == 0 ? 1 : 0, V = W == 2 ? 1 : 2;
    const glm::ivec3 d = grid.dims, first = box.lo, last = box.lo + box.size - 1;
    const glm::vec3 s(grid.spacing);
    const float r = float(reach);
    const uint32_t stride[3] = {1, uint32_t(d.x), uint32_t(d.x) * uint32_t(d.y)};  // (a slab holds under 2³² voxels)
    const TriangleDistance distance(tri, normal, glm::ivec3(U, V, W));
    Candidates& cand = scratch->candidates;
    // Keeps each candidate closer than its voxel's best so far (branch-free: most are not).
    auto flush = [&] {
      distance.measure(&cand);
      uint32_t* touched = scratch->touched + scratch->touchedCount;
      size_t count = 0;
      for (int i = 0; i < cand.count; ++i) {
        SlabScratch::Closest& best = scratch->closest[cand.at[i]];
        const bool closer = cand.dist2[i] < best.dist2;  // it starts at the reach²
        touched[count] = cand.at[i];
        count += size_t(closer & (best.owner == kNone));
        best.dist2 = closer ? cand.dist2[i] : best.dist2;
        best.owner = closer ? t : best.owner;
      }
      scratch->touchedCount += count;
      cand.count = 0;
    };
    // A row (a, b) holds the voxels c ∈ [cLo + a·dA + b·dB, … + width] within the reach of the
    // plane (a hundredth of a voxel more for rounding).
    const glm::vec3 slope = normal * s;  // the plane's distance per voxel along each axis
    const float margin = 0.01f;
    const float dA = -slope[U] / slope[W], dB = -slope[V] / slope[W], width = 2.0f * r / std::abs(slope[W]) + 2.0f * margin;
    const float cLo = (glm::dot(normal, tri.a) - r * (slope[W] > 0.0f ? 1.0f : -1.0f)) / slope[W] - margin;
    // The rows within the reach of the triangle's projection along W: inside each of its edges'
    // lines moved out by the reach. Each line bounds a row's a from below or above as a linear
    // function of b; the unused bound of each is out of the grid.
    float loSlope[3], loOffset[3], hiSlope[3], hiOffset[3];
    {
      const glm::vec2 corner[3] = {{tri.a[U], tri.a[V]}, {tri.b[U], tri.b[V]}, {tri.c[U], tri.c[V]}};
      const glm::vec2 e01 = corner[1] - corner[0], e02 = corner[2] - corner[0];
      const float cross = e01.x * e02.y - e01.y * e02.x, turn = cross > 0.0f ? 1.0f : -1.0f;
      // (A sliver whose turn rounding may get wrong bounds no row.)
      const bool sliver = std::abs(cross) <= 1e-4f * (glm::dot(e01, e01) + glm::dot(e02, e02));
      for (int e = 0; e < 3; ++e) {
        // out·(q − corner) ≤ reach·|out| for q = (a·s_u, b·s_v), out the edge's outward normal.
        const glm::vec2 dir = corner[(e + 1) % 3] - corner[e], out = turn * glm::vec2(dir.y, -dir.x);
        const float bound = (r * glm::length(out) + glm::dot(out, corner[e])) / (out.x * s[U]) + (out.x > 0.0f ? margin : -margin);
        const float across = -out.y * s[V] / (out.x * s[U]);
        // (out.x = 0, an edge along u, bounds b only: the box's b-range holds it.)
        const bool upper = out.x > 0.0f && !sliver, lower = out.x < 0.0f && !sliver;
        loSlope[e] = lower ? across : 0.0f;
        loOffset[e] = lower ? bound : -1e30f;
        hiSlope[e] = upper ? across : 0.0f;
        hiOffset[e] = upper ? bound : 1e30f;
      }
    }
    for (int b = first[V]; b <= last[V]; ++b) {
      const float fb = float(b);
      const float aLo = maxf(maxf(loSlope[0] * fb + loOffset[0], loSlope[1] * fb + loOffset[1]), loSlope[2] * fb + loOffset[2]);
      const float aHi = minf(minf(hiSlope[0] * fb + hiOffset[0], hiSlope[1] * fb + hiOffset[1]), hiSlope[2] * fb + hiOffset[2]);
      const int a0 = std::max(first[U], ceilIndex(aLo, first[U], last[U])), a1 = std::min(last[U], floorIndex(aHi, first[U], last[U]));
      const float rowLo = cLo + fb * dB, pv = fb * s[V] - tri.a[V];
      for (int a = a0; a <= a1; ++a) {
        const float lo = rowLo + float(a) * dA;
        const int c0 = std::max(first[W], ceilIndex(lo, first[W], last[W])), c1 = std::min(last[W], floorIndex(lo + width, first[W], last[W]));
        if (c1 < c0) continue;
        if (cand.count + (c1 - c0 + 1) > kCandidateBatch) flush();  // (a longer row fits the room past the batch)
        const float pu = float(a) * s[U] - tri.a[U];
        uint32_t at = uint32_t(a) * stride[U] + uint32_t(b) * stride[V] + uint32_t(c0) * stride[W] - uint32_t(k0) * stride[2];
        for (int c = c0; c <= c1; ++c, at += stride[W]) {
          const int i = cand.count++;
          cand.u[i] = pu;
          cand.v[i] = pv;
          cand.w[i] = float(c) * s[W] - tri.a[W];
          cand.at[i] = at;
        }
      }
    }
    if (cand.count > 0) flush();
  }

  // Stage 3: each band voxel's box fraction of the tangent plane at its closest point; resets the
  // scratch for the next slab. Returns the band voxels and, of them, those the fill had inside.
  std::pair<size_t, size_t> filterBand(int k0, SlabScratch* scratch) const {
    const glm::ivec3 d = grid.dims;
    const glm::dvec3 box = boxSides(grid, options);
    const double half = 0.5 * options.thickness;
    const size_t planeSize = size_t(d.x) * size_t(d.y);
    const float r2 = float(reach * reach);
    size_t band = 0, bandInside = 0;
    for (size_t q = 0; q < scratch->touchedCount; ++q) {
      const uint32_t n = scratch->touched[q];
      const uint32_t t = scratch->closest[n].owner;
      scratch->closest[n] = {r2, kNone};
      const uint32_t row = n / uint32_t(d.x);  // (32-bit divisions: a slab holds under 2³² voxels)
      const int i = int(n - row * uint32_t(d.x)), j = int(row % uint32_t(d.y)), k = k0 + int(row / uint32_t(d.y));
      const size_t out = n + size_t(k0) * planeSize;
      const Tri tri = this->tri(t);
      const glm::vec3 normal = tri.normal();
      const glm::dvec3 p = glm::dvec3(i, j, k) * grid.spacing;
      const glm::dvec3 c(closestOnTriangle(glm::vec3(p), tri.a, tri.b, tri.c));
      const double dist = glm::length(p - c);
      const glm::dvec3 dir = dist > 1e-6 * reach ? (p - c) / dist : glm::dvec3(normal);
      const glm::dvec3 m = glm::abs(dir) * box;
      ++band;
      if (options.normals) scratch->normals.push_back({uint64_t(out), normal});
      if (solid) {
        const bool inside = store->one(out);
        bandInside += inside;
        store->set(out, options.filter == ScanFilter::None ? double(inside) : boxHalfSpaceFraction(m, inside ? dist : -dist));
      } else {
        store->set(out, options.filter == ScanFilter::None ? double(dist <= half) : sheetFraction(m, dist, half));
      }
    }
    scratch->touchedCount = 0;
    return {band, bandInside};
  }
};

void validateMesh(const TriangleMesh& mesh) {
  if (mesh.triangles.empty()) HYB_THROW(ValueError, "mesh: no triangles (expected a triangle mesh to scan-convert)");
  for (size_t v = 0; v < mesh.vertices.size(); ++v) {
    const glm::vec3& p = mesh.vertices[v];
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z))
      HYB_THROW(ValueError, "mesh: vertex ", v, " is not finite (", p.x, ", ", p.y, ", ", p.z, ")");
  }
  for (size_t t = 0; t < mesh.triangles.size(); ++t) {
    const glm::uvec3& tri = mesh.triangles[t];
    for (int c = 0; c < 3; ++c)
      if (tri[c] >= mesh.vertices.size())
        HYB_THROW(ValueError, "mesh: triangle ", t, " refers to vertex ", tri[c], " but the mesh has ", mesh.vertices.size(), " vertices");
  }
}

// Sentences for a mesh that cannot give a useful coverage: outside the grid, or smaller than a voxel.
void meshExtentWarnings(const glm::dvec3& lo, const glm::dvec3& hi, const VoxelGrid& grid, double reach, std::vector<std::string>* warnings) {
  const glm::dvec3 gridLo = -0.5 * grid.spacing - reach, gridHi = glm::dvec3(grid.dims - 1) * grid.spacing + 0.5 * grid.spacing + reach;
  auto box = [](const glm::dvec3& a, const glm::dvec3& b) {
    return detail::concat("[", a.x, ", ", b.x, "] × [", a.y, ", ", b.y, "] × [", a.z, ", ", b.z, "] mm");
  };
  if (glm::any(glm::lessThan(hi, gridLo)) || glm::any(glm::greaterThan(lo, gridHi)))
    warnings->push_back("mesh lies wholly outside the grid: it spans " + box(lo, hi) + " of the grid frame, the grid " + box(gridLo, gridHi));
  const glm::dvec3 extent = (hi - lo) / grid.spacing;
  if (std::max({extent.x, extent.y, extent.z}) < 1.0)
    warnings->push_back(detail::concat("mesh is smaller than one voxel (", extent.x, " × ", extent.y, " × ", extent.z,
                                       " voxels): are its coordinates in the grid's units (mm) and space? Detail below the filter's width is not resolved"));
}

}  // namespace

double boxHalfSpaceFraction(const glm::dvec3& m, double t) { return sortedBoxFraction(sortedMagnitudes(m), t); }

ScanResult scanConvertMesh(const TriangleMesh& mesh, const VoxelGrid& grid, const ScanOptions& options) {
  validateMesh(mesh);
  checkOptions(options, false);
  checkGrid(grid);
  MeshScan scan{grid, options, nullptr, mesh.triangles.data(), {}, {}, options.thickness == 0.0, 0.0, nullptr};
  scan.reach = boxReach(grid, options) + 0.5 * options.thickness;

  // The vertices in the grid frame (the triangles' corners are read through their indices).
  const size_t n = mesh.triangles.size(), vertices = mesh.vertices.size();
  const std::shared_ptr<void> pointBuffer = hugePageBuffer(vertices * sizeof(glm::vec3));
  glm::vec3* points = static_cast<glm::vec3*>(pointBuffer.get());
  scan.points = points;
#pragma omp parallel for schedule(static)
  for (int64_t v = 0; v < int64_t(vertices); ++v) points[v] = glm::vec3(toGridPoint(glm::dvec3(mesh.vertices[size_t(v)]), options.space, grid));
  glm::dvec3 lo(std::numeric_limits<double>::max()), hi(-std::numeric_limits<double>::max());
  for (size_t v = 0; v < vertices; ++v) {
    lo = glm::min(lo, glm::dvec3(points[v]));
    hi = glm::max(hi, glm::dvec3(points[v]));
  }
  std::vector<std::string> warnings;
  if (options.extentWarnings) meshExtentWarnings(lo, hi, grid, scan.reach, &warnings);

  // Triangles to slabs: those whose z-extent, widened by the reach, meets a slab's planes and whose
  // y-extent meets the grid's rows (x does not matter: a crossing left of the grid flips parity).
  const int slabs = scan.slabCount();
  const glm::dvec3 s = grid.spacing;
  auto slabRange = [&](const Tri& tri, int* first, int* last) {
    const double zlo = std::min({tri.a.z, tri.b.z, tri.c.z}) - scan.reach, zhi = std::max({tri.a.z, tri.b.z, tri.c.z}) + scan.reach;
    const double ylo = std::min({tri.a.y, tri.b.y, tri.c.y}) - scan.reach, yhi = std::max({tri.a.y, tri.b.y, tri.c.y}) + scan.reach;
    const double k0 = std::max(0.0, std::ceil(zlo / s.z)), k1 = std::min(double(grid.dims.z - 1), std::floor(zhi / s.z));
    if (k1 < k0 || yhi < 0.0 || ylo > double(grid.dims.y - 1) * s.y) return false;
    *first = int(k0) / kSlabPlanes;
    *last = int(k1) / kSlabPlanes;
    return true;
  };
  scan.slabStart.assign(size_t(slabs) + 1, 0);
  for (uint32_t t = 0; t < uint32_t(n); ++t) {
    int first, last;
    if (slabRange(scan.tri(t), &first, &last))
      for (int sl = first; sl <= last; ++sl) ++scan.slabStart[size_t(sl) + 1];
  }
  for (int sl = 0; sl < slabs; ++sl) scan.slabStart[size_t(sl) + 1] += scan.slabStart[size_t(sl)];
  scan.slabTris.resize(scan.slabStart.back());
  {
    std::vector<uint32_t> next(scan.slabStart.begin(), scan.slabStart.end() - 1);
    for (uint32_t t = 0; t < uint32_t(n); ++t) {
      int first, last;
      if (slabRange(scan.tri(t), &first, &last))
        for (int sl = first; sl <= last; ++sl) scan.slabTris[next[size_t(sl)]++] = t;
    }
  }

  CoverageStore store(grid.dims, options.type);
  scan.store = &store;
  const bool band = scan.reach > 0.0;
  size_t oddRows = 0, bandVoxels = 0, bandInside = 0, fillInside = 0;
  VoxelNormals normals;
  ParallelFailure failure;
#pragma omp parallel reduction(+ : oddRows, bandVoxels, bandInside, fillInside)
  {
    SlabScratch scratch;
    failure.run([&] {
      if (band) {
        const size_t slabVoxels = size_t(grid.dims.x) * size_t(grid.dims.y) * size_t(std::min(kSlabPlanes, grid.dims.z));
        scratch.closest.assign(slabVoxels, {float(scan.reach * scan.reach), kNone});
        scratch.touchedBuffer = hugePageBuffer((slabVoxels + 1) * sizeof(uint32_t));
        scratch.touched = static_cast<uint32_t*>(scratch.touchedBuffer.get());
        scratch.candidates.allocate(std::max({grid.dims.x, grid.dims.y, kSlabPlanes}));  // (rows along z stay in the slab)
      }
    });
#pragma omp for schedule(dynamic, 1)
    for (int sl = 0; sl < slabs; ++sl)
      failure.run([&] {
        const int k0 = sl * kSlabPlanes, k1 = std::min(grid.dims.z, k0 + kSlabPlanes);
        const std::span<const uint32_t> list(scan.slabTris.data() + scan.slabStart[size_t(sl)], scan.slabStart[size_t(sl) + 1] - scan.slabStart[size_t(sl)]);
        const size_t planeSize = size_t(grid.dims.x) * size_t(grid.dims.y);
        store.fill(size_t(k0) * planeSize, size_t(k1 - k0) * planeSize, false);
        if (scan.solid) scan.fillSolid(k0, k1, list, &scratch, &fillInside, &oddRows);
        if (band) {
          scan.closestTriangles(k0, k1, list, &scratch);
          const auto [b, in] = scan.filterBand(k0, &scratch);
          bandVoxels += b;
          bandInside += in;
        }
      });
#pragma omp critical
    failure.run([&] {
      if (normals.empty()) normals = std::move(scratch.normals);
      else normals.insert(normals.end(), scratch.normals.begin(), scratch.normals.end());
    });
  }
  failure.rethrow();
  if (oddRows > 0)
    warnings.push_back(detail::concat("mesh is not closed: ", oddRows, " rows of voxels cross it an odd number of times (the solid is filled "
                                      "only between pairs of crossings; give a thickness to scan-convert it as a sheet)"));
  ScanResult result = makeResult(grid, std::move(store), std::move(warnings), bandVoxels, fillInside - bandInside);
  result.normals = std::move(normals);
  return result;
}

// ---- Analytic primitives ----

ScanResult scanConvertSphere(const glm::dvec3& center, double radius, const VoxelGrid& grid, const ScanOptions& options) {
  checkOptions(options, false);
  checkGrid(grid);
  if (!finite(center)) HYB_THROW(ValueError, "sphere: centre (", center.x, ", ", center.y, ", ", center.z, ") is not finite");
  if (!std::isfinite(radius) || radius <= 0.0) HYB_THROW(ValueError, "sphere: radius ", radius, " must be positive");
  if (options.space == ScanSpace::Index && !(grid.spacing.x == grid.spacing.y && grid.spacing.y == grid.spacing.z))
    HYB_THROW(ValueError, "sphere: a radius in voxels needs an isotropic grid (spacing ", grid.spacing.x, " × ", grid.spacing.y, " × ",
              grid.spacing.z, " mm); give the sphere in grid or patient space");
  const glm::dvec3 c = toGridPoint(center, options.space, grid);
  const double r = options.space == ScanSpace::Index ? radius * grid.spacing.x : radius;
  const double reach = boxReach(grid, options);
  const glm::dvec3 box = boxSides(grid, options);
  CoverageStore store(grid.dims, options.type);
  size_t band = 0, inside = 0;
  forEachVoxel(grid, &store, &band, &inside, [&](const glm::dvec3& p) {
    const double rho = glm::length(p - c);
    if (rho <= r - reach) return rho <= r ? 1.0 : 0.0;
    if (rho >= r + reach) return 0.0;
    const glm::dvec3 n = (p - c) / rho;
    // The sphere bends away from its tangent plane by |u⊥|²/(2ρ) at a tangential offset u⊥; the
    // box's mean |u⊥|² is Σ (side_i² / 12)(1 − n_i²).
    const glm::dvec3 sq = box * box * (glm::dvec3(1.0) - n * n) / 12.0;
    return boxHalfSpaceFraction(glm::abs(n) * box, (r - rho) - (sq.x + sq.y + sq.z) / (2.0 * rho));
  });
  std::vector<std::string> warnings;
  if (options.extentWarnings) meshExtentWarnings(c - r, c + r, grid, reach, &warnings);
  return makeResult(grid, std::move(store), std::move(warnings), band, inside);
}

namespace {
// The unit grid-frame normal and the grid-frame point of a plane given in @p options.space.
std::pair<glm::dvec3, glm::dvec3> gridPlane(const glm::dvec3& point, const glm::dvec3& normal, const VoxelGrid& grid, const ScanOptions& options,
                                            const char* what) {
  if (!finite(point)) HYB_THROW(ValueError, what, ": point (", point.x, ", ", point.y, ", ", point.z, ") is not finite");
  if (!finite(normal) || normal == glm::dvec3(0.0))
    HYB_THROW(ValueError, what, ": normal (", normal.x, ", ", normal.y, ", ", normal.z, ") must be finite and not zero");
  const glm::dvec3 n = toGridNormal(normal, options.space, grid);
  return {toGridPoint(point, options.space, grid), n / glm::length(n)};
}
}  // namespace

ScanResult scanConvertPlane(const glm::dvec3& point, const glm::dvec3& normal, const VoxelGrid& grid, const ScanOptions& options) {
  checkOptions(options, true);
  checkGrid(grid);
  const std::pair<glm::dvec3, glm::dvec3> plane = gridPlane(point, normal, grid, options, "plane");
  const glm::dvec3 q = plane.first, n = plane.second;  // (named locals: clang 14 captures no bindings)
  const double half = 0.5 * options.thickness, reach = half + boxReach(grid, options);
  const glm::dvec3 m = glm::abs(n) * boxSides(grid, options);
  CoverageStore store(grid.dims, options.type);
  size_t band = 0, inside = 0;
  forEachVoxel(grid, &store, &band, &inside, [&](const glm::dvec3& p) {
    const double dist = std::abs(glm::dot(n, p - q));
    if (dist >= reach) return 0.0;
    return options.filter == ScanFilter::None ? double(dist <= half) : sheetFraction(m, dist, half);
  });
  return makeResult(grid, std::move(store), {}, band, inside);
}

ScanResult scanConvertHalfSpace(const glm::dvec3& point, const glm::dvec3& normal, const VoxelGrid& grid, const ScanOptions& options) {
  checkOptions(options, false);
  checkGrid(grid);
  const std::pair<glm::dvec3, glm::dvec3> plane = gridPlane(point, normal, grid, options, "half-space");
  const glm::dvec3 q = plane.first, n = plane.second;  // (named locals: clang 14 captures no bindings)
  const glm::dvec3 m = glm::abs(n) * boxSides(grid, options);
  const bool none = options.filter == ScanFilter::None;
  CoverageStore store(grid.dims, options.type);
  size_t band = 0, inside = 0;
  forEachVoxel(grid, &store, &band, &inside, [&](const glm::dvec3& p) {
    const double t = -glm::dot(n, p - q);  // distance into the half-space
    return none ? double(t >= 0.0) : boxHalfSpaceFraction(m, t);
  });
  return makeResult(grid, std::move(store), {}, band, inside);
}

ScanResult scanConvertPolygon(std::span<const glm::dvec3> corners, const VoxelGrid& grid, const ScanOptions& options) {
  checkOptions(options, true);
  if (corners.size() < 3) HYB_THROW(ValueError, "polygon: ", corners.size(), " corners (expected at least 3)");
  for (size_t i = 0; i < corners.size(); ++i)
    if (!finite(corners[i])) HYB_THROW(ValueError, "polygon: corner ", i, " is not finite");
  // Newell's normal; every corner within 10⁻⁶ of the polygon's size of its plane, every fan
  // triangle turning the same way (the fan from corner 0 covers the polygon once).
  glm::dvec3 normal(0.0), centre(0.0);
  double size = 0.0;
  for (size_t i = 0; i < corners.size(); ++i) {
    const glm::dvec3 &a = corners[i], &b = corners[(i + 1) % corners.size()];
    normal += glm::dvec3((a.y - b.y) * (a.z + b.z), (a.z - b.z) * (a.x + b.x), (a.x - b.x) * (a.y + b.y));
    centre += a / double(corners.size());
    size = std::max(size, glm::length(b - a));
  }
  if (glm::length(normal) <= 1e-12 * size * size) HYB_THROW(ValueError, "polygon: its corners enclose no area");
  normal = glm::normalize(normal);
  TriangleMesh mesh;
  for (size_t i = 0; i < corners.size(); ++i) {
    if (std::abs(glm::dot(normal, corners[i] - centre)) > 1e-6 * size)
      HYB_THROW(ValueError, "polygon: corner ", i, " lies ", glm::dot(normal, corners[i] - centre), " off the plane of the others (expected coplanar corners)");
    if (i >= 2 && glm::dot(glm::cross(corners[i - 1] - corners[0], corners[i] - corners[0]), normal) < 0.0)
      HYB_THROW(ValueError, "polygon: corner ", i, " folds the fan from corner 0 (expected a convex polygon, or one star-shaped from its first corner)");
    mesh.vertices.emplace_back(corners[i]);
    if (i >= 2) mesh.triangles.emplace_back(0u, uint32_t(i - 1), uint32_t(i));
  }
  return scanConvertMesh(mesh, grid, options);
}

// ---- Test and bench meshes ----

TriangleMesh uvSphere(const glm::dvec3& center, double radius, int rings) {
  TriangleMesh m;
  const int segments = 2 * rings;
  for (int i = 0; i <= rings; ++i)
    for (int j = 0; j < segments; ++j) {
      const double th = std::numbers::pi * i / rings, ph = 2.0 * std::numbers::pi * j / segments;
      m.vertices.push_back(glm::vec3(center + radius * glm::dvec3(std::sin(th) * std::cos(ph), std::sin(th) * std::sin(ph), std::cos(th))));
    }
  auto at = [&](int i, int j) { return uint32_t(i * segments + (j % segments)); };
  for (int i = 0; i < rings; ++i)
    for (int j = 0; j < segments; ++j) {
      if (i > 0) m.triangles.push_back({at(i, j), at(i + 1, j), at(i, j + 1)});
      if (i + 1 < rings) m.triangles.push_back({at(i, j + 1), at(i + 1, j), at(i + 1, j + 1)});
    }
  return m;
}

TriangleMesh geodesicSphere(const glm::dvec3& center, double radius, int frequency) {
  if (frequency < 1 || frequency > 4096) HYB_THROW(ValueError, "geodesic sphere: frequency ", frequency, " must be 1 … 4096");
  if (!std::isfinite(radius) || radius <= 0.0) HYB_THROW(ValueError, "geodesic sphere: radius ", radius, " must be positive");
  const double g = std::numbers::phi;
  const glm::dvec3 ico[12] = {{-1, g, 0}, {1, g, 0}, {-1, -g, 0}, {1, -g, 0}, {0, -1, g}, {0, 1, g},
                              {0, -1, -g}, {0, 1, -g}, {g, 0, -1}, {g, 0, 1}, {-g, 0, -1}, {-g, 0, 1}};
  const int faces[20][3] = {{0, 11, 5}, {0, 5, 1}, {0, 1, 7}, {0, 7, 10}, {0, 10, 11}, {1, 5, 9}, {5, 11, 4}, {11, 10, 2}, {10, 7, 6}, {7, 1, 8},
                            {3, 9, 4}, {3, 4, 2}, {3, 2, 6}, {3, 6, 8}, {3, 8, 9}, {4, 9, 5}, {2, 4, 11}, {6, 2, 10}, {8, 6, 7}, {9, 8, 1}};
  const int f = frequency;
  TriangleMesh mesh;
  mesh.vertices.reserve(size_t(20) * size_t(f + 1) * size_t(f + 2) / 2);
  mesh.triangles.reserve(size_t(20) * size_t(f) * size_t(f));
  for (const auto& face : faces) {
    // Point (i, j) of the face: weights (f − i − j, i, j) on its corners, summed in the order of the
    // corners' indices so that a point of an edge two faces share comes out the same in both.
    auto point = [&](int i, int j) {
      std::pair<int, int> w[3] = {{face[0], f - i - j}, {face[1], i}, {face[2], j}};
      std::sort(std::begin(w), std::end(w));
      glm::dvec3 p(0.0);
      for (const auto& [corner, weight] : w) p += ico[corner] * double(weight);
      return glm::vec3(center + radius * glm::normalize(p));
    };
    const uint32_t base = uint32_t(mesh.vertices.size());
    auto index = [&](int i, int j) { return base + uint32_t(j * (f + 1) - j * (j - 1) / 2 + i); };  // row j holds f − j + 1 points
    for (int j = 0; j <= f; ++j)
      for (int i = 0; i + j <= f; ++i) mesh.vertices.push_back(point(i, j));
    for (int j = 0; j < f; ++j)
      for (int i = 0; i + j < f; ++i) {
        mesh.triangles.emplace_back(index(i, j), index(i + 1, j), index(i, j + 1));
        if (i + j + 1 < f) mesh.triangles.emplace_back(index(i + 1, j), index(i + 1, j + 1), index(i, j + 1));
      }
  }
  return mesh;
}

double enclosedVolume(const TriangleMesh& mesh) {
  double v = 0.0;
  for (const glm::uvec3& t : mesh.triangles)
    v += glm::dot(glm::dvec3(mesh.vertices[t.x]), glm::cross(glm::dvec3(mesh.vertices[t.y]), glm::dvec3(mesh.vertices[t.z])));
  return v / 6.0;
}

}  // namespace hyb
