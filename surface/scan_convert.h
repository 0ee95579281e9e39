// Filtered 3D scan-conversion (Levoy, "Design for a Real-Time High-Quality Volume Rendering
// Workstation", Chapel Hill Workshop on Volume Visualization 1989; docs/scan-conversion.md):
// geometry is band-limited and sampled onto a volume's grid as a coverage volume, each voxel the
// fraction of its cell the primitive fills, so that volumetric compositing alone renders it
// without aliasing.
//
// The filter is a box of `width` voxel cells centred on each voxel: its value is the exact
// partial-volume fraction of the cell, which is what Levoy's sub-voxel translations average to.
// Near a surface the primitive is taken as its tangent plane at the closest point (exact for a
// plane; second order in the cell size over the curvature radius elsewhere), and the fraction of
// the cell on one side of a plane has a closed form (boxHalfSpaceFraction).
#pragma once

#include <glm/glm.hpp>

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "surface/mesh.h"
#include "volume/core/huge_pages.h"
#include "volume/patient_frame.h"
#include "volume/volume.h"

namespace hyb {

/// A voxel grid: voxel (i, j, k) at grid point (i·sx, j·sy, k·sz) mm, placed in the patient by
/// its frame (volume/patient_frame.h).
struct VoxelGrid {
  glm::ivec3 dims{0};
  glm::dvec3 spacing{1.0};
  PatientFrame frame;
  /// The grid of @p volume (its dims, spacing and frame).
  static VoxelGrid of(const Volume& volume) { return {volume.dims(), volume.spacing(), volume.frame()}; }
};

/// Which coordinates a primitive's points are given in.
enum class ScanSpace {
  Index,    ///< voxel indices: voxel (i, j, k) at (i, j, k)
  Grid,     ///< the grid frame, mm: voxel (i, j, k) at (i·sx, j·sy, k·sz)
  Patient,  ///< LPS mm, placed by the grid's frame
};

/// The kernel a primitive's indicator is filtered with before it is sampled at the voxels.
enum class ScanFilter {
  None,  ///< point sampling at the voxel centre: a binary voxelization (aliases when the primitive moves)
  Box,   ///< a box of `width` cells centred on the voxel: the exact fraction of that box the primitive fills
};

/// How the coverage voxels are stored.
enum class CoverageType {
  UInt8,    ///< fraction · 255, rounded (1 byte a voxel)
  Float32,  ///< the fraction itself
};

/// Options of every scan-conversion.
struct ScanOptions {
  ScanSpace space = ScanSpace::Patient;
  ScanFilter filter = ScanFilter::Box;
  /// The box's side in voxel cells, > 0 (1: each voxel's own cell, the partial-volume fraction).
  double width = 1.0;
  /// Meshes and polygons: 0 makes a closed mesh the solid it bounds; > 0 makes any mesh a sheet
  /// of this thickness in mm centred on its surface. Polygons and planes need it > 0.
  double thickness = 0.0;
  CoverageType type = CoverageType::UInt8;
  /// Meshes and polygons: also return each band voxel's closest triangle's normal (ScanResult::normals).
  bool normals = false;
  /// Warn of a mesh wholly outside the grid or smaller than a voxel (false: the caller has).
  bool extentWarnings = true;
};

/// A voxel's surface normal: the unit normal of its closest triangle, in the grid frame, pointing
/// the way the triangle's corners turn counter-clockwise (so consistent over a consistently wound mesh).
struct VoxelNormal {
  uint64_t voxel = 0;  ///< its index, x fastest
  glm::vec3 normal{0.0f};
};
/// Band voxels' normals: a million of them take tens of MB, on 2 MiB pages (volume/core/huge_pages.h).
using VoxelNormals = std::vector<VoxelNormal, HugePageAllocator<VoxelNormal>>;

/// A coverage volume and what the scan-conversion noticed.
struct ScanResult {
  /// On the grid, with its frame; values in [0, 1] (or 0 … 255 for UInt8). It owns its buffer as a
  /// borrowing Volume does: read it with value(), at() or visitSamples() (samples() has no vector).
  Volume coverage;
  /// Conditions that make the result suspect, one sentence each: a mesh wholly outside the grid,
  /// one smaller than a voxel (units?), a solid mesh that is not closed.
  std::vector<std::string> warnings;
  size_t bandVoxels = 0;    ///< voxels within the filter's reach of the surface, whose value was filtered
  size_t insideVoxels = 0;  ///< voxels wholly inside (value 1)
  /// With ScanOptions::normals, a mesh's or polygon's band voxels' normals, in no particular order;
  /// empty otherwise.
  VoxelNormals normals;
};

/// The fraction of the cube [−½, ½]³ where m·u ≤ t, exact (closed form, stable for any m ≠ 0,
/// including normals on and near the axes). Only |m_i| matter (the cube is symmetric).
double boxHalfSpaceFraction(const glm::dvec3& m, double t);

/// Scan-converts @p mesh onto @p grid (@p options.space gives its coordinates): the solid a closed
/// mesh bounds (thickness 0; inside by scanline parity along x, so the winding of the triangles does
/// not matter), or a sheet of @p options.thickness mm around any mesh. Voxels within the filter's
/// reach of the surface take the box fraction of the tangent plane at their closest surface point;
/// the others are 0 or 1. On all cores (z-slabs).
/// @throw ValueError when the mesh has no triangles, a vertex that is not finite, or an index out of
/// range, or an option is out of range (each message names the first offending item).
ScanResult scanConvertMesh(const TriangleMesh& mesh, const VoxelGrid& grid, const ScanOptions& options = {});

/// Scan-converts the ball of @p radius about @p center; the box fraction of the tangent plane at
/// each voxel's closest surface point, its offset corrected for the curvature to second order.
/// @throw ValueError when the centre is not finite or the radius not positive and finite.
ScanResult scanConvertSphere(const glm::dvec3& center, double radius, const VoxelGrid& grid, const ScanOptions& options = {});

/// Scan-converts the infinite plane through @p point with normal @p normal as a sheet of
/// @p options.thickness mm (> 0), exactly: the difference of two half-space fractions.
/// @throw ValueError when a vector is not finite, the normal is zero, or the thickness not positive.
ScanResult scanConvertPlane(const glm::dvec3& point, const glm::dvec3& normal, const VoxelGrid& grid, const ScanOptions& options);

/// Scan-converts the half-space n·(x − point) ≤ 0 (the side @p normal points away from), exactly.
/// @throw ValueError when a vector is not finite or the normal is zero.
ScanResult scanConvertHalfSpace(const glm::dvec3& point, const glm::dvec3& normal, const VoxelGrid& grid, const ScanOptions& options = {});

/// Scan-converts the planar polygon of @p corners (in order, at least 3, coplanar within 10⁻⁶ of
/// its size, convex or star-shaped from its first corner) as a sheet of @p options.thickness mm (> 0): a fan of triangles through
/// scanConvertMesh, so its rim is rounded by the thickness.
/// @throw ValueError when there are fewer than 3 corners, one is not finite, they are not coplanar,
/// or the fan from the first corner folds.
ScanResult scanConvertPolygon(std::span<const glm::dvec3> corners, const VoxelGrid& grid, const ScanOptions& options);

/// A geodesic sphere: the icosahedron's faces divided into @p frequency² triangles each (20·f²
/// triangles), projected onto the sphere of @p radius about @p center; outward winding. Vertices
/// on shared edges are computed in one order, so they are bit-identical (a watertight soup).
/// @throw ValueError when the frequency is below 1 or above 4096 or the radius not positive.
TriangleMesh geodesicSphere(const glm::dvec3& center, double radius, int frequency);

/// A UV sphere: @p rings bands of 2·rings quads between the poles, split into triangles
/// (4·rings² − 4·rings of them, the poles' bands fans), projected onto the sphere of @p radius
/// about @p center; outward winding. Its thin triangles near the poles are what a CAD export holds.
TriangleMesh uvSphere(const glm::dvec3& center, double radius, int rings);

/// The volume a closed, consistently wound mesh encloses (divergence theorem), in its units³;
/// negative when it is wound inward.
double enclosedVolume(const TriangleMesh& mesh);

}  // namespace hyb
