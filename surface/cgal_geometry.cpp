// CGAL is confined to this file: Polygon Mesh Processing for topology checks, self-intersection,
// orientation and volume; an AABB tree for the bounded-error Hausdorff distance.
#include "surface/cgal_geometry.h"

#include <CGAL/AABB_traits.h>
#include <CGAL/AABB_tree.h>
#include <CGAL/AABB_triangle_primitive.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Polygon_mesh_processing/measure.h>
#include <CGAL/Polygon_mesh_processing/orientation.h>
#include <CGAL/Polygon_mesh_processing/polygon_soup_to_polygon_mesh.h>
#include <CGAL/Polygon_mesh_processing/self_intersections.h>
#include <CGAL/Surface_mesh.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <limits>
#include <map>

#include "volume/error.h"
#include "volume/parallel.h"

namespace hyb {

namespace {

using Kernel = CGAL::Exact_predicates_inexact_constructions_kernel;
using Point = Kernel::Point_3;
using Triangle = Kernel::Triangle_3;
using Mesh = CGAL::Surface_mesh<Point>;
using TrianglePrimitive = CGAL::AABB_triangle_primitive<Kernel, std::vector<Triangle>::const_iterator>;
using TriangleTree = CGAL::AABB_tree<CGAL::AABB_traits<Kernel, TrianglePrimitive>>;
namespace PMP = CGAL::Polygon_mesh_processing;

Point toPoint(const glm::vec3& p) { return Point(p.x, p.y, p.z); }

// Converts @p in; false when it is not a polygon mesh (non-manifold).
bool toSurfaceMesh(const TriangleMesh& in, Mesh* out) {
  std::vector<Point> points;
  points.reserve(in.vertices.size());
  for (const glm::vec3& p : in.vertices) points.push_back(toPoint(p));
  std::vector<std::vector<size_t>> faces;
  faces.reserve(in.triangles.size());
  for (const glm::uvec3& t : in.triangles) faces.push_back({t.x, t.y, t.z});
  if (!PMP::is_polygon_soup_a_polygon_mesh(faces)) return false;
  PMP::polygon_soup_to_polygon_mesh(points, faces, *out);
  return true;
}

}  // namespace

MeshCheck checkMesh(const TriangleMesh& mesh) {
  MeshCheck c;
  try {
    // Boundary edges counted on the soup, independently of CGAL's conversion.
    std::map<std::pair<uint32_t, uint32_t>, int> edges;
    for (const glm::uvec3& t : mesh.triangles)
      for (int k = 0; k < 3; ++k) ++edges[std::minmax(t[k], t[(k + 1) % 3])];
    for (const auto& [e, n] : edges) c.boundaryEdges += n == 1;
    Mesh m;
    c.manifold = toSurfaceMesh(mesh, &m);
    if (!c.manifold) return c;  // CGAL 5.5 tests self-intersection on polygon meshes only
    c.closed = CGAL::is_closed(m);
    c.selfIntersecting = PMP::does_self_intersect(m);
    if (c.closed && !c.selfIntersecting && !mesh.triangles.empty()) {
      c.outward = PMP::is_outward_oriented(m);
      c.volume = CGAL::to_double(PMP::volume(m));
    }
  } catch (const std::exception& e) {
    HYB_THROW(RuntimeError, "CGAL mesh check failed: ", e.what());
  }
  return c;
}

namespace {

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

  // The squared lengths of the edges of triangle @p v (a Triangle or its three corners), each
  // indexed by the corner opposite it.
  template <class Corners>
  static std::array<double, 3> squaredEdges(const Corners& v) {
    return {CGAL::squared_distance(v[1], v[2]), CGAL::squared_distance(v[2], v[0]), CGAL::squared_distance(v[0], v[1])};
  }

  // The corner opposite the longest of the edges @p e (the first of equal ones).
  static int longestOf(const std::array<double, 3>& e) { return int(std::max_element(e.begin(), e.end()) - e.begin()); }

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
    for (const Nearest& c : d) {
      double far = 0.0;
      for (const Point& p : v) far = std::max(far, CGAL::squared_distance(p, mOriginals[c.triangle]));
      bound = std::min(bound, std::sqrt(far));
    }
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

  // The radius of the smallest circle around the triangle of squared edges @p e: half the
  // longest edge when the triangle is right or obtuse, else the circumradius.
  static double enclosingRadius(std::array<double, 3> e) {
    std::sort(e.begin(), e.end());
    if (e[2] >= e[0] + e[1]) return 0.5 * std::sqrt(e[2]);
    const double a = std::sqrt(e[0]), b = std::sqrt(e[1]), c = std::sqrt(e[2]);
    const double area4 = std::sqrt(std::max((a + b + c) * (-a + b + c) * (a - b + c) * (a + b - c), 0.0));
    return area4 > 0.0 ? a * b * c / area4 : 0.5 * c;
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

}  // namespace hyb
