// CGAL is confined to this file: a Surface_mesh for self-intersection (Polygon Mesh Processing),
// orientation and volume; an AABB tree for the bounded-error Hausdorff distance. The sampled
// Hausdorff distance needs closest points only, from a tree of its own (TriangleBvh).
#include "surface/cgal_geometry.h"

#include <CGAL/AABB_traits.h>
#include <CGAL/AABB_tree.h>
#include <CGAL/AABB_triangle_primitive.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Polygon_mesh_processing/measure.h>
#include <CGAL/Polygon_mesh_processing/orientation.h>
#include <CGAL/Surface_mesh.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <limits>
#include <numbers>

#include "volume/core/error.h"
#include "volume/core/parallel.h"

namespace hyb {

namespace {

using Kernel = CGAL::Exact_predicates_inexact_constructions_kernel;
using Point = Kernel::Point_3;
using Triangle = Kernel::Triangle_3;
using Segment = Kernel::Segment_3;
using Mesh = CGAL::Surface_mesh<Point>;
using TrianglePrimitive = CGAL::AABB_triangle_primitive<Kernel, std::vector<Triangle>::const_iterator>;
using TriangleTree = CGAL::AABB_tree<CGAL::AABB_traits<Kernel, TrianglePrimitive>>;
namespace PMP = CGAL::Polygon_mesh_processing;

Point toPoint(const glm::vec3& p) { return Point(p.x, p.y, p.z); }

constexpr uint32_t kNone = std::numeric_limits<uint32_t>::max();  // no index

// The squared distance from @p p to triangle @p t, in double precision: to its projection when
// that falls inside (the barycentric test of Ericson, Real-Time Collision Detection 5.1.5), else
// to the nearest edge. A triangle without area has no inside: it is measured as its edges.
double squaredDistance(const glm::dvec3& p, const std::array<glm::dvec3, 3>& t) {
  auto segment = [&](const glm::dvec3& a, const glm::dvec3& b) {
    const glm::dvec3 ab = b - a;
    const double len2 = glm::dot(ab, ab);
    const double s = len2 > 0.0 ? std::clamp(glm::dot(p - a, ab) / len2, 0.0, 1.0) : 0.0;
    const glm::dvec3 d = p - (a + s * ab);
    return glm::dot(d, d);
  };
  const glm::dvec3 &a = t[0], &b = t[1], &c = t[2];
  const glm::dvec3 ab = b - a, ac = c - a, ap = p - a, bp = p - b, cp = p - c;
  const double d1 = glm::dot(ab, ap), d2 = glm::dot(ac, ap), d3 = glm::dot(ab, bp), d4 = glm::dot(ac, bp), d5 = glm::dot(ab, cp),
               d6 = glm::dot(ac, cp);
  const double va = d3 * d6 - d5 * d4, vb = d5 * d2 - d1 * d6, vc = d1 * d4 - d3 * d2;
  const bool inside = va > 0.0 && vb > 0.0 && vc > 0.0;  // strictly: a triangle without area has no inside
  if (!inside) return std::min({segment(a, b), segment(b, c), segment(c, a)});
  const double sum = va + vb + vc;
  const glm::dvec3 d = p - (a + ab * (vb / sum) + ac * (vc / sum));
  return glm::dot(d, d);
}

// A bounding volume hierarchy over a mesh's triangles, for closest points and for the pairs whose
// boxes meet. Inner nodes hold their two children's boxes (64 bytes: one cache line a visit);
// leaves of up to four triangles are copies of their corners in leaf order (36 bytes a triangle);
// about 70 bytes a triangle in all. A closest-point query starts at the leaf of a triangle near its
// answer (the last query's nearby) and climbs, searching the other child of each node on the way
// whose box is nearer than the best so far, nearer child first; it may stop at the first triangle
// within a given distance. CGAL's AABB tree takes 64 bytes a triangle for its nodes alone, and its
// closest-point search starts at the root and visits children left first.
class TriangleBvh {
 public:
  struct Nearest {
    double distance2 = 0.0;  // squared
    uint32_t slot = 0;       // the triangle's place in the tree
  };

  explicit TriangleBvh(const TriangleMesh& mesh) {
    const size_t n = mesh.triangles.size();
    HYB_CHECK(n > 0 && n < kNone);
    std::vector<Item> items(n);
    for (uint32_t i = 0; i < n; ++i) {
      const glm::uvec3 t = mesh.triangles[i];
      items[i] = {(mesh.vertices[t.x] + mesh.vertices[t.y] + mesh.vertices[t.z]) / 3.0f, i};
    }
    mNodes.resize(std::max(innerNodes(uint32_t(n)).first, 1u));
    mParent.assign(mNodes.size(), kNone);
    if (n <= kLeafSize) {
      setChild(0, 0, {0, uint32_t(n), leafBox(mesh, items, 0, uint32_t(n))});
      setChild(0, 1, {});  // none: an empty box, never near anything
    } else {
#pragma omp parallel
#pragma omp single
      split(0, mesh, items, 0, uint32_t(n));
    }
    mCorners.resize(n);
    mIds.resize(n);
    mOwner.resize(n);
#pragma omp parallel for schedule(static)
    for (size_t k = 0; k < n; ++k) {
      const glm::uvec3 t = mesh.triangles[items[k].triangle];
      mCorners[k] = {mesh.vertices[t.x], mesh.vertices[t.y], mesh.vertices[t.z]};
      mIds[k] = items[k].triangle;
    }
    for (uint32_t i = 0; i < mNodes.size(); ++i)
      for (size_t k = 0; k < 2; ++k)
        if (mNodes[i].count[k] > 0) std::fill_n(mOwner.begin() + mNodes[i].child[k], mNodes[i].count[k], i);
  }

  // The mesh's index of the triangle in @p slot.
  uint32_t triangle(uint32_t slot) const { return mIds[slot]; }

  std::array<glm::dvec3, 3> corners(uint32_t slot) const {
    const std::array<glm::vec3, 3>& c = mCorners[slot];
    return {glm::dvec3(c[0]), glm::dvec3(c[1]), glm::dvec3(c[2])};
  }

