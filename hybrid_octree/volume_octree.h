// Volume Octree (Boada, Navazo and Scopigno, TVC 2001; Boada and Navazo 2002 §2.1): one octree over
// the volume whose nodes carry min/max and the list of nodal errors ε_p, p = 0…L−k (docs/volume-octree.md).
//
// Geometry. The root covers 2^L cells per axis, L = ⌈log2(max(n_a − 1))⌉, in voxel-index space
// (voxel centres at integers). A node at level k has edge E = 2^(L−k) cells and covers the closed
// box [o, o+E] of samples. Nodes exist where they overlap the grid's cells. Nothing outside the
// grid is ever read: where a node overhangs the grid, its box is cut at the grid's last sample.
//
// Nodal errors. ε_p(n) is the largest |v − T| over n's samples, with T the trilinear interpolation
// of n's sub-grid of spacing s = E/2^p: knots at o + j·s along each axis, the last one moved onto
// the grid's last sample where the node overhangs the grid ("position clamping"; a trilinear field
// is therefore reproduced exactly by every node at every level, by prefiltered knots to their 16
// bits). ε_0 is computed directly for every stored node; ε_p = max over children of ε_(p−1)
// (exact); below the leaves the sub-levels are computed directly inside each leaf. ε_(L−k) = 0.
//
// Knot values. Lattices take the samples at their knots (the paper's subsampling) except, when the
// octree is built with prefiltering (the default), those spaced kPrefilterSpacing…
// kPrefilterMaxSpacing voxels apart: they take the volume prefiltered by the lattice's tent
// (knot_pyramid.h). Nodal errors are measured against the knots a lattice holds, so ε_p keeps its
// meaning: the largest difference between the samples and what a brick at level p shows.
//
// Textures built from a node at level p hold the knot values; a renderer that needs uniformly
// spaced texels extrapolates the overhanging last texel linearly, which reproduces T exactly.
#pragma once

#include <glm/glm.hpp>

#include <algorithm>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "hybrid_octree/knot_pyramid.h"
#include "hybrid_octree/octree_node.h"
#include "surface/mesh.h"
#include "volume/core/file_util.h"
#include "volume/core/progress.h"
#include "volume/plane_source.h"
#include "volume/sample_window.h"
#include "volume/volume.h"

namespace hyb {

/// A uniformly spaced lattice of sample positions (voxel indices), position-clamped at the grid's
/// far side: knot j on axis a sits at min(origin[a] + j·step, last[a]). A texture of `dims` texels
/// whose overhanging last texel is extrapolated linearly reproduces its trilinear field exactly.
struct KnotLattice {
  glm::ivec3 origin{0};  ///< first knot
  int step = 1;          ///< voxels between knots
  glm::ivec3 dims{1};    ///< knots per axis
  glm::ivec3 last{0};    ///< position of the last knot per axis (≤ grid dims − 1)
  uint64_t count() const { return uint64_t(dims.x) * uint64_t(dims.y) * uint64_t(dims.z); }
  /// Position (voxel index) of knot @p j on axis @p a.
  int knot(int a, int j) const { return std::min(origin[a] + j * step, last[a]); }
};

/// Build parameters of a VolumeOctree.
struct VolumeOctreeOptions {
  int leafEdge = 8;        ///< edge in cells of the smallest stored nodes (power of two, 1…256)
  bool prefilter = true;   ///< coarse lattices (≥ kPrefilterSpacing apart) hold tent-prefiltered knots
  const Progress* progress = nullptr;  ///< hears of the build's stages ("volume octree"), or none
};

/// What sees the planes of a streamed build's second pass (the knot store's writer).
class PlaneVisitor {
 public:
  virtual ~PlaneVisitor() = default;
  /// Before the first plane: the octree's prefiltered knots (empty when not prefiltered) and depth.
  virtual void begin(const KnotPyramid& knots, int depth) = 0;
  /// Passes over the planes it needs (the build's second pass is its first); known after begin().
  virtual int passes() const { return 1; }
  /// Before pass @p pass (0 … passes() − 1).
  virtual void beginPass(int /*pass*/) {}
  /// Plane @p z, in order, with planes z − 1 and z + 1 (those within the grid) held by @p window.
  virtual void plane(const SampleWindow& window, int z) = 0;
};

/// Runs @p visitor's passes @p first … passes() − 1 over @p planes, each plane once the next one is
/// in; @p progress advances a plane at a time.
void visitPlanes(PlaneSource& planes, PlaneVisitor& visitor, int first, ProgressTask* progress = nullptr);

/// The Volume Octree, built once and stored as one pointer-free node array.
class VolumeOctree {
 public:
  VolumeOctree() = default;

