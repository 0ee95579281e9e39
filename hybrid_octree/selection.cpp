#include "hybrid_octree/selection.h"

#include <cmath>
#include <queue>
#include <string>

#include "volume/error.h"

namespace hyb {

std::string SelectionParams::validate() const {
  if (!std::isfinite(epsilon) || epsilon < 0.0f) return detail::concat("--epsilon ", epsilon, " invalid (expected a finite value >= 0)");
  if (focus && !(std::isfinite(focus->x) && std::isfinite(focus->y) && std::isfinite(focus->z)))
    return "--focus invalid (expected three finite coordinates in mm)";
  if (!std::isfinite(focusRadiusMm) || focusRadiusMm < 0.0) return "focus radius invalid (expected >= 0 mm)";
  if (maxBrickEdge < 1 || (maxBrickEdge & (maxBrickEdge - 1)))
    return detail::concat("maximum brick edge ", maxBrickEdge, " invalid (expected a power of two)");
  return "";
}

double nodeImportance(const VolumeOctree& octree, const OctreeNode& n, const SelectionParams& params) {
  if (!params.focus) return 1.0;
  glm::ivec3 lo, hi;
  octree.voxelBox(n, &lo, &hi);
  const glm::dvec3 boxLo = glm::dvec3(lo) * params.spacing, boxHi = glm::dvec3(hi) * params.spacing;
  const glm::dvec3 nearest = glm::clamp(*params.focus, boxLo, boxHi);
  const double d = glm::length(*params.focus - nearest);
  double radius = params.focusRadiusMm;
  if (radius <= 0.0) radius = 0.25 * glm::length(glm::dvec3(octree.dims() - 1) * params.spacing);
  return radius > 0.0 ? 1.0 / (1.0 + d / radius) : 1.0;
}

Selection selectNodes(const VolumeOctree& octree, const SelectionParams& params) {
  if (const std::string msg = params.validate(); !msg.empty()) throw ValueError(msg);
  Selection sel;
  const auto& nodes = octree.nodes();
  // Recursive descent with an explicit stack (children pushed in reverse keep slot order).
  std::vector<uint32_t> stack{0};
  while (!stack.empty()) {
    const uint32_t i = stack.back();
    stack.pop_back();
    const OctreeNode& n = nodes[i];
    const double imp = nodeImportance(octree, n, params);
    const float tolerance = float(double(params.epsilon) / imp);
    const int p = octree.levelFor(n, tolerance);
    if ((1 << p) <= params.maxBrickEdge || n.isLeaf()) {
      Brick b;
      b.node = i;
      b.p = p;
      b.error = octree.errors(n)[size_t(p)];
      b.importance = float(imp);
      b.texels = octree.texelDims(n, p);
      sel.bricks.push_back(b);
      continue;
    }
    for (int slot = 7; slot >= 0; --slot)
      if (n.childMask & (1u << slot)) stack.push_back(childIndex(n, slot));
  }
  for (const Brick& b : sel.bricks) sel.texels += b.texelCount();

  // Budget: lower the cheapest brick (importance-weighted error per texel saved) one level at a time.
  if (params.texelBudget > 0 && sel.texels > params.texelBudget) {
    using Entry = std::pair<double, size_t>;  // (cost, brick index)
    std::priority_queue<Entry, std::vector<Entry>, std::greater<Entry>> heap;
    auto push = [&](size_t bi) {
      const Brick& b = sel.bricks[bi];
      if (b.p == 0) return;
      const OctreeNode& n = nodes[b.node];
      const uint64_t saved = b.texelCount() - [&] {
        const glm::ivec3 t = octree.texelDims(n, b.p - 1);
        return uint64_t(t.x) * t.y * t.z;
      }();
      const double cost = double(b.importance) * octree.errors(n)[size_t(b.p - 1)] / double(std::max<uint64_t>(saved, 1));
      heap.push({cost, bi});
    };
    for (size_t bi = 0; bi < sel.bricks.size(); ++bi) push(bi);
    while (sel.texels > params.texelBudget && !heap.empty()) {
      const size_t bi = heap.top().second;
      heap.pop();
      Brick& b = sel.bricks[bi];
      const OctreeNode& n = nodes[b.node];
      sel.texels -= b.texelCount();
      --b.p;
      b.texels = octree.texelDims(n, b.p);
      b.error = octree.errors(n)[size_t(b.p)];
      sel.texels += b.texelCount();
      push(bi);
    }
    sel.budgetMet = sel.texels <= params.texelBudget;
  }
  for (const Brick& b : sel.bricks) sel.maxError = std::max(sel.maxError, b.error);
  return sel;
}

}  // namespace hyb
