#include "hybrid_octree/selection.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <limits>
#include <queue>
#include <string>
#include <unordered_map>
#include <unordered_set>

#include "volume/core/error.h"

namespace hyb {

namespace {

// ε_p of node i at level p: the data's, and params' channel error where the node holds the channel
// and p is below its full resolution.
float nodalError(const VolumeOctree& octree, const SelectionParams& params, uint32_t i, int p) {
  const OctreeNode& n = octree.nodes()[i];
  const float data = octree.errors(n)[size_t(p)];
  if (!params.holdsChannel || p >= octree.maxLevel(n) || !params.holdsChannel(i)) return data;
  return std::max(data, params.channelError);
}

// Calls visit(j) for every brick j whose closed node box meets the closed voxel box [lo, hi];
// isBrick(j) tells the bricks apart from the inner nodes above them.
template <class IsBrick, class Visit>
void forEachBrickTouching(const VolumeOctree& t, const glm::ivec3& lo, const glm::ivec3& hi, const IsBrick& isBrick,
                          const Visit& visit) {
  uint32_t stack[64 * 8];
  int top = 0;
  stack[top++] = 0;
  while (top > 0) {
    const uint32_t j = stack[--top];
    const OctreeNode& n = t.nodes()[j];
    const glm::ivec3 o(n.origin), e = o + t.edge(n);
    if (glm::any(glm::greaterThan(o, hi)) || glm::any(glm::lessThan(e, lo))) continue;
    if (isBrick(j)) {
      visit(j);
      continue;
    }
    for (int slot = 0; slot < 8; ++slot)
      if (n.childMask & (1u << slot)) stack[top++] = childIndex(n, slot);
  }
}

// The box of @p n cropped to the grid, in world mm.
void worldBox(const VolumeOctree& t, const OctreeNode& n, const glm::dvec3& spacing, glm::dvec3* lo, glm::dvec3* hi) {
  glm::ivec3 a, b;
  t.voxelBox(n, &a, &b);
  *lo = glm::dvec3(a) * spacing;
  *hi = glm::dvec3(b) * spacing;
}

// Distance from @p p to the box [lo, hi] (0 inside).
double distanceToBox(const glm::dvec3& p, const glm::dvec3& lo, const glm::dvec3& hi) { return glm::length(p - glm::clamp(p, lo, hi)); }

glm::ivec3 nodeLo(const OctreeNode& n) { return glm::ivec3(n.origin); }
glm::ivec3 nodeHi(const VolumeOctree& t, const OctreeNode& n) { return glm::ivec3(n.origin) + t.edge(n); }

// The greedy refinement of Carmona et al. over a restricted octree, with an undo journal so that a
// refinement whose restriction closure overruns the budget can be taken back.
class Refiner {
 public:
  Refiner(const VolumeOctree& t, const SelectionParams& params) : mT(t), mParams(params), mP(t.nodes().size(), -1) {
    mBrickLevel = std::max(0, std::countr_zero(unsigned(params.maxBrickEdge)));
    set(0, 0);
  }

  uint64_t texels() const { return mTexels; }
  const std::vector<int8_t>& levels() const { return mP; }
  bool hidden(uint32_t i) const { return view(i).hidden; }
  double importance(uint32_t i) const { return view(i).importance; }

  // Refines every brick that asks for it, best first, within the budget. A refinement that was
  // taken back may fit once others have happened (a free split whose restriction closure cost
  // texels, say), so the bricks are offered again until a pass changes nothing.
  void run() {
    using Entry = std::pair<double, std::pair<uint32_t, int>>;  // (priority, (node, p when pushed))
    std::priority_queue<Entry> heap;
    auto push = [&](uint32_t i) {
      if (wantsRefinement(i)) heap.push({priority(i), {i, mP[i]}});
    };
    prefetch({0});
    push(0);
    for (int pass = 0; pass < 4 && !heap.empty(); ++pass) {
      bool rolledBack = false, changed = false;
      while (!heap.empty()) {
        const auto [i, p] = heap.top().second;
        heap.pop();
        if (mP[i] != p || !wantsRefinement(i)) continue;  // stale entry
        mJournal.clear();
        const uint64_t before = mTexels;
        const bool onlyFree = !asked(i);
        refineRestricted(i);
        if ((mParams.texelBudget > 0 && mTexels > mParams.texelBudget) || (onlyFree && mTexels > before)) {
          const std::vector<std::pair<uint32_t, int8_t>> undo = std::move(mJournal);
          for (auto it = undo.rbegin(); it != undo.rend(); ++it) set(it->first, it->second);
          HYB_CHECK(mTexels == before);
          rolledBack = true;
          continue;  // this node stays as it is; smaller refinements elsewhere may still fit
        }
        changed = true;
        std::vector<uint32_t> touched;
        for (const auto& [node, old] : mJournal)
          if (mP[node] >= 0) touched.push_back(node);
        prefetch(touched);
        for (uint32_t node : touched) push(node);
      }
      if (!rolledBack || !changed) break;
      for (uint32_t i = 0; i < mP.size(); ++i) push(i);
    }
  }

