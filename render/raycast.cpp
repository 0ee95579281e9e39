// Reference hybrid ray tracer: M. Levoy, "A Hybrid Ray Tracer for Rendering Polygon and Volume
// Data", IEEE CG&A 10(2), 1990; empty-space skipping and early termination after Levoy 1990,
// "Efficient Ray Tracing of Volume Data".
#include "render/raycast.h"

#include <algorithm>
#include <cmath>

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

}  // namespace

Image raycast(const Volume& volume, const VolumeOctree& octree, const TransferFunction& tf, const Camera& camera,
              const RaycastOptions& options, RaycastStats* stats) {
  Image image(camera.width, camera.height);
  const glm::dvec3 spacing = volume.spacing();
  const glm::dvec3 boxHi = volume.extentMm();
  const double dt = options.stepVoxels * std::min({spacing.x, spacing.y, spacing.z});
  const glm::ivec3 cells = glm::max(volume.dims() - 1, glm::ivec3(1));

  // Nodes whose value range the transfer function maps to zero opacity.
  const auto& nodes = octree.nodes();
  std::vector<uint8_t> transparent(nodes.size());
  for (size_t i = 0; i < nodes.size(); ++i)
    transparent[i] = options.skipEmptySpace && tf.maxAlpha(nodes[i].minValue, nodes[i].maxValue) <= 0.0f;

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
#pragma omp parallel for schedule(dynamic, 1) reduction(+ : samples, skipped, crossings)
  for (int y = 0; y < camera.height; ++y) {
    std::vector<Hit> hits;
    for (int x = 0; x < camera.width; ++x) {
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
          if (inBox && keepLo >= t0 - slack && keepLo <= t1 + slack) {
            const glm::vec4 c = tf.lookup(volume.sample(glm::vec3((o + d * keepLo) / spacing)));
            if (c.a > 0.0f) {
              image.at(x, y) = glm::vec4(glm::vec3(c), 1.0f);
              continue;
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
      auto surfaceUntil = [&](double t) {  // composite surface crossings before distance t
        while (nextHit < hits.size() && hits[nextHit].t <= t && acc.a < 0.999) {
          const glm::vec4 c = options.surfaceColor;
          composite(glm::dvec3(c) * headlight(hits[nextHit].normal, d), c.a);
          ++nextHit;
          ++crossings;
        }
      };
      if (inBox && options.volume && t1 > t0) {
        // Volume segments of length dt from t0, split at surface crossings.
        for (double ta = t0; ta < t1 && acc.a < 0.999;) {
          glm::dvec3 lo, hi;
          const glm::dvec3 p = o + d * ta;
          if (transparentBoxAt(p / spacing, &lo, &hi)) {
            double e0, e1;
            slab(o, d, lo, hi, &e0, &e1);
            const double resume = t0 + std::ceil((std::max(e1, ta) - t0) / dt + 1e-9) * dt;
            surfaceUntil(std::min(resume, t1));
            ++skipped;
            ta = resume;
            continue;
          }
          double tb = std::min(ta + dt, t1);
          for (double s = ta; s < tb && acc.a < 0.999;) {
            const double e = (nextHit < hits.size() && hits[nextHit].t < tb) ? std::max(hits[nextHit].t, s) : tb;
            if (e > s) {
              const double tm = 0.5 * (s + e);
              const glm::dvec3 q = (o + d * tm) / spacing;
              glm::vec4 c = tf.lookup(volume.sample(glm::vec3(q)));
              if (options.voi) c.a = float(std::min(1.0, double(c.a) * options.voi->factor(o + d * tm)));
              ++samples;
              const float a = TransferFunction::segmentAlpha(c.a, float(e - s));
              if (a > 0.0f) {
                double shade = 1.0;
                if (options.shading) {
                  const glm::dvec3 g(volume.sampleGradient(glm::vec3(q)));
                  const double len = glm::length(g);
                  if (len > 1e-6) shade = headlight(g / len, d);
                }
                composite(glm::dvec3(c) * shade, a);
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
    }
  }
  if (stats) *stats = RaycastStats{samples, skipped, crossings};
  return image;
}

}  // namespace hyb
