// Reference hybrid ray tracer: M. Levoy, "A Hybrid Ray Tracer for Rendering Polygon and Volume
// Data", IEEE CG&A 10(2), 1990; empty-space skipping and early termination after Levoy 1990,
// "Efficient Ray Tracing of Volume Data".
#include "render/raycast.h"

#include <algorithm>
#include <cmath>

#include "volume/error.h"
#include "volume/parallel.h"

namespace hyb {

namespace {

// Entry and exit distances of the ray through the box [lo, hi]; false when it misses.
bool slab(const glm::dvec3& o, const glm::dvec3& d, const glm::dvec3& lo, const glm::dvec3& hi, double* t0, double* t1) {
  double a = -1e300, b = 1e300;
  for (int k = 0; k < 3; ++k) {
    if (std::abs(d[k]) < 1e-300) {
      if (o[k] < lo[k] || o[k] > hi[k]) return false;
      continue;
    }
    double ta = (lo[k] - o[k]) / d[k], tb = (hi[k] - o[k]) / d[k];
    if (ta > tb) std::swap(ta, tb);
    a = std::max(a, ta);
    b = std::min(b, tb);
  }
  *t0 = a;
  *t1 = b;
  return a <= b;
}

// Shading factor of a headlight on a surface with normal n (two-sided Lambert with ambient).
double headlight(const glm::dvec3& n, const glm::dvec3& dir) { return 0.25 + 0.75 * std::abs(glm::dot(n, dir)); }

// What every pass of one reference frame reads, made once: its inputs, and the nodes whose value
// range the transfer function maps to zero opacity (skipped along the rays).
struct RayFrame {
  const Volume& volume;
  const VolumeOctree& octree;
  const TransferFunction& tf;
  const Camera& camera;
  const RaycastOptions& options;
  RaycastStats* stats;
  ProgressTask* progress;
  std::vector<uint8_t> transparent;
  RayFrame(const Volume& v, const VolumeOctree& t, const TransferFunction& f, const Camera& c, const RaycastOptions& o, RaycastStats* s,
           ProgressTask* p)
      : volume(v), octree(t), tf(f), camera(c), options(o), stats(s), progress(p), transparent(t.nodes().size()) {
    for (size_t i = 0; i < transparent.size(); ++i)
      transparent[i] = o.skipEmptySpace && f.maxAlpha(t.nodes()[i].minValue, t.nodes()[i].maxValue) <= 0.0f;
  }
};

// Traces pixels pixel(0) … pixel(count − 1) into @p out on all cores, chunk pixels at a time.
template <class Pixel>
void tracePixels(const RayFrame& f, size_t count, size_t chunk, const Pixel& pixel, Image* out) {
  const Volume& volume = f.volume;
  const VolumeOctree& octree = f.octree;
  const TransferFunction& tf = f.tf;
  const Camera& camera = f.camera;
  const RaycastOptions& options = f.options;
  const std::vector<uint8_t>& transparent = f.transparent;
  Image& image = *out;
  const glm::dvec3 spacing = volume.spacing();
  const glm::dvec3 boxHi = volume.extentMm();
  const double dt = options.stepVoxels * std::min({spacing.x, spacing.y, spacing.z});
  const glm::ivec3 cells = glm::max(volume.dims() - 1, glm::ivec3(1));
  const auto& nodes = octree.nodes();

  // The transparent node containing voxel-space point q (or -1), with its box in mm.
  auto transparentBoxAt = [&](const glm::dvec3& q, glm::dvec3* lo, glm::dvec3* hi) -> bool {
    const glm::dvec3 c = glm::clamp(q, glm::dvec3(0.0), glm::dvec3(cells) - 1e-6);
    uint32_t i = 0;
    for (;;) {
      const OctreeNode& n = nodes[i];
      if (transparent[i]) {
        glm::ivec3 a, b;
        octree.voxelBox(n, &a, &b);
        *lo = glm::dvec3(a) * spacing;
        *hi = glm::dvec3(b) * spacing;
        return true;
      }
      if (n.isLeaf()) return false;
      const int half = octree.edge(n) / 2;
      const glm::ivec3 rel = glm::ivec3(glm::floor(c)) - glm::ivec3(n.origin);
      const int slot = (rel.x >= half) | (rel.y >= half) << 1 | (rel.z >= half) << 2;
      if (!(n.childMask & (1u << slot))) return false;
      i = childIndex(n, slot);
    }
  };

  const glm::dvec4 cut = options.cut ? options.cut->keptSide(camera) : glm::dvec4(0, 0, 0, 1);

  uint64_t samples = 0, skipped = 0, crossings = 0;
  ParallelFailure failure;  // a progress callback that stops the frame
#pragma omp parallel reduction(+ : samples, skipped, crossings)
  {
    std::vector<Hit> hits;
    std::optional<KnotSampler> paged;
    if (options.knots) paged.emplace(*options.knots);
    auto sampleAt = [&](const glm::vec3& q) { return paged ? paged->sample(q) : volume.sample(q); };
    auto gradientAt = [&](const glm::vec3& q) { return paged ? paged->sampleGradient(q) : volume.sampleGradient(q); };
#pragma omp for schedule(dynamic, chunk)
    for (size_t i = 0; i < count; ++i) {
      // One iteration a pixel; what it throws (a progress callback that stops, a block that cannot
      // be read) ends the frame.
      failure.run([&] {
        f.progress->advance();
        const glm::ivec2 px = pixel(i);
        const int x = px.x, y = px.y;
        glm::dvec3 o, d;
        camera.ray(x + 0.5, y + 0.5, &o, &d);
        glm::dvec4 acc(0.0);  // premultiplied rgb, alpha
        auto composite = [&](const glm::dvec3& rgb, double a) {
          acc += glm::dvec4(rgb * a, a) * (1.0 - acc.a);
        };
        double t0 = 0, t1 = 0;
        const bool inBox = slab(o, d, glm::dvec3(0.0), boxHi, &t0, &t1);
        t0 = std::max(t0, 0.0);
        // The cutting plane: only [keepLo, keepHi] of the ray is kept; where the ray enters the kept
        // side inside the data box, the plane shows the data's colour, opaque.
        double keepLo = 0.0, keepHi = 1e300;
        if (options.cut) {
          const double sd = glm::dot(glm::dvec3(cut), o) + cut.w, dn = glm::dot(glm::dvec3(cut), d);
          if (dn > 0.0) {
            keepLo = std::max(0.0, -sd / dn);
            const double slack = 1e-9 * glm::length(boxHi);
            if (inBox && keepLo >= t0 - slack && keepLo <= t1 + slack && (!options.region || options.region->contains(o + d * keepLo))) {
              const glm::vec4 c = tf.lookup(sampleAt(glm::vec3((o + d * keepLo) / spacing)));
              if (c.a > 0.0f) {
                image.at(x, y) = glm::vec4(glm::vec3(c), 1.0f);
                return;
              }
            }
          } else if (sd < 0.0) {
            keepHi = -1.0;  // the whole ray is on the removed side
          } else if (dn < 0.0) {
            keepHi = -sd / dn;
          }
        }
        t0 = std::max(t0, keepLo);
        t1 = std::min(t1, keepHi);
        if (options.surface) options.surface->allHits(o, d, keepLo, std::max(keepLo, keepHi), &hits);
        size_t nextHit = 0;
        double backT = -1.0;  // the last pre-integrated segment's end, and its value
        float backValue = 0.0f;
        auto surfaceUntil = [&](double t) {  // composite surface crossings before distance t
          while (nextHit < hits.size() && hits[nextHit].t <= t && acc.a < 0.999) {
            const glm::vec4 c = options.surfaceColor;
            composite(glm::dvec3(c) * headlight(hits[nextHit].normal, d), c.a);
            ++nextHit;
            ++crossings;
          }
        };
        // A region's frame: the segments whose (unclipped) middles lie in the region, on the whole
        // frame's lattice from t0, so that the regions' images composite into the whole frame's.
        double first = t0, last = t1;
        if (options.region && inBox) {
          double r0 = 0, r1 = 0;
          if (slab(o, d, options.region->lo, options.region->hi, &r0, &r1)) {
            first = t0 + std::max(0.0, std::floor((r0 - t0) / dt) - 1.0) * dt;
            last = std::min(t1, r1 + dt);
          } else {
            last = first;
          }
        }
        auto owned = [&](double ta) {  // by the lattice index, so that every region decides alike
          return !options.region || options.region->contains(o + d * (t0 + (std::round((ta - t0) / dt) + 0.5) * dt));
        };
        if (inBox && options.volume && t1 > t0) {
          // Volume segments of length dt from t0, split at surface crossings.
          for (double ta = first; ta < last && acc.a < 0.999;) {
            if (!owned(ta)) {
              ta += dt;
              continue;
            }
            glm::dvec3 lo, hi;
            const glm::dvec3 p = o + d * ta;
            if (transparentBoxAt(p / spacing, &lo, &hi)) {
              // The whole segments inside the transparent node are skipped; the one it leaves in is
              // sampled (its middle, or its end pre-integrated, may lie beyond the node).
              double e0, e1;
              slab(o, d, lo, hi, &e0, &e1);
              const double resume = t0 + std::floor((std::max(e1, ta) - t0) / dt + 1e-9) * dt;
              if (resume > ta) {
                surfaceUntil(std::min(resume, t1));
                ++skipped;
                ta = resume;
                continue;
              }
            }
            double tb = std::min(ta + dt, t1);
            for (double s = ta; s < tb && acc.a < 0.999;) {
              const double e = (nextHit < hits.size() && hits[nextHit].t < tb) ? std::max(hits[nextHit].t, s) : tb;
              if (e > s) {
                const double tm = 0.5 * (s + e);
                const glm::dvec3 q = (o + d * tm) / spacing;
                auto shadeAt = [&] {
                  if (!options.shading) return 1.0;
                  const glm::dvec3 g(gradientAt(glm::vec3(q)));
                  const double len = glm::length(g);
                  return len > 1e-6 ? headlight(g / len, d) : 1.0;
                };
                if (const PreIntegrationTable* pre = options.preintegrated) {
                  // The segment [s, e] between its two ends' values (the front one is the last
                  // segment's back one when they meet).
                  const bool meets = s == backT;
                  const float front = meets ? backValue : sampleAt(glm::vec3((o + d * s) / spacing));
                  backValue = sampleAt(glm::vec3((o + d * e) / spacing));
                  backT = e;
                  samples += meets ? 1 : 2;
                  const glm::vec4 c = pre->lookup(front, backValue, e - s, options.voi ? options.voi->factor(o + d * tm) : 1.0);
                  if (c.a > 0.0f) acc += glm::dvec4(glm::dvec3(c) * shadeAt(), c.a) * (1.0 - acc.a);
                } else {
                  glm::vec4 c = tf.lookup(sampleAt(glm::vec3(q)));
                  if (options.voi) c.a = float(std::min(1.0, double(c.a) * options.voi->factor(o + d * tm)));
                  ++samples;
                  const float a = TransferFunction::segmentAlpha(c.a, float(e - s));
                  if (a > 0.0f) composite(glm::dvec3(c) * shadeAt(), a);
                }
              }
              s = e;
              surfaceUntil(s);
            }
            ta = tb;
          }
        }
        surfaceUntil(1e300);
        image.at(x, y) = glm::vec4(acc);
      });
    }
  }
  failure.rethrow();
  f.stats->samples += samples;
  f.stats->skippedLeaves += skipped;
  f.stats->surfaceHits += crossings;
  f.stats->rays += count;
}

// Levoy's progressive (adaptive) refinement: rays on a grid 2^(levels − 1) pixels apart, then, level
// by level, at half the spacing inside every square whose corners' colours differ by more than the
// tolerance; the other squares keep the bilinear interpolation of their corners. With tolerance 0
// the last level traces every pixel not traced yet: the image is the exact one.
Image refine(const RayFrame& f) {
  const RaycastOptions& options = f.options;
  const int W = f.camera.width, H = f.camera.height, levels = options.refineLevels;
  Image image(W, H);
  std::vector<uint8_t> traced(size_t(W) * size_t(H), 0);
  std::vector<glm::ivec2> todo;
  auto want = [&](int x, int y) {
    uint8_t& t = traced[size_t(y) * size_t(W) + size_t(x)];
    if (!t) todo.push_back({x, y});
    t = 1;
  };
  auto trace = [&] {
    tracePixels(f, todo.size(), 64, [&](size_t i) { return todo[i]; }, &image);
    todo.clear();
  };
  // Squares [x0, x1] × [y0, y1] whose corners are traced: the first grid's, then their quarters.
  struct Square {
    int x0, y0, x1, y1;
  };
  auto grid = [](int n, int s) {
    std::vector<int> g;
    for (int v = 0; v < n; v += s) g.push_back(v);
    if (g.back() != n - 1) g.push_back(n - 1);
    return g;
  };
  const int first = 1 << (levels - 1);
  const std::vector<int> gx = grid(W, first), gy = grid(H, first);
  std::vector<Square> open, settled;
  for (size_t j = 0; j < gy.size(); ++j)
    for (size_t i = 0; i < gx.size(); ++i) {
      want(gx[i], gy[j]);
      if ((i + 1 < gx.size() || gx.size() == 1) && (j + 1 < gy.size() || gy.size() == 1))
        open.push_back({gx[i], gy[j], gx[std::min(i + 1, gx.size() - 1)], gy[std::min(j + 1, gy.size() - 1)]});
    }
  auto fill = [&](const Square& q) {
    const glm::vec4 a = image.at(q.x0, q.y0), b = image.at(q.x1, q.y0), c = image.at(q.x0, q.y1), e = image.at(q.x1, q.y1);
    for (int y = q.y0; y <= q.y1; ++y)
      for (int x = q.x0; x <= q.x1; ++x) {
        if (traced[size_t(y) * size_t(W) + size_t(x)]) continue;
        const float u = q.x1 > q.x0 ? float(x - q.x0) / float(q.x1 - q.x0) : 0.0f, v = q.y1 > q.y0 ? float(y - q.y0) / float(q.y1 - q.y0) : 0.0f;
        image.at(x, y) = glm::mix(glm::mix(a, b, u), glm::mix(c, e, u), v);
      }
  };
  auto differ = [&](const Square& q) {
    const glm::vec4 a = image.at(q.x0, q.y0), b = image.at(q.x1, q.y0), c = image.at(q.x0, q.y1), e = image.at(q.x1, q.y1);
    const glm::vec4 spread = glm::max(glm::max(a, b), glm::max(c, e)) - glm::min(glm::min(a, b), glm::min(c, e));
    return std::max({spread.r, spread.g, spread.b, spread.a}) > options.refineTolerance;
  };
  for (int level = 1; level <= levels; ++level) {
    if (level > 1) {
      std::vector<Square> next;
      for (const Square& q : open) {
        if (q.x1 - q.x0 <= 1 && q.y1 - q.y0 <= 1) continue;  // every pixel of it is a corner
        if (!differ(q) && options.refineTolerance > 0.0f) {
          settled.push_back(q);
          continue;
        }
        // Halves along each axis at least two pixels long (the square itself along the others).
        auto halves = [](int lo, int hi) {
          return hi - lo >= 2 ? std::vector<glm::ivec2>{{lo, (lo + hi) / 2}, {(lo + hi) / 2, hi}} : std::vector<glm::ivec2>{{lo, hi}};
        };
        for (const glm::ivec2& ry : halves(q.y0, q.y1))
          for (const glm::ivec2& rx : halves(q.x0, q.x1)) {
            for (const int y : {ry.x, ry.y})
              for (const int x : {rx.x, rx.y}) want(x, y);
            next.push_back({rx.x, ry.x, rx.y, ry.y});
          }
      }
      open.swap(next);
    }
    trace();
    for (const Square& q : settled) fill(q);
    for (const Square& q : open) fill(q);
    if (options.onLevel) options.onLevel(level, image, f.stats->rays);
  }
  return image;
}

}  // namespace

RaycastOptions raycastOptions(const FrameGrid& grid, const Look& look, const Quality& quality, const Bvh* surface) {
  RaycastOptions ro;
  ro.stepVoxels = quality.step.value_or(0.25);
  ro.shading = look.shading;
  ro.surface = surface;
  ro.surfaceColor = look.surfaceColor;
  ro.cut = grid.cut ? &*grid.cut : nullptr;
  ro.voi = grid.voi ? &*grid.voi : nullptr;
  ro.region = quality.region ? &*quality.region : nullptr;
  // Levoy's refinement: progressive levels (the first grid 2^(N−1) pixels apart), or four with
  // an adaptive tolerance alone; the last level is exact unless the tolerance is given.
  ro.refineLevels = quality.progressive > 1 ? quality.progressive : quality.adaptive > 0 ? 4 : 1;
  ro.refineTolerance = float(quality.adaptive / 255.0);
  ro.rows = quality.rows;
  return ro;
}

Image raycast(const Volume& volume, const VolumeOctree& octree, const TransferFunction& tf, const Camera& camera,
              const RaycastOptions& options, RaycastStats* stats) {
  HYB_CHECK(options.refineLevels >= 1 && options.refineLevels <= 16 && options.refineTolerance >= 0.0f);
  const glm::ivec2 rows = options.rows.value_or(glm::ivec2(0, camera.height));
  HYB_CHECK(rows.x >= 0 && rows.x < rows.y && rows.y <= camera.height && (!options.rows || options.refineLevels == 1));
  // Rays from farther away lose the sample positions' precision (and NaN ones index nothing).
  if (!withinCameraRange(camera.eye) || !withinCameraRange(camera.center))
    HYB_THROW(ValueError, "camera eye and center must lie within ", kMaxCameraMm, " mm of the origin");
  RaycastStats counts;
  Image image(camera.width, camera.height);
  ProgressTask progress(options.progress, "ray tracing", uint64_t(camera.width) * uint64_t(rows.y - rows.x));
  const RayFrame f(volume, octree, tf, camera, options, &counts, &progress);
  if (options.refineLevels > 1) {
    image = refine(f);
  } else {
    // Squares of 8² pixels: neighbouring rays read the same samples (and a paged scene's tiles)
    // while they are at hand.
    constexpr int kSquare = 8;
    std::vector<glm::ivec2> order;
    order.reserve(size_t(camera.width) * size_t(rows.y - rows.x));
    for (int y0 = rows.x; y0 < rows.y; y0 += kSquare)
      for (int x0 = 0; x0 < camera.width; x0 += kSquare)
        for (int y = y0; y < std::min(y0 + kSquare, rows.y); ++y)
          for (int x = x0; x < std::min(x0 + kSquare, camera.width); ++x) order.push_back({x, y});
    tracePixels(f, order.size(), kSquare * kSquare, [&order](size_t i) { return order[i]; }, &image);
  }
  if (stats) *stats = counts;
  return image;
}

}  // namespace hyb
