// OpenMesh lives in this translation unit only (STYLE 6).
#include <OpenMesh/Core/IO/MeshIO.hh>  // first, so the readers and writers register
#include <OpenMesh/Core/Mesh/TriMesh_ArrayKernelT.hh>

#include "surface/mesh_io.h"

#include <filesystem>
#include <fstream>

#include "volume/error.h"
#include "volume/file_util.h"

namespace hyb {

namespace {

using OMesh = OpenMesh::TriMesh_ArrayKernelT<>;

bool supported(const std::string& ext) { return ext == ".ply" || ext == ".obj" || ext == ".stl" || ext == ".off"; }

// OpenMesh does not write a file for a mesh without vertices; write the format's empty form.
void writeEmpty(const std::string& path, const std::string& ext) {
  writeFileAtomically(path, [&](std::ostream& out) {
    if (ext == ".ply")
      out << "ply\nformat binary_little_endian 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
             "property float z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n";
    else if (ext == ".off")
      out << "OFF\n0 0 0\n";
    else if (ext == ".obj")
      out << "# empty mesh\n";
    else {  // binary STL: 80-byte header and a zero triangle count
      const std::string header(80, ' ');
      out.write(header.data(), 80);
      const uint32_t zero = 0;
      out.write(reinterpret_cast<const char*>(&zero), 4);
    }
  });
}

}  // namespace

void writeMesh(const std::string& path, const TriangleMesh& mesh) {
  const std::string ext = fileExtension(path);
  if (!supported(ext)) HYB_THROW(IoError, path, ": unknown mesh format '", ext, "' (expected .ply, .obj, .stl or .off)");
  if (mesh.triangles.empty()) return writeEmpty(path, ext);
  OMesh om;
  om.reserve(mesh.vertices.size(), mesh.triangles.size() * 3 / 2, mesh.triangles.size());
  std::vector<OMesh::VertexHandle> vh;
  vh.reserve(mesh.vertices.size());
  for (const glm::vec3& p : mesh.vertices) vh.push_back(om.add_vertex(OMesh::Point(p.x, p.y, p.z)));
  {
    // OpenMesh reports each face its half-edge structure rejects on omerr; those are expected here
    // (classic MC's non-manifold edges) and handled below, so the report is silenced meanwhile.
    struct Quiet {
      bool was = omerr().is_enabled();
      Quiet() { omerr().disable(); }
      ~Quiet() { if (was) omerr().enable(); }
    } quiet;
    for (const glm::uvec3& t : mesh.triangles)
      if (!om.add_face(vh[t.x], vh[t.y], vh[t.z]).is_valid()) {
        // A face OpenMesh's half-edge structure cannot take (non-manifold): keep it with own vertices.
        OMesh::VertexHandle copy[3];
        for (int k = 0; k < 3; ++k) {
          const OMesh::Point p = om.point(vh[t[k]]);  // a copy: adding a vertex may move the points
          copy[k] = om.add_vertex(p);
        }
        om.add_face(copy[0], copy[1], copy[2]);
      }
  }
  OpenMesh::IO::Options options;
  if (ext == ".ply" || ext == ".stl") options += OpenMesh::IO::Options::Binary;
  writeFileAtomicallyByName(path, [&](const std::string& tmp) {
    if (!OpenMesh::IO::write_mesh(om, tmp, options)) HYB_THROW(IoError, path, ": OpenMesh could not write the mesh");
  });
}

TriangleMesh readMesh(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) HYB_THROW(IoError, path, ": file does not exist");
  TriangleMesh out;
  if (std::filesystem::file_size(path, ec) <= 84) {  // empty forms written above
    std::ifstream in(path, std::ios::binary);
    const std::string head((std::istreambuf_iterator<char>(in)), {});
    if (head.find("element vertex 0") != std::string::npos || head.rfind("OFF\n0 ", 0) == 0 || head.rfind("# empty", 0) == 0 ||
        head.size() == 84)
      return out;
  }
  OMesh om;
  OpenMesh::IO::Options options;
  if (!OpenMesh::IO::read_mesh(om, path, options)) HYB_THROW(IoError, path, ": OpenMesh could not read the mesh");
  for (const auto& v : om.vertices()) {
    const auto p = om.point(v);
    out.vertices.push_back({p[0], p[1], p[2]});
  }
  for (const auto& f : om.faces()) {
    glm::uvec3 t;
    int k = 0;
    for (const auto& v : om.fv_range(f)) t[k++] = uint32_t(v.idx());
    out.triangles.push_back(t);
  }
  return out;
}

}  // namespace hyb
