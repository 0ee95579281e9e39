// Budgeted, importance-driven node selection (docs/multires.md, docs/volume-octree.md): Boada, Navazo and Scopigno 2001
// (OTcut: ε_u over importance), Carmona et al. (greedy refinement by priority under a texture budget,
// restricted octree, per-corner blending towards coarser data), LaMar 1999 (culling).
//
// Resolution. A brick (node n, texture level p) has voxel-to-texel ratio 2^r, r = maxLevel(n) − p.
// Refinement lowers r by one: it raises p while 2^p < B_max, then splits the node into its children
// at the same p. So every brick but the root holds 2^p = B_max texel intervals per edge and a
// coarser neighbour is always a larger node (the property per-corner blending needs).
//
// Blending (Carmona et al.): a brick whose corner touches a coarser visible brick gets weight 0 at
// that corner (1 elsewhere, trilinear inside the node, reaching 1 halfway across: the renderer's
// kBlendSteepness) and shows mix(coarse, own, w), the coarse field being that of
// VolumeOctree::coarseLattice. On a face shared with a coarser brick all weights are 0, so the
// field is continuous across the level change. The renderer bakes the mix into the brick's own
// texels: blending costs no texture memory and no shader work.
#pragma once

#include <glm/glm.hpp>

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include "hybrid_octree/volume_octree.h"

namespace hyb {

/// Parameters of a selection.
struct SelectionParams {
  float epsilon = 0.0f;               ///< ε_u: largest nodal error allowed at importance 1, data units (≥ 0)
  std::optional<glm::dvec3> focus;    ///< region of interest (world mm); none = no focus term
  std::optional<glm::dvec3> eye;      ///< viewpoint (world mm); none = no eye-distance term and no distance filter
  double focusRadiusMm = 0.0;         ///< importance falloff distance; 0 = a quarter of the volume diagonal
  int maxBrickEdge = 16;              ///< B_max: texel intervals per brick edge (power of two)
  uint64_t texelBudget = 0;           ///< T_max in texels; 0 = unlimited
  glm::dvec3 spacing{1.0};            ///< voxel spacing (mm), to measure distances
  bool restricted = true;             ///< keep 26-neighbouring visible bricks within one resolution level
  bool blend = true;                  ///< mark the corners that blend towards coarser neighbours
  /// Largest opacity the transfer function gives a value range [lo, hi]; a node whose range gets 0
  /// is transparent and costs nothing. None: every node is visible.
  std::function<float(float lo, float hi)> opacity;
  /// Distortion after the transfer function: how much an error of @p error data units in values
  /// within [lo, hi] can change the classified opacity and colour. None: the error itself.
  std::function<double(float lo, float hi, float error)> distortion;
  /// The error brick (node, level p) makes in the image (BrickImageError; 0 where exact). When
  /// set and a budget is given, the priority is what a refinement removes of it, times the
  /// importance, per texel it costs, instead of distortion(ε_p): the budget goes where it changes
  /// the image most. (Without a budget the order of refinement does not change the result.)
  std::function<double(uint32_t node, int p)> brickError;
  /// Optional: brickError will soon be asked for these bricks (node, p); measure them together
  /// (BrickImageError::prefetch, on all cores).
  std::function<void(const std::vector<std::pair<uint32_t, int>>&)> prefetchBrickErrors;
  /// Size in mm of one pixel at the nearest point of the world box [lo, hi] (the camera's); with
  /// lodPixels > 0 a brick is not refined once its texels are at most lodPixels pixels apart there
  /// (LaMar's screen-space criterion: finer data cannot be seen). None: no screen-space stop.
  std::function<double(const glm::dvec3& lo, const glm::dvec3& hi)> pixelSize;
  double lodPixels = 0.0;             ///< texel spacing, in pixels, below which refinement stops; 0 = off
  /// Whether the world box [lo, hi] (mm) can be seen (frustum culling); none: always.
  std::function<bool(const glm::dvec3& lo, const glm::dvec3& hi)> inView;
  /// A second channel the nodes carry beside the data (a scan-converted geometry channel), or none:
  /// a node for which it is true is never hidden as transparent, and its nodal error below its full
  /// resolution is at least channelError (data units; combined with the data's by max).
  std::function<bool(uint32_t node)> holdsChannel;
  float channelError = 0.0f;