  // The triangle nearest to @p p, or the first found within sqrt(@p enough2) of it; the search
  // starts from triangle @p hint (a slot), whose distance bounds it from the start.
  Nearest nearest(const glm::dvec3& p, uint32_t hint, double enough2) const {
    Nearest best{squaredDistance(p, corners(hint)), hint};
    for (uint32_t node = mOwner[hint], from = kNone; node != kNone && best.distance2 > enough2; from = node, node = mParent[node]) {
      const Node& n = mNodes[node];
      const std::array<double, 2> d{boxDistance2(n.lo[0], n.hi[0], p), boxDistance2(n.lo[1], n.hi[1], p)};
      const size_t nearer = d[1] < d[0] ? 1 : 0;
      for (const size_t k : {nearer, 1 - nearer})
        if (d[k] < best.distance2 && best.distance2 > enough2) {
          if (n.count[k] > 0) searchLeaf(n.child[k], n.count[k], p, &best);
          else if (n.child[k] != from) searchBelow(n.child[k], p, enough2, &best);  // not where the climb came from
        }
    }
    return best;
  }

  // Calls visit(a, b) for every pair of triangles (slots a ≠ b, once) whose boxes meet, closed
  // boxes as CGAL's box intersection: the tree walked against itself, the pairs within each child
  // of a node and across the two; the top levels' as tasks. Descends no further once stop().
  template <class Visit, class Stop>
  void overlappingPairs(const Visit& visit, const Stop& stop) const {
    Ref root{0, 0, childOf(0, 0).box};
    root.box.add(childOf(0, 1).box);
#pragma omp parallel
#pragma omp single
    within(root, visit, stop, 0);
  }

 private:
  struct Node {
    std::array<glm::vec3, 2> lo, hi;  // the children's boxes (their triangles' float corners: exact)
    std::array<uint32_t, 2> child{};  // an inner node's index, or a leaf's first slot
    std::array<uint32_t, 2> count{};  // a leaf's triangles; 0 for an inner node
  };
  struct Item {
    glm::vec3 centroid;
    uint32_t triangle;
  };
  struct Box {  // closed
    glm::vec3 lo{std::numeric_limits<float>::infinity()}, hi{-std::numeric_limits<float>::infinity()};  // empty
    void add(const Box& b) { lo = glm::min(lo, b.lo), hi = glm::max(hi, b.hi); }
    bool meets(const Box& b) const { return glm::all(glm::lessThanEqual(lo, b.hi)) && glm::all(glm::lessThanEqual(b.lo, hi)); }
  };
  struct Ref {  // a child of a node: an inner node (count 0) or a leaf's slots, and its box
    uint32_t index = 0, count = 0;
    Box box;
  };
  static constexpr uint32_t kLeafSize = 4;
  static constexpr int kTaskDepth = 8;  // tasks above this depth: enough for all threads, few enough to be cheap

  Ref childOf(uint32_t node, size_t k) const { return {mNodes[node].child[k], mNodes[node].count[k], {mNodes[node].lo[k], mNodes[node].hi[k]}}; }
  Box boxOf(uint32_t slot) const {
    const std::array<glm::vec3, 3>& c = mCorners[slot];
    return {glm::min(glm::min(c[0], c[1]), c[2]), glm::max(glm::max(c[0], c[1]), c[2])};
  }

  // The pairs under @p r: within a leaf, or within each child of a node and across the two.
  template <class Visit, class Stop>
  void within(const Ref& r, const Visit& visit, const Stop& stop, int depth) const {
    if (stop() || !r.box.meets(r.box)) return;  // an empty box: the root's missing second child
    if (r.count > 0) {
      for (uint32_t i = r.index; i < r.index + r.count; ++i)
        for (uint32_t j = i + 1; j < r.index + r.count; ++j)
          if (boxOf(i).meets(boxOf(j))) visit(i, j);
      return;
    }
    const Ref first = childOf(r.index, 0), second = childOf(r.index, 1);
#pragma omp task default(shared) firstprivate(first, depth) if (depth < kTaskDepth)
    within(first, visit, stop, depth + 1);
#pragma omp task default(shared) firstprivate(second, depth) if (depth < kTaskDepth)
    within(second, visit, stop, depth + 1);
    across(first, second, visit, stop);
#pragma omp taskwait
  }

  // The pairs of a triangle under @p r and one under @p s, descending the larger box's node.
  template <class Visit, class Stop>
  void across(const Ref& r, const Ref& s, const Visit& visit, const Stop& stop) const {
    if (stop() || !r.box.meets(s.box)) return;
    if (r.count > 0 && s.count > 0) {
      for (uint32_t i = r.index; i < r.index + r.count; ++i)
        for (uint32_t j = s.index; j < s.index + s.count; ++j)
          if (boxOf(i).meets(boxOf(j))) visit(i, j);
      return;
    }
    auto extent = [](const Ref& x) { const glm::vec3 e = x.box.hi - x.box.lo; return std::max({e.x, e.y, e.z}); };
    if (s.count > 0 || (r.count == 0 && extent(r) >= extent(s))) {
      across(childOf(r.index, 0), s, visit, stop);
      across(childOf(r.index, 1), s, visit, stop);
    } else {
      across(r, childOf(s.index, 0), visit, stop);
      across(r, childOf(s.index, 1), visit, stop);
    }
  }

  static double boxDistance2(const glm::vec3& lo, const glm::vec3& hi, const glm::dvec3& p) {
    const glm::dvec3 d = glm::max(glm::max(glm::dvec3(lo) - p, p - glm::dvec3(hi)), glm::dvec3(0.0));
    return glm::dot(d, d);
  }

  void searchLeaf(uint32_t first, uint32_t count, const glm::dvec3& p, Nearest* best) const {
    for (uint32_t j = first; j < first + count; ++j)
      if (const double t2 = squaredDistance(p, corners(j)); t2 < best->distance2) *best = {t2, j};
  }