 private:
  int level(uint32_t i) const { return mT.maxLevel(mT.nodes()[i]) - mP[i]; }

  float tolerance(uint32_t i) const { return float(double(mParams.epsilon) / view(i).importance); }

  bool overTolerance(uint32_t i) const { return error(i) > tolerance(i); }
  // ε_p of brick i: the data's, and the channel's where it holds one (by max).
  float error(uint32_t i) const { return nodalError(mT, mParams, i, mP[i]); }
  // Refinement asked for by ε_u or by the distance filter (where it still changes anything).
  bool asked(uint32_t i) const {
    const OctreeNode& n = mT.nodes()[i];
    const double texelMm = double(mT.edge(n) >> mP[i]) * std::min({mParams.spacing.x, mParams.spacing.y, mParams.spacing.z});
    if (texelMm <= view(i).pixelMm) return false;  // finer texels would not be seen
    return overTolerance(i) || (view(i).nearEye && error(i) > 0.0f);
  }

  // Whether splitting brick i costs no more texels than keeping it: its transparent or culled
  // children cost nothing, so a coarse node that is mostly empty is better split.
  bool splitIsFree(uint32_t i) const {
    const OctreeNode& n = mT.nodes()[i];
    if (n.isLeaf() || mP[i] < std::min(mBrickLevel, mT.maxLevel(n))) return false;
    uint64_t children = 0;
    for (int slot = 0; slot < 8; ++slot)
      if (n.childMask & (1u << slot)) children += cost(childIndex(n, slot), mP[i]);
    return children <= cost(i, mP[i]);
  }

  bool wantsRefinement(uint32_t i) const {
    return mP[i] >= 0 && !hidden(i) && level(i) > 0 && (asked(i) || splitIsFree(i));
  }

  // P = D·Imp with D the distortion of ε_p after the transfer function, or with brickError the
  // image error refining removes times Imp per texel it costs; a tiny term in ε_p orders nodes
  // that neither tells apart. Free splits come first: they cost nothing and make the image no worse.
  double priority(uint32_t i) const {
    if (!asked(i)) return std::numeric_limits<double>::infinity();
    const OctreeNode& n = mT.nodes()[i];
    const float e = error(i);
    if (mParams.brickError && mParams.texelBudget > 0) return imageGain(i) * view(i).importance + 1e-12 * double(e);
    const double d = mParams.distortion ? mParams.distortion(n.minValue, n.maxValue, e) : double(e);
    return d * view(i).importance + 1e-12 * double(e);
  }

  // Has the image errors that the priorities of bricks @p nodes will read measured together.
  void prefetch(const std::vector<uint32_t>& nodes) const {
    if (!mParams.prefetchBrickErrors || !mParams.brickError || mParams.texelBudget == 0) return;
    std::vector<std::pair<uint32_t, int>> bricks;
    for (uint32_t i : nodes) {
      if (!wantsRefinement(i)) continue;
      bricks.push_back({i, mP[i]});
      const std::vector<std::pair<uint32_t, int>> finer = refined(i);
      bricks.insert(bricks.end(), finer.begin(), finer.end());
    }
    mParams.prefetchBrickErrors(bricks);
  }

  // The visible bricks (node, p) that refining brick i once makes of it: itself at p + 1, or its
  // visible children at p (hidden ones show nothing, as the samples there, and cost nothing).
  std::vector<std::pair<uint32_t, int>> refined(uint32_t i) const {
    if (refinesInPlace(i)) return {{i, mP[i] + 1}};
    const OctreeNode& n = mT.nodes()[i];
    std::vector<std::pair<uint32_t, int>> children;
    for (int slot = 0; slot < 8; ++slot)
      if ((n.childMask & (1u << slot)) && !hidden(childIndex(n, slot))) children.push_back({childIndex(n, slot), mP[i]});
    return children;
  }

