// The hybrid slice renderer (Boada and Navazo 2002, §4; docs/renderer.md) on OpenGL 4.5 core through
// OSMesa: one 3D texture per selected brick at its level p, view-aligned slices cut on the CPU from
// globally aligned planes, bricks drawn back to front in octree order (valid for perspective and
// orthographic views), composited in a float framebuffer with premultiplied colours.
//
// Opaque surfaces are drawn first with depth writes. Translucent surface triangles go through the
// SlabPolygon lists: each is put into the slabs between global slice planes that its depth range
// covers (drawn once in each, keeping that slab's fragments, where it spans several), sorted back
// to front inside a slab, and drawn between the slices of its brick; the lists are rebuilt for
// every view. Triangles that cover no pixel centre are left out.
#pragma once

#include <cstdint>
#include <optional>

#include "hybrid_octree/selection.h"
#include "hybrid_octree/volume_octree.h"
#include "render/camera.h"
#include "render/cut_plane.h"
#include "render/frame_request.h"
#include "render/geometry_channel.h"
#include "render/voi.h"
#include "render/gl_context.h"
#include "render/image.h"
#include "render/preintegration.h"
#include "render/regions.h"
#include "render/slices/brick_textures.h"
#include "render/slices/slab_polygons.h"
#include "render/transfer_function.h"
#include "render/user_meshes.h"
#include "surface/mesh.h"
#include "volume/core/progress.h"
#include "volume/volume.h"