  void searchBelow(uint32_t root, const glm::dvec3& p, double enough2, Nearest* best) const {
    std::array<uint32_t, 64> stack;  // inner nodes whose boxes are nearer than the best; depth ≤ 32
    size_t top = 0;
    stack[top++] = root;
    while (top > 0 && best->distance2 > enough2) {
      const Node& n = mNodes[stack[--top]];
      const std::array<double, 2> d{boxDistance2(n.lo[0], n.hi[0], p), boxDistance2(n.lo[1], n.hi[1], p)};
      const size_t nearer = d[1] < d[0] ? 1 : 0;
      for (const size_t k : {nearer, 1 - nearer})
        if (n.count[k] > 0 && d[k] < best->distance2) searchLeaf(n.child[k], n.count[k], p, best);
      for (const size_t k : {1 - nearer, nearer})  // the nearer one on top
        if (n.count[k] == 0 && d[k] < best->distance2) stack[top++] = n.child[k];
    }
  }

  static Box leafBox(const TriangleMesh& mesh, const std::vector<Item>& items, uint32_t first, uint32_t last) {
    Box b;
    for (uint32_t k = first; k < last; ++k)
      for (int c = 0; c < 3; ++c) {
        const glm::vec3& v = mesh.vertices[mesh.triangles[items[k].triangle][c]];
        b.add({v, v});
      }
    return b;
  }

  void setChild(uint32_t node, size_t k, const Ref& r) {
    mNodes[node].child[k] = r.index;
    mNodes[node].count[k] = r.count;
    mNodes[node].lo[k] = r.box.lo;
    mNodes[node].hi[k] = r.box.hi;
  }

  // {f(m), f(m + 1)}, f(m) the inner nodes of a subtree of m triangles: none for a leaf, else one
  // and its halves' (⌊m/2⌋ and ⌈m/2⌉; those of m and m + 1 are ⌊m/2⌋ or ⌊m/2⌋ + 1). Fixed by m
  // alone, so each subtree has its range of nodes before it is built: the halves are built at once.
  static std::pair<uint32_t, uint32_t> innerNodes(uint32_t m) {
    if (m < kLeafSize) return {0, 0};
    const std::pair<uint32_t, uint32_t> halves = innerNodes(m / 2);  // a pair: clang 14 cannot capture bindings
    const uint32_t h = m / 2;
    auto count = [&](uint32_t y) { return y == h ? halves.first : halves.second; };
    auto f = [&](uint32_t x) { return x <= kLeafSize ? 0u : 1u + count(x / 2) + count(x - x / 2); };
    return {f(m), f(m + 1)};
  }

  // Splits items[first, last) (more than a leaf) at the median centroid along the longest axis
  // into the two children of inner node @p node (the first child's subtree next to it, the
  // second's after that), and those below them, large halves as tasks; returns their box.
  Box split(uint32_t node, const TriangleMesh& mesh, std::vector<Item>& items, uint32_t first, uint32_t last) {
    Box centroids;
    for (uint32_t k = first; k < last; ++k) centroids.add({items[k].centroid, items[k].centroid});
    const glm::vec3 extent = centroids.hi - centroids.lo;
    const int axis = extent.x >= extent.y && extent.x >= extent.z ? 0 : extent.y >= extent.z ? 1 : 2;
    const uint32_t middle = first + (last - first) / 2;
    std::nth_element(items.begin() + first, items.begin() + middle, items.begin() + last,
                     [axis](const Item& a, const Item& b) { return a.centroid[axis] < b.centroid[axis]; });
    const std::array<uint32_t, 3> bounds{first, middle, last};
    const std::array<uint32_t, 2> index{node + 1, node + 1 + innerNodes(middle - first).first};
    std::array<Box, 2> boxes;
    for (size_t k = 0; k < 2; ++k) {
      const uint32_t from = bounds[k], to = bounds[k + 1];
      if (to - from <= kLeafSize) {
        boxes[k] = leafBox(mesh, items, from, to);
        setChild(node, k, {from, to - from, boxes[k]});
        continue;
      }
      mParent[index[k]] = node;
#pragma omp task default(shared) firstprivate(k, from, to) if (to - from > 65536)
      {
        boxes[k] = split(index[k], mesh, items, from, to);
        setChild(node, k, {index[k], 0, boxes[k]});
      }
    }
#pragma omp taskwait
    Box box = boxes[0];
    box.add(boxes[1]);
    return box;
  }

