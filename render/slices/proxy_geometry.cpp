#include "render/slices/proxy_geometry.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <limits>

#include "volume/core/error.h"

namespace hyb {

namespace {

// Calls visit(block) for every block set in @p v.
template <class Visit>
void forEachVisibleBlock(const VisibleBlocks& v, const Visit& visit) {
  const uint32_t nx = uint32_t(v.blocks.x), nxy = nx * uint32_t(v.blocks.y);
  for (size_t w = 0; w < v.bits.size(); ++w)
    for (uint64_t word = v.bits[w]; word != 0; word &= word - 1) {
      const uint32_t index = uint32_t(w * 64 + size_t(std::countr_zero(word)));
      visit(glm::ivec3(int(index % nx), int(index % nxy / nx), int(index / nxy)));
    }
}

// The box (voxel units) of blocks @p b0 to @p b1 of lattice @p L (blocks are 2×2×2 cells).
void blockBox(const KnotLattice& L, const glm::ivec3& b0, const glm::ivec3& b1, glm::dvec3* lo, glm::dvec3* hi) {
  for (int a = 0; a < 3; ++a) {
    (*lo)[a] = L.knot(a, std::min(2 * b0[a], L.dims[a] - 1));
    (*hi)[a] = L.knot(a, std::min(2 * b1[a] + 2, L.dims[a] - 1));
  }
}

}  // namespace

VisibleValues::VisibleValues(const std::vector<glm::vec4>& lut, const LutLayout& layout) : mLayout(layout), mPrefix(lut.size() + 1, 0) {
  for (size_t i = 0; i < lut.size(); ++i) mPrefix[i + 1] = mPrefix[i] + (lut[i].a > 0.0f);
  // FNV-1a over the layout and which entries are visible.
  uint64_t h = 1469598103934665603ull;
  auto mix = [&](uint64_t x) { h = (h ^ x) * 1099511628211ull; };
  for (float f : {layout.vmin, layout.vmax, layout.scale}) mix(std::bit_cast<uint32_t>(f));
  for (const glm::vec4& e : lut) mix(e.a > 0.0f);
  mKey = h == 0 ? 1 : h;
}

void findVisibleBlocks(const BrickRanges& r, const VisibleValues& visible, VisibleBlocks* v) {
  if (v->key == visible.key() && v->blocks == r.blocks) return;
  v->key = visible.key();
  v->blocks = r.blocks;
  v->lo = glm::ivec3(std::numeric_limits<int>::max());
  v->hi = glm::ivec3(-1);
  v->bits.assign((r.values.size() + 63) / 64, 0);
  size_t index = 0;
  for (int bz = 0; bz < r.blocks.z; ++bz)
    for (int by = 0; by < r.blocks.y; ++by)
      for (int bx = 0; bx < r.blocks.x; ++bx, ++index)
        if (visible.any(r.values[index][0], r.values[index][1])) {
          v->bits[index / 64] |= uint64_t(1) << (index % 64);
          v->lo = glm::min(v->lo, glm::ivec3(bx, by, bz));
          v->hi = glm::max(v->hi, glm::ivec3(bx, by, bz));
        }
}

bool VisibleValues::any(float lo, float hi) const {
  const std::array<uint16_t, 2> span = mLayout.entries(lo, hi);
  return mPrefix[size_t(span[1]) + 1] > mPrefix[span[0]];
}

std::pair<double, double> ProxyDepth::range(const glm::dvec3& lo, const glm::dvec3& hi) const {
  if (!shells) {
    const glm::dvec3 nearCorner = glm::mix(hi, lo, glm::dvec3(glm::greaterThan(forward, glm::dvec3(0.0))));
    return {glm::dot(forward, nearCorner), glm::dot(forward, lo + hi - nearCorner)};
  }
  double far = 0.0;
  for (int c = 0; c < 8; ++c) far = std::max(far, glm::length(glm::dvec3(c & 1 ? hi.x : lo.x, c & 2 ? hi.y : lo.y, c & 4 ? hi.z : lo.z) - eye));
  return {glm::length(eye - glm::clamp(eye, lo, hi)), far};
}

bool visibleBox(const VisibleBlocks& v, const KnotLattice& L, glm::dvec3* lo, glm::dvec3* hi) {
  if (v.empty()) return false;
  blockBox(L, v.lo, v.hi, lo, hi);
  return true;
}

void proxyBoxes(const VisibleBlocks& v, const KnotLattice& L, const glm::dvec3& spacing, const ProxyDepth& depth, const ProxyPlanes& planes,
                std::vector<std::pair<glm::dvec3, glm::dvec3>>* boxes) {
  const double delta = planes.delta, grow = planes.grow;  // (named locals: clang 14 captures no bindings)
  const long long kLo = planes.kLo;
  const int merge = planes.merge;
  const long long count = (long long)boxes->size();
  std::fill(boxes->begin(), boxes->end(), std::pair{glm::dvec3(1e300), glm::dvec3(-1e300)});
  auto add = [&](const glm::ivec3& b0, const glm::ivec3& b1) {
    glm::dvec3 lo, hi;
    blockBox(L, b0, b1, &lo, &hi);
    lo = lo * spacing - grow;
    hi = hi * spacing + grow;
    const auto [near, far] = depth.range(lo, hi);
    const long long k0 = std::max((long long)std::ceil(near / delta) - kLo, 0LL);
    const long long k1 = std::min((long long)std::floor(far / delta) - kLo, count - 1);
    for (long long k = k0; k <= k1; ++k) {
      auto& [ulo, uhi] = (*boxes)[size_t(k)];
      ulo = glm::min(ulo, lo);
      uhi = glm::max(uhi, hi);
    }
  };
  HYB_DCHECK(std::has_single_bit(unsigned(merge)));
  if (merge == 1) {
    forEachVisibleBlock(v, [&](const glm::ivec3& b) { add(b, b); });
    return;
  }
  // Groups of merge³ blocks, each visible when any of its blocks is.
  const glm::ivec3 groups = (v.blocks + merge - 1) / merge;
  std::vector<uint8_t> any(size_t(groups.x) * size_t(groups.y) * size_t(groups.z), 0);
  const int shift = std::countr_zero(unsigned(merge));
  size_t index = 0;
  for (int z = 0; z < v.blocks.z; ++z)
    for (int y = 0; y < v.blocks.y; ++y) {
      uint8_t* row = &any[size_t(groups.x) * (size_t(y >> shift) + size_t(groups.y) * size_t(z >> shift))];
      for (int x = 0; x < v.blocks.x; ++x, ++index)
        if (v.bits[index >> 6] >> (index & 63) & 1) row[x >> shift] = 1;
    }
  index = 0;
  for (int z = 0; z < groups.z; ++z)
    for (int y = 0; y < groups.y; ++y)
      for (int x = 0; x < groups.x; ++x, ++index)
        if (any[index]) {
          const glm::ivec3 b0 = glm::ivec3(x, y, z) * merge;
          add(b0, glm::min(b0 + merge - 1, v.blocks - 1));
        }
}

bool slicePolygon(const glm::dvec3& lo, const glm::dvec3& hi, const glm::dvec3& f, double depth, std::vector<float>* out) {
  std::vector<glm::dvec3> pts;
  pts.reserve(12);
  for (int axis = 0; axis < 3; ++axis)
    for (int c = 0; c < 4; ++c) {
      glm::dvec3 a, b;
      const int u = (axis + 1) % 3, v = (axis + 2) % 3;
      a[u] = b[u] = (c & 1) ? hi[u] : lo[u];
      a[v] = b[v] = (c & 2) ? hi[v] : lo[v];
      a[axis] = lo[axis];
      b[axis] = hi[axis];
      const double da = glm::dot(f, a) - depth, db = glm::dot(f, b) - depth;
      if ((da < 0) == (db < 0) && da != 0 && db != 0) continue;  // an endpoint on the plane counts
      const double t = da == db ? 0.0 : da / (da - db);
      pts.push_back(a + (b - a) * t);
    }
  const int n = int(pts.size());
  if (n < 3) return false;
  glm::dvec3 centre(0.0);
  for (int i = 0; i < n; ++i) centre += pts[i];
  centre /= double(n);
  const glm::dvec3 r = glm::normalize(std::abs(f.x) < 0.9 ? glm::cross(f, glm::dvec3(1, 0, 0)) : glm::cross(f, glm::dvec3(0, 1, 0)));
  const glm::dvec3 u = glm::cross(f, r);
  // Around the centre by angle, as atan2 orders them from −π, with a pseudo-angle: the "diamond"
  // angle in (−2, 2], monotonic in the true one.
  auto angle = [&](const glm::dvec3& p) {
    const double x = glm::dot(p - centre, r), y = glm::dot(p - centre, u), l = std::abs(x) + std::abs(y);
    if (l == 0.0) return 0.0;
    const double d = y >= 0 ? (x >= 0 ? y / l : 2.0 - y / l) : (x < 0 ? 2.0 - y / l : 4.0 + y / l);
    return d > 2.0 ? d - 4.0 : d;
  };
  std::sort(pts.begin(), pts.end(), [&](const glm::dvec3& p, const glm::dvec3& q) { return angle(p) < angle(q); });
  for (int i = 1; i + 1 < n; ++i)
    for (const glm::dvec3* p : {&pts[0], &pts[i], &pts[i + 1]})
      for (int k = 0; k < 3; ++k) out->insert(out->end(), {float((*p)[k])});
  return true;
}

void clipToBox(const glm::dvec3& lo, const glm::dvec3& hi, std::vector<glm::dvec3>* poly) {
  std::vector<glm::dvec3> out;
  for (int axis = 0; axis < 3; ++axis)
    for (int side = 0; side < 2; ++side) {
      if (poly->empty()) return;
      // Inside: x[axis] >= lo[axis] (side 0) or x[axis] <= hi[axis] (side 1).
      auto dist = [&](const glm::dvec3& p) { return side == 0 ? p[axis] - lo[axis] : hi[axis] - p[axis]; };
      out.clear();
      for (size_t i = 0; i < poly->size(); ++i) {
        const glm::dvec3 &a = (*poly)[i], &b = (*poly)[(i + 1) % poly->size()];
        const double da = dist(a), db = dist(b);
        if (da >= 0) out.push_back(a);
        if ((da >= 0) != (db >= 0)) out.push_back(a + (b - a) * (da / (da - db)));
      }
      poly->swap(out);
    }
}

bool shellFrame(const glm::dvec3& lo, const glm::dvec3& hi, const glm::dvec3& eye, ShellFrame* fr) {
  const glm::dvec3 toCentre = 0.5 * (lo + hi) - eye;
  if (glm::length(toCentre) == 0.0) return false;  // the eye at the centre: no axis (it holds the eye)
  fr->a = glm::normalize(toCentre);
  fr->e1 = glm::normalize(glm::cross(fr->a, std::abs(fr->a.x) < 0.9 ? glm::dvec3(1, 0, 0) : glm::dvec3(0, 1, 0)));
  fr->e2 = glm::cross(fr->a, fr->e1);
  fr->s0 = fr->t0 = 1e300;
  fr->s1 = fr->t1 = -1e300;
  for (int c = 0; c < 8; ++c) {
    const glm::dvec3 d = glm::dvec3((c & 1) ? hi.x : lo.x, (c & 2) ? hi.y : lo.y, (c & 4) ? hi.z : lo.z) - eye;
    const double da = glm::dot(d, fr->a);
    if (da <= 0.5 * glm::length(d)) return false;  // more than 60 degrees off the axis
    const double s = glm::dot(d, fr->e1) / da, t = glm::dot(d, fr->e2) / da;
    fr->s0 = std::min(fr->s0, s);
    fr->s1 = std::max(fr->s1, s);
    fr->t0 = std::min(fr->t0, t);
    fr->t1 = std::max(fr->t1, t);
  }
  return true;
}

int shellCells(const ShellFrame& frame, double r, double delta) {
  // Chords whose sagitta stays below a quarter of the spacing.
  const double theta = 2.0 * std::acos(std::max(-1.0, 1.0 - delta / (4.0 * r)));
  return std::clamp(int(std::ceil(std::max(frame.s1 - frame.s0, frame.t1 - frame.t0) / theta)), 1, 32);
}

bool shellPolygon(const glm::dvec3& lo, const glm::dvec3& hi, const ShellFrame& fr, const Shell& shell, std::vector<float>* out) {
  const glm::dvec3 eye = shell.eye;  // (named locals: clang 14 captures no bindings)
  const double r = shell.r;
  const int n = shell.n;
  const size_t before = out->size();
  auto at = [&](int i, int j) {
    const double s = fr.s0 + (fr.s1 - fr.s0) * i / n, t = fr.t0 + (fr.t1 - fr.t0) * j / n;
    return eye + r * glm::normalize(fr.a + s * fr.e1 + t * fr.e2);
  };
  std::vector<glm::dvec3> poly;
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i)
      for (int half = 0; half < 2; ++half) {
        poly = half == 0 ? std::vector<glm::dvec3>{at(i, j), at(i + 1, j), at(i + 1, j + 1)}
                         : std::vector<glm::dvec3>{at(i, j), at(i + 1, j + 1), at(i, j + 1)};
        clipToBox(lo, hi, &poly);
        for (size_t k = 1; k + 1 < poly.size(); ++k)
          for (const glm::dvec3* p : {&poly[0], &poly[k], &poly[k + 1]})
            for (int c = 0; c < 3; ++c) out->push_back(float((*p)[c]));
      }
  return out->size() > before;
}

}  // namespace hyb
