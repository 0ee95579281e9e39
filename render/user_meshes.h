// Meshes of the user's own (an implant or plate from CAD, a segmentation exported from 3D Slicer,
// a planning surface) drawn inside the CT exactly, by both renderers (docs/user-geometry.md): read
// and checked here, in patient space, then put in the grid frame and cut to the Volume Octree's
// leaf cells so that each piece lies in one brick and joins that brick's SlabPolygon lists.
#pragma once

#include <glm/glm.hpp>

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "hybrid_octree/volume_octree.h"
#include "render/frame_request.h"
#include "surface/mesh.h"
#include "volume/volume.h"

namespace hyb {

/// The patient space a mesh file's coordinates are in.
enum class MeshSpace { LPS, RAS };

/// The space @p path says it is written in: 3D Slicer's "SPACE=RAS" or "SPACE=LPS" in the header
/// (a PLY comment, an OBJ or OFF comment line, an STL header or solid name), or none.
std::optional<MeshSpace> meshFileSpace(const std::string& path);

/// Checks @p mesh as a user mesh: at least one triangle, every vertex finite, every index in range.
/// @throw ValueError "<name>: ..." naming the first offending vertex or triangle.
void checkUserMesh(const TriangleMesh& mesh, const std::string& name);

/// Reads the mesh file @p path (.ply .obj .stl .off, patient mm) as a user mesh in LPS: a file whose
/// header says SPACE=RAS, or one without a SPACE when @p space is RAS, has x and y negated. Vertex
/// normals in the file are dropped (user meshes are shaded by their triangles' planes).
/// @throw IoError naming the file when it cannot be read, ValueError naming it when checkUserMesh
///        refuses it.
UserMesh readUserMesh(const std::string& path, const glm::vec4& color, MeshSpace space);

/// The edges of @p mesh that more than two of its triangles share (vertices at one position being one).
size_t nonManifoldEdges(const TriangleMesh& mesh);

/// What is odd about @p mesh against @p volume, one line each (empty: nothing): wholly outside the
/// volume's box (it is still drawn where visible), smaller than one voxel (a file in metres?), or
/// non-manifold (nonManifoldEdges).
std::vector<std::string> userMeshWarnings(const UserMesh& mesh, const Volume& volume);

/// A frame's user meshes in the grid frame (mm), as the renderers take them.
struct GridMeshes {
  std::vector<TriangleMesh> whole;  ///< each mesh, shaded by its triangles' planes: the reference's
  std::vector<glm::vec4> colors;    ///< each mesh's straight RGBA
  /// Every mesh's triangles cut at the faces of the Volume Octree's leaf cells (inside the volume),
  /// each piece a polygon (polygonStarts) lying in one leaf, hence in one brick: the slices'.
  TriangleMesh pieces;
  std::vector<uint16_t> pieceMesh;  ///< per polygon of pieces: the mesh it comes from
  bool empty() const { return whole.empty(); }
};

/// @p meshes (patient mm) in the grid frame of @p frame, cut to the leaf cells of @p octree over a
/// grid of voxels spaced @p spacing mm.
GridMeshes gridMeshes(const std::vector<UserMesh>& meshes, const PatientFrame& frame, const VolumeOctree& octree, const glm::dvec3& spacing);

}  // namespace hyb
