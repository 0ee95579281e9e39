#include "render/bvh.h"

#include <embree3/rtcore.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <mutex>
#include <optional>

#include "volume/core/error.h"

namespace hyb {

namespace {

// One Embree device for the process (its threads and memory pools), made at the first BVH.
RTCDevice device() {
  static RTCDevice d = [] {
    RTCDevice made = rtcNewDevice(nullptr);
    if (!made) HYB_THROW(RuntimeError, "Embree: cannot create a device (error ", int(rtcGetDeviceError(nullptr)), ")");
    return made;
  }();
  return d;
}

// What a query passes its filter: the mesh, the ray in double precision and the hits so far.
struct Query {
  RTCIntersectContext context;  // first: Embree hands the filter this pointer
  const std::vector<const TriangleMesh*>* meshes;
  glm::dvec3 origin, dir;
  double tMin, tMax;
  std::vector<Hit>* hits;  // every hit (allHits), or null: the nearest only, in nearest (firstHit)
  std::optional<Hit> nearest;
};

// Records the crossing Embree found, measured again in double precision (Möller–Trumbore on the
// same triangle), and rejects it so that the traversal goes on to the next; for firstHit, keeps
// the nearest as Embree measured it and accepts it, so that Embree leaves out what lies beyond.
void recordHit(const RTCFilterFunctionNArguments* args) {
  Query& q = *reinterpret_cast<Query*>(args->context);
  const uint32_t prim = RTCHitN_primID(args->hit, args->N, 0), part = RTCHitN_geomID(args->hit, args->N, 0);
  const TriangleMesh& mesh = *(*q.meshes)[part];
  const glm::uvec3 tri = mesh.triangles[prim];
  const glm::dvec3 p0 = mesh.vertices[tri.x], p1 = mesh.vertices[tri.y], p2 = mesh.vertices[tri.z];
  const glm::dvec3 e1 = p1 - p0, e2 = p2 - p0;
  double t = RTCRayN_tfar(args->ray, args->N, 0), u = RTCHitN_u(args->hit, args->N, 0), v = RTCHitN_v(args->hit, args->N, 0);
  if (q.hits) {
    args->valid[0] = 0;
    const glm::dvec3 pv = glm::cross(q.dir, e2);
    const double det = glm::dot(e1, pv);
    if (std::abs(det) >= 1e-18) {  // (edge-on: Embree's own numbers)
      const glm::dvec3 tv = q.origin - p0, qv = glm::cross(tv, e1);
      u = std::clamp(glm::dot(tv, pv) / det, 0.0, 1.0);
      v = std::clamp(glm::dot(q.dir, qv) / det, 0.0, 1.0 - u);
      t = glm::dot(e2, qv) / det;
    }
  }
  if (!(t > q.tMin && t < q.tMax)) {
    args->valid[0] = 0;
    return;
  }
  if (!q.hits && q.nearest && !(t < q.nearest->t || (t == q.nearest->t && part < q.nearest->part))) {
    args->valid[0] = 0;
    return;
  }
  const glm::dvec3 facet = glm::normalize(glm::cross(e1, e2));
  Hit hit{t, facet, part};
  if (!mesh.normals.empty()) {
    const glm::dvec3 n = (1.0 - u - v) * glm::dvec3(mesh.normals[tri.x]) + u * glm::dvec3(mesh.normals[tri.y]) + v * glm::dvec3(mesh.normals[tri.z]);
    const double len = glm::length(n);
    if (len > 0.0) hit.normal = n / len;
  }
  if (q.hits)
    q.hits->push_back(hit);
  else
    q.nearest = hit;
}

// Embree's ray for a query from @p o along @p d over (tMin, tMax), widened by float's rounding of
// the origin and of finite bounds: the filter keeps only tMin < t < tMax, in double. A bound beyond
// float's range is none.
RTCRayHit rayOf(const glm::dvec3& o, const glm::dvec3& d, double tMin, double tMax) {
  RTCRayHit rh{};
  rh.ray.org_x = float(o.x);
  rh.ray.org_y = float(o.y);
  rh.ray.org_z = float(o.z);
  rh.ray.dir_x = float(d.x);
  rh.ray.dir_y = float(d.y);
  rh.ray.dir_z = float(d.z);
  constexpr double kFloatMax = double(std::numeric_limits<float>::max());
  const bool far = !(tMax < 0.5 * kFloatMax);
  const double slack = 1e-6 * (glm::length(o) + std::abs(tMin) + (far ? 0.0 : std::abs(tMax))) + 1e-6;
  rh.ray.tnear = float(std::clamp(tMin - slack, 0.0, 0.5 * kFloatMax));
  rh.ray.tfar = far ? std::numeric_limits<float>::infinity() : float(tMax + slack);
  rh.ray.mask = ~0u;
  rh.ray.flags = 0;
  rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  return rh;
}

}  // namespace

Bvh::Bvh(const std::vector<const TriangleMesh*>& meshes) : mMeshes(meshes) {
  size_t triangles = 0;
  for (const TriangleMesh* mesh : meshes) triangles += mesh->triangles.size();
  if (triangles == 0) return;
  RTCDevice dev = device();
  RTCScene scene = rtcNewScene(dev);
  rtcSetSceneFlags(scene, RTC_SCENE_FLAG_ROBUST);  // no shortcuts that could miss a crossing
  rtcSetSceneBuildQuality(scene, RTC_BUILD_QUALITY_HIGH);  // built once per surface, traced by every reference frame
  for (size_t part = 0; part < meshes.size(); ++part) {
    const TriangleMesh& mesh = *meshes[part];
    if (mesh.triangles.empty()) continue;  // (attached by ID: the others keep their places)
    RTCGeometry geometry = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_TRIANGLE);
    // Copies (Embree pads its buffers for its vector loads): 12 bytes a vertex, 12 a triangle.
    auto* vertices = static_cast<float*>(rtcSetNewGeometryBuffer(geometry, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), mesh.vertices.size()));
    auto* indices = static_cast<unsigned*>(rtcSetNewGeometryBuffer(geometry, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(unsigned), mesh.triangles.size()));
    if (!vertices || !indices) {
      rtcReleaseGeometry(geometry);
      rtcReleaseScene(scene);
      HYB_THROW(RuntimeError, "Embree: cannot allocate the buffers of ", mesh.triangles.size(), " triangles");
    }
    std::memcpy(vertices, mesh.vertices.data(), mesh.vertices.size() * sizeof(glm::vec3));
    std::memcpy(indices, mesh.triangles.data(), mesh.triangles.size() * sizeof(glm::uvec3));
    rtcSetGeometryIntersectFilterFunction(geometry, recordHit);
    rtcCommitGeometry(geometry);
    rtcAttachGeometryByID(scene, geometry, unsigned(part));
    rtcReleaseGeometry(geometry);
  }
  rtcCommitScene(scene);
  if (const RTCError e = rtcGetDeviceError(dev); e != RTC_ERROR_NONE) {
    rtcReleaseScene(scene);
    HYB_THROW(RuntimeError, "Embree: cannot build the BVH of ", triangles, " triangles (error ", int(e), ")");
  }
  mScene = scene;
}