  /// Builds the octree of @p volume on all available cores.
  /// @throw ValueError when options.leafEdge is not a power of two in 1…256.
  static VolumeOctree build(const Volume& volume, const VolumeOctreeOptions& options = VolumeOctreeOptions());
  /// Builds the octree of the volume @p planes reads, in two passes over its planes, holding a few
  /// planes at a time (leaf edge + 1), the knots and the nodes; @p visitor sees the second pass's.
  static VolumeOctree build(PlaneSource& planes, const VolumeOctreeOptions& options, PlaneVisitor* visitor = nullptr);

  /// Reassembles an octree from stored parts (scene files), checking that the node array has exactly
  /// the shape @p dims and @p leafEdge imply and that every value is finite.
  /// @throw IoError naming @p source when the parts are inconsistent.
  /// With @p prefilteredFrom (the volume the parts were built from), the octree is a prefiltered one
  /// and its knot pyramid is rebuilt from that volume.
  static VolumeOctree fromParts(glm::ivec3 dims, int leafEdge, std::vector<OctreeNode> nodes,
                                std::vector<float> errors, const std::string& source,
                                const Volume* prefilteredFrom = nullptr);
  /// The same checks, the arrays left where they lie (a scene file's section mapped read-only:
  /// the kernel pages the nodes a frame reads in and out), kept alive by @p owner.
  struct MappedParts {
    std::span<const OctreeNode> nodes;
    std::span<const float> errors;
    std::shared_ptr<const InputFile::Mapping> owner;
  };
  static VolumeOctree fromParts(glm::ivec3 dims, int leafEdge, const MappedParts& parts, const std::string& source,
                                const Volume* prefilteredFrom = nullptr);

  /// Checks a reassembled octree against the samples it claims to describe: every leaf's min/max
  /// equals its box's, every inner node's its children's, and every node's finest error is 0 (its
  /// full resolution is the samples). The other errors are not rebuilt (that is the build's cost).
  /// @throw IoError naming @p source at the first node that disagrees.
  void validateAgainst(const Volume& volume, const std::string& source) const;

  /// L: the root's edge is 2^L cells.
  int depth() const { return mDepth; }
  /// Edge in cells of the leaves.
  int leafEdge() const { return mLeafEdge; }
  /// Sample grid the octree was built over.
  const glm::ivec3& dims() const { return mDims; }
  /// All nodes, breadth first; the root is nodes()[0].
  std::span<const OctreeNode> nodes() const { return mOwner ? mMappedNodes : std::span<const OctreeNode>(mNodes); }
  const OctreeNode& root() const { return nodes()[0]; }
  /// Flat array of every node's error list.
  std::span<const float> errorData() const { return mOwner ? mMappedErrors : std::span<const float>(mErrors); }
  /// Whether the arrays lie in a mapped file (fromParts with an owner) rather than in memory of their own.
  bool mapped() const { return mOwner != nullptr; }
  /// Mapped: gives the pages read so far back (a walk over the whole tree, such as the default
  /// camera's fit, need not keep them); the frames after fault in what they read. Else nothing.
  void releasePages() const {
    if (mOwner) mOwner->release();
  }

  /// Edge of @p n in cells.
  int edge(const OctreeNode& n) const { return 1 << (mDepth - n.level); }
  /// Largest texture level of @p n: L − k (one texel per voxel).
  int maxLevel(const OctreeNode& n) const { return mDepth - n.level; }
  /// ε_p(n) for p = 0…maxLevel(n), in data units.
  std::span<const float> errors(const OctreeNode& n) const {
    return errorData().subspan(n.errorOffset, size_t(maxLevel(n) + 1));
  }

