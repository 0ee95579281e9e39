#include "hybrid_octree/surface_export.h"

#include <algorithm>
#include <chrono>
#include <iomanip>
#include <ostream>
#include <sstream>

#include "hybrid_octree/surface_octree.h"
#include "surface/dmc.h"
#include "surface/mesh_ops.h"
#include "volume/core/error.h"

namespace hyb {

namespace {

using Clock = std::chrono::steady_clock;
double msSince(Clock::time_point t0) { return std::chrono::duration<double, std::milli>(Clock::now() - t0).count(); }

}  // namespace

bool isSurfaceKind(const std::string& kind) { return kind == "dmc" || kind == "octree" || kind == "mc"; }

namespace {

std::string surfaceOctreeLine(float iso, size_t cells, size_t nodes, uint64_t planeIds, std::optional<double> buildMs) {
  std::ostringstream s;
  s << "surface  iso " << iso << ": " << cells << " DiscMC cells merged into " << nodes << " terminal nodes (" << planeIds << " plane ids, "
    << SurfaceOctree::bytesFor(nodes) << " bytes)";
  if (buildMs) s << ", " << std::fixed << std::setprecision(1) << *buildMs << " ms";
  else s << " (from the scene)";
  return s.str() + "\n";
}

}  // namespace

std::string surfaceOctreeLine(const SurfaceOctree& so, std::optional<double> buildMs) {
  uint64_t planes = 0;
  for (size_t i = 0; i < so.nodeCount(); ++i) planes += so.node(i).planeCount;
  so.releasePages();
  return surfaceOctreeLine(so.isovalue(), so.cellCount(), so.nodeCount(), planes, buildMs);
}

std::string surfaceOctreeLine(const SpooledSurfaceOctree& so, double buildMs) {
  return surfaceOctreeLine(so.isovalue(), so.cellCount(), so.nodeCount(), so.planeIds(), buildMs);
}

ExportedSurface exportSurface(const Scene& scene, const ExportRequest& request, const Progress* progress, std::ostream& out) {
  const float iso = request.iso;
  const std::string& kind = request.kind;
  const bool closed = request.closed, againstMc = request.againstMc;
  if (!isSurfaceKind(kind)) HYB_THROW(ValueError, "surface kind '", kind, "' invalid (expected ", kSurfaceKindsText, ")");
  if (!scene.volume.hasSamples() && (kind != "octree" || closed || againstMc))
    HYB_THROW(ValueError, "the ", kind, closed ? " closed" : "", " surface of a scene read paged needs its samples (load it whole)");
  // Closed: the volume padded by one sample well below the isovalue on every face, so the surface
  // is capped where it meets them (half a voxel outside the data, DiscMC's midpoints).
  std::optional<Volume> padded;
  std::optional<VolumeOctree> paddedOctree;
  if (closed) {
    const Volume& v = scene.volume;
    padded = paddedVolume(v, std::min(v.minValue(), iso) - std::max(1.0f, v.maxValue() - v.minValue()));
    paddedOctree = VolumeOctree::build(*padded, VolumeOctreeOptions{8, true, progress});
  }
  const Volume& v = closed ? *padded : scene.volume;
  const VolumeOctree& octree = closed ? *paddedOctree : scene.octree;
  // The Surface Octree's own surface finds its cells itself.
  const std::vector<VoxelBlock> blocks = kind != "octree" || againstMc ? isoBlocks(octree, iso) : std::vector<VoxelBlock>{};
  ExportedSurface e;
  auto t0 = Clock::now();
  if (kind == "mc" || againstMc) {
    e.mc = extractMarchingCubes(v, iso, blocks);
    scaleToMillimetres(&e.mc, v.spacing());
    e.mcMs = msSince(t0);
  }
  t0 = Clock::now();
  if (kind == "mc") {
    if (againstMc) {
      e.mesh = e.mc;
    } else {
      e.mesh = std::move(e.mc);
      e.mc = TriangleMesh{};
    }
    e.polygons = e.mesh.triangles.size();
  } else if (kind == "dmc") {
    const DiscreteMesh d = extractDiscMC(v, iso, blocks);
    e.polygons = d.faceCount();
    e.mesh = toTriangleMesh(d, v.spacing());
  } else {
    const bool stored = !closed && scene.surface && scene.surface->isovalue() == iso;
    const auto ts = Clock::now();
    // A paged scene's is extracted through its cache, a leaf at a time.
    const SurfaceOctree so = closed ? SurfaceOctree::build(v, octree, iso) : sceneSurface(scene, iso, progress);
    out << surfaceOctreeLine(so, stored ? std::nullopt : std::optional<double>(msSince(ts)));
    const DiscreteMesh d = so.reconstruct(kMaxDim, progress);  // one mesh: merge coplanar polygons across bricks too
    e.polygons = d.faceCount();
    e.mesh = fineMeshToTriangles(d, v.spacing());
  }
  if (request.normals) {
    if (closed)
      setGradientNormals(v, &e.mesh);
    else
      setSceneNormals(scene, &e.mesh);  // a paged scene's through its cache, the same normals
  }
  // Patient coordinates (LPS mm), as the volume's own.
  toPatientSpace(v.frame(), &e.mesh);
  toPatientSpace(v.frame(), &e.mc);
  e.ms = kind == "mc" ? e.mcMs : msSince(t0);
  out << std::fixed << std::setprecision(1) << "surface  " << kind << " at iso " << iso << (closed ? " (closed)" : "") << ": " << e.polygons
      << " polygons, " << e.mesh.triangles.size() << " triangles, " << e.mesh.vertices.size() << " vertices, " << e.ms << " ms\n";
  if (againstMc)
    out << "vs mc    " << e.mc.triangles.size() << " triangles in " << e.mcMs << " ms; triangles ratio " << std::setprecision(3)
        << (e.mc.triangles.empty() ? 1.0 : double(e.mesh.triangles.size()) / double(e.mc.triangles.size())) << "\n";
  return e;
}

}  // namespace hyb
