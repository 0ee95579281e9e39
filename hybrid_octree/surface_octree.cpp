// Surface Octree: I. Boada, I. Navazo, "An Octree Isosurface Codification based on Discrete Planes",
// SCCG 2001, with the exact code and merge rule of DESIGN 3.2 (see surface_octree.h).
#include "hybrid_octree/surface_octree.h"

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <iterator>
#include <numeric>
#include <tuple>

#include "surface/dmc.h"
#include "surface/dmc_table.h"
#include "surface/flat_map.h"
#include "volume/error.h"

namespace hyb {

namespace {

using I64 = int64_t;
using V64 = glm::i64vec3;
constexpr int kFine = 12;  // fine units per doubled unit

// A plane n·X = d in doubled coordinates (n from the 13 orientations or an axis).
struct Plane {
  glm::ivec3 n;
  I64 d;
};

Plane toPlane(const GeoPlane& g) { return {orientationNormal(g.orientation), g.d}; }

I64 dot64(const glm::ivec3& n, const V64& p) { return I64(n.x) * p.x + I64(n.y) * p.y + I64(n.z) * p.z; }

// Sign of plane @p at the fine point p / scale.
int sideOf(const Plane& pl, const V64& p, I64 scale) {
  const I64 v = dot64(pl.n, p) - I64(kFine) * scale * pl.d;
  return (v > 0) - (v < 0);
}

// Exact intersection of three planes in fine coordinates; false when they do not meet in a point.
bool intersect3(const Plane& a, const Plane& b, const Plane& c, V64* out) {
  const glm::ivec3 bc = icross(b.n, c.n), ca = icross(c.n, a.n), ab = icross(a.n, b.n);
  const I64 det = idot(a.n, bc);
  if (det == 0) return false;
  // |det| <= 4 for the 13 orientations and the axes, so kFine / det is exact.
  static constexpr std::array<I64, 9> kScale{-kFine / 4, -kFine / 3, -kFine / 2, -kFine, 0, kFine, kFine / 2, kFine / 3, kFine / 4};
  HYB_CHECK(det >= -4 && det <= 4);
  const V64 num = V64(bc) * a.d + V64(ca) * b.d + V64(ab) * c.d;
  *out = num * kScale[size_t(det + 4)];
  return true;
}

I64 orient3(const V64& a, const V64& b, const V64& c, const V64& d) {
  const V64 u = b - a, v = c - a, w = d - a;
  return u.x * (v.y * w.z - v.z * w.y) - u.y * (v.x * w.z - v.z * w.x) + u.z * (v.x * w.y - v.y * w.x);
}

// Axis-aligned box [lo, hi] in doubled coordinates.
struct Box {
  glm::ivec3 lo, hi;
  std::array<Plane, 6> faces() const {
    std::array<Plane, 6> f;
    for (int a = 0; a < 3; ++a) {
      glm::ivec3 n(0);
      n[a] = 1;
      f[size_t(2 * a)] = {n, lo[a]};
      f[size_t(2 * a + 1)] = {n, hi[a]};
    }
    return f;
  }
  bool contains(const V64& p) const {
    for (int a = 0; a < 3; ++a)
      if (p[a] < I64(kFine) * lo[a] || p[a] > I64(kFine) * hi[a]) return false;
    return true;
  }
};

// For every sign vector σ over @p planes: does R_σ ∩ box have volume, and an interior point
// (sum of the set's vertices over their count).
struct Regions {
  uint32_t occurs = 0;
  std::array<V64, 32> sum{};
  std::array<I64, 32> count{};
};

Regions analyseRegions(const Plane* planes, int np, const Box& box) {
  // The vertices of the arrangement of the planes and the box's faces inside the box, one per
  // triple meeting in a point: box corners, planes on box edges, two planes on a face, three planes.
  struct Vertex {
    V64 p;
    uint32_t pos, neg;  // planes with the vertex strictly on the positive / negative side
  };
  std::array<Vertex, 8 + 12 * 5 + 6 * 10 + 10> vertices;
  size_t nv = 0;
  auto add = [&](const V64& p) {
    if (!box.contains(p)) return;
    Vertex v{p, 0, 0};
    for (int j = 0; j < np; ++j) {
      const int s = sideOf(planes[j], p, 1);
      if (s > 0) v.pos |= 1u << j;
      if (s < 0) v.neg |= 1u << j;
    }
    vertices[nv++] = v;
  };
  const V64 lo = V64(box.lo) * I64(kFine), hi = V64(box.hi) * I64(kFine);
  for (int c = 0; c < 8; ++c) add(V64(c & 1 ? hi.x : lo.x, c & 2 ? hi.y : lo.y, c & 4 ? hi.z : lo.z));
  for (int j = 0; j < np; ++j) {
    const glm::ivec3& n = planes[j].n;
    for (int a = 0; a < 3; ++a) {  // the edges along axis a: solve for p[a] (normal components are 0 or ±1)
      if (n[a] == 0) continue;
      const int b = (a + 1) % 3, c = (a + 2) % 3;
      for (int e = 0; e < 4; ++e) {
        V64 p;
        p[b] = e & 1 ? hi[b] : lo[b];
        p[c] = e & 2 ? hi[c] : lo[c];
        p[a] = (I64(kFine) * planes[j].d - n[b] * p[b] - n[c] * p[c]) * n[a];
        add(p);
      }
    }
  }
  const auto faces = box.faces();
  for (int i = 0; i < np; ++i)
    for (int j = i + 1; j < np; ++j) {
      V64 p;
      for (const Plane& f : faces)
        if (intersect3(planes[i], planes[j], f, &p)) add(p);
      for (int k = j + 1; k < np; ++k)
        if (intersect3(planes[i], planes[j], planes[k], &p)) add(p);
    }
  // The closed set P_σ (σ's closed half-spaces ∩ box) is the hull of the vertices it holds, so their
  // average c lies in its relative interior. P_σ has volume iff no constraint holds with equality on
  // all of it, i.e. iff c is strictly inside every half-space and the box.
  Regions r;
  for (size_t i = 0; i < nv; ++i) {  // add each vertex to every σ it is compatible with
    const uint32_t on = ((1u << np) - 1) & ~(vertices[i].pos | vertices[i].neg);  // planes through it
    for (uint32_t sub = on;; sub = (sub - 1) & on) {
      r.sum[vertices[i].pos | sub] += vertices[i].p;
      ++r.count[vertices[i].pos | sub];
      if (sub == 0) break;
    }
  }
  for (uint32_t sigma = 0; sigma < (1u << np); ++sigma) {
    const V64 sum = r.sum[sigma];
    const I64 m = r.count[sigma];
    if (m == 0) continue;
    bool solid = true;
    for (int j = 0; j < np && solid; ++j) solid = sideOf(planes[j], sum, m) != 0;
    for (int a = 0; a < 3 && solid; ++a) solid = sum[a] > I64(kFine) * m * box.lo[a] && sum[a] < I64(kFine) * m * box.hi[a];
    if (solid) r.occurs |= 1u << sigma;
  }
  return r;
}

// Canonical geometric planes of a DiscMC case (sorted, unique), local to the cell.
std::vector<GeoPlane> casePlanes(const dmc::Case& c) {
  std::vector<GeoPlane> g;
  for (const PlaneId& p : c.planes) g.push_back(GeoPlane{p.orientation, p.sign > 0 ? p.d : -p.d});
  std::sort(g.begin(), g.end());
  g.erase(std::unique(g.begin(), g.end()), g.end());
  return g;
}

// Membership of the fine point p / scale in the solid of a DiscMC case, by the parity of crossings
// of a segment to a corner with exact orientation tests (a corner whose segment is degenerate is
// skipped).
bool caseContains(const dmc::Case& c, int mask, const V64& p, I64 scale) {
  for (int corner = 0; corner < 8; ++corner) {
    const V64 q = V64(dmc::cornerPosition(corner)) * (I64(kFine) * scale);
    int crossings = 0;
    bool degenerate = false;
    for (const auto& t : c.triangles) {
      const V64 a = V64(dmc::edgeMidpoint(t[0])) * (I64(kFine) * scale), b = V64(dmc::edgeMidpoint(t[1])) * (I64(kFine) * scale),
                cc = V64(dmc::edgeMidpoint(t[2])) * (I64(kFine) * scale);
      const I64 sp = orient3(a, b, cc, p), sq = orient3(a, b, cc, q);
      if (sp == 0 || sq == 0) {
        degenerate = true;
        break;
      }
      if ((sp > 0) == (sq > 0)) continue;
      const I64 e1 = orient3(p, q, a, b), e2 = orient3(p, q, b, cc), e3 = orient3(p, q, cc, a);
      if (e1 == 0 || e2 == 0 || e3 == 0) {
        degenerate = true;
        break;
      }
      if ((e1 > 0) == (e2 > 0) && (e2 > 0) == (e3 > 0)) ++crossings;
    }
    if (degenerate) continue;
    return bool((mask >> corner) & 1) != bool(crossings & 1);
  }
  HYB_CHECK(false);  // some corner always gives a generic segment
  return false;
}

SurfaceNode computeLeafCode(int mask, bool alternative) {
  SurfaceNode node;
  const dmc::Case& c = alternative ? dmc::alternativeCaseTable()[size_t(mask)] : dmc::caseTable()[size_t(mask)];
  if (c.triangles.empty()) return node;
  const std::vector<GeoPlane> g = casePlanes(c);
  HYB_CHECK(g.size() <= node.planes.size());
  node.planeCount = uint8_t(g.size());
  std::array<Plane, 5> planes;
  for (size_t i = 0; i < g.size(); ++i) {
    node.planes[i] = g[i];
    planes[i] = toPlane(g[i]);
  }
  const Regions r = analyseRegions(planes.data(), int(g.size()), Box{glm::ivec3(0), glm::ivec3(2)});
  node.occurs = r.occurs;
  for (uint32_t sigma = 0; sigma < (1u << g.size()); ++sigma)
    if ((r.occurs >> sigma) & 1)
      if (caseContains(c, mask, r.sum[sigma], r.count[sigma])) node.inside |= 1u << sigma;
  return node;
}

const std::array<std::array<SurfaceNode, 2>, 256>& leafCodes() {
  static const auto table = [] {
    std::array<std::array<SurfaceNode, 2>, 256> t{};
    for (int m = 1; m < 255; ++m) {
      t[size_t(m)][0] = computeLeafCode(m, false);
      if (dmc::caseTable()[size_t(m)].hasFold()) t[size_t(m)][1] = computeLeafCode(m, true);
    }
    return t;
  }();
  return table;
}

Box nodeBox(const glm::ivec3& origin, int edge, const glm::ivec3& dims) {
  return Box{2 * origin, 2 * glm::min(origin + edge, glm::max(dims - 1, glm::ivec3(1)))};
}

// analyseRegions memoised on the box's size and the planes relative to its corner: flat and
// repetitive surfaces meet the same local configurations again and again. Points are returned in
// the box's own coordinates shifted back. The key is exact in 64 bits for boxes of up to 8 cells
// (the default merge limit); larger boxes are analysed uncached.
class RegionCache {
 public:
  /// The regions of a node, compactly: point k is the interior point of the k-th region in
  /// occurs, relative to the box's corner: add count · 12 · box.lo to its sum to get fine coordinates.
  struct Compact {
    uint32_t occurs = 0;
    const std::pair<V64, I64>* points = nullptr;
  };

