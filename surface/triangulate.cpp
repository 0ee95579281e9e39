#include "surface/triangulate.h"

#include <algorithm>
#include <cstdint>
#include <cstdlib>

namespace hyb {

namespace {
struct P2 {
  int64_t x, y;
};
int64_t orient(const P2& a, const P2& b, const P2& c) { return (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x); }
// True when p lies inside or on the boundary of the counter-clockwise triangle abc.
bool inTriangle(const P2& a, const P2& b, const P2& c, const P2& p) {
  return orient(a, b, p) >= 0 && orient(b, c, p) >= 0 && orient(c, a, p) >= 0;
}
// The polygon projected along the dominant axis of its normal, keeping counter-clockwise order.
std::vector<P2> project(const std::vector<glm::ivec3>& points, const uint32_t* loop, size_t n, const glm::ivec3& normal) {
  int axis = 0;
  for (int a = 1; a < 3; ++a)
    if (std::abs(normal[a]) > std::abs(normal[axis])) axis = a;
  const int u = (axis + 1) % 3, v = (axis + 2) % 3;
  const bool flip = normal[axis] < 0;
  std::vector<P2> p(n);
  for (size_t i = 0; i < n; ++i) {
    const glm::ivec3& q = points[loop[i]];
    p[i] = flip ? P2{q[v], q[u]} : P2{q[u], q[v]};
  }
  return p;
}

using I3 = std::array<int64_t, 3>;
I3 cross(const I3& a, const I3& b) { return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]}; }
int64_t dot(const I3& a, const I3& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

// The metric of the plane with integer normal n, made once a polygon: u = n × e and v = n × u
// (integer, orthogonal, u × v along n), so that a point has plane coordinates (p·u/|u|, p·v/|v|).
struct PlaneMetric {
  I3 u, v;
  __int128 uu, vv;  // |u|², |v|²
  explicit PlaneMetric(const glm::ivec3& n) {
    int axis = 0;  // e: the axis along which n is smallest, so that n × e is not zero
    for (int k = 1; k < 3; ++k)
      if (std::abs(n[k]) < std::abs(n[axis])) axis = k;
    I3 e{0, 0, 0};
    e[size_t(axis)] = 1;
    u = cross({n.x, n.y, n.z}, e);
    v = cross({n.x, n.y, n.z}, u);
    uu = dot(u, u);
    vv = dot(v, v);
  }
};

// Whether point d lies strictly inside the circle through the counter-clockwise triangle abc, all
// four in the polygon's plane, measured in that plane's own metric — not the dominant-axis
// projection, which stretches the diagonal planes by √2 in one direction. The usual lifted
// determinant in the coordinates of @p plane, scaled by the positive |u|³|v|³, is exact in
// integers (128 bits: the coordinates of a 2^15-voxel grid stay far below overflow).
bool inCircle(const PlaneMetric& plane, const glm::ivec3& a, const glm::ivec3& b, const glm::ivec3& c, const glm::ivec3& d) {
  const auto& [u, v, uu, vv] = plane;
  __int128 m[3][3];
  const glm::ivec3* rows[3] = {&a, &b, &c};
  for (int r = 0; r < 3; ++r) {
    const I3 q{int64_t(rows[r]->x) - d.x, int64_t(rows[r]->y) - d.y, int64_t(rows[r]->z) - d.z};
    const __int128 x = dot(q, u), y = dot(q, v);
    m[r][0] = x;
    m[r][1] = y;
    m[r][2] = x * x * vv + y * y * uu;  // (x² / uu + y² / vv) · uu·vv
  }
  const __int128 det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
                       m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
  // (x, y) is right-handed about n (u × v points along n), as a, b, c are counter-clockwise.
  return det > 0;
}

// Lawson's flips on the triangles @p tris (local indices into the loop @p p, counter-clockwise)
// of one polygon: an interior edge whose opposite corner lies inside the other triangle's
// circumcircle is replaced by the other diagonal, when the two triangles form a strictly convex
// quadrilateral, until none is left. The result is the polygon's constrained Delaunay
// triangulation (its edges never flip): the most nearly equilateral triangles its corners allow.
void delaunayFlips(const std::vector<glm::ivec3>& points, const uint32_t* loop, const std::vector<P2>& p, const glm::ivec3& n,
                   std::vector<std::array<size_t, 3>>* tris) {
  constexpr size_t kNone = SIZE_MAX;
  std::vector<std::array<size_t, 3>>& T = *tris;
  const PlaneMetric plane(n);
  // nb[t][k]: the triangle across edge (T[t][k], T[t][k+1]), from one sort of the edges.
  std::vector<std::array<size_t, 3>> nb(T.size(), {kNone, kNone, kNone});
  std::vector<std::array<size_t, 3>> sides;  // an edge's smaller corner, larger corner, 3 t + k
  std::vector<std::array<size_t, 2>> todo;   // (t, k): edges to look at
  sides.reserve(3 * T.size());
  for (size_t t = 0; t < T.size(); ++t)
    for (size_t k = 0; k < 3; ++k) sides.push_back({std::min(T[t][k], T[t][(k + 1) % 3]), std::max(T[t][k], T[t][(k + 1) % 3]), 3 * t + k});
  std::sort(sides.begin(), sides.end());
  for (size_t i = 0; i + 1 < sides.size(); ++i)
    if (sides[i][0] == sides[i + 1][0] && sides[i][1] == sides[i + 1][1]) {
      const size_t e0 = sides[i][2], e1 = sides[i + 1][2];
      nb[e0 / 3][e0 % 3] = e1 / 3;
      nb[e1 / 3][e1 % 3] = e0 / 3;
      todo.push_back({e0 / 3, e0 % 3});
    }
  auto repoint = [&](size_t t, size_t from, size_t to) {  // t's neighbour @p from is now @p to
    if (t == kNone) return;
    for (size_t& x : nb[t])
      if (x == from) x = to;
  };
  const size_t maxFlips = 4 * T.size() * T.size() + 16;  // Lawson's flips end after O(n²); a guard
  for (size_t flips = 0; !todo.empty() && flips < maxFlips;) {
    const auto [t0, k0] = todo.back();
    todo.pop_back();
    const size_t t1 = nb[t0][k0];
    if (t1 == kNone) continue;
    // t0 = (a, b, c) and t1 = (b, a, d) share the edge a-b.
    const size_t a = T[t0][k0], b = T[t0][(k0 + 1) % 3], c = T[t0][(k0 + 2) % 3];
    size_t k1 = 0;
    while (k1 < 3 && !(T[t1][k1] == b && T[t1][(k1 + 1) % 3] == a)) ++k1;
    if (k1 == 3) continue;
    const size_t d = T[t1][(k1 + 2) % 3];
    if (orient(p[c], p[a], p[d]) <= 0 || orient(p[d], p[b], p[c]) <= 0) continue;  // not strictly convex
    if (!inCircle(plane, points[loop[a]], points[loop[b]], points[loop[c]], points[loop[d]])) continue;
    const size_t nbc = nb[t0][(k0 + 1) % 3], nca = nb[t0][(k0 + 2) % 3], nad = nb[t1][(k1 + 1) % 3], ndb = nb[t1][(k1 + 2) % 3];
    T[t0] = {c, a, d};
    nb[t0] = {nca, nad, t1};
    T[t1] = {d, b, c};
    nb[t1] = {ndb, nbc, t0};
    repoint(nad, t1, t0);
    repoint(nbc, t0, t1);
    // The quadrilateral's sides may now fail against the triangles beyond them.
    todo.insert(todo.end(), {{t0, 0}, {t0, 1}, {t1, 0}, {t1, 1}});
    ++flips;
  }
}

}  // namespace

