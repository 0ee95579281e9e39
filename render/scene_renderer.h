// The scene renderer: the one object the command line, the benchmark and the viewer render
// through. Built once from a scene (volume, Volume Octree, optional Surface Octree) and kept alive,
// it owns what frames share: the OpenGL context (made at the first slice frame), the brick texture
// cache (bounded by a texture-memory limit), the shader programs, the isosurfaces reconstructed so
// far and the image errors of the last view. A frame is asked for by a view (the camera and the
// image's size), a look (transfer function, surface, cut, volume of interest) and a quality (the
// renderer, ε, budget, step, proxy), and only what depends on what changed is redone: a new camera
// keeps the bricks; a new transfer function keeps the textures (their value ranges are in data
// units) and rebuilds the visible blocks; a new isovalue rebuilds the surface only.
//
// Coordinates the caller gives are patient millimetres (LPS); the renderers work in the grid frame.
// Use one SceneRenderer from one thread (the OpenGL context is current on the thread that made it).
#pragma once

#include <glm/glm.hpp>

#include <atomic>
#include <cstdint>
#include <functional>
#include <list>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "hybrid_octree/hybrid_io.h"
#include "hybrid_octree/selection.h"
#include "render/bvh.h"
#include "render/camera.h"
#include "render/cut_plane.h"
#include "render/frame_request.h"
#include "render/gl_context.h"
#include "render/image.h"
#include "render/raycast.h"
#include "render/regions.h"
#include "render/selection_policy.h"
#include "render/slices.h"
#include "render/transfer_function.h"
#include "render/voi.h"
#include "volume/core/progress.h"

