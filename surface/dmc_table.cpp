// Derivation of the Discretized Marching Cubes table: Montani, Scateni and Scopigno,
// "Discretized Marching Cubes", Visualization '94, with face-consistent loops (docs/surface.md).
#include "surface/dmc_table.h"

#include <algorithm>
#include <functional>
#include <map>
#include <set>

#include "volume/core/error.h"

namespace hyb::dmc {

namespace {

// Edges: along axis a, the corner pairs (c, c | 1<<a) with bit a of c clear, in increasing c.
std::array<std::array<int, 2>, 12> makeEdges() {
  std::array<std::array<int, 2>, 12> e{};
  int n = 0;
  for (int axis = 0; axis < 3; ++axis)
    for (int c = 0; c < 8; ++c)
      if (!(c & (1 << axis))) e[size_t(n++)] = {c, c | (1 << axis)};
  return e;
}
const std::array<std::array<int, 2>, 12> kEdges = makeEdges();

int edgeBetween(int a, int b) {
  for (int e = 0; e < 12; ++e)
    if ((kEdges[size_t(e)][0] == a && kEdges[size_t(e)][1] == b) || (kEdges[size_t(e)][0] == b && kEdges[size_t(e)][1] == a))
      return e;
  HYB_CHECK(false);
  return -1;
}

struct Face {
  std::array<int, 4> corners;  // cyclic
  glm::ivec3 normal;           // outward
};

std::array<Face, 6> makeFaces() {
  std::array<Face, 6> faces{};
  int n = 0;
  for (int axis = 0; axis < 3; ++axis)
    for (int side = 0; side < 2; ++side) {
      const int u = (axis + 1) % 3, v = (axis + 2) % 3;
      Face f;
      const int base = side << axis;
      f.corners = {base, base | (1 << u), base | (1 << u) | (1 << v), base | (1 << v)};
      f.normal = glm::ivec3(0);
      f.normal[axis] = side ? 1 : -1;
      faces[size_t(n++)] = f;
    }
  return faces;
}
const std::array<Face, 6> kFaces = makeFaces();

// Step 1: directed loops of edge ids.
std::vector<std::vector<uint8_t>> buildLoops(int mask) {
  auto inside = [mask](int c) { return (mask >> c) & 1; };
  std::array<int, 12> next;
  next.fill(-1);
  for (const Face& f : kFaces) {
    std::array<int, 4> fe;
    int crossed = 0;
    for (int i = 0; i < 4; ++i) {
      fe[size_t(i)] = edgeBetween(f.corners[size_t(i)], f.corners[size_t((i + 1) % 4)]);
      crossed += inside(f.corners[size_t(i)]) != inside(f.corners[size_t((i + 1) % 4)]);
    }
    std::vector<std::array<int, 2>> segments;
    if (crossed == 2) {
      std::array<int, 2> s{};
      int k = 0;
      for (int i = 0; i < 4; ++i)
        if (inside(f.corners[size_t(i)]) != inside(f.corners[size_t((i + 1) % 4)])) s[size_t(k++)] = fe[size_t(i)];
      segments.push_back(s);
    } else if (crossed == 4) {
      // Ambiguous face: cut off each outside corner (inside corners stay connected).
      for (int i = 0; i < 4; ++i)
        if (!inside(f.corners[size_t(i)])) segments.push_back({fe[size_t((i + 3) % 4)], fe[size_t(i)]});
    }
    for (auto [p, q] : segments) {
      // Direct p -> q so that (d × N)·(c_in − P) > 0, c_in the inside corner of edge p.
      auto orientedOk = [&](int a, int b) {
        const glm::ivec3 P = edgeMidpoint(a), d = edgeMidpoint(b) - P;
        const int cin = inside(kEdges[size_t(a)][0]) ? kEdges[size_t(a)][0] : kEdges[size_t(a)][1];
        return idot(icross(d, f.normal), cornerPosition(cin) - P) > 0;
      };
      if (!orientedOk(p, q)) std::swap(p, q);
      HYB_CHECK(orientedOk(p, q));
      HYB_CHECK(next[size_t(p)] == -1);
      next[size_t(p)] = q;
    }
  }
  std::vector<std::vector<uint8_t>> loops;
  std::array<bool, 12> used{};
  for (int start = 0; start < 12; ++start) {
    if (next[size_t(start)] < 0 || used[size_t(start)]) continue;
    std::vector<uint8_t> loop;
    for (int e = start; !used[size_t(e)]; e = next[size_t(e)]) {
      used[size_t(e)] = true;
      loop.push_back(uint8_t(e));
      HYB_CHECK(next[size_t(e)] >= 0);
    }
    loops.push_back(std::move(loop));
  }
  return loops;
}

// A triangle of a loop (positions into the loop) with its plane, or invalid.
struct Tri {
  std::array<int, 3> v;
  PlaneId plane;
};

// Which diagonals (non-loop edges between two midpoints of one cube face) a triangulation may use.
enum class Diagonals {
  None,         // none: the preferred triangulations
  CornerCut,    // one cutting off an inside corner of an ambiguous face (a fold touching the face)
  Centre,       // one through the centre of an ambiguous face (the alternative of a fold)
};

// True when midpoints of edges ea, eb (on one face) cut off a corner, i.e. share a face corner.
bool cutsCorner(int ea, int eb) {
  const auto a = kEdges[size_t(ea)], b = kEdges[size_t(eb)];
  return a[0] == b[0] || a[0] == b[1] || a[1] == b[0] || a[1] == b[1];
}

// Face index (into kFaces) that contains both points, or -1.
int commonFace(const glm::ivec3& a, const glm::ivec3& b) {
  for (int axis = 0; axis < 3; ++axis)
    if (a[axis] == b[axis] && (a[axis] == 0 || a[axis] == 2)) return 2 * axis + (a[axis] == 2 ? 1 : 0);
  return -1;
}

bool makeTri(const std::vector<uint8_t>& loop, int i, int j, int k, Diagonals diagonals, Tri* out) {
  const int n = int(loop.size());
  const glm::ivec3 A = edgeMidpoint(loop[size_t(i)]), B = edgeMidpoint(loop[size_t(j)]), C = edgeMidpoint(loop[size_t(k)]);
  int sign = 0;
  const int o = orientationOf(icross(B - A, C - A), &sign);
  if (o < 0) return false;  // degenerate or not one of the 13 orientations
  for (int axis = 0; axis < 3; ++axis)
    if (A[axis] == B[axis] && B[axis] == C[axis] && (A[axis] == 0 || A[axis] == 2)) return false;  // in a cube face
  auto isLoopEdge = [n](int a, int b) { return (a + 1) % n == b || (b + 1) % n == a; };
  const std::array<std::array<int, 2>, 3> sides = {{{i, j}, {j, k}, {k, i}}};
  for (auto [a, b] : sides) {
    if (isLoopEdge(a, b)) continue;
    const int ea = loop[size_t(a)], eb = loop[size_t(b)];
    const int f = commonFace(edgeMidpoint(ea), edgeMidpoint(eb));
    if (f < 0) continue;
    if (diagonals == Diagonals::None || cutsCorner(ea, eb) != (diagonals == Diagonals::CornerCut)) return false;
  }
  out->v = {i, j, k};
  out->plane = PlaneId{int8_t(o), int8_t(sign), 0};
  out->plane.d = idot(out->plane.normal(), A);
  return true;
}

// Step 2a: all valid triangulations of one loop (vertex positions i..j of the loop, i < j).
using Triangulation = std::vector<Tri>;
std::vector<Triangulation> triangulations(const std::vector<uint8_t>& loop, Diagonals diagonals) {
  const int n = int(loop.size());
  std::map<std::pair<int, int>, std::vector<Triangulation>> memo;
  std::function<const std::vector<Triangulation>&(int, int)> solve = [&](int i, int j) -> const std::vector<Triangulation>& {
    const auto key = std::make_pair(i, j);
    if (const auto it = memo.find(key); it != memo.end()) return it->second;
    std::vector<Triangulation> result;
    if (j - i < 2) {
      result.push_back({});
    } else {
      for (int k = i + 1; k < j; ++k) {
        Tri t;
        if (!makeTri(loop, i, k, j, diagonals, &t)) continue;
        const auto left = solve(i, k);  // copies: the memo may rehash
        const auto right = solve(k, j);
        for (const auto& l : left)
          for (const auto& r : right) {
            Triangulation tr = l;
            tr.insert(tr.end(), r.begin(), r.end());
            tr.push_back(t);
            result.push_back(std::move(tr));
          }
      }
    }
    return memo[key] = std::move(result);
  };
  return solve(0, n - 1);
}

std::set<PlaneId> planesOf(const Triangulation& t) {
  std::set<PlaneId> s;
  for (const Tri& x : t) s.insert(x.plane);
  return s;
}

// Step 3: boundary loops of a set of triangles (edge-id vertices), consistently oriented.
std::vector<std::vector<uint8_t>> mergeTriangles(const std::vector<std::array<uint8_t, 3>>& tris) {
  std::map<std::pair<int, int>, int> directed;
  for (const auto& t : tris)
    for (int s = 0; s < 3; ++s) ++directed[{t[size_t(s)], t[size_t((s + 1) % 3)]}];
  std::map<int, int> next;
  for (const auto& [e, count] : directed)
    if (!directed.count({e.second, e.first})) {
      HYB_CHECK(count == 1 && !next.count(e.first));
      next[e.first] = e.second;
    }
  std::vector<std::vector<uint8_t>> loops;
  while (!next.empty()) {
    std::vector<uint8_t> loop;
    int v = next.begin()->first;
    while (next.count(v)) {
      loop.push_back(uint8_t(v));
      const int w = next[v];
      next.erase(v);
      v = w;
    }
    loops.push_back(std::move(loop));
  }
  return loops;
}

// The fold of a triangulation: the face diagonal it uses (unordered edge pair), if any.
std::array<int, 2> foldOf(const std::vector<uint8_t>& loop, const Triangulation& t) {
  const int n = int(loop.size());
  for (const Tri& x : t)
    for (int s = 0; s < 3; ++s) {
      const int a = x.v[size_t(s)], b = x.v[size_t((s + 1) % 3)];
      if ((a + 1) % n == b || (b + 1) % n == a) continue;
      const int ea = loop[size_t(a)], eb = loop[size_t(b)];
      if (commonFace(edgeMidpoint(ea), edgeMidpoint(eb)) >= 0) return {std::min(ea, eb), std::max(ea, eb)};
    }
  return {-1, -1};
}

// @p fold selects the fallback kind for loops without a plain triangulation.
Case deriveCase(int mask, Diagonals fold) {
  Case c;
  c.loops = buildLoops(mask);
  if (c.loops.empty()) return c;
  std::vector<std::vector<Triangulation>> options;
  for (const auto& loop : c.loops) {
    // Prefer triangulations without diagonals in a cube face; 24 loops have none and need one.
    options.push_back(triangulations(loop, Diagonals::None));
    if (options.back().empty()) options.back() = triangulations(loop, fold);
    if (options.back().empty()) {  // unsolved: caught by the stats
      Case unsolved;
      unsolved.loops = c.loops;
      return unsolved;
    }
  }
  // Fewest distinct planes over the product of the loops' options.
  std::vector<size_t> choice(options.size(), 0), best;
  size_t bestPlanes = SIZE_MAX;
  std::function<void(size_t, std::set<PlaneId>)> search = [&](size_t l, std::set<PlaneId> planes) {
    if (planes.size() >= bestPlanes) return;
    if (l == options.size()) {
      bestPlanes = planes.size();
      best = choice;
      return;
    }
    for (size_t o = 0; o < options[l].size(); ++o) {
      choice[l] = o;
      std::set<PlaneId> p = planes;
      const auto add = planesOf(options[l][o]);
      p.insert(add.begin(), add.end());
      search(l + 1, std::move(p));
    }
  };
  search(0, {});
  std::map<PlaneId, uint8_t> planeIndex;
  for (size_t l = 0; l < c.loops.size(); ++l) {
    if (const auto f = foldOf(c.loops[l], options[l][best[l]]); f[0] >= 0) c.fold = {uint8_t(f[0]), uint8_t(f[1])};
    for (const Tri& t : options[l][best[l]]) {
      if (!planeIndex.count(t.plane)) {
        planeIndex[t.plane] = uint8_t(c.planes.size());
        c.planes.push_back(t.plane);
      }
      c.triangles.push_back({c.loops[l][size_t(t.v[0])], c.loops[l][size_t(t.v[1])], c.loops[l][size_t(t.v[2])]});
      c.trianglePlane.push_back(planeIndex[t.plane]);
    }
  }
  for (uint8_t p = 0; p < c.planes.size(); ++p) {
    std::vector<std::array<uint8_t, 3>> onPlane;
    for (size_t t = 0; t < c.triangles.size(); ++t)
      if (c.trianglePlane[t] == p) onPlane.push_back(c.triangles[t]);
    for (auto& loop : mergeTriangles(onPlane)) c.polygons.push_back(CasePolygon{p, std::move(loop)});
  }
  return c;
}

}  // namespace

std::array<int, 2> edgeCorners(int e) { return kEdges[size_t(e)]; }

glm::ivec3 edgeMidpoint(int e) { return (cornerPosition(kEdges[size_t(e)][0]) + cornerPosition(kEdges[size_t(e)][1])) / 2; }

const std::array<Case, 256>& caseTable() {
  static const std::array<Case, 256> table = [] {
    std::array<Case, 256> t;
    for (int m = 0; m < 256; ++m) t[size_t(m)] = deriveCase(m, Diagonals::CornerCut);
    return t;
  }();
  return table;
}

const std::array<Case, 256>& alternativeCaseTable() {
  static const std::array<Case, 256> table = [] {
    std::array<Case, 256> t;
    for (int m = 0; m < 256; ++m)
      if (caseTable()[size_t(m)].hasFold()) t[size_t(m)] = deriveCase(m, Diagonals::Centre);
    return t;
  }();
  return table;
}

CaseTableStats caseTableStats() {
  CaseTableStats s;
  const auto& table = caseTable();
  for (int m = 1; m < 255; ++m) {
    const Case& c = table[size_t(m)];
    if (c.triangles.empty()) continue;
    ++s.solved;
    ++s.byPlaneCount[std::min<size_t>(4, c.planes.size())];
    for (const auto& l : c.loops) s.maxLoopSize = std::max(s.maxLoopSize, int(l.size()));
    s.maxPolygonsPerCell = std::max(s.maxPolygonsPerCell, int(c.polygons.size()));
  }
  return s;
}

}  // namespace hyb::dmc
