#include "render/user_meshes.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <iterator>
#include <numeric>
#include <sstream>
#include <tuple>

#include "surface/mesh_io.h"
#include "volume/core/error.h"

namespace hyb {

namespace {

// The part of a mesh file where 3D Slicer records its space: an STL's 80-byte header, a PLY's
// header, the leading comment lines of an OBJ or OFF.
std::string headerOf(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::string head(4096, '\0');
  in.read(head.data(), std::streamsize(head.size()));
  head.resize(size_t(in.gcount()));
  const MeshFormat* format = meshFormatOf(path);
  const std::string ext = format ? format->extension : "";
  if (ext == ".stl") return head.substr(0, std::min<size_t>(head.size(), 80));
  if (ext == ".ply") return head.substr(0, head.find("end_header"));
  std::string comments;
  std::istringstream lines(head);
  for (std::string line; std::getline(lines, line);) {
    if (line.rfind("OFF", 0) == 0 && comments.empty()) continue;
    if (line.empty() || line[0] != '#') break;
    comments += line + "\n";
  }
  return comments;
}

// Sutherland–Hodgman of @p poly at the plane p[axis] = s, both sides at once.
void split(const std::vector<glm::dvec3>& poly, int axis, double s, std::vector<glm::dvec3>* below, std::vector<glm::dvec3>* above) {
  below->clear();
  above->clear();
  for (size_t i = 0; i < poly.size(); ++i) {
    const glm::dvec3& a = poly[i];
    const glm::dvec3& b = poly[(i + 1) % poly.size()];
    const bool aBelow = a[axis] < s, bBelow = b[axis] < s;
    (aBelow ? below : above)->push_back(a);
    if (aBelow != bBelow) {
      glm::dvec3 c = a + (b - a) * ((s - a[axis]) / (b[axis] - a[axis]));
      c[axis] = s;
      below->push_back(c);
      above->push_back(c);
    }
  }
}

// Cuts one triangle at the leaf cells' faces inside the volume and appends its pieces.
class LeafCutter {
 public:
  LeafCutter(const VolumeOctree& octree, const glm::dvec3& spacing, GridMeshes* out) : mOut(out) {
    const glm::ivec3 cells = glm::max(octree.dims() - 1, glm::ivec3(1));
    mCells = (cells + octree.leafEdge() - 1) / octree.leafEdge();
    mCellMm = double(octree.leafEdge()) * spacing;
  }

  void cut(const glm::dvec3& a, const glm::dvec3& b, const glm::dvec3& c, uint16_t mesh) {
    mMesh = mesh;
    along(0, {a, b, c});
  }

 private:
  int cellOf(double x, int axis) const { return std::clamp(int(std::floor(x / mCellMm[axis])), 0, mCells[axis] - 1); }

  void along(int axis, std::vector<glm::dvec3> poly) {
    if (axis == 3) return emit(poly);
    int lo = mCells[axis], hi = -1;
    for (const glm::dvec3& p : poly) {
      lo = std::min(lo, cellOf(p[axis], axis));
      hi = std::max(hi, cellOf(p[axis], axis));
    }
    std::vector<glm::dvec3> below, above;
    for (int c = lo; c < hi && poly.size() >= 3; ++c) {
      split(poly, axis, double(c + 1) * mCellMm[axis], &below, &above);
      if (below.size() >= 3) along(axis + 1, below);
      poly.swap(above);
    }
    if (poly.size() >= 3) along(axis + 1, std::move(poly));
  }

  void emit(const std::vector<glm::dvec3>& poly) {
    TriangleMesh& m = mOut->pieces;
    glm::dvec3 area(0.0);
    for (size_t k = 1; k + 1 < poly.size(); ++k) area += glm::cross(poly[k] - poly[0], poly[k + 1] - poly[0]);
    if (!(glm::length(area) > 0.0)) return;  // a sliver left on a cell's face
    const uint32_t first = uint32_t(m.vertices.size());
    for (const glm::dvec3& p : poly) m.vertices.push_back(glm::vec3(p));
    for (uint32_t k = 1; k + 1 < poly.size(); ++k) m.triangles.push_back({first, first + k, first + k + 1});
    m.polygonStarts.push_back(uint32_t(m.triangles.size()));
    mOut->pieceMesh.push_back(mMesh);
  }

  GridMeshes* mOut;
  glm::ivec3 mCells;
  glm::dvec3 mCellMm;
  uint16_t mMesh = 0;
};

}  // namespace

std::optional<MeshSpace> meshFileSpace(const std::string& path) {
  const std::string head = headerOf(path);
  const size_t at = head.find("SPACE=");
  if (at == std::string::npos) return std::nullopt;
  const std::string word = head.substr(at + 6, 3);
  if (word == "RAS") return MeshSpace::RAS;
  if (word == "LPS") return MeshSpace::LPS;
  return std::nullopt;
}

void checkUserMesh(const TriangleMesh& mesh, const std::string& name) {
  if (mesh.triangles.empty()) HYB_THROW(ValueError, name, ": the mesh has no triangles");
  for (size_t v = 0; v < mesh.vertices.size(); ++v) {
    const glm::vec3& p = mesh.vertices[v];
    if (!(std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z)))
      HYB_THROW(ValueError, name, ": vertex ", v, " is not finite (", p.x, ", ", p.y, ", ", p.z, ")");
  }
  for (size_t t = 0; t < mesh.triangles.size(); ++t)
    for (int k = 0; k < 3; ++k)
      if (mesh.triangles[t][k] >= mesh.vertices.size())
        HYB_THROW(ValueError, name, ": triangle ", t, " uses vertex ", mesh.triangles[t][k], " (expected indices below ", mesh.vertices.size(), ")");
}