  /// Knots per axis of @p n's sub-grid at level @p p, cropped to the grid (seamless bricks: up to
  /// 2^p + 1 per axis; fewer where the node overhangs the grid).
  glm::ivec3 texelDims(const OctreeNode& n, int p) const { return lattice(n, p).dims; }
  /// The knots of @p n's sub-grid at level @p p (spacing edge/2^p, starting at the node's origin).
  KnotLattice lattice(const OctreeNode& n, int p) const;
  /// The knots one level coarser than lattice(n, p) (spacing 2·edge/2^p, aligned to multiples of
  /// it) that cover @p n: the data a brick next to a coarser neighbour blends towards. For p ≥ 1
  /// they are every other knot of lattice(n, p); for p = 0 they are the parent's corners.
  KnotLattice coarseLattice(const OctreeNode& n, int p) const;
  /// Whether lattices spaced kPrefilterSpacing or more apart hold prefiltered knots.
  bool prefiltered() const { return !mKnots.empty(); }
  /// Whether lattices of spacing @p step hold prefiltered knots (else the samples at their knots).
  bool prefilteredAt(int step) const { return mKnots.covers(step); }
  /// The value a lattice of spacing @p step holds at its knot @p p (each coordinate a multiple of
  /// step or the grid's last index): the sample, or the prefiltered value.
  float knotValue(const Volume& v, int step, const glm::ivec3& p) const { return mKnots.knotValue(v, step, p); }
  /// The prefiltered knots (empty unless prefiltered()).
  const KnotPyramid& knots() const { return mKnots; }
  /// The trilinear interpolation at voxel @p p of @p at(knot) over the position-clamped lattice of
  /// spacing @p step whose knots are the multiples of step (and the grid's last index): with the
  /// knots' values, what a brick of that spacing shows there.
  template <class At>
  auto latticeField(int step, const glm::ivec3& p, const At& at) const {
    glm::ivec3 lo, hi;
    glm::vec3 t;
    for (int a = 0; a < 3; ++a) {
      const int last = mDims[a] - 1;
      lo[a] = std::min(p[a] / step * step, last);
      hi[a] = std::min(lo[a] + step, last);
      t[a] = hi[a] > lo[a] ? float(p[a] - lo[a]) / float(hi[a] - lo[a]) : 0.0f;
    }
    auto corner = [&](int c) { return at(glm::ivec3(c & 1 ? hi.x : lo.x, c & 2 ? hi.y : lo.y, c & 4 ? hi.z : lo.z)); };
    const auto x00 = glm::mix(corner(0), corner(1), t.x), x10 = glm::mix(corner(2), corner(3), t.x);
    const auto x01 = glm::mix(corner(4), corner(5), t.x), x11 = glm::mix(corner(6), corner(7), t.x);
    return glm::mix(glm::mix(x00, x10, t.y), glm::mix(x01, x11, t.y), t.z);
  }
  /// Voxel-space box of @p n cropped to the grid: [lo, hi] with hi ≤ dims − 1.
  void voxelBox(const OctreeNode& n, glm::ivec3* lo, glm::ivec3* hi) const;

  /// Bytes held by the node and error arrays and the knot pyramid (the octree's memory overhead).
  size_t bytesUsed() const {
    return nodes().size() * sizeof(OctreeNode) + errorData().size() * sizeof(float) + mKnots.bytesUsed() + sizeof(*this);
  }

 private:
  // Checks stored parts against the shape dims and leafEdge imply (fromParts) and makes the octree
  // without its arrays.
  static VolumeOctree checkedShell(glm::ivec3 dims, int leafEdge, std::span<const OctreeNode> nodes, std::span<const float> errors,
                                   const std::string& source, const Volume* prefilteredFrom);

  glm::ivec3 mDims{0};
  int mDepth = 0;
  int mLeafEdge = 1;
  std::vector<OctreeNode> mNodes;
  std::vector<float> mErrors;
  std::shared_ptr<const InputFile::Mapping> mOwner;  // of the mapped arrays below, when set
  std::span<const OctreeNode> mMappedNodes;
  std::span<const float> mMappedErrors;
  KnotPyramid mKnots;  // empty unless prefiltered
};

/// The leaves whose samples straddle @p iso (some < iso, some ≥ iso) as voxel blocks: the only cells
/// an isosurface extraction needs to visit (min/max culling, Wilhelms and Van Gelder 1992).
std::vector<VoxelBlock> isoBlocks(const VolumeOctree& octree, float iso);

}  // namespace hyb
