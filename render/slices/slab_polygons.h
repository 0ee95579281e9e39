// SlabPolygon lists (Boada and Navazo 2002, §4.1, corrected and in view-aligned form as
// docs/renderer.md states):
// every translucent surface polygon of a brick is put into each slab [kΔ, (k+1)Δ) between two of
// the brick's proxies that its depth range covers, and the instances are sorted far to near (by
// slab, then by depth inside a slab), so that the slice renderer draws them between the right two
// slices and surface and volume composite in depth order at any resolution. The lists are rebuilt
// for every view. A triangle that covers several slabs is drawn once in each, whole, and its
// fragments outside the slab are discarded (planes and shells alike): the slabs partition its
// fragments exactly. Cutting it into pieces on the CPU instead (as the paper does) gave a clinical
// surface's 512² frame 1.4 times the triangles and vertices for llvmpipe to set up.
#pragma once

#include <glm/glm.hpp>

#include <array>
#include <cstdint>
#include <limits>
#include <span>
#include <vector>

#include "hybrid_octree/selection.h"
#include "hybrid_octree/volume_octree.h"
#include "render/regions.h"
#include "render/slices/proxy_geometry.h"
#include "surface/mesh.h"
#include "volume/volume.h"

namespace hyb {

/// One brick's vertex stream, as the slice shader takes it: 9 floats a vertex, position (mm),
/// normal, kind (0 a slice, 1 a surface triangle), and the depths its fragments must lie within,
/// [near, far) (±1e30 where the triangle is in one slab, or at the ends of those it covers).
inline constexpr int kStreamFloats = 9;
/// Appends one vertex to @p stream.
inline void putVertex(std::vector<float>* stream, const glm::vec3& p, const glm::vec3& n, float kind, float lo, float hi) {
  stream->insert(stream->end(), {p.x, p.y, p.z, n.x, n.y, n.z, kind, lo, hi});
}

/// A surface's planar polygons: polygon p is triangles [starts[p], starts[p + 1]) of the mesh. A
/// mesh that says nothing of polygons has one polygon a triangle.
struct SurfacePolygons {
  const TriangleMesh* mesh = nullptr;
  std::vector<uint32_t> starts;
  /// Per polygon, the colour it is drawn with (the stream's kind is 1 + it: the slice shader's
  /// table of colours, 0 the isosurface's), or empty: all 0.
  std::vector<uint16_t> colors;
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
/// With @p region (a sort-last frame's), centroids are taken inside it, so that a piece of a polygon
/// cut to the region goes to one of its bricks.
BrickPolygons polygonsByBrick(const Volume& volume, const VolumeOctree& octree, const Selection& selection, const SurfacePolygons& surface,
                              const RegionBox* region = nullptr);

/// The pixel centres a frame samples. Coverage is sampled at pixel centres, so a triangle whose
/// projected bounding box holds none draws no fragment and is left out; one whose box holds a few
/// is tested against each: covering none it is left out too, and where the depths of those it
/// covers lie in one slab it is drawn in that slab alone, whole. Most of a clinical surface's
/// triangles are smaller than a pixel of a 512² frame.
class PixelCentres {
 public:
  PixelCentres(const glm::mat4& viewProj, int width, int height);
  /// What a triangle covers, where that is sure: the number of pixel centres, and (given @p depth)
  /// the depths the fragments there may take, each widened by what 1/64 pixel and float rounding
  /// can change. Not known for a triangle whose box is wider than kMaxCentres pixels or holds more
  /// than kMaxCentres centres, that reaches behind the eye, or that passes within 1/64 pixel of a
  /// centre (llvmpipe snaps vertices to 1/256 pixel): those are drawn in every slab their depth
  /// range covers.
  struct Cover {
    bool known = false;
    int centres = 0;
    double nearest = 0, farthest = 0;
  };
  static constexpr int kMaxCentres = 4;
  Cover cover(const glm::vec3& a, const glm::vec3& b, const glm::vec3& c, const ProxyDepth* depth) const;
  /// Whether the box [@p lo, @p hi] lies in front of the eye and more than a pixel beside the image
  /// on one side: cover() knows every triangle inside it to cover no centre.
  bool besideImage(const glm::dvec3& lo, const glm::dvec3& hi) const;