namespace hyb {

/// What a frame used and how long each stage took.
struct FrameStats {
  Renderer renderer = Renderer::Slices;
  uint64_t budgetTexels = 0;  ///< the budget as texels (0 = unlimited)
  uint64_t fullTexels = 0;    ///< this view's full-resolution texels (when the budget is a percentage)
  SlicesStats slices;
  RaycastStats rays;
  size_t surfacePolygons = 0, surfaceTriangles = 0;
  /// The cubes (voxels a side) the surface drawn was clustered by: 1 for the Surface Octree's
  /// surface, s ≥ 2 for clusteredSurface's (Quality::lodPixels).
  int surfaceSpacing = 1;
  bool surfaceBuilt = false;  ///< the surface was built for this frame (not from the scene or an earlier frame)
  bool surfaceSimplified = false;  ///< a level of the simplified surface was drawn (Quality::simplifiedSurface)
  double surfaceBuildMs = 0, surfacePolygonsMs = 0;  ///< this frame's work on the surface (0 when kept)
  /// Regions of the scene's Surface Octree this frame reconstructed and kept from earlier frames,
  /// when it draws the surface by regions (SceneRenderer::byRegions; both 0 otherwise).
  size_t surfaceRegionsMade = 0, surfaceRegionsKept = 0;
  double selectMs = 0, renderMs = 0;
  double preintegrationMs = 0;     ///< making the pre-integration table (0 when kept or not used)
  double bvhMs = 0;                ///< making the ray tracer's BVH of the surface (0 when kept or not used)
  /// Putting the user meshes in the grid frame, cut to leaf cells, and their BVH (0 when kept).
  double meshesMs = 0;
  size_t meshTriangles = 0;        ///< the user meshes' triangles (before cutting)
  /// Scan-converting the user meshes and primitives (MeshMethod::ScanConvert; 0 when kept), and
  /// the bytes their channel holds.
  double geometryMs = 0;
  uint64_t geometryBytes = 0;
  size_t brickErrorsMeasured = 0;  ///< the view's bricks whose image error has been measured
  uint64_t textureBytesKept = 0;   ///< the brick texture cache after the frame
  /// Bricks of the selection drawn from a coarser level because their knots were not cached (the
  /// prefetch thread is loading them) or their textures were beyond Quality::packTexels
  /// (Quality::waitForBricks false). 0: the frame is final.
  size_t bricksNotResident = 0;
};

/// A frame: its image (premultiplied RGBA), the selection it drew (slices) and its stats.
struct RenderedFrame {
  Image image;
  Selection selection;
  FrameStats stats;
};

/// Receives each image of a progressive frame before the last: level (1-based), levels, image, and
/// the stats of that level.
using LevelCallback = std::function<void(int level, int levels, const Image& image, const FrameStats& stats)>;

/// The blocks (voxels a side) within which PreparedSurface::simplified[0] is simplified: each of
/// its triangles lies inside one block, hence inside one brick of edge at least this many voxels.
inline constexpr int kSimplifiedBlockVoxels = 32;
/// PreparedSurface::simplified: level k is simplified to 2^k voxels' error within blocks of
/// kSimplifiedBlockVoxels·2^k voxels (from level k − 1, within 2^(k−1) voxels more), at least
/// kSimplifiedLevels levels, and more until the coarsest one's error reaches the volume's longest
/// extent over kCoarsestLevelFraction: two pixels (the viewer's moving frames' error) of a
/// 128-pixel view of the whole volume, the size of most of its moving frames. A larger study's
/// small frames then draw about as many triangles as a smaller one's (simplifiedLevelCount).
inline constexpr int kSimplifiedLevels = 4;
inline constexpr int kCoarsestLevelFraction = 64;
/// The levels simplifiedLevels makes for a volume of @p dims voxels spaced @p spacing mm (errors
/// in its smallest spacing): on isotropic voxels 4 up to 512 a side, 5 up to 1024, 6 up to 2048.
int simplifiedLevelCount(const glm::ivec3& dims, const glm::dvec3& spacing);

/// An isosurface ready to draw: its Surface Octree, its polygons triangulated, with both kinds of
/// normals, and its simplified levels (made by SceneRenderer::prepareSurface, on any thread), and
/// the coarse surfaces frames whose pixels are wider than a voxel drew. Kept by a renderer.
struct PreparedSurface {
  float iso = 0.0f;
  bool exact = false;                  ///< built, polygons and smooth are made
  std::optional<SurfaceOctree> built;  ///< none when the scene's own surface has this isovalue
  size_t polygons = 0;
  /// Grid frame, mm, with the gradient's normals; shared with a viewer's builder thread, which
  /// simplifies it while frames draw it (the renderer may let go of it meanwhile).
  std::shared_ptr<const TriangleMesh> smooth;
  /// smooth without its normals (each triangle shaded by its plane): made when first asked for, as
  /// most frames and every viewer shade by the gradient (a copy costs 19 bytes a triangle).
  TriangleMesh facet;
  /// Smooth, simplified to 1, 2, 4, … voxels' error within blocks (simplifiedLevelCount): for the
  /// viewer's frames before the final one, each drawing the coarsest its pixels allow; made when one
  /// first asks for them, or by a viewer's builder thread (SceneRenderer::simplifiedLevels); a frame
  /// that does not wait for its surface draws a clustered or the full-resolution one meanwhile.
  std::vector<TriangleMesh> simplified;
  std::unique_ptr<Bvh> bvh[2];         ///< facet, smooth; made by the first reference frame
  const TriangleMesh* bvhMesh[2] = {nullptr, nullptr};  ///< the mesh each was made for
  /// clusteredSurface of each cube edge s ≥ 2 a frame drew (grid frame, mm, smooth): made by that frame.
  std::map<int, TriangleMesh> coarse;
  /// Bytes its meshes and Surface Octree hold (not Embree's BVHs, which the reference frames make).
  size_t bytesUsed() const;
  const TriangleMesh& mesh(SurfaceNormals n) {
    HYB_CHECK(smooth);
    if (n == SurfaceNormals::Gradient) return *smooth;
    if (facet.triangles.size() != smooth->triangles.size()) facet = TriangleMesh{smooth->vertices, smooth->triangles, {}, smooth->polygonStarts};
    return facet;
  }
};

/// A frame whose Surface Octree's reconstruction (SurfaceOctree::reconstructBytes) would take more
/// than this fraction of Options::memoryBytes reconstructs it region by region (regions of at most
/// kSurfaceRegionNodes nodes), keeping only the polygons it draws (SceneRenderer::byRegions).
inline constexpr int kWholeSurfaceMemoryDivisor = 2;
inline constexpr size_t kSurfaceRegionNodes = 16384;

/// Decompressed bytes of the store's coarse levels that a frame which does not wait for the store
/// reads whether cached or not (the phantom's spacings of 16 and more; the clinical study's of 4).
inline constexpr uint64_t kReadAnywayBytes = uint64_t(16) << 20;

class SceneRenderer {
 public:
  struct Options {
    uint64_t textureLimitBytes = 0;      ///< brick textures kept between frames; 0 = no limit
    const Progress* progress = nullptr;  ///< hears of long steps (surfaces, reference frames, slices)
    /// false: no brick texture outlives its draw (one frame: the textures never all held at once)
    bool keepTextures = true;
    /// Frames that do not wait for a paged store (Quality::waitForBricks) read its levels that
    /// hold at most this many bytes whether cached or not (KnotStore::coarseSpacing).
    uint64_t readAnywayBytes = kReadAnywayBytes;
    /// A paged scene's --memory (SceneLoadOptions::memoryBytes): its block cache gets what its
    /// octrees, the brick textures kept (textureLimitBytes) and the surfaces this renderer keeps
    /// leave (sceneCacheBytes), shrinking as surfaces are made and growing as they go. 0: the
    /// cache keeps the bound it was opened with.
    uint64_t memoryBytes = 0;
    /// Largest region a surface drawn by regions is reconstructed in (SurfaceOctree::regions).
    size_t surfaceRegionNodes = kSurfaceRegionNodes;
  };
  explicit SceneRenderer(Scene scene, const Options& options);
  explicit SceneRenderer(Scene scene) : SceneRenderer(std::move(scene), Options{}) {}
  SceneRenderer(const SceneRenderer&) = delete;
  SceneRenderer& operator=(const SceneRenderer&) = delete;
  ~SceneRenderer();