  /// Regions of @p planes (at most K) in @p box; valid until the next call.
  Compact get(const GeoPlane* planes, size_t np, const Box& box) {
    HYB_DCHECK(np <= size_t(kMaxNodePlanes));
    const glm::ivec3 size = box.hi - box.lo;
    std::array<Plane, kMaxNodePlanes> local;
    // size: 5 bits an axis (≤ 16); a plane: orientation + 1 in 4 bits, local d + 64 in 7 (|d| ≤ 3 · 16).
    bool exact = glm::all(glm::lessThanEqual(size, glm::ivec3(16)));
    uint64_t key = uint64_t(size.x) | uint64_t(size.y) << 5 | uint64_t(size.z) << 10;
    for (size_t i = 0; i < np; ++i) {
      const glm::ivec3& n = orientationNormal(planes[i].orientation);
      local[i] = {n, planes[i].d - idot(n, box.lo)};
      exact = exact && local[i].d >= -64 && local[i].d < 64;
      key |= uint64_t((planes[i].orientation + 1) | (local[i].d + 64) << 4) << (15 + 11 * i);
    }
    if (exact)
      if (const uint32_t* found = mIndex.find(key)) return {mEntries[*found].occurs, mPoints.data() + mEntries[*found].first};
    if (mEntries.size() >= kMaxEntries) {
      mEntries.clear();
      mPoints.clear();
      mIndex = FlatMap(kMaxEntries);
    }
    if (exact) mIndex[key] = uint32_t(mEntries.size());
    const Regions r = analyseRegions(local.data(), int(np), Box{glm::ivec3(0), size});
    mEntries.push_back({r.occurs, uint32_t(mPoints.size())});
    for (uint32_t sigma = 0; sigma < 32; ++sigma)
      if ((r.occurs >> sigma) & 1) mPoints.emplace_back(r.sum[sigma], r.count[sigma]);
    return {r.occurs, mPoints.data() + mEntries.back().first};
  }

