// Proxy geometry of the slice renderer (LaMar 1999): the polygons that sample a brick, on
// view-aligned planes f·x = kΔ (globally aligned, cut from the brick's box on the CPU; docs/renderer.md)
// or on spherical shells |x − eye| = kΔ around the eye (perspective), each cut to the blocks of
// the brick that the transfer function can make visible. Grid-frame millimetres throughout.
#pragma once

#include <glm/glm.hpp>

#include <array>
#include <cstdint>
#include <utility>
#include <vector>

#include "hybrid_octree/volume_octree.h"
#include "render/slices/brick_textures.h"
#include "render/transfer_function.h"

namespace hyb {

/// Which values the transfer function's lookup table can make visible (a non-zero opacity), in the
/// table's own entries: a range of values reads the entries LutLayout::entries gives it.
class VisibleValues {
 public:
  VisibleValues(const std::vector<glm::vec4>& lut, const LutLayout& layout);
  /// Whether some value in [lo, hi] reads an entry with a non-zero opacity.
  bool any(float lo, float hi) const;
  /// Equal for transfer tables that show the same values (never 0).
  uint64_t key() const { return mKey; }

 private:
  LutLayout mLayout;
  std::vector<int> mPrefix;  // visible entries before each entry
  uint64_t mKey = 0;
};

/// Refreshes @p blocks to those of @p ranges that @p visible can show, unless they are already.
void findVisibleBlocks(const BrickRanges& ranges, const VisibleValues& visible, VisibleBlocks* blocks);

/// The depth the proxies are laid out along: planes f·x = kΔ ("depth" is f·x) or shells
/// |x − eye| = kΔ ("depth" is the distance to the eye).
struct ProxyDepth {
  bool shells = false;
  glm::dvec3 forward{0, 0, 1}, eye{0.0};
  /// The depth of point @p p.
  double of(const glm::dvec3& p) const { return shells ? glm::length(p - eye) : glm::dot(forward, p); }
  /// The depths the box [lo, hi] spans: planes between its nearest and farthest corners, shells
  /// between its nearest point and farthest corner.
  std::pair<double, double> range(const glm::dvec3& lo, const glm::dvec3& hi) const;
};

/// The box (voxel units) of the visible blocks @p blocks of lattice @p lattice; false when there is none.
bool visibleBox(const VisibleBlocks& blocks, const KnotLattice& lattice, glm::dvec3* lo, glm::dvec3* hi);

/// The proxies at depth k·delta, k from kLo; with merge > 1 the blocks are taken in groups of
/// merge³, each visible when any of its blocks is: coarser boxes for fewer block visits. Each
/// block's box grows by grow mm on every side first (pre-integrated fragments read their
/// segment's ends, up to a spacing either side).
struct ProxyPlanes {
  double delta = 1.0;
  long long kLo = 0;
  int merge = 1;
  double grow = 0.0;
};
/// For the proxies k in [kLo, kLo + boxes->size()): the box (mm) of the visible blocks each proxy
/// meets (empty boxes have lo > hi); a block meets the proxies its depth range spans.
void proxyBoxes(const VisibleBlocks& blocks, const KnotLattice& lattice, const glm::dvec3& spacing, const ProxyDepth& depth, const ProxyPlanes& planes,
                std::vector<std::pair<glm::dvec3, glm::dvec3>>* boxes);

/// Appends plane f·x = depth ∩ box [lo, hi] as a triangle fan (mm, xyz a vertex) to @p out;
/// returns whether the plane cuts the box in a polygon.
bool slicePolygon(const glm::dvec3& lo, const glm::dvec3& hi, const glm::dvec3& f, double depth, std::vector<float>* out);

/// Sutherland–Hodgman: clips the convex polygon @p poly to the box [lo, hi].
void clipToBox(const glm::dvec3& lo, const glm::dvec3& hi, std::vector<glm::dvec3>* poly);

/// Directions from the eye to a box, as gnomonic coordinates (s, t) around the axis a towards the
/// box's centre: d ∝ a + s·e1 + t·e2.
struct ShellFrame {
  glm::dvec3 a, e1, e2;
  double s0, s1, t0, t1;
};
/// The shell frame of box [lo, hi] seen from @p eye; false when the box is too wide seen from the
/// eye (a corner more than 60° off the axis) or holds it: such bricks use planes.
bool shellFrame(const glm::dvec3& lo, const glm::dvec3& hi, const glm::dvec3& eye, ShellFrame* frame);
/// Cells of the n×n chord grid that keeps a shell of radius @p r within a quarter of @p delta.
int shellCells(const ShellFrame& frame, double r, double delta);
/// A shell: the sphere |x − eye| = r, drawn as an n×n grid of chords.
struct Shell {
  glm::dvec3 eye;
  double r = 1.0;
  int n = 1;
};
/// Appends shell @p shell inside the box [lo, hi] as triangles (mm, xyz a vertex): its chords over
/// the box's directions @p frame, each clipped to the box. Returns whether anything was appended.
bool shellPolygon(const glm::dvec3& lo, const glm::dvec3& hi, const ShellFrame& frame, const Shell& shell, std::vector<float>* out);

}  // namespace hyb
