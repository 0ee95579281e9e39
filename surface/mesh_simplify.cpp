// meshoptimizer lives in this translation unit only (STYLE 6).
#include "surface/mesh_simplify.h"

#include <meshoptimizer.h>

#include <algorithm>
#include <iterator>
#include <tuple>
#include <cmath>
#include <cstdint>
#include <unordered_map>
#include <utility>
#include <vector>

#include "surface/mesh_ops.h"
#include "volume/core/error.h"
#include "volume/core/parallel.h"

namespace hyb {

namespace {

using Edge = std::pair<uint32_t, uint32_t>;  // vertex indices, the smaller first

// Edge @p k of triangle @p t (from its corner k to the next).
Edge edgeOf(const glm::uvec3& t, int k) { return std::minmax(t[k], t[(k + 1) % 3]); }

void sortUnique(std::vector<uint32_t>* v) {
  std::sort(v->begin(), v->end());
  v->erase(std::unique(v->begin(), v->end()), v->end());
}

// How many triangles of @p triangles use each edge, sorted by edge.
std::vector<std::pair<Edge, int>> edgeCounts(const std::vector<glm::uvec3>& triangles) {
  std::vector<Edge> edges;
  edges.reserve(3 * triangles.size());
  for (const glm::uvec3& t : triangles)
    for (int k = 0; k < 3; ++k) edges.push_back(edgeOf(t, k));
  std::sort(edges.begin(), edges.end());
  std::vector<std::pair<Edge, int>> counts;
  for (const Edge& e : edges)
    if (!counts.empty() && counts.back().first == e)
      ++counts.back().second;
    else
      counts.push_back({e, 1});
  return counts;
}

// The edges used by other than two triangles: where a surface is open (or not manifold).
std::vector<std::pair<Edge, int>> openEdges(const std::vector<glm::uvec3>& triangles) {
  std::vector<std::pair<Edge, int>> open = edgeCounts(triangles);
  std::erase_if(open, [](const auto& e) { return e.second == 2; });
  return open;
}

glm::dvec3 centroid(const TriangleMesh& mesh, const glm::uvec3& t) {
  return (glm::dvec3(mesh.vertices[t.x]) + glm::dvec3(mesh.vertices[t.y]) + glm::dvec3(mesh.vertices[t.z])) / 3.0;
}

// @p triangles (of @p mesh) simplified by meshoptimizer within @p errorMm, their border locked.
std::vector<glm::uvec3> simplifyLocked(const TriangleMesh& mesh, const std::vector<glm::uvec3>& triangles, double errorMm) {
  std::vector<uint32_t> global;  // their vertices, sorted
  for (const glm::uvec3& t : triangles) global.insert(global.end(), {t.x, t.y, t.z});
  sortUnique(&global);
  auto local = [&](uint32_t v) { return uint32_t(std::lower_bound(global.begin(), global.end(), v) - global.begin()); };
  std::vector<uint32_t> indices;
  indices.reserve(3 * triangles.size());
  for (const glm::uvec3& t : triangles) indices.insert(indices.end(), {local(t.x), local(t.y), local(t.z)});
  std::vector<float> positions;
  positions.reserve(3 * global.size());
  for (uint32_t v : global) positions.insert(positions.end(), {mesh.vertices[v].x, mesh.vertices[v].y, mesh.vertices[v].z});
  // meshoptimizer's error is relative to the sub-mesh's extent.
  const float scale = meshopt_simplifyScale(positions.data(), global.size(), 3 * sizeof(float));
  if (!(scale > 0.0f)) return triangles;
  std::vector<uint32_t> out(indices.size());
  out.resize(meshopt_simplify(out.data(), indices.data(), indices.size(), positions.data(), global.size(), 3 * sizeof(float), 0,
                              float(errorMm / double(scale)), meshopt_SimplifyLockBorder, nullptr));
  std::vector<glm::uvec3> simplified;
  simplified.reserve(out.size() / 3);
  for (size_t i = 0; i + 2 < out.size(); i += 3) simplified.push_back({global[out[i]], global[out[i + 1]], global[out[i + 2]]});
  return simplified;
}

// Adds to @p fixed the vertices of the edges that @p after, simplified from @p before, uses a
// different number of times; returns whether there were any.
bool fixChangedEdges(const std::vector<glm::uvec3>& before, const std::vector<glm::uvec3>& after, std::vector<uint32_t>* fixed) {
  std::vector<std::pair<Edge, int>> changed;
  const std::vector<std::pair<Edge, int>> a = openEdges(before), b = openEdges(after);
  std::set_symmetric_difference(a.begin(), a.end(), b.begin(), b.end(), std::back_inserter(changed));
  for (const auto& [edge, count] : changed) fixed->insert(fixed->end(), {edge.first, edge.second});
  sortUnique(fixed);
  return !changed.empty();
}

// Flips away the flat triangles of @p tris (of @p mesh's vertices), which meshoptimizer leaves
// where it collapses along a straight line (e.g. onto three locked border vertices in a line): a
// flat (a, b, c), b on the edge ca, and its neighbour (a, c, d) become (a, b, d) and (b, c, d),
// which cover exactly the neighbour (so they stay inside its block) and use every other edge as
// before. Adds to @p fixed the vertices of those it cannot flip (no neighbour, a flat neighbour, or
// an edge bd there already) and returns whether there were any.
bool flipFlatTriangles(const TriangleMesh& mesh, std::vector<glm::uvec3>* triangles, std::vector<uint32_t>* fixed) {
  std::vector<glm::uvec3>& tris = *triangles;
  auto flatCorner = [&](const glm::uvec3& t) {  // the corner opposite the longest edge of a flat t, else -1
    const glm::dvec3 p[3] = {glm::dvec3(mesh.vertices[t.x]), glm::dvec3(mesh.vertices[t.y]), glm::dvec3(mesh.vertices[t.z])};
    if (!flatTriangle(p[0], p[1], p[2])) return -1;
    int k = 0;
    for (int j = 1; j < 3; ++j)
      if (glm::length(p[(j + 2) % 3] - p[(j + 1) % 3]) > glm::length(p[(k + 2) % 3] - p[(k + 1) % 3])) k = j;
    return k;
  };
  std::unordered_map<uint64_t, uint32_t> owner;  // directed edge (from << 32 | to) -> triangle
  auto key = [](uint32_t from, uint32_t to) { return uint64_t(from) << 32 | to; };
  auto own = [&](uint32_t t, bool add) {
    for (int e = 0; e < 3; ++e) {
      const uint64_t k = key(tris[t][e], tris[t][(e + 1) % 3]);
      if (add) owner[k] = t; else owner.erase(k);
    }
  };
  for (uint32_t t = 0; t < tris.size(); ++t) own(t, true);
  const size_t before = fixed->size();
  for (uint32_t i = 0; i < tris.size(); ++i) {
    const int k = flatCorner(tris[i]);
    if (k < 0) continue;
    const uint32_t b = tris[i][k], c = tris[i][(k + 1) % 3], a = tris[i][(k + 2) % 3];  // the long edge c -> a
    const auto across = owner.find(key(a, c));
    const uint32_t j = across == owner.end() ? 0 : across->second;
    const glm::uvec3 n = tris[j];
    const uint32_t d = n.x == a ? n.z : n.y == a ? n.x : n.y;  // n is (a, c, d) rotated
    if (across == owner.end() || flatCorner(n) >= 0 || owner.count(key(b, d)) || owner.count(key(d, b))) {
      fixed->insert(fixed->end(), {a, b, c});
      continue;
    }
    own(i, false);
    own(j, false);
    tris[i] = {a, b, d};
    tris[j] = {b, c, d};
    own(i, true);
    own(j, true);
  }
  sortUnique(fixed);
  return fixed->size() != before;
}

// The edges of the blocks' triangles @p kept used by another number of triangles than in the input
// (@p counts; 2 for an edge a collapse made), with each block that uses them.
std::vector<std::pair<Edge, uint32_t>> edgesInError(const std::vector<std::vector<glm::uvec3>>& kept, const std::vector<std::pair<Edge, int>>& counts) {
  std::vector<std::pair<Edge, uint32_t>> edges;  // each edge of the result, with its block
  for (size_t b = 0; b < kept.size(); ++b)
    for (const glm::uvec3& t : kept[b])
      for (int k = 0; k < 3; ++k) edges.push_back({edgeOf(t, k), uint32_t(b)});
  std::sort(edges.begin(), edges.end());
  std::vector<std::pair<Edge, uint32_t>> bad;
  for (size_t i = 0, j = 0; i < edges.size(); i = j) {
    while (j < edges.size() && edges[j].first == edges[i].first) ++j;
    const auto in = std::lower_bound(counts.begin(), counts.end(), std::pair{edges[i].first, 0});
    if (int(j - i) != (in != counts.end() && in->first == edges[i].first ? in->second : 2)) bad.insert(bad.end(), edges.begin() + long(i), edges.begin() + long(j));
  }
  return bad;
}

// Whether the edges @p link (a vertex's link: the edges opposite it) are empty or one loop, each
// of their vertices on two of them.
bool oneLoop(std::vector<Edge> link) {
  if (link.empty()) return true;
  std::vector<uint32_t> ends;
  for (const Edge& e : link) ends.insert(ends.end(), {e.first, e.second});
  std::sort(ends.begin(), ends.end());
  for (size_t i = 0; i < ends.size(); i += 2)
    if (i + 1 >= ends.size() || ends[i] != ends[i + 1] || (i + 2 < ends.size() && ends[i + 2] == ends[i])) return false;
  // Walk the loop from the first edge: it must take in every edge.
  size_t walked = 1;
  uint32_t from = link[0].first, at = link[0].second;
  link.erase(link.begin());
  while (at != from) {
    const auto it = std::find_if(link.begin(), link.end(), [&](const Edge& e) { return e.first == at || e.second == at; });
    if (it == link.end()) return false;
    at = it->first == at ? it->second : it->first;
    link.erase(it);
    ++walked;
  }
  return link.empty() && walked > 0;
}

// A triangle of block a and its mirror image in block b (dropMirroredPairs).
struct MirroredPair {
  glm::uvec3 ta, tb;
  uint32_t a, b;
};

// Two neighbouring blocks that each collapsed onto the same three vertices of their common border
// leave a triangle and its mirror image over one another: a fin of no area between them, whose
// edges are used too often. Both triangles go (the surface is then as if neither had been made,
// its edges used as before), rather than both blocks being simplified again: on a CT's bone that
// is nearly every block. Only the triangles of @p bad edges (sorted, with their blocks) are looked
// at; the pairs dropped are added to @p dropped. Returns whether any went.
bool dropMirroredPairs(const std::vector<std::pair<Edge, uint32_t>>& bad, std::vector<std::vector<glm::uvec3>>* kept, std::vector<MirroredPair>* dropped) {
  auto isBad = [&](const Edge& e) {
    const auto it = std::lower_bound(bad.begin(), bad.end(), std::pair{e, uint32_t(0)});
    return it != bad.end() && it->first == e;
  };
  struct Candidate {
    glm::uvec3 sorted;  // its vertices, ascending
    bool parity;        // its orientation
    uint32_t block, index;
  };
  std::vector<Candidate> candidates;
  std::vector<uint32_t> blocks;  // the blocks of the bad edges, ascending
  for (const auto& e : bad) blocks.push_back(e.second);
  sortUnique(&blocks);
  for (uint32_t b : blocks)
    for (uint32_t i = 0; i < (*kept)[b].size(); ++i) {
      const glm::uvec3 t = (*kept)[b][i];
      if (!isBad(edgeOf(t, 0)) && !isBad(edgeOf(t, 1)) && !isBad(edgeOf(t, 2))) continue;
      glm::uvec3 r = t;  // rotated to start at its smallest vertex: the orientation is whether the rest ascend
      while (r.x > r.y || r.x > r.z) r = {r.y, r.z, r.x};
      candidates.push_back({{r.x, std::min(r.y, r.z), std::max(r.y, r.z)}, r.y < r.z, b, i});
    }
  auto less = [](const Candidate& a, const Candidate& b) {
    return std::tie(a.sorted.x, a.sorted.y, a.sorted.z, a.block) < std::tie(b.sorted.x, b.sorted.y, b.sorted.z, b.block);
  };
  std::sort(candidates.begin(), candidates.end(), less);
  std::vector<std::pair<const Candidate*, const Candidate*>> pairs;
  for (size_t i = 0, j = 0; i < candidates.size(); i = j) {
    while (j < candidates.size() && candidates[j].sorted == candidates[i].sorted) ++j;
    if (j - i == 2 && candidates[i].parity != candidates[i + 1].parity && candidates[i].block != candidates[i + 1].block)
      pairs.push_back({&candidates[i], &candidates[i + 1]});
  }
  // A pair is kept where dropping the pairs would leave one of its vertices' triangles in two fans
  // (two fins at one vertex: a pinch, not a surface); its blocks are then done again. A pair kept
  // is back in its corners' links, which may pinch another corner: checked again until none is.
  std::vector<uint32_t> corners;
  for (const auto& [a, b] : pairs) corners.insert(corners.end(), {a->sorted.x, a->sorted.y, a->sorted.z});
  sortUnique(&corners);
  auto corner = [&](uint32_t v) {
    const auto it = std::lower_bound(corners.begin(), corners.end(), v);
    return it != corners.end() && *it == v ? long(it - corners.begin()) : -1L;
  };
  std::vector<std::vector<uint64_t>> dropping(kept->size());  // (index) of each block's triangles in pairs
  for (const auto& [a, b] : pairs) {
    dropping[a->block].push_back(a->index);
    dropping[b->block].push_back(b->index);
  }
  for (auto& d : dropping) std::sort(d.begin(), d.end());
  std::vector<std::vector<Edge>> links(corners.size());  // each corner's link without the pairs dropped
  auto link = [&](const glm::uvec3& t) {
    for (int k = 0; k < 3; ++k)
      if (const long c = corner(t[k]); c >= 0) links[size_t(c)].push_back(edgeOf(t, (k + 1) % 3));
  };
  for (size_t b = 0; b < kept->size(); ++b)
    for (uint32_t i = 0; i < (*kept)[b].size(); ++i)
      if (!std::binary_search(dropping[b].begin(), dropping[b].end(), uint64_t(i))) link((*kept)[b][i]);
  std::vector<char> keepPair(pairs.size(), 0);
  for (bool changed = true; changed;) {
    std::vector<char> pinched(corners.size(), 0);
    for (size_t c = 0; c < corners.size(); ++c) pinched[c] = !oneLoop(links[c]);
    changed = false;
    for (size_t p = 0; p < pairs.size(); ++p) {
      const auto& [a, b] = pairs[p];
      if (keepPair[p] || !(pinched[size_t(corner(a->sorted.x))] || pinched[size_t(corner(a->sorted.y))] || pinched[size_t(corner(a->sorted.z))]))
        continue;
      keepPair[p] = changed = true;  // back in its corners' links
      link((*kept)[a->block][a->index]);
      link((*kept)[b->block][b->index]);
    }
  }
  std::vector<std::vector<uint32_t>> drop(kept->size());
  for (size_t p = 0; p < pairs.size(); ++p) {
    if (keepPair[p]) continue;
    const auto& [a, b] = pairs[p];
    drop[a->block].push_back(a->index);
    drop[b->block].push_back(b->index);
    dropped->push_back({(*kept)[a->block][a->index], (*kept)[b->block][b->index], a->block, b->block});
  }
  bool any = false;
  for (size_t b = 0; b < drop.size(); ++b) {
    if (drop[b].empty()) continue;
    sortUnique(&drop[b]);
    std::vector<glm::uvec3>& tris = (*kept)[b];
    for (size_t k = drop[b].size(); k-- > 0;) tris.erase(tris.begin() + long(drop[b][k]));
    any = true;
  }
  return any;
}

// One block's triangles simplified within @p errorMm, those touching a @p fixed vertex (sorted) kept
// as they are. meshoptimizer does not check the link condition: a collapse beside locked vertices
// can stack triangles on their edge; nor does it avoid flat triangles, which are flipped away.
// Where it stacked triangles or left a flat one that cannot be flipped, the vertices concerned are
// fixed too and the block is done again (twelve tries, then it stays as it came).
std::vector<glm::uvec3> simplifyBlock(const TriangleMesh& mesh, const std::vector<glm::uvec3>& triangles, double errorMm, std::vector<uint32_t> fixed) {
  for (int attempt = 0; attempt < 12; ++attempt) {
    std::vector<glm::uvec3> kept, free;
    for (const glm::uvec3& t : triangles) {
      const bool touches = std::binary_search(fixed.begin(), fixed.end(), t.x) || std::binary_search(fixed.begin(), fixed.end(), t.y) ||
                           std::binary_search(fixed.begin(), fixed.end(), t.z);
      (touches ? kept : free).push_back(t);
    }
    std::vector<glm::uvec3> result = simplifyLocked(mesh, free, errorMm);
    const bool changedEdges = fixChangedEdges(free, result, &fixed);
    if (!flipFlatTriangles(mesh, &result, &fixed) && !changedEdges) {
      result.insert(result.end(), kept.begin(), kept.end());
      return result;
    }
  }
  return triangles;
}

}  // namespace

TriangleMesh simplifyWithinBlocks(const TriangleMesh& mesh, const glm::dvec3& blockMm, double maxErrorMm, const Progress* progress, SimplifyStats* stats) {
  const bool blockOk = std::isfinite(blockMm.x) && std::isfinite(blockMm.y) && std::isfinite(blockMm.z) && glm::all(glm::greaterThan(blockMm, glm::dvec3(0.0)));
  if (!blockOk) HYB_THROW(ValueError, "simplification block must be a finite positive size (mm)");
  if (!(std::isfinite(maxErrorMm) && maxErrorMm > 0.0)) HYB_THROW(ValueError, "simplification error must be a finite positive distance (mm)");

  // The triangles by the block holding their centroid (21 bits a block coordinate, offset so that
  // a mesh a little outside the grid's positive octant keeps its order).
  std::vector<std::pair<uint64_t, uint32_t>> keyed(mesh.triangles.size());
  for (size_t t = 0; t < keyed.size(); ++t) {
    const glm::dvec3 b = glm::clamp(glm::floor(centroid(mesh, mesh.triangles[t]) / blockMm) + double(1 << 20), glm::dvec3(0.0), glm::dvec3((1 << 21) - 1));
    keyed[t] = {uint64_t(b.x) | uint64_t(b.y) << 21 | uint64_t(b.z) << 42, uint32_t(t)};
  }
  std::sort(keyed.begin(), keyed.end());
  std::vector<std::vector<glm::uvec3>> input;
  for (size_t t = 0; t < keyed.size(); ++t) {
    if (t == 0 || keyed[t].first != keyed[t - 1].first) input.emplace_back();
    input.back().push_back(mesh.triangles[keyed[t].second]);
  }

  // Each block on its own, then across blocks: a collapse onto a border vertex can span three of
  // them with a triangle in the block's face, and the neighbour may make one there too, over it:
  // such a pair is dropped (dropMirroredPairs). Where an edge is still used by more or fewer
  // triangles than in the input, its two vertices are fixed in the blocks that use it (triangles
  // touching them stay) and those blocks are done again; after four rounds a block still at fault
  // keeps its whole border, after five it stays as it came.
  const size_t blocks = input.size();
  std::vector<std::vector<glm::uvec3>> kept(blocks);
  std::vector<std::vector<uint32_t>> fixed(blocks);
  std::vector<char> redo(blocks, 1);
  std::vector<MirroredPair> dropped;
  const std::vector<std::pair<Edge, int>> counts = edgeCounts(mesh.triangles);
  ProgressTask task(progress, "simplified surface", blocks);
  for (int round = 0; round < 6; ++round) {
    if (round == 4)
      for (size_t b = 0; b < blocks; ++b)
        if (redo[b])
          for (const auto& [edge, count] : openEdges(input[b])) fixed[b].insert(fixed[b].end(), {edge.first, edge.second});
    for (std::vector<uint32_t>& f : fixed) sortUnique(&f);
    // A pair dropped beside a block done again comes back to the block that stays: the other may
    // not make its half again.
    size_t restored = 0;
    std::erase_if(dropped, [&](const MirroredPair& p) {
      if (!redo[p.a] && !redo[p.b]) return false;
      if (!redo[p.a]) kept[p.a].push_back(p.ta);
      if (!redo[p.b]) kept[p.b].push_back(p.tb);
      restored += !redo[p.a] || !redo[p.b];
      return true;
    });
    if (stats) stats->pairsRestored += restored;
    ParallelFailure failure;
#pragma omp parallel for schedule(dynamic)
    for (size_t b = 0; b < blocks; ++b)
      if (redo[b])
        failure.run([&] {
          kept[b] = round < 5 ? simplifyBlock(mesh, input[b], maxErrorMm, fixed[b]) : input[b];
          if (round == 0) task.advance();
        });
    failure.rethrow();
    std::vector<std::pair<Edge, uint32_t>> bad = edgesInError(kept, counts);
    if (!bad.empty() && dropMirroredPairs(bad, &kept, &dropped)) bad = edgesInError(kept, counts);
    std::fill(redo.begin(), redo.end(), 0);
    for (const auto& [edge, b] : bad) {
      redo[b] = 1;
      fixed[b].insert(fixed[b].end(), {edge.first, edge.second});
    }
    if (bad.empty()) break;
    if (stats && round < 5) stats->blocksRedone += size_t(std::count(redo.begin(), redo.end(), 1));
  }
  if (stats) {
    stats->blocks = blocks;
    stats->mirroredPairs = dropped.size();
  }

  TriangleMesh result;
  result.vertices = mesh.vertices;
  for (const std::vector<glm::uvec3>& k : kept) result.triangles.insert(result.triangles.end(), k.begin(), k.end());
  removeUnreferencedVertices(&result);
  return result;
}

}  // namespace hyb
