// Mesh files through OpenMesh: PLY, OBJ, STL and OFF.
#pragma once

#include <string>
#include <vector>

#include "surface/mesh.h"

namespace hyb {

/// A mesh file format writeMesh writes: the one table every front door (export, the viewer's
/// download, Python's export) checks a file's extension against.
struct MeshFormat {
  std::string extension;  ///< with its dot: ".ply"
  bool binary = false;    ///< written binary (PLY, STL), else as text (OBJ, OFF)
  bool normals = false;   ///< can carry vertex normals (PLY, OBJ)
};

/// The formats, in the order messages list them: .ply, .obj, .stl, .off.
const std::vector<MeshFormat>& meshFormats();
/// The format of @p path's extension (lower case); null when no format has it.
const MeshFormat* meshFormatOf(const std::string& path);
/// The extensions as a message lists them: ".ply, .obj, .stl or .off" (@p withNormals: only the
/// formats that carry vertex normals, ".ply or .obj"; @p dots false: "ply, obj, stl or off").
std::string meshExtensionsText(bool withNormals = false, bool dots = true);

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

/// The bytes writeMesh writes for @p mesh as @p format (a file whose extension is @p format's).
/// @throw IoError naming @p name (the file's name, for messages) as writeMesh does.
std::string meshBytes(const TriangleMesh& mesh, const MeshFormat& format, const MeshWriteOptions& options = {}, const std::string& name = "mesh");

/// Reads a triangle mesh (for round trips and checks), with its vertex normals when the file has them.
/// @throw IoError naming @p path when it cannot be read, naming the face when one of an OFF, OBJ
///        or PLY file's faces uses a vertex the file does not hold, naming the vertex when one is
///        not finite, and when its faces would take more than memoryLimit() to read.
TriangleMesh readMesh(const std::string& path);

}  // namespace hyb