UserMesh readUserMesh(const std::string& path, const glm::vec4& color, MeshSpace space) {
  if (!meshFormatOf(path)) HYB_THROW(IoError, path, ": not a mesh file (expected ", meshExtensionsText(), ")");
  TriangleMesh mesh = readMesh(path);
  checkUserMesh(mesh, path);
  mesh.normals.clear();
  if (meshFileSpace(path).value_or(space) == MeshSpace::RAS)
    for (glm::vec3& p : mesh.vertices) p = glm::vec3(-p.x, -p.y, p.z);
  return UserMesh{path, std::make_shared<const TriangleMesh>(std::move(mesh)), color, nullptr};
}

size_t nonManifoldEdges(const TriangleMesh& mesh) {
  // Vertices at one position are one: a reader gives a face its half-edge structure cannot take
  // vertices of its own there.
  std::vector<uint32_t> order(mesh.vertices.size()), same(mesh.vertices.size());
  std::iota(order.begin(), order.end(), 0u);
  auto key = [&](uint32_t v) { return std::tuple(mesh.vertices[v].x, mesh.vertices[v].y, mesh.vertices[v].z); };
  std::sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) { return key(a) < key(b); });
  for (size_t i = 0; i < order.size(); ++i) same[order[i]] = i > 0 && key(order[i]) == key(order[i - 1]) ? same[order[i - 1]] : order[i];
  std::vector<uint64_t> edges;  // each triangle's edges, as their (lower, higher) vertices
  edges.reserve(3 * mesh.triangles.size());
  for (const glm::uvec3& t : mesh.triangles)
    for (int k = 0; k < 3; ++k) {
      const uint32_t a = same[t[k]], b = same[t[(k + 1) % 3]];
      edges.push_back(uint64_t(std::min(a, b)) << 32 | std::max(a, b));
    }
  std::sort(edges.begin(), edges.end());
  size_t shared = 0;
  for (size_t i = 0, j = 0; i < edges.size(); i = j) {
    for (j = i + 1; j < edges.size() && edges[j] == edges[i];) ++j;
    shared += j - i > 2;
  }
  return shared;
}

std::vector<std::string> userMeshWarnings(const UserMesh& m, const Volume& volume) {
  std::vector<std::string> out;
  const PatientFrame& frame = volume.frame();
  glm::dvec3 lo(1e300), hi(-1e300);
  for (const glm::vec3& p : m.mesh->vertices) {
    const glm::dvec3 g = frame.toGrid(glm::dvec3(p));
    lo = glm::min(lo, g);
    hi = glm::max(hi, g);
  }
  const glm::dvec3 box = volume.extentMm();
  if (glm::any(glm::lessThan(hi, glm::dvec3(0.0))) || glm::any(glm::greaterThan(lo, box)))
    out.push_back(detail::concat(m.name, ": the mesh lies wholly outside the volume's box (drawn where it is visible)"));
  const glm::dvec3 s = volume.spacing();
  const double voxel = std::min({s.x, s.y, s.z}), extent = std::max({hi.x - lo.x, hi.y - lo.y, hi.z - lo.z});
  if (extent < voxel)
    out.push_back(detail::concat(m.name, ": the mesh spans ", extent, " mm, less than one voxel (", voxel, " mm): in metres? (expected millimetres)"));
  if (const size_t edges = nonManifoldEdges(*m.mesh))
    out.push_back(detail::concat(m.name, ": ", edges, edges == 1 ? " edge is" : " edges are",
                                 " shared by more than two triangles (non-manifold): drawn as given, but a solid label volume's inside may be wrong there"));
  return out;
}

GridMeshes gridMeshes(const std::vector<UserMesh>& meshes, const PatientFrame& frame, const VolumeOctree& octree, const glm::dvec3& spacing) {
  GridMeshes out;
  out.pieces.polygonStarts.push_back(0);
  LeafCutter cutter(octree, spacing, &out);
  for (size_t k = 0; k < meshes.size(); ++k) {
    const TriangleMesh& in = *meshes[k].mesh;
    TriangleMesh whole{{}, in.triangles, {}, {}};
    whole.vertices.reserve(in.vertices.size());
    for (const glm::vec3& p : in.vertices) whole.vertices.push_back(glm::vec3(frame.toGrid(glm::dvec3(p))));
    for (const glm::uvec3& t : whole.triangles)
      cutter.cut(glm::dvec3(whole.vertices[t.x]), glm::dvec3(whole.vertices[t.y]), glm::dvec3(whole.vertices[t.z]), uint16_t(k));
    out.whole.push_back(std::move(whole));
    out.colors.push_back(meshes[k].color);
  }
  return out;
}

}  // namespace hyb
