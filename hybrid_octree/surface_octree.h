// Surface Octree (Boada and Navazo, "An Octree Isosurface Codification based on Discrete Planes",
// SCCG 2001; docs/surface.md): the DiscMC surface coded per terminal node by at most K discrete planes and
// a truth table, merged bottom-up without loss.
//
// Coordinates. "Fine" coordinates are 12 × the doubled grid (24 × voxel index): every vertex of an
// arrangement of discrete planes and axis-aligned box faces is an integer there, because the
// determinant of three of their normals is ±1, ±2, ±3 or ±4.
//
// Code. A terminal surface node stores planes P (geometric: orientation and d, at most K) and, for
// every sign vector σ over P whose region R_σ meets the node's box in a solid, whether that region is
// inside the solid. The surface is the boundary of the solid inside the box.
//
// Merge. A node whose children are all terminal merges when the union of their planes has at most K
// members. That is lossless: the surface inside the node lies on those planes, so no surface crosses
// the open convex set R_σ ∩ box and the solid is constant on it. Its truth value is read from the
// child holding an interior point of R_σ ∩ box (the average of the set's vertices, exact).
//
// Reconstruction. Each plane is clipped to the node's box and split by the other planes; the convex
// pieces where the truth value changes across the plane are the surface, oriented outward. Pieces of
// a node on the same plane and facing are merged into polygons; vertices of neighbouring nodes that
// lie on a polygon's edges along a node face are inserted (T-junctions), so the output is watertight.
#pragma once

#include <glm/glm.hpp>

#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "hybrid_octree/volume_octree.h"
#include "surface/mesh.h"
#include "volume/core/error.h"
#include "volume/core/file_util.h"
#include "volume/core/progress.h"
#include "volume/volume.h"

namespace hyb {

class KnotSource;
class PlaneSource;
namespace detail {
class SpoolFile;
}

/// A geometric discrete plane N_o·X = d in doubled coordinates (N_o the canonical normal).
struct GeoPlane {
  int8_t orientation = 0;
  int32_t d = 0;
  friend bool operator==(const GeoPlane& a, const GeoPlane& b) { return a.orientation == b.orientation && a.d == b.d; }
  friend bool operator<(const GeoPlane& a, const GeoPlane& b) {
    return a.orientation != b.orientation ? a.orientation < b.orientation : a.d < b.d;
  }
};

/// Largest number of planes a terminal node may hold (K = 4, docs/surface.md). Leaves whose DiscMC case
/// needs the centre-diagonal variant hold 5; they never merge.
inline constexpr int kMaxNodePlanes = 4;

/// A terminal surface node.
struct SurfaceNode {
  glm::u16vec3 origin{0};       ///< cell index of the node's minimum corner
  uint16_t edge = 1;            ///< edge in cells (a power of two)
  uint8_t planeCount = 0;
  std::array<GeoPlane, 5> planes{};
  uint32_t inside = 0;          ///< bit σ: region σ is inside the solid (bit j of σ: positive side of plane j)
  uint32_t occurs = 0;          ///< bit σ: region σ meets the node's box in a solid
  friend bool operator==(const SurfaceNode&, const SurfaceNode&) = default;
};

/// Bytes a node takes in a scene file (field by field, without the struct's padding, so that two
/// saves of one scene are the same bytes).
inline constexpr size_t kSurfaceNodeBytes = 6 + 2 + 1 + std::tuple_size_v<decltype(SurfaceNode::planes)> * 5 + 4 + 4;
/// Writes @p node's kSurfaceNodeBytes bytes at @p out.
void encodeSurfaceNode(const SurfaceNode& node, uint8_t* out);
/// Reads a node encodeSurfaceNode wrote at @p in (unchecked: SurfaceOctree::fromParts checks it).
SurfaceNode decodeSurfaceNode(const uint8_t* in);
/// Takes encoded nodes a piece at a time, in order.
using SurfaceNodeSink = std::function<void(std::span<const uint8_t>)>;

/// Build options.
struct SurfaceOctreeOptions {
  int maxPlanes = kMaxNodePlanes;  ///< K
  /// Largest merged node edge in cells (a power of two, at most the volume octree's leaf edge);
  /// 0 = the leaf edge. Every surface node lies in exactly one volume leaf, so the renderer finds a
  /// brick's polygons by range and the build merges leaf by leaf.
  int maxEdge = 0;
  const Progress* progress = nullptr;  ///< hears of the leaves merged ("surface octree")
};

/// An aligned cube of cells and the range of a Surface Octree's nodes inside it
/// (SurfaceOctree::regions).
struct SurfaceRegion {
  glm::ivec3 origin{0};
  int edge = 0;
  uint32_t first = 0, last = 0;  ///< nodes [first, last)
};

/// The Surface Octree of one isovalue.
class SurfaceOctree {
 public:
  SurfaceOctree() = default;

