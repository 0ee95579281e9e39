#include "hybrid_octree/coarse_surface.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <numeric>

#include "surface/dmc.h"
#include "surface/dmc_table.h"
#include "surface/flat_map.h"
#include "volume/core/error.h"
#include "volume/core/parallel.h"

namespace hyb {

namespace {

// Widens [*mn, *mx] to hold every sample of the voxel box [lo, hi] (inclusive), from the nodes of
// subtree @p i inside the box and the leaves across its faces (their closed boxes: a superset).
void rangeIn(const VolumeOctree& t, uint32_t i, const glm::ivec3& lo, const glm::ivec3& hi, float* mn, float* mx) {
  const OctreeNode& n = t.nodes()[i];
  glm::ivec3 nlo, nhi;
  t.voxelBox(n, &nlo, &nhi);
  if (glm::any(glm::greaterThan(nlo, hi)) || glm::any(glm::lessThan(nhi, lo))) return;
  if (n.isLeaf() || (glm::all(glm::greaterThanEqual(nlo, lo)) && glm::all(glm::lessThanEqual(nhi, hi)))) {
    *mn = std::min(*mn, n.minValue);
    *mx = std::max(*mx, n.maxValue);
    return;
  }
  uint32_t child = n.firstChild;
  for (int slot = 0; slot < 8; ++slot)
    if (n.childMask >> slot & 1) rangeIn(t, child++, lo, hi, mn, mx);
}

// What the vertices clustered into one cube add up to: area-weighted positions and the gradient's
// unit normals, summed as they are (outward) and as their outer products (whose principal axis is
// the normal's line whatever the signs: the two faces of a sheet thinner than the cube add up
// there instead of cancelling, in any order of summation).
struct Cluster {
  glm::dvec3 position{0.0};
  double weight = 0.0;
  glm::vec3 outward{0.0f};
  float magnitude = 0.0f;  // of the unit normals summed, area-weighted
  std::array<float, 6> outer{};  // xx, xy, xz, yy, yz, zz
  void add(const glm::dvec3& p, double w, const glm::vec3& n) {  // n: unit, or 0 where the gradient vanishes
    position += w * p;
    weight += w;
    const float a = float(w);
    outward += a * n;
    magnitude += a * glm::length(n);
    const std::array<float, 6> o{n.x * n.x, n.x * n.y, n.x * n.z, n.y * n.y, n.y * n.z, n.z * n.z};
    for (size_t k = 0; k < 6; ++k) outer[k] += a * o[k];
  }
  void add(const Cluster& c) {
    position += c.position;
    weight += c.weight;
    outward += c.outward;
    magnitude += c.magnitude;
    for (size_t k = 0; k < 6; ++k) outer[k] += c.outer[k];
  }
  // Outward where the normals agree; else the outer products' principal axis (power iteration from
  // their largest column), its sign left to orientNormals.
  glm::vec3 normal() const {
    if (glm::length(outward) > 0.5f * magnitude && magnitude > 0.0f) return glm::normalize(outward);
    const glm::mat3 m(outer[0], outer[1], outer[2], outer[1], outer[3], outer[4], outer[2], outer[4], outer[5]);
    glm::vec3 v = m[0];
    if (glm::length(m[1]) > glm::length(v)) v = m[1];
    if (glm::length(m[2]) > glm::length(v)) v = m[2];
    for (int i = 0; i < 16 && glm::length(v) > 0.0f; ++i) v = glm::normalize(m * v);
    return glm::length(v) > 0.0f ? v : glm::vec3(0, 0, 1);
  }
};

// Turns @p mesh's vertex normals so that the corners of each triangle agree in sign (two-sided
// shading ignores the sign, but opposed corners would interpolate through zero, a dark band):
// breadth first over shared triangles from each vertex not reached yet.
void orientNormals(TriangleMesh* mesh) {
  const size_t n = mesh->vertices.size();
  std::vector<uint32_t> first(n + 1, 0), tris(3 * mesh->triangles.size());  // the triangles of each vertex
  for (const glm::uvec3& t : mesh->triangles)
    for (int k = 0; k < 3; ++k) ++first[t[k] + 1];
  for (size_t v = 0; v < n; ++v) first[v + 1] += first[v];
  std::vector<uint32_t> fill(first.begin(), first.end() - 1);
  for (uint32_t i = 0; i < mesh->triangles.size(); ++i)
    for (int k = 0; k < 3; ++k) tris[fill[mesh->triangles[i][k]]++] = i;
  std::vector<uint8_t> reached(n, 0);
  std::vector<uint32_t> queue;
  for (uint32_t seed = 0; seed < n; ++seed) {
    if (reached[seed]) continue;
    reached[seed] = 1;
    queue.assign(1, seed);
    for (size_t q = 0; q < queue.size(); ++q) {
      const uint32_t u = queue[q];
      for (uint32_t k = first[u]; k < first[u + 1]; ++k)
        for (int c = 0; c < 3; ++c) {
          const uint32_t w = mesh->triangles[tris[k]][c];
          if (reached[w]) continue;
          reached[w] = 1;
          if (glm::dot(mesh->normals[w], mesh->normals[u]) < 0.0f) mesh->normals[w] = -mesh->normals[w];
          queue.push_back(w);
        }
    }
  }
}

// Gives each triangle corners whose normals agree with its plane's side (a vertex whose normal
// does not, in some of its triangles, gets a copy with the normal turned for them): what
// orientNormals leaves opposed (a crease, the two tables of a bone thinner than a cube joined by a
// triangle, where its fronts meet) would otherwise interpolate through zero inside the triangle,
// a dark speck or line.
void splitOpposedCorners(TriangleMesh* mesh) {
  std::vector<uint32_t> turned(mesh->vertices.size(), UINT32_MAX);  // each vertex's copy with its normal turned
  for (glm::uvec3& t : mesh->triangles) {
    const glm::vec3 n0 = mesh->normals[t.x], n1 = mesh->normals[t.y], n2 = mesh->normals[t.z];
    if (glm::dot(n0, n1) >= 0.0f && glm::dot(n1, n2) >= 0.0f && glm::dot(n0, n2) >= 0.0f) continue;
    glm::vec3 side = glm::cross(mesh->vertices[t.y] - mesh->vertices[t.x], mesh->vertices[t.z] - mesh->vertices[t.x]);
    if (!(glm::dot(side, side) > 0.0f)) side = n0;  // a degenerate triangle: its first corner's side
    for (int k = 0; k < 3; ++k) {
      if (glm::dot(mesh->normals[t[k]], side) >= 0.0f) continue;
      if (turned[t[k]] == UINT32_MAX) {
        turned[t[k]] = uint32_t(mesh->vertices.size());
        const glm::vec3 p = mesh->vertices[t[k]], n = mesh->normals[t[k]];
        mesh->vertices.push_back(p);
        mesh->normals.push_back(-n);
      }
      t[k] = turned[t[k]];
    }
  }
}

// One block's share: the clusters its vertices fall in (with their cubes' keys) and its triangles
// over them, each once per orientation.
struct BlockClusters {
  std::vector<uint64_t> keys;
  std::vector<Cluster> clusters;
  std::vector<glm::uvec3> triangles;
};

// @p t rotated to start at its smallest index: one form per orientation.
glm::uvec3 canonical(const glm::uvec3& t) {
  if (t.y < t.x && t.y < t.z) return {t.y, t.z, t.x};
  if (t.z < t.x && t.z < t.y) return {t.z, t.x, t.y};
  return t;
}
bool lexLess(const glm::uvec3& a, const glm::uvec3& b) { return a.x != b.x ? a.x < b.x : a.y != b.y ? a.y < b.y : a.z < b.z; }

// Sorts and removes repeated triangles.
void unique(std::vector<glm::uvec3>* triangles) {
  std::sort(triangles->begin(), triangles->end(), lexLess);
  triangles->erase(std::unique(triangles->begin(), triangles->end()), triangles->end());
}

// What clusteredSurface asks of each block.
struct ClusterJob {
  const KnotSource& knots;
  const VolumeOctree& octree;
  int s;
  float iso;
  glm::ivec3 cubes;  // cluster cubes per axis
  double minWeight;  // what a corner weighs beyond its area: a cluster of degenerate triangles still has a mean
};

// The Marching Cubes triangles of the cells [lo, lo + n − 1) (their corners' samples read with the
// neighbour either side a gradient needs), a leaf's box at a time, the boxes the isovalue cannot
// cross skipped; their corners clustered into @p out, their triangles of three clusters kept once.
void clusterBlock(const ClusterJob& job, const glm::ivec3& lo, const glm::ivec3& n, BlockClusters* out) {
  const glm::ivec3 dims = job.knots.dims();
  const glm::dvec3 spacing = job.knots.spacing();
  const glm::ivec3 rlo = glm::max(lo - 1, glm::ivec3(0)), rn = glm::min(lo + n, dims - 1) - rlo + 1;
  std::vector<float> values(size_t(rn.x) * size_t(rn.y) * size_t(rn.z));
  job.knots.read(1, rlo, rn, values.data(), nullptr);
  auto sample = [&](int x, int y, int z) { return values[size_t(x - rlo.x) + size_t(rn.x) * (size_t(y - rlo.y) + size_t(rn.y) * size_t(z - rlo.z))]; };
  auto at = [&](const glm::ivec3& p) { return sample(lo.x + p.x, lo.y + p.y, lo.z + p.z); };
  // The outward normal on the edge from a to a + d, as Volume::sampleGradient's (zero where it vanishes).
  auto normalAt = [&](const glm::ivec3& a, const glm::ivec3& d, float t) {
    const glm::vec3 g = glm::mix(centralDifferences(lo + a, dims, spacing, sample), centralDifferences(lo + a + d, dims, spacing, sample), t);
    const float len = glm::length(g);
    return len > 0.0f && std::isfinite(len) ? -g / len : glm::vec3(0.0f);
  };
  FlatMap local(256);
  auto cluster = [&](const glm::dvec3& voxel) {
    const glm::ivec3 c = glm::min(glm::ivec3(glm::floor(voxel / double(job.s))), job.cubes - 1);
    const uint64_t key = uint64_t(c.x) + uint64_t(job.cubes.x) * (uint64_t(c.y) + uint64_t(job.cubes.y) * uint64_t(c.z));
    return local.findOrInsert(key, [&] {
      out->keys.push_back(key);
      out->clusters.emplace_back();
      return uint32_t(out->clusters.size() - 1);
    });
  };
  const auto& table = dmc::caseTable();
  std::array<glm::dvec3, 12> corner;
  std::array<glm::vec3, 12> normal;
  auto triangulate = [&](const glm::ivec3& base) {
    unsigned mask = 0;
    for (int c = 0; c < 8; ++c)
      if (at(base + dmc::cornerPosition(c) / 2) >= job.iso) mask |= 1u << c;
    for (const auto& loop : table[mask].loops) {
      for (size_t v = 0; v < loop.size(); ++v) {
        const auto [ca, cb] = dmc::edgeCorners(loop[v]);
        const glm::ivec3 a = base + dmc::cornerPosition(ca) / 2, d = dmc::cornerPosition(cb) / 2 - dmc::cornerPosition(ca) / 2;
        const float va = at(a), vb = at(a + d);
        const float t = (job.iso - va) / (vb - va);  // the corners classify differently, so va != vb
        corner[v] = glm::dvec3(lo + a) + double(t) * glm::dvec3(d);
        normal[v] = normalAt(a, d, t);
      }
      for (size_t v = 1; v + 1 < loop.size(); ++v) {
        const size_t c3[3] = {0, v, v + 1};
        glm::dvec3 p[3];
        glm::uvec3 ids;
        for (int q = 0; q < 3; ++q) {
          p[q] = corner[c3[q]] * spacing;
          ids[q] = cluster(corner[c3[q]]);
        }
        const double w = glm::length(glm::cross(p[1] - p[0], p[2] - p[0])) + job.minWeight;  // twice the area
        for (int q = 0; q < 3; ++q) out->clusters[ids[q]].add(p[q], w, normal[c3[q]]);
        if (ids.x != ids.y && ids.y != ids.z && ids.x != ids.z) out->triangles.push_back(canonical(ids));
      }
    }
  };
  const int sub = job.octree.leafEdge();  // boxes clipped to the block
  for (int sz = 0; sz + 1 < n.z; sz += sub)
    for (int sy = 0; sy + 1 < n.y; sy += sub)
      for (int sx = 0; sx + 1 < n.x; sx += sub) {
        const glm::ivec3 slo(sx, sy, sz), shi = glm::min(slo + sub, n - 1);
        float mn = job.octree.root().maxValue, mx = job.octree.root().minValue;
        rangeIn(job.octree, 0, lo + slo, lo + shi, &mn, &mx);
        if (!(mn < job.iso && job.iso <= mx)) continue;
        for (int k = slo.z; k < shi.z; ++k)
          for (int j = slo.y; j < shi.y; ++j)
            for (int i = slo.x; i < shi.x; ++i) triangulate(glm::ivec3(i, j, k));
      }
  unique(&out->triangles);
}

}  // namespace

TriangleMesh knotSurface(const KnotSource& knots, int s, float iso) {
  const glm::ivec3 dims = knots.dims(), n = knotCounts(dims, s);
  const size_t count = size_t(n.x) * size_t(n.y) * size_t(n.z);
  std::vector<float> values(count);
  std::vector<glm::vec3> gradients(s >= 2 ? count : 0);
  knots.read(s, glm::ivec3(0), n, values.data(), s >= 2 ? gradients.data() : nullptr);
  TriangleMesh mesh = extractMarchingCubes(Volume(n, glm::dvec3(1.0), ScalarType::Float32, std::move(values), "knots"), iso);
  // A knot coordinate in voxels: j·s, the last knot on the last sample.
  auto voxel = [&](float x, int axis) {
    const int last = n[axis] - 1;
    if (last == 0 || x <= float(last - 1)) return x * float(s);
    const float before = float((last - 1) * s);
    return before + (x - float(last - 1)) * (float(dims[axis] - 1) - before);
  };
  if (!gradients.empty()) {
    mesh.normals.resize(mesh.vertices.size());
    for (size_t v = 0; v < mesh.vertices.size(); ++v) {
      const glm::vec3 q = glm::clamp(mesh.vertices[v], glm::vec3(0.0f), glm::vec3(n - 1));
      const glm::ivec3 i0 = glm::min(glm::ivec3(q), n - 1), i1 = glm::min(i0 + 1, n - 1);
      const glm::vec3 t = q - glm::vec3(i0);
      glm::vec3 g(0.0f);
      for (int c = 0; c < 8; ++c) {
        const glm::ivec3 at(c & 1 ? i1.x : i0.x, c & 2 ? i1.y : i0.y, c & 4 ? i1.z : i0.z);
        const float w = (c & 1 ? t.x : 1.0f - t.x) * (c & 2 ? t.y : 1.0f - t.y) * (c & 4 ? t.z : 1.0f - t.z);
        g += w * gradients[size_t(at.x) + size_t(n.x) * (size_t(at.y) + size_t(n.y) * size_t(at.z))];
      }
      const float length = glm::length(g);
      mesh.normals[v] = length > 0.0f ? -g / length : glm::vec3(0.0f, 0.0f, 1.0f);  // (outward: towards lower values)
    }
  }
  const glm::vec3 spacing(knots.spacing());
  for (glm::vec3& p : mesh.vertices) p = glm::vec3(voxel(p.x, 0), voxel(p.y, 1), voxel(p.z, 2)) * spacing;
  return mesh;
}

int clusterSpacingFor(double pixelMm, const glm::dvec3& spacing, int maxSpacing) {
  const double voxelMm = std::max({spacing.x, spacing.y, spacing.z});
  int s = 1;
  while (2 * s <= maxSpacing && double(2 * s) * voxelMm <= pixelMm) s *= 2;
  return s;
}

TriangleMesh clusteredSurface(const KnotSource& knots, const VolumeOctree& octree, int s, float iso, const Progress* progress, int blockCells) {
  HYB_CHECK(s >= 1 && blockCells >= 1 && knots.dims() == octree.dims());
  const glm::ivec3 cells = glm::max(knots.dims() - 1, glm::ivec3(0));
  const glm::ivec3 blocks = (cells + blockCells - 1) / blockCells;
  std::vector<glm::ivec3> todo;  // the blocks whose samples may straddle the isovalue
  for (int bz = 0; bz < blocks.z; ++bz)
    for (int by = 0; by < blocks.y; ++by)
      for (int bx = 0; bx < blocks.x; ++bx) {
        const glm::ivec3 lo = glm::ivec3(bx, by, bz) * blockCells, hi = glm::min(lo + blockCells, cells);
        float mn = octree.root().maxValue, mx = octree.root().minValue;
        rangeIn(octree, 0, lo, hi, &mn, &mx);
        if (mn < iso && iso <= mx) todo.push_back(lo);
      }
  const double voxelMm = std::min({knots.spacing().x, knots.spacing().y, knots.spacing().z});
  // Cubes per axis: the last sample's plane belongs to the cube before it, not a sliver of its own.
  const glm::ivec3 cubes = glm::max((cells + s - 1) / s, glm::ivec3(1));
  const ClusterJob job{knots, octree, s, iso, cubes, 1e-9 * voxelMm * voxelMm};

  // The blocks a batch at a time, each on its own (all cores), then the batch's clusters merged in
  // block order (the same sums whatever the threads) and its triangles kept once each: a batch's
  // parts are all that is held beside the result.
  constexpr size_t kBatch = 256;
  std::vector<BlockClusters> parts;
  ProgressTask task(progress, "coarse surface", todo.size());
  FlatMap global(1024);
  std::vector<uint64_t> keys;
  std::vector<Cluster> clusters;
  std::vector<glm::uvec3> triangles;
  std::vector<uint32_t> to;
  for (size_t first = 0; first < todo.size(); first += kBatch) {
    parts.assign(std::min(kBatch, todo.size() - first), BlockClusters{});
    ParallelFailure failure;
#pragma omp parallel for schedule(dynamic)
    for (size_t bi = 0; bi < parts.size(); ++bi)
      failure.run([&] {
        const glm::ivec3 lo = todo[first + bi];
        clusterBlock(job, lo, glm::min(lo + blockCells, cells) - lo + 1, &parts[bi]);
        task.advance();
      });
    failure.rethrow();
    for (BlockClusters& b : parts) {
      to.resize(b.clusters.size());
      for (size_t c = 0; c < b.clusters.size(); ++c) {
        to[c] = global.findOrInsert(b.keys[c], [&] {
          keys.push_back(b.keys[c]);
          clusters.emplace_back();
          return uint32_t(clusters.size() - 1);
        });
        clusters[to[c]].add(b.clusters[c]);
      }
      for (const glm::uvec3& t : b.triangles) triangles.push_back({to[t.x], to[t.y], to[t.z]});
      b = BlockClusters{};
    }
  }
  global = FlatMap(0);

  // Vertices numbered by their cubes, triangles once each.
  std::vector<uint32_t> order(clusters.size()), rank(clusters.size());
  std::iota(order.begin(), order.end(), 0u);
  std::sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) { return keys[a] < keys[b]; });
  TriangleMesh mesh;
  mesh.vertices.reserve(clusters.size());
  mesh.normals.reserve(clusters.size());
  for (uint32_t r = 0; r < order.size(); ++r) {
    const Cluster& c = clusters[order[r]];
    rank[order[r]] = r;
    mesh.vertices.push_back(glm::vec3(c.position / c.weight));
    mesh.normals.push_back(c.normal());
  }
  for (glm::uvec3& t : triangles) t = canonical({rank[t.x], rank[t.y], rank[t.z]});
  unique(&triangles);
  mesh.triangles = std::move(triangles);
  orientNormals(&mesh);
  splitOpposedCorners(&mesh);
  return mesh;
}

}  // namespace hyb
