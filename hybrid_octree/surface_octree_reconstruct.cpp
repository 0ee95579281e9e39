// Surface Octree, reconstruction (Boada and Navazo, SCCG 2001; docs/surface.md): from the terminal nodes' codes back to polygons, in
// four stages: each node's polygons (its planes clipped to its box and split by each other, kept
// where the solid changes, merged per plane and facing), T-junction vertices inserted where a
// polygon meets finer neighbours along a node face, coplanar polygons merged within a merge cube,
// and straight-through vertices no other polygon uses dropped. Exact: fine integer coordinates.
#include <algorithm>
#include <array>
#include <iterator>
#include <numeric>
#include <span>

#include "hybrid_octree/discrete_geometry.h"
#include "hybrid_octree/surface_octree.h"
#include "surface/dmc.h"
#include "surface/flat_map.h"
#include "volume/core/error.h"
#include "volume/core/parallel.h"

namespace hyb {

namespace {

using namespace detail;  // fine-coordinate geometry

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

// The polygons of the nodes, flat (a vector per polygon costs more than its vertices): polygon p's
// loop is points[starts[p] .. starts[p + 1]) (fine coordinates, below 2^21: 32 bits), its plane
// planes[p] (d in fine units), its node nodes[p].
struct OutPolys {
  std::vector<glm::ivec3> points;
  std::vector<size_t> starts{0};
  std::vector<PlaneId> planes;
  std::vector<uint32_t> nodes;

  size_t size() const { return planes.size(); }
  std::span<const glm::ivec3> loop(size_t p) const { return {points.data() + starts[p], starts[p + 1] - starts[p]}; }
  void add(const Poly& loop, const PlaneId& plane, uint32_t node) {
    for (const V64& v : loop) points.emplace_back(v);
    starts.push_back(points.size());
    planes.push_back(plane);
    nodes.push_back(node);
  }
  void append(const OutPolys& o) {
    const size_t base = points.size();
    points.insert(points.end(), o.points.begin(), o.points.end());
    for (size_t p = 1; p < o.starts.size(); ++p) starts.push_back(base + o.starts[p]);
    planes.insert(planes.end(), o.planes.begin(), o.planes.end());
    nodes.insert(nodes.end(), o.nodes.begin(), o.nodes.end());
  }
};

// Each polygon's loop as vertex ids of the mesh, flat: polygon p's is ids[start[p] .. start[p] +
// size[p]); a merged loop is appended, a loop merged into another has size 0.
struct Loops {
  std::vector<uint32_t> ids;
  std::vector<size_t> start;
  std::vector<uint32_t> size;

  std::span<uint32_t> of(size_t p) { return {ids.data() + start[p], size[p]}; }
  std::span<const uint32_t> of(size_t p) const { return {ids.data() + start[p], size[p]}; }
  void close(size_t p) { size[p] = uint32_t(ids.size() - start[p]); }
};

// Stage 1, one node: each plane clipped to the node's box and split by the node's other planes; the
// convex pieces where the truth value changes across the plane are the surface, oriented outward,
// and the pieces on one plane with one facing are merged into polygons (@p pos and @p neg are
// scratch).
void nodePolygons(const SurfaceNode& node, uint32_t nodeIndex, const glm::ivec3& dims, Poly& pos, Poly& neg, OutPolys& polys) {
  const Box box = nodeBox(glm::ivec3(node.origin), node.edge, dims);
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
      for (const Poly& p : emit) polys.add(p, id, nodeIndex);
    }
  }
}

// The key of the line through @p a and @p b when both lie on a face of @p box: exact in 64 bits, the
// face's axis and coordinate, the reduced direction within the face (components in {-1, 0, 1}: the
// line lies on one of the 13 planes and an axis plane) and its offset.
bool faceLine(const Box& box, const V64& a, const V64& b, uint64_t* key) {
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
        *key = uint64_t(axis) | uint64_t(c) << 2 | uint64_t(du + 1) << 23 | uint64_t(dv + 1) << 25 | uint64_t(offset + (I64(1) << 23)) << 27;
        return true;
      }
  return false;
}