  /// Extracts DiscMC cell codes over the cells @p octree's min/max say the isovalue crosses and
  /// merges them bottom-up, leaf by leaf on all cores, each leaf reading its samples (spacing 1)
  /// from @p knots: a paged scene's read through its cache, never whole.
  /// @throw IoError as KnotSource::read.
  static SurfaceOctree build(const KnotSource& knots, const VolumeOctree& octree, float iso,
                             const SurfaceOctreeOptions& options = SurfaceOctreeOptions());
  /// The same from a volume in memory.
  static SurfaceOctree build(const Volume& volume, const VolumeOctree& octree, float iso,
                             const SurfaceOctreeOptions& options = SurfaceOctreeOptions());
  /// The same from @p planes, read once more from the first (a streamed build): the leaves a slab
  /// at a time, holding leafEdge + 2 planes.
  /// @throw IoError as PlaneSource::read.
  static SurfaceOctree build(PlaneSource& planes, const VolumeOctree& octree, float iso,
                             const SurfaceOctreeOptions& options = SurfaceOctreeOptions());

  /// Hands @p sink every node encoded (encodeSurfaceNode), in order, a few MB at a time.
  void encodeNodes(const SurfaceNodeSink& sink) const;

  /// Reassembles a stored octree, checking every node against @p dims.
  /// @throw IoError naming @p source when a node is out of range or inconsistent.
  static SurfaceOctree fromParts(glm::ivec3 dims, float iso, size_t cellCount, int mergeEdge, std::vector<SurfaceNode> nodes,
                                 const std::string& source);
  /// Nodes encoded (encodeSurfaceNode) inside a scene file's mapping (its SURF section).
  struct MappedNodes {
    std::shared_ptr<const InputFile::Mapping> mapping;
    const uint8_t* at = nullptr;  ///< the first node's bytes, inside mapping
    size_t count = 0;
  };
  /// The same over @p nodes, left in their mapping: each is checked once here, the pages read given
  /// back as it goes, and decoded again when read (node(), reconstructIn), so the octree holds none
  /// of them. @throw IoError as fromParts.
  static SurfaceOctree fromMapped(glm::ivec3 dims, float iso, size_t cellCount, int mergeEdge, MappedNodes nodes, const std::string& source);

  /// Terminal surface nodes in Morton order of their origins (white, black and grey nodes are implicit).
  /// @pre !mapped(): a mapped octree's are read one at a time by node().
  const std::vector<SurfaceNode>& nodes() const {
    HYB_CHECK(!mapped());
    return mNodes;
  }
  /// Node @p i of nodeCount(), decoded when the octree is mapped.
  SurfaceNode node(size_t i) const { return mapped() ? decodeSurfaceNode(mEncoded + i * kSurfaceNodeBytes) : mNodes[i]; }
  size_t nodeCount() const { return mapped() ? mMappedCount : mNodes.size(); }
  /// Whether the nodes stay in a scene file's mapping (fromMapped).
  bool mapped() const { return mMapping != nullptr; }
  /// Gives back the pages of the mapping read so far (nothing when not mapped).
  void releasePages() const {
    if (mMapping) mMapping->release();
  }
  /// The nodes inside the aligned cube of cells [origin, origin + edge): a contiguous range of nodes().
  /// Nodes larger than the cube are not listed (none are when edge ≥ the build's maxEdge).
  std::pair<uint32_t, uint32_t> rangeIn(const glm::ivec3& origin, int edge) const;
  float isovalue() const { return mIso; }
  const glm::ivec3& dims() const { return mDims; }
  /// Surface cells the DiscMC extraction produced (the leaves before merging).
  size_t cellCount() const { return mCellCount; }
  /// Largest node edge the build allowed; reconstructed polygons never cross a cube of this edge.
  int mergeEdge() const { return mMergeEdge; }
  /// What the octree holds in memory: its nodes, none when mapped (a region's are decoded while it
  /// is reconstructed).
  size_t bytesUsed() const { return bytesFor(mNodes.size()); }
  /// What an octree of @p nodes nodes holds.
  static size_t bytesFor(size_t nodes) { return nodes * sizeof(SurfaceNode) + sizeof(SurfaceOctree); }
  /// At most what reconstruct()'s working arrays hold beside the octree: 480–530 bytes a node on
  /// CT bone (docs/scale.md), with a margin.
  uint64_t reconstructBytes() const { return 600 * uint64_t(nodeCount()); }

  /// Polygons of every terminal node, merged per plane and facing inside each node and then across
  /// nodes inside each aligned cube of @p mergeCube cells (0 = mergeEdge(), so every polygon lies in
  /// one volume leaf; export passes the whole volume), with T-junction vertices inserted; vertices
  /// in fine coordinates (12 × doubled). Watertight where DiscMC is. @p progress hears of it
  /// ("surface polygons").
  DiscreteMesh reconstruct(int mergeCube = 0, const Progress* progress = nullptr) const;

