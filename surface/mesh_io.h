// Mesh files through OpenMesh: PLY, OBJ, STL and OFF.
#pragma once

#include <string>

#include "surface/mesh.h"

namespace hyb {

/// Writes @p mesh to @p path (format from the extension: .ply .obj .stl .off) atomically.
/// PLY and STL are written binary, OBJ and OFF as text. An empty mesh writes a valid empty file.
/// @throw IoError naming @p path for an unknown extension or a failed write.
void writeMesh(const std::string& path, const TriangleMesh& mesh);

/// Reads a triangle mesh (for round trips and checks).
/// @throw IoError naming @p path when it cannot be read.
TriangleMesh readMesh(const std::string& path);

}  // namespace hyb
