// The scenes a viewer server keeps open for its clients (viewers, each known by a number): loading
// a volume in the background with its progress, the summary a viewer needs before its first frame,
// the isosurfaces built in the background for the viewers that ask for them, which surface each
// viewer's frames draw, and the release of a scene no viewer has shown for a while. The server
// keeps only its sockets, its messages and each client's frame requests and quality.
//
// Locking: the pool is guarded by the mutex its owner gives it. Call every method with that mutex
// held; the pool's threads (one loader, one builder a scene) take it too. Events are called with
// it held, from the owner's calls or the pool's threads: a handler must not block or lock it.
// Scenes are rendered and released on one thread (the owner's render thread: a SceneRenderer's
// OpenGL context is current there), which calls forFrame() and collect().
#pragma once

#include <array>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "hybrid_octree/hybrid_io.h"
#include "render/camera.h"
#include "render/scene_renderer.h"
#include "volume/core/progress.h"
#include "volume/volume.h"

namespace hyb {

/// What a viewer needs to know of an open scene before its first frame, made once when it loads.
struct SceneSummary {
  std::string key;            ///< the scene's identity in the pool
  std::string path, series;   ///< as the loader read them
  std::string name;           ///< what a viewer calls it
  glm::ivec3 dims{0};
  glm::dvec3 spacing{1.0};
  float minValue = 0.0f, maxValue = 0.0f;
  Histogram histogram;        ///< 128 bins over the value range
  std::string orientation;    ///< the grid's orientation code ("LPS", "RAS", ...)
  bool orientationAssumed = false;  ///< the file carries none: the code is the reader's convention
  glm::dvec3 boundsLo{0.0}, boundsHi{0.0};  ///< the data's box in the patient, LPS mm
  /// The six anatomical views (AnatomicalView's order), 512², framing what the default transfer
  /// function (TransferFunction::defaultFor the value range) makes visible.
  std::array<Camera, 6> views;
  std::optional<float> sceneIso;  ///< the isovalue of the scene file's own Surface Octree
  /// A coarse stand-in shown while the scene itself loads (ScenePool::Options::previewer); the
  /// scene replaces it under the same key.
  bool preview = false;
};

/// A paged scene of more samples than this summarizes the histogram of its samples at even
/// positions (an eighth, read in a few seconds where all of an 8 GiB study take half a minute).
inline constexpr uint64_t kSummarySamples = uint64_t(1) << 27;

/// A scene of more samples than this (paged or in memory) draws a clustered surface
/// (previewSpacing) while the full-resolution one is made: a clinical study's in about a second
/// where the full one takes seven, the 8 GiB phantom's in seconds where the full one takes over a minute.
inline constexpr uint64_t kPreviewSurfaceSamples = uint64_t(1) << 24;

/// The cubes of a scene's surface preview: about a pixel of a 96-pixel frame of the whole volume
/// (the viewer's smallest moving frames), at least 2 voxels and at most the octree's leaf edge.
int previewSpacing(const glm::ivec3& dims, const glm::dvec3& spacing, int leafEdge);

/// The summary of @p scene, read from @p path and @p series, shown as @p name under @p key. A paged
/// scene's histogram reads its store a block at a time: every sample up to @p histogramSamples,
/// beyond them the samples at even positions.
SceneSummary summarizeScene(const Scene& scene, const std::string& key, const std::string& path, const std::string& series,
                            const std::string& name, uint64_t histogramSamples = kSummarySamples);

class ScenePool {
 public:
  using Clock = std::chrono::steady_clock;
  /// Reads a volume or scene file (path and DICOM series) and builds its octree, reporting to
  /// @p progress (which throws to stop it when no viewer waits for it any more).
  using Loader = std::function<Scene(const std::string& path, const std::string& series, const Progress* progress)>;
  /// A coarse scene of the same path and series, quick to make, to show while the loader reads
  /// (a PACS series being retrieved), or none when the loader will be quick enough.
  using Previewer = std::function<std::optional<Scene>(const std::string& path, const std::string& series, const Progress* progress)>;

  struct Options {
    Loader loader;
    Previewer previewer;  ///< may be empty: no previews
    uint64_t textureLimitBytes = 0;   ///< each scene's brick texture cache (0: no limit)
    uint64_t memoryBytes = 0;         ///< each paged scene's --memory (SceneRenderer::Options::memoryBytes)
    /// A scene no viewer shows is released this long after the last one left it (0: at once).
    std::chrono::milliseconds releaseAfter{10000};
    /// A scene of more samples than this draws a clustered preview of a surface first.
    uint64_t previewSamples = kPreviewSurfaceSamples;
  };

  /// A surface's state, told to the viewers that asked for it.
  enum class SurfaceState { Building, Ready, Failed };

  /// What the pool tells its owner (with the mutex held; a handler must not block or lock it).
  struct Events {
    /// The load @p viewer waits for progresses: @p task and its fraction done.
    std::function<void(uint64_t viewer, const std::string& key, const std::string& task, double fraction)> loading;
    /// @p viewer now shows @p summary's scene, or, with @p summary null, its load failed (@p error).
    std::function<void(uint64_t viewer, const std::string& key, const SceneSummary* summary, const std::string& error)> opened;
    /// The surface of @p iso that @p viewer asked for: building (@p task, @p fraction), ready or failed.
    std::function<void(uint64_t viewer, const std::string& key, float iso, SurfaceState state, const std::string& task, double fraction)> surface;
    /// There is work for collect() (a surface is built, a scene may be released).
    std::function<void()> wake;
  };