bool triangulatePolygon(const std::vector<glm::ivec3>& points, const uint32_t* loop, size_t n, const glm::ivec3& normal,
                        std::vector<std::array<uint32_t, 3>>* out) {
  if (n < 3) return false;
  const std::vector<P2> p = project(points, loop, n, normal);
  std::vector<size_t> idx(n);
  for (size_t i = 0; i < n; ++i) idx[i] = i;
  std::vector<std::array<size_t, 3>> tris;  // local indices
  tris.reserve(n - 2);
  size_t guard = 0;
  while (idx.size() > 3) {
    bool clipped = false;
    const size_t m = idx.size();
    for (size_t k = 0; k < m; ++k) {
      const size_t ia = idx[(k + m - 1) % m], ib = idx[k], ic = idx[(k + 1) % m];
      if (orient(p[ia], p[ib], p[ic]) <= 0) continue;  // reflex or collinear: not an ear
      bool empty = true;
      for (size_t t = 0; t < m && empty; ++t) {
        const size_t iq = idx[t];
        if (iq == ia || iq == ib || iq == ic) continue;
        if ((p[iq].x == p[ia].x && p[iq].y == p[ia].y) || (p[iq].x == p[ic].x && p[iq].y == p[ic].y)) continue;
        if (inTriangle(p[ia], p[ib], p[ic], p[iq])) empty = false;
      }
      if (!empty) continue;
      tris.push_back({ia, ib, ic});
      idx.erase(idx.begin() + ptrdiff_t(k));
      clipped = true;
      break;
    }
    if (!clipped) {
      // Only collinear remainders are left: drop one vertex that lies between its neighbours.
      bool dropped = false;
      for (size_t k = 0; k < m && !dropped; ++k)
        if (orient(p[idx[(k + m - 1) % m]], p[idx[k]], p[idx[(k + 1) % m]]) == 0) {
          idx.erase(idx.begin() + ptrdiff_t(k));
          dropped = true;
        }
      if (!dropped || ++guard > n) return false;
    }
  }
  if (orient(p[idx[0]], p[idx[1]], p[idx[2]]) > 0) tris.push_back({idx[0], idx[1], idx[2]});
  // Ear clipping fans a large polygon from one corner into slivers across its whole length; the
  // flips make them as round as the corners allow (docs/surface.md).
  if (tris.size() > 1) delaunayFlips(points, loop, p, normal, &tris);
  for (const auto& t : tris) out->push_back({loop[t[0]], loop[t[1]], loop[t[2]]});
  return true;
}

}  // namespace hyb