Bvh::~Bvh() {
  if (mScene) rtcReleaseScene(mScene);
}

void Bvh::allHits(const glm::dvec3& o, const glm::dvec3& d, double tMin, double tMax, std::vector<Hit>* hits) const {
  hits->clear();
  if (!mScene) return;
  Query q{{}, &mMeshes, o, d, tMin, tMax, hits, std::nullopt};
  rtcInitIntersectContext(&q.context);
  RTCRayHit rh = rayOf(o, d, tMin, tMax);
  rtcIntersect1(mScene, &q.context, &rh);
  // A ray through an edge or vertex shared by several triangles of a mesh crosses it once there (and
  // Embree's spatial splits may report one triangle twice); equal distances are ordered by mesh.
  std::sort(hits->begin(), hits->end(), [](const Hit& a, const Hit& b) { return a.t != b.t ? a.t < b.t : a.part < b.part; });
  auto same = [](const Hit& a, const Hit& b) { return a.part == b.part && std::abs(a.t - b.t) < 1e-9 * (1 + std::abs(a.t)); };
  hits->erase(std::unique(hits->begin(), hits->end(), same), hits->end());
}

std::optional<Hit> Bvh::firstHit(const glm::dvec3& o, const glm::dvec3& d, double tMin, double tMax) const {
  if (!mScene) return std::nullopt;
  Query q{{}, &mMeshes, o, d, tMin, tMax, nullptr, std::nullopt};
  rtcInitIntersectContext(&q.context);
  RTCRayHit rh = rayOf(o, d, tMin, tMax);
  rtcIntersect1(mScene, &q.context, &rh);
  return q.nearest;
}

}  // namespace hyb
