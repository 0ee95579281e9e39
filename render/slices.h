// The hybrid slice renderer (Boada and Navazo 2002, §4; DESIGN 3.4–3.5) on OpenGL 4.5 core through
// OSMesa: one 3D texture per selected brick at its level p, view-aligned slices cut on the CPU from
// globally aligned planes, bricks drawn back to front in octree order (valid for perspective and
// orthographic views), composited in a float framebuffer with premultiplied colours.
//
// Opaque surfaces are drawn first with depth writes. Translucent surface triangles go through the
// SlabPolygon lists: each is put into the slabs between global slice planes that its depth range
// covers (clipped to each slab on the CPU where it spans several; per fragment for shells), sorted
// back to front inside a slab, and drawn between the slices of its brick; the lists are rebuilt for
// every view.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <unordered_map>
#include <vector>

#include "hybrid_octree/selection.h"
#include "hybrid_octree/volume_octree.h"
#include "render/camera.h"
#include "render/cut_plane.h"
#include "render/voi.h"
#include "render/gl_context.h"
#include "render/image.h"
#include "render/transfer_function.h"
#include "surface/mesh.h"
#include "volume/volume.h"

namespace hyb {

/// Proxy geometry that samples the bricks (LaMar 1999).
enum class Proxy {
  Planes,  ///< view-aligned planes f·x = kΔ, globally aligned
  Shells,  ///< spherical shells |x − eye| = kΔ around the eye (perspective; bricks the eye is too close
           ///< to, and orthographic views, use planes)
};

/// Value ranges of a brick's texels over blocks of 2×2×2 knot cells, as the span of transfer-function
/// lookup entries each block can read. The field inside a cell lies within its eight texels, so the
/// spans bound, for any transfer function, the part of the brick that can be visible.
struct BrickRanges {
  glm::ivec3 blocks{0};                         ///< blocks per axis
  std::vector<std::array<uint16_t, 2>> entries;  ///< per block (x fastest): first and last entry
};

/// Precision of the brick textures' value and gradient: 8 bits (RGBA8, which llvmpipe filters in
/// fixed point) or 16 bits (RGBA16: twice the bytes, slower frames, for transfer functions whose
/// features are narrow against a brick's range of values, e.g. soft tissue next to air and bone).
enum class TexelBits { Eight = 8, Sixteen = 16 };
/// Bytes of one brick texel: value and three gradient components.
inline constexpr uint64_t bytesPerTexel(TexelBits bits) { return bits == TexelBits::Sixteen ? 8 : 4; }
/// Bytes of one texel of the 16-bit value textures made for 8-bit bricks a cutting plane crosses.
inline constexpr uint64_t kBytesPerCutTexel = 2;

/// A brick's texture, the mapping of its normalised values back to data units, and the ranges of
/// its texels.
struct CachedBrick {
  unsigned texture = 0;
  unsigned cutTexture = 0;  ///< 8-bit bricks: its values at 16 bits, made once a cutting plane crosses it
  float valueOffset = 0.0f, valueScale = 1.0f;  ///< value = offset + scale · (2·texel − 1)
  BrickRanges ranges;
};

/// Brick textures kept across frames of one volume and octree: a view that is rendered again (an
/// interactive viewer, progressive refinement, a benchmark) uploads only bricks it has not drawn
/// before. Keyed by node, level and blended corners. Also keeps the slice shader programs, keyed
/// by their sources' feature defines. Owns GL objects: destroy it, or clear() it, while its
/// GlContext is current.
class BrickTextureCache {
 public:
  BrickTextureCache() = default;
  BrickTextureCache(const BrickTextureCache&) = delete;
  BrickTextureCache& operator=(const BrickTextureCache&) = delete;
  ~BrickTextureCache() { clear(); }

  /// Brick @p b's entry, or null.
  CachedBrick* find(const Brick& b);
  /// Takes ownership of @p brick's textures.
  CachedBrick& insert(const Brick& b, CachedBrick brick);
  size_t size() const { return mTextures.size(); }
  /// The value range of the transfer function's lookup table, to which the bricks' block ranges
  /// refer (it follows the transfer function's domain), and the texels' precision: a frame with
  /// another range or precision drops the bricks.
  void setLayout(float lutMin, float lutMax, TexelBits bits);
  /// The linked program kept under @p key, or 0.
  unsigned program(const std::string& key) const;
  /// Takes ownership of @p program.
  void insertProgram(const std::string& key, unsigned program);
  void clear();

 private:
  static uint64_t key(const Brick& b) { return uint64_t(b.node) | uint64_t(uint8_t(b.p)) << 32 | uint64_t(b.coarseCorners) << 40; }
  void clearBricks();
  std::unordered_map<uint64_t, CachedBrick> mTextures;
  float mLutMin = 0.0f, mLutMax = 0.0f;
  TexelBits mBits = TexelBits::Eight;
  std::unordered_map<std::string, unsigned> mPrograms;
};

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
  const CutPlane* cut = nullptr;          ///< cutting plane, or none
  const VolumeOfInterest* voi = nullptr;  ///< opacity scaling box, or none
  bool cutLine = true;                    ///< draw the surface's intersection with the cutting plane
  BrickTextureCache* textures = nullptr;  ///< brick textures reused across frames (none: uploaded per frame)
  TexelBits texelBits = TexelBits::Eight;
  bool visibleBoxes = true;             ///< slice only the box of each brick's cells that the transfer
                                        ///< function can make visible (false: the whole brick; same image)
  bool slabOrder = true;                  ///< false: draw each brick's surface after its slices (a
                                          ///< deliberately wrong order, to show the tests catch it)
};

/// What a frame used.
struct SlicesStats {
  size_t bricks = 0;               ///< textured bricks
  size_t blendedBricks = 0;        ///< of which blend towards coarser data at some corner
  uint64_t texels = 0;             ///< texels uploaded, blend textures included
  uint64_t textureBytes = 0;       ///< texels' bytes and those of the cutting plane's 16-bit values
  uint64_t slices = 0;            ///< slice polygons (or shell pieces) drawn
  uint64_t shellBricks = 0;       ///< bricks sampled by spherical shells
  uint64_t surfaceTriangles = 0;  ///< translucent triangles placed
  uint64_t slabPolygonDraws = 0;  ///< translucent pieces drawn: a triangle's, or a convex polygon's, part in each slab it covers
  uint64_t fragments = 0;         ///< fragment shader invocations of the slices and slab polygons
  uint64_t cutPolygons = 0;       ///< pieces of the cutting plane drawn (one per textured brick it crosses)
  uint64_t cutLineSegments = 0;   ///< segments of the surface's intersection with the cutting plane
};

/// Throughput baseline: seconds llvmpipe takes to blend @p quads full-screen quads that sample a
/// 3D texture of @p volume into a float framebuffer of @p width x @p height, and the fragments it
/// shaded. The texture is R32F, or with @p brickFormat the bricks' default RGBA8 (value and
/// gradient), to tell the cost of the format from that of the shader. Requires a current GlContext.
double plainQuadSeconds(const Volume& volume, int width, int height, int quads, uint64_t* fragments, bool brickFormat = false);

/// Renders the bricks of @p selection. Requires a current GlContext.
/// @throw RuntimeError when OpenGL fails (shader compilation, framebuffer).
Image renderSlices(const Volume& volume, const VolumeOctree& octree, const Selection& selection, const TransferFunction& tf,
                   const Camera& camera, const SlicesOptions& options, SlicesStats* stats = nullptr);

}  // namespace hyb
