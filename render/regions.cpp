// Sort-last regions (render/regions.h).
#include "render/regions.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

#include "volume/core/error.h"

namespace hyb {

namespace {

// A brick's box in cells (voxel indices), cropped to the grid.
struct CellBox {
  glm::ivec3 lo, hi;
};

struct Splitter {
  const std::vector<CellBox>& boxes;
  const std::vector<double>& costs;
  glm::dvec3 spacing;
  Regions* out;

  // Splits bricks @p ids (box @p box) among regions [first, first + parts); returns the tree node.
  int split(std::vector<uint32_t> ids, const RegionBox& box, int first, int parts) {
    const int node = int(out->tree.size());
    out->tree.emplace_back();
    if (parts == 1) {
      out->tree[size_t(node)].region = first;
      out->boxes[size_t(first)] = box;
      for (const uint32_t b : ids) {
        out->brickRegion[b] = uint32_t(first);
        out->cost[size_t(first)] += costs[b];
      }
      return node;
    }
    const int below = parts / 2;
    const double total = std::accumulate(ids.begin(), ids.end(), 0.0, [&](double s, uint32_t b) { return s + costs[b]; });
    const double want = total * double(below) / double(parts);
    // The plane no brick straddles whose side below comes nearest its share (ties: the first axis,
    // the lowest plane).
    int bestAxis = -1, bestCut = 0;
    double bestMiss = INFINITY;
    for (int a = 0; a < 3; ++a) {
      std::sort(ids.begin(), ids.end(), [&](uint32_t p, uint32_t q) { return boxes[p].lo[a] < boxes[q].lo[a]; });
      double before = 0.0;  // cost of the bricks starting below the candidate
      int reach = std::numeric_limits<int>::min();  // their furthest end
      for (size_t i = 0; i < ids.size();) {
        const int x = boxes[ids[i]].lo[a];
        if (i > 0 && reach <= x && std::abs(before - want) < bestMiss) {
          bestMiss = std::abs(before - want);
          bestAxis = a;
          bestCut = x;
        }
        for (; i < ids.size() && boxes[ids[i]].lo[a] == x; ++i) {
          before += costs[ids[i]];
          reach = std::max(reach, boxes[ids[i]].hi[a]);
        }
      }
    }
    Regions::Node n;
    RegionBox lo = box, hi = box;
    std::vector<uint32_t> under, over;
    if (bestAxis < 0) {
      // Nothing to split: the regions above are empty boxes at the box's top.
      n.axis = 0;
      n.position = box.hi.x;
      under = std::move(ids);
      hi.lo.x = box.hi.x;
    } else {
      n.axis = bestAxis;
      n.position = double(bestCut) * spacing[bestAxis];
      for (const uint32_t b : ids) (boxes[b].lo[bestAxis] < bestCut ? under : over).push_back(b);
      lo.hi[bestAxis] = n.position;
      hi.lo[bestAxis] = n.position;
    }
    n.below = split(std::move(under), lo, first, below);
    n.above = split(std::move(over), hi, first + below, parts - below);
    out->tree[size_t(node)] = n;
    return node;
  }
};

}  // namespace

double regionCost(const Brick& b) { return (b.hidden ? 0.0 : double(b.texelCount())) + 4096.0; }

Regions splitSelection(const VolumeOctree& octree, const glm::dvec3& spacing, const Selection& selection, int parts) {
  if (parts < 1) HYB_THROW(ValueError, "regions: ", parts, " parts (expected at least 1)");
  const glm::ivec3 cells = glm::max(octree.dims() - 1, glm::ivec3(1));
  std::vector<CellBox> boxes(selection.bricks.size());
  std::vector<double> costs(selection.bricks.size());
  for (size_t b = 0; b < boxes.size(); ++b) {
    const OctreeNode& n = octree.nodes()[selection.bricks[b].node];
    const glm::ivec3 lo(n.origin);
    boxes[b] = {lo, glm::min(lo + octree.edge(n), cells)};
    costs[b] = regionCost(selection.bricks[b]);
  }
  Regions out;
  out.boxes.resize(size_t(parts));
  out.brickRegion.assign(boxes.size(), 0);
  out.cost.assign(size_t(parts), 0.0);
  std::vector<uint32_t> ids(boxes.size());
  std::iota(ids.begin(), ids.end(), 0u);
  Splitter{boxes, costs, spacing, &out}.split(std::move(ids), RegionBox{}, 0, parts);
  return out;
}

std::vector<int> Regions::frontToBack(const glm::dvec3& eye) const {
  std::vector<int> order;
  std::vector<int> stack{0};
  while (!stack.empty()) {
    const Node& n = tree[size_t(stack.back())];
    stack.pop_back();
    if (n.axis < 0) {
      order.push_back(n.region);
      continue;
    }
    const bool eyeBelow = eye[n.axis] < n.position;
    stack.push_back(eyeBelow ? n.above : n.below);  // popped second: behind
    stack.push_back(eyeBelow ? n.below : n.above);
  }
  return order;
}

namespace {

struct ClipVertex {
  glm::vec3 p, n;
};

// The point where edge (a, b) meets the plane p[axis] = s, computed from the endpoint lower along
// the axis so that both sides of the plane get the same bits.
ClipVertex crossing(ClipVertex a, ClipVertex b, int axis, float s) {
  if (b.p[axis] < a.p[axis]) std::swap(a, b);
  const float t = (s - a.p[axis]) / (b.p[axis] - a.p[axis]);
  ClipVertex c{a.p + (b.p - a.p) * t, a.n + (b.n - a.n) * t};
  c.p[axis] = s;
  return c;
}

// Sutherland–Hodgman against the closed half-space sign·(p[axis] − s) ≤ 0.
void clip(std::vector<ClipVertex>* poly, int axis, float s, float sign, std::vector<ClipVertex>* scratch) {
  scratch->clear();
  const size_t n = poly->size();
  for (size_t i = 0; i < n; ++i) {
    const ClipVertex& a = (*poly)[i];
    const ClipVertex& b = (*poly)[(i + 1) % n];
    const bool ina = sign * (a.p[axis] - s) <= 0.0f, inb = sign * (b.p[axis] - s) <= 0.0f;
    if (ina) scratch->push_back(a);
    if (ina != inb) scratch->push_back(crossing(a, b, axis, s));
  }
  poly->swap(*scratch);
}

}  // namespace

TriangleMesh cutMeshToRegion(const TriangleMesh& mesh, const RegionBox& box) {
  TriangleMesh out;
  if (box.empty()) return out;
  const bool smooth = !mesh.normals.empty();
  std::vector<uint32_t> starts = mesh.polygonStarts;
  if (starts.empty()) {
    starts.resize(mesh.triangles.size() + 1);
    std::iota(starts.begin(), starts.end(), 0u);
  }
  std::vector<uint32_t> remap(mesh.vertices.size(), UINT32_MAX);
  auto keep = [&](uint32_t v) {
    if (remap[v] == UINT32_MAX) {
      remap[v] = uint32_t(out.vertices.size());
      out.vertices.push_back(mesh.vertices[v]);
      if (smooth) out.normals.push_back(mesh.normals[v]);
    }
    return remap[v];
  };
  std::vector<ClipVertex> poly, scratch;
  out.polygonStarts.push_back(0);
  for (size_t f = 0; f + 1 < starts.size(); ++f) {
    glm::dvec3 lo(INFINITY), hi(-INFINITY), centroid(0.0);
    for (uint32_t t = starts[f]; t < starts[f + 1]; ++t)
      for (int k = 0; k < 3; ++k) {
        const glm::dvec3 p(mesh.vertices[mesh.triangles[t][k]]);
        lo = glm::min(lo, p);
        hi = glm::max(hi, p);
        centroid += p;
      }
    if (starts[f + 1] == starts[f]) continue;
    centroid /= 3.0 * double(starts[f + 1] - starts[f]);
    if (glm::any(glm::lessThan(hi, box.lo)) || glm::any(glm::greaterThan(lo, box.hi))) continue;  // outside
    const bool inside = glm::all(glm::lessThanEqual(box.lo, lo)) && glm::all(glm::lessThanEqual(hi, box.hi));
    if (inside) {
      if (!box.contains(centroid)) continue;  // lying on a face: the region holding its centroid draws it
      for (uint32_t t = starts[f]; t < starts[f + 1]; ++t)
        out.triangles.push_back({keep(mesh.triangles[t].x), keep(mesh.triangles[t].y), keep(mesh.triangles[t].z)});
    } else {
      // Flat on an axis and lying on a face of the box: the region holding that plane (half-open) draws it.
      bool onOtherSide = false;
      for (int a = 0; a < 3; ++a) onOtherSide |= lo[a] == hi[a] && !(box.lo[a] <= lo[a] && lo[a] < box.hi[a]);
      if (onOtherSide) continue;
      for (uint32_t t = starts[f]; t < starts[f + 1]; ++t) {
        poly.clear();
        for (int k = 0; k < 3; ++k) {
          const uint32_t v = mesh.triangles[t][k];
          poly.push_back({mesh.vertices[v], smooth ? mesh.normals[v] : glm::vec3(0.0f)});
        }
        for (int a = 0; a < 3 && poly.size() >= 3; ++a) {
          if (std::isfinite(box.lo[a]) && lo[a] < box.lo[a]) clip(&poly, a, float(box.lo[a]), -1.0f, &scratch);
          if (poly.size() >= 3 && std::isfinite(box.hi[a]) && hi[a] > box.hi[a]) clip(&poly, a, float(box.hi[a]), 1.0f, &scratch);
        }
        if (poly.size() < 3) continue;
        const uint32_t first = uint32_t(out.vertices.size());
        for (const ClipVertex& c : poly) {
          out.vertices.push_back(c.p);
          if (smooth) out.normals.push_back(c.n);
        }
        for (uint32_t k = 1; k + 1 < poly.size(); ++k) out.triangles.push_back({first, first + k, first + k + 1});
      }
    }
    if (out.triangles.size() > out.polygonStarts.back()) out.polygonStarts.push_back(uint32_t(out.triangles.size()));
  }
  if (mesh.polygonStarts.empty()) out.polygonStarts.clear();  // nothing was known of polygons
  return out;
}

}  // namespace hyb
