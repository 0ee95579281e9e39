// Mesh files through OpenMesh: PLY, OBJ, STL and OFF.
#pragma once

#include <string>

#include "surface/mesh.h"

namespace hyb {

/// What a mesh file carries besides its triangles.
struct MeshWriteOptions {
  bool normals = false;  ///< the mesh's vertex normals (PLY and OBJ only)
  /// The coordinates' space, recorded as 3D Slicer reads it ("SPACE=LPS" in the PLY and OBJ
  /// comments and the STL header); empty: not recorded.
  std::string space;
};

/// Writes @p mesh to @p path (format from the extension: .ply .obj .stl .off) atomically.
/// PLY and STL are written binary, OBJ and OFF as text. An empty mesh writes a valid empty file.
/// @throw IoError naming @p path for an unknown extension, normals asked of STL or OFF, or a
///        failed write.
void writeMesh(const std::string& path, const TriangleMesh& mesh, const MeshWriteOptions& options = {});

/// Reads a triangle mesh (for round trips and checks), with its vertex normals when the file has them.
/// @throw IoError naming @p path when it cannot be read.
TriangleMesh readMesh(const std::string& path);

}  // namespace hyb
