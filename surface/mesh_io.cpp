// OpenMesh lives in this translation unit only (STYLE 6).
#include <OpenMesh/Core/IO/MeshIO.hh>  // first, so the readers and writers register
#include <OpenMesh/Core/Mesh/TriMesh_ArrayKernelT.hh>

#include "surface/mesh_io.h"

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "volume/core/error.h"
#include "volume/core/file_util.h"

namespace hyb {

namespace {

using OMesh = OpenMesh::TriMesh_ArrayKernelT<>;

// Silences OpenMesh's logs while it lives: its readers and writers print what they do, and its
// mesh reports rejected faces; failures reach us as return values, reported in our own words.
class Quiet {
 public:
  Quiet() : mLog(omlog().is_enabled()), mOut(omout().is_enabled()), mErr(omerr().is_enabled()) {
    omlog().disable();
    omout().disable();
    omerr().disable();
  }
  Quiet(const Quiet&) = delete;
  Quiet& operator=(const Quiet&) = delete;
  ~Quiet() {
    if (mLog) omlog().enable();
    if (mOut) omout().enable();
    if (mErr) omerr().enable();
  }

 private:
  bool mLog, mOut, mErr;
};

// OpenMesh does not write a file for a mesh without vertices: the format's empty form.
std::string emptyBytes(const std::string& ext) {
  if (ext == ".ply")
    return "ply\nformat binary_little_endian 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
           "property float z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n";
  if (ext == ".off") return "OFF\n0 0 0\n";
  if (ext == ".obj") return "# empty mesh\n";
  // binary STL: 80-byte header and a zero triangle count
  return std::string(80, ' ') + std::string(4, '\0');
}

// Records the coordinates' space where 3D Slicer looks for it: a PLY "comment SPACE=LPS" header
// line, an OBJ "# SPACE=LPS" line, or the STL's 80-byte header.
void recordSpace(std::string* bytes, const std::string& ext, const std::string& space, const std::string& path) {
  if (ext == ".off") return;
  const std::string tag = "SPACE=" + space;
  if (ext == ".stl") {
    if (bytes->size() < 84) HYB_THROW(IoError, path, ": the STL writer produced ", bytes->size(), " bytes (expected at least 84)");
    std::string header = "hybrid-octree " + tag;
    header.resize(80, ' ');
    bytes->replace(0, 80, header);
    return;
  }
  size_t at = 0;
  if (ext == ".ply") {  // after "ply" and the "format" line
    for (int l = 0; l < 2; ++l) {
      const size_t nl = bytes->find('\n', at);
      if (nl == std::string::npos) HYB_THROW(IoError, path, ": the PLY writer produced no header");
      at = nl + 1;
    }
  }
  bytes->insert(at, ext == ".ply" ? "comment " + tag + "\n" : "# " + tag + "\n");
}

}  // namespace

const std::vector<MeshFormat>& meshFormats() {
  static const std::vector<MeshFormat> formats = {{".ply", true, true}, {".obj", false, true}, {".stl", true, false}, {".off", false, false}};
  return formats;
}

const MeshFormat* meshFormatOf(const std::string& path) {
  const std::string ext = fileExtension(path);
  for (const MeshFormat& f : meshFormats())
    if (f.extension == ext) return &f;
  return nullptr;
}

std::string meshExtensionsText(bool withNormals, bool dots) {
  std::vector<std::string> names;
  for (const MeshFormat& f : meshFormats())
    if (!withNormals || f.normals) names.push_back(dots ? f.extension : f.extension.substr(1));
  std::string text;
  for (size_t i = 0; i < names.size(); ++i) text += (i == 0 ? "" : i + 1 == names.size() ? " or " : ", ") + names[i];
  return text;
}

void writeMesh(const std::string& path, const TriangleMesh& mesh, const MeshWriteOptions& options) {
  const MeshFormat* format = meshFormatOf(path);
  if (!format) HYB_THROW(IoError, path, ": unknown mesh format '", fileExtension(path), "' (expected ", meshExtensionsText(), ")");
  const std::string bytes = meshBytes(mesh, *format, options, path);
  writeFileAtomically(path, [&](std::ostream& out) { out.write(bytes.data(), std::streamsize(bytes.size())); });
}

std::string meshBytes(const TriangleMesh& mesh, const MeshFormat& format, const MeshWriteOptions& options, const std::string& name) {
  const std::string& ext = format.extension;
  const bool normals = options.normals && !mesh.normals.empty();
  if (options.normals && !format.normals)
    HYB_THROW(IoError, name, ": vertex normals can be written to ", meshExtensionsText(true), " files only (STL keeps facet normals, OFF none)");
  if (mesh.triangles.empty()) return emptyBytes(ext);
  OMesh om;
  if (normals) om.request_vertex_normals();
  om.reserve(mesh.vertices.size(), mesh.triangles.size() * 3 / 2, mesh.triangles.size());
  std::vector<OMesh::VertexHandle> vh;
  vh.reserve(mesh.vertices.size());
  for (size_t i = 0; i < mesh.vertices.size(); ++i) {
    const glm::vec3& p = mesh.vertices[i];
    vh.push_back(om.add_vertex(OMesh::Point(p.x, p.y, p.z)));
    if (normals) om.set_normal(vh.back(), OMesh::Normal(mesh.normals[i].x, mesh.normals[i].y, mesh.normals[i].z));
  }
  {
    // OpenMesh reports each face its half-edge structure rejects on omerr; those are expected here
    // (classic MC's non-manifold edges) and handled below.
    const Quiet quiet;
    for (const glm::uvec3& t : mesh.triangles)
      if (!om.add_face(vh[t.x], vh[t.y], vh[t.z]).is_valid()) {
        // A face OpenMesh's half-edge structure cannot take (non-manifold): keep it with own vertices.
        OMesh::VertexHandle copy[3];
        for (int k = 0; k < 3; ++k) {
          const OMesh::Point p = om.point(vh[t[k]]);  // a copy: adding a vertex may move the points
          copy[k] = om.add_vertex(p);
          if (normals) om.set_normal(copy[k], OMesh::Normal(mesh.normals[t[k]].x, mesh.normals[t[k]].y, mesh.normals[t[k]].z));
        }
        om.add_face(copy[0], copy[1], copy[2]);
      }
  }
  OpenMesh::IO::Options io;
  if (format.binary) io += OpenMesh::IO::Options::Binary;
  if (normals) io += OpenMesh::IO::Options::VertexNormal;
  // Written to memory, then to the file by our own stream: OpenMesh's file writers report success
  // on a full disk.
  std::ostringstream made(std::ios::binary);
  if (ext == ".obj") made << std::fixed;  // as OpenMesh's OBJ file writer formats its numbers
  {
    const Quiet quiet;  // the writers log what they write ("[STLWriter] : write binary file")
    if (!OpenMesh::IO::write_mesh(om, made, ext.substr(1), io) || !made)
      HYB_THROW(IoError, name, ": OpenMesh could not write the mesh");
  }
  std::string bytes = std::move(made).str();
  if (!options.space.empty()) recordSpace(&bytes, ext, options.space, name);
  return bytes;
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
  om.request_vertex_normals();
  OpenMesh::IO::Options options = OpenMesh::IO::Options::VertexNormal;
  const Quiet quiet;
  if (!OpenMesh::IO::read_mesh(om, path, options)) HYB_THROW(IoError, path, ": OpenMesh could not read the mesh");
  const bool normals = options.check(OpenMesh::IO::Options::VertexNormal);
  for (const auto& v : om.vertices()) {
    const auto p = om.point(v);
    out.vertices.push_back({p[0], p[1], p[2]});
    if (normals) {
      const auto n = om.normal(v);
      out.normals.push_back({n[0], n[1], n[2]});
    }
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
