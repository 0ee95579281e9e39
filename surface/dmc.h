// Isosurface extraction: Discretized Marching Cubes (Montani, Scateni and Scopigno, Visualization
// '94) and classic Marching Cubes (Lorensen and Cline, SIGGRAPH '87) as the accuracy and speed
// baseline. Both use the same face-consistent loops (surface/dmc_table.h), so both are crack-free.
// A corner is inside the solid when its sample is ≥ the isovalue.
#pragma once

#include <algorithm>
#include <span>
#include <vector>

#include "surface/mesh.h"
#include "volume/volume.h"

namespace hyb {

/// What DiscMC emits per cell.
enum class DmcFaces {
  Triangles,     ///< the table's triangles
  CellPolygons,  ///< the table's triangles merged per plane inside each cell
};

/// DiscMC surface of @p volume at @p iso over the cells of @p blocks (all cells when empty).
/// Vertices are shared between faces; every face lies on one of the 13 discrete orientations.
/// Blocks must not overlap in cells.
DiscreteMesh extractDiscMC(const Volume& volume, float iso, std::span<const VoxelBlock> blocks = {},
                           DmcFaces faces = DmcFaces::CellPolygons);

/// A cell the isosurface crosses: mask has bit c set for inside corner c; alternative says the cell
/// uses its case's centre-diagonal variant (dmc::alternativeCaseTable) to avoid a fold shared with
/// the cell below.
struct SurfaceCell {
  glm::u16vec3 cell;
  uint8_t mask;
  bool alternative;
};

/// The samples of the box lo … lo + count − 1 of a grid of gridDims, as float, x fastest: a part of
/// a volume, read with the volume's accessors, for an extraction that does not hold the samples whole.
struct SampleBox {
  glm::ivec3 gridDims{0}, lo{0}, count{0};
  std::vector<float> values;
  /// The box of the samples the extraction of @p block reads: its own and, where the grid has them,
  /// those one voxel below (a cell's DiscMC variant looks at the cell below it).
  static SampleBox around(const VoxelBlock& block, const glm::ivec3& gridDims) {
    SampleBox b{gridDims, glm::max(block.lo - 1, glm::ivec3(0)), glm::ivec3(0), {}};
    b.count = block.hi - b.lo + 1;
    b.values.resize(size_t(b.count.x) * size_t(b.count.y) * size_t(b.count.z));
    return b;
  }
  const glm::ivec3& dims() const { return gridDims; }
  const float* row(int j, int k) const { return values.data() + size_t(count.x) * (size_t(j - lo.y) + size_t(count.y) * size_t(k - lo.z)); }
  float at(int i, int j, int k) const { return row(j, k)[i - lo.x]; }
  void readRow(int i, int j, int k, int n, float* out) const { std::copy_n(row(j, k) + (i - lo.x), n, out); }
};

/// Appends the cells of @p block the isosurface crosses to @p cells, x fastest, reading @p samples
/// (at least SampleBox::around(block)).
void appendSurfaceCells(const SampleBox& samples, float iso, const VoxelBlock& block, std::vector<SurfaceCell>* cells);

/// Classic Marching Cubes with vertices interpolated along the edges, in voxel coordinates,
/// each loop fan-triangulated.
TriangleMesh extractMarchingCubes(const Volume& volume, float iso, std::span<const VoxelBlock> blocks = {});

/// Triangulates @p mesh (exact ear clipping) and maps its integer vertices to grid millimetres:
/// voxel coordinates are vertices / @p unitsPerVoxel (2 for DiscMC's doubled grid), times @p spacing.
/// Vertices no face uses are dropped.
TriangleMesh toTriangleMesh(const DiscreteMesh& mesh, const glm::dvec3& spacing, double unitsPerVoxel = 2.0);

/// Scales a voxel-coordinate triangle mesh to world millimetres.
void scaleToMillimetres(TriangleMesh* mesh, const glm::dvec3& spacing);

}  // namespace hyb
