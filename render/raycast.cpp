// Reference hybrid ray tracer: M. Levoy, "A Hybrid Ray Tracer for Rendering Polygon and Volume
// Data", IEEE CG&A 10(2), 1990; empty-space skipping and early termination after Levoy 1990,
// "Efficient Ray Tracing of Volume Data".
#include "render/raycast.h"

#include <algorithm>
#include <cmath>
#include <optional>

#include "volume/core/error.h"
#include "volume/core/parallel.h"

namespace hyb {

bool raySlab(const glm::dvec3& o, const glm::dvec3& d, const glm::dvec3& lo, const glm::dvec3& hi, double* t0, double* t1) {
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

namespace {

// Shading factor of a headlight on a surface with normal n (two-sided Lambert with ambient).
double headlight(const glm::dvec3& n, const glm::dvec3& dir) { return 0.25 + 0.75 * std::abs(glm::dot(n, dir)); }

// The scene a reference frame traces: the volume, its Volume Octree and the transfer function.
struct RayScene {
  const Volume& volume;
  const VolumeOctree& octree;
  const TransferFunction& tf;
};

// What every pass of one reference frame reads, made once: its inputs, the ray march's constants,
// and the nodes whose value range the transfer function maps to zero opacity (skipped along the rays).
struct RayFrame {
  const Volume& volume;
  const VolumeOctree& octree;
  const TransferFunction& tf;
  const Camera& camera;
  const RaycastOptions& options;
  RaycastStats* stats;
  ProgressTask* progress;
  glm::dvec3 spacing, boxHi;  // mm
  double dt;                  // the segments' length, mm
  glm::ivec3 cells;
  glm::dvec4 cut;  // the cutting plane's kept side (everything kept without a plane)
  std::vector<uint8_t> transparent;
  RayFrame(const RayScene& scene, const Camera& c, const RaycastOptions& o, RaycastStats* s, ProgressTask* p)
      : volume(scene.volume), octree(scene.octree), tf(scene.tf), camera(c), options(o), stats(s), progress(p), spacing(volume.spacing()),
        boxHi(volume.extentMm()), dt(o.stepVoxels * std::min({spacing.x, spacing.y, spacing.z})),
        cells(glm::max(volume.dims() - 1, glm::ivec3(1))), cut(o.cut ? o.cut->keptSide(c) : glm::dvec4(0, 0, 0, 1)),
        transparent(octree.nodes().size()) {
    for (size_t i = 0; i < transparent.size(); ++i)
      transparent[i] = o.skipEmptySpace && tf.maxAlpha(octree.nodes()[i].minValue, octree.nodes()[i].maxValue) <= 0.0f &&
                       !(o.geometry && o.geometry->holds(uint32_t(i)));
  }

  // The transparent node containing voxel-space point q, with its box in mm; false when none does.
  bool transparentBoxAt(const glm::dvec3& q, glm::dvec3* lo, glm::dvec3* hi) const {
    const auto& nodes = octree.nodes();
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
  }
};

// One ray as it is traced: where it runs, the stretch of it kept, and what it has composited.
struct Ray {
  glm::dvec3 o, d;
  double t0 = 0, t1 = 0;  // its stretch inside the data box, then inside the kept stretch too
  bool inBox = false;
  double keepLo = 0.0, keepHi = 1e300;  // the stretch on the cutting plane's kept side
  glm::dvec4 acc{0.0};                  // premultiplied rgb, alpha
  size_t nextHit = 0;                   // the first surface crossing not composited yet
  double backT = -1.0;                  // the last pre-integrated segment's end, and its value
  float backValue = 0.0f;
};

// One thread's tracer: a ray's stages as methods (the cutting plane, the surface crossings, the
// volume's segments), its buffers and counts kept from one pixel to the next.
class PixelTracer {
 public:
  explicit PixelTracer(const RayFrame& f) : mF(f), mOptions(f.options) {
    if (mOptions.knots) mPaged.emplace(*mOptions.knots);
  }

  // The colour of pixel (x, y): premultiplied, or the cutting plane's opaque where the ray meets it.
  glm::vec4 trace(int x, int y) {
    Ray r;
    mF.camera.ray(x + 0.5, y + 0.5, &r.o, &r.d);
    r.inBox = raySlab(r.o, r.d, glm::dvec3(0.0), mF.boxHi, &r.t0, &r.t1);
    r.t0 = std::max(r.t0, 0.0);
    if (mOptions.cut) {
      if (const std::optional<glm::vec4> plane = keepCutSide(r)) return *plane;
    }
    r.t0 = std::max(r.t0, r.keepLo);
    r.t1 = std::min(r.t1, r.keepHi);
    if (mOptions.surface) mOptions.surface->allHits(r.o, r.d, r.keepLo, std::max(r.keepLo, r.keepHi), &mHits);
    if (mOptions.meshes) addMeshHits(r);
    if (r.inBox && mOptions.volume && r.t1 > r.t0) marchVolume(r);
    surfaceUntil(r, 1e300);
    return glm::vec4(r.acc);
  }

  uint64_t samples = 0, skipped = 0, crossings = 0;

 private:
  float sampleAt(const glm::vec3& q) { return mPaged ? mPaged->sample(q) : mF.volume.sample(q); }
  glm::vec3 gradientAt(const glm::vec3& q) { return mPaged ? mPaged->sampleGradient(q) : mF.volume.sampleGradient(q); }

  static void composite(Ray& r, const glm::dvec3& rgb, double a) { r.acc += glm::dvec4(rgb * a, a) * (1.0 - r.acc.a); }

  // The cutting plane: only [keepLo, keepHi] of the ray is kept; where the ray enters the kept side
  // inside the data box, the plane shows the data's colour, opaque (returned).
  std::optional<glm::vec4> keepCutSide(Ray& r) {
    const glm::dvec4& cut = mF.cut;
    const double sd = glm::dot(glm::dvec3(cut), r.o) + cut.w, dn = glm::dot(glm::dvec3(cut), r.d);
    if (dn > 0.0) {
      r.keepLo = std::max(0.0, -sd / dn);
      const double slack = 1e-9 * glm::length(mF.boxHi);
      if (r.inBox && r.keepLo >= r.t0 - slack && r.keepLo <= r.t1 + slack && (!mOptions.region || mOptions.region->contains(r.o + r.d * r.keepLo))) {
        const glm::vec4 c = mF.tf.lookup(sampleAt(glm::vec3((r.o + r.d * r.keepLo) / mF.spacing)));
        if (c.a > 0.0f) return glm::vec4(glm::vec3(c), 1.0f);
      }
    } else if (sd < 0.0) {
      r.keepHi = -1.0;  // the whole ray is on the removed side
    } else if (dn < 0.0) {
      r.keepHi = -sd / dn;
    }
    return std::nullopt;
  }

  // The user meshes' crossings merged into the isosurface's (mesh k's as part k + 1).
  void addMeshHits(const Ray& r) {
    if (!mOptions.surface) mHits.clear();
    mOptions.meshes->allHits(r.o, r.d, r.keepLo, std::max(r.keepLo, r.keepHi), &mMeshHits);
    if (mMeshHits.empty()) return;
    for (Hit& h : mMeshHits) ++h.part;
    const size_t surface = mHits.size();
    mHits.insert(mHits.end(), mMeshHits.begin(), mMeshHits.end());
    std::inplace_merge(mHits.begin(), mHits.begin() + std::ptrdiff_t(surface), mHits.end(), [](const Hit& a, const Hit& b) { return a.t < b.t; });
  }

  // Composites the surface crossings before distance @p t.
  void surfaceUntil(Ray& r, double t) {
    while (r.nextHit < mHits.size() && mHits[r.nextHit].t <= t && r.acc.a < 0.999) {
      const uint32_t part = mHits[r.nextHit].part;
      const glm::vec4 c = part == 0 ? mOptions.surfaceColor : mOptions.meshColors[part - 1];
      composite(r, glm::dvec3(c) * headlight(mHits[r.nextHit].normal, r.d), c.a);
      ++r.nextHit;
      ++crossings;
    }
  }

  // Volume segments of length dt from t0, split at surface crossings, the whole segments inside a
  // transparent node skipped. A region's frame marches the segments whose (unclipped) middles lie in
  // the region, on the whole frame's lattice from t0, so that the regions' images composite into
  // the whole frame's.
  void marchVolume(Ray& r) {
    const double dt = mF.dt, t0 = r.t0, t1 = r.t1;
    double first = t0, last = t1;
    if (mOptions.region) {
      double r0 = 0, r1 = 0;
      if (raySlab(r.o, r.d, mOptions.region->lo, mOptions.region->hi, &r0, &r1)) {
        first = t0 + std::max(0.0, std::floor((r0 - t0) / dt) - 1.0) * dt;
        last = std::min(t1, r1 + dt);
      } else {
        last = first;
      }
    }
    auto owned = [&](double ta) {  // by the lattice index, so that every region decides alike
      return !mOptions.region || mOptions.region->contains(r.o + r.d * (t0 + (std::round((ta - t0) / dt) + 0.5) * dt));
    };
    for (double ta = first; ta < last && r.acc.a < 0.999;) {
      if (!owned(ta)) {
        ta += dt;
        continue;
      }
      if (const double resume = skipTransparent(r, ta); resume > ta) {
        surfaceUntil(r, std::min(resume, t1));
        ++skipped;
        ta = resume;
        continue;
      }
      const double tb = std::min(ta + dt, t1);
      for (double s = ta; s < tb && r.acc.a < 0.999;) {
        const double e = (r.nextHit < mHits.size() && mHits[r.nextHit].t < tb) ? std::max(mHits[r.nextHit].t, s) : tb;
        if (e > s) compositeSegment(r, s, e);
        s = e;
        surfaceUntil(r, s);
      }
      ta = tb;
    }
  }

  // Where the segments inside the transparent node holding the segment starting at @p ta end (the
  // one the ray leaves the node in is sampled: its middle, or its end pre-integrated, may lie beyond
  // the node); @p ta itself when no transparent node holds it.
  double skipTransparent(const Ray& r, double ta) const {
    glm::dvec3 lo, hi;
    if (!mF.transparentBoxAt((r.o + r.d * ta) / mF.spacing, &lo, &hi)) return ta;
    double e0, e1;
    raySlab(r.o, r.d, lo, hi, &e0, &e1);
    return r.t0 + std::floor((std::max(e1, ta) - r.t0) / mF.dt + 1e-9) * mF.dt;
  }

  // Composites the volume's segment [s, e] of the ray: sampled at its middle, or pre-integrated
  // between its two ends' values.
  void compositeSegment(Ray& r, double s, double e) {
    const double tm = 0.5 * (s + e);
    const glm::dvec3 q = (r.o + r.d * tm) / mF.spacing;
    auto shadeAt = [&] {
      if (!mOptions.shading) return 1.0;
      const glm::dvec3 g(gradientAt(glm::vec3(q)));
      const double len = glm::length(g);
      return len > 1e-6 ? headlight(g / len, r.d) : 1.0;
    };
    if (const PreIntegrationTable* pre = mOptions.preintegrated) {
      // The front value is the last segment's back one when they meet.
      const bool meets = s == r.backT;
      const float front = meets ? r.backValue : sampleAt(glm::vec3((r.o + r.d * s) / mF.spacing));
      r.backValue = sampleAt(glm::vec3((r.o + r.d * e) / mF.spacing));
      r.backT = e;
      samples += meets ? 1 : 2;
      const glm::vec4 c = pre->lookup(front, r.backValue, e - s, mOptions.voi ? mOptions.voi->factor(r.o + r.d * tm) : 1.0);
      const glm::vec4 data = c.a > 0.0f ? glm::vec4(glm::vec3(c) * float(shadeAt()), c.a) : glm::vec4(0.0f);
      if (mOptions.geometry) return compositePremultiplied(r, withGeometry(q, r.d, e - s, data));
      if (c.a > 0.0f) r.acc += glm::dvec4(glm::dvec3(c) * shadeAt(), c.a) * (1.0 - r.acc.a);
    } else {
      glm::vec4 c = mF.tf.lookup(sampleAt(glm::vec3(q)));
      if (mOptions.voi) c.a = float(std::min(1.0, double(c.a) * mOptions.voi->factor(r.o + r.d * tm)));
      ++samples;
      const float a = TransferFunction::segmentAlpha(c.a, float(e - s));
      if (mOptions.geometry) {
        const glm::vec4 data = a > 0.0f ? glm::vec4(glm::vec3(c) * float(shadeAt()) * a, a) : glm::vec4(0.0f);
        return compositePremultiplied(r, withGeometry(q, r.d, e - s, data));
      }
      if (a > 0.0f) composite(r, glm::dvec3(c) * shadeAt(), a);
    }
  }

  // The sample @p data (premultiplied) at voxel-space point @p q of a segment @p len mm long of a ray
  // along @p dir with the geometry channel's parts composited over it (compositeGeometry).
  glm::vec4 withGeometry(const glm::dvec3& q, const glm::dvec3& dir, double len, const glm::vec4& data) {
    const GeometryChannel& g = *mOptions.geometry;
    mGeometry.resize(g.parts.size());
    for (size_t k = 0; k < g.parts.size(); ++k) mGeometry[k] = g.parts[k].at(glm::vec3(q));
    return compositeGeometry(g, mGeometry.data(), glm::vec3(dir), len, data);
  }

  static void compositePremultiplied(Ray& r, const glm::vec4& c) {
    if (c.a > 0.0f) r.acc += glm::dvec4(c) * (1.0 - r.acc.a);
  }

  const RayFrame& mF;
  const RaycastOptions& mOptions;
  std::vector<Hit> mHits;  // the ray's surface crossings, in order
  std::vector<Hit> mMeshHits;
  std::vector<glm::vec4> mGeometry;  // the geometry parts' coverage and normal at a sample
  std::optional<KnotSampler> mPaged;
};

// Traces pixels pixel(0) … pixel(count − 1) into @p out on all cores, chunk pixels at a time.
template <class Pixel>
void tracePixels(const RayFrame& f, size_t count, size_t chunk, const Pixel& pixel, Image* out, int firstRow = 0) {
  uint64_t samples = 0, skipped = 0, crossings = 0;
  ParallelFailure failure;  // a progress callback that stops the frame
#pragma omp parallel reduction(+ : samples, skipped, crossings)
  {
    PixelTracer tracer(f);
#pragma omp for schedule(dynamic, chunk)
    for (size_t i = 0; i < count; ++i) {
      // One iteration a pixel; what it throws (a progress callback that stops, a block that cannot
      // be read) ends the frame.
      failure.run([&] {
        f.progress->advance();
        const glm::ivec2 px = pixel(i);
        out->at(px.x, px.y - firstRow) = tracer.trace(px.x, px.y);
      });
    }
    samples += tracer.samples;
    skipped += tracer.skipped;
    crossings += tracer.crossings;
  }
  failure.rethrow();
  f.stats->samples += samples;
  f.stats->skippedLeaves += skipped;
  f.stats->surfaceHits += crossings;
  f.stats->rays += count;
}

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
  Image image(camera.width, rows.y - rows.x);  // (a band's rows only: a 2048² frame's whole image is 64 MB)
  ProgressTask progress(options.progress, "ray tracing", uint64_t(camera.width) * uint64_t(rows.y - rows.x));
  const RayFrame f({volume, octree, tf}, camera, options, &counts, &progress);
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
    tracePixels(f, order.size(), kSquare * kSquare, [&order](size_t i) { return order[i]; }, &image, rows.x);
  }
  if (stats) *stats = counts;
  return image;
}

}  // namespace hyb
