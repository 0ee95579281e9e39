#include "surface/triangulate.h"

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
}  // namespace

bool triangulatePolygon(const std::vector<glm::ivec3>& points, const uint32_t* loop, size_t n, const glm::ivec3& normal,
                        std::vector<std::array<uint32_t, 3>>* out) {
  if (n < 3) return false;
  const std::vector<P2> p = project(points, loop, n, normal);
  std::vector<size_t> idx(n);
  for (size_t i = 0; i < n; ++i) idx[i] = i;
  const size_t start = out->size();
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
      out->push_back({loop[ia], loop[ib], loop[ic]});
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
      if (!dropped || ++guard > n) {
        out->resize(start);
        return false;
      }
    }
  }
  if (orient(p[idx[0]], p[idx[1]], p[idx[2]]) > 0) out->push_back({loop[idx[0]], loop[idx[1]], loop[idx[2]]});
  return true;
}

bool isConvex(const std::vector<glm::ivec3>& points, const uint32_t* loop, size_t n, const glm::ivec3& normal) {
  if (n < 3) return false;
  const std::vector<P2> p = project(points, loop, n, normal);
  bool left = false, right = false;
  for (size_t i = 0; i < n; ++i) {
    const int64_t side = orient(p[(i + n - 1) % n], p[i], p[(i + 1) % n]);
    left = left || side > 0;
    right = right || side < 0;
  }
  return left != right;
}

}  // namespace hyb
