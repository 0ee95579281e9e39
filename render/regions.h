// Sort-last regions: a frame's selected bricks split into N convex regions of whole octree
// subtrees (a k-d tree whose planes cut no brick), balanced by the bricks' cost, and the regions'
// visibility order from an eye. Each region's image, composited in that order with premultiplied
// "over", is the frame's image: the regions are convex and their k-d tree orders them exactly
// from any eye, perspective or orthographic. docs/distributed.md.
#pragma once

#include <glm/glm.hpp>

#include <cstdint>
#include <vector>

#include "hybrid_octree/selection.h"
#include "hybrid_octree/volume_octree.h"
#include "surface/mesh.h"

namespace hyb {

/// A region of space, grid frame mm (voxel (i,j,k) at (i·sx, j·sy, k·sz)): the points p with
/// lo ≤ p < hi on every axis. A face on the volume's boundary is at ±infinity, so the regions of
/// a split tile all of space and every point lies in exactly one.
struct RegionBox {
  glm::dvec3 lo{-INFINITY}, hi{INFINITY};
  bool contains(const glm::dvec3& p) const { return glm::all(glm::lessThanEqual(lo, p)) && glm::all(glm::lessThan(p, hi)); }
  bool empty() const { return !glm::all(glm::lessThan(lo, hi)); }
  bool operator==(const RegionBox&) const = default;
};

/// The split of a selection into regions.
struct Regions {
  std::vector<RegionBox> boxes;    ///< region r's box
  std::vector<uint32_t> brickRegion;  ///< the region of each brick of the selection
  std::vector<double> cost;        ///< each region's cost (regionCost summed over its bricks)
  /// The k-d tree: node 0 is the root; a leaf holds region = its index, an inner node the plane
  /// {p : p[axis] = position} (mm) with the side below it in `below`, the side above in `above`.
  struct Node {
    int axis = -1;  ///< −1: a leaf
    double position = 0.0;
    int below = -1, above = -1, region = -1;
  };
  std::vector<Node> tree;

  /// The regions front to back from @p eye (grid frame mm; for an orthographic view, a point far
  /// behind the camera along its view direction): at each plane the side holding the eye first.
  std::vector<int> frontToBack(const glm::dvec3& eye) const;
};

/// What drawing brick @p b costs, for balancing: its texels when visible, a constant for its
/// draw call either way.
double regionCost(const Brick& b);

/// Splits @p selection's bricks into @p parts regions (k-d: each split halves the ranks and cuts at
/// the plane, among those no brick straddles, that balances the two sides' cost best). Regions of
/// whole subtrees, their bricks each in one region; a set of bricks that no plane splits (one
/// brick) leaves the other side's regions empty.
/// @throw ValueError when @p parts < 1.
Regions splitSelection(const VolumeOctree& octree, const glm::dvec3& spacing, const Selection& selection, int parts);

/// The part of @p mesh (grid frame mm, triangulated polygons) a region draws: each polygon inside
/// the box's closed faces whole where its centroid lies in the region (one region for a polygon
/// lying on a face), each polygon that crosses a face cut to the box (its triangles clipped, the
/// new vertices computed alike on the two sides, normals interpolated) as one polygon. The regions
/// of a split together draw the whole surface once.
TriangleMesh cutMeshToRegion(const TriangleMesh& mesh, const RegionBox& box);

}  // namespace hyb