  ScenePool(std::mutex& mutex, Options options, Events events);
  /// Waits for the loader and builders (told to stop); releases every scene. Call it without the
  /// mutex held, on the render thread.
  ~ScenePool();
  ScenePool(const ScenePool&) = delete;
  ScenePool& operator=(const ScenePool&) = delete;

  /// Loads scene @p key now (@p path and @p series, called @p name), on the calling thread without
  /// the mutex held (a server's volume at start). @throw the loader's errors.
  const SceneSummary& preload(const std::string& key, const std::string& path, const std::string& series, const std::string& name);

  /// @p viewer asks to show scene @p key (read from @p path and @p series, called @p name): at once
  /// when it is open (Events::opened before returning), else when the loader has read it (the
  /// viewer keeps what it showed until then). A viewer's earlier open still loading is forgotten
  /// (its load stops when no other viewer waits for it). While a preview of the scene is open the
  /// viewer shows it and waits for the scene: Events::opened again, with the scene, when it is read
  /// (or without, when it fails: the preview is then closed).
  void open(uint64_t viewer, const std::string& key, const std::string& path, const std::string& series, const std::string& name);
  /// @p viewer is gone: what it showed and asked for is forgotten.
  void leave(uint64_t viewer);
  /// The summary of the scene @p viewer shows, or null.
  const SceneSummary* shown(uint64_t viewer) const;
  /// The summary of the open scene @p key, or null.
  const SceneSummary* summary(const std::string& key) const;
  /// The isovalues whose surfaces scene @p key holds, ready to draw.
  std::vector<float> readySurfaces(const std::string& key) const;

  /// What a frame of @p viewer draws (render thread).
  struct Frame {
    SceneRenderer* renderer = nullptr;  ///< null: the viewer shows no scene
    const SceneSummary* summary = nullptr;
    /// The surface to draw: the one asked for when ready or its clustered preview is, else the
    /// viewer's last one (if kept), else none. Frames draw it with Quality::waitForSurface false.
    std::optional<float> iso;
    bool surfaceReady = true;           ///< false while the surface asked for is being built at full resolution
    bool surfaceBuilding = false;       ///< the builder is at work on the surface asked for (its levels, once ready)
  };
  /// The scene @p viewer shows and the surface its frame draws when it asks for @p iso; starts
  /// building that surface when it is neither ready nor on its way.
  Frame forFrame(uint64_t viewer, std::optional<float> iso);

  /// Render thread: adopts the surfaces built since (returning the keys of the scenes that got
  /// one, whose viewers may want their last frame again), starts the builds waiting, and releases
  /// the scenes due (destroyed with @p lock released, then the heap trimmed).
  std::vector<std::string> collect(std::unique_lock<std::mutex>& lock);
  /// Whether collect() has something to do now.
  bool hasWork() const;
  /// When a scene will be due for release, if one will.
  std::optional<Clock::time_point> nextRelease() const;
  /// Scenes loaded (for logs and tests).
  size_t loaded() const { return mScenes.size(); }

  /// Keeps scene @p key open while the caller reads it without the mutex (an export); null when
  /// it is not open or is a preview. Every pin needs an unpin.
  const Scene* pin(const std::string& key);
  void unpin(const std::string& key);

 private:
  struct Entry;
  struct Load;
  struct Viewer {
    std::string key;              // the scene shown ("" before one is)
    std::string loading;          // the scene being loaded for it ("" none)
    std::optional<float> asked;   // the isovalue its last frame asked for
    std::optional<float> drawn;   // the one its last frame drew
  };
  void loaderLoop();
  /// Shows the preview of @p load's scene to its waiters, when the previewer makes one (mutex held).
  void preview(Load& load, const Progress& progress, std::unique_lock<std::mutex>& lock);
  /// @p viewer shows @p e from now on (a preview's viewer also waits for the scene), and is told.
  void show(uint64_t viewer, Entry& e);
  /// The open scene @p key is a preview replaced or closed: destroyed on the render thread (collect)
  /// once its builder has ended.
  void retire(const std::string& key);
  void startBuild(Entry& e, float iso);
  /// Whether the surface of @p iso has yet to be built, or its simplified levels.
  bool needsBuild(const Entry& e, float iso) const;
  void sendSurface(const Entry& e, float iso, SurfaceState state, const std::string& task, double fraction);
  void repin(Entry& e);
  void dropLoadWaiter(uint64_t viewer);
  std::unique_ptr<Entry> makeEntry(Scene scene, const std::string& key, const std::string& path, const std::string& series,
                                   const std::string& name) const;

  std::mutex& mMutex;
  Options mOptions;
  Events mEvents;
  std::map<std::string, std::unique_ptr<Entry>> mScenes;
  std::vector<std::unique_ptr<Entry>> mRetired;  // previews replaced, for collect() to destroy
  std::map<uint64_t, Viewer> mViewers;
  std::deque<std::unique_ptr<Load>> mLoads;  // waiting, then the one being read first
  std::condition_variable mLoadWake;
  bool mStopping = false;
  std::thread mLoader;
};

}  // namespace hyb