// Stage 2, T-junctions: every polygon's loop as vertex ids of @p mesh, with the vertices that lie on
// one of its edges along a node face (a finer neighbour's) inserted in order, so the surface is
// watertight.
Loops insertTJunctions(const OutPolys& polys, std::span<const SurfaceNode> nodes, const glm::ivec3& dims, DiscreteMesh* out) {
  DiscreteMesh& mesh = *out;
  auto boxOf = [&](size_t p) {
    const SurfaceNode& n = nodes[polys.nodes[p]];
    return nodeBox(glm::ivec3(n.origin), n.edge, dims);
  };
  // The points of every line, sorted by line and then lexicographically (their order along it):
  // a point is its gridKey, whose order is the lexicographic one. The reconstruction's largest
  // array: counted before it is made (not grown by doubling), sorted as (line, point) pairs, then
  // kept as the points alone with a table of each line's first, sized by the lines.
  auto forEachFaceEdge = [&](auto&& f) {
    for (size_t pi = 0; pi < polys.size(); ++pi) {
      const std::span<const glm::ivec3> loop = polys.loop(pi);
      const Box box = boxOf(pi);
      for (size_t k = 0; k < loop.size(); ++k) {
        uint64_t key;
        const glm::ivec3 &a = loop[k], &b = loop[(k + 1) % loop.size()];
        if (faceLine(box, V64(a), V64(b), &key)) f(key, a, b);
      }
    }
  };
  size_t faceEdges = 0;
  forEachFaceEdge([&](uint64_t, const glm::ivec3&, const glm::ivec3&) { ++faceEdges; });
  std::vector<std::pair<uint64_t, uint64_t>> linePoints;
  linePoints.reserve(2 * faceEdges);
  forEachFaceEdge([&](uint64_t key, const glm::ivec3& a, const glm::ivec3& b) {
    linePoints.emplace_back(key, gridKey(a));
    linePoints.emplace_back(key, gridKey(b));
  });
  std::sort(linePoints.begin(), linePoints.end());
  linePoints.erase(std::unique(linePoints.begin(), linePoints.end()), linePoints.end());
  size_t lines = 0;
  for (size_t k = 0; k < linePoints.size(); ++k) lines += k == 0 || linePoints[k].first != linePoints[k - 1].first;
  FlatMap lineStart(lines);
  std::vector<uint64_t> onLine(linePoints.size());
  for (size_t k = linePoints.size(); k-- > 0;) {
    lineStart[linePoints[k].first] = uint32_t(k);
    onLine[k] = linePoints[k].second;
  }
  std::vector<std::pair<uint64_t, uint64_t>>().swap(linePoints);

  FlatMap ids(polys.size());
  auto vertexId = [&](uint64_t point) {
    return ids.findOrInsert(point, [&] {
      mesh.vertices.push_back(gridPoint(point));
      return uint32_t(mesh.vertices.size() - 1);
    });
  };
  Loops loops;
  loops.start.reserve(polys.size());
  loops.size.reserve(polys.size());
  loops.ids.reserve(polys.points.size());
  for (size_t pi = 0; pi < polys.size(); ++pi) {
    const std::span<const glm::ivec3> loop = polys.loop(pi);
    const Box box = boxOf(pi);
    loops.start.push_back(loops.ids.size());
    loops.size.push_back(0);
    for (size_t k = 0; k < loop.size(); ++k) {
      const glm::ivec3 &a = loop[k], &b = loop[(k + 1) % loop.size()];
      loops.ids.push_back(vertexId(gridKey(a)));
      uint64_t key;
      if (!faceLine(box, V64(a), V64(b), &key)) continue;
      // Insert the line's vertices strictly between a and b, in order from a to b.
      const uint64_t ka = gridKey(a), kb = gridKey(b);
      const bool forward = ka < kb;
      const uint64_t lo = std::min(ka, kb), hi = std::max(ka, kb);
      auto first = onLine.begin() + *lineStart.find(key);
      while (*first <= lo) ++first;  // lo and hi are on the line
      auto last = first;
      while (*last < hi) ++last;
      if (forward) {
        for (auto it = first; it != last; ++it) loops.ids.push_back(vertexId(*it));
      } else {
        for (auto it = last; it != first;) loops.ids.push_back(vertexId(*--it));
      }
    }
    loops.close(pi);
  }
  return loops;
}