  std::vector<Node> mNodes;                        // the root first
  std::vector<uint32_t> mParent;                   // of each node (kNone: the root)
  std::vector<std::array<glm::vec3, 3>> mCorners;  // each slot's triangle
  std::vector<uint32_t> mIds;                      // the mesh's index of each slot's triangle
  std::vector<uint32_t> mOwner;                    // the node whose leaf holds each slot
};

// The soup's edges: corner edge 3t + j runs from corner j of triangle t to corner j + 1. Found by
// sorting them on their two vertices, 16 bytes an edge, where CGAL's soup conversion keeps sets
// and maps of them (docs/surface.md, "Checks").
struct SoupEdges {
  size_t boundary = 0;         // edges of one triangle
  bool manifold = true;        // no triangle repeats a vertex, no edge is in three or in two the same way round
  std::vector<uint32_t> twin;  // the corner edge running the other way, or kNone (a boundary edge)
};

SoupEdges soupEdges(const TriangleMesh& mesh) {
  const size_t count = 3 * mesh.triangles.size();
  HYB_CHECK(count < kNone);
  SoupEdges s;
  std::vector<std::pair<uint64_t, uint32_t>> edges(count);  // both vertices, lower first; the corner edge
  for (size_t e = 0; e < count; ++e) {
    const glm::uvec3& t = mesh.triangles[e / 3];
    const uint32_t u = t[int(e % 3)], v = t[int((e + 1) % 3)];
    s.manifold = s.manifold && u != v;  // in a triangle, a repeated vertex is a repeated corner pair
    edges[e] = {uint64_t(std::min(u, v)) << 32 | std::max(u, v), uint32_t(e)};
  }
  std::sort(edges.begin(), edges.end());
  s.twin.assign(count, kNone);
  for (size_t i = 0, j = 0; i < count; i = j) {
    for (j = i + 1; j < count && edges[j].first == edges[i].first;) ++j;
    if (j - i == 1) {
      ++s.boundary;
    } else {
      const uint32_t e = edges[i].second, f = edges[i + 1].second;
      const bool opposite = mesh.triangles[e / 3][int(e % 3)] != mesh.triangles[f / 3][int(f % 3)];  // their first vertices differ
      if (j - i > 2 || !opposite) s.manifold = false;
      s.twin[e] = f;
      s.twin[f] = e;
    }
  }
  return s;
}

// Whether each vertex's triangles make one fan, walked around it across the edges' twins (of a
// soup whose edges are manifold: the walk is then a permutation of the vertex's corners).
bool singleFans(const TriangleMesh& mesh, const std::vector<uint32_t>& twin) {
  std::vector<uint32_t> corners(mesh.vertices.size(), 0), first(mesh.vertices.size(), kNone);
  for (uint32_t c = 0; c < twin.size(); ++c) {
    const uint32_t v = mesh.triangles[c / 3][int(c % 3)];
    if (corners[v]++ == 0) first[v] = c;
  }
  for (size_t v = 0; v < corners.size(); ++v) {
    if (corners[v] == 0) continue;
    // Corner c = 3t + j is also the edge leaving it; 3t + (j + 2) % 3 is the edge into it, whose
    // twin leaves the vertex in the next triangle: that twin is the next corner.
    uint32_t seen = 1;
    bool around = false;
    for (uint32_t c = first[v]; seen <= corners[v];) {
      const uint32_t next = twin[c - c % 3 + (c + 2) % 3];
      if (next == kNone || (around = next == first[v])) break;
      c = next;
      ++seen;
    }
    // At a boundary, the other way round: the twin of the edge leaving c enters the vertex.
    for (uint32_t c = first[v]; !around && seen <= corners[v];) {
      const uint32_t in = twin[c];
      if (in == kNone) break;
      c = in - in % 3 + (in + 1) % 3;
      ++seen;
    }
    if (seen != corners[v]) return false;
  }
  return true;
}

// The Surface_mesh of a manifold soup, linked from its edges' twins (CGAL's soup conversion finds
// them again in maps). Only the vertices triangles use: CGAL's orientation test reads every vertex's
// halfedge. A border halfedge, the other half of a boundary edge, enters the vertex the edge leaves;
// its next leaves that vertex, the only border halfedge that does (one fan a vertex).
Mesh toSurfaceMesh(const TriangleMesh& in, const SoupEdges& edges) {
  const size_t count = edges.twin.size();
  std::vector<Mesh::Vertex_index> vertex(in.vertices.size(), Mesh::null_vertex());
  for (const glm::uvec3& t : in.triangles)
    for (int k = 0; k < 3; ++k) vertex[t[k]] = Mesh::Vertex_index(0);  // used
  Mesh m;
  m.reserve(Mesh::size_type(std::count(vertex.begin(), vertex.end(), Mesh::Vertex_index(0))), Mesh::size_type((count + edges.boundary) / 2),
            Mesh::size_type(in.triangles.size()));
  for (size_t i = 0; i < vertex.size(); ++i)
    if (vertex[i] != Mesh::null_vertex()) vertex[i] = m.add_vertex(toPoint(in.vertices[i]));
  std::vector<Mesh::Halfedge_index> half(count);
  for (size_t e = 0; e < count; ++e)
    if (edges.twin[e] == kNone || edges.twin[e] > e) {
      half[e] = m.add_edge();
      if (edges.twin[e] != kNone) half[edges.twin[e]] = m.opposite(half[e]);
    }
  auto to = [&](size_t e) { return vertex[in.triangles[e / 3][int((e + 1) % 3)]]; };  // the vertex corner edge e enters
  auto from = [&](size_t e) { return vertex[in.triangles[e / 3][int(e % 3)]]; };
  for (size_t t = 0; t < in.triangles.size(); ++t) {
    const Mesh::Face_index f = m.add_face();
    m.set_halfedge(f, half[3 * t]);
    for (size_t e = 3 * t; e < 3 * t + 3; ++e) {
      m.set_target(half[e], to(e));
      m.set_face(half[e], f);
      m.set_next(half[e], half[3 * t + (e + 1) % 3]);
      m.set_halfedge(to(e), half[e]);
    }
  }
  if (edges.boundary > 0) {
    std::vector<Mesh::Halfedge_index> leaving(in.vertices.size());  // the border halfedge leaving each vertex
    for (size_t e = 0; e < count; ++e)
      if (edges.twin[e] == kNone) {
        const Mesh::Halfedge_index b = m.opposite(half[e]);
        m.set_target(b, from(e));
        m.set_face(b, Mesh::null_face());
        m.set_halfedge(from(e), b);  // a boundary vertex's halfedge is a border one
        leaving[size_t(to(e))] = b;
      }
    for (size_t e = 0; e < count; ++e)
      if (edges.twin[e] == kNone) m.set_next(m.opposite(half[e]), leaving[size_t(from(e))]);
  }
  return m;
}

// Whether triangles @p f and @p g of a manifold mesh meet other than where they are joined:
// CGAL's rule (Polygon Mesh Processing's do_faces_intersect) on the soup's indices, with its exact
// predicates. Joined along an edge, they intersect only when coplanar and folded onto each other;
// at a vertex, when the edge of one opposite it meets the other; else when they have any point in
// common.
bool facesIntersect(const TriangleMesh& mesh, uint32_t f, uint32_t g) {
  const glm::uvec3 a = mesh.triangles[f], b = mesh.triangles[g];
  auto point = [&](uint32_t v) { return toPoint(mesh.vertices[v]); };
  auto triangle = [&](const glm::uvec3& t) { return Triangle(point(t.x), point(t.y), point(t.z)); };
  int shared = 0, i = 0, j = 0;  // how many corners they share; one of them in a and in b
  for (int k = 0; k < 3; ++k)
    for (int l = 0; l < 3; ++l)
      if (a[k] == b[l]) ++shared, i = k, j = l;
  if (shared == 3) return true;  // the same corners the other way round: folded onto each other
  if (shared == 2) {
    int c = 0, d = 0;  // the corners not shared
    while (a[c] == b.x || a[c] == b.y || a[c] == b.z) ++c;
    while (b[d] == a.x || b[d] == a.y || b[d] == a.z) ++d;
    const Point p = point(a[(c + 1) % 3]), q = point(a[(c + 2) % 3]), r = point(a[c]), s = point(b[d]);
    return CGAL::coplanar(p, q, r, s) && CGAL::coplanar_orientation(p, q, r, s) == CGAL::POSITIVE;
  }
  if (shared == 1)
    return CGAL::do_intersect(triangle(a), Segment(point(b[(j + 1) % 3]), point(b[(j + 2) % 3]))) ||
           CGAL::do_intersect(triangle(b), Segment(point(a[(i + 1) % 3]), point(a[(i + 2) % 3])));
  return CGAL::do_intersect(triangle(a), triangle(b));
}

// Whether manifold @p mesh intersects itself, as CGAL's does_self_intersect decides it: a
// triangle whose corners are collinear does; else two triangles that meet (see facesIntersect),
// every pair whose boxes meet (closed boxes, as CGAL's box intersection) from @p tree, tested on
// all cores (CGAL 5.5 tests them on one: its parallel version needs TBB).
bool selfIntersects(const TriangleMesh& mesh, const TriangleBvh& tree) {
  std::atomic<bool> found{false};
  const long long count = (long long)mesh.triangles.size();
#pragma omp parallel for schedule(static)
  for (long long f = 0; f < count; ++f) {
    const glm::uvec3 t = mesh.triangles[size_t(f)];
    if (CGAL::collinear(toPoint(mesh.vertices[t.x]), toPoint(mesh.vertices[t.y]), toPoint(mesh.vertices[t.z]))) found = true;
  }
  if (found) return true;
  ParallelFailure failure;  // CGAL's exceptions
  tree.overlappingPairs(
      [&](uint32_t a, uint32_t b) {
        failure.run([&] {
          if (!found.load(std::memory_order_relaxed) && facesIntersect(mesh, tree.triangle(a), tree.triangle(b))) found = true;
        });
      },
      [&] { return found.load(std::memory_order_relaxed); });
  failure.rethrow();
  return found;
}

}  // namespace

MeshCheck checkMesh(const TriangleMesh& mesh) {
  MeshCheck c;
  try {
    Mesh m;
    {
      const SoupEdges edges = soupEdges(mesh);
      c.boundaryEdges = edges.boundary;
      c.manifold = edges.manifold && singleFans(mesh, edges.twin);
      if (!c.manifold) return c;  // self-intersections are CGAL's on polygon meshes only (as its own test in 5.5)
      c.selfIntersecting = !mesh.triangles.empty() && selfIntersects(mesh, TriangleBvh(mesh));  // the tree freed before the mesh is made
      m = toSurfaceMesh(mesh, edges);
    }
    HYB_DCHECK(CGAL::is_valid_polygon_mesh(m));
    c.closed = CGAL::is_closed(m);
    if (c.closed && !c.selfIntersecting && !mesh.triangles.empty()) {
      c.outward = PMP::is_outward_oriented(m);
      c.volume = CGAL::to_double(PMP::volume(m));
    }
  } catch (const Error&) {
    throw;
  } catch (const std::exception& e) {
    HYB_THROW(RuntimeError, "CGAL mesh check failed: ", e.what());
  }
  return c;
}

namespace {

// The squared lengths of the edges of triangle @p v (a Triangle or its three corners), each
// indexed by the corner opposite it.
template <class Corners>
std::array<double, 3> squaredEdges(const Corners& v) {
  return {CGAL::squared_distance(v[1], v[2]), CGAL::squared_distance(v[2], v[0]), CGAL::squared_distance(v[0], v[1])};
}

// The corner opposite the longest of the edges @p e (the first of equal ones).
int longestOf(const std::array<double, 3>& e) { return int(std::max_element(e.begin(), e.end()) - e.begin()); }

// The radius of the smallest circle around the triangle of squared edges @p e: half the
// longest edge when the triangle is right or obtuse, else the circumradius.
double enclosingRadius(std::array<double, 3> e) {
  std::sort(e.begin(), e.end());
  if (e[2] >= e[0] + e[1]) return 0.5 * std::sqrt(e[2]);
  const double a = std::sqrt(e[0]), b = std::sqrt(e[1]), c = std::sqrt(e[2]);
  const double area4 = std::sqrt(std::max((a + b + c) * (-a + b + c) * (a - b + c) * (a + b - c), 0.0));
  return area4 > 0.0 ? a * b * c / area4 : 0.5 * c;
}

// The largest distance from the corners @p v to triangle @p t: from any point of their triangle
// (distance to a convex set is convex, so its largest value on a triangle is at a corner).
double farthestCorner(const std::array<Point, 3>& v, const Triangle& t) {
  double far = 0.0;
  for (const Point& p : v) far = std::max(far, CGAL::squared_distance(p, t));
  return std::sqrt(far);
}

// The distance from the points of one mesh to another (the target), bracketed: what a point
// attains is a lower bound of the one-sided Hausdorff distance; a triangle's points are at most
// U from the target, with U the least of
//  - max_i d(v_i, t) for a target triangle t (distance to a convex set is convex, so its largest
//    value on a triangle is at a corner; Sieger et al.'s bound), t among the corners' nearest, and
//  - max_i d_i + R, R the triangle's smallest enclosing circle's radius (distance is 1-Lipschitz,
//    and every point of the triangle lies within R of a corner).
// A triangle whose U exceeds the largest attained distance by more than the error bound is
// bisected at its longest edge; once R ≤ the bound the second term settles it, so the recursion
// ends. (Splitting in four at the edges' midpoints makes children similar to their parent, so a
// sliver — a large merged polygon's fan has many, tens of mm long — would need ~aspect² splits
// before its bounds tighten; bisection makes them rounder.) Splits are counted: past the work
// limit a triangle is settled with the U it has (the bracket stays true, only wider than the bound).
// The tree holds the target's triangles cut by the same bisection to edges no longer than a few
// typical ones (the same point set): the boxes of slivers overlap so much that a closest-point
// query visits thousands of them. U's first term reads the uncut triangle a piece came from.
class OneSidedHausdorff {
 public:
  OneSidedHausdorff(const TriangleMesh& target, double errorBound, uint64_t maxSplits) : mBound(errorBound), mMaxSplits(maxSplits) {
    mOriginals.reserve(target.triangles.size());
    std::vector<double> longest;
    longest.reserve(target.triangles.size());
    for (const glm::uvec3& t : target.triangles) {
      mOriginals.emplace_back(toPoint(target.vertices[t.x]), toPoint(target.vertices[t.y]), toPoint(target.vertices[t.z]));
      const std::array<double, 3> e = squaredEdges(mOriginals.back());
      longest.push_back(e[size_t(longestOf(e))]);
    }
    // Pieces' edges at most four times the median longest edge (squared lengths); a target of
    // points alone is not cut.
    std::nth_element(longest.begin(), longest.begin() + ptrdiff_t(longest.size() / 2), longest.end());
    const double median = longest[longest.size() / 2];
    const double limit = median > 0.0 ? 16.0 * median : std::numeric_limits<double>::infinity();
    mTriangles.reserve(mOriginals.size());
    mOrigin.reserve(mOriginals.size());
    for (size_t i = 0; i < mOriginals.size(); ++i) cut(mOriginals[i], i, limit);
    mTree.insert(mTriangles.begin(), mTriangles.end());
    mTree.build();
    // A query starts from the nearest of these hints. CGAL's default hint is each triangle's first
    // corner, and a fanned polygon's triangles share theirs: a query far from the fan's apex then
    // starts with a sphere millimetres wide and visits thousands of boxes. The pieces' centroids
    // cover the surface. Built now: the parallel queries below only read the tree.
    std::vector<TriangleTree::Point_and_primitive_id> hints;
    hints.reserve(mTriangles.size());
    for (auto it = mTriangles.cbegin(); it != mTriangles.cend(); ++it) hints.emplace_back(CGAL::centroid(*it), it);
    mTree.accelerate_distance_queries(hints.begin(), hints.end());
  }

