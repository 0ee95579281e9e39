// Surface Octree, the build: I. Boada, I. Navazo, "An Octree Isosurface Codification based on
// Discrete Planes", SCCG 2001, with an exact node code and merge rule (surface_octree.h, docs/surface.md):
// DiscMC leaf codes, merged bottom-up without loss. The reconstruction is surface_octree_reconstruct.cpp.
#include "hybrid_octree/surface_octree.h"

#include "hybrid_octree/discrete_geometry.h"

#include <algorithm>
#include <array>
#include <bit>
#include <functional>
#include <span>
#include <cmath>
#include <cstring>
#include <iterator>
#include <numeric>
#include <tuple>

#include "hybrid_octree/knot_source.h"
#include "hybrid_octree/knot_store.h"
#include "surface/dmc.h"
#include "surface/dmc_table.h"
#include "surface/flat_map.h"
#include "volume/core/error.h"
#include "volume/core/parallel.h"
#include "volume/core/progress.h"
#include "volume/plane_source.h"
#include "volume/sample_window.h"

namespace hyb {

namespace {

using namespace detail;  // fine-coordinate geometry

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

// Merges the DiscMC cells of one volume-octree leaf bottom-up. A leaf is at least as large as the
// merge limit, so leaves are independent: each one's cells are put in Morton order and merged while
// they are in cache, and its nodes come out in Morton order after those of the leaves before it.
class BlockMerger {
 public:
  BlockMerger(float iso, int maxPlanes, int mergeEdge) : mIso(iso), mMaxPlanes(maxPlanes), mMergeEdge(mergeEdge), mCodes(leafCodes()) {}

  /// Appends the terminal nodes of the cells of @p block to @p out, reading @p samples (at least
  /// SampleBox::around(block)); returns the number of cells.
  size_t run(const VoxelBlock& block, const SampleBox& samples, std::vector<SurfaceNode>* out) {
    mSamples = &samples;
    mCells.clear();
    appendSurfaceCells(samples, mIso, block, &mCells);
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
    const Box box = nodeBox(origin, parentEdge, mSamples->dims());
    const RegionCache::Compact r = mCache.get(u.data(), nu, box);
    const V64 corner = V64(box.lo) * I64(kFine);
    parent.node.occurs = r.occurs;
    // A uniform (absent) child is wholly inside or outside; every octant touches the parent's
    // centre sample, so one read classifies them all (octant origins where the centre lies
    // outside the grid).
    const glm::ivec3 centre = origin + edge;
    const bool centreInGrid = glm::all(glm::lessThan(centre, mSamples->dims()));
    const bool centreInside = centreInGrid && mSamples->at(centre.x, centre.y, centre.z) >= mIso;
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
        const glm::ivec3 s = glm::min(childOrigin, mSamples->dims() - 1);
        inside = mSamples->at(s.x, s.y, s.z) >= mIso;
      }
      if (inside) parent.node.inside |= 1u << sigma;
    }
    return parent;
  }