// Stage 3: polygons of different nodes on the same plane with the same facing that share an edge,
// within one merge cube of @p mergeCube cells, become one where their union's boundary is a single
// loop (union-find over shared edges; the surface is unchanged).
void mergeCoplanar(const OutPolys& polys, std::span<const SurfaceNode> nodes, int mergeCube, Loops* loopsOut) {
  Loops& loops = *loopsOut;
  std::vector<uint32_t> parent(polys.size());
  std::iota(parent.begin(), parent.end(), 0u);
  auto find = [&](uint32_t x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  };
  auto cellOf = [&](size_t pi) { return gridKey(glm::ivec3(nodes[polys.nodes[pi]].origin) / mergeCube); };
  auto edgeKey = [](uint32_t from, uint32_t to) { return uint64_t(from) << 32 | to; };
  // Each directed edge's owner, the last polygon that has it: sorted (edge, polygon) pairs, a
  // sixteenth of the memory of a hash table over them.
  std::vector<std::pair<uint64_t, uint32_t>> owner;
  owner.reserve(loops.ids.size());
  for (size_t pi = 0; pi < polys.size(); ++pi) {
    const std::span<const uint32_t> loop = loops.of(pi);
    for (size_t k = 0; k < loop.size(); ++k) owner.emplace_back(edgeKey(loop[k], loop[(k + 1) % loop.size()]), uint32_t(pi));
  }
  std::sort(owner.begin(), owner.end());
  for (size_t pi = 0; pi < polys.size(); ++pi) {
    const std::span<const uint32_t> loop = loops.of(pi);
    for (size_t k = 0; k < loop.size(); ++k) {
      const uint64_t reverse = edgeKey(loop[(k + 1) % loop.size()], loop[k]);
      auto it = std::upper_bound(owner.begin(), owner.end(), std::pair{reverse, UINT32_MAX});
      if (it == owner.begin() || (--it)->first != reverse || it->second == pi) continue;
      const uint32_t q = it->second;
      if (polys.planes[q] == polys.planes[pi] && cellOf(q) == cellOf(pi)) parent[find(uint32_t(pi))] = find(q);
    }
  }
  std::vector<std::pair<uint64_t, uint32_t>>().swap(owner);
  // The sets, as runs of (root, polygon) pairs; each set's boundary from its sorted directed edges.
  std::vector<std::pair<uint32_t, uint32_t>> bySet(polys.size());
  for (uint32_t pi = 0; pi < polys.size(); ++pi) bySet[pi] = {find(pi), pi};
  std::sort(bySet.begin(), bySet.end());
  std::vector<uint64_t> edges, boundary;
  std::vector<uint8_t> used;
  std::vector<uint32_t> merged;
  for (size_t b = 0, e; b < bySet.size(); b = e) {
    for (e = b + 1; e < bySet.size() && bySet[e].first == bySet[b].first; ++e) {
    }
    if (e - b < 2) continue;
    const uint32_t root = bySet[b].first;
    edges.clear();
    for (size_t m = b; m < e; ++m) {
      const std::span<const uint32_t> loop = loops.of(bySet[m].second);
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
    merged.clear();
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
    loops.start[root] = loops.ids.size();
    loops.ids.insert(loops.ids.end(), merged.begin(), merged.end());
    loops.close(root);
    for (size_t m = b; m < e; ++m)
      if (bySet[m].second != root) loops.size[bySet[m].second] = 0;
  }
}

// Stage 4: drops straight-through vertices no other polygon uses (they only add triangles; a vertex
// another polygon references is kept, so no T-junction opens), and adds to @p mesh the faces of the
// nodes in @p keep (the others only count the vertices they use).
void dropStraightVertices(const OutPolys& polys, Loops& loops, std::pair<uint32_t, uint32_t> keep, DiscreteMesh* out) {
  DiscreteMesh& mesh = *out;
  std::vector<uint32_t> uses(mesh.vertices.size(), 0);
  for (size_t pi = 0; pi < polys.size(); ++pi)
    for (uint32_t v : loops.of(pi)) ++uses[v];
  for (size_t pi = 0; pi < polys.size(); ++pi) {
    if (loops.size[pi] == 0) continue;  // merged into another polygon
    if (polys.nodes[pi] < keep.first || polys.nodes[pi] >= keep.second) continue;
    uint32_t* loop = loops.of(pi).data();
    uint32_t& n = loops.size[pi];
    for (bool removed = true; removed && n > 3;) {
      removed = false;
      for (size_t k = 0; k < n && n > 3; ++k) {
        const uint32_t prev = loop[(k + n - 1) % n], cur = loop[k], next = loop[(k + 1) % n];
        if (uses[cur] != 1) continue;
        const V64 u = V64(mesh.vertices[cur]) - V64(mesh.vertices[prev]), w = V64(mesh.vertices[next]) - V64(mesh.vertices[cur]);
        const V64 x(u.y * w.z - u.z * w.y, u.z * w.x - u.x * w.z, u.x * w.y - u.y * w.x);
        if (x != V64(0) || u.x * w.x + u.y * w.y + u.z * w.z <= 0) continue;  // a corner, or a spike
        std::copy(loop + k + 1, loop + n, loop + k);
        --n;
        uses[cur] = 0;
        removed = true;
      }
    }
    mesh.addFace(loop, n, polys.planes[pi]);
  }
}

// The four stages over @p nodes (consecutive nodes of one octree, in its order), the faces of
// nodes [keep.first, keep.second) added to the mesh.
DiscreteMesh reconstructNodes(std::span<const SurfaceNode> nodes, const glm::ivec3& dims, int mergeCube, std::pair<uint32_t, uint32_t> keep,
                              const Progress* progress) {
  // A node's polygons depend on the node alone: nodes are processed in parallel, in contiguous
  // chunks whose polygons are concatenated in node order (the output does not depend on threads).
  const size_t chunks = std::min<size_t>(nodes.size(), 64), per = chunks ? (nodes.size() + chunks - 1) / chunks : 0;
  const size_t stage = std::max<size_t>(1, chunks / 8);  // progress: a later stage counts as this many chunks
  ProgressTask task(progress, "surface polygons", chunks + 3 * stage);
  std::vector<OutPolys> parts(chunks);
  ParallelFailure failure;
#pragma omp parallel for schedule(dynamic)
  for (size_t c = 0; c < chunks; ++c)
    failure.run([&] {
      Poly pos, neg;
      for (size_t k = c * per; k < std::min(nodes.size(), (c + 1) * per); ++k) nodePolygons(nodes[k], uint32_t(k), dims, pos, neg, parts[c]);
      task.advance();
    });
  failure.rethrow();
  OutPolys polys;
  for (OutPolys& part : parts) {
    polys.append(part);
    part = OutPolys();
  }
  task.advance(stage);
  DiscreteMesh mesh;
  Loops loops = insertTJunctions(polys, nodes, dims, &mesh);
  std::vector<glm::ivec3>().swap(polys.points);  // the loops are vertex ids now
  std::vector<size_t>().swap(polys.starts);
  task.advance(stage);
  mergeCoplanar(polys, nodes, mergeCube, &loops);
  task.advance(stage);
  dropStraightVertices(polys, loops, keep, &mesh);
  return mesh;
}

// @p mesh's vertices that its faces use, in their order, the faces renumbered.
void dropUnusedVertices(DiscreteMesh* mesh) {
  constexpr uint32_t kUnused = UINT32_MAX;
  std::vector<uint32_t> remap(mesh->vertices.size(), kUnused);
  for (uint32_t v : mesh->indices) remap[v] = 0;
  uint32_t next = 0;
  for (size_t v = 0; v < remap.size(); ++v)
    if (remap[v] != kUnused) {
      remap[v] = next;
      mesh->vertices[next++] = mesh->vertices[v];
    }
  mesh->vertices.resize(next);
  for (uint32_t& v : mesh->indices) v = remap[v];
}

}  // namespace