  // The bracket [lower, upper] of the one-sided distance from @p source to the target.
  std::array<double, 2> from(const TriangleMesh& source, ProgressTask* progress) const {
    // The corners first: their largest distance is the bar most triangles are settled against.
    // (Vertices no triangle uses are not on the surface.)
    const size_t n = source.vertices.size();
    std::vector<uint8_t> used(n, 0);
    for (const glm::uvec3& t : source.triangles) used[t.x] = used[t.y] = used[t.z] = 1;
    std::vector<Nearest> corners(n);
    double lower = 0.0;
#pragma omp parallel for schedule(static) reduction(max : lower)
    for (size_t i = 0; i < n; ++i)
      if (used[i]) {
        corners[i] = nearest(toPoint(source.vertices[i]));
        lower = std::max(lower, corners[i].distance);
      }
    // (A reduction's private copies start at the lowest value, not at the corners' bar.)
    const double bar = lower;
    double upper = lower;
    const long long count = (long long)source.triangles.size();
    const int chunk = int(std::clamp(count / 64, 1LL, 256LL));  // neighbours together (the tree's cache), yet all threads busy
    ParallelFailure failure;  // a progress callback that stops the work, or CGAL's exceptions
#pragma omp parallel for schedule(dynamic, chunk) reduction(max : lower, upper)
    for (long long f = 0; f < count; ++f)
      failure.run([&] {
        progress->advance();
        const glm::uvec3 t = source.triangles[size_t(f)];
        std::array<double, 2> b{std::max(lower, bar), upper};
        settle({toPoint(source.vertices[t.x]), toPoint(source.vertices[t.y]), toPoint(source.vertices[t.z])},
               {corners[t.x], corners[t.y], corners[t.z]}, &b);
        lower = std::max(lower, b[0]);
        upper = std::max(upper, b[1]);
      });
    failure.rethrow();
    return {lower, std::max(upper, lower)};
  }

