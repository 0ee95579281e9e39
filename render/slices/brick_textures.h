// Brick textures of the slice renderer: one 3D texture per selected brick at its level p
// ((2^p + 1)³ knots, docs/multires.md; a non-power-of-two texture a brick), holding the value and the shading
// gradient; Carmona et al.'s blending towards coarser neighbours baked into the texels; and the
// cache that keeps them across frames, bounded by a texture-memory limit (least recently used
// bricks evicted). docs/renderer.md and docs/multires.md hold the measurements behind the choices.
#pragma once

#include <glm/glm.hpp>

#include <array>
#include <cstdint>
#include <functional>
#include <list>
#include <string>
#include <unordered_map>
#include <vector>

#include "hybrid_octree/knot_source.h"
#include "hybrid_octree/selection.h"
#include "hybrid_octree/volume_octree.h"
#include "render/frame_request.h"
#include "render/gl_objects.h"
#include "volume/volume.h"

namespace hyb {

/// Bytes of one texel of the 16-bit value textures made for 8-bit bricks a cutting plane crosses.
inline constexpr uint64_t kBytesPerCutTexel = 2;

/// Value ranges of a brick's texels over blocks of 2×2×2 knot cells (data units). The field inside
/// a cell lies within its eight texels, so the ranges bound, for any transfer function, the part of
/// the brick that can be visible.
struct BrickRanges {
  glm::ivec3 blocks{0};                      ///< blocks per axis
  std::vector<std::array<float, 2>> values;  ///< per block (x fastest): smallest and largest texel value
};

/// The blocks of a brick that a transfer function can show, found once per transfer function (a
/// new camera reuses them): one bit a block (x fastest) and the blocks' bounding box.
struct VisibleBlocks {
  uint64_t key = 0;  ///< the VisibleValues::key() they were found for; 0: not yet
  glm::ivec3 blocks{0}, lo{0}, hi{-1};
  std::vector<uint64_t> bits;
  bool empty() const { return hi.x < 0; }
};

/// A brick's texture, the mapping of its normalised values back to data units, and its ranges.
struct CachedBrick {
  gl::Texture texture;
  gl::Texture cutTexture;  ///< 8-bit bricks: its values at 16 bits, made once a cutting plane crosses it
  float valueOffset = 0.0f, valueScale = 1.0f;  ///< value = offset + scale · (2·texel − 1)
  BrickRanges ranges;
  VisibleBlocks visible;
  uint64_t bytes = 0;  ///< memory its textures hold (both; heldTextureBytes)
};

/// The memory llvmpipe allocates for a 3D texture of @p dims texels of @p texelBytes each: its rows
/// padded to four texels and then to a cache line (64 bytes), its images to four rows (Mesa's
/// llvmpipe_texture_layout). A brick of 33³ RGBA8 texels holds 1.58 times its texels' bytes.
uint64_t heldTextureBytes(const glm::ivec3& dims, uint64_t texelBytes);

/// A brick ready for upload: its value mapping and texels (the CPU half of an upload, made on all
/// cores a batch ahead of the draws that upload them).
struct PackedBrick {
  CachedBrick brick;  ///< textures not made yet
  std::vector<uint8_t> bytes;
};

/// The texels of brick @p b, value and gradient: its lattice's knot values (samples, or prefiltered
/// ones on coarse lattices) with the volume's own gradient at each knot (latticeKnots), or where a corner blends
/// (Carmona et al.) mix(coarse field, own field, w), w reaching 1 halfway across the node from the
/// corners that touch a coarser brick. The overhanging last texel of a cropped lattice is
/// extrapolated, so that uniform trilinear filtering reproduces the lattice's field exactly.
std::vector<glm::vec4> brickTexels(const KnotSource& source, const VolumeOctree& octree, const Brick& b);
/// The knots brickTexels reads for @p b: its lattice's, and where a corner blends its coarse lattice's.
std::vector<KnotBox> brickKnotBoxes(const VolumeOctree& octree, const Brick& b);
/// The seam blending removes at @p b: the largest difference, at its knots on faces shared with a
/// coarser brick (where brickTexels' weight is 0), between its own value and the coarser level's
/// field (data units), which a frame drawn without blending shows as a step there. 0 when no corner
/// of @p b touches a coarser brick.
float seamHeight(const KnotSource& source, const VolumeOctree& octree, const Brick& b);

/// The ranges of @p texels (a lattice of @p dims knots) over blocks of 2×2×2 cells.
BrickRanges texelRanges(const std::vector<glm::vec4>& texels, const glm::ivec3& dims);

/// Packs @p texels for an RGBA8 or RGBA16 texture: the value mapped from its range to [0, 1], the
/// gradient divided by its largest component (zero exact at the middle code).
PackedBrick packBrick(const std::vector<glm::vec4>& texels, TexelBits bits);

/// Makes @p packed's texture (on unit 0, left bound) and hands its brick over. Needs a current
/// GlContext.
CachedBrick uploadBrick(PackedBrick&& packed, const glm::ivec3& dims, TexelBits bits);

/// Uploads @p brick's values alone at 16 bits (R16, the same mapping as its own texture): a
/// cutting plane shows the data to 1/65535 of the brick's range.
void uploadCutTexture(const std::vector<glm::vec4>& texels, const glm::ivec3& dims, CachedBrick* brick);

/// Brick textures kept across frames of one volume and octree: a view rendered again (an
/// interactive viewer, progressive refinement, a benchmark) uploads only bricks it has not drawn
/// before. Keyed by node, level and blended corners. A texture-memory limit bounds what it keeps:
/// a frame's new bricks are kept as they are drawn while they fit, earlier frames' least recently
/// used bricks evicted to make room (those that do not fit are deleted after their draw), and after
/// a frame the least recently used bricks of earlier frames are evicted until it holds no more than
/// the limit (bricks the frame found here stay while it draws, whatever their size). Also keeps the slice shader
/// programs, keyed by their sources' feature defines. Owns GL objects: destroy it, or clear() it,
/// while its GlContext is current.
class BrickTextureCache {
 public:
  /// @p limitBytes: texture memory kept between frames; 0 = no limit.
  explicit BrickTextureCache(uint64_t limitBytes = 0) : mLimit(limitBytes) {}
  BrickTextureCache(const BrickTextureCache&) = delete;
  BrickTextureCache& operator=(const BrickTextureCache&) = delete;

