#include "render/bvh.h"

#include <algorithm>
#include <cmath>
#include <numeric>

namespace hyb {

Bvh::Bvh(const TriangleMesh& mesh) : mMesh(&mesh) {
  const size_t n = mesh.triangles.size();
  if (n == 0) return;
  mTriangles.resize(n);
  std::iota(mTriangles.begin(), mTriangles.end(), 0u);
  std::vector<glm::vec3> centroid(n);
  for (size_t i = 0; i < n; ++i) {
    const glm::uvec3 t = mesh.triangles[i];
    centroid[i] = (mesh.vertices[t.x] + mesh.vertices[t.y] + mesh.vertices[t.z]) / 3.0f;
  }
  struct Task {
    uint32_t node, first, count;
  };
  mNodes.push_back({});
  std::vector<Task> stack{{0, 0, uint32_t(n)}};
  while (!stack.empty()) {
    const Task task = stack.back();
    stack.pop_back();
    glm::vec3 lo(1e30f), hi(-1e30f), clo(1e30f), chi(-1e30f);
    for (uint32_t i = task.first; i < task.first + task.count; ++i) {
      const glm::uvec3 t = mesh.triangles[mTriangles[i]];
      for (int k = 0; k < 3; ++k) {
        lo = glm::min(lo, mesh.vertices[t[k]]);
        hi = glm::max(hi, mesh.vertices[t[k]]);
      }
      clo = glm::min(clo, centroid[mTriangles[i]]);
      chi = glm::max(chi, centroid[mTriangles[i]]);
    }
    Node& node = mNodes[task.node];
    node.lo = lo;
    node.hi = hi;
    if (task.count <= 4) {
      node.first = task.first;
      node.count = task.count;
      continue;
    }
    const glm::vec3 ext = chi - clo;
    const int axis = ext.x > ext.y ? (ext.x > ext.z ? 0 : 2) : (ext.y > ext.z ? 1 : 2);
    const uint32_t mid = task.first + task.count / 2;
    std::nth_element(mTriangles.begin() + task.first, mTriangles.begin() + mid, mTriangles.begin() + task.first + task.count,
                     [&](uint32_t a, uint32_t b) { return centroid[a][axis] < centroid[b][axis]; });
    const uint32_t left = uint32_t(mNodes.size());
    node.first = left;
    node.count = 0;
    mNodes.push_back({});
    mNodes.push_back({});
    stack.push_back({left, task.first, mid - task.first});
    stack.push_back({left + 1, mid, task.first + task.count - mid});
  }
}

void Bvh::allHits(const glm::dvec3& o, const glm::dvec3& d, double tMin, double tMax, std::vector<Hit>* hits) const {
  hits->clear();
  if (mNodes.empty()) return;
  const glm::dvec3 inv(1.0 / d.x, 1.0 / d.y, 1.0 / d.z);
  uint32_t stack[64];
  int sp = 0;
  stack[sp++] = 0;
  while (sp > 0) {
    const Node& node = mNodes[stack[--sp]];
    // Slab test.
    double t0 = tMin, t1 = tMax;
    for (int a = 0; a < 3; ++a) {
      double ta = (double(node.lo[a]) - o[a]) * inv[a], tb = (double(node.hi[a]) - o[a]) * inv[a];
      if (ta > tb) std::swap(ta, tb);
      t0 = std::max(t0, ta);
      t1 = std::min(t1, tb);
    }
    if (t0 > t1 * (1 + 1e-12) + 1e-12) continue;
    if (node.count == 0) {
      stack[sp++] = node.first;
      stack[sp++] = node.first + 1;
      continue;
    }
    for (uint32_t i = node.first; i < node.first + node.count; ++i) {
      const glm::uvec3 tri = mMesh->triangles[mTriangles[i]];
      const glm::dvec3 p0 = mMesh->vertices[tri.x], p1 = mMesh->vertices[tri.y], p2 = mMesh->vertices[tri.z];
      // Möller–Trumbore in double precision.
      const glm::dvec3 e1 = p1 - p0, e2 = p2 - p0, pv = glm::cross(d, e2);
      const double det = glm::dot(e1, pv);
      if (std::abs(det) < 1e-18) continue;
      const double invDet = 1.0 / det;
      const glm::dvec3 tv = o - p0;
      const double u = glm::dot(tv, pv) * invDet;
      if (u < 0.0 || u > 1.0) continue;
      const glm::dvec3 qv = glm::cross(tv, e1);
      const double v = glm::dot(d, qv) * invDet;
      if (v < 0.0 || u + v > 1.0) continue;
      const double t = glm::dot(e2, qv) * invDet;
      if (t <= tMin || t >= tMax) continue;
      if (mMesh->normals.empty()) {
        hits->push_back({t, glm::normalize(glm::cross(e1, e2))});
      } else {
        const glm::dvec3 n = (1.0 - u - v) * glm::dvec3(mMesh->normals[tri.x]) + u * glm::dvec3(mMesh->normals[tri.y]) +
                             v * glm::dvec3(mMesh->normals[tri.z]);
        const double len = glm::length(n);
        hits->push_back({t, len > 0.0 ? n / len : glm::normalize(glm::cross(e1, e2))});
      }
    }
  }
  std::sort(hits->begin(), hits->end(), [](const Hit& a, const Hit& b) { return a.t < b.t; });
  // A ray through an edge or vertex shared by several triangles crosses the surface once there.
  auto same = [](const Hit& a, const Hit& b) { return std::abs(a.t - b.t) < 1e-9 * (1 + std::abs(a.t)); };
  hits->erase(std::unique(hits->begin(), hits->end(), same), hits->end());
}

}  // namespace hyb