 private:
  static constexpr size_t kMaxEntries = 1 << 16;
  struct Entry {
    uint32_t occurs, first;  // regions, and the index of the first one's point in mPoints
  };
  std::vector<Entry> mEntries;
  std::vector<std::pair<V64, I64>> mPoints;
  FlatMap mIndex{4096};
};

// Morton code of a cell index.
uint64_t morton(const glm::ivec3& c) {
  auto spread = [](uint64_t v) {
    v &= 0x1fffff;  // 21 bits an axis
    v = (v | (v << 32)) & 0x1f00000000ffffULL;
    v = (v | (v << 16)) & 0x1f0000ff0000ffULL;
    v = (v | (v << 8)) & 0x100f00f00f00f00fULL;
    v = (v | (v << 4)) & 0x10c30c30c30c30c3ULL;
    v = (v | (v << 2)) & 0x1249249249249249ULL;
    return v;
  };
  return spread(uint64_t(c.x)) | spread(uint64_t(c.y)) << 1 | spread(uint64_t(c.z)) << 2;
}

// Merges the DiscMC cells of one volume-octree leaf bottom-up. A leaf is at least as large as the
// merge limit, so leaves are independent: each one's cells are put in Morton order and merged while
// they are in cache, and its nodes come out in Morton order after those of the leaves before it.
class BlockMerger {
 public:
  BlockMerger(const Volume& volume, float iso, int maxPlanes, int mergeEdge)
      : mVolume(volume), mIso(iso), mMaxPlanes(maxPlanes), mMergeEdge(mergeEdge), mCodes(leafCodes()) {}

  /// Appends the terminal nodes of the cells of @p block to @p out; returns the number of cells.
  size_t run(const VoxelBlock& block, std::vector<SurfaceNode>* out) {
    mCells.clear();
    appendSurfaceCells(mVolume, mIso, block, &mCells);
    if (mCells.empty()) return 0;
    sortCells(block);
    mLevel.resize(mCells.size());
    for (size_t i = 0; i < mOrder.size(); ++i) {
      const SurfaceCell& cell = mCells[mOrder[i].second];
      Entry& e = mLevel[i];
      e.code = mOrder[i].first;
      e.grey = false;
      e.node = mCodes[cell.mask][cell.alternative ? 1 : 0];
      e.node.origin = cell.cell;
      e.node.edge = 1;
      const glm::ivec3 shift = 2 * glm::ivec3(cell.cell);
      for (int p = 0; p < e.node.planeCount; ++p)
        e.node.planes[size_t(p)].d += idot(orientationNormal(e.node.planes[size_t(p)].orientation), shift);
    }
    mEmitted.clear();
    mEmittedOrder.clear();
    for (int edge = 1, level = 0; !mLevel.empty(); edge *= 2, ++level) {
      const int parentEdge = edge * 2;
      const int shift = 3 * (level + 1);  // Morton bits below the parent
      mNext.clear();
      for (size_t b = 0, e; b < mLevel.size(); b = e) {
        const uint64_t parent = mLevel[b].code >> shift;
        for (e = b + 1; e < mLevel.size() && mLevel[e].code >> shift == parent; ++e) {
        }
        mNext.push_back(merge(b, e, level, parentEdge <= mMergeEdge));
      }
      mLevel.swap(mNext);
      if (std::all_of(mLevel.begin(), mLevel.end(), [](const Entry& x) { return x.grey; })) break;
    }
    for (const Entry& e : mLevel)
      if (!e.grey) emit(e);
    std::sort(mEmittedOrder.begin(), mEmittedOrder.end());
    for (const auto& [key, i] : mEmittedOrder) out->push_back(mEmitted[i]);
    return mCells.size();
  }

 private:
  struct Entry {
    SurfaceNode node;
    uint64_t code = 0;  // Morton code of the node's origin
    bool grey = false;
  };