 private:
  struct Nearest {
    double distance = 0.0;
    size_t triangle = 0;
  };

  Nearest nearest(const Point& p) const {
    const auto [q, id] = mTree.closest_point_and_primitive(p);
    return {std::sqrt(CGAL::squared_distance(p, q)), mOrigin[size_t(id - mTriangles.begin())]};
  }

  // Adds @p t to the tree's triangles, bisected at its longest edge until no edge is longer than
  // the square root of @p limit; every piece remembers @p origin.
  void cut(const Triangle& t, size_t origin, double limit) {
    const std::array<double, 3> e = squaredEdges(t);
    const int i = longestOf(e);
    if (e[size_t(i)] <= limit) {
      mTriangles.push_back(t);
      mOrigin.push_back(origin);
      return;
    }
    const Point m = CGAL::midpoint(t[(i + 1) % 3], t[(i + 2) % 3]);
    cut(Triangle(t[i], t[(i + 1) % 3], m), origin, limit);
    cut(Triangle(t[i], m, t[(i + 2) % 3]), origin, limit);
  }

  // Settles triangle @p v (its corners' nearest @p d) against the bracket @p b, splitting it as
  // long as its bound exceeds the attained distance by more than the error bound.
  void settle(const std::array<Point, 3>& v, const std::array<Nearest, 3>& d, std::array<double, 2>* b) const {
    const double attained = std::max({d[0].distance, d[1].distance, d[2].distance});
    (*b)[0] = std::max((*b)[0], attained);
    const std::array<double, 3> e = squaredEdges(v);
    double bound = attained + enclosingRadius(e);
    for (const Nearest& c : d) bound = std::min(bound, farthestCorner(v, mOriginals[c.triangle]));
    if (bound <= (*b)[0] + mBound || mSplits.fetch_add(1, std::memory_order_relaxed) >= mMaxSplits) {
      (*b)[1] = std::max((*b)[1], bound);
      return;
    }
    const int i = longestOf(e), j = (i + 1) % 3, k = (i + 2) % 3;
    const Point m = CGAL::midpoint(v[j], v[k]);
    const Nearest dm = nearest(m);
    settle({v[i], v[j], m}, {d[i], d[j], dm}, b);
    settle({v[i], m, v[k]}, {d[i], dm, d[k]}, b);
  }

