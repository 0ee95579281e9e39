// The `scan-convert` method of drawing user geometry (Levoy 1989; docs/user-geometry.md): each
// mesh or analytic primitive of a frame is filtered and scan-converted (surface/scan_convert.h) into
// a coverage channel on the volume's grid, a sheet of one voxel (a plane's own thickness) around its
// surface, with the normal of the closest surface at each voxel, which both renderers shade and
// composite with the data's classified samples by one rule (compositeGeometry). The Volume Octree's nodes carry the channel's largest coverage, so that a
// brick holding geometry is never skipped as empty and is refined to full resolution.
#pragma once

#include <glm/glm.hpp>
#include <glm/ext/vector_uint3_sized.hpp>
#include <glm/ext/vector_uint4_sized.hpp>

#include <cstdint>
#include <string>
#include <vector>

#include "hybrid_octree/volume_octree.h"
#include "render/frame_request.h"
#include "render/gl_objects.h"
#include "surface/scan_convert.h"
#include "volume/volume.h"

namespace hyb {

/// One mesh's or primitive's coverage and surface normal, cropped to the voxels where it covers
/// anything (with a voxel of zeros around them where the grid has one).
struct GeometryPart {
  glm::ivec3 lo{0}, dims{0};  ///< the crop's first voxel and its size (voxels)
  /// Per voxel of the crop, x fastest: the coverage (fraction · 255), then the unit normal n of the
  /// closest surface (grid frame; a mesh's by its triangles' winding) as 128 + 127·n, 128s where
  /// there is none: the RGBA8 texels the slices sample. Empty when the part covers nothing.
  std::vector<glm::u8vec4> texels;
  glm::vec4 color{1.0f};     ///< straight RGBA; a is the opacity of one crossing of the sheet
  double thicknessMm = 1.0;  ///< the sheet's thickness τ (mm)
  /// The coverage in [0, 1] (x) and the normal (yzw: the decoded n, trilinear, so not unit; zero
  /// where there is none) at @p q (voxel units), trilinear, zero outside the crop (as a texture
  /// clamped to its border reads it).
  glm::vec4 at(const glm::vec3& q) const;
};

/// A frame's user geometry scan-converted onto the volume's grid.
struct GeometryChannel {
  std::vector<GeometryPart> parts;  ///< in the look's order of meshes
  /// Per Volume Octree node: the largest coverage (0 … 1) over its voxel box.
  std::vector<float> nodeMax;
  std::vector<std::string> warnings;  ///< the scan-conversions' (a mesh not closed...), one line each
  double ms = 0.0;                    ///< the scan-conversion's time
  /// The parts' textures (RGBA8, texture units 3…), made by the first slice frame that draws them.
  mutable std::vector<gl::Texture> textures;

  bool empty() const { return parts.empty(); }
  /// Whether node @p node's box holds any coverage.
  bool holds(uint32_t node) const { return node < nodeMax.size() && nodeMax[node] > 0.0f; }
  /// Bytes of the parts' texels (as much again in their textures once made).
  uint64_t bytes() const;
};

/// The most parts a slice frame samples (texture units 3 … 3 + kMaxGeometryParts − 1).
inline constexpr int kMaxGeometryParts = kMaxUserMeshes;

/// Scan-converts @p meshes (patient mm) onto the grid of @p volume with the filter of @p meshFilter
/// (Look::meshFilter, --mesh-filter: a box of that many voxel cells, 0 the voxel centre
/// point-sampled): a mesh as a sheet of the smallest voxel spacing around its surface; an analytic
/// primitive (UserMesh::primitive) exactly (a plane as a sheet of its thickness, a sphere's surface
/// as a shell of the smallest voxel spacing, a polygon as a sheet of it). Each voxel's normal is its
/// closest triangle's (a mesh, a polygon), the sphere's radial direction or the plane's. Then each
/// node of @p octree gets its box's largest coverage.
GeometryChannel scanConvertGeometry(const std::vector<UserMesh>& meshes, const Volume& volume, const VolumeOctree& octree, double meshFilter = 1.0);

/// @p meshes scan-converted onto the grid of @p volume as an export (3D Slicer's model to labelmap):
/// a mesh as the solid it bounds, a sphere as its ball, a plane or polygon as its sheet (a plane's
/// thickness, else the smallest voxel spacing), the box filter of one cell, the union taken by the
/// largest coverage. @p asFraction: float32 fractions in [0, 1]; else a uint8 label, 1 where the
/// coverage is at least ½. On the grid and in the patient frame of @p volume.
/// @p warnings receives the scan-conversions' ("a mesh not closed..."), one line each.
Volume geometryVolume(const std::vector<UserMesh>& meshes, const Volume& volume, bool asFraction, std::vector<std::string>* warnings);

/// The one rule both renderers composite a sample with (docs/user-geometry.md): the parts, in
/// order, each over those after it, are over the data's sample. With c a part's coverage and n its
/// normal at the sample, d the ray's direction and cos = |n·d| (1 where it has no normal), the part
/// over a segment of @p lenMm has opacity 1 − (1 − a)^(c · cos · len / τ): the path's projection on
/// the normal integrates to τ across the sheet, so a crossing at any incidence composites a, as a
/// polygon crossing does; its colour is shaded by the polygons' and the isosurface's headlight,
/// 0.25 + 0.75·cos. @p data and the result are premultiplied RGBA; @p samples holds each part's
/// GeometryPart::at at the sample; @p dir is the ray's unit direction (grid frame).
glm::vec4 compositeGeometry(const GeometryChannel& g, const glm::vec4* samples, const glm::vec3& dir, double lenMm, const glm::vec4& data);

/// The triangles drawn for analytic primitive @p p by the `polygons` method, in patient mm: a
/// plane's polygon inside the box of @p volume, a sphere's geodesic sphere with edges of about a
/// voxel (at most 81 920 triangles), a polygon's fan.
TriangleMesh tessellatePrimitive(const UserPrimitive& p, const Volume& volume);

}  // namespace hyb