 private:
  glm::dmat4 mViewProj, mInverse;
  glm::dvec2 mSize;
};

/// The slabs of one brick: width @p delta (mm) along @p depth.
struct SlabLayout {
  ProxyDepth depth;
  double delta = 0.0;
  bool sliced = true;  ///< false: the brick has no slices, its polygons all in slab 0
  bool cut = true;     ///< false: each polygon whole in the slab of its centroid's depth
};

/// Polygons of one brick from one surface (the isosurface, or the user meshes' pieces).
struct SlabSource {
  const SurfacePolygons* surface = nullptr;
  std::span<const uint32_t> polygons;
};

/// One brick's SlabPolygon list.
class SlabPolygonList {
 public:
  /// As the one-surface build, over the polygons of several surfaces sorted together (ties in the
  /// order of the sources).
  void build(std::span<const SlabSource> sources, const SlabLayout& slabs, const PixelCentres* centres = nullptr);
  /// Buckets @p polygons of @p surface into the slabs of @p slabs that their depth ranges cover,
  /// and sorts the instances far to near (polygons of equal depth in their order in @p polygons).
  /// In a brick without slices every polygon is one instance in slab 0, sorted back to front by its
  /// centroid; uncut, every polygon is one instance, whole, in the slab of its centroid's depth.
  /// Triangles that @p centres says cover no pixel centre are left out (the polygon's depth stays
  /// that of all its triangles), and those whose covered centres lie in one slab go to that slab alone.
  void build(const SurfacePolygons& surface, std::span<const uint32_t> polygons, const SlabLayout& slabs, const PixelCentres* centres = nullptr) {
    const SlabSource one{&surface, polygons};
    build(std::span<const SlabSource>(&one, 1), slabs, centres);
  }
  /// Whether no polygon was placed.
  bool empty() const { return mInstances.empty(); }
  /// The first and last slab the polygons cover (when sliced and not empty).
  long long firstSlab() const { return mFirst; }
  long long lastSlab() const { return mLast; }
  /// Appends to @p stream the triangles of the instances in slabs ≥ @p slab not emitted yet, far
  /// to near, each with its slab's depths; the normals are the mesh's vertex normals, or each
  /// triangle's own; the kind is 1 + the polygon's colour (SurfacePolygons::colors).
  void emitDownTo(long long slab, std::vector<float>* stream);
  /// Appends everything not emitted yet.
  void emitRest(std::vector<float>* stream) { emitDownTo(std::numeric_limits<long long>::min(), stream); }
  /// Triangles placed (those left out included), those left out, and triangles drawn (once per
  /// slab each covers).
  uint64_t triangles() const { return mTriangles; }
  uint64_t unseen() const { return mUnseen; }
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

  // A polygon of the list: its surface (index into mSurfaces) and its index there.
  struct Polygon {
    uint32_t source, index;
  };
  std::vector<const SurfacePolygons*> mSurfaces;
  double mDelta = 1.0;
  std::vector<Instance> mInstances;
  size_t mNext = 0;                                  // instances emitted so far
  std::vector<Polygon> mPolygons;                    // the brick's polygons
  std::vector<uint32_t> mFirstSpan;                  // per polygon: its first triangle's span
  std::vector<std::array<int32_t, 2>> mSpans;        // the slabs each triangle covers (first > last: left out)
  long long mFirst = 0, mLast = -1;
  uint64_t mTriangles = 0, mUnseen = 0, mDraws = 0;
};

/// Distance from @p p to the triangle (a, b, c) (Ericson, Real-Time Collision Detection, 5.1.5).
double distanceToTriangle(const glm::dvec3& p, const glm::dvec3& a, const glm::dvec3& b, const glm::dvec3& c);

}  // namespace hyb