namespace hyb {

/// Options of the slice renderer.
struct SlicesOptions {
  double stepVoxels = 0.5;              ///< slice spacing along the view direction, in smallest voxel spacings
  bool shading = true;                  ///< gradient (headlight) shading of the volume
  Proxy proxy = Proxy::Planes;
  /// Isosurface triangles in world mm, or none. Translucent triangles are placed in the brick that
  /// holds their centroid, so each must lie inside one brick (Surface Octree polygons lie inside one
  /// volume leaf, hence one brick).
  const TriangleMesh* surface = nullptr;
  glm::vec4 surfaceColor{1.0f};           ///< straight RGBA; a < 1 is translucent (per crossing)
  /// User meshes (their pieces, each in one leaf cell, hence one brick), or none: drawn in the
  /// SlabPolygon lists beside the translucent isosurface, each piece with its mesh's colour,
  /// translucent or opaque alike.
  const GridMeshes* meshes = nullptr;
  /// The user geometry scan-converted onto the volume's grid (render/geometry_channel.h), or none:
  /// each part's coverage a texture (made once, kept by the channel) composited with each slice
  /// sample by the reference's rule; bricks holding it are sliced whole at the base spacing.
  const GeometryChannel* geometry = nullptr;
  const CutPlane* cut = nullptr;          ///< cutting plane, or none
  const VolumeOfInterest* voi = nullptr;  ///< opacity scaling box, or none
  bool cutLine = true;                    ///< draw the surface's intersection with the cutting plane
  BrickTextureCache* textures = nullptr;  ///< brick textures reused across frames (none: uploaded per frame)
  gl::TargetCache* targets = nullptr;     ///< render targets reused across frames (none: the frame's own)
  /// Where bricks read their knots (a scene's paged store), or none: the volume and octree in
  /// memory. Both give bit-identical bricks.
  const KnotSource* knots = nullptr;
  TexelBits texelBits = TexelBits::Eight;
  /// Pre-integrated classification: each fragment's segment, cut to its brick's box, reads this
  /// table at the values of its two ends (two brick reads instead of one; shading by their
  /// gradients' mean); none: post-classified at the slice. Its layers should cover the frame's
  /// segments (half the base spacing to 128 times it); longer and shorter ones read the end layers.
  const PreIntegrationTable* preintegrated = nullptr;
  bool visibleBoxes = true;             ///< slice only the box of each brick's cells that the transfer
                                        ///< function can make visible (false: the whole brick; same image)
  bool slabOrder = true;                  ///< false: draw each brick's surface after its slices (a
                                          ///< deliberately wrong order, to show the tests catch it)
  /// Draw each translucent polygon in every slab its depth range covers, each slab keeping its part
  /// (exact order); false puts it whole in the slab of its centroid's depth, misplacing what lies
  /// in the neighbouring slabs (the viewer's frames before the final one: llvmpipe's cost of the
  /// instances, not the misplacement, is what shows; docs/viewer.md).
  bool cutToSlabs = true;
  /// Leave out the surface triangles that cover no pixel centre, and draw those whose covered
  /// centres lie in one slab there alone (PixelCentres; the image is the same either way).
  bool leaveOutUnseen = true;
  const Progress* progress = nullptr;     ///< hears of the bricks drawn ("slices"); may throw to stop the frame
  /// Renders only the image rows [rows.x, rows.y) (from the top), with exactly the pixels a whole
  /// frame has there: a scissor, and bricks whose projection misses the band skipped; the image is
  /// those rows only. A large frame drawn band by
  /// band lets other work run between its bands.
  std::optional<glm::ivec2> rows;
  /// A region of a sort-last frame (render/regions.h), or none: only the bricks inside it are
  /// drawn (the surface given should be cut to it, cutMeshToRegion); the slices stay on the whole
  /// frame's planes, so the regions' images composited front to back make the whole frame's image.
  const RegionBox* region = nullptr;
  /// Bricks packed at once (on all cores), a batch ahead of their draws: a frame holds at most two
  /// batches' packed texels (SlicesStats::peakPackedBricks), whatever its brick count. The image
  /// does not depend on it.
  size_t packBatch = 256;
};

/// The options a frame's look and quality ask of the slice renderer, @p surface the triangles it
/// draws (or none), @p meshes the user meshes (or none) and @p grid the frame in the grid frame,
/// which must outlive them. What an
/// engine keeps across frames (SlicesOptions::textures, knots, preintegrated) and the progress are
/// its own to set.
SlicesOptions slicesOptions(const FrameGrid& grid, const Look& look, const Quality& quality, const TriangleMesh* surface,
                            const GridMeshes* meshes = nullptr);

/// The pixel centres a slice frame of @p camera over @p volume tests its surface's triangles
/// against (SlicesOptions::leaveOutUnseen): a triangle PixelCentres::cover knows to cover none of
/// them is left out of the frame.
PixelCentres framePixelCentres(const Volume& volume, const Camera& camera);

/// What a frame used.
struct SlicesStats {
  size_t bricks = 0;               ///< textured bricks
  size_t uploadedBricks = 0;       ///< of which packed and uploaded by this frame (the others were cached)
  size_t blendedBricks = 0;        ///< of which blend towards coarser data at some corner
  size_t peakPackedBricks = 0;     ///< most bricks whose packed texels were held at once (packed, texture not made yet)
  uint64_t texels = 0;             ///< texels uploaded, blend textures included
  uint64_t textureBytes = 0;       ///< texels' bytes and those of the cutting plane's 16-bit values
  uint64_t slices = 0;            ///< slice polygons (or shell pieces) drawn
  uint64_t shellBricks = 0;       ///< bricks sampled by spherical shells
  uint64_t surfaceTriangles = 0;  ///< translucent triangles placed
  uint64_t unseenTriangles = 0;   ///< surface triangles (translucent or opaque) left out: they cover no pixel centre
  uint64_t slabPolygonDraws = 0;  ///< translucent triangles drawn: each once in every slab it covers
  uint64_t fragments = 0;         ///< fragment shader invocations of the slices and slab polygons
  uint64_t cutPolygons = 0;       ///< pieces of the cutting plane drawn (one per textured brick it crosses)
  uint64_t cutLineSegments = 0;   ///< segments of the surface's intersection with the cutting plane
};

/// What a slice frame draws, in the grid frame: the volume, its Volume Octree and the bricks
/// selected from it, all of which must outlive the frame.
struct SelectedBricks {
  const Volume& volume;
  const VolumeOctree& octree;
  const Selection& selection;
};

/// Renders the selected bricks of @p bricks. Requires a current GlContext.
/// @throw RuntimeError when OpenGL fails (shader compilation, framebuffer).
Image renderSlices(const SelectedBricks& bricks, const TransferFunction& tf, const Camera& camera, const SlicesOptions& options,
                   SlicesStats* stats = nullptr);

}  // namespace hyb