  /// Brick @p b's entry (marked as used by this frame), or null.
  CachedBrick* find(const Brick& b);
  /// Whether brick @p b is kept (not marked as used).
  bool contains(const Brick& b) const { return mEntries.contains(key(b)); }
  /// Takes ownership of @p brick's textures; the entry is used by this frame.
  CachedBrick& insert(const Brick& b, CachedBrick brick);
  /// Records @p bytes more held by brick @p b's entry (a cut texture made for it).
  void grew(const Brick& b, uint64_t bytes);
  /// Starts a frame: bricks found or inserted from now on are this frame's.
  void beginFrame() { ++mFrame; }
  /// Evicts least recently used bricks of earlier frames until at most the limit is held.
  void evict();
  /// Evicts least recently used bricks of earlier frames until @p bytes more fit within the
  /// limit; whether they now fit (always, without a limit).
  bool makeRoom(uint64_t bytes);
  /// The texels' precision: a frame with another precision drops the bricks.
  void setBits(TexelBits bits);
  size_t size() const { return mEntries.size(); }
  /// Memory the kept bricks' textures hold (CachedBrick::bytes).
  uint64_t bytes() const { return mBytes; }
  uint64_t limit() const { return mLimit; }
  void setLimit(uint64_t bytes) { mLimit = bytes; }
  /// Bricks evicted so far.
  uint64_t evicted() const { return mEvicted; }
  /// The linked program kept under @p key, or 0.
  GLuint program(const std::string& key) const;
  /// Takes ownership of @p program.
  void insertProgram(const std::string& key, gl::Program program);
  /// The texture kept for the pre-integration table of id @p tableId, made by @p make when it is
  /// another table's (or none is kept): uploading its layers every frame is a large part of it.
  GLuint tableTexture(uint64_t tableId, const std::function<gl::Texture()>& make);
  void clear();

 private:
  struct Entry {
    CachedBrick brick;
    uint64_t frame = 0;                 // the last frame that used it
    std::list<uint64_t>::iterator age;  // its place in mOrder
  };
  static uint64_t key(const Brick& b) { return uint64_t(b.node) | uint64_t(uint8_t(b.p)) << 32 | uint64_t(b.coarseCorners) << 40; }
  void touch(Entry& e, uint64_t k);
  void clearBricks();
  std::unordered_map<uint64_t, Entry> mEntries;
  std::list<uint64_t> mOrder;  // keys, least recently used first
  uint64_t mLimit = 0, mBytes = 0, mFrame = 0, mEvicted = 0;
  TexelBits mBits = TexelBits::Eight;
  std::unordered_map<std::string, gl::Program> mPrograms;
  uint64_t mTableId = 0;
  gl::Texture mTable;
};

}  // namespace hyb
