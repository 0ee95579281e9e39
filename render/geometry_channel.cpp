#include "render/geometry_channel.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <numbers>
#include <type_traits>

#include "volume/core/error.h"

namespace hyb {

namespace {

// The coverage of @p r (Float32) at voxel n.
float fraction(const ScanResult& r, size_t n) { return r.coverage.value(n); }

// A unit normal as the texel's three bytes, 128 + 127·n.
glm::u8vec3 encodeNormal(const glm::vec3& n) {
  return glm::u8vec3(glm::clamp(glm::round(128.0f + 127.0f * n), glm::vec3(1.0f), glm::vec3(255.0f)));
}

// A full grid of fractions, @p value(n) at voxel n (x fastest), cropped to its non-zero voxels with
// a voxel of zeros around them, as texels without normals.
template <class Value>
GeometryPart cropped(const glm::ivec3& dims, const Value& value) {
  GeometryPart part;
  glm::ivec3 lo(dims), hi(-1);
  for (int k = 0; k < dims.z; ++k)
    for (int j = 0; j < dims.y; ++j) {
      const size_t row = size_t(dims.x) * (size_t(j) + size_t(dims.y) * size_t(k));
      for (int i = 0; i < dims.x; ++i)
        if (value(row + size_t(i)) * 255.0f >= 0.5f) {  // what rounds to a byte above 0
          lo = glm::min(lo, glm::ivec3(i, j, k));
          hi = glm::max(hi, glm::ivec3(i, j, k));
        }
    }
  if (hi.x < 0) return part;
  lo = glm::max(lo - 1, glm::ivec3(0));
  hi = glm::min(hi + 1, dims - 1);
  part.lo = lo;
  part.dims = hi - lo + 1;
  part.texels.resize(size_t(part.dims.x) * size_t(part.dims.y) * size_t(part.dims.z));
  size_t out = 0;
  for (int k = lo.z; k <= hi.z; ++k)
    for (int j = lo.y; j <= hi.y; ++j)
      for (int i = lo.x; i <= hi.x; ++i) {
        const float v = value(size_t(i) + size_t(dims.x) * (size_t(j) + size_t(dims.y) * size_t(k)));
        part.texels[out++] = glm::u8vec4(uint8_t(std::lround(std::clamp(v, 0.0f, 1.0f) * 255.0f)), 128, 128, 128);
      }
  return part;
}

// Sets the normal of every voxel of @p part's crop to @p normal(grid mm) (an analytic primitive's).
template <class Normal>
void setNormals(GeometryPart* part, const glm::dvec3& spacing, const Normal& normal) {
  size_t n = 0;
  for (int k = 0; k < part->dims.z; ++k)
    for (int j = 0; j < part->dims.y; ++j)
      for (int i = 0; i < part->dims.x; ++i, ++n) {
        const glm::u8vec3 code = encodeNormal(glm::vec3(normal(glm::dvec3(part->lo + glm::ivec3(i, j, k)) * spacing)));
        part->texels[n] = glm::u8vec4(part->texels[n].x, code);
      }
}

// Sets the normals of @p part's voxels that @p normals (a mesh's band, grid voxel indices) holds.
void setBandNormals(GeometryPart* part, const glm::ivec3& dims, std::span<const VoxelNormal> normals) {
  const size_t plane = size_t(dims.x) * size_t(dims.y);
  for (const VoxelNormal& v : normals) {
    const glm::ivec3 q = glm::ivec3(int(v.voxel % size_t(dims.x)), int((v.voxel / size_t(dims.x)) % size_t(dims.y)), int(v.voxel / plane)) - part->lo;
    if (glm::any(glm::lessThan(q, glm::ivec3(0))) || glm::any(glm::greaterThanEqual(q, part->dims))) continue;
    glm::u8vec4& t = part->texels[size_t(q.x) + size_t(part->dims.x) * (size_t(q.y) + size_t(part->dims.y) * size_t(q.z))];
    t = glm::u8vec4(t.x, encodeNormal(v.normal));
  }
}

// @p r's coverage (UInt8 or Float32) cropped.
GeometryPart cropped(const ScanResult& r) {
  return r.coverage.visitSamples([&](const auto* d) {
    const float scale = std::is_same_v<std::remove_cv_t<std::remove_pointer_t<decltype(d)>>, float> ? 1.0f : 1.0f / 255.0f;
    return cropped(r.coverage.dims(), [&](size_t n) { return float(d[n]) * scale; });
  });
}

// The largest coverage of @p parts over node @p i's voxel box, its descendants' first.
float nodeMaximum(const VolumeOctree& octree, const std::vector<GeometryPart>& parts, uint32_t i, std::vector<float>* out) {
  const OctreeNode& n = octree.nodes()[i];
  float m = 0.0f;
  if (n.isLeaf()) {
    glm::ivec3 a, b;
    octree.voxelBox(n, &a, &b);
    for (const GeometryPart& p : parts) {
      if (p.texels.empty()) continue;
      const glm::ivec3 lo = glm::max(a, p.lo), hi = glm::min(b, p.lo + p.dims - 1);
      for (int k = lo.z; k <= hi.z; ++k)
        for (int j = lo.y; j <= hi.y; ++j)
          for (int x = lo.x; x <= hi.x; ++x) {
            const glm::ivec3 q = glm::ivec3(x, j, k) - p.lo;
            m = std::max(m, float(p.texels[size_t(q.x) + size_t(p.dims.x) * (size_t(q.y) + size_t(p.dims.y) * size_t(q.z))].x) / 255.0f);
          }
    }
  } else {
    for (int slot = 0; slot < 8; ++slot)
      if (n.childMask & (1u << slot)) m = std::max(m, nodeMaximum(octree, parts, childIndex(n, slot), out));
  }
  (*out)[i] = m;
  return m;
}

}  // namespace

glm::vec4 GeometryPart::at(const glm::vec3& q) const {
  if (texels.empty()) return glm::vec4(0.0f);
  const glm::vec3 p = q - glm::vec3(lo);
  const glm::ivec3 i0(glm::floor(p));
  const glm::vec3 t = p - glm::vec3(i0);
  auto fetch = [&](int x, int y, int z) {
    if (x < 0 || y < 0 || z < 0 || x >= dims.x || y >= dims.y || z >= dims.z) return glm::vec4(0.0f, 128.0f, 128.0f, 128.0f);  // the border
    return glm::vec4(texels[size_t(x) + size_t(dims.x) * (size_t(y) + size_t(dims.y) * size_t(z))]);
  };
  auto lerp = [](const glm::vec4& a, const glm::vec4& b, float w) { return a + (b - a) * w; };
  const glm::vec4 c00 = lerp(fetch(i0.x, i0.y, i0.z), fetch(i0.x + 1, i0.y, i0.z), t.x);
  const glm::vec4 c10 = lerp(fetch(i0.x, i0.y + 1, i0.z), fetch(i0.x + 1, i0.y + 1, i0.z), t.x);
  const glm::vec4 c01 = lerp(fetch(i0.x, i0.y, i0.z + 1), fetch(i0.x + 1, i0.y, i0.z + 1), t.x);
  const glm::vec4 c11 = lerp(fetch(i0.x, i0.y + 1, i0.z + 1), fetch(i0.x + 1, i0.y + 1, i0.z + 1), t.x);
  const glm::vec4 v = lerp(lerp(c00, c10, t.y), lerp(c01, c11, t.y), t.z);
  return glm::vec4(v.x / 255.0f, (glm::vec3(v.y, v.z, v.w) - 128.0f) / 127.0f);
}

uint64_t GeometryChannel::bytes() const {
  uint64_t b = nodeMax.size() * sizeof(float);
  for (const GeometryPart& p : parts) b += p.texels.size() * sizeof(glm::u8vec4);
  return b;
}

GeometryChannel scanConvertGeometry(const std::vector<UserMesh>& meshes, const Volume& volume, const VolumeOctree& octree, double meshFilter) {
  const auto t0 = std::chrono::steady_clock::now();
  GeometryChannel g;
  const VoxelGrid grid = VoxelGrid::of(volume);
  const double voxel = std::min({grid.spacing.x, grid.spacing.y, grid.spacing.z});
  ScanOptions o;
  o.space = ScanSpace::Patient;
  o.filter = meshFilter > 0.0 ? ScanFilter::Box : ScanFilter::None;
  o.width = meshFilter > 0.0 ? meshFilter : 1.0;  // (unused when point-sampled)
  o.normals = true;
  for (const UserMesh& m : meshes) {
    double tau = voxel;
    const UserPrimitive* p = m.primitive.get();
    ScanResult r;
    GeometryPart part;
    // Bytes, as the crop keeps them; a sphere's shell, a difference of two balls, in floats.
    o.type = p && p->kind == UserPrimitive::Kind::Sphere ? CoverageType::Float32 : CoverageType::UInt8;
    if (p && p->kind == UserPrimitive::Kind::Plane) {
      tau = p->thickness > 0.0 ? p->thickness : voxel;
      o.thickness = tau;
      r = scanConvertPlane(p->points.front(), p->normal, grid, o);
      part = cropped(r);
    } else if (p && p->kind == UserPrimitive::Kind::Sphere) {
      // The sphere's surface as a shell: the ball of R + τ/2 less the ball of R − τ/2.
      o.thickness = 0.0;
      r = scanConvertSphere(p->points.front(), p->radius + 0.5 * tau, grid, o);
      if (p->radius > 0.5 * tau) {
        const ScanResult inner = scanConvertSphere(p->points.front(), p->radius - 0.5 * tau, grid, o);
        part = cropped(grid.dims, [&](size_t n) { return std::max(0.0f, fraction(r, n) - fraction(inner, n)); });
      } else {
        part = cropped(r);
      }
    } else if (p && p->kind == UserPrimitive::Kind::Polygon) {
      o.thickness = tau;
      r = scanConvertPolygon(p->points, grid, o);
      part = cropped(r);
    } else {
      o.thickness = tau;
      r = scanConvertMesh(*m.mesh, grid, o);
      part = cropped(r);
    }
    for (const std::string& w : r.warnings) g.warnings.push_back(m.name + ": " + w);
    if (!part.texels.empty()) {
      // The normals: the plane's, the sphere's radial direction, or the closest triangle's.
      if (p && p->kind == UserPrimitive::Kind::Plane) {
        const glm::dvec3 n = glm::normalize(grid.frame.vectorToGrid(p->normal));
        setNormals(&part, grid.spacing, [&](const glm::dvec3&) { return n; });
      } else if (p && p->kind == UserPrimitive::Kind::Sphere) {
        const glm::dvec3 c = grid.frame.toGrid(p->points.front());
        setNormals(&part, grid.spacing, [&](const glm::dvec3& x) {
          const double rho = glm::length(x - c);
          return rho > 0.0 ? (x - c) / rho : glm::dvec3(0.0);
        });
      } else {
        setBandNormals(&part, grid.dims, r.normals);
      }
    }
    part.color = m.color;
    part.thicknessMm = tau;
    g.parts.push_back(std::move(part));
  }
  g.nodeMax.assign(octree.nodes().size(), 0.0f);
  if (!octree.nodes().empty()) nodeMaximum(octree, g.parts, 0, &g.nodeMax);
  g.ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return g;
}

Volume geometryVolume(const std::vector<UserMesh>& meshes, const Volume& volume, bool asFraction, std::vector<std::string>* warnings) {
  const VoxelGrid grid = VoxelGrid::of(volume);
  const double voxel = std::min({grid.spacing.x, grid.spacing.y, grid.spacing.z});
  ScanOptions o;  // the bytes the renderers' channel is made of: no float grid per mesh
  o.extentWarnings = false;  // userMeshWarnings told them as the meshes were read
  // The union: each voxel's largest coverage (fraction · 255) over the meshes.
  std::vector<uint8_t> most(size_t(grid.dims.x) * size_t(grid.dims.y) * size_t(grid.dims.z), 0);
  for (const UserMesh& m : meshes) {
    const UserPrimitive* p = m.primitive.get();
    ScanResult r;
    o.thickness = p && p->kind == UserPrimitive::Kind::Plane && p->thickness > 0.0 ? p->thickness : voxel;
    if (p && p->kind == UserPrimitive::Kind::Plane) {
      r = scanConvertPlane(p->points.front(), p->normal, grid, o);
    } else if (p && p->kind == UserPrimitive::Kind::Polygon) {
      r = scanConvertPolygon(p->points, grid, o);
    } else if (p && p->kind == UserPrimitive::Kind::Sphere) {
      o.thickness = 0.0;
      r = scanConvertSphere(p->points.front(), p->radius, grid, o);
    } else {
      o.thickness = 0.0;
      r = scanConvertMesh(*m.mesh, grid, o);
    }
    for (const std::string& w : r.warnings) warnings->push_back(m.name + ": " + w);
    HYB_CHECK(r.coverage.storedType() == ScalarType::UInt8 && r.coverage.voxelCount() == most.size());
    r.coverage.visitSamples([&](const auto* c) {
      for (size_t n = 0; n < most.size(); ++n) most[n] = std::max<uint8_t>(most[n], uint8_t(c[n]));
    });
  }
  Volume out;
  if (asFraction) {
    // The fraction in steps of 1/255 (Slicer's 6 × 6 × 6 supersampled fractional labelmap has 1/216).
    std::vector<float> fraction(most.size());
    for (size_t n = 0; n < most.size(); ++n) fraction[n] = float(most[n]) / 255.0f;
    out = Volume(grid.dims, grid.spacing, ScalarType::Float32, std::move(fraction), "coverage fraction");
  } else {
    for (uint8_t& v : most) v = v >= 128 ? 1 : 0;  // at least half covered (a fraction f is stored as f · 255 rounded)
    out = Volume(grid.dims, grid.spacing, ScalarType::UInt8, SampleArray(std::move(most)), "coverage label");
  }
  out.setFrame(grid.frame);
  return out;
}

glm::vec4 compositeGeometry(const GeometryChannel& g, const glm::vec4* samples, const glm::vec3& dir, double lenMm, const glm::vec4& data) {
  glm::vec4 over(0.0f);  // the parts so far, premultiplied, each over those after it
  for (size_t k = 0; k < g.parts.size(); ++k) {
    const float c = samples[k].x;
    if (!(c > 0.0f)) continue;
    const GeometryPart& p = g.parts[k];
    const glm::vec3 n(samples[k].y, samples[k].z, samples[k].w);
    const float nn = glm::dot(n, n);
    // |n·d|: the headlight's, and the path's projection on the normal, which integrates to τ across
    // the sheet at any incidence (1, unshaded, where the part has no normal).
    const float cosine = nn > 1e-12f ? std::abs(glm::dot(n, dir)) / std::sqrt(nn) : 1.0f;
    const float a = 1.0f - std::pow(1.0f - p.color.a, float(double(c) * cosine * lenMm / p.thicknessMm));
    over += glm::vec4(glm::vec3(p.color) * ((0.25f + 0.75f * cosine) * a), a) * (1.0f - over.a);
  }
  return over + data * (1.0f - over.a);
}

TriangleMesh tessellatePrimitive(const UserPrimitive& p, const Volume& volume) {
  TriangleMesh mesh;
  const PatientFrame& frame = volume.frame();
  const glm::dvec3 extent = volume.extentMm();
  const double voxel = std::min({volume.spacing().x, volume.spacing().y, volume.spacing().z});
  switch (p.kind) {
    case UserPrimitive::Kind::Sphere: {
      const int f = std::clamp(int(std::ceil(1.05 * p.radius / voxel)), 1, 64);
      return geodesicSphere(p.points.front(), p.radius, f);
    }
    case UserPrimitive::Kind::Polygon:
      for (size_t i = 0; i < p.points.size(); ++i) {
        mesh.vertices.emplace_back(p.points[i]);
        if (i >= 2) mesh.triangles.emplace_back(0u, uint32_t(i - 1), uint32_t(i));
      }
      return mesh;
    case UserPrimitive::Kind::Plane: {
      // The plane cut to the volume's box (grid frame), its corners ordered about their centre.
      const glm::dvec3 q = frame.toGrid(p.points.front());
      glm::dvec3 n = frame.toGrid(p.points.front() + p.normal) - q;
      n = glm::normalize(n);
      std::vector<glm::dvec3> corners;
      for (int axis = 0; axis < 3; ++axis)
        for (int c = 0; c < 4; ++c) {  // the four box edges along axis
          const int u = (axis + 1) % 3, v = (axis + 2) % 3;
          glm::dvec3 a(0.0);
          a[u] = (c & 1) ? extent[u] : 0.0;
          a[v] = (c & 2) ? extent[v] : 0.0;
          if (std::abs(n[axis]) < 1e-12) continue;
          const double t = glm::dot(n, q - a) / n[axis];
          if (t < 0.0 || t > extent[axis]) continue;
          a[axis] = t;
          corners.push_back(a);
        }
      if (corners.size() < 3) return mesh;
      glm::dvec3 centre(0.0);
      for (const glm::dvec3& c : corners) centre += c / double(corners.size());
      const glm::dvec3 e1 = glm::normalize(std::abs(n.x) < 0.9 ? glm::cross(n, glm::dvec3(1, 0, 0)) : glm::cross(n, glm::dvec3(0, 1, 0)));
      const glm::dvec3 e2 = glm::cross(n, e1);
      std::sort(corners.begin(), corners.end(), [&](const glm::dvec3& a, const glm::dvec3& b) {
        return std::atan2(glm::dot(a - centre, e2), glm::dot(a - centre, e1)) < std::atan2(glm::dot(b - centre, e2), glm::dot(b - centre, e1));
      });
      corners.erase(std::unique(corners.begin(), corners.end(), [](const glm::dvec3& a, const glm::dvec3& b) { return glm::length(a - b) < 1e-9; }),
                    corners.end());
      for (size_t i = 0; i < corners.size(); ++i) {
        mesh.vertices.emplace_back(frame.toPatient(corners[i]));
        if (i >= 2) mesh.triangles.emplace_back(0u, uint32_t(i - 1), uint32_t(i));
      }
      return mesh;
    }
  }
  return mesh;
}

}  // namespace hyb