  const Scene& scene() const { return mScene; }
  const Volume& volume() const { return mScene.volume; }
  const VolumeOctree& octree() const { return mScene.octree; }

  /// Renders one frame (the last of a progressive sequence; @p onLevel hears of the others).
  /// @throw ValueError for impossible parameters; RuntimeError when OpenGL fails.
  RenderedFrame render(const View& view, const Look& look, const Quality& quality, const LevelCallback& onLevel = {});

  /// The bricks a slice frame of @p view, @p look and @p quality selects (what render() draws,
  /// before a paged store's residency), without drawing: for sweeps that pick their settings by it.
  /// @throw ValueError for impossible parameters.
  Selection select(const View& view, const Look& look, const Quality& quality);

  /// A sort-last frame: its selection (select()) split into @p parts regions (splitSelection) to
  /// be rendered apart (Quality::region) and composited in the order given, front to back from the
  /// view's eye (far behind the camera for an orthographic view).
  /// @throw ValueError for impossible parameters.
  struct SortLast {
    Selection selection;  ///< the whole frame's
    Regions regions;
    std::vector<int> frontToBack;
  };
  SortLast sortLast(const View& view, const Look& look, const Quality& quality, int parts);

  /// Builds the isosurface a frame of @p view, @p look and @p quality draws (the Surface Octree's,
  /// with the normals @p look asks for, or the coarse one its level of detail allows) and reports
  /// that work and the surface; render() does it too when it was not done.
  FrameStats prepare(const View& view, const Look& look, const Quality& quality);

  /// The isosurface of @p iso in the grid frame, built (or taken from the scene) on first use and
  /// kept: its triangles with the @p normals asked for.
  const TriangleMesh& surface(float iso, SurfaceNormals normals);
  /// The polygons of the surface of @p iso (0 before it is built).
  size_t surfacePolygons(float iso) const;
  /// Whether the surface of @p iso is ready: a frame showing it at full resolution builds nothing.
  bool hasSurface(float iso) const;
  /// Bytes the surfaces kept hold (PreparedSurface::bytesUsed): counted against Options::memoryBytes.
  size_t surfaceBytes() const;
  /// Whether a surface of @p iso is kept, full-resolution or clustered: a frame that does not wait
  /// for its surface (Quality::waitForSurface) can draw it.
  bool hasAnySurface(float iso) const;
  /// The isovalues of the surfaces kept, most recently used first.
  std::vector<float> surfaceIsos() const;

  /// Makes the isosurface of @p iso of @p scene, touching no renderer: it only reads the scene, so
  /// it may run on another thread while a renderer of the same scene draws (a viewer keeps showing
  /// the old surface meanwhile). @p stats, when given, receives the build and polygon times.
  /// @p reserve, when given, hears what the reconstruction will hold at most before it starts
  /// (SurfaceOctree::reconstructBytes), and 0 once it is done or stopped (surfaceReservation).
  static std::unique_ptr<PreparedSurface> prepareSurface(const Scene& scene, float iso, const Progress* progress = nullptr,
                                                         FrameStats* stats = nullptr, const std::function<void(uint64_t)>& reserve = {});
  /// A reserve callback for prepareSurface and simplifiedLevels, on any thread: what it is told
  /// counts against Options::memoryBytes with the surfaces kept until it is told 0. Each callback
  /// counts apart (surfaces may be made on two threads at once). Thread-safe.
  std::function<void(uint64_t)> surfaceReservation();
  /// Counts @p bytes more, or fewer, of surfaces made elsewhere and not yet adopted
  /// (adoptSurface) against Options::memoryBytes; in any order from any thread.
  void holdSurfaceBytes(uint64_t bytes);
  void releaseSurfaceBytes(uint64_t bytes);
  /// The simplified levels of @p smooth (PreparedSurface::simplified; normals from @p scene), also
  /// touching no renderer; @p reserve hears what they hold at most while made
  /// (kSimplifyBytesPerTriangle), then 0.
  static std::vector<TriangleMesh> simplifiedLevels(const Scene& scene, const TriangleMesh& smooth, const Progress* progress = nullptr,
                                                    const std::function<void(uint64_t)>& reserve = {});
  /// The full-resolution surface of @p iso (smooth) when it is kept without its simplified levels;
  /// else null.
  std::shared_ptr<const TriangleMesh> unsimplified(float iso) const;
  /// Keeps @p surface (made from this renderer's scene) as the surface of its isovalue, joined with
  /// what is kept of it: the full-resolution surface, the clustered ones, the simplified levels (a
  /// viewer's builder hands them over one after the other).
  void adoptSurface(std::unique_ptr<PreparedSurface> surface);
  /// Surfaces kept: those of the isovalues pinned here (a viewer's clients draw them) and, of the
  /// others, the two used most recently. Unpinned surfaces beyond those are dropped now.
  void pinSurfaces(std::vector<float> isos);

