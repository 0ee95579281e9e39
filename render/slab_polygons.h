// SlabPolygon lists (Boada and Navazo 2002, §4.1; DESIGN 3.4, corrected and in view-aligned form):
// every translucent surface polygon of a brick is put into each slab [kΔ, (k+1)Δ) between two of
// the brick's proxies that its depth range covers, cut to that slab, and the pieces are sorted far
// to near (by slab, then by depth inside a slab), so that the slice renderer draws them between
// the right two slices and surface and volume composite in depth order at any resolution. The
// lists are rebuilt for every view. Planar slabs are cut here on the CPU (llvmpipe's clipper was
// the costliest step of drawing slab triangles); shell slabs are clipped per fragment.
#pragma once

#include <glm/glm.hpp>

#include <array>
#include <cstdint>
#include <limits>
#include <span>
#include <utility>
#include <vector>

#include "hybrid_octree/selection.h"
#include "hybrid_octree/volume_octree.h"
#include "render/proxy_geometry.h"
#include "surface/mesh.h"
#include "volume/volume.h"

namespace hyb {

/// One brick's vertex stream, as the slice shader takes it: 9 floats a vertex, position (mm),
/// normal, kind (0 a slice, 1 a surface piece), and the near and far depth of the piece's slab
/// (shells only; ±1e30 elsewhere).
inline constexpr int kStreamFloats = 9;
/// Appends one vertex to @p stream.
inline void putVertex(std::vector<float>* stream, const glm::vec3& p, const glm::vec3& n, float kind, float lo, float hi) {
  stream->insert(stream->end(), {p.x, p.y, p.z, n.x, n.y, n.z, kind, lo, hi});
}

/// A surface's planar polygons: polygon p is triangles [starts[p], starts[p + 1]) of the mesh and,
/// when it is convex, its boundary loops[loopStarts[p] .. loopStarts[p + 1]) (a slab cuts those
/// whole). A mesh that says nothing of polygons has one polygon a triangle.
struct SurfacePolygons {
  const TriangleMesh* mesh = nullptr;
  std::vector<uint32_t> starts;
  std::span<const uint32_t> loopStarts, loops;
  explicit SurfacePolygons(const TriangleMesh& surface);
  size_t count() const { return starts.size() - 1; }
};

/// The surface's polygons by brick: the brick holding each polygon's centroid (Surface Octree
/// polygons lie inside one volume leaf, hence one brick), as one list in brick order.
struct BrickPolygons {
  std::vector<uint32_t> offsets, list;
  /// Brick @p b's polygons (indices into the SurfacePolygons).
  std::span<const uint32_t> of(size_t b) const { return {list.data() + offsets[b], list.data() + offsets[b + 1]}; }
};
BrickPolygons polygonsByBrick(const Volume& volume, const VolumeOctree& octree, const Selection& selection, const SurfacePolygons& surface);

/// One brick's SlabPolygon list.
class SlabPolygonList {
 public:
  /// Buckets @p polygons of @p surface into the slabs of width @p delta along @p depth that their
  /// depth ranges cover, and sorts the instances far to near. With @p sliced false (a brick without
  /// slices) every polygon is one instance in slab 0, sorted back to front by its centroid; with
  /// @p cut false every polygon is one instance, whole, in the slab of its centroid's depth.
  void build(const SurfacePolygons& surface, std::span<const uint32_t> polygons, const ProxyDepth& depth, double delta, bool sliced, bool cut = true);
  /// Whether no polygon was placed.
  bool empty() const { return mInstances.empty(); }
  /// The first and last slab the polygons cover (when sliced and not empty).
  long long firstSlab() const { return mFirst; }
  long long lastSlab() const { return mLast; }
  /// Appends to @p stream the pieces of the instances in slabs ≥ @p slab not emitted yet, far to
  /// near; the normals are the mesh's vertex normals, interpolated where a piece is cut, or each
  /// triangle's own.
  void emitDownTo(long long slab, std::vector<float>* stream);
  /// Appends everything not emitted yet.
  void emitRest(std::vector<float>* stream) { emitDownTo(std::numeric_limits<long long>::min(), stream); }
  /// Triangles placed, and pieces drawn (a triangle's, or a convex polygon's, part in one slab).
  uint64_t triangles() const { return mTriangles; }
  uint64_t draws() const { return mDraws; }

 private:
  // A slab instance: sort key (the polygon's centroid depth, clamped to the slab), slab, and the
  // polygon's place in mPolygons (16 bytes: sorting is a frame's cost).
  struct Instance {
    double depth;
    int32_t slab;
    uint32_t polygon;
  };
  void emit(const Instance& in, std::vector<float>* stream);
  void emitTriangle(uint32_t triangle, int32_t slab, bool clip, std::vector<float>* stream);
  void emitClipped(int32_t slab, std::vector<float>* stream);

  const SurfacePolygons* mSurface = nullptr;
  ProxyDepth mDepth;
  double mDelta = 1.0;
  bool mSmooth = false;
  std::vector<Instance> mInstances;
  size_t mNext = 0;                                  // instances emitted so far
  std::vector<uint32_t> mPolygons;                   // the brick's polygons (surface indices)
  std::vector<std::array<int32_t, 2>> mPolygonSpans;  // per polygon: the slabs it covers
  std::vector<uint32_t> mFirstSpan;                  // per polygon: its first triangle's span
  std::vector<std::array<int32_t, 2>> mSpans;        // the slabs each triangle covers
  std::vector<std::pair<glm::dvec3, glm::vec3>> mPiece, mKept;  // a piece being cut: positions, normals
  long long mFirst = 0, mLast = -1;
  uint64_t mTriangles = 0, mDraws = 0;
};

/// Distance from @p p to the triangle (a, b, c) (Ericson, Real-Time Collision Detection, 5.1.5).
double distanceToTriangle(const glm::dvec3& p, const glm::dvec3& a, const glm::dvec3& b, const glm::dvec3& c);

}  // namespace hyb