  // mOrder = indices of mCells in Morton order. The block's corner is aligned to its (power-of-two)
  // edge, so local Morton codes order the cells; blocks of up to 16³ cells are bucketed by them.
  void sortCells(const VoxelBlock& block) {
    mOrder.clear();
    if (glm::any(glm::greaterThan(block.hi - block.lo, glm::ivec3(16)))) {
      for (size_t i = 0; i < mCells.size(); ++i) mOrder.emplace_back(morton(glm::ivec3(mCells[i].cell)), uint32_t(i));
      std::sort(mOrder.begin(), mOrder.end());
      return;
    }
    const uint64_t base = morton(block.lo);
    for (size_t i = 0; i < mCells.size(); ++i) {
      const uint32_t code = uint32_t(morton(glm::ivec3(mCells[i].cell) - block.lo));
      HYB_DCHECK((base & code) == 0);  // the block's corner is aligned to its edge
      mSlot[code] = uint32_t(i);
      mOccupied[code >> 6] |= uint64_t(1) << (code & 63);
    }
    for (size_t w = 0; w < mOccupied.size(); ++w)
      for (; mOccupied[w]; mOccupied[w] &= mOccupied[w] - 1) {
        const size_t code = w * 64 + size_t(std::countr_zero(mOccupied[w]));
        mOrder.emplace_back(base | code, mSlot[code]);
      }
  }

  void emit(const Entry& e) {
    mEmittedOrder.emplace_back(e.code, uint32_t(mEmitted.size()));
    mEmitted.push_back(e.node);
  }

  // The parent of the Morton-contiguous children mLevel[b, e) at @p level (edge 2^level): merged
  // when allowed and their planes number at most K, else grey with its terminal children emitted.
  Entry merge(size_t b, size_t e, int level, bool mayMerge) {
    const int edge = 1 << level;
    const glm::ivec3 origin = glm::ivec3(mLevel[b].node.origin) & ~(2 * edge - 1);
    Entry parent;
    parent.code = mLevel[b].code & ~((uint64_t(1) << (3 * level + 3)) - 1);
    parent.grey = !mayMerge;
    std::array<GeoPlane, kMaxNodePlanes + 1> u;  // the union, sorted, stops growing past K
    size_t nu = 0;
    for (size_t i = b; i < e && !parent.grey; ++i) {
      parent.grey = mLevel[i].grey || mLevel[i].node.planeCount > kMaxNodePlanes;
      for (int j = 0; j < mLevel[i].node.planeCount && !parent.grey; ++j) {
        const GeoPlane& g = mLevel[i].node.planes[size_t(j)];
        const auto at = std::lower_bound(u.begin(), u.begin() + ptrdiff_t(nu), g);
        if (at != u.begin() + ptrdiff_t(nu) && *at == g) continue;
        if (int(nu) == mMaxPlanes) {
          parent.grey = true;
          break;
        }
        std::copy_backward(at, u.begin() + ptrdiff_t(nu), u.begin() + ptrdiff_t(nu) + 1);
        *at = g;
        ++nu;
      }
    }
    const int parentEdge = 2 * edge;
    parent.node.origin = glm::u16vec3(origin);
    parent.node.edge = uint16_t(parentEdge);
    if (parent.grey) {
      for (size_t i = b; i < e; ++i)
        if (!mLevel[i].grey) emit(mLevel[i]);
      return parent;
    }
    parent.node.planeCount = uint8_t(nu);
    std::copy(u.begin(), u.begin() + ptrdiff_t(nu), parent.node.planes.begin());
    // A child on all of the union's planes in which every sign vector has a region: the parent's
    // regions contain the child's, so they all occur too and share the child's truth values.
    const uint32_t all = (uint32_t(1) << (1u << nu)) - 1;  // nu ≤ K = 4
    for (size_t i = b; i < e; ++i)
      if (mLevel[i].node.planeCount == nu && mLevel[i].node.occurs == all) {
        parent.node.occurs = all;
        parent.node.inside = mLevel[i].node.inside;
        return parent;
      }
    const Box box = nodeBox(origin, parentEdge, mVolume.dims());
    const RegionCache::Compact r = mCache.get(u.data(), nu, box);
    const V64 corner = V64(box.lo) * I64(kFine);
    parent.node.occurs = r.occurs;
    // A uniform (absent) child is wholly inside or outside; every octant touches the parent's
    // centre sample, so one read classifies them all (octant origins where the centre lies
    // outside the grid).
    const glm::ivec3 centre = origin + edge;
    const bool centreInGrid = glm::all(glm::lessThan(centre, mVolume.dims()));
    const bool centreInside = centreInGrid && mVolume.at(centre.x, centre.y, centre.z) >= mIso;
    // Children by octant (slot bits x | y<<1 | z<<2), nullptr for uniform octants.
    std::array<const Entry*, 8> children{};
    for (size_t i = b; i < e; ++i) {
      children[size_t(mLevel[i].code >> (3 * level) & 7)] = &mLevel[i];
    }
    const glm::ivec3 mid = 2 * (origin + edge);
    for (uint32_t sigma = 0, k = 0; sigma < (1u << nu); ++sigma) {
      if (!((r.occurs >> sigma) & 1)) continue;
      const auto& [sum, m] = r.points[k++];
      const V64 p = sum + corner * m;
      // Octant of the interior point (either one where it lies on a mid-plane).
      glm::ivec3 childOrigin = origin;
      for (int a = 0; a < 3; ++a)
        if (p[a] >= I64(kFine) * m * mid[a]) childOrigin[a] += edge;
      bool inside = false;
      const glm::ivec3 rel = glm::ivec3(glm::notEqual(childOrigin, origin));
      const Entry* child = children[size_t(rel.x | rel.y << 1 | rel.z << 2)];
      if (child) {
        inside = nodeContains(child->node, p, m);
      } else if (centreInGrid) {
        inside = centreInside;
      } else {  // a uniform octant: the class of any of its samples
        const glm::ivec3 s = glm::min(childOrigin, mVolume.dims() - 1);
        inside = mVolume.at(s.x, s.y, s.z) >= mIso;
      }
      if (inside) parent.node.inside |= 1u << sigma;
    }
    return parent;
  }

