#include "surface/mesh_ops.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <utility>

#include "volume/core/parallel.h"

namespace hyb {

bool flatTriangle(const glm::dvec3& a, const glm::dvec3& b, const glm::dvec3& c) {
  const double longest = std::max({glm::length(b - a), glm::length(c - b), glm::length(a - c)});
  const double scale = std::max({std::abs(a.x), std::abs(a.y), std::abs(a.z), std::abs(b.x), std::abs(b.y), std::abs(b.z), std::abs(c.x),
                                 std::abs(c.y), std::abs(c.z)});
  return glm::length(glm::cross(b - a, c - a)) <= floatResolutionMm(scale) * longest;
}

void removeUnreferencedVertices(TriangleMesh* mesh) {
  constexpr uint32_t kUnused = UINT32_MAX;
  std::vector<uint32_t> remap(mesh->vertices.size(), kUnused);
  for (const glm::uvec3& t : mesh->triangles)
    for (int k = 0; k < 3; ++k) remap[t[k]] = 0;
  uint32_t next = 0;
  for (size_t v = 0; v < remap.size(); ++v) {
    if (remap[v] == kUnused) continue;
    remap[v] = next;
    mesh->vertices[next] = mesh->vertices[v];
    if (!mesh->normals.empty()) mesh->normals[next] = mesh->normals[v];
    ++next;
  }
  if (next == mesh->vertices.size()) return;
  mesh->vertices.resize(next);
  if (!mesh->normals.empty()) mesh->normals.resize(next);
  for (glm::uvec3& t : mesh->triangles)
    for (int k = 0; k < 3; ++k) t[k] = remap[t[k]];
}

void setGradientNormals(const Volume& volume, TriangleMesh* mesh) {
  setGradientNormals(volume.spacing(), [&](std::span<const glm::vec3> points, glm::vec3* gradients) {
    for (size_t i = 0; i < points.size(); ++i) gradients[i] = volume.sampleGradient(points[i]);
  }, mesh);
}

void setGradientNormals(const glm::dvec3& spacing, const GradientsAt& gradients, TriangleMesh* mesh) {
  const size_t n = mesh->vertices.size();
  std::vector<glm::dvec3> faceSum(n, glm::dvec3(0.0));  // area-weighted: |cross| is twice the area
  for (const glm::uvec3& t : mesh->triangles) {
    const glm::dvec3 a(mesh->vertices[t.x]), b(mesh->vertices[t.y]), c(mesh->vertices[t.z]);
    const glm::dvec3 w = glm::cross(b - a, c - a);
    for (int k = 0; k < 3; ++k) faceSum[t[k]] += w;
  }
  mesh->normals.resize(n);
  const glm::dvec3 toVoxel = 1.0 / spacing;
  // Runs of neighbouring vertices (a mesh lists them in the order its faces were made): a paged
  // field reads each run's few tiles once.
  constexpr size_t kRun = 4096;
  ParallelFailure failure;
#pragma omp parallel for schedule(dynamic)
  for (size_t first = 0; first < n; first += kRun)
    failure.run([&] {
      const size_t count = std::min(kRun, n - first);
      std::vector<glm::vec3> points(count), g(count);
      for (size_t i = 0; i < count; ++i) points[i] = glm::vec3(glm::dvec3(mesh->vertices[first + i]) * toVoxel);
      gradients(points, g.data());
      for (size_t i = 0; i < count; ++i) {
        const size_t v = first + i;
        const glm::dvec3 gv(g[i]);
        const double len = glm::length(gv);
        const double faces = glm::length(faceSum[v]);
        mesh->normals[v] = len > 0.0 && std::isfinite(len) ? glm::vec3(-gv / len) : faces > 0.0 ? glm::vec3(faceSum[v] / faces) : glm::vec3(0, 0, 1);
      }
    });
  failure.rethrow();
}

void toPatientSpace(const PatientFrame& frame, TriangleMesh* mesh) {
  for (glm::vec3& p : mesh->vertices) p = glm::vec3(frame.toPatient(glm::dvec3(p)));
  for (glm::vec3& nrm : mesh->normals) nrm = glm::vec3(frame.vectorToPatient(glm::dvec3(nrm)));
  if (!frame.mirrored()) return;
  for (glm::uvec3& t : mesh->triangles) std::swap(t.y, t.z);
}

}  // namespace hyb