  /// The aligned cubes of cells, in Morton order, that partition the nodes into runs of at most
  /// @p maxNodes (a cube of mergeEdge() cells may hold more): the cubes the root splits into,
  /// recursively, until each holds few enough; cubes holding no node are left out.
  std::vector<SurfaceRegion> regions(size_t maxNodes) const;
  /// The polygons reconstruct() gives the nodes of @p region (one of regions()), the same loops in
  /// the same order, vertices renumbered in their order there: the region's nodes are reconstructed
  /// with those of the neighbouring cubes that touch it (their vertices on its faces make its
  /// T-junctions, and a vertex they share is not dropped), not the whole octree.
  DiscreteMesh reconstructIn(const SurfaceRegion& region) const;

 private:
  friend class SpooledSurfaceOctree;
  // The octree of @p iso over @p dims with its merge edge, @p options checked, no nodes yet.
  static SurfaceOctree empty(const glm::ivec3& dims, const VolumeOctree& octree, float iso, const SurfaceOctreeOptions& options);
  // Appends the leaves' nodes in their order (Morton order: the leaves are).
  void gather(std::vector<std::vector<SurfaceNode>> perBlock);

  // An octree of no nodes with the stored head, checked (fromParts, fromMapped): throws naming @p source.
  static SurfaceOctree withHead(glm::ivec3 dims, float iso, size_t cellCount, int mergeEdge, const std::string& source);
  // Every node's check (fromParts, fromMapped): throws naming @p source and node @p i.
  static void checkNode(const SurfaceNode& n, size_t i, const glm::ivec3& dims, int mergeEdge, uint64_t* previous, const std::string& source);
  // The nodes in memory, or (mapped) the section's encoded nodes in its mapping.
  std::vector<SurfaceNode> mNodes;
  std::shared_ptr<const InputFile::Mapping> mMapping;
  const uint8_t* mEncoded = nullptr;
  size_t mMappedCount = 0;
  glm::ivec3 mDims{0};
  float mIso = 0;
  size_t mCellCount = 0;
  int mMergeEdge = 1;
};

/// A Surface Octree built from planes (a streamed build) whose nodes wait, encoded as a scene file
/// holds them, in a temporary file beside the scene (gone from its directory from the start) until
/// the scene is written: the build holds one slab of leaves' nodes at a time and an index of the
/// leaves, never the whole surface (docs/scale.md, The streamed build).
class SpooledSurfaceOctree {
 public:
  /// The octree SurfaceOctree::build(planes, octree, iso, options) makes, its nodes spooled in
  /// @p spoolDir ("" = the working directory) a slab at a time.
  /// @throw IoError as PlaneSource::read, or naming @p spoolDir when the temporary file cannot be
  /// made or written.
  static SpooledSurfaceOctree build(PlaneSource& planes, const VolumeOctree& octree, float iso, const std::string& spoolDir,
                                    const SurfaceOctreeOptions& options = SurfaceOctreeOptions());
  SpooledSurfaceOctree(SpooledSurfaceOctree&&) noexcept;
  SpooledSurfaceOctree& operator=(SpooledSurfaceOctree&&) noexcept;
  ~SpooledSurfaceOctree();

  float isovalue() const { return mHead.isovalue(); }
  const glm::ivec3& dims() const { return mHead.dims(); }
  size_t cellCount() const { return mHead.cellCount(); }
  int mergeEdge() const { return mHead.mergeEdge(); }
  size_t nodeCount() const { return mNodeCount; }
  /// Plane ids over every node (the sum of their plane counts).
  uint64_t planeIds() const { return mPlaneIds; }
  /// Hands @p sink the nodes encoded in Morton order, as SurfaceOctree::encodeNodes does.
  /// @throw IoError when the temporary file cannot be read.
  void encodeNodes(const SurfaceNodeSink& sink) const;
  /// The octree in memory: SurfaceOctree::build(planes, …)'s, node for node.
  SurfaceOctree load() const;

 private:
  SpooledSurfaceOctree();
  SurfaceOctree mHead;  // the grid, isovalue, cell count and merge edge; no nodes
  struct Leaf {
    uint64_t first = 0;  // its first node's index in the spool
    uint32_t count = 0;
  };
  std::vector<Leaf> mLeaves;  // per leaf the isovalue crosses, in Morton order
  std::unique_ptr<detail::SpoolFile> mSpool;
  size_t mNodeCount = 0;
  uint64_t mPlaneIds = 0;
};

/// The code of DiscMC case @p mask (alternative: the centre-diagonal variant) for a cell at the
/// origin: canonical planes and truth table. For tests.
SurfaceNode leafCode(int mask, bool alternative);

/// Whether the fine-coordinate point @p p (scaled by @p scale) lies inside the solid of @p node, given
/// that it is strictly off the node's planes. For tests.
bool nodeContains(const SurfaceNode& node, const glm::i64vec3& p, int64_t scale);

/// Converts fine coordinates to world millimetres and triangulates (ear clipping).
TriangleMesh fineMeshToTriangles(const DiscreteMesh& mesh, const glm::dvec3& spacing);

}  // namespace hyb
