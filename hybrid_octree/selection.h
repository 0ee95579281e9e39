// Error-driven node selection (DESIGN 3.3; Boada, Navazo and Scopigno 2001, OTcut):
// pick the nodes to render and, per node, its texture level p (voxel-to-texel ratio 2^(L−k−p)).
#pragma once

#include <glm/glm.hpp>

#include <cstdint>
#include <optional>
#include <vector>

#include "hybrid_octree/volume_octree.h"

namespace hyb {

/// Parameters of a selection.
struct SelectionParams {
  float epsilon = 0.0f;               ///< ε_u: largest nodal error allowed at the focus, data units (≥ 0)
  std::optional<glm::dvec3> focus;    ///< region of interest (world mm); none = uniform importance
  double focusRadiusMm = 0.0;         ///< importance falloff distance; 0 = a quarter of the volume diagonal
  int maxBrickEdge = 64;              ///< B_max: a node becomes a brick when 2^p ≤ B_max (power of two)
  uint64_t texelBudget = 0;           ///< T_max in texels; 0 = unlimited
  glm::dvec3 spacing{1.0};            ///< voxel spacing (mm), to measure distances to the focus

  /// Returns an empty string when valid, else a message naming the offending parameter.
  std::string validate() const;
};

/// One selected node and the level its texture is built at.
struct Brick {
  uint32_t node = 0;       ///< index into VolumeOctree::nodes()
  int p = 0;               ///< texture level: 2^p texel intervals per node edge
  float error = 0;         ///< ε_p(node): largest approximation error of this brick, data units
  float importance = 1;    ///< Imp(node, focus) in (0, 1]
  glm::ivec3 texels{0};    ///< texture samples per axis (cropped to the grid)
  uint64_t texelCount() const { return uint64_t(texels.x) * texels.y * texels.z; }
};

/// The result of a selection: bricks cover the grid exactly once.
struct Selection {
  std::vector<Brick> bricks;
  uint64_t texels = 0;      ///< total texture samples
  float maxError = 0;       ///< largest ε_p over the bricks
  bool budgetMet = true;    ///< false when texelBudget could not be reached even at p = 0
};

/// Importance of @p n for @p params: 1 / (1 + d / R), d the distance from the node's box to the focus.
double nodeImportance(const VolumeOctree& octree, const OctreeNode& n, const SelectionParams& params);

/// Selects bricks: recursing from the root, p(n) is the smallest p with ε_p(n) ≤ ε_u / Imp(n); n is a
/// brick when 2^p ≤ B_max or n is a leaf. While the texels exceed the budget, the brick with the
/// smallest Imp·ε_(p−1) per texel saved is lowered one level.
/// @throw ValueError when @p params is invalid.
Selection selectNodes(const VolumeOctree& octree, const SelectionParams& params);

}  // namespace hyb