  double mBound;
  uint64_t mMaxSplits;
  mutable std::atomic<uint64_t> mSplits{0};
  std::vector<Triangle> mOriginals;  // the target's triangles
  std::vector<Triangle> mTriangles;  // their pieces, in the tree
  std::vector<size_t> mOrigin;       // the original of each piece
  TriangleTree mTree;
};

}  // namespace

HausdorffBracket hausdorffDistance(const TriangleMesh& a, const TriangleMesh& b, double errorBound, uint64_t maxSplits,
                                   const Progress* progress) {
  if (!(errorBound > 0.0)) HYB_THROW(ValueError, "Hausdorff distance: error bound ", errorBound, " must be positive");
  if (a.triangles.empty() && b.triangles.empty()) return {0.0, 0.0};
  if (a.triangles.empty() || b.triangles.empty()) return {std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity()};
  try {
    ProgressTask task(progress, "Hausdorff distance", a.triangles.size() + b.triangles.size());
    const std::array<double, 2> ab = OneSidedHausdorff(b, errorBound, maxSplits / 2).from(a, &task),
                                ba = OneSidedHausdorff(a, errorBound, maxSplits / 2).from(b, &task);
    return {std::max(ab[0], ba[0]), std::max(ab[1], ba[1])};
  } catch (const Error&) {
    throw;
  } catch (const std::exception& e) {
    HYB_THROW(RuntimeError, "CGAL Hausdorff distance failed: ", e.what());
  }
}

namespace {

// A 64-bit mix (SplitMix64's output function, Steele, Lea and Flood 2014).
uint64_t mix64(uint64_t z) {
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  return z ^ (z >> 31);
}

// SplitMix64: a stream of its own for each triangle, so the samples do not depend on which thread
// draws them.
class SplitMix {
 public:
  explicit SplitMix(uint64_t seed) : mState(seed) {}
  uint64_t next() { return mix64(mState += 0x9e3779b97f4a7c15ULL); }
  double uniform() { return double(next() >> 11) * 0x1.0p-53; }  // in [0, 1)
  // A Poisson variate of mean @p mean: Knuth's product of uniforms, a mean of at most 16 at a time
  // (a sum of independent Poisson variates is one; e^-16 is far from underflow).
  uint64_t poisson(double mean) {
    uint64_t n = 0;
    for (; mean > 0.0; mean -= 16.0)
      for (double p = uniform(), limit = std::exp(-std::min(mean, 16.0)); p > limit; p *= uniform()) ++n;
    return n;
  }

 private:
  uint64_t mState;
};

// Visits the points of a Poisson process of @p density points per unit area on triangle @p v: the
// triangle is halved at its longest edge down to pieces no longer than sqrt(@p pieceEdge2), each
// given a Poisson count of uniform points. Counts of disjoint pieces are independent Poisson
// variates, so their union is the same process on the triangle; and consecutive points are near
// each other, so each query's answer is a good start for the next.
template <class Visit>
void samplePoisson(const std::array<glm::dvec3, 3>& v, double density, double pieceEdge2, SplitMix* random, const Visit& visit) {
  const double area = 0.5 * glm::length(glm::cross(v[1] - v[0], v[2] - v[0]));
  if (!(area > 0.0)) return;  // a point or a segment: no area to sample (its corners are measured)
  const std::array<double, 3> e{glm::dot(v[1] - v[2], v[1] - v[2]), glm::dot(v[2] - v[0], v[2] - v[0]), glm::dot(v[0] - v[1], v[0] - v[1])};
  const int i = longestOf(e), j = (i + 1) % 3, k = (i + 2) % 3;
  if (e[size_t(i)] > pieceEdge2) {
    const glm::dvec3 m = 0.5 * (v[j] + v[k]);
    samplePoisson({v[i], v[j], m}, density, pieceEdge2, random, visit);
    samplePoisson({v[i], m, v[k]}, density, pieceEdge2, random, visit);
    return;
  }
  for (uint64_t n = random->poisson(density * area); n > 0; --n) {
    double s = random->uniform(), t = random->uniform();
    if (s + t > 1.0) s = 1.0 - s, t = 1.0 - t;  // the other half of the parallelogram folded in: uniform on the triangle
    visit(v[0] + s * (v[1] - v[0]) + t * (v[2] - v[0]));
  }
}

// One side of the sampled distance: points of a source mesh measured against the target's tree.
// Each query starts from the answer of one nearby.
class SampledSide {
 public:
  struct Result {
    double lower = 0.0, upper = 0.0;
    uint64_t samples = 0;
  };

  explicit SampledSide(const TriangleMesh& target) : mTree(target) {}

