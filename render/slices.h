// The hybrid slice renderer (Boada and Navazo 2002, §4; DESIGN 3.4–3.5) on OpenGL 4.5 core through
// OSMesa: one 3D texture per selected brick at its level p, view-aligned slices cut on the CPU from
// globally aligned planes, bricks drawn back to front in octree order (valid for perspective and
// orthographic views), composited in a float framebuffer with premultiplied colours.
//
// This first version renders the volume and opaque surfaces (depth-tested, drawn first); the
// SlabPolygon integration of translucent surfaces is not implemented yet.
#pragma once

#include "hybrid_octree/selection.h"
#include "hybrid_octree/volume_octree.h"
#include "render/camera.h"
#include "render/gl_context.h"
#include "render/image.h"
#include "render/transfer_function.h"
#include "surface/mesh.h"
#include "volume/volume.h"

namespace hyb {

/// Options of the slice renderer.
struct SlicesOptions {
  double stepVoxels = 0.5;              ///< slice spacing along the view direction, in smallest voxel spacings
  bool shading = true;                  ///< gradient (headlight) shading of the volume
  const TriangleMesh* surface = nullptr;  ///< opaque isosurface triangles in world mm, or none
  glm::vec3 surfaceColor{1.0f};
};

/// What a frame used.
struct SlicesStats {
  size_t bricks = 0;
  uint64_t texels = 0;
  uint64_t textureBytes = 0;
  uint64_t slices = 0;            ///< slice polygons drawn
};

/// Renders the bricks of @p selection. Requires a current GlContext.
/// @throw RuntimeError when OpenGL fails (shader compilation, framebuffer).
Image renderSlices(const Volume& volume, const VolumeOctree& octree, const Selection& selection, const TransferFunction& tf,
                   const Camera& camera, const SlicesOptions& options, SlicesStats* stats = nullptr);

}  // namespace hyb
