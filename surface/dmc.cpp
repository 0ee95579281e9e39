// Discretized Marching Cubes: C. Montani, R. Scateni, R. Scopigno, "Discretized Marching Cubes",
// Visualization '94, 281–287. Classic Marching Cubes: W. Lorensen, H. Cline, SIGGRAPH '87.
#include "surface/dmc.h"
#include "surface/mesh_ops.h"

#include <algorithm>
#include <bit>
#ifdef __SSE2__
#include <immintrin.h>
#endif

#include "surface/dmc_table.h"
#include "surface/flat_map.h"
#include "surface/triangulate.h"
#include "volume/core/error.h"

namespace hyb {

namespace {

template <class Grid>
unsigned cellMask(const Grid& v, float iso, int i, int j, int k) {
  unsigned mask = 0;
  for (int c = 0; c < 8; ++c) mask |= unsigned(v.at(i + (c & 1), j + ((c >> 1) & 1), k + ((c >> 2) & 1)) >= iso) << c;
  return mask;
}

// Whether a DiscMC cell uses the centre-diagonal variant of its case: its fold lies on its low face
// and the cell below folds onto the same diagonal (dmc_table.h).
template <class Grid>
bool usesAlternative(const Grid& v, float iso, int i, int j, int k, unsigned mask) {
  const dmc::Case& c = dmc::caseTable()[mask];
  if (!c.hasFold()) return false;
  const glm::ivec3 a = dmc::edgeMidpoint(c.fold[0]), b = dmc::edgeMidpoint(c.fold[1]);
  for (int axis = 0; axis < 3; ++axis) {
    if (a[axis] != 0 || b[axis] != 0) continue;  // the fold is on the low face of this axis
    glm::ivec3 n(i, j, k);
    if (--n[axis] < 0) return false;
    const dmc::Case& below = dmc::caseTable()[cellMask(v, iso, n.x, n.y, n.z)];
    if (!below.hasFold()) return false;
    // Compare the folds in the upper cell's coordinates: the cell below is shifted by 2 on this axis.
    glm::ivec3 shift(0);
    shift[axis] = -2;
    const glm::ivec3 p = dmc::edgeMidpoint(below.fold[0]) + shift, q = dmc::edgeMidpoint(below.fold[1]) + shift;
    return (p == a && q == b) || (p == b && q == a);
  }
  return false;
}

const dmc::Case& cellCase(const Volume& v, float iso, int i, int j, int k, unsigned mask) {
  return usesAlternative(v, iso, i, j, k, mask) ? dmc::alternativeCaseTable()[mask] : dmc::caseTable()[mask];
}

// Bit i set where row[i] >= iso, for @p n <= 64 samples.
uint64_t insideBits(const float* row, int n, float iso) {
  uint64_t bits = 0;
  int i = 0;
#ifdef __SSE2__
  const __m128 t = _mm_set1_ps(iso);
  for (; i + 4 <= n; i += 4) bits |= uint64_t(_mm_movemask_ps(_mm_cmpge_ps(_mm_loadu_ps(row + i), t))) << i;
#endif
  for (; i < n; ++i) bits |= uint64_t(row[i] >= iso) << i;
  return bits;
}

// Calls visit(i, j, k, mask) for every cell of the blocks whose corners are not all on one side
// (all cells, in blocks of 16³, when @p blocks is empty), x fastest. Each row of a block's samples is
// classified once into a bit mask (blocks wider than 63 cells are cut along x); a row of cells
// combines four of them, and only its mixed cells are visited.
template <class Grid, typename Visit>
void forEachActiveCell(const Grid& v, float iso, std::span<const VoxelBlock> blocks, Visit&& visit) {
  constexpr int kMaxRun = 63;  // cells a row: its samples fit a 64-bit mask
  std::vector<VoxelBlock> pieces;
  if (blocks.empty()) {
    constexpr int kTile = 16;
    const glm::ivec3 last = glm::max(v.dims() - 1, glm::ivec3(0));
    for (int z = 0; z < last.z; z += kTile)
      for (int y = 0; y < last.y; y += kTile)
        for (int x = 0; x < last.x; x += kTile)
          pieces.push_back({glm::ivec3(x, y, z), glm::min(glm::ivec3(x, y, z) + kTile, last)});
    blocks = pieces;
  } else if (std::any_of(blocks.begin(), blocks.end(), [](const VoxelBlock& b) { return b.hi.x - b.lo.x > kMaxRun; })) {
    for (const VoxelBlock& b : blocks)
      for (int x = b.lo.x; x < b.hi.x; x += kMaxRun)
        pieces.push_back({glm::ivec3(x, b.lo.y, b.lo.z), glm::ivec3(std::min(x + kMaxRun, b.hi.x), b.hi.y, b.hi.z)});
    blocks = pieces;
  }
  std::vector<uint64_t> rows;  // bit i: sample i of a row is inside
  std::vector<float> row(size_t(kMaxRun) + 1);
  for (const VoxelBlock& b : blocks) {
    HYB_DCHECK(glm::all(glm::greaterThanEqual(b.lo, glm::ivec3(0))) && glm::all(glm::lessThan(b.hi, v.dims())));
    const glm::ivec3 n = b.hi - b.lo + 1;  // samples a side
    if (glm::any(glm::lessThan(n, glm::ivec3(2)))) continue;
    rows.resize(size_t(n.y) * size_t(n.z));
    for (int k = 0; k < n.z; ++k)
      for (int j = 0; j < n.y; ++j) {
        v.readRow(b.lo.x, b.lo.y + j, b.lo.z + k, n.x, row.data());
        rows[size_t(k) * size_t(n.y) + size_t(j)] = insideBits(row.data(), n.x, iso);
      }
    const uint64_t cellsOfRow = (uint64_t(1) << (n.x - 1)) - 1;
    for (int k = 0; k + 1 < n.z; ++k)
      for (int j = 0; j + 1 < n.y; ++j) {
        const uint64_t* r = rows.data() + size_t(k) * size_t(n.y) + size_t(j);
        const uint64_t r00 = r[0], r10 = r[1], r01 = r[n.y], r11 = r[n.y + 1];
        // Per cell i: any corner inside, all corners inside (bits i and i + 1 of the four rows).
        const uint64_t any = r00 | r10 | r01 | r11, all = r00 & r10 & r01 & r11;
        for (uint64_t mixed = ((any | any >> 1) & ~(all & all >> 1)) & cellsOfRow; mixed; mixed &= mixed - 1) {
          const int i = std::countr_zero(mixed);
          const unsigned mask = unsigned(r00 >> i & 3) | unsigned(r10 >> i & 3) << 2 | unsigned(r01 >> i & 3) << 4 |
                                unsigned(r11 >> i & 3) << 6;
          visit(b.lo.x + i, b.lo.y + j, b.lo.z + k, mask);
        }
      }
  }
}

}  // namespace

void appendSurfaceCells(const SampleBox& samples, float iso, const VoxelBlock& block, std::vector<SurfaceCell>* cells) {
  HYB_DCHECK(glm::all(glm::lessThanEqual(samples.lo, glm::max(block.lo - 1, glm::ivec3(0)))) &&
             glm::all(glm::lessThan(block.hi, samples.lo + samples.count)));
  forEachActiveCell(samples, iso, std::span<const VoxelBlock>(&block, 1), [&](int i, int j, int k, unsigned mask) {
    cells->push_back({glm::u16vec3(i, j, k), uint8_t(mask), usesAlternative(samples, iso, i, j, k, mask)});
  });
}

DiscreteMesh extractDiscMC(const Volume& volume, float iso, std::span<const VoxelBlock> blocks, DmcFaces faces) {
  std::array<glm::ivec3, 12> mid;
  for (int e = 0; e < 12; ++e) mid[size_t(e)] = dmc::edgeMidpoint(e);
  DiscreteMesh mesh;
  FlatMap map(1 << 16);
  uint32_t ids[12];
  forEachActiveCell(volume, iso, blocks, [&](int i, int j, int k, unsigned mask) {
    const dmc::Case& c = cellCase(volume, iso, i, j, k, mask);
    const glm::ivec3 base = 2 * glm::ivec3(i, j, k);
    auto vertex = [&](uint8_t e) {
      const glm::ivec3 p = base + mid[e];  // doubled coordinates: below 2^17
      return map.findOrInsert(gridKey(p), [&] {
        mesh.vertices.push_back(p);
        return uint32_t(mesh.vertices.size() - 1);
      });
    };
    if (faces == DmcFaces::CellPolygons) {
      for (const dmc::CasePolygon& poly : c.polygons) {
        for (size_t v = 0; v < poly.edges.size(); ++v) ids[v] = vertex(poly.edges[v]);
        mesh.addFace(ids, poly.edges.size(), c.planes[poly.plane].translated(base));
      }
    } else {
      for (size_t t = 0; t < c.triangles.size(); ++t) {
        for (int v = 0; v < 3; ++v) ids[v] = vertex(c.triangles[t][size_t(v)]);
        mesh.addFace(ids, 3, c.planes[c.trianglePlane[t]].translated(base));
      }
    }
  });
  return mesh;
}

TriangleMesh extractMarchingCubes(const Volume& volume, float iso, std::span<const VoxelBlock> blocks) {
  const auto& table = dmc::caseTable();
  TriangleMesh mesh;
  FlatMap map(1 << 16);
  std::array<uint32_t, 12> ids;
  forEachActiveCell(volume, iso, blocks, [&](int i, int j, int k, unsigned mask) {
    const dmc::Case& c = table[mask];
    const glm::ivec3 base(i, j, k);
    for (const auto& loop : c.loops) {
      for (size_t v = 0; v < loop.size(); ++v) {
        const auto [ca, cb] = dmc::edgeCorners(loop[v]);
        const glm::ivec3 a = base + dmc::cornerPosition(ca) / 2, b = base + dmc::cornerPosition(cb) / 2;
        ids[v] = map.findOrInsert(uint64_t(volume.index(a.x, a.y, a.z)) * 3 + uint64_t(loop[v] / 4), [&] {
          const float va = volume.at(a.x, a.y, a.z), vb = volume.at(b.x, b.y, b.z);
          const float t = (iso - va) / (vb - va);  // corners classify differently, so va != vb
          mesh.vertices.push_back(glm::vec3(a) + t * glm::vec3(b - a));
          return uint32_t(mesh.vertices.size() - 1);
        });
      }
      for (size_t v = 1; v + 1 < loop.size(); ++v) mesh.triangles.push_back({ids[0], ids[v], ids[v + 1]});
    }
  });
  return mesh;
}

TriangleMesh toTriangleMesh(const DiscreteMesh& mesh, const glm::dvec3& spacing, double unitsPerVoxel) {
  TriangleMesh out;
  out.vertices.reserve(mesh.vertices.size());
  for (const glm::ivec3& p : mesh.vertices) out.vertices.push_back(glm::vec3(glm::dvec3(p) / unitsPerVoxel * spacing));
  std::vector<std::array<uint32_t, 3>> tris;
  out.polygonStarts.reserve(mesh.faceCount() + 1);
  out.polygonStarts.push_back(0);
  for (size_t f = 0; f < mesh.faceCount(); ++f) {
    const uint32_t* loop = &mesh.indices[mesh.offsets[f]];
    const size_t n = mesh.faceSize(f);
    tris.clear();
    const bool ok = triangulatePolygon(mesh.vertices, loop, n, mesh.planes[f].normal(), &tris);
    HYB_CHECK(ok);
    for (const auto& t : tris) out.triangles.push_back({t[0], t[1], t[2]});
    out.polygonStarts.push_back(uint32_t(out.triangles.size()));
  }
  removeUnreferencedVertices(&out);
  return out;
}

void scaleToMillimetres(TriangleMesh* mesh, const glm::dvec3& spacing) {
  for (glm::vec3& p : mesh->vertices) p = glm::vec3(glm::dvec3(p) * spacing);
}

}  // namespace hyb
