#include "apps/viewer/viewer_server.h"

#include <turbojpeg.h>

#include <boost/asio.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/websocket.hpp>
#include <nlohmann/json.hpp>

#include <atomic>
#include <charconv>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <deque>
#include <fstream>
#include <iomanip>
#include <list>
#include <map>
#include <mutex>
#include <set>
#include <sstream>
#include <thread>

#include "apps/viewer/viewer_files.h"
#include "apps/viewer/viewer_protocol.h"
#include "apps/viewer/viewer_quality.h"
#include "hybrid_octree/surface_export.h"
#include "render/patient_view.h"
#include "render/scene_pool.h"
#include "render/scene_renderer.h"
#include "surface/mesh_io.h"
#include "surface/mesh_ops.h"
#include "volume/core/error.h"
#include "volume/core/file_util.h"

namespace hyb::viewer {

namespace net = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
using tcp = net::ip::tcp;
using nlohmann::json;
using Clock = std::chrono::steady_clock;

// Frames before the final one draw the surface simplified, its finest level within blocks of this edge: with
// bricks no smaller, each of its triangles lies inside one brick and is drawn in the right order (coarser
// levels, drawn where pixels are larger than their error, are placed by their triangles' centroids).
static_assert(kInteractiveBrickEdge == kSimplifiedBlockVoxels);

namespace {

double msSince(Clock::time_point t0) { return std::chrono::duration<double, std::milli>(Clock::now() - t0).count(); }
// Wall-clock milliseconds since the epoch: the page compares them with its own clock (same machine)
// to tell the time a message spends between the two.
double epochMs() { return std::chrono::duration<double, std::milli>(std::chrono::system_clock::now().time_since_epoch()).count(); }

std::vector<uint8_t> encodeJpeg(const std::vector<uint8_t>& rgba, int width, int height, int quality) {
  tjhandle tj = tjInitCompress();
  if (!tj) HYB_THROW(RuntimeError, "JPEG encoder: ", tjGetErrorStr());
  unsigned char* buffer = nullptr;
  unsigned long bytes = 0;
  // Full chroma: interactive frames are small and shown magnified, where 4:2:0 costs 0.1-0.2 dB.
  const int status = tjCompress2(tj, rgba.data(), width, 0, height, TJPF_RGBA, &buffer, &bytes, TJSAMP_444, quality, TJFLAG_FASTDCT);
  std::vector<uint8_t> out;
  if (status == 0) out.assign(buffer, buffer + bytes);
  tjFree(buffer);
  tjDestroy(tj);
  if (status != 0) HYB_THROW(RuntimeError, "JPEG encoding failed");
  return out;
}

json vec3Json(const glm::dvec3& v) { return json::array({v.x, v.y, v.z}); }

// The camera in the frame table's fields (eye, center, up, fov, ortho, ortho_height, size).
json cameraToJson(const Camera& c) { return settingsJson(cameraSettings(c), kViewer, isCameraField); }

// The `hybrid-octree render` command line that makes the same image (the transfer function's
// points in the file @p tfFile when they are not a preset).
std::string renderCommand(const std::string& path, const std::string& series, const FrameRequest& r, const std::string& tfFile) {
  FrameSettings s = r.settings;
  if (!s.tfPoints.empty()) {
    s.tfPoints.clear();
    s.tf = tfFile;
  }
  if (!s.iso) s.surfaceColor = kDefaultSurfaceColor;  // (no surface: its colour says nothing)
  std::string cmd = "hybrid-octree render " + shellQuote(path);
  if (!series.empty()) cmd += " --series " + shellQuote(series);
  return cmd + commandLineOf(s) + " -o view.png";
}

// The transfer function's points as a --tf file.
std::string tfText(const std::vector<TransferFunction::Point>& points) {
  std::ostringstream s;
  s << "# value r g b a (opacity of 1 mm)\n" << std::setprecision(9);
  for (const TransferFunction::Point& p : points) s << p.value << " " << p.color.r << " " << p.color.g << " " << p.color.b << " " << p.alpha << "\n";
  return s.str();
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// A client: what its page asked for last, and how well its frames are made. Shared by its socket
// (network thread) and the render thread, under the server's mutex.

// When a frame's request came from the page: its wait for the render thread, and its arrival's
// wall clock.
struct Arrival {
  double waitMs = 0.0, epochMs = 0.0;
};

// A final frame larger than kBandPixels is drawn band by band, other clients' frames between its
// bands, so that it holds the render thread for one band at a time (the pixels are the whole
// frame's: SlicesOptions::rows).
inline constexpr int kBandPixels = 512 * 512;

// What a frame shows of its scene's surfaces (ScenePool::Frame): the isovalue drawn, whether the
// one asked for is ready, whether the builder is at work on it.
struct SurfaceShown {
  std::optional<float> iso;
  bool ready = true, building = false;
  explicit SurfaceShown(const ScenePool::Frame& f) : iso(f.iso), ready(f.surfaceReady), building(f.surfaceBuilding) {}
  /// The surface a frame of @p r draws: none when it asks for none.
  std::optional<float> drawn(const FrameRequest& r) const { return r.settings.iso ? iso : std::nullopt; }
};

// A frame message's header: the request it answers, the ladder's level it was drawn at, the
// surface shown, when the request came, and the frame's counts and times.
struct FrameHeader {
  const SceneSummary& scene;
  const FrameRequest& r;
  const QualityLevel& q;
  int level = 0;
  bool final = false;
  const SurfaceShown& surface;
  const std::optional<Arrival>& arrival;
  const FrameStats& st;
  double maxError = 0, renderMs = 0;

  /// The header as the page reads it (type "frame"), of an image @p width x @p height encoded in @p encodeMs.
  json toJson(int width, int height, double encodeMs) const {
    const std::optional<float> iso = surface.drawn(r);
    json header = {{"type", "frame"},
                   {"scene", scene.key},
                   {"seq", r.seq},
                   {"quality", r.interacting ? "interactive" : final ? "final" : "refining"},
                   {"level", level},
                   {"ladder", iso ? "surface" : "volume"},
                   {"levelText", q.describe()},
                   {"format", final ? "png" : "jpeg"},
                   {"width", width},
                   {"height", height},
                   {"waitMs", arrival ? json(arrival->waitMs) : json(nullptr)},
                   {"requestEpochMs", arrival ? json(arrival->epochMs) : json(nullptr)},
                   {"sentEpochMs", epochMs()},
                   {"renderMs", renderMs},
                   {"encodeMs", encodeMs},
                   {"textureBytes", st.slices.textureBytes},
                   {"bricks", st.slices.bricks},
                   {"maxError", maxError},
                   {"bricksNotResident", st.bricksNotResident},  // > 0: bricks drawn coarser (beyond the packing bound, or loading)
                   {"iso", iso ? json(*iso) : json(nullptr)},
                   {"surfaceReady", !r.settings.iso || surface.ready},  // false: the surface asked for is still being built
                   // > 1: the surface drawn is clustered by cubes this many voxels wide (a preview, or the level of detail)
                   {"surfaceSpacing", iso ? json(st.surfaceSpacing) : json(nullptr)},
                   {"surfaceBuilding", surface.building},  // the surface asked for, or its levels for moving frames, on its way
                   {"camera", cameraToJson(explicitCamera(r.settings))}};
    if (final && (!r.settings.iso || surface.ready)) {  // (while the surface asked for is built, the frame is not the command's)
      header["command"] = renderCommand(scene.path, scene.series, r, "view.tf");
      if (!r.settings.tfPoints.empty()) header["tfText"] = tfText(r.settings.tfPoints);
    }
    return header;
  }
};

struct BandedFrame {
  BandedFrame(FrameRequest r, const SurfaceShown& s) : request(std::move(r)), surface(s) {}
  FrameRequest request;
  SurfaceShown surface;
  std::optional<Arrival> arrival;
  Image image;
  int next = 0;           // the first row not drawn yet
  int rowsPerBand = 0;
  double renderMs = 0.0;  // the bands' render times so far
  FrameStats stats;       // the last band's
  double maxError = 0.0;
};

struct Client {
  uint64_t id = 0;
  std::string sceneKey;                 // the scene its frames are of; empty before one is open
  std::optional<FrameRequest> pending;  // the newest request not yet rendered
  std::optional<Clock::time_point> pendingSince;  // when the page sent it (none: the server asks again)
  double pendingEpochMs = 0.0;          // the same, wall clock
  std::optional<FrameRequest> current;  // the request being refined
  std::vector<int> refine;              // levels still to render for it, next last
  bool refineSurface = false;           // ... of the surface's ladder
  std::optional<BandedFrame> banded;    // its final frame, part drawn
  AdaptiveQuality volumeQuality, surfaceQuality, surfaceRayQuality;
  bool raysForSurface = false;  // the surface's ladder ray-traces small frames (surfaceRaysFit)
  std::atomic<bool> open{true};
  std::function<void(std::string message, bool binary)> send;  // posts to the socket; drops when closed
  explicit Client(double targetMs)
      : volumeQuality(kVolumeLadder, targetMs), surfaceQuality(kSurfaceLadder, targetMs), surfaceRayQuality(kSurfaceRayLadder, targetMs) {}
  // The ladder of frames with a surface or without: they cost and lose accuracy differently.
  AdaptiveQuality& quality(bool surface) { return surface ? (raysForSurface ? surfaceRayQuality : surfaceQuality) : volumeQuality; }
  bool hasWork() const { return open && !sceneKey.empty() && (pending || !refine.empty() || banded); }
  // A new scene: nothing of the last one's requests, refinement or measured times applies to it.
  void showScene(const std::string& key) {
    sceneKey = key;
    pending.reset();
    current.reset();
    refine.clear();
    banded.reset();
    volumeQuality.reset();
    surfaceQuality.reset();
    surfaceRayQuality.reset();
  }
};

struct ServerState {
  ServerOptions options;
  std::string token;
  net::io_context io{1};
  tcp::acceptor acceptor{io};
  std::thread netThread, renderThread, exportThread;
  std::atomic<bool> stopping{false};
  bool started = false;
  bool othersStopped = false;  // the network and export threads have ended (under the mutex)

  // Work shared by the threads, and the pool's state: under this mutex.
  std::mutex mutex;
  std::condition_variable wake;
  std::map<uint64_t, std::shared_ptr<Client>> clients;
  std::unique_ptr<ScenePool> pool;
  std::string defaultScene;  // the --volume scene's key, or empty
  struct Export {
    std::string sceneKey;
    float iso;
    std::string format;
    std::function<void(std::string body, std::string error)> reply;
  };
  std::deque<Export> exports;
  uint64_t nextClient = 1;
  std::vector<DataEntry> listing;  // the data directory's volumes, listed at start
  std::string dataRoot;            // the data directory, every link resolved ("" without one)

  void log(const std::string& line) {
    if (options.log) *options.log << "view     " << line << std::endl;
  }

  static std::string keyOf(const std::string& path, const std::string& series) { return series.empty() ? path : path + "#" + series; }

  void send(uint64_t viewer, const std::string& message) {
    if (const auto c = clients.find(viewer); c != clients.end()) c->second->send(message, false);
  }

  // ---- what the page is told -----------------------------------------------------------------

  // What the page's menu calls scene @p key (a DICOM series by its directory, modality, slices and
  // description, not its UID); the key itself when the listing has no such entry.
  std::string labelOf(const std::string& key) const {
    for (const DataEntry& e : listing)
      if (keyOf(e.path, e.series) == key) return e.label;
    return key;
  }

  // @p text with the data directory's own path left out of the paths it names (the page knows
  // its volumes by their paths in that directory).
  std::string inDataDirTerms(std::string text) const {
    if (dataRoot.empty()) return text;
    const std::string prefix = dataRoot + "/";
    for (size_t at = text.find(prefix); at != std::string::npos; at = text.find(prefix, at)) text.erase(at, prefix.size());
    return text;
  }

  json volumesJson() const {
    json list = json::array();
    for (const DataEntry& e : listing) list.push_back({{"path", e.path}, {"series", e.series}, {"label", e.label}});
    return list;
  }

  json infoJson(const SceneSummary& s) const {
    json views = json::object();
    const char* names[] = {"anterior", "posterior", "left", "right", "superior", "inferior"};
    for (int v = 0; v < 6; ++v) views[names[v]] = cameraToJson(s.views[size_t(v)]);
    const Histogram& h = s.histogram;
    json presets = json::object();
    auto pointsJson = [](const TransferFunction& tf) {
      json pts = json::array();
      for (const TransferFunction::Point& q : tf.points()) pts.push_back(json::array({q.value, q.color.r, q.color.g, q.color.b, q.alpha}));
      return pts;
    };
    for (const std::string& p : TransferFunction::presetNames()) presets[p] = pointsJson(TransferFunction::preset(p));
    const json defaultTf = pointsJson(TransferFunction::defaultFor(s.minValue, s.maxValue));
    json info = {{"type", "info"},
                 {"scene", s.key},
                 {"name", s.name},
                 {"dims", json::array({s.dims.x, s.dims.y, s.dims.z})},
                 {"spacing", vec3Json(s.spacing)},
                 {"range", json::array({s.minValue, s.maxValue})},
                 {"histogram", {{"min", h.minValue}, {"max", h.maxValue}, {"counts", h.counts}}},
                 {"orientation", s.orientation},
                 {"orientationAssumed", s.orientationAssumed},
                 {"bounds", {{"min", vec3Json(s.boundsLo)}, {"max", vec3Json(s.boundsHi)}}},
                 {"center", vec3Json(0.5 * (s.boundsLo + s.boundsHi))},
                 {"views", views},
                 {"presets", presets},
                 {"defaultPreset", TransferFunction::defaultPresetFor(s.minValue, s.maxValue)},
                 {"defaultTf", defaultTf},
                 {"iso", s.sceneIso ? json(*s.sceneIso) : json(nullptr)},
                 {"defaultIso", TransferFunction::defaultIsoFor(s.minValue, s.maxValue)},
                 {"surfaces", pool->readySurfaces(s.key)},
                 {"volumes", volumesJson()},
                 {"fields", fieldsJson(kViewer)}};  // what a frame message takes: the page's controls' ranges
    if (!options.dataDir.empty()) info["open"] = {{"path", s.name}, {"series", s.series}};
    return info;
  }

  // The pool's events: each goes to the client it concerns only (under the mutex).
  ScenePool::Events poolEvents() {
    ScenePool::Events e;
    e.loading = [this](uint64_t viewer, const std::string& key, const std::string& task, double fraction) {
      send(viewer, json{{"type", "loading"}, {"scene", key}, {"task", task}, {"progress", fraction}}.dump());
    };
    e.opened = [this](uint64_t viewer, const std::string& key, const SceneSummary* summary, const std::string& error) {
      const auto c = clients.find(viewer);
      if (c == clients.end()) return;
      if (!summary) {
        json m = json::parse(errorMessage("cannot open " + labelOf(key) + ": " + inDataDirTerms(error)));
        m["scene"] = key;
        c->second->send(m.dump(-1, ' ', false, json::error_handler_t::replace), false);
        return;
      }
      c->second->showScene(key);
      c->second->send(infoJson(*summary).dump(-1, ' ', false, json::error_handler_t::replace), false);
    };
    e.surface = [this](uint64_t viewer, const std::string& key, float iso, ScenePool::SurfaceState state, const std::string& task, double fraction) {
      const char* name = state == ScenePool::SurfaceState::Building ? "building" : state == ScenePool::SurfaceState::Ready ? "ready" : "failed";
      json m = {{"type", "surface"}, {"scene", key}, {"iso", iso}, {"state", name}};
      if (state == ScenePool::SurfaceState::Building) m["task"] = task, m["progress"] = fraction;
      send(viewer, m.dump());
    };
    e.wake = [this] { wake.notify_all(); };
    return e;
  }

  // ---- rendering ----------------------------------------------------------------------------

  // Clients showing scene @p key refine again (a surface they asked for may have come).
  void refineAgain(const std::string& key) {
    for (const auto& [id, c] : clients)
      if (c->sceneKey == key && c->current && !c->pending) {
        c->pending = c->current;
        c->pending->interacting = false;
        c->pendingSince.reset();
      }
  }

  void renderLoop() {
    std::unique_lock<std::mutex> lock(mutex);
    size_t turn = 0;
    auto ready = [&] {
      if (stopping || pool->hasWork()) return true;
      for (const auto& [id, c] : clients)
        if (c->hasWork()) return true;
      return false;
    };
    while (!stopping) {
      if (const std::optional<ScenePool::Clock::time_point> due = pool->nextRelease())
        wake.wait_until(lock, *due, ready);
      else
        wake.wait(lock, ready);
      if (stopping) break;
      for (const std::string& key : pool->collect(lock)) refineAgain(key);
      // The clients with work, in turn: a large final frame gives way between its bands.
      std::vector<std::shared_ptr<Client>> waiting;
      for (const auto& [id, c] : clients)
        if (c->hasWork()) waiting.push_back(c);
      if (!waiting.empty()) serve(*waiting[turn++ % waiting.size()], lock);
    }
    // The renderers' OpenGL contexts are this thread's: destroyed here once the network and export
    // threads, which use the pool, have ended, and without the mutex (the pool's threads still want
    // it while they stop).
    wake.wait(lock, [&] { return othersStopped; });
    std::unique_ptr<ScenePool> gone = std::move(pool);
    lock.unlock();
    gone.reset();
  }

  // One step of @p client's work: its newest request's first frame, the next refinement, or the
  // next band of its final frame (called and returning with @p lock held; unlocked to render).
  void serve(Client& client, std::unique_lock<std::mutex>& lock) {
    int level = 0;
    std::optional<Arrival> arrival;
    bool surface = client.refineSurface;
    if (client.pending) {
      if (client.pendingSince) arrival = Arrival{msSince(*client.pendingSince), client.pendingEpochMs};
      client.pendingSince.reset();
      client.current = std::move(client.pending);
      client.pending.reset();
      client.banded.reset();
      client.refine.clear();
      const FrameRequest& r = *client.current;
      if (!r.scene.empty() && r.scene != client.sceneKey) {  // asked of the scene shown before this one
        client.current.reset();
        return;
      }
      const ScenePool::Frame shown = pool->forFrame(client.id, r.iso());
      surface = shown.iso.has_value();
      // (once the full surface is ready: the ray tracer draws no preview, it would build it here)
      client.raysForSurface =
          shown.renderer && shown.surfaceReady && surfaceRaysFit(shown.renderer->volume().dims(), shown.renderer->volume().spacing());
      AdaptiveQuality& quality = client.quality(surface);
      if (r.interacting) {
        level = quality.chooseInteractiveLevel();
      } else {
        client.refine = quality.refinement();
        client.refineSurface = surface;
        std::reverse(client.refine.begin(), client.refine.end());
        level = client.refine.back();
        client.refine.pop_back();
      }
    } else if (!client.banded) {
      level = client.refine.back();
      client.refine.pop_back();
    }
    const ScenePool::Frame scene = pool->forFrame(client.id, client.current->iso());
    if (!scene.renderer) {
      client.refine.clear();
      client.banded.reset();
      return;
    }
    const FrameRequest request = client.banded ? client.banded->request : *client.current;
    const bool final = !request.interacting && client.refine.empty() && level == 0;
    const glm::ivec2 size = request.size();
    if (final && !client.banded && int64_t(size.x) * size.y > kBandPixels) {
      BandedFrame b(request, SurfaceShown(scene));
      b.arrival = arrival;
      b.image = Image(size.x, size.y);
      b.rowsPerBand = std::max(16, kBandPixels / size.x);
      client.banded = std::move(b);
    }
    if (client.banded) {
      serveBand(client, *scene.renderer, *scene.summary, lock);
      return;
    }
    const QualityLevel& rung = client.quality(surface).ladder()[size_t(level)];
    const SurfaceShown shown(scene);
    const std::optional<float> iso = shown.drawn(request);
    const SceneSummary summary = *scene.summary;
    lock.unlock();
    std::string message;
    double ms = 0.0;
    bool cold = false;
    double coarser = 0.0;  // share of the bricks drawn coarser
    try {
      const auto t0 = Clock::now();
      const FrameParts parts = frameParts(request, scene.renderer->scene(), rung, level, iso);
      const RenderedFrame frame = scene.renderer->render(parts.view, parts.look, parts.quality);
      const double renderMs = msSince(t0);
      const FrameStats& st = frame.stats;
      // (also a ray-traced frame that made the surface's BVH, or one that made a pre-integration table)
      cold = 2 * st.slices.uploadedBricks > st.slices.bricks || st.bvhMs > 0.0 || st.preintegrationMs > 0.0;
      coarser = double(st.bricksNotResident) / double(std::max<size_t>(1, st.slices.bricks + st.bricksNotResident));
      const FrameHeader header{summary, request, rung, level, final, shown, arrival, st, frame.selection.maxError, renderMs};
      message = encodeFrame(header, frame.image, t0, &ms);
    } catch (const std::exception& e) {
      message.clear();
      client.send(errorMessage(e.what(), request.seq), false);
    }
    lock.lock();
    if (!message.empty()) {  // (a failed frame's time says nothing of its level)
      client.quality(surface).record(level, ms, cold, coarser);
      client.send(std::move(message), true);
    }
  }

  // The next band of @p client's final frame; the frame goes out with its last.
  void serveBand(Client& client, SceneRenderer& renderer, const SceneSummary& scene, std::unique_lock<std::mutex>& lock) {
    BandedFrame& b = *client.banded;
    const glm::ivec2 rows(b.next, std::min(b.next + b.rowsPerBand, b.image.height));
    const QualityLevel& rung = client.quality(b.surface.iso.has_value()).ladder()[0];
    const FrameRequest request = b.request;
    const std::optional<float> iso = b.surface.drawn(request);
    const SceneSummary summary = scene;
    lock.unlock();
    std::string message, error;
    RenderedFrame frame;
    const auto t0 = Clock::now();
    try {
      FrameParts parts = frameParts(request, renderer.scene(), rung, 0, iso);
      parts.quality.rows = rows;
      frame = renderer.render(parts.view, parts.look, parts.quality);
    } catch (const std::exception& e) {
      error = e.what();
    }
    const double ms = msSince(t0);
    lock.lock();
    if (!client.banded || client.banded->request.seq != request.seq) return;  // replaced meanwhile
    if (!error.empty()) {
      client.banded.reset();
      client.send(errorMessage(error, request.seq), false);
      return;
    }
    for (int y = rows.x; y < rows.y; ++y)
      std::copy_n(&frame.image.at(0, y), b.image.width, &b.image.at(0, y));
    b.renderMs += ms;
    b.stats = frame.stats;
    b.maxError = std::max(b.maxError, double(frame.selection.maxError));
    b.next = rows.y;
    if (b.next < b.image.height) return;
    BandedFrame done = std::move(b);
    client.banded.reset();
    lock.unlock();
    double total = 0.0;
    try {
      const FrameHeader header{summary, done.request, rung, 0, true, done.surface, done.arrival, done.stats, done.maxError, done.renderMs};
      message = encodeFrame(header, done.image, Clock::now(), &total);
    } catch (const std::exception& e) {
      error = e.what();
    }
    lock.lock();
    if (!message.empty())
      client.send(std::move(message), true);
    else
      client.send(errorMessage(error, done.request.seq), false);
  }

  // What a frame of @p r at @p level of the ladder (rung @p q) draws and how.
  struct FrameParts {
    View view;
    Look look;
    Quality quality;
  };
  static FrameParts frameParts(const FrameRequest& r, const Scene& scene, const QualityLevel& q, int level, std::optional<float> iso) {
    std::ostringstream warnings;  // (an isovalue outside the data: the page's info says so)
    const FrameSetup setup = setUpFrame(r.settings, scene, warnings);
    FrameParts p{setup.view, setup.look, setup.quality};
    p.view.camera.width = std::max(kMinImageEdge, int(std::lround(r.size().x * q.scale)));
    p.view.camera.height = std::max(kMinImageEdge, int(std::lround(r.size().y * q.scale)));
    p.look.iso = iso;
    p.quality.waitForSurface = false;  // the pool's builder makes it; meanwhile its preview, or none
    if (q.rays) p.quality.renderer = Renderer::Raycast;
    if (level > 0) {
      p.quality.budgetPercent = q.budgetPercent < 100.0 ? q.budgetPercent : 0.0;
      p.quality.step = q.step;
      p.quality.reuseViewErrors = r.interacting;
      // The refining frame too: it comes between the motion and the final frame, which it delays.
      p.quality.simplifiedSurface = true;
      p.quality.surfaceErrorPixels = kInteractiveSurfaceErrorPixels;
      p.quality.cutToSlabs = false;
      p.quality.maxBrickEdge = kInteractiveBrickEdge;
      p.quality.lodPixels = kInteractiveLodPixels;
      p.quality.waitForBricks = false;  // a paged scene's bricks not cached yet are drawn coarser meanwhile
      p.quality.packTexels = kInteractivePackTexels;
    } else {
      p.quality.lodPixels = kFinalLodPixels;
    }
    return p;
  }

  // A frame's message: its header and the image, JPEG before the final frame, PNG for it (render
  // thread, unlocked); @p ms receives the frame's time from @p t0, encoding included.
  static std::string encodeFrame(const FrameHeader& h, const Image& image, Clock::time_point t0, double* ms) {
    const auto t1 = Clock::now();
    const std::vector<uint8_t> rgba = toRgba8(image, glm::vec3(0.0f));
    const std::vector<uint8_t> bytes = h.final ? encodePng(rgba, image.width, image.height) : encodeJpeg(rgba, image.width, image.height, 95);
    const double encodeMs = msSince(t1);
    *ms = msSince(t0);
    return frameMessage(h.toJson(image.width, image.height, encodeMs).dump(-1, ' ', false, json::error_handler_t::replace), bytes);
  }

  // ---- exports ------------------------------------------------------------------------------

  // A mesh of a scene's isosurface in patient coordinates, as `export --surface octree` writes,
  // made on a thread of its own (frames go on meanwhile).
  void exportLoop() {
    std::unique_lock<std::mutex> lock(mutex);
    while (!stopping) {
      wake.wait(lock, [&] { return stopping || !exports.empty(); });
      if (stopping) break;
      Export e = std::move(exports.front());
      exports.pop_front();
      const Scene* scene = pool->pin(e.sceneKey);
      if (!scene) {
        e.reply("", "no such scene");
        continue;
      }
      lock.unlock();
      std::string body, error;
      try {
        body = meshFile(*scene, e.iso, e.format);
      } catch (const std::exception& ex) {
        error = ex.what();
      }
      lock.lock();
      pool->unpin(e.sceneKey);
      e.reply(std::move(body), std::move(error));
    }
  }

  static std::string meshFile(const Scene& scene, float iso, const std::string& format) {
    std::ostringstream log;  // export's report: the page shows none
    const TriangleMesh mesh = exportSurface(scene, ExportRequest{iso, "octree"}, nullptr, log).mesh;
    const Volume& v = scene.volume;
    if (mesh.triangles.empty()) HYB_THROW(ValueError, "iso: no surface at ", iso, " (the data's values are ", v.minValue(), " to ", v.maxValue(), ")");
    return meshBytes(mesh, *meshFormatOf("surface." + format), MeshWriteOptions{false, "LPS"});
  }

  // ---- network ------------------------------------------------------------------------------

  bool authorised(const http::request<http::string_body>& req) const {
    if (const auto q = queryParam(std::string_view(req.target().data(), req.target().size()), "token"); q && tokenMatches(*q, token)) return true;
    const auto cookie = req.find(http::field::cookie);
    if (cookie == req.end()) return false;
    const auto c = cookieValue(std::string_view(cookie->value().data(), cookie->value().size()), "hyb_token");
    return c && tokenMatches(*c, token);
  }

  // False when the server has its maximum of clients already.
  bool addClient(const std::shared_ptr<Client>& c) {
    const std::lock_guard<std::mutex> lock(mutex);
    if (int(clients.size()) >= options.maxClients) return false;
    c->id = nextClient++;
    clients[c->id] = c;
    if (!defaultScene.empty()) {
      // Told at once while it is open; read again if it was released while no client showed it.
      pool->open(c->id, defaultScene, options.volume, options.series, std::filesystem::path(options.volume).filename().string());
    } else {
      c->send(json{{"type", "volumes"}, {"volumes", volumesJson()}}.dump(), false);
    }
    return true;
  }

  void removeClient(const std::shared_ptr<Client>& c) {
    const std::lock_guard<std::mutex> lock(mutex);
    c->open = false;
    clients.erase(c->id);
    pool->leave(c->id);
  }

  void onMessage(const std::shared_ptr<Client>& c, const std::string& text) {
    Request request;
    try {
      request = parseRequest(text);
    } catch (const Error& e) {
      c->send(errorMessage(e.what()), false);
      return;
    }
    if (const auto* open = std::get_if<OpenRequest>(&request)) {
      if (options.dataDir.empty()) {
        c->send(errorMessage("open: the server has no data directory (start it with --data-dir)"), false);
        return;
      }
      std::filesystem::path real;
      try {
        real = resolveInDataDir(options.dataDir, open->path);
      } catch (const Error& e) {
        c->send(errorMessage(e.what()), false);
        return;
      }
      const std::lock_guard<std::mutex> lock(mutex);
      pool->open(c->id, keyOf(open->path, open->series), real.string(), open->series, open->path);
      return;
    }
    auto& frame = std::get<FrameRequest>(request);
    const std::lock_guard<std::mutex> lock(mutex);
    if (c->sceneKey.empty()) {
      c->send(errorMessage("no volume is open (send an open message first)", frame.seq), false);
      return;
    }
    if (!frame.scene.empty() && frame.scene != c->sceneKey) return;  // for the scene shown before: stale
    c->pending = std::move(frame);  // replaces an older one not yet rendered
    c->pendingSince = Clock::now();
    c->pendingEpochMs = epochMs();
    wake.notify_all();
  }

  void queueExport(const std::string& sceneKey, float iso, const std::string& format, std::function<void(std::string, std::string)> reply) {
    const std::lock_guard<std::mutex> lock(mutex);
    exports.push_back(Export{sceneKey, iso, format, std::move(reply)});
    wake.notify_all();
  }
};

namespace {

// One WebSocket: reads messages into its client; writes the newest frame and every text message.
class WsSession : public std::enable_shared_from_this<WsSession> {
 public:
  WsSession(tcp::socket&& socket, ServerState& server) : mWs(std::move(socket)), mServer(server) {}

  void run(http::request<http::string_body> req) {
    mWs.set_option(websocket::stream_base::timeout::suggested(beast::role_type::server));
    mWs.read_message_max(kMaxMessageBytes);
    mWs.async_accept(req, beast::bind_front_handler(&WsSession::onAccept, shared_from_this()));
  }

 private:
  void onAccept(beast::error_code ec) {
    if (ec) return;
    mClient = std::make_shared<Client>(mServer.options.frameTargetMs);
    std::weak_ptr<WsSession> self = shared_from_this();
    net::any_io_executor executor = mWs.get_executor();
    mClient->send = [self, executor](std::string message, bool binary) {
      net::post(executor, [self, message = std::move(message), binary]() mutable {
        if (auto s = self.lock()) s->queue(std::move(message), binary);
      });
    };
    if (!mServer.addClient(mClient)) {
      // Told why, then closed once the message is out.
      mClient.reset();
      auto me = shared_from_this();
      auto text = std::make_shared<std::string>(errorMessage("the viewer serves " + std::to_string(mServer.options.maxClients) + " clients at most"));
      mWs.text(true);
      mWs.async_write(net::buffer(*text), [me, text](beast::error_code, size_t) {
        me->mWs.async_close(websocket::close_code::try_again_later, [me](beast::error_code) {});
      });
      return;
    }
    mServer.log("client connected");
    read();
  }

  // A message is read in parts as they come: one whose first part came more than
  // ServerOptions::messageTimeout ago closes the socket (a client trickling bytes would otherwise
  // keep its slot for good); an idle socket is left alone (Beast's pings find a peer that is gone).
  void read() { mWs.async_read_some(mBuffer, kMaxMessageBytes, beast::bind_front_handler(&WsSession::onRead, shared_from_this())); }

  void onRead(beast::error_code ec, size_t) {
    if (!mClient) return;  // closed meanwhile (a failed write, the queue's bound): what was read is dropped
    if (ec) {
      close(ec == websocket::error::message_too_big ? "sent a message over the limit" : "");
      return;
    }
    if (!mInMessage) {
      mInMessage = true;
      mDeadline.expires_after(mServer.options.messageTimeout);
      mDeadline.async_wait([self = shared_from_this()](beast::error_code e) {
        if (e || !self->mInMessage) return;
        self->close("took longer than the message timeout to send a message");
      });
    }
    if (!mWs.is_message_done()) {
      read();
      return;
    }
    mInMessage = false;
    mDeadline.cancel();
    if (!mWs.got_text()) {
      queue(errorMessage("message: expected JSON text, not binary"), false);
    } else {
      mServer.onMessage(mClient, beast::buffers_to_string(mBuffer.data()));
    }
    mBuffer.consume(mBuffer.size());
    if (mClient) read();
  }

  // Ends the session, once: the client leaves the server, what waits to be written is dropped and
  // the socket is closed, so that its pending read and write end with an error. A handler already
  // queued with a message read or a write done finds mClient empty and does nothing more.
  void close(const std::string& why = "") {
    if (!mClient) return;
    mServer.removeClient(mClient);
    mServer.log(why.empty() ? "client disconnected" : "client " + why + ": closed");
    mClient.reset();
    mDeadline.cancel();
    mQueue.erase(mQueue.begin() + (mWriting ? 1 : 0), mQueue.end());  // (the one being written is its buffer until the write ends)
    mWaitingTextBytes = 0;
    beast::get_lowest_layer(mWs).close();
  }

  // Text messages all go, up to kMaxQueuedTextBytes waiting (a client that does not read them is
  // closed); of frames only the newest waiting one (a slow link drops stale frames).
  void queue(std::string message, bool binary) {
    if (!mClient) return;
    if (binary) {
      for (auto it = mQueue.begin() + (mWriting ? 1 : 0); it != mQueue.end();)
        it = it->second ? mQueue.erase(it) : it + 1;
    } else if ((mWaitingTextBytes += message.size()) > kMaxQueuedTextBytes) {
      close("does not read its messages (over " + std::to_string(kMaxQueuedTextBytes) + " bytes waiting)");
      return;
    }
    mQueue.emplace_back(std::move(message), binary);
    if (!mWriting) write();
  }

  void write() {
    mWriting = true;
    const auto& [message, binary] = mQueue.front();
    if (!binary) mWaitingTextBytes -= message.size();
    mWs.binary(binary);
    mWs.async_write(net::buffer(message), beast::bind_front_handler(&WsSession::onWrite, shared_from_this()));
  }

  void onWrite(beast::error_code ec, size_t) {
    mQueue.pop_front();
    mWriting = false;
    if (!mClient) return;
    if (ec) {
      close();
      return;
    }
    if (!mQueue.empty()) write();
  }

  websocket::stream<beast::tcp_stream> mWs;
  ServerState& mServer;
  beast::flat_buffer mBuffer;
  net::steady_timer mDeadline{mWs.get_executor()};  // the message being read must be complete by then
  bool mInMessage = false;
  std::shared_ptr<Client> mClient;
  std::deque<std::pair<std::string, bool>> mQueue;  // messages to write, the front one being written while mWriting
  bool mWriting = false;
  size_t mWaitingTextBytes = 0;  // text messages in mQueue not being written yet
};

// An HTTP reply: its status, content type and body, and the headers some replies add.
struct Reply {
  http::status status = http::status::ok;
  std::string type, body;
  bool setCookie = false;  // the access token's cookie (the page opened with ?token=)
  bool headOnly = false;   // a HEAD request: the headers only
  std::string download;    // a file to save: its name (Content-Disposition)
};

// A plain-text reply: a refusal, or why a request failed.
Reply textReply(http::status status, std::string text) { return Reply{status, "text/plain", std::move(text), false, false, ""}; }

// One HTTP connection: the page's assets, the mesh export, or the upgrade to the WebSocket.
class HttpSession : public std::enable_shared_from_this<HttpSession> {
 public:
  HttpSession(tcp::socket&& socket, ServerState& server) : mStream(std::move(socket)), mServer(server) {}
  void run() { read(); }

 private:
  void read() {
    mParser.emplace();
    mParser->header_limit(8 * 1024);
    mParser->body_limit(1024);
    mStream.expires_after(std::chrono::seconds(30));
    http::async_read(mStream, mBuffer, *mParser, beast::bind_front_handler(&HttpSession::onRead, shared_from_this()));
  }

  void onRead(beast::error_code ec, size_t) {
    if (ec) {
      if (ec != http::error::end_of_stream && ec != beast::error::timeout && ec != net::error::operation_aborted) {
        // A malformed request: answer once and close.
        respond(textReply(http::status::bad_request, "bad request\n"), false, 11);
      }
      return;
    }
    http::request<http::string_body> req = mParser->release();
    const std::string target(req.target());
    const std::string path(targetPath(target));
    if (!mServer.authorised(req)) {
      respond(textReply(http::status::forbidden, "403: this page needs its access token (the URL hybrid-octree view printed)\n"), false, req.version());
      return;
    }
    if (websocket::is_upgrade(req)) {
      // Only this server's page may drive the viewer with the cookie it holds: browsers send the
      // page's origin with a socket; one without (not a browser's page) or of another is refused.
      const auto origin = req.find(http::field::origin);
      const auto host = req.find(http::field::host);
      if (path != "/ws" || origin == req.end() || host == req.end() || std::string(origin->value()) != "http://" + std::string(host->value())) {
        respond(textReply(http::status::forbidden, "403: not this page's socket\n"), false, req.version());
        return;
      }
      std::make_shared<WsSession>(mStream.release_socket(), mServer)->run(std::move(req));
      return;
    }
    if (req.method() != http::verb::get && req.method() != http::verb::head) {
      respond(textReply(http::status::method_not_allowed, "405: only GET\n"), req.keep_alive(), req.version());
      return;
    }
    const bool setCookie = queryParam(target, "token").has_value();
    if (path == "/api/mesh") {
      exportMesh(target, req.version(), req.keep_alive());
      return;
    }
    const Asset* asset = findAsset(path);
    if (!asset) {
      respond(textReply(http::status::not_found, "404: no such page\n"), req.keep_alive(), req.version());
      return;
    }
    respond(Reply{http::status::ok, std::string(asset->contentType), std::string(asset->bytes), setCookie, req.method() == http::verb::head, ""},
            req.keep_alive(), req.version());
  }

  void exportMesh(const std::string& target, unsigned version, bool keepAlive) {
    const auto iso = queryParam(target, "iso");
    const auto format = queryParam(target, "format").value_or("ply");
    std::string scene = queryParam(target, "scene").value_or(mServer.defaultScene);
    double value = 0;
    try {
      size_t used = 0;
      value = iso ? std::stod(*iso, &used) : NAN;
      if (!iso || used != iso->size() || !std::isfinite(value)) throw std::invalid_argument("iso");
    } catch (const std::exception&) {
      respond(textReply(http::status::bad_request, "400: iso: expected a number\n"), keepAlive, version);
      return;
    }
    if (!meshFormatOf("surface." + format)) {
      respond(textReply(http::status::bad_request, "400: format: expected " + meshExtensionsText(false, false) + "\n"), keepAlive, version);
      return;
    }
    auto self = shared_from_this();
    net::any_io_executor executor = mStream.get_executor();
    std::ostringstream name;  // the file's name says its isovalue
    name << "surface-" << float(value) << "." << format;
    mServer.queueExport(scene, float(value), format, [self, executor, version, keepAlive, file = name.str()](std::string body, std::string error) {
      net::post(executor, [self, body = std::move(body), error = std::move(error), version, keepAlive, file]() {
        if (!error.empty()) self->respond(textReply(http::status::bad_request, "400: " + error + "\n"), keepAlive, version);
        else self->respond(Reply{http::status::ok, "application/octet-stream", body, false, false, file}, keepAlive, version);
      });
    });
  }

  void respond(Reply reply, bool keepAlive, unsigned version) {
    auto res = std::make_shared<http::response<http::string_body>>(reply.status, version);
    res->set(http::field::server, "hybrid-octree");
    res->set(http::field::content_type, reply.type);
    res->set(http::field::cache_control, "no-store");
    res->set("X-Content-Type-Options", "nosniff");
    res->set("Content-Security-Policy", "default-src 'self'; img-src 'self' blob: data:; connect-src 'self'");
    if (reply.setCookie) res->set(http::field::set_cookie, "hyb_token=" + mServer.token + "; Path=/; HttpOnly; SameSite=Strict");
    if (!reply.download.empty()) res->set(http::field::content_disposition, "attachment; filename=\"" + reply.download + "\"");
    res->keep_alive(keepAlive);
    const size_t size = reply.body.size();
    if (!reply.headOnly) res->body() = std::move(reply.body);
    res->content_length(size);
    http::async_write(mStream, *res, [self = shared_from_this(), res, keepAlive](beast::error_code ec, size_t) {
      if (ec || !keepAlive) {
        beast::error_code ignored;
        self->mStream.socket().shutdown(tcp::socket::shutdown_send, ignored);
        return;
      }
      self->read();
    });
  }

  beast::tcp_stream mStream;
  ServerState& mServer;
  beast::flat_buffer mBuffer;
  std::optional<http::request_parser<http::string_body>> mParser;
};

void accept(ServerState& s) {
  s.acceptor.async_accept(net::make_strand(s.io), [&s](beast::error_code ec, tcp::socket socket) {
    if (ec) {
      if (!s.stopping) accept(s);
      return;
    }
    // Frames go out as written: Nagle's algorithm would hold a frame's last segment for the
    // client's delayed acknowledgement.
    beast::error_code ignored;
    socket.set_option(tcp::no_delay(true), ignored);
    std::make_shared<HttpSession>(std::move(socket), s)->run();
    accept(s);
  });
}

}  // namespace

Server::Server(ServerOptions options) : mImpl(std::make_unique<ServerState>()) {
  ServerState& s = *mImpl;
  s.options = std::move(options);
  s.token = s.options.token.empty() ? makeToken() : s.options.token;
  if (!s.options.loader) HYB_THROW(ValueError, "view: no volume loader");
  if (s.options.volume.empty() && s.options.dataDir.empty()) HYB_THROW(ValueError, "view: expected a volume or --data-dir");
  if (!s.options.dataDir.empty()) {
    s.listing = listDataDir(s.options.dataDir);
    s.dataRoot = std::filesystem::canonical(s.options.dataDir).string();  // (listDataDir has read it)
  }
  ScenePool::Options po;
  po.loader = s.options.loader;
  po.textureLimitBytes = s.options.textureLimitBytes;
  po.memoryBytes = s.options.memoryBytes;
  po.releaseAfter = s.options.releaseAfter;
  s.pool = std::make_unique<ScenePool>(s.mutex, std::move(po), s.poolEvents());
  if (!s.options.volume.empty()) {
    s.defaultScene = ServerState::keyOf(s.options.volume, s.options.series);
    s.pool->preload(s.defaultScene, s.options.volume, s.options.series, std::filesystem::path(s.options.volume).filename().string());
  }
  beast::error_code ec;
  const net::ip::address address = net::ip::make_address(s.options.host, ec);
  if (ec) HYB_THROW(ValueError, "--host '", s.options.host, "': expected an IP address (", ec.message(), ")");
  const tcp::endpoint endpoint(address, s.options.port);
  s.acceptor.open(endpoint.protocol(), ec);
  if (!ec) s.acceptor.set_option(net::socket_base::reuse_address(true), ec);
  if (!ec) s.acceptor.bind(endpoint, ec);
  if (!ec) s.acceptor.listen(net::socket_base::max_listen_connections, ec);
  if (ec) HYB_THROW(IoError, "--port ", s.options.port, ": cannot listen on ", s.options.host, ":", s.options.port, " (", ec.message(), ")");
}

Server::~Server() { stop(); }

uint16_t Server::port() const { return mImpl->acceptor.local_endpoint().port(); }
const std::string& Server::token() const { return mImpl->token; }
std::string Server::url() const {
  const std::string host = mImpl->options.host.find(':') != std::string::npos ? "[" + mImpl->options.host + "]" : mImpl->options.host;
  return "http://" + host + ":" + std::to_string(port()) + "/?token=" + mImpl->token;
}

void Server::start() {
  ServerState& s = *mImpl;
  if (s.started) return;
  s.started = true;
  accept(s);
  s.renderThread = std::thread([&s] { s.renderLoop(); });
  s.exportThread = std::thread([&s] { s.exportLoop(); });
  s.netThread = std::thread([&s] { s.io.run(); });
}

void Server::run() {
  start();
  if (mImpl->netThread.joinable()) mImpl->netThread.join();
}

void Server::stop() {
  ServerState& s = *mImpl;
  if (s.stopping.exchange(true)) return;
  {
    const std::lock_guard<std::mutex> lock(s.mutex);
    s.wake.notify_all();
  }
  net::post(s.io, [&s] {
    beast::error_code ignored;
    s.acceptor.close(ignored);
  });
  s.io.stop();
  for (std::thread* t : {&s.netThread, &s.exportThread})
    if (t->joinable() && t->get_id() != std::this_thread::get_id()) t->join();
  {
    const std::lock_guard<std::mutex> lock(s.mutex);
    s.othersStopped = true;
    s.wake.notify_all();
  }
  if (s.renderThread.joinable() && s.renderThread.get_id() != std::this_thread::get_id()) s.renderThread.join();
  s.pool.reset();  // never started (the render thread destroys it otherwise): no context was made
}

}  // namespace hyb::viewer
