// CGAL is confined to this file: Polygon Mesh Processing for topology checks, self-intersection,
// orientation, volume, and the bounded-error Hausdorff distance (Sieger et al., CGAL 5.3+).
#include "surface/cgal_geometry.h"

#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Polygon_mesh_processing/distance.h>
#include <CGAL/Polygon_mesh_processing/measure.h>
#include <CGAL/Polygon_mesh_processing/orientation.h>
#include <CGAL/Polygon_mesh_processing/orient_polygon_soup.h>
#include <CGAL/Polygon_mesh_processing/polygon_soup_to_polygon_mesh.h>
#include <CGAL/Polygon_mesh_processing/self_intersections.h>
#include <CGAL/Surface_mesh.h>

#include <limits>
#include <map>

#include "volume/error.h"

namespace hyb {

namespace {

using Kernel = CGAL::Exact_predicates_inexact_constructions_kernel;
using Point = Kernel::Point_3;
using Mesh = CGAL::Surface_mesh<Point>;
namespace PMP = CGAL::Polygon_mesh_processing;

// Converts @p in; when it is not a polygon mesh, returns false unless @p repair, in which case
// non-manifold vertices and edges are duplicated (geometry unchanged) so distances can be measured.
bool toSurfaceMesh(const TriangleMesh& in, Mesh* out, bool repair = false) {
  std::vector<Point> points;
  points.reserve(in.vertices.size());
  for (const glm::vec3& p : in.vertices) points.emplace_back(p.x, p.y, p.z);
  std::vector<std::vector<size_t>> faces;
  faces.reserve(in.triangles.size());
  for (const glm::uvec3& t : in.triangles) faces.push_back({t.x, t.y, t.z});
  if (!PMP::is_polygon_soup_a_polygon_mesh(faces)) {
    if (!repair) return false;
    PMP::orient_polygon_soup(points, faces);
  }
  PMP::polygon_soup_to_polygon_mesh(points, faces, *out);
  return true;
}

}  // namespace

MeshCheck checkMesh(const TriangleMesh& mesh) {
  MeshCheck c;
  try {
    // Boundary edges counted on the soup, independently of CGAL's conversion.
    std::map<std::pair<uint32_t, uint32_t>, int> edges;
    for (const glm::uvec3& t : mesh.triangles)
      for (int k = 0; k < 3; ++k) ++edges[std::minmax(t[k], t[(k + 1) % 3])];
    for (const auto& [e, n] : edges) c.boundaryEdges += n == 1;
    Mesh m;
    c.manifold = toSurfaceMesh(mesh, &m);
    if (!c.manifold) return c;  // CGAL 5.5 tests self-intersection on polygon meshes only
    c.closed = CGAL::is_closed(m);
    c.selfIntersecting = PMP::does_self_intersect(m);
    if (c.closed && !c.selfIntersecting && !mesh.triangles.empty()) {
      c.outward = PMP::is_outward_oriented(m);
      c.volume = CGAL::to_double(PMP::volume(m));
    }
  } catch (const std::exception& e) {
    HYB_THROW(RuntimeError, "CGAL mesh check failed: ", e.what());
  }
  return c;
}

double hausdorffDistance(const TriangleMesh& a, const TriangleMesh& b, double errorBound) {
  if (a.triangles.empty() && b.triangles.empty()) return 0.0;
  if (a.triangles.empty() || b.triangles.empty()) return std::numeric_limits<double>::infinity();
  try {
    Mesh ma, mb;
    toSurfaceMesh(a, &ma, true);
    toSurfaceMesh(b, &mb, true);
    return PMP::bounded_error_symmetric_Hausdorff_distance<CGAL::Sequential_tag>(ma, mb, errorBound);
  } catch (const Error&) {
    throw;
  } catch (const std::exception& e) {
    HYB_THROW(RuntimeError, "CGAL Hausdorff distance failed: ", e.what());
  }
}

}  // namespace hyb