  /// Starts making the render target of a slice frame of @p width x @p height on a thread of its
  /// own (gl::TargetCache::prepare), once a frame has made this renderer's context: a large frame
  /// asked for ahead of its first band finds it made.
  void prepareTarget(int width, int height);
  /// Frames drawn into a target prepareTarget made.
  size_t targetsMadeAhead() const { return mTargets.madeAhead(); }

  /// Drops the brick textures and programs: the next frame packs, uploads and compiles anew.
  void dropTextures();
  /// Texture memory the cache holds.
  uint64_t textureBytes() const { return mTextures ? mTextures->bytes() : 0; }

 private:
  struct Errors;
  /// The surface a frame draws (Look::iso set), its work and size in @p st.
  const TriangleMesh* frameSurface(const FrameGrid& g, const Look& look, const Quality& quality, FrameStats* st);
  /// Whether a frame of @p quality draws the scene's surface of @p iso reconstructed region by
  /// region: a slice frame that waits for its full-resolution surface, none kept, whose
  /// reconstruction whole would take more than 1/kWholeSurfaceMemoryDivisor of the memory bound.
  bool byRegions(const Camera& gridCamera, const Quality& quality, float iso) const;
  /// That frame's surface: the polygons of the scene's Surface Octree that it draws (one of whose
  /// triangles PixelCentres does not know to cover no centre, or crossing the cutting plane whose
  /// line is drawn), region by region, in the whole surface's order: the frame's image is the one
  /// the whole surface gives. Regions are kept (mRegions) while they fit in their bound.
  const TriangleMesh& regionSurface(const FrameGrid& g, const Look& look, FrameStats* st);
  /// The two renderers' frames, the surface @p mesh (or none) in it.
  void renderRaycast(const FrameGrid& g, const Look& look, const Quality& quality, const TriangleMesh* mesh, const LevelCallback& onLevel,
                     RenderedFrame* out);
  void renderSlicesFrame(const FrameGrid& g, const Look& look, const Quality& quality, const TriangleMesh* mesh, const LevelCallback& onLevel,
                         RenderedFrame* out);
  /// The selection parameters of a frame (ε, the budget as texels in @p st, the view's errors).
  SelectionParams selectionParams(const FrameGrid& g, const Look& look, const Quality& quality, FrameStats* st);
  /// The kept entry of @p iso (made empty when there is none), most recently used now.
  PreparedSurface& entry(float iso);
  /// entry(iso) with its full-resolution surface made.
  PreparedSurface& surfaceEntry(float iso, FrameStats* stats);
  /// The surface of @p iso clustered by cubes of @p s ≥ 2 voxels, made when not kept.
  const TriangleMesh& coarseSurface(float iso, int s, FrameStats* stats);
  /// The cubes (voxels a side) the surface of a frame of @p gridCamera and @p quality is clustered
  /// by (Quality::lodPixels): 1 for the Surface Octree's surface.
  int surfaceSpacing(const Camera& gridCamera, const Quality& quality) const;
  /// The cubes of the surface of @p iso such a frame draws: surfaceSpacing, or what is kept nearest
  /// it when the frame does not wait for its surface (0: nothing is kept, the frame draws none; a
  /// moving frame draws a kept preview until the simplified levels come).
  int drawnSpacing(const Camera& gridCamera, const Quality& quality, float iso) const;
  /// Makes (or finds) the surface of @p iso clustered by cubes of @p s voxels (1: the Surface
  /// Octree's, with @p normals), and reports that work and the surface in @p st.
  const TriangleMesh& prepareAt(float iso, int s, SurfaceNormals normals, FrameStats* st);
  /// @p mesh cut to @p region (cutMeshToRegion), kept for the next frame of the same region.
  const TriangleMesh& regionSurface(const TriangleMesh& mesh, const RegionBox& region);
  /// The look's user meshes in the grid frame (kept while the look's meshes and colours are the
  /// same), with their BVH when @p bvh; none when the look has none.
  const GridMeshes* frameMeshes(const Look& look, bool bvh, FrameStats* st);
  /// The look's user meshes and primitives scan-converted (MeshMethod::ScanConvert; kept while the
  /// look's meshes, colours and filter are the same), or none.
  const GeometryChannel* frameGeometry(const Look& look, FrameStats* st);
  /// The size (mm) of a pixel of @p gridCamera where the volume comes nearest the eye.
  double nearestPixelMm(const Camera& gridCamera) const;
  PreparedSurface& keep(std::unique_ptr<PreparedSurface> surface);
  void trimSurfaces();
  /// Gives a paged scene's cache what its octrees, the kept surfaces and a surface being made
  /// elsewhere leave of Options::memoryBytes (render thread).
  void boundCache();
  void setCacheBound();  // from mKeptBytes and mReservedBytes, under mBoundMutex
  ViewErrors& viewErrors(const Camera& gridCamera, const TransferFunction& tf, const std::optional<CutPlane>& cut,
                         const std::optional<VolumeOfInterest>& voi, bool anyCamera);
  void ensureGl();
  /// The pre-integration table of @p tf with layers for segments of [minMm, maxMm], kept until the
  /// transfer function changes or a frame needs other layers (its making timed in @p st).
  const PreIntegrationTable& preintegration(const TransferFunction& tf, double minMm, double maxMm, FrameStats* st);
  /// Makes @p selection drawable from what is resident (Quality::waitForBricks false) and packs
  /// at most @p packTexels (0: any), asks a paged store's prefetch thread for the knots not
  /// cached, and returns how many bricks are drawn coarser.
  size_t drawResident(const Camera& gridCamera, uint64_t packTexels, Selection* selection);

