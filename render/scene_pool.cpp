#include "render/scene_pool.h"

#include <malloc.h>

#include <algorithm>

#include "hybrid_octree/coarse_surface.h"
#include "render/patient_view.h"
#include "render/transfer_function.h"
#include "volume/core/error.h"

namespace hyb {

namespace {

// Thrown by a progress callback to stop a load or build that nobody waits for any more.
struct Cancelled {};

// Progress messages of one task go out at most this often (and at its start and end).
constexpr auto kProgressInterval = std::chrono::milliseconds(100);

}  // namespace

int previewSpacing(const glm::ivec3& dims, const glm::dvec3& spacing, int leafEdge) {
  const glm::dvec3 extent = glm::dvec3(dims) * spacing;
  const double extentMm = std::max({extent.x, extent.y, extent.z});
  return std::max(2, clusterSpacingFor(extentMm / 96.0, spacing, leafEdge));
}

SceneSummary summarizeScene(const Scene& scene, const std::string& key, const std::string& path, const std::string& series,
                            const std::string& name, uint64_t histogramSamples) {
  const Volume& v = scene.volume;
  SceneSummary s;
  s.key = key;
  s.path = path;
  s.series = series;
  s.name = name;
  s.dims = v.dims();
  s.spacing = v.spacing();
  s.minValue = v.minValue();
  s.maxValue = v.maxValue();
  const int spacing = v.voxelCount() > histogramSamples ? 2 : 1;
  const uint64_t count = spacing == 1 ? v.voxelCount() : [&] {
    const glm::ivec3 k = knotCounts(v.dims(), 2);
    return uint64_t(k.x) * uint64_t(k.y) * uint64_t(k.z);
  }();
  s.histogram = scene.knots ? computeHistogram(count, v.minValue(), v.maxValue(), 128,
                                               [&](const auto& use) { scene.knots->forEachValue(spacing, use); })
                            : computeHistogram(v, 128);
  s.orientation = orientationCode(v.frame().direction);
  s.orientationAssumed = v.frame().assumed;
  s.boundsLo = glm::dvec3(1e300);
  s.boundsHi = glm::dvec3(-1e300);
  const glm::dvec3 extent = v.extentMm();
  for (int c = 0; c < 8; ++c) {
    const glm::dvec3 p = v.frame().toPatient(glm::dvec3(c & 1 ? extent.x : 0, c & 2 ? extent.y : 0, c & 4 ? extent.z : 0));
    s.boundsLo = glm::min(s.boundsLo, p);
    s.boundsHi = glm::max(s.boundsHi, p);
  }
  std::vector<glm::dvec3> points =
      visiblePoints(v, scene.octree, TransferFunction::defaultFor(v.minValue(), v.maxValue()), std::nullopt, scene.knots.get());
  if (points.empty())  // nothing visible: the data's box
    for (int c = 0; c < 8; ++c) points.push_back(glm::dvec3(c & 1 ? s.boundsHi.x : s.boundsLo.x, c & 2 ? s.boundsHi.y : s.boundsLo.y, c & 4 ? s.boundsHi.z : s.boundsLo.z));
  scene.octree.releasePages();  // the fit walked every visible leaf; a frame reads far fewer
  for (int view = 0; view < 6; ++view) s.views[size_t(view)] = fitCamera(points, viewDirection(AnatomicalView(view)), {30.0, false, 512, 512});
  if (scene.surface) s.sceneIso = scene.surface->isovalue();
  return s;
}

// An open scene: its renderer, the surfaces on their way, and who holds it.
struct ScenePool::Entry {
  SceneSummary summary;
  std::unique_ptr<SceneRenderer> renderer;
  std::vector<float> ready;                // the renderer's surfaces (readable without touching it)
  std::deque<float> queued;                // isovalues asked for, waiting for the builder
  std::optional<float> building;
  std::thread builder;
  std::unique_ptr<PreparedSurface> built;  // handed over by the builder at its end: the simplified levels
  // Handed over before: a clustered preview, then the full-resolution surface (drawn meanwhile).
  std::vector<std::unique_ptr<PreparedSurface>> handed;
  bool buildDone = false;                  // the builder has ended (built is null when it failed or stopped)
  bool buildStopped = false;               // ... because no viewer wanted its surface any more
  std::vector<float> levelsFailed;         // surfaces whose simplified levels failed: not tried again
  Clock::time_point lastProgress{};
  bool repin = true;                       // the viewers' isovalues changed since the renderer was told
  int pins = 0;
  std::optional<Clock::time_point> unusedSince;  // no viewer has shown it since
  ~Entry() {
    if (builder.joinable()) builder.join();
  }
};

// A scene being read for the viewers waiting for it.
struct ScenePool::Load {
  std::string key, path, series, name;
  std::set<uint64_t> waiters;
  Clock::time_point lastProgress{};
};

ScenePool::ScenePool(std::mutex& mutex, Options options, Events events) : mMutex(mutex), mOptions(std::move(options)), mEvents(std::move(events)) {
  HYB_CHECK(mOptions.loader && mEvents.loading && mEvents.opened && mEvents.surface && mEvents.wake);
  mLoader = std::thread([this] { loaderLoop(); });
}

ScenePool::~ScenePool() {
  {
    const std::lock_guard<std::mutex> lock(mMutex);
    mStopping = true;  // a load or build in progress stops at its next progress report
  }
  mLoadWake.notify_all();
  if (mLoader.joinable()) mLoader.join();
  for (auto& [key, e] : mScenes)
    if (e->builder.joinable()) e->builder.join();
  for (auto& e : mRetired)
    if (e->builder.joinable()) e->builder.join();
  mScenes.clear();  // the renderers, on this (the render) thread
  mRetired.clear();
}

std::unique_ptr<ScenePool::Entry> ScenePool::makeEntry(Scene scene, const std::string& key, const std::string& path, const std::string& series,
                                                       const std::string& name) const {
  auto e = std::make_unique<Entry>();
  e->summary = summarizeScene(scene, key, path, series, name);
  SceneRenderer::Options ro;
  ro.textureLimitBytes = mOptions.textureLimitBytes;
  ro.memoryBytes = mOptions.memoryBytes;
  e->renderer = std::make_unique<SceneRenderer>(std::move(scene), ro);  // its OpenGL context comes with its first frame
  return e;
}

const SceneSummary& ScenePool::preload(const std::string& key, const std::string& path, const std::string& series, const std::string& name) {
  std::unique_ptr<Entry> e = makeEntry(mOptions.loader(path, series, nullptr), key, path, series, name);
  const std::lock_guard<std::mutex> lock(mMutex);
  e->unusedSince = Clock::now();
  return (mScenes[key] = std::move(e))->summary;
}

void ScenePool::dropLoadWaiter(uint64_t viewer) {
  for (const auto& load : mLoads) load->waiters.erase(viewer);  // a load left without waiters stops
  if (auto it = mViewers.find(viewer); it != mViewers.end()) it->second.loading.clear();
}

void ScenePool::open(uint64_t viewer, const std::string& key, const std::string& path, const std::string& series, const std::string& name) {
  dropLoadWaiter(viewer);
  Viewer& v = mViewers[viewer];
  if (const auto it = mScenes.find(key); it != mScenes.end()) {
    show(viewer, *it->second);
    mEvents.wake();  // (the scene it left may be due for release)
    if (!it->second->summary.preview) return;  // (a preview's viewer waits for the scene too)
  }
  v.loading = key;
  for (const auto& load : mLoads)
    if (load->key == key) {
      load->waiters.insert(viewer);
      return;
    }
  mLoads.push_back(std::make_unique<Load>(Load{key, path, series, name, {viewer}, {}}));
  mLoadWake.notify_all();
}

void ScenePool::leave(uint64_t viewer) {
  dropLoadWaiter(viewer);
  const auto it = mViewers.find(viewer);
  if (it == mViewers.end()) return;
  if (const auto e = mScenes.find(it->second.key); e != mScenes.end()) e->second->repin = true;
  mViewers.erase(it);
  mEvents.wake();
}

const SceneSummary* ScenePool::shown(uint64_t viewer) const {
  const auto v = mViewers.find(viewer);
  return v == mViewers.end() ? nullptr : summary(v->second.key);
}

const SceneSummary* ScenePool::summary(const std::string& key) const {
  const auto e = mScenes.find(key);
  return e == mScenes.end() ? nullptr : &e->second->summary;
}

std::vector<float> ScenePool::readySurfaces(const std::string& key) const {
  const auto e = mScenes.find(key);
  return e == mScenes.end() ? std::vector<float>{} : e->second->ready;
}

void ScenePool::loaderLoop() {
  std::unique_lock<std::mutex> lock(mMutex);
  for (;;) {
    mLoadWake.wait(lock, [&] { return mStopping || !mLoads.empty(); });
    if (mStopping) return;
    Load& load = *mLoads.front();  // stays in the queue while it is read, so that viewers can join it
    if (load.waiters.empty()) {
      mLoads.pop_front();
      continue;
    }
    const Progress progress([&](const std::string& task, double fraction) {
      const std::lock_guard<std::mutex> guard(mMutex);
      if (mStopping || load.waiters.empty()) throw Cancelled{};
      const auto now = Clock::now();
      if (fraction > 0.0 && fraction < 1.0 && now - load.lastProgress < kProgressInterval) return;
      load.lastProgress = now;
      for (const uint64_t viewer : load.waiters) mEvents.loading(viewer, load.key, task, fraction);
    });
    const std::string key = load.key, path = load.path, series = load.series, name = load.name;
    for (const uint64_t viewer : load.waiters) mEvents.loading(viewer, key, "reading", 0.0);
    std::unique_ptr<Entry> entry;
    std::string error;
    bool stopped = false;
    try {
      if (mOptions.previewer && !mScenes.count(key)) preview(load, progress, lock);
      lock.unlock();
      entry = makeEntry(mOptions.loader(path, series, &progress), key, path, series, name);
    } catch (const Cancelled&) {
      stopped = true;
    } catch (const std::exception& e) {
      error = e.what();
    }
    if (!lock.owns_lock()) lock.lock();
    const std::unique_ptr<Load> done = std::move(mLoads.front());
    mLoads.pop_front();
    if (mStopping) return;
    // The viewers waiting for it, and those shown its preview meanwhile.
    std::set<uint64_t> told = done->waiters;
    for (const auto& [id, v] : mViewers)
      if (v.key == key) told.insert(id);
    const bool previewed = mScenes.count(key) && mScenes[key]->summary.preview;
    if (!entry) {
      if (stopped) continue;  // (a preview stays, for a viewer that opens it again)
      if (previewed) retire(key);
      for (const uint64_t viewer : told) {
        Viewer& v = mViewers[viewer];
        if (v.key == key) v.key.clear();
        if (v.loading == key) v.loading.clear();
        mEvents.opened(viewer, key, nullptr, error);
      }
      continue;
    }
    if (previewed) retire(key);
    Entry& e = *(mScenes[key] = std::move(entry));
    for (const uint64_t viewer : told) show(viewer, e);
    if (told.empty()) e.unusedSince = Clock::now();
    mEvents.wake();
  }
}

void ScenePool::preview(Load& load, const Progress& progress, std::unique_lock<std::mutex>& lock) {
  lock.unlock();
  std::unique_ptr<Entry> entry;
  try {
    if (std::optional<Scene> scene = mOptions.previewer(load.path, load.series, &progress)) {
      entry = makeEntry(std::move(*scene), load.key, load.path, load.series, load.name);
      entry->summary.preview = true;
    }
  } catch (const Cancelled&) {
    throw;
  } catch (const std::exception&) {
    // (no preview: the load itself says what is wrong with the series, if anything)
  }
  lock.lock();
  if (!entry || mStopping || load.waiters.empty() || mScenes.count(load.key)) return;
  Entry& e = *(mScenes[load.key] = std::move(entry));
  for (const uint64_t viewer : load.waiters) show(viewer, e);
  mEvents.wake();
}

void ScenePool::show(uint64_t viewer, Entry& e) {
  Viewer& v = mViewers[viewer];
  if (const auto left = mScenes.find(v.key); left != mScenes.end() && left->second.get() != &e) left->second->repin = true;
  const std::string& key = e.summary.key;
  v = Viewer{key, e.summary.preview ? key : "", std::nullopt, std::nullopt};
  e.unusedSince.reset();
  e.repin = true;
  mEvents.opened(viewer, key, &e.summary, "");
}

void ScenePool::retire(const std::string& key) {
  const auto it = mScenes.find(key);
  mRetired.push_back(std::move(it->second));
  mScenes.erase(it);
  mEvents.wake();
}

void ScenePool::sendSurface(const Entry& e, float iso, SurfaceState state, const std::string& task, double fraction) {
  for (const auto& [id, v] : mViewers)
    if (v.key == e.summary.key && v.asked == iso) mEvents.surface(id, e.summary.key, iso, state, task, fraction);
}

void ScenePool::startBuild(Entry& e, float iso) {
  if (e.builder.joinable()) e.builder.join();  // (ended: its result was collected)
  e.building = iso;
  e.buildDone = e.buildStopped = false;
  e.lastProgress = Clock::now();
  if (!e.renderer->hasSurface(iso)) sendSurface(e, iso, SurfaceState::Building, "surface", 0.0);
  const bool preview = !e.renderer->hasAnySurface(iso);  // (not again after a build that stopped)
  // The full-resolution surface kept from a build that stopped before its simplified levels: only
  // they are left to make (shared: the renderer may let go of it while the builder reads).
  e.builder = std::thread([this, &e, iso, preview, smooth = e.renderer->unsimplified(iso)]() mutable {
    const std::string key = e.summary.key;
    auto wanted = [&] {
      const auto current = mScenes.find(key);  // (not a preview replaced meanwhile)
      return current != mScenes.end() && current->second.get() == &e &&
             std::any_of(mViewers.begin(), mViewers.end(), [&](const auto& v) { return v.second.key == key && v.second.asked == iso; });
    };
    bool ready = smooth != nullptr;  // the full-resolution surface is the renderer's: frames draw it
    const Progress progress([&](const std::string& task, double fraction) {
      const std::lock_guard<std::mutex> guard(mMutex);
      if (mStopping || !wanted()) throw Cancelled{};
      if (ready) return;  // (the viewers were told it is ready; the levels are for moving frames)
      const auto now = Clock::now();
      if (fraction > 0.0 && fraction < 1.0 && now - e.lastProgress < kProgressInterval) return;
      e.lastProgress = now;
      sendSurface(e, iso, SurfaceState::Building, task, fraction);
    });
    std::unique_ptr<PreparedSurface> s;
    bool stopped = false;
    auto hand = [&](std::unique_ptr<PreparedSurface> made) {
      e.renderer->holdSurfaceBytes(made->bytesUsed());  // until adopted (collect)
      const std::lock_guard<std::mutex> guard(mMutex);
      e.handed.push_back(std::move(made));
      mEvents.wake();
    };
    try {
      // Only reads the scene: the render thread keeps drawing with the renderer meanwhile. A large
      // scene's frames draw a clustered surface first, made in a fraction of the time; the final
      // frames draw the full-resolution one while its simplified levels are made.
      const Scene& scene = e.renderer->scene();
      if (!smooth) {
        if (preview && scene.volume.voxelCount() > mOptions.previewSamples) {
          const int cubes = previewSpacing(scene.volume.dims(), scene.volume.spacing(), scene.octree.leafEdge());
          const VolumeKnots inMemory(scene.volume, scene.octree);  // (read only when the scene is not paged)
          const KnotSource& knots = scene.knots ? static_cast<const KnotSource&>(*scene.knots) : inMemory;
          // First the knots' Marching Cubes (a fraction of a second), then the clustered surface in its place.
          for (const bool quick : {true, false}) {
            auto made = std::make_unique<PreparedSurface>();
            made->iso = iso;
            made->coarse.emplace(cubes, quick ? knotSurface(knots, cubes, iso) : clusteredSurface(knots, scene.octree, cubes, iso, &progress));
            hand(std::move(made));
          }
        }
        std::unique_ptr<PreparedSurface> exact = SceneRenderer::prepareSurface(scene, iso, &progress, nullptr, e.renderer->surfaceReservation());
        smooth = exact->smooth;  // shared, not copied
        hand(std::move(exact));
        ready = true;
      }
      s = std::make_unique<PreparedSurface>();
      s->iso = iso;
      s->simplified = SceneRenderer::simplifiedLevels(scene, *smooth, &progress, e.renderer->surfaceReservation());
      e.renderer->holdSurfaceBytes(s->bytesUsed());  // until adopted (collect)
    } catch (const Cancelled&) {
      stopped = true;
    } catch (const std::exception&) {
    }
    const std::lock_guard<std::mutex> guard(mMutex);
    e.built = std::move(s);
    e.buildDone = true;
    e.buildStopped = stopped;
    mEvents.wake();
  });
}

ScenePool::Frame ScenePool::forFrame(uint64_t viewer, std::optional<float> iso) {
  const auto it = mViewers.find(viewer);
  if (it == mViewers.end() || !mScenes.count(it->second.key)) return {};
  Viewer& v = it->second;
  Entry& e = *mScenes[v.key];
  Frame f{e.renderer.get(), &e.summary, std::nullopt, true};
  if (v.asked != iso) e.repin = true;
  v.asked = iso;
  if (iso && e.renderer->hasSurface(*iso)) {
    v.drawn = iso;
  } else if (iso) {
    f.surfaceReady = false;
    if (e.renderer->hasAnySurface(*iso))
      v.drawn = iso;  // its clustered preview
    else if (!(v.drawn && e.renderer->hasAnySurface(*v.drawn)))
      v.drawn.reset();  // the one drawn before, while it is kept; never another's
  } else {
    v.drawn.reset();
  }
  if (iso && needsBuild(e, *iso) && e.building != iso && std::find(e.queued.begin(), e.queued.end(), *iso) == e.queued.end()) {
    if (!e.building) {
      startBuild(e, *iso);
    } else {
      e.queued.push_back(*iso);
      if (!f.surfaceReady) sendSurface(e, *iso, SurfaceState::Building, "waiting", 0.0);
    }
  }
  f.iso = v.drawn;
  f.surfaceBuilding = iso && e.building == iso;
  if (e.repin) repin(e);
  return f;
}

bool ScenePool::needsBuild(const Entry& e, float iso) const {
  if (!e.renderer->hasSurface(iso)) return true;
  return e.renderer->unsimplified(iso) && std::find(e.levelsFailed.begin(), e.levelsFailed.end(), iso) == e.levelsFailed.end();
}

void ScenePool::repin(Entry& e) {
  std::vector<float> isos;
  for (const auto& [id, v] : mViewers)
    if (v.key == e.summary.key)
      for (const std::optional<float>& iso : {v.asked, v.drawn})
        if (iso) isos.push_back(*iso);
  e.renderer->pinSurfaces(std::move(isos));
  e.ready.clear();
  for (const float iso : e.renderer->surfaceIsos())
    if (e.renderer->hasSurface(iso)) e.ready.push_back(iso);
  e.repin = false;
}

bool ScenePool::hasWork() const {
  const auto now = Clock::now();
  if (std::any_of(mRetired.begin(), mRetired.end(), [](const auto& e) { return !e->builder.joinable() || e->buildDone; })) return true;
  for (const auto& [key, e] : mScenes)
    if (e->buildDone || !e->handed.empty() || e->repin) return true;
  const std::optional<Clock::time_point> due = nextRelease();
  return due && *due <= now;
}

std::optional<ScenePool::Clock::time_point> ScenePool::nextRelease() const {
  std::optional<Clock::time_point> next;
  for (const auto& scene : mScenes) {
    const std::string& key = scene.first;  // (not a structured binding: clang 14 cannot capture one)
    const auto& e = scene.second;
    const bool shown = std::any_of(mViewers.begin(), mViewers.end(), [&](const auto& v) { return v.second.key == key; });
    if (shown || e->pins > 0 || e->building) continue;
    const Clock::time_point due = e->unusedSince.value_or(Clock::now()) + mOptions.releaseAfter;
    if (!next || due < *next) next = due;
  }
  return next;
}

std::vector<std::string> ScenePool::collect(std::unique_lock<std::mutex>& lock) {
  std::vector<std::string> changed;
  const auto now = Clock::now();
  std::vector<std::unique_ptr<Entry>> gone;
  for (auto it = mScenes.begin(); it != mScenes.end();) {
    Entry& e = *it->second;
    for (std::unique_ptr<PreparedSurface>& made : e.handed) {
      const bool exact = made->exact;
      const float iso = made->iso;
      e.renderer->releaseSurfaceBytes(made->bytesUsed());  // (counted as kept from now on)
      e.renderer->adoptSurface(std::move(made));
      e.repin = true;
      if (exact) sendSurface(e, iso, SurfaceState::Ready, "", 1.0);
      changed.push_back(it->first);
    }
    e.handed.clear();
    if (e.buildDone) {
      e.builder.join();
      const float iso = *e.building;
      e.building.reset();
      e.buildDone = false;
      if (e.built) e.renderer->releaseSurfaceBytes(e.built->bytesUsed());
      if (e.built && e.renderer->hasSurface(iso)) {  // (not when the surface was dropped meanwhile)
        e.renderer->adoptSurface(std::move(e.built));  // (the final frames' surface is the same: no frame again)
        sendSurface(e, iso, SurfaceState::Ready, "", 1.0);  // (again: the viewers may say it was being simplified)
      } else if (!e.built && !e.buildStopped) {
        if (!e.renderer->hasSurface(iso))
          sendSurface(e, iso, SurfaceState::Failed, "", 0.0);
        else
          e.levelsFailed.push_back(iso);  // (moving frames draw the preview or the full surface instead)
      }
      // The next isovalue still asked for.
      while (!e.queued.empty() && !e.building) {
        const float next = e.queued.front();
        e.queued.pop_front();
        const bool asked = std::any_of(mViewers.begin(), mViewers.end(), [&](const auto& v) { return v.second.key == it->first && v.second.asked == next; });
        if (asked && needsBuild(e, next)) startBuild(e, next);
      }
    }
    if (e.repin) repin(e);
    const bool shown = std::any_of(mViewers.begin(), mViewers.end(), [&](const auto& v) { return v.second.key == it->first; });
    if (shown) {
      e.unusedSince.reset();
    } else if (!e.unusedSince) {
      e.unusedSince = now;
    }
    if (!shown && e.pins == 0 && !e.building && now - *e.unusedSince >= mOptions.releaseAfter) {
      gone.push_back(std::move(it->second));
      it = mScenes.erase(it);
    } else {
      ++it;
    }
  }
  for (auto it = mRetired.begin(); it != mRetired.end();) {
    if ((*it)->builder.joinable() && !(*it)->buildDone) {
      ++it;
      continue;
    }
    gone.push_back(std::move(*it));
    it = mRetired.erase(it);
  }
  if (!gone.empty()) {
    // Its renderer's OpenGL context is this thread's; the memory it held goes back to the system.
    lock.unlock();
    gone.clear();
    malloc_trim(0);
    lock.lock();
  }
  return changed;
}

const Scene* ScenePool::pin(const std::string& key) {
  const auto e = mScenes.find(key);
  if (e == mScenes.end() || e->second->summary.preview) return nullptr;  // (a preview is replaced, pinned or not)
  ++e->second->pins;
  return &e->second->renderer->scene();
}

void ScenePool::unpin(const std::string& key) {
  const auto e = mScenes.find(key);
  HYB_CHECK(e != mScenes.end() && e->second->pins > 0);
  if (--e->second->pins == 0) mEvents.wake();
}

}  // namespace hyb