  /// Returns an empty string when valid, else a message naming the offending parameter.
  std::string validate() const;
};

/// One selected node and the level its texture is built at.
struct Brick {
  uint32_t node = 0;          ///< index into VolumeOctree::nodes()
  int p = 0;                  ///< texture level: 2^p texel intervals per node edge
  float error = 0;            ///< ε_p(node): largest approximation error of this brick, data units
  float importance = 1;       ///< Imp(node) in (0, 1]
  bool hidden = false;        ///< transparent by its min/max or outside the view: no texture
  uint8_t coarseCorners = 0;  ///< bit c (slot order x|y<<1|z<<2) set when corner c touches a coarser brick
  glm::ivec3 texels{0};       ///< texture samples per axis (cropped to the grid); 0 when hidden
  uint64_t texelCount() const { return uint64_t(texels.x) * texels.y * texels.z; }
};

/// The result of a selection: bricks (hidden ones included) cover the grid exactly once.
struct Selection {
  std::vector<Brick> bricks;
  uint64_t texels = 0;       ///< texture samples of the visible bricks
  size_t blendedBricks = 0;  ///< visible bricks with a corner that blends
  float maxError = 0;        ///< largest ε_p over the visible bricks
  bool budgetMet = true;     ///< false when even the coarsest selection exceeds texelBudget
};

/// Which brick of a selection each node is (its index in Selection::bricks, −1 for none): a hash
/// map, so that a frame costs what its bricks do, not what the octree's nodes do (9.6 M on the
/// 8 GiB phantom: a per-node array was 38 MB to allocate and clear, several times a frame).
class BrickIndex {
 public:
  explicit BrickIndex(const Selection& selection) {
    mOf.reserve(selection.bricks.size());
    for (size_t b = 0; b < selection.bricks.size(); ++b) mOf.emplace(selection.bricks[b].node, int(b));
  }
  int operator[](uint32_t node) const {
    const auto it = mOf.find(node);
    return it == mOf.end() ? -1 : it->second;
  }

 private:
  std::unordered_map<uint32_t, int> mOf;
};

/// Importance of @p n: 1/(1 + d_f/R) for the focus times 1/(1 + (d_e − d_near)/R) for the eye,
/// d the distance from the node's box (R: focusRadiusMm; d_near: the volume's distance to the eye).
double nodeImportance(const VolumeOctree& octree, const OctreeNode& n, const SelectionParams& params);

/// Resolution level r of a brick: its voxel-to-texel ratio is 2^r.
inline int resolutionLevel(const VolumeOctree& octree, const Brick& b) {
  return octree.maxLevel(octree.nodes()[b.node]) - b.p;
}

/// Selects bricks. Starting from the root at p = 0, the visible brick of highest priority
/// (D·Imp, or with brickError the image error a refinement removes times Imp per texel) is refined while its ε_p exceeds ε_u/Imp or, with an eye, while the eye is nearer to it
/// than its diagonal (LaMar's distance filter), keeping the tree restricted (refining coarser
/// neighbours as needed) and skipping refinements that would exceed the texel budget.
/// @throw ValueError when @p params is invalid.
Selection selectNodes(const VolumeOctree& octree, const SelectionParams& params);

/// Sets each visible brick's coarseCorners from its neighbours (a corner blends when a visible brick
/// of a higher resolution level touches it) and counts the blended bricks.
void assignBlendCorners(const VolumeOctree& octree, Selection* selection);

/// Whether every two touching visible bricks differ by at most one resolution level.
bool isRestricted(const VolumeOctree& octree, const Selection& selection);

/// The selection a frame can draw now when only some bricks' knots are at hand (@p resident says
/// which bricks are): each visible brick that is not is drawn from the finest resident brick of
/// its node at a lower level, else from its smallest ancestor whose brick at level 0 is resident
/// (the root's always is: a frame reads it), which replaces every brick below it. The spacings of
/// the lattices tried double at each step, so no region is left without a brick (never a hole);
/// bricks keep their blend corners (a seam may show where a neighbour became coarser). The bricks
/// replaced are appended to @p missing, in the selection's order.
Selection residentSelection(const VolumeOctree& octree, const Selection& selection, const std::function<bool(const Brick&)>& resident,
                            std::vector<Brick>* missing);

}  // namespace hyb