DiscreteMesh SurfaceOctree::reconstruct(int mergeCube, const Progress* progress) const {
  if (mergeCube <= 0) mergeCube = mMergeEdge;
  HYB_CHECK((mergeCube & (mergeCube - 1)) == 0);
  if (!mapped()) return reconstructNodes(mNodes, mDims, mergeCube, {0u, uint32_t(mNodes.size())}, progress);
  std::vector<SurfaceNode> nodes(nodeCount());  // decoded while they are reconstructed
  for (size_t i = 0; i < nodes.size(); ++i) nodes[i] = node(i);
  releasePages();
  return reconstructNodes(nodes, mDims, mergeCube, {0u, uint32_t(nodes.size())}, progress);
}

DiscreteMesh SurfaceOctree::reconstructIn(const SurfaceRegion& region) const {
  const int m = mMergeEdge;
  HYB_CHECK(region.edge >= m && region.edge % m == 0 && region.first <= region.last && region.last <= nodeCount());
  // The region's closed box and the nodes of the cubes of mergeEdge cells around it (no node is
  // larger) whose closed boxes touch it: every polygon with a vertex on the region's faces is
  // theirs, so the region's T-junctions, merges and shared vertices are those of the whole.
  const glm::ivec3 lo = region.origin, hi = region.origin + region.edge;
  auto touches = [&](const SurfaceNode& n) {
    const glm::ivec3 o(n.origin);
    return glm::all(glm::lessThanEqual(o, hi)) && glm::all(glm::greaterThanEqual(o + int(n.edge), lo));
  };
  const glm::ivec3 cells = glm::max(mDims - 1, glm::ivec3(1));
  std::vector<std::pair<uint32_t, uint32_t>> around;  // node ranges of the cubes around the region
  for (int z = lo.z - m; z <= hi.z; z += m)
    for (int y = lo.y - m; y <= hi.y; y += m)
      for (int x = lo.x - m; x <= hi.x; x += m) {
        const glm::ivec3 c(x, y, z);
        const bool inside = glm::all(glm::greaterThanEqual(c, lo)) && glm::all(glm::lessThan(c, hi));
        if (inside) {  // (the interior's cubes are the region's range: skip along x to its far side)
          x = hi.x - m;
          continue;
        }
        if (glm::any(glm::lessThan(c, glm::ivec3(0))) || glm::any(glm::greaterThanEqual(c, cells))) continue;
        const auto r = rangeIn(c, m);
        if (r.first < r.second) around.push_back(r);
      }
  around.push_back({region.first, region.last});
  std::sort(around.begin(), around.end());
  std::vector<SurfaceNode> nodes;
  std::pair<uint32_t, uint32_t> keep{0, 0};
  for (const auto& [b, e] : around) {
    if (b == region.first && e == region.last) {
      keep.first = uint32_t(nodes.size());
      for (uint32_t i = b; i < e; ++i) nodes.push_back(node(i));
      keep.second = uint32_t(nodes.size());
      continue;
    }
    for (uint32_t i = b; i < e; ++i)
      if (const SurfaceNode n = node(i); touches(n)) nodes.push_back(n);
  }
  DiscreteMesh mesh = reconstructNodes(nodes, mDims, m, keep, nullptr);
  dropUnusedVertices(&mesh);
  return mesh;
}

TriangleMesh fineMeshToTriangles(const DiscreteMesh& mesh, const glm::dvec3& spacing) { return toTriangleMesh(mesh, spacing, 2.0 * kFine); }

}  // namespace hyb
