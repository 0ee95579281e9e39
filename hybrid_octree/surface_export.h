// A scene's isosurface as a mesh file holds it: the one path of `export`, the viewer's download and
// Python's Scene.surface/export.
#pragma once

#include <iosfwd>
#include <optional>
#include <string>

#include "hybrid_octree/hybrid_io.h"
#include "surface/mesh.h"

namespace hyb {

/// Which isosurface exportSurface makes.
struct ExportRequest {
  float iso = 0;
  /// dmc (DiscMC), octree (the Surface Octree's, coplanar polygons merged) or mc (classic
  /// Marching Cubes).
  std::string kind = "dmc";
  bool closed = false;   ///< capped on the volume's faces (the volume padded below the isovalue)
  bool normals = false;  ///< vertex normals from the volume's gradient
  /// Classic Marching Cubes' surface beside it (export --check compares them; not made otherwise:
  /// it doubles the extraction's time and memory).
  bool againstMc = false;
};

/// An exported isosurface, in patient coordinates (LPS mm).
struct ExportedSurface {
  TriangleMesh mesh, mc;  ///< mc: when asked againstMc
  size_t polygons = 0;    ///< before triangulation (DiscMC's and the Surface Octree's faces)
  double ms = 0, mcMs = 0;
};

/// The surface kinds as messages list them: "dmc, octree or mc".
inline constexpr const char* kSurfaceKindsText = "dmc, octree or mc";
/// Whether @p kind is one of kSurfaceKindsText's.
bool isSurfaceKind(const std::string& kind);

/// Makes @p request's isosurface of @p scene, printing what it made on @p out ("surface ..." lines,
/// as `export` prints them). A paged scene's Surface Octree surface is read through its cache.
/// @throw ValueError for another kind, or a paged scene asked for a surface that needs its samples.
ExportedSurface exportSurface(const Scene& scene, const ExportRequest& request, const Progress* progress, std::ostream& out);

/// One line on a Surface Octree, with its build time when it was just built (else "from the scene").
std::string surfaceOctreeLine(const SurfaceOctree& so, std::optional<double> buildMs);
/// The same of a streamed build's octree, built in @p buildMs.
std::string surfaceOctreeLine(const SpooledSurfaceOctree& so, double buildMs);

}  // namespace hyb