  const SampleBox* mSamples = nullptr;
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

namespace {

// Reads the samples of a box (SampleBox::around a block) into it; called from several threads at once.
using ReadBox = std::function<void(SampleBox*)>;

// What a merge of leaves needs of the octree being built: the grid, the isovalue, the planes a node
// may hold and the largest merged node's edge.
struct MergeRule {
  glm::ivec3 dims;
  float iso;
  int maxPlanes;
  int mergeEdge;
};

// Merges @p blocks (volume-octree leaves) by @p rule on all cores, block i's nodes into (*nodes)[i];
// returns the cells extracted. Consecutive leaves in one aligned cube of kStoreBlock voxels (Morton
// order keeps them together) are read as one box: a paged store reads each of its blocks about once.
size_t mergeBlocks(std::span<const VoxelBlock> blocks, const MergeRule& rule, const ReadBox& read, std::vector<std::vector<SurfaceNode>>* nodes,
                   ProgressTask* progress) {
  std::vector<size_t> runs;  // where each run of leaves starts, and the end
  for (size_t i = 0; i < blocks.size(); ++i)
    if (i == 0 || blocks[i].lo / kStoreBlock != blocks[i - 1].lo / kStoreBlock) runs.push_back(i);
  runs.push_back(blocks.size());
  size_t cells = 0;
  ParallelFailure failure;
#pragma omp parallel reduction(+ : cells) if (runs.size() > 2)
  {
    BlockMerger merger(rule.iso, rule.maxPlanes, rule.mergeEdge);
#pragma omp for schedule(dynamic)
    for (size_t r = 0; r < runs.size() - 1; ++r)
      failure.run([&] {
        VoxelBlock all = blocks[runs[r]];
        for (size_t i = runs[r]; i < runs[r + 1]; ++i) {
          all.lo = glm::min(all.lo, blocks[i].lo);
          all.hi = glm::max(all.hi, blocks[i].hi);
        }
        SampleBox box = SampleBox::around(all, rule.dims);
        read(&box);
        for (size_t i = runs[r]; i < runs[r + 1]; ++i) cells += merger.run(blocks[i], box, &(*nodes)[i]);
        progress->advance(runs[r + 1] - runs[r]);
      });
  }
  failure.rethrow();
  return cells;
}

void checkOptions(const SurfaceOctreeOptions& options) {
  if (options.maxPlanes < 1 || options.maxPlanes > kMaxNodePlanes)
    HYB_THROW(ValueError, "maximum planes per node ", options.maxPlanes, " invalid (expected 1..", kMaxNodePlanes, ")");
  if (options.maxEdge < 0 || (options.maxEdge & (options.maxEdge - 1)))
    HYB_THROW(ValueError, "largest merged node edge ", options.maxEdge, " invalid (expected 0 or a power of two)");
}

}  // namespace

SurfaceOctree SurfaceOctree::empty(const glm::ivec3& dims, const VolumeOctree& octree, float iso, const SurfaceOctreeOptions& options) {
  checkOptions(options);
  SurfaceOctree so;
  so.mDims = dims;
  so.mIso = iso;
  so.mMergeEdge = options.maxEdge > 0 ? std::min(options.maxEdge, octree.leafEdge()) : octree.leafEdge();
  return so;
}

SurfaceOctree SurfaceOctree::build(const KnotSource& knots, const VolumeOctree& octree, float iso, const SurfaceOctreeOptions& options) {
  SurfaceOctree so = empty(knots.dims(), octree, iso, options);
  const std::vector<VoxelBlock> blocks = isoBlocks(octree, iso);
  std::vector<std::vector<SurfaceNode>> nodes(blocks.size());
  ProgressTask progress(options.progress, "surface octree", blocks.size());
  so.mCellCount = mergeBlocks(blocks, {so.mDims, iso, options.maxPlanes, so.mMergeEdge},
                              [&](SampleBox* b) { knots.read(1, b->lo, b->count, b->values.data(), nullptr); }, &nodes, &progress);
  so.gather(std::move(nodes));
  return so;
}

SurfaceOctree SurfaceOctree::build(const Volume& volume, const VolumeOctree& octree, float iso, const SurfaceOctreeOptions& options) {
  return build(VolumeKnots(volume, octree), octree, iso, options);
}

namespace {

// The slabs of a streamed build: the leaves @p blocks (in Morton order) a slab at a time (their
// Morton order visits slabs back and forth), each reading the planes from one below its own to
// its top, leafEdge + 2 of them at most; @p done(indices, nodes) hears of each slab's leaves (their
// indices in @p blocks, ascending) and their nodes. Returns the cells extracted.
using SlabDone = std::function<void(std::span<const uint32_t>, std::vector<std::vector<SurfaceNode>>&)>;
size_t mergeSlabs(PlaneSource& planes, std::span<const VoxelBlock> blocks, const MergeRule& rule, const Progress* progressTo, const SlabDone& done) {
  std::vector<uint32_t> bySlab(blocks.size());
  std::iota(bySlab.begin(), bySlab.end(), 0u);
  std::stable_sort(bySlab.begin(), bySlab.end(), [&](uint32_t a, uint32_t b) { return blocks[a].lo.z < blocks[b].lo.z; });
  std::vector<VoxelBlock> slab;
  std::vector<std::vector<SurfaceNode>> slabNodes;
  int height = 0;
  for (const VoxelBlock& b : blocks) height = std::max(height, b.hi.z - b.lo.z);
  SampleWindow window(planes, height + 2);
  planes.rewind();
  ProgressTask progress(progressTo, "surface octree", blocks.size());
  size_t cells = 0;
  for (size_t b = 0, e; b < bySlab.size(); b = e) {
    const int z = blocks[bySlab[b]].lo.z;
    for (e = b; e < bySlab.size() && blocks[bySlab[e]].lo.z == z; ++e) {}
    slab.clear();
    for (size_t i = b; i < e; ++i) slab.push_back(blocks[bySlab[i]]);
    const int top = std::max_element(slab.begin(), slab.end(), [](const VoxelBlock& p, const VoxelBlock& q) { return p.hi.z < q.hi.z; })->hi.z;
    while (window.next() <= top) window.load(planes);
    slabNodes.assign(slab.size(), {});
    cells += mergeBlocks(slab, rule, [&](SampleBox* box) {
      float* out = box->values.data();
      for (int k = 0; k < box->count.z; ++k)
        for (int j = 0; j < box->count.y; ++j, out += box->count.x) window.readRow(box->lo.x, box->lo.y + j, box->lo.z + k, box->count.x, out);
    }, &slabNodes, &progress);
    done(std::span<const uint32_t>(bySlab).subspan(b, e - b), slabNodes);
  }
  return cells;
}

// Nodes encoded a batch at a time: 64 Ki nodes, 2.75 MB.
constexpr size_t kEncodeBatch = size_t(1) << 16;

}  // namespace

SurfaceOctree SurfaceOctree::build(PlaneSource& planes, const VolumeOctree& octree, float iso, const SurfaceOctreeOptions& options) {
  SurfaceOctree so = empty(planes.dims(), octree, iso, options);
  const std::vector<VoxelBlock> blocks = isoBlocks(octree, iso);
  std::vector<std::vector<SurfaceNode>> nodes(blocks.size());
  so.mCellCount = mergeSlabs(planes, blocks, {so.mDims, iso, options.maxPlanes, so.mMergeEdge}, options.progress,
                             [&](std::span<const uint32_t> indices, std::vector<std::vector<SurfaceNode>>& slabNodes) {
                               for (size_t i = 0; i < indices.size(); ++i) nodes[indices[i]] = std::move(slabNodes[i]);
                             });
  so.gather(std::move(nodes));
  return so;
}

SpooledSurfaceOctree::SpooledSurfaceOctree() = default;
SpooledSurfaceOctree::SpooledSurfaceOctree(SpooledSurfaceOctree&&) noexcept = default;
SpooledSurfaceOctree& SpooledSurfaceOctree::operator=(SpooledSurfaceOctree&&) noexcept = default;
SpooledSurfaceOctree::~SpooledSurfaceOctree() = default;

SpooledSurfaceOctree SpooledSurfaceOctree::build(PlaneSource& planes, const VolumeOctree& octree, float iso, const std::string& spoolDir,
                                                 const SurfaceOctreeOptions& options) {
  SpooledSurfaceOctree so;
  so.mHead = SurfaceOctree::empty(planes.dims(), octree, iso, options);
  so.mSpool = std::make_unique<detail::SpoolFile>(spoolDir, "surface octree");
  const std::vector<VoxelBlock> blocks = isoBlocks(octree, iso);
  so.mLeaves.resize(blocks.size());
  std::vector<uint8_t> bytes;
  so.mHead.mCellCount = mergeSlabs(planes, blocks, {so.dims(), iso, options.maxPlanes, so.mergeEdge()}, options.progress,
                                   [&](std::span<const uint32_t> indices, std::vector<std::vector<SurfaceNode>>& slabNodes) {
                                     size_t count = 0;
                                     for (const auto& n : slabNodes) count += n.size();
                                     bytes.resize(count * kSurfaceNodeBytes);
                                     uint8_t* at = bytes.data();
                                     for (size_t i = 0; i < indices.size(); ++i) {
                                       so.mLeaves[indices[i]] = Leaf{so.mNodeCount, uint32_t(slabNodes[i].size())};
                                       so.mNodeCount += slabNodes[i].size();
                                       for (const SurfaceNode& n : slabNodes[i]) {
                                         encodeSurfaceNode(n, at);
                                         at += kSurfaceNodeBytes;
                                         so.mPlaneIds += n.planeCount;
                                       }
                                     }
                                     so.mSpool->append(bytes.data(), bytes.size());
                                   });
  return so;
}

void SpooledSurfaceOctree::encodeNodes(const SurfaceNodeSink& sink) const {
  // Runs of leaves whose nodes lie together in the spool are read as one, a batch at a time.
  std::vector<uint8_t> bytes;
  for (size_t i = 0; i < mLeaves.size();) {
    const uint64_t first = mLeaves[i].first;
    uint64_t end = first;
    for (; i < mLeaves.size() && mLeaves[i].first == end && end - first < kEncodeBatch; ++i) end += mLeaves[i].count;
    if (end == first) continue;
    bytes.resize(size_t(end - first) * kSurfaceNodeBytes);
    mSpool->read(first * kSurfaceNodeBytes, bytes.size(), bytes.data());
    sink(bytes);
  }
}

SurfaceOctree SpooledSurfaceOctree::load() const {
  SurfaceOctree so = mHead;
  so.mNodes.reserve(mNodeCount);
  encodeNodes([&](std::span<const uint8_t> bytes) {
    for (size_t at = 0; at < bytes.size(); at += kSurfaceNodeBytes) so.mNodes.push_back(decodeSurfaceNode(bytes.data() + at));
  });
  return so;
}

void SurfaceOctree::encodeNodes(const SurfaceNodeSink& sink) const {
  std::vector<uint8_t> bytes;
  const size_t count = nodeCount();
  for (size_t b = 0; b < count; b += kEncodeBatch) {
    const size_t e = std::min(count, b + kEncodeBatch);
    if (mapped()) {  // already encoded: the mapping's bytes, its pages given back a batch at a time
      sink({mEncoded + b * kSurfaceNodeBytes, (e - b) * kSurfaceNodeBytes});
      releasePages();
      continue;
    }
    bytes.resize((e - b) * kSurfaceNodeBytes);
    for (size_t i = b; i < e; ++i) encodeSurfaceNode(mNodes[i], bytes.data() + (i - b) * kSurfaceNodeBytes);
    sink(bytes);
  }
}

void encodeSurfaceNode(const SurfaceNode& node, uint8_t* out) {
  auto put = [&out](const auto& v) {
    std::memcpy(out, &v, sizeof v);
    out += sizeof v;
  };
  put(node.origin);
  put(node.edge);
  put(node.planeCount);
  for (const GeoPlane& p : node.planes) {
    put(p.orientation);
    put(p.d);
  }
  put(node.inside);
  put(node.occurs);
}

SurfaceNode decodeSurfaceNode(const uint8_t* in) {
  SurfaceNode node;
  auto get = [&in](auto* v) {
    std::memcpy(v, in, sizeof *v);
    in += sizeof *v;
  };
  get(&node.origin);
  get(&node.edge);
  get(&node.planeCount);
  for (GeoPlane& p : node.planes) {
    get(&p.orientation);
    get(&p.d);
  }
  get(&node.inside);
  get(&node.occurs);
  return node;
}

void SurfaceOctree::gather(std::vector<std::vector<SurfaceNode>> perBlock) {
  size_t count = 0;
  for (const auto& n : perBlock) count += n.size();
  mNodes.reserve(count);
  for (auto& n : perBlock) {
    mNodes.insert(mNodes.end(), n.begin(), n.end());
    std::vector<SurfaceNode>().swap(n);
  }
}

std::pair<uint32_t, uint32_t> SurfaceOctree::rangeIn(const glm::ivec3& origin, int edge) const {
  const uint64_t lo = morton(origin), hi = lo + uint64_t(edge) * uint64_t(edge) * uint64_t(edge);
  // The first node at or past a Morton code: a binary search reading only the nodes' origins.
  auto firstAt = [&](size_t from, uint64_t code) {
    size_t count = nodeCount() - from;
    while (count > 0) {
      const size_t half = count / 2, mid = from + half;
      glm::u16vec3 o;
      if (mapped())
        std::memcpy(&o, mEncoded + mid * kSurfaceNodeBytes, sizeof o);  // (the origin leads a node's bytes)
      else
        o = mNodes[mid].origin;
      if (morton(glm::ivec3(o)) < code) {
        from = mid + 1;
        count -= half + 1;
      } else {
        count = half;
      }
    }
    return from;
  };
  const size_t b = firstAt(0, lo), e = firstAt(b, hi);
  return {uint32_t(b), uint32_t(e)};
}

std::vector<SurfaceRegion> SurfaceOctree::regions(size_t maxNodes) const {
  std::vector<SurfaceRegion> out;
  int root = mMergeEdge;
  while (root < mDims.x || root < mDims.y || root < mDims.z) root *= 2;
  const glm::ivec3 cells = glm::max(mDims - 1, glm::ivec3(1));
  // Depth first, children in Morton order: the regions' node ranges follow each other.
  std::function<void(const glm::ivec3&, int)> split = [&](const glm::ivec3& origin, int edge) {
    if (glm::any(glm::greaterThanEqual(origin, cells))) return;
    const auto [b, e] = rangeIn(origin, edge);
    if (b == e) return;
    if (e - b <= maxNodes || edge <= mMergeEdge) {
      out.push_back({origin, edge, b, e});
      return;
    }
    const int h = edge / 2;
    for (int c = 0; c < 8; ++c) split(origin + h * glm::ivec3(c & 1, (c >> 1) & 1, (c >> 2) & 1), h);
  };
  split(glm::ivec3(0), root);
  return out;
}

void SurfaceOctree::checkNode(const SurfaceNode& n, size_t i, const glm::ivec3& dims, int mergeEdge, uint64_t* previous,
                              const std::string& source) {
  const glm::ivec3 o(n.origin);
  const bool ok = n.edge >= 1 && (n.edge & (n.edge - 1)) == 0 && o.x % n.edge == 0 && o.y % n.edge == 0 && o.z % n.edge == 0 &&
                  glm::all(glm::lessThan(o, glm::max(dims - 1, glm::ivec3(1)))) && n.planeCount >= 1 && n.planeCount <= n.planes.size() &&
                  (uint64_t(n.occurs) >> (1u << n.planeCount)) == 0 && (n.inside & ~n.occurs) == 0 && morton(o) >= *previous &&
                  n.edge <= mergeEdge;
  bool planesOk = ok;  // (only a plane count within the array: a hostile one is past its end)
  for (int j = 0; planesOk && j < n.planeCount; ++j)
    planesOk = n.planes[size_t(j)].orientation >= 0 && n.planes[size_t(j)].orientation < kOrientationCount;
  if (!ok || !planesOk) HYB_THROW(IoError, source, ": surface octree node ", i, " is invalid");
  *previous = morton(o);
}

SurfaceOctree SurfaceOctree::withHead(glm::ivec3 dims, float iso, size_t cellCount, int mergeEdge, const std::string& source) {
  validateDims(dims, source);
  if (mergeEdge < 1 || mergeEdge > kMaxDim || (mergeEdge & (mergeEdge - 1)))
    HYB_THROW(IoError, source, ": surface octree merge edge ", mergeEdge, " invalid (expected a power of two)");
  if (!std::isfinite(iso)) HYB_THROW(IoError, source, ": surface octree isovalue ", iso, " is invalid");
  SurfaceOctree so;
  so.mDims = dims;
  so.mIso = iso;
  so.mCellCount = cellCount;
  so.mMergeEdge = mergeEdge;
  return so;
}

SurfaceOctree SurfaceOctree::fromParts(glm::ivec3 dims, float iso, size_t cellCount, int mergeEdge,
                                       std::vector<SurfaceNode> nodes, const std::string& source) {
  SurfaceOctree so = withHead(dims, iso, cellCount, mergeEdge, source);
  uint64_t previous = 0;
  for (size_t i = 0; i < nodes.size(); ++i) checkNode(nodes[i], i, dims, mergeEdge, &previous, source);
  so.mNodes = std::move(nodes);
  return so;
}

SurfaceOctree SurfaceOctree::fromMapped(glm::ivec3 dims, float iso, size_t cellCount, int mergeEdge, MappedNodes nodes,
                                        const std::string& source) {
  const InputFile::Mapping* mapping = nodes.mapping.get();
  HYB_CHECK(mapping && nodes.at >= mapping->data() && uint64_t(nodes.at - mapping->data()) + nodes.count * kSurfaceNodeBytes <= mapping->size());
  SurfaceOctree so = withHead(dims, iso, cellCount, mergeEdge, source);
  constexpr size_t kReleaseNodes = (size_t(64) << 20) / kSurfaceNodeBytes;
  uint64_t previous = 0;
  for (size_t i = 0; i < nodes.count; ++i) {
    checkNode(decodeSurfaceNode(nodes.at + i * kSurfaceNodeBytes), i, dims, mergeEdge, &previous, source);
    if ((i + 1) % kReleaseNodes == 0) mapping->release();
  }
  mapping->release();
  so.mMapping = std::move(nodes.mapping);
  so.mEncoded = nodes.at;
  so.mMappedCount = nodes.count;
  return so;
}

}  // namespace hyb