  Result from(const TriangleMesh& source, double density, uint64_t seed, ProgressTask* progress) const {
    // The corners, exactly where they might be the farthest. Each vertex is measured with the
    // first triangle that uses it, in the triangles' order: the corners of a triangle and of the
    // next are near each other, each query started from the last one's answer. Chunks start
    // afresh (the first triangle as the hint, nothing found yet), so what a query stops at does
    // not depend on the threads: nor does the upper bound made from them.
    const size_t n = source.vertices.size();
    const long long count = (long long)source.triangles.size();
    std::vector<uint32_t> first(n, kNone);
    for (uint32_t f = 0; f < uint32_t(count); ++f)
      for (int k = 0; k < 3; ++k)
        if (uint32_t& i = first[source.triangles[f][k]]; i == kNone) i = f;
    std::vector<double> distance(n, 0.0);  // from each vertex, or a bound of it no larger than the largest distance found
    std::vector<uint32_t> nearest(n, 0);   // a target triangle (its slot) that far from it
    constexpr long long kChunk = 1024;     // triangles; few fresh starts, yet all threads busy
    double lower = 0.0, upper = 0.0;
    uint64_t samples = 0;
    ParallelFailure failure;  // a progress callback that stops the work
#pragma omp parallel for schedule(dynamic, 1) reduction(max : lower)
    for (long long c = 0; c < (count + kChunk - 1) / kChunk; ++c)
      failure.run([&] {
        uint32_t hint = 0;
        double found = 0.0;
        for (long long f = c * kChunk; f < std::min(count, (c + 1) * kChunk); ++f)
          for (int k = 0; k < 3; ++k) {
            const uint32_t i = source.triangles[size_t(f)][k];
            if (first[i] != uint32_t(f)) continue;
            const TriangleBvh::Nearest q = mTree.nearest(glm::dvec3(source.vertices[i]), hint, found * found);
            distance[i] = std::sqrt(q.distance2);
            nearest[i] = hint = q.slot;
            found = std::max(found, distance[i]);
          }
        progress->advance(uint64_t(std::min(count, (c + 1) * kChunk) - c * kChunk));
        lower = std::max(lower, found);
      });
    failure.rethrow();
    // The triangles: each one's exact bound, and its samples, in pieces of a few points each.
    const double bar = lower, pieceEdge2 = 8.0 / density;
#pragma omp parallel for schedule(dynamic, 256) reduction(max : lower, upper) reduction(+ : samples)
    for (long long f = 0; f < count; ++f)
      failure.run([&] {
        progress->advance();
        const glm::uvec3 t = source.triangles[size_t(f)];
        const std::array<glm::dvec3, 3> v{glm::dvec3(source.vertices[t.x]), glm::dvec3(source.vertices[t.y]), glm::dvec3(source.vertices[t.z])};
        // hausdorffDistance's bounds of a triangle, unsplit: its corners' largest distance plus its
        // enclosing radius, or less, their largest distance to one target triangle (computed only
        // where the first would raise the largest so far).
        const std::array<double, 3> e{glm::dot(v[1] - v[2], v[1] - v[2]), glm::dot(v[2] - v[0], v[2] - v[0]), glm::dot(v[0] - v[1], v[0] - v[1])};
        double bound = std::max({distance[t.x], distance[t.y], distance[t.z]}) + enclosingRadius(e);
        for (const uint32_t c : {nearest[t.x], nearest[t.y], nearest[t.z]})
          if (bound > std::max(upper, bar)) {
            const std::array<glm::dvec3, 3> near = mTree.corners(c);
            bound = std::min(bound, std::sqrt(std::max({squaredDistance(v[0], near), squaredDistance(v[1], near), squaredDistance(v[2], near)})));
          }
        upper = std::max(upper, bound);
        uint32_t hint = nearest[t.x];
        SplitMix random(mix64(seed ^ mix64(uint64_t(f))));
        samplePoisson(v, density, pieceEdge2, &random, [&](const glm::dvec3& p) {
          // Exact only where it might be the farthest: the search stops within the largest so far.
          const double enough = std::max(lower, bar);
          const TriangleBvh::Nearest q = mTree.nearest(p, hint, enough * enough);
          hint = q.slot;
          lower = std::max(lower, std::sqrt(q.distance2));
          ++samples;
        });
      });
    failure.rethrow();
    Result r;
    r.lower = std::max(lower, bar);
    r.upper = std::max(upper, r.lower);
    r.samples = samples;
    return r;
  }

 private:
  TriangleBvh mTree;
};

}  // namespace

// Why the patch bound holds on one side (a Poisson process of density λ on a mesh M measured
// against the other, N; D the largest distance measured, d(x) a point's distance to N; a search
// that stops within the largest so far does not change D). When M's area is below A there is
// nothing to prove. Else let t* be the largest t with area{d ≥ t} ≥ A (that area is
// left-continuous in t). If D ≥ t*, then area{d > D} ≤ area{d > t*} ≤ A. So area{d > D} > A needs
// D < t*: no point of the process fell in {d ≥ t*}, a fixed region of area ≥ A, which happens
// with probability exp(−λ · its area) ≤ exp(−λA). With λ = ln(2/δ)/A that is δ/2 a side, δ for
// the two (δ = 1 − confidence).
SampledHausdorff sampledHausdorffDistance(const TriangleMesh& a, const TriangleMesh& b, const SampledHausdorffOptions& options,
                                          const Progress* progress) {
  if (!(options.patchRadius > 0.0 && std::isfinite(options.patchRadius)))
    HYB_THROW(ValueError, "sampled Hausdorff distance: patch radius ", options.patchRadius, " must be positive and finite");
  if (!(options.confidence > 0.0 && options.confidence < 1.0))
    HYB_THROW(ValueError, "sampled Hausdorff distance: confidence ", options.confidence, " must be in (0, 1)");
  for (const TriangleMesh* m : {&a, &b})
    for (const glm::vec3& p : m->vertices)
      if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z))
        HYB_THROW(ValueError, "sampled Hausdorff distance: a vertex (", p.x, ", ", p.y, ", ", p.z, ") is not finite");
  SampledHausdorff h;
  h.patchArea = std::numbers::pi * options.patchRadius * options.patchRadius;
  h.confidence = options.confidence;
  if (a.triangles.empty() && b.triangles.empty()) return h;
  if (a.triangles.empty() || b.triangles.empty()) {
    h.lower = h.upper = std::numeric_limits<double>::infinity();
    return h;
  }
  const double density = std::log(2.0 / (1.0 - options.confidence)) / h.patchArea;
  try {
    ProgressTask task(progress, "Hausdorff distance", 2 * (a.triangles.size() + b.triangles.size()));  // each triangle twice: its corners, its samples
    const SampledSide::Result ab = SampledSide(b).from(a, density, mix64(options.seed), &task),
                              ba = SampledSide(a).from(b, density, mix64(options.seed + 1), &task);
    h.lower = std::max(ab.lower, ba.lower);
    h.upper = std::max(ab.upper, ba.upper);
    h.samples = ab.samples + ba.samples;
  } catch (const Error&) {
    throw;
  } catch (const std::exception& e) {
    HYB_THROW(RuntimeError, "sampled Hausdorff distance failed: ", e.what());
  }
  return h;
}

}  // namespace hyb