  Scene mScene;
  Options mOptions;
  std::optional<GlContext> mGl;                  // made at the first slice frame
  std::unique_ptr<BrickTextureCache> mTextures;  // destroyed before the context
  gl::TargetCache mTargets;                      // (the same)
  std::list<std::unique_ptr<PreparedSurface>> mSurfaces;  // most recently used first
  std::vector<float> mPinned;                             // kept whatever else is built
  std::mutex mBoundMutex;                                 // the cache bound is set from two threads
  std::atomic<uint64_t> mKeptBytes{0}, mReservedBytes{0};  // surfaceBytes(), and the surfaceReservation()s
  std::unique_ptr<Errors> mErrors;               // the last view's
  std::unique_ptr<PreIntegrationTable> mPreintegration;   // the last frame's, and its transfer function
  TransferFunction mPreintegrationTf;
  struct RegionSurface {
    const TriangleMesh* from = nullptr;
    size_t triangles = 0, vertices = 0;  // of `from`, whose address a remade entry may reuse
    RegionBox box;
    TriangleMesh mesh;
  } mRegionSurface;  // the last sort-last frame's
  struct SurfaceRegions {
    float iso = 0.0f;
    std::vector<SurfaceRegion> regions;
    std::vector<std::shared_ptr<const TriangleMesh>> kept;  // per region its triangles (grid mm, no normals), or none
    uint64_t keptBytes = 0;
    TriangleMesh frame;  // the last frame's polygons
    uint64_t bytes() const { return keptBytes + frame.bytesUsed(); }
  } mRegions;  // the scene's surface by regions (byRegions)
  struct KeptMeshes {
    std::vector<std::shared_ptr<const TriangleMesh>> from;  // held: their addresses stay theirs
    std::vector<glm::vec4> colors;
    GridMeshes grid;
    std::unique_ptr<Bvh> bvh;
  } mMeshes;  // the last frame's user meshes
  struct KeptGeometry {
    std::vector<std::shared_ptr<const TriangleMesh>> from;  // held: their addresses stay theirs
    std::vector<glm::vec4> colors;
    double filter = 1.0;  // Look::meshFilter
    std::unique_ptr<GeometryChannel> channel;  // its textures are deleted in the context (declared after mGl)
  } mGeometry;  // the last frame's scan-converted geometry
};

}  // namespace hyb