  // What refining brick i once removes of its image error, per texel it adds (restriction
  // closures aside).
  double imageGain(uint32_t i) const {
    double after = 0.0;
    int64_t added = -int64_t(cost(i, mP[i]));
    for (const auto& [b, p] : refined(i)) {
      after += mParams.brickError(b, p);
      added += int64_t(cost(b, p));
    }
    return std::max(0.0, mParams.brickError(i, mP[i]) - after) / double(std::max<int64_t>(added, 1));
  }

  // Texels brick i costs at level p.
  uint64_t cost(uint32_t i, int p) const { return p < 0 || hidden(i) ? 0 : mT.lattice(mT.nodes()[i], p).count(); }

  // Every change of the cut goes through here (journalled).
  void set(uint32_t i, int p) {
    mJournal.push_back({i, mP[i]});
    mTexels = mTexels - cost(i, mP[i]) + cost(i, p);
    mP[i] = int8_t(p);
  }

  // Whether refining brick i raises its p (up to B_max texel intervals), else it splits.
  bool refinesInPlace(uint32_t i) const {
    const OctreeNode& n = mT.nodes()[i];
    return mP[i] < std::min(mBrickLevel, mT.maxLevel(n)) || n.isLeaf();
  }

  // One level finer: a higher p up to B_max, then the children at the same p.
  void refineOnce(uint32_t i, std::vector<uint32_t>* created) {
    const OctreeNode& n = mT.nodes()[i];
    const int p = mP[i];
    HYB_DCHECK(level(i) > 0);
    if (refinesInPlace(i)) {
      set(i, p + 1);
      created->push_back(i);
      return;
    }
    set(i, -1);
    for (int slot = 0; slot < 8; ++slot)
      if (n.childMask & (1u << slot)) {
        const uint32_t c = childIndex(n, slot);
        set(c, p);
        created->push_back(c);
      }
  }

  // Refines brick i, then every visible brick that would become two or more levels coarser than a
  // touching visible brick.
  void refineRestricted(uint32_t i) {
    std::vector<uint32_t> work;
    refineOnce(i, &work);
    if (!mParams.restricted) return;
    const auto isBrick = [&](uint32_t j) { return mP[j] >= 0; };
    while (!work.empty()) {
      const uint32_t b = work.back();
      work.pop_back();
      if (mP[b] < 0 || hidden(b)) continue;
      const OctreeNode& n = mT.nodes()[b];
      uint32_t coarse = UINT32_MAX;
      forEachBrickTouching(mT, nodeLo(n), nodeHi(mT, n), isBrick, [&](uint32_t j) {
        if (coarse == UINT32_MAX && !hidden(j) && level(j) > level(b) + 1) coarse = j;
      });
      if (coarse == UINT32_MAX) continue;
      work.push_back(b);  // check b again once this neighbour is one level finer
      refineOnce(coarse, &work);
    }
  }

