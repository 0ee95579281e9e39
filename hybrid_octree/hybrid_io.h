// Scene files (.hoct): the volume and its Hybrid Octree in one versioned binary.
//
// Layout (little-endian): magic "HYBOCT\x1a\n", u32 version, u32 section count, then per section
// a u32 tag, u64 payload size, u32 CRC-32 of the payload, and the payload. Sections: VOLM (volume:
// dims, spacing, source type, stored type, sample count, value range, patient frame, whether the
// frame was assumed, info), KDAT (the knot store's compressed blocks, knot_store.h; its section CRC
// is 0, each block has its own), KIDX (the store's levels and block index), VOCT (Volume Octree),
// SURF (Surface Octree, optional). VOCT and SURF begin with a 64-bit hash of the VOLM and KIDX
// payloads they were built from (KIDX holds every block's CRC). The bytes are deterministic: a
// scene saved twice is the same file. Readers reject a foreign magic, another version (files
// before version 6: rebuilding them is the safe answer), truncation, CRC mismatches, sections of
// another volume, and, when the samples are loaded, an octree whose min/max disagree with them;
// unknown sections are skipped.
#pragma once

#include <memory>
#include <optional>
#include <string>

#include "hybrid_octree/knot_store.h"
#include "hybrid_octree/surface_octree.h"
#include "hybrid_octree/volume_octree.h"
#include "volume/volume.h"

namespace hyb {

struct RawLayout;  // volume/volume_io.h

/// Current scene-file version.
// 2: the octree records its knot mode; 3: the volume its patient frame and info; 4: the octree
// sections the volume's content hash, surface nodes field by field (deterministic bytes); 5: the
// samples in the type the volume holds them in, and whether its orientation was assumed; 6: the
// samples in a paged, compressed knot store.
inline constexpr uint32_t kSceneVersion = 6;

/// A loaded scene: the volume, its Volume Octree and, when built with an isovalue, its Surface Octree.
struct Scene {
  Volume volume;  ///< without its samples when loaded paged (see knots)
  VolumeOctree octree;
  std::optional<SurfaceOctree> surface;
  /// Loaded paged: where the bricks, the reference ray tracer and an isosurface's extraction read
  /// their samples, through its cache. Null when the samples were loaded.
  std::shared_ptr<KnotStore> knots;
};

/// The Surface Octree of @p iso: the scene's own when it is of that isovalue, else extracted from
/// the scene's samples (a paged scene's leaf by leaf through its cache, never whole).
/// @throw IoError as KnotSource::read.
SurfaceOctree sceneSurface(const Scene& scene, float iso, const Progress* progress = nullptr);

/// Sets @p mesh's vertex normals from the scene's gradient (setGradientNormals; a paged scene's
/// read through its cache, bit-identical to the samples' in memory).
void setSceneNormals(const Scene& scene, TriangleMesh* mesh);

/// How a scene is loaded.
struct SceneLoadOptions {
  /// Read every sample into the volume (true), or leave them in the file's knot store (paged).
  bool samples = true;
  /// Paged: bytes the scene may hold (0: no bound): its octrees, and the store's cache of
  /// decompressed blocks, which gets what the octrees leave, at least a quarter
  /// (sceneCacheBytes).
  uint64_t memoryBytes = 0;
};

/// The cache bound of a paged scene whose octrees hold @p octreeBytes within @p memoryBytes (0: no
/// bound): what the octrees leave, at least a quarter of @p memoryBytes.
uint64_t sceneCacheBytes(uint64_t memoryBytes, uint64_t octreeBytes);

/// Writes @p volume, @p octree and, if given, @p surface to @p path atomically.
/// @throw IoError naming @p path when it cannot be written.
void saveScene(const std::string& path, const Volume& volume, const VolumeOctree& octree,
               const SurfaceOctree* surface = nullptr);

/// Writes the scene of the volume @p description describes (its grid, types, range, frame and info;
/// no samples needed), whose knot store @p store made from its planes while @p octree was built
/// (VolumeOctree::build with @p store as the visitor), atomically to @p path.
/// @throw IoError naming @p path when it cannot be written.
void saveScene(const std::string& path, const Volume& description, const VolumeOctree& octree, KnotStoreWriter& store,
               const SurfaceOctree* surface = nullptr);

/// The same with the Surface Octree @p surface, whose nodes are copied from its temporary file.
/// @throw IoError naming @p path when it cannot be written, or as SpooledSurfaceOctree::encodeNodes.
void saveScene(const std::string& path, const Volume& description, const VolumeOctree& octree, KnotStoreWriter& store,
               const SpooledSurfaceOctree& surface);

/// Where the temporary files of a scene to be saved at @p path wait: its directory.
std::string spoolDirectoryFor(const std::string& path);

/// The store writer of a scene to be saved at @p path from @p planes (its blocks wait beside it).
KnotStoreWriter storeWriterFor(const std::string& path, const PlaneSource& planes);

/// Reads a scene written by saveScene.
/// @throw IoError naming @p path for foreign, older, newer, truncated or corrupt files.
Scene loadScene(const std::string& path, const SceneLoadOptions& options = SceneLoadOptions());

/// True when @p path starts with the scene-file magic.
bool isSceneFile(const std::string& path);

/// Where a scene comes from: a scene file, or a volume (file, DICOM directory or series, raw with
/// its layout) whose octree is built.
struct SceneSource {
  std::string path;
  const RawLayout* raw = nullptr;  ///< headerless raw data's layout; null: the file describes itself
  std::string series;              ///< a DICOM directory's Series Instance UID; empty: the largest series
  const Progress* progress = nullptr;  ///< where the read and the build report; may be null
};

/// A scene opened by openScene, with what it took.
struct OpenedScene {
  Scene scene;
  bool loaded = false;  ///< read from a scene file (else read as a volume, its octree built)
  double readMs = 0, buildMs = 0;  ///< a scene file's load counts as its read
};

/// Refuses a grid with fewer than 2 samples along an axis (a single DICOM image: a localizer), which
/// has nothing between its samples to render or mesh. @throw ValueError naming @p what.
void checkSceneGrid(const glm::ivec3& dims, const std::string& what);

/// Loads @p source when it is a scene file (as @p load says: paged or whole), else reads the volume
/// and builds its octree with @p options (its progress: @p source's). The volume's reader warnings
/// stay in scene.volume.warnings().
/// @throw IoError or ValueError as loadScene and readVolume, and as checkSceneGrid.
OpenedScene openScene(const SceneSource& source, const VolumeOctreeOptions& options = {}, const SceneLoadOptions& load = {});

}  // namespace hyb