  const Volume& mVolume;
  float mIso;
  int mMaxPlanes, mMergeEdge;
  const std::array<std::array<SurfaceNode, 2>, 256>& mCodes;
  RegionCache mCache;
  std::vector<SurfaceCell> mCells;
  std::vector<std::pair<uint64_t, uint32_t>> mOrder;  // Morton code, index in mCells
  std::array<uint64_t, 64> mOccupied{};  // local Morton codes of a block of up to 16³ cells
  std::array<uint32_t, 4096> mSlot;
  std::vector<Entry> mLevel, mNext;
  std::vector<SurfaceNode> mEmitted;
  std::vector<std::pair<uint64_t, uint32_t>> mEmittedOrder;  // Morton code, index in mEmitted
};

}  // namespace

SurfaceNode leafCode(int mask, bool alternative) { return leafCodes()[size_t(mask)][alternative ? 1 : 0]; }

bool nodeContains(const SurfaceNode& node, const glm::i64vec3& p, int64_t scale) {
  uint32_t sigma = 0;
  for (int j = 0; j < node.planeCount; ++j) {
    const int s = sideOf(toPlane(node.planes[size_t(j)]), p, scale);
    HYB_DCHECK(s != 0);
    if (s > 0) sigma |= 1u << j;
  }
  HYB_DCHECK((node.occurs >> sigma) & 1);
  return (node.inside >> sigma) & 1;
}

SurfaceOctree SurfaceOctree::build(const Volume& volume, const VolumeOctree& octree, float iso,
                                   const SurfaceOctreeOptions& options) {
  if (options.maxPlanes < 1 || options.maxPlanes > kMaxNodePlanes)
    HYB_THROW(ValueError, "maximum planes per node ", options.maxPlanes, " invalid (expected 1..", kMaxNodePlanes, ")");
  if (options.maxEdge < 0 || (options.maxEdge & (options.maxEdge - 1)))
    HYB_THROW(ValueError, "largest merged node edge ", options.maxEdge, " invalid (expected 0 or a power of two)");
  SurfaceOctree so;
  so.mDims = volume.dims();
  so.mIso = iso;
  so.mMergeEdge = options.maxEdge > 0 ? std::min(options.maxEdge, octree.leafEdge()) : octree.leafEdge();
  BlockMerger merger(volume, iso, options.maxPlanes, so.mMergeEdge);
  for (const VoxelBlock& block : isoBlocks(octree, iso)) so.mCellCount += merger.run(block, &so.mNodes);
  return so;
}

std::pair<uint32_t, uint32_t> SurfaceOctree::rangeIn(const glm::ivec3& origin, int edge) const {
  const uint64_t lo = morton(origin), hi = lo + uint64_t(edge) * uint64_t(edge) * uint64_t(edge);
  auto key = [](const SurfaceNode& n) { return morton(glm::ivec3(n.origin)); };
  const auto b = std::partition_point(mNodes.begin(), mNodes.end(), [&](const SurfaceNode& n) { return key(n) < lo; });
  const auto e = std::partition_point(b, mNodes.end(), [&](const SurfaceNode& n) { return key(n) < hi; });
  return {uint32_t(b - mNodes.begin()), uint32_t(e - mNodes.begin())};
}

SurfaceOctree SurfaceOctree::fromParts(glm::ivec3 dims, float iso, size_t cellCount, int mergeEdge,
                                       std::vector<SurfaceNode> nodes, const std::string& source) {
  validateDims(dims, source);
  if (mergeEdge < 1 || mergeEdge > kMaxDim || (mergeEdge & (mergeEdge - 1)))
    HYB_THROW(IoError, source, ": surface octree merge edge ", mergeEdge, " invalid (expected a power of two)");
  uint64_t previous = 0;
  for (size_t i = 0; i < nodes.size(); ++i) {
    const SurfaceNode& n = nodes[i];
    const glm::ivec3 o(n.origin);
    const bool ok = n.edge >= 1 && (n.edge & (n.edge - 1)) == 0 && o.x % n.edge == 0 && o.y % n.edge == 0 &&
                    o.z % n.edge == 0 && glm::all(glm::lessThan(o, glm::max(dims - 1, glm::ivec3(1)))) && n.planeCount >= 1 &&
                    n.planeCount <= n.planes.size() && (uint64_t(n.occurs) >> (1u << n.planeCount)) == 0 &&
                    (n.inside & ~n.occurs) == 0 && morton(o) >= previous && n.edge <= mergeEdge;
    bool planesOk = true;
    for (int j = 0; j < n.planeCount; ++j) planesOk &= n.planes[size_t(j)].orientation >= 0 && n.planes[size_t(j)].orientation < kOrientationCount;
    if (!ok || !planesOk || !std::isfinite(iso)) HYB_THROW(IoError, source, ": surface octree node ", i, " is invalid");
    previous = morton(o);
  }
  SurfaceOctree so;
  so.mDims = dims;
  so.mIso = iso;
  so.mCellCount = cellCount;
  so.mMergeEdge = mergeEdge;
  so.mNodes = std::move(nodes);
  return so;
}

// ---------------------------------------------------------------------------------------------
// Reconstruction

namespace {

// A convex polygon on one plane, vertices in fine coordinates, counter-clockwise around +normal.
using Poly = std::vector<V64>;

I64 evalFine(const Plane& pl, const V64& p) { return dot64(pl.n, p) - I64(kFine) * pl.d; }

// Splits convex @p poly by @p pl into its parts with eval ≥ 0 and ≤ 0 (exact: intersection points
// are arrangement vertices, integral in fine coordinates).
void split(const Poly& poly, const Plane& pl, Poly* pos, Poly* neg) {
  pos->clear();
  neg->clear();
  const size_t n = poly.size();
  for (size_t i = 0; i < n; ++i) {
    const V64& a = poly[i];
    const V64& b = poly[(i + 1) % n];
    const I64 ea = evalFine(pl, a), eb = evalFine(pl, b);
    if (ea >= 0) pos->push_back(a);
    if (ea <= 0) neg->push_back(a);
    if ((ea > 0 && eb < 0) || (ea < 0 && eb > 0)) {
      const V64 num = a * eb - b * ea;
      const I64 den = eb - ea;
      HYB_CHECK(num.x % den == 0 && num.y % den == 0 && num.z % den == 0);
      const V64 x = num / den;
      pos->push_back(x);
      neg->push_back(x);
    }
  }
}

// Plane ∩ box as a convex polygon counter-clockwise around the plane's normal.
Poly clipToBox(const Plane& pl, const Box& box) {
  // Start from the box's face polygon cut: intersect the plane with the 12 box edges.
  std::vector<V64> pts;
  const auto faces = box.faces();
  for (int a = 0; a < 6; ++a)
    for (int b = a + 1; b < 6; ++b) {
      if (a / 2 == b / 2) continue;  // parallel faces
      V64 p;
      if (!intersect3(pl, faces[size_t(a)], faces[size_t(b)], &p) || !box.contains(p)) continue;
      if (std::find(pts.begin(), pts.end(), p) == pts.end()) pts.push_back(p);
    }
  if (pts.size() < 3) return {};
  // Sort counter-clockwise around the normal: project, gift-wrap (points are in convex position).
  int axis = 0;
  for (int a = 1; a < 3; ++a)
    if (std::abs(pl.n[a]) > std::abs(pl.n[axis])) axis = a;
  const int u = (axis + 1) % 3, v = (axis + 2) % 3;
  const bool flip = pl.n[axis] < 0;
  auto cross2 = [&](const V64& o, const V64& p, const V64& q) {
    const I64 c = (p[u] - o[u]) * (q[v] - o[v]) - (p[v] - o[v]) * (q[u] - o[u]);
    return flip ? -c : c;
  };
  size_t start = 0;
  for (size_t i = 1; i < pts.size(); ++i)
    if (pts[i][u] < pts[start][u] || (pts[i][u] == pts[start][u] && pts[i][v] < pts[start][v])) start = i;
  Poly hull;
  size_t cur = start;
  do {
    hull.push_back(pts[cur]);
    size_t cand = (cur + 1) % pts.size();
    for (size_t i = 0; i < pts.size(); ++i) {
      if (i == cur) continue;
      const I64 c = cross2(pts[cur], pts[cand], pts[i]);
      if (c < 0) cand = i;  // i is more clockwise: wrap tighter
    }
    cur = cand;
  } while (cur != start && hull.size() <= pts.size());
  return hull;
}

bool lexLess(const V64& a, const V64& b) { return std::tie(a.x, a.y, a.z) < std::tie(b.x, b.y, b.z); }
}  // namespace

DiscreteMesh SurfaceOctree::reconstruct(int mergeCube, const Progress* progress) const {
  if (mergeCube <= 0) mergeCube = mMergeEdge;
  HYB_CHECK((mergeCube & (mergeCube - 1)) == 0);
  struct OutPoly {
    std::vector<V64> loop;
    PlaneId plane;  // d in fine units
    Box box;
    glm::u16vec3 origin;  // of the node
  };
  // A node's polygons depend on the node alone: nodes are processed in parallel, in contiguous
  // chunks whose polygons are concatenated in node order (the output does not depend on threads).
  auto polygonsOf = [&](const SurfaceNode& node, Poly& pos, Poly& neg, std::vector<OutPoly>& polys) {
    const Box box = nodeBox(glm::ivec3(node.origin), node.edge, mDims);
    const int np = node.planeCount;
    for (int i = 0; i < np; ++i) {
      const Plane pi = toPlane(node.planes[size_t(i)]);
      std::vector<Poly> pieces{clipToBox(pi, box)};
      if (pieces[0].size() < 3) continue;
      for (int j = 0; j < np; ++j) {
        if (j == i) continue;
        const Plane pj = toPlane(node.planes[size_t(j)]);
        std::vector<Poly> out;
        for (const Poly& p : pieces) {
          split(p, pj, &pos, &neg);
          if (pos.size() >= 3) out.push_back(pos);
          if (neg.size() >= 3) out.push_back(neg);
        }
        pieces.swap(out);
      }
      // Keep the pieces where the solid changes across plane i; group by facing.
      std::array<std::vector<Poly>, 2> kept;  // [0]: outward = +normal, [1]: outward = −normal
      for (Poly& p : pieces) {
        V64 c(0);
        for (const V64& x : p) c += x;
        const I64 m = I64(p.size());
        uint32_t sigma = 0;
        bool interior = true;
        for (int j = 0; j < np && interior; ++j) {
          if (j == i) continue;
          const int s = sideOf(toPlane(node.planes[size_t(j)]), c, m);
          interior = s != 0;
          if (s > 0) sigma |= 1u << j;
        }
        if (!interior) continue;  // a degenerate sliver
        const uint32_t sp = sigma | (1u << i), sn = sigma;
        if (!((node.occurs >> sp) & 1) || !((node.occurs >> sn) & 1)) continue;
        const uint32_t inPos = (node.inside >> sp) & 1u, inNeg = (node.inside >> sn) & 1u;
        if (inPos == inNeg) continue;
        if (inPos) std::reverse(p.begin(), p.end());  // outside on the negative side: face −normal
        kept[inPos].push_back(std::move(p));
      }
      for (int facing = 0; facing < 2; ++facing) {
        if (kept[size_t(facing)].empty()) continue;
        PlaneId id{node.planes[size_t(i)].orientation, int8_t(facing ? -1 : 1), 0};
        id.d = int32_t((facing ? -1 : 1) * I64(kFine) * pi.d);
        // Merge pieces sharing edges: cancel opposite directed edges, chain the rest. A vertex with
        // two outgoing edges (pieces touching at a point) or several loops (holes) keeps the pieces.
        // Few edges per group: small vectors with linear search beat node-based maps here.
        std::vector<std::pair<V64, V64>> edges;
        for (const Poly& p : kept[size_t(facing)])
          for (size_t k = 0; k < p.size(); ++k) {
            const V64 a = p[k], b = p[(k + 1) % p.size()];
            if (a == b) continue;
            const auto rev = std::find(edges.begin(), edges.end(), std::make_pair(b, a));
            if (rev != edges.end()) {
              *rev = edges.back();
              edges.pop_back();
            } else {
              edges.emplace_back(a, b);
            }
          }
        bool branching = false;
        for (size_t x = 0; x < edges.size() && !branching; ++x)
          for (size_t y = x + 1; y < edges.size() && !branching; ++y) branching = edges[x].first == edges[y].first;
        std::vector<Poly> loops;
        while (!branching && !edges.empty()) {
          Poly loop;
          V64 v = edges.back().first;
          for (auto it = edges.end() - 1;;) {
            loop.push_back(v);
            v = it->second;
            *it = edges.back();
            edges.pop_back();
            it = std::find_if(edges.begin(), edges.end(), [&](const auto& e) { return e.first == v; });
            if (it == edges.end()) break;
          }
          loops.push_back(std::move(loop));
        }
        const std::vector<Poly>& emit = (!branching && loops.size() == 1) ? loops : kept[size_t(facing)];
        for (const Poly& p : emit) polys.push_back({p, id, box, node.origin});
      }
    }
  };
  const size_t chunks = std::min<size_t>(mNodes.size(), 64), per = chunks ? (mNodes.size() + chunks - 1) / chunks : 0;
  // Progress: the nodes' chunks, then the three stages after them, a chunk's worth each.
  ProgressTask task(progress, "surface polygons", chunks + 3 * std::max<size_t>(1, chunks / 8));
  std::vector<std::vector<OutPoly>> parts(chunks);
#pragma omp parallel for schedule(dynamic)
  for (size_t c = 0; c < chunks; ++c) {
    Poly pos, neg;
    for (size_t k = c * per; k < std::min(mNodes.size(), (c + 1) * per); ++k) polygonsOf(mNodes[k], pos, neg, parts[c]);
    task.advance();
  }
  std::vector<OutPoly> polys;
  for (std::vector<OutPoly>& part : parts) std::move(part.begin(), part.end(), std::back_inserter(polys));

  task.advance(std::max<size_t>(1, chunks / 8));
  // T-junctions: vertices on the same line in a node face are inserted into every edge on that line.
  // A line is keyed exactly in 64 bits: the face's axis and coordinate, the reduced direction within
  // the face (components in {-1, 0, 1}: the line lies on one of the 13 planes and an axis plane) and
  // its offset.
  auto faceLine = [](const Box& box, const V64& a, const V64& b, uint64_t* key) {
    for (int axis = 0; axis < 3; ++axis)
      for (I64 c : {I64(kFine) * box.lo[axis], I64(kFine) * box.hi[axis]})
        if (a[axis] == c && b[axis] == c) {
          const int u = (axis + 1) % 3, v = (axis + 2) % 3;
          I64 du = b[u] - a[u], dv = b[v] - a[v];
          const I64 g = std::gcd(std::llabs(du), std::llabs(dv));
          du /= g;
          dv /= g;
          if (du < 0 || (du == 0 && dv < 0)) du = -du, dv = -dv;
          HYB_DCHECK(std::llabs(du) <= 1 && std::llabs(dv) <= 1);
          const I64 offset = dv * a[u] - du * a[v];  // fine coordinates are < 2^21, so |offset| < 2^22
          *key = uint64_t(axis) | uint64_t(c) << 2 | uint64_t(du + 1) << 23 | uint64_t(dv + 1) << 25 |
                 uint64_t(offset + (I64(1) << 23)) << 27;
          return true;
        }
    return false;
  };
  // The points of every line, sorted by line and then lexicographically (their order along it).
  std::vector<std::pair<uint64_t, V64>> linePoints;
  for (const OutPoly& p : polys)
    for (size_t k = 0; k < p.loop.size(); ++k) {
      uint64_t key;
      const V64 &a = p.loop[k], &b = p.loop[(k + 1) % p.loop.size()];
      if (faceLine(p.box, a, b, &key)) {
        linePoints.emplace_back(key, a);
        linePoints.emplace_back(key, b);
      }
    }
  std::sort(linePoints.begin(), linePoints.end(), [](const auto& x, const auto& y) {
    return x.first != y.first ? x.first < y.first : lexLess(x.second, y.second);
  });
  linePoints.erase(std::unique(linePoints.begin(), linePoints.end()), linePoints.end());
  FlatMap lineStart(linePoints.size() / 2);
  for (size_t k = linePoints.size(); k-- > 0;) lineStart[linePoints[k].first] = uint32_t(k);

  DiscreteMesh mesh;
  FlatMap ids(polys.size() * 2);
  auto vertexId = [&](const V64& p) {
    const uint64_t key = gridKey(glm::ivec3(p));
    const uint32_t id = ids.findOrInsert(key, [&] {
      mesh.vertices.push_back(glm::ivec3(p));
      return uint32_t(mesh.vertices.size() - 1);
    });
    HYB_DCHECK(V64(mesh.vertices[id]) == p);
    return id;
  };
  std::vector<std::vector<uint32_t>> loops(polys.size());
  for (size_t pi = 0; pi < polys.size(); ++pi) {
    const OutPoly& p = polys[pi];
    std::vector<uint32_t>& loop = loops[pi];
    for (size_t k = 0; k < p.loop.size(); ++k) {
      const V64 &a = p.loop[k], &b = p.loop[(k + 1) % p.loop.size()];
      loop.push_back(vertexId(a));
      uint64_t key;
      if (!faceLine(p.box, a, b, &key)) continue;
      // Insert the line's vertices strictly between a and b, in order from a to b.
      const bool forward = lexLess(a, b);
      const V64& lo = forward ? a : b;
      const V64& hi = forward ? b : a;
      auto first = linePoints.begin() + *lineStart.find(key);
      while (lexLess(first->second, lo) || first->second == lo) ++first;  // lo and hi are on the line
      auto last = first;
      while (lexLess(last->second, hi)) ++last;
      if (forward) {
        for (auto it = first; it != last; ++it) loop.push_back(vertexId(it->second));
      } else {
        for (auto it = last; it != first;) loop.push_back(vertexId((--it)->second));
      }
    }
  }
  task.advance(std::max<size_t>(1, chunks / 8));
  // Merge polygons of different nodes that lie on the same plane with the same facing and share an
  // edge, within one merge cube of edge @p mergeCube cells (a volume leaf by default, so that every
  // polygon stays inside one brick): union-find over shared edges, then the union's boundary replaces
  // them when it is a single loop (the surface is unchanged).
  {
    std::vector<uint32_t> parent(polys.size());
    std::iota(parent.begin(), parent.end(), 0u);
    auto find = [&](uint32_t x) {
      while (parent[x] != x) x = parent[x] = parent[parent[x]];
      return x;
    };
    auto cellOf = [&](size_t pi) { return gridKey(glm::ivec3(polys[pi].origin) / mergeCube); };
    auto edgeKey = [](uint32_t from, uint32_t to) { return uint64_t(from) << 32 | to; };
    FlatMap owner(polys.size() * 4);
    for (size_t pi = 0; pi < polys.size(); ++pi)
      for (size_t k = 0; k < loops[pi].size(); ++k) owner[edgeKey(loops[pi][k], loops[pi][(k + 1) % loops[pi].size()])] = uint32_t(pi);
    for (size_t pi = 0; pi < polys.size(); ++pi)
      for (size_t k = 0; k < loops[pi].size(); ++k) {
        const uint32_t* q = owner.find(edgeKey(loops[pi][(k + 1) % loops[pi].size()], loops[pi][k]));
        if (!q || *q == pi) continue;
        if (polys[*q].plane == polys[pi].plane && cellOf(*q) == cellOf(pi)) parent[find(uint32_t(pi))] = find(*q);
      }
    // The sets, as runs of (root, polygon) pairs; each set's boundary from its sorted directed edges.
    std::vector<std::pair<uint32_t, uint32_t>> bySet(polys.size());
    for (uint32_t pi = 0; pi < polys.size(); ++pi) bySet[pi] = {find(pi), pi};
    std::sort(bySet.begin(), bySet.end());
    std::vector<uint64_t> edges, boundary;
    std::vector<uint8_t> used;
    for (size_t b = 0, e; b < bySet.size(); b = e) {
      for (e = b + 1; e < bySet.size() && bySet[e].first == bySet[b].first; ++e) {
      }
      if (e - b < 2) continue;
      const uint32_t root = bySet[b].first;
      edges.clear();
      for (size_t m = b; m < e; ++m) {
        const std::vector<uint32_t>& loop = loops[bySet[m].second];
        for (size_t k = 0; k < loop.size(); ++k) edges.push_back(edgeKey(loop[k], loop[(k + 1) % loop.size()]));
      }
      std::sort(edges.begin(), edges.end());
      edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
      // Boundary: directed edges whose reverse is not in the set; sorted by their first vertex.
      boundary.clear();
      for (uint64_t x : edges)
        if (!std::binary_search(edges.begin(), edges.end(), edgeKey(uint32_t(x), uint32_t(x >> 32)))) boundary.push_back(x);
      bool branching = boundary.empty();
      for (size_t k = 1; k < boundary.size() && !branching; ++k) branching = boundary[k] >> 32 == boundary[k - 1] >> 32;
      if (branching) continue;
      // Walk the boundary from its first edge; a single loop replaces the members.
      std::vector<uint32_t> merged;
      used.assign(boundary.size(), 0);
      uint32_t v = uint32_t(boundary[0] >> 32);
      for (;;) {
        const auto it = std::lower_bound(boundary.begin(), boundary.end(), uint64_t(v) << 32);
        if (it == boundary.end() || uint32_t(*it >> 32) != v || used[size_t(it - boundary.begin())]) break;
        used[size_t(it - boundary.begin())] = 1;
        merged.push_back(v);
        v = uint32_t(*it);
      }
      if (merged.size() != boundary.size()) continue;  // several loops (a hole): keep the members
      loops[root] = std::move(merged);
      for (size_t m = b; m < e; ++m)
        if (bySet[m].second != root) loops[bySet[m].second].clear();
    }
  }

  task.advance(std::max<size_t>(1, chunks / 8));
  // Drop straight-through vertices that no other polygon uses: they only add triangles. A vertex
  // another polygon references is kept, so no T-junction can open.
  std::vector<uint32_t> uses(mesh.vertices.size(), 0);
  for (const auto& loop : loops)
    for (uint32_t v : loop) ++uses[v];
  for (size_t pi = 0; pi < polys.size(); ++pi) {
    std::vector<uint32_t>& loop = loops[pi];
    if (loop.empty()) continue;  // merged into another polygon
    for (bool removed = true; removed && loop.size() > 3;) {
      removed = false;
      for (size_t k = 0; k < loop.size() && loop.size() > 3; ++k) {
        const uint32_t prev = loop[(k + loop.size() - 1) % loop.size()], cur = loop[k], next = loop[(k + 1) % loop.size()];
        if (uses[cur] != 1) continue;
        const V64 u = V64(mesh.vertices[cur]) - V64(mesh.vertices[prev]), w = V64(mesh.vertices[next]) - V64(mesh.vertices[cur]);
        const V64 x(u.y * w.z - u.z * w.y, u.z * w.x - u.x * w.z, u.x * w.y - u.y * w.x);
        if (x != V64(0) || u.x * w.x + u.y * w.y + u.z * w.z <= 0) continue;  // a corner, or a spike
        loop.erase(loop.begin() + ptrdiff_t(k));
        uses[cur] = 0;
        removed = true;
      }
    }
    mesh.addFace(loop.data(), loop.size(), polys[pi].plane);
  }
  return mesh;
}

TriangleMesh fineMeshToTriangles(const DiscreteMesh& mesh, const glm::dvec3& spacing) {
  return toTriangleMesh(mesh, spacing, 2.0 * kFine);
}

}  // namespace hyb