  const VolumeOctree& mT;
  const SelectionParams& mParams;
  std::vector<int8_t> mP;  // brick level per node, −1 when the node is not a brick
  // What the view makes of a node, computed when the refinement first meets it: a frame meets a
  // few thousand of a large study's millions of nodes.
  struct NodeView {
    bool hidden = false;   // transparent under the transfer function, or outside the view
    bool nearEye = false;  // LaMar's distance filter: nearer to the eye than its own diagonal
    double importance = 1.0;
    double pixelMm = 0.0;  // lodPixels pixels at the node, mm (0: no screen-space stop)
  };
  const NodeView& view(uint32_t i) const {
    const auto [it, added] = mViews.try_emplace(i);
    if (added) {
      NodeView& v = it->second;
      const OctreeNode& n = mT.nodes()[i];
      glm::dvec3 boxLo, boxHi;
      worldBox(mT, n, mParams.spacing, &boxLo, &boxHi);
      const bool transparent =
          mParams.opacity && !(mParams.opacity(n.minValue, n.maxValue) > 0.0f) && !(mParams.holdsChannel && mParams.holdsChannel(i));
      v.hidden = transparent || (mParams.inView && !mParams.inView(boxLo, boxHi));
      v.importance = nodeImportance(mT, n, mParams);
      v.nearEye = mParams.eye && distanceToBox(*mParams.eye, boxLo, boxHi) < glm::length(boxHi - boxLo);
      v.pixelMm = mParams.pixelSize && mParams.lodPixels > 0.0 ? mParams.lodPixels * mParams.pixelSize(boxLo, boxHi) : 0.0;
    }
    return it->second;
  }
  mutable std::unordered_map<uint32_t, NodeView> mViews;
  int mBrickLevel = 6;
  uint64_t mTexels = 0;
  std::vector<std::pair<uint32_t, int8_t>> mJournal;  // (node, previous level)
};

}  // namespace

std::string SelectionParams::validate() const {
  if (!std::isfinite(epsilon) || epsilon < 0.0f) return detail::concat("--epsilon ", epsilon, " invalid (expected a finite value >= 0)");
  if (focus && !(std::isfinite(focus->x) && std::isfinite(focus->y) && std::isfinite(focus->z)))
    return "--focus invalid (expected three finite coordinates in mm)";
  if (eye && !(std::isfinite(eye->x) && std::isfinite(eye->y) && std::isfinite(eye->z))) return "eye position invalid (expected finite mm)";
  if (!std::isfinite(focusRadiusMm) || focusRadiusMm < 0.0) return "focus radius invalid (expected >= 0 mm)";
  if (!std::isfinite(lodPixels) || lodPixels < 0.0) return detail::concat("--lod-pixels ", lodPixels, " invalid (expected a finite value >= 0)");
  if (maxBrickEdge < 1 || maxBrickEdge > 256 || (maxBrickEdge & (maxBrickEdge - 1)))
    return detail::concat("--max-brick ", maxBrickEdge, " invalid (expected a power of two in 1..256 texels)");
  return "";
}

double nodeImportance(const VolumeOctree& octree, const OctreeNode& n, const SelectionParams& params) {
  if (!params.focus && !params.eye) return 1.0;
  glm::dvec3 boxLo, boxHi;
  worldBox(octree, n, params.spacing, &boxLo, &boxHi);
  const glm::dvec3 extent = glm::dvec3(octree.dims() - 1) * params.spacing;
  double radius = params.focusRadiusMm;
  if (radius <= 0.0) radius = 0.25 * glm::length(extent);
  if (radius <= 0.0) return 1.0;
  double imp = 1.0;
  if (params.focus) imp /= 1.0 + distanceToBox(*params.focus, boxLo, boxHi) / radius;
  if (params.eye) imp /= 1.0 + (distanceToBox(*params.eye, boxLo, boxHi) - distanceToBox(*params.eye, glm::dvec3(0.0), extent)) / radius;
  return imp;
}

Selection selectNodes(const VolumeOctree& octree, const SelectionParams& params) {
  if (const std::string msg = params.validate(); !msg.empty()) throw ValueError(msg);
  Refiner refiner(octree, params);
  Selection sel;
  sel.budgetMet = params.texelBudget == 0 || refiner.texels() <= params.texelBudget;
  refiner.run();

  // The bricks in depth-first slot order.
  const std::vector<int8_t>& level = refiner.levels();
  std::vector<uint32_t> stack{0};
  while (!stack.empty()) {
    const uint32_t i = stack.back();
    stack.pop_back();
    const OctreeNode& n = octree.nodes()[i];
    if (level[i] >= 0) {
      Brick b;
      b.node = i;
      b.p = level[i];
      b.error = nodalError(octree, params, i, b.p);
      b.importance = float(refiner.importance(i));
      b.hidden = refiner.hidden(i);
      if (!b.hidden) b.texels = octree.texelDims(n, b.p);
      sel.bricks.push_back(b);
      continue;
    }
    for (int slot = 7; slot >= 0; --slot)
      if (n.childMask & (1u << slot)) stack.push_back(childIndex(n, slot));
  }
  for (const Brick& b : sel.bricks)
    if (!b.hidden) sel.maxError = std::max(sel.maxError, b.error);
  for (const Brick& b : sel.bricks) sel.texels += b.texelCount();
  if (params.blend) assignBlendCorners(octree, &sel);
  return sel;
}

void assignBlendCorners(const VolumeOctree& octree, Selection* sel) {
  const BrickIndex of(*sel);
  const auto isBrick = [&](uint32_t j) { return of[j] >= 0; };
  sel->blendedBricks = 0;
  for (Brick& b : sel->bricks) {
    b.coarseCorners = 0;
    if (b.hidden) continue;
    const OctreeNode& n = octree.nodes()[b.node];
    const int r = resolutionLevel(octree, b);
    for (int c = 0; c < 8; ++c) {
      const glm::ivec3 corner = nodeLo(n) + childOffset(c, octree.edge(n));
      forEachBrickTouching(octree, corner, corner, isBrick, [&](uint32_t j) {
        const Brick& nb = sel->bricks[size_t(of[j])];
        if (!nb.hidden && resolutionLevel(octree, nb) > r) b.coarseCorners |= uint8_t(1u << c);
      });
    }
    sel->blendedBricks += b.coarseCorners != 0;
  }
}

bool isRestricted(const VolumeOctree& octree, const Selection& sel) {
  const BrickIndex of(sel);
  const auto isBrick = [&](uint32_t j) { return of[j] >= 0; };
  for (const Brick& b : sel.bricks) {
    if (b.hidden) continue;
    const OctreeNode& n = octree.nodes()[b.node];
    const int r = resolutionLevel(octree, b);
    bool ok = true;
    forEachBrickTouching(octree, nodeLo(n), nodeHi(octree, n), isBrick, [&](uint32_t j) {
      const Brick& nb = sel.bricks[size_t(of[j])];
      if (!nb.hidden && std::abs(resolutionLevel(octree, nb) - r) > 1) ok = false;
    });
    if (!ok) return false;
  }
  return true;
}

Selection residentSelection(const VolumeOctree& octree, const Selection& selection, const std::function<bool(const Brick&)>& resident,
                            std::vector<Brick>* missing) {
  const std::span<const OctreeNode> nodes = octree.nodes();
  // The nodes from the root down to @p n.
  auto path = [&](const OctreeNode& n) {
    std::vector<uint32_t> p{0};
    while (nodes[p.back()].level < n.level) {
      const OctreeNode& at = nodes[p.back()];
      p.push_back(childIndex(at, childSlot(glm::ivec3(n.origin), octree.depth() - at.level - 1)));
    }
    return p;
  };
  auto brickOf = [&](uint32_t node, int p, float importance) {
    Brick b;
    b.node = node;
    b.p = p;
    b.error = octree.errors(nodes[node])[size_t(p)];
    b.importance = importance;
    b.texels = octree.texelDims(nodes[node], p);
    return b;
  };
  std::unordered_map<uint32_t, Brick> replacing;  // by node: the brick drawing it and all below it
  for (const Brick& b : selection.bricks) {
    const OctreeNode& n = nodes[b.node];
    if (b.hidden || (b.p == 0 && n.level == 0) || resident(b)) continue;
    missing->push_back(b);
    std::optional<Brick> r;
    for (int q = b.p - 1; q >= 0 && !r; --q)
      if (Brick c = brickOf(b.node, q, b.importance); resident(c)) r = c;
    if (!r) {
      const std::vector<uint32_t> up = path(n);
      for (int level = n.level - 1; level >= 0 && !r; --level)
        if (Brick c = brickOf(up[size_t(level)], 0, b.importance); level == 0 || resident(c)) r = c;
    }
    const auto [it, added] = replacing.emplace(r->node, *r);
    if (!added) it->second.importance = std::max(it->second.importance, b.importance);
  }
  // The outermost replacing brick whose node is or holds brick @p b's (a replacement below another
  // is dropped with the bricks it replaced), or null.
  auto coveredBy = [&](const Brick& b) -> const Brick* {
    for (uint32_t a : path(nodes[b.node]))
      if (const auto it = replacing.find(a); it != replacing.end()) return &it->second;
    return nullptr;
  };
  Selection out;
  out.budgetMet = selection.budgetMet;
  std::unordered_set<uint32_t> placed;
  auto add = [&](const Brick& b) {
    out.bricks.push_back(b);
    if (b.hidden) return;
    out.texels += b.texelCount();
    out.blendedBricks += b.coarseCorners != 0;
    out.maxError = std::max(out.maxError, b.error);
  };
  for (const Brick& b : selection.bricks) {
    if (const Brick* r = coveredBy(b); !r)
      add(b);
    else if (placed.insert(r->node).second)
      add(*r);
  }
  return out;
}

}  // namespace hyb
