#include "apps/viewer_server.h"

#include <turbojpeg.h>

#include <boost/asio.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/websocket.hpp>
#include <nlohmann/json.hpp>

#include <atomic>
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

#include "apps/viewer_files.h"
#include "apps/viewer_protocol.h"
#include "apps/viewer_quality.h"
#include "render/patient_view.h"
#include "render/scene_renderer.h"
#include "surface/mesh_io.h"
#include "surface/mesh_ops.h"
#include "volume/error.h"
#include "volume/file_util.h"

namespace hyb::viewer {

namespace net = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
using tcp = net::ip::tcp;
using nlohmann::json;
using Clock = std::chrono::steady_clock;

// Frames before the final one draw the surface simplified within blocks of this edge: with bricks no smaller,
// each of its triangles lies inside one brick and is drawn in the right order.
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

json cameraToJson(const Camera& c) {
  return {{"eye", vec3Json(c.eye)}, {"center", vec3Json(c.center)}, {"up", vec3Json(c.up)}, {"fov", c.fovDeg},
          {"ortho", c.ortho},       {"height", c.orthoHeight},       {"pixels", json::array({c.width, c.height})}};
}

// Doubles printed so that reading them back gives the same bits.
std::string exact(double x) {
  std::ostringstream s;
  s << std::setprecision(17) << x;
  return s.str();
}
std::string exact3(const glm::dvec3& v) { return exact(v.x) + "," + exact(v.y) + "," + exact(v.z); }

// Arguments quoted for a POSIX shell when they need it.
std::string shellQuote(const std::string& s) {
  if (!s.empty() && s.find_first_not_of("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789-_./,:=%+") == std::string::npos) return s;
  std::string out = "'";
  for (char c : s) out += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return out + "'";
}

// The `hybrid-octree render` command line that makes the same image (the transfer function in
// the file @p tfFile when it is not a plain preset).
std::string renderCommand(const std::string& path, const std::string& series, const FrameRequest& r, const std::string& tfFile) {
  const Camera& c = r.camera;
  std::string cmd = "hybrid-octree render " + shellQuote(path);
  if (!series.empty()) cmd += " --series " + shellQuote(series);
  cmd += " --eye " + exact3(c.eye) + " --center " + exact3(c.center) + " --up " + exact3(c.up);
  cmd += c.ortho ? " --ortho" : " --fov " + exact(c.fovDeg);
  cmd += " --size " + std::to_string(c.width) + "x" + std::to_string(c.height);
  cmd += !r.preset.empty() && r.opacityScale == 1.0f ? " --preset " + r.preset : " --tf " + tfFile;
  if (!r.shading) cmd += " --shading off";
  if (r.iso) {
    const glm::vec4& s = r.surfaceColor;
    cmd += " --iso " + exact(*r.iso) + " --surface-color " + exact(s.r) + "," + exact(s.g) + "," + exact(s.b) + "," + exact(s.a);
  }
  if (r.cut) cmd += " --cut " + exact3(r.cut->point) + "," + exact3(r.cut->normal);
  if (r.voi)
    cmd += " --voi " + exact3(r.voi->lo) + "," + exact3(r.voi->hi) + " --voi-inside " + exact(r.voi->inside) + " --voi-outside " +
           exact(r.voi->outside) + " --voi-ramp " + exact(r.voi->ramp);
  return cmd + " -o view.png";
}

std::string tfText(const TransferFunction& tf) {
  std::ostringstream s;
  s << "# value r g b a (opacity of 1 mm)\n" << std::setprecision(9);
  for (const TransferFunction::Point& p : tf.points()) s << p.value << " " << p.color.r << " " << p.color.g << " " << p.color.b << " " << p.alpha << "\n";
  return s.str();
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// A client: what its page asked for last, and how well its frames are made. Shared by its socket
// (network thread) and the render thread, under the server's work mutex.

struct Client {
  uint64_t id = 0;
  std::string sceneKey;                 // the volume it shows; empty before one is open
  std::optional<FrameRequest> pending;  // the newest request not yet rendered
  std::optional<Clock::time_point> pendingSince;  // when the page sent it (none: the server asks again)
  double pendingEpochMs = 0.0;          // the same, wall clock
  std::optional<FrameRequest> current;  // the request being refined
  std::vector<int> refine;              // levels still to render for it, next last
  bool refineSurface = false;           // ... of the surface's ladder
  std::optional<float> shownIso;        // the surface its frames draw: the one asked for once it is ready
  AdaptiveQuality volumeQuality, surfaceQuality;
  std::atomic<bool> open{true};
  std::function<void(std::string message, bool binary)> send;  // posts to the socket; drops when closed
  explicit Client(double targetMs) : volumeQuality(kVolumeLadder, targetMs), surfaceQuality(kSurfaceLadder, targetMs) {}
  // The ladder of frames with a surface or without: they cost and lose accuracy differently.
  AdaptiveQuality& quality(bool surface) { return surface ? surfaceQuality : volumeQuality; }
  bool hasWork() const { return open && !sceneKey.empty() && (pending || !refine.empty()); }
};

// One open volume and its renderer (made and used on the render thread only).
struct SceneSlot {
  std::string key, path, series, name;
  std::unique_ptr<SceneRenderer> renderer;
  json info;                        // what the page needs to know of the volume
  std::optional<float> shownIso;    // the newest surface ready: drawn by a client whose own is not
  std::optional<float> buildingIso;
  std::optional<float> wantedIso;   // asked for while another was being built
  std::thread builder;
  std::unique_ptr<PreparedSurface> built;  // handed over by the builder, adopted by the render thread
  bool buildFailed = false;
  std::atomic<int> busy{0};         // exports in flight
  ~SceneSlot() {
    if (builder.joinable()) builder.join();
  }
};

struct ServerState {
  ServerOptions options;
  std::string token;
  net::io_context io{1};
  tcp::acceptor acceptor{io};
  std::thread netThread, renderThread, loaderThread;
  std::atomic<bool> stopping{false};
  bool started = false;

  // Work shared with the render thread.
  std::mutex mutex;
  std::condition_variable wake;
  std::list<std::shared_ptr<Client>> clients;
  std::map<std::string, std::unique_ptr<SceneSlot>> scenes;
  std::deque<std::pair<std::shared_ptr<Client>, OpenRequest>> opens;  // waiting for the loader
  struct Export {
    std::string sceneKey;
    float iso;
    std::string format;
    std::function<void(std::string body, std::string error)> reply;
  };
  std::deque<Export> exports;
  uint64_t nextClient = 1;
  std::vector<DataEntry> listing;  // the data directory's volumes, listed at start

  void log(const std::string& line) {
    if (options.log) *options.log << "view     " << line << std::endl;
  }

  // ---- scenes -------------------------------------------------------------------------------

  static std::string keyOf(const std::string& path, const std::string& series) { return series.empty() ? path : path + "#" + series; }

  std::unique_ptr<SceneSlot> makeSlot(const std::string& path, const std::string& series, const std::string& name) {
    Scene scene = options.loader(path, series);
    auto slot = std::make_unique<SceneSlot>();
    slot->key = keyOf(path, series);
    slot->path = path;
    slot->series = series;
    slot->name = name;
    const bool hasSceneIso = scene.surface.has_value();
    const double sceneIso = hasSceneIso ? double(scene.surface->isovalue()) : 0.0;
    SceneRenderer::Options ro;
    ro.textureLimitBytes = options.textureLimitBytes;
    slot->renderer = std::make_unique<SceneRenderer>(std::move(scene), ro);
    const Volume& vol = slot->renderer->volume();
    // The anatomical views framed to what the default transfer function shows.
    const TransferFunction tf = TransferFunction::defaultFor(vol.minValue(), vol.maxValue());
    const std::vector<glm::dvec3> points = visiblePoints(vol, slot->renderer->octree(), tf, std::nullopt);
    json views = json::object();
    const std::pair<const char*, AnatomicalView> named[] = {{"anterior", AnatomicalView::Anterior}, {"posterior", AnatomicalView::Posterior},
                                                            {"left", AnatomicalView::Left},         {"right", AnatomicalView::Right},
                                                            {"superior", AnatomicalView::Superior}, {"inferior", AnatomicalView::Inferior}};
    for (const auto& [label, view] : named) views[label] = cameraToJson(fitCamera(points, viewDirection(view), 30.0, false, 512, 512));
    const Histogram h = computeHistogram(vol, 128);
    glm::dvec3 lo(1e300), hi(-1e300);
    const glm::dvec3 extent = glm::dvec3(vol.dims() - 1) * vol.spacing();
    for (int c = 0; c < 8; ++c) {
      const glm::dvec3 p = vol.frame().toPatient(glm::dvec3(c & 1 ? extent.x : 0, c & 2 ? extent.y : 0, c & 4 ? extent.z : 0));
      lo = glm::min(lo, p);
      hi = glm::max(hi, p);
    }
    json presets = json::object();
    for (const std::string& p : TransferFunction::presetNames()) {
      json pts = json::array();
      const TransferFunction preset = TransferFunction::preset(p);
      for (const TransferFunction::Point& q : preset.points())
        pts.push_back(json::array({q.value, q.color.r, q.color.g, q.color.b, q.alpha}));
      presets[p] = pts;
    }
    slot->info = {{"type", "info"},
                  {"scene", slot->key},
                  {"name", name},
                  {"dims", json::array({vol.dims().x, vol.dims().y, vol.dims().z})},
                  {"spacing", vec3Json(vol.spacing())},
                  {"range", json::array({vol.minValue(), vol.maxValue()})},
                  {"histogram", {{"min", h.minValue}, {"max", h.maxValue}, {"counts", h.counts}}},
                  {"orientation", orientationCode(vol.frame().direction)},
                  {"bounds", {{"min", vec3Json(lo)}, {"max", vec3Json(hi)}}},
                  {"center", vec3Json(0.5 * (lo + hi))},
                  {"views", views},
                  {"presets", presets},
                  {"defaultPreset", vol.minValue() < -500.0f && vol.maxValue() > 300.0f ? "ct-skin-bone" : ""},
                  {"defaultTf", json::array()},
                  {"iso", nullptr}};
    if (hasSceneIso) slot->info["iso"] = sceneIso;
    for (const TransferFunction::Point& q : tf.points()) slot->info["defaultTf"].push_back(json::array({q.value, q.color.r, q.color.g, q.color.b, q.alpha}));
    return slot;
  }

  json volumesJson() const {
    json list = json::array();
    for (const DataEntry& e : listing) list.push_back({{"path", e.path}, {"series", e.series}, {"label", e.label}});
    return list;
  }
  json infoFor(const SceneSlot& slot) const {
    json info = slot.info;
    info["volumes"] = volumesJson();
    return info;
  }

  // Loads the volumes clients asked to open, one at a time, off the render thread.
  void loaderLoop() {
    std::unique_lock<std::mutex> lock(mutex);
    while (!stopping) {
      wake.wait(lock, [&] { return stopping || !opens.empty(); });
      if (stopping) break;
      auto [client, request] = opens.front();
      opens.pop_front();
      const std::string key = keyOf(request.path, request.series);
      if (scenes.count(key)) {
        client->sceneKey = key;
        client->send(infoFor(*scenes[key]).dump(), false);
        continue;
      }
      lock.unlock();
      std::unique_ptr<SceneSlot> slot;
      std::string error;
      try {
        const std::filesystem::path real = resolveInDataDir(options.dataDir, request.path);
        client->send(json{{"type", "loading"}, {"path", request.path}}.dump(), false);
        slot = makeSlot(real.string(), request.series, request.path);
        slot->key = key;
        slot->info["scene"] = key;
        slot->info["open"] = {{"path", request.path}, {"series", request.series}};
      } catch (const std::exception& e) {
        error = e.what();
      }
      lock.lock();
      if (!slot) {
        client->send(errorMessage(error), false);
        continue;
      }
      evictUnused();
      client->sceneKey = key;
      client->pending.reset();
      client->refine.clear();
      client->send(infoFor(*slot).dump(), false);
      scenes[key] = std::move(slot);
      wake.notify_all();
    }
  }

  // Keeps at most two volumes no client shows (under the lock; joins their builders).
  void evictUnused() {
    std::set<std::string> used;
    for (const auto& c : clients) used.insert(c->sceneKey);
    size_t idle = 0;
    for (auto it = scenes.begin(); it != scenes.end();) {
      const bool free = !used.count(it->first) && it->second->busy == 0 && !it->second->buildingIso;
      if (free && ++idle > 1) {
        // Destroying a renderer frees its OpenGL context, which the render thread made: hand it over.
        retired.push_back(std::move(it->second));
        it = scenes.erase(it);
      } else {
        ++it;
      }
    }
  }
  std::vector<std::unique_ptr<SceneSlot>> retired;  // destroyed by the render thread

  // ---- rendering ----------------------------------------------------------------------------

  // Starts building the surface of @p iso in the background (under the lock).
  void requestSurface(SceneSlot& slot, float iso) {
    if (slot.renderer->hasSurface(iso)) {
      slot.wantedIso.reset();  // (a client still wanting it asks again when the build in flight ends)
      return;
    }
    if (slot.buildingIso == iso) return;
    if (slot.buildingIso) {
      slot.wantedIso = iso;
      return;
    }
    slot.buildingIso = iso;
    slot.wantedIso.reset();
    if (slot.builder.joinable()) slot.builder.join();
    broadcast(slot, json{{"type", "surface"}, {"iso", iso}, {"state", "building"}, {"progress", 0.0}}.dump());
    slot.builder = std::thread([this, &slot, iso] {
      std::unique_ptr<PreparedSurface> s;
      try {
        const Progress progress([&](const std::string& task, double f) {
          const std::lock_guard<std::mutex> lock(mutex);
          broadcast(slot, json{{"type", "surface"}, {"iso", iso}, {"state", "building"}, {"task", task}, {"progress", f}}.dump());
        });
        s = SceneRenderer::prepareSurface(slot.renderer->scene(), iso, &progress, nullptr, true);
      } catch (const std::exception& e) {
        log(std::string("surface build failed: ") + e.what());
      }
      const std::lock_guard<std::mutex> lock(mutex);
      slot.built = std::move(s);
      slot.buildFailed = !slot.built;
      wake.notify_all();
    });
  }

  void broadcast(const SceneSlot& slot, const std::string& message) {
    for (const auto& c : clients)
      if (c->sceneKey == slot.key) c->send(message, false);
  }

  // Adopts finished surfaces and starts the builds asked for meanwhile (under the lock).
  void collectSurfaces() {
    for (auto& [key, slot] : scenes) {
      if (!slot->buildingIso || (!slot->built && !slot->buildFailed)) continue;
      const float iso = *slot->buildingIso;
      if (slot->built) {
        slot->renderer->adoptSurface(std::move(slot->built));
        slot->shownIso = iso;
        broadcast(*slot, json{{"type", "surface"}, {"iso", iso}, {"state", "ready"}}.dump());
      } else {
        broadcast(*slot, json{{"type", "surface"}, {"iso", iso}, {"state", "failed"}}.dump());
      }
      slot->buildingIso.reset();
      slot->buildFailed = false;
      if (slot->wantedIso) requestSurface(*slot, *slot->wantedIso);
      // Clients showing this scene refine again with the new surface.
      for (const auto& c : clients)
        if (c->sceneKey == key && c->current && !c->pending) {
          c->pending = c->current;
          c->pending->interacting = false;
          c->pendingSince.reset();
        }
    }
  }

  void renderLoop() {
    std::unique_lock<std::mutex> lock(mutex);
    size_t turn = 0;
    while (!stopping) {
      wake.wait(lock, [&] {
        if (stopping || !retired.empty() || !exports.empty()) return true;
        for (auto& [k, s] : scenes)
          if (s->built || s->buildFailed) return true;
        for (const auto& c : clients)
          if (c->hasWork()) return true;
        return false;
      });
      if (stopping) break;
      retired.clear();
      collectSurfaces();
      if (!exports.empty()) {
        Export e = std::move(exports.front());
        exports.pop_front();
        runExport(e, lock);
        continue;
      }
      // The clients with work, in turn.
      std::vector<std::shared_ptr<Client>> ready;
      for (const auto& c : clients)
        if (c->hasWork()) ready.push_back(c);
      if (ready.empty()) continue;
      std::shared_ptr<Client> client = ready[turn++ % ready.size()];
      SceneSlot* slot = scenes.count(client->sceneKey) ? scenes[client->sceneKey].get() : nullptr;
      if (!slot) {
        client->pending.reset();
        client->refine.clear();
        continue;
      }
      // The newest request replaces whatever refinement was under way.
      int level = 0;
      std::optional<Arrival> arrival;
      bool surface = client->refineSurface;
      if (client->pending) {
        if (client->pendingSince) arrival = Arrival{msSince(*client->pendingSince), client->pendingEpochMs};
        client->pendingSince.reset();
        client->current = std::move(client->pending);
        client->pending.reset();
        const FrameRequest& r = *client->current;
        if (r.iso) {
          requestSurface(*slot, *r.iso);
          // The surface asked for once it is ready; until then the one shown before, if still kept.
          if (slot->renderer->hasSurface(*r.iso))
            client->shownIso = r.iso;
          else if (!client->shownIso || !slot->renderer->hasSurface(*client->shownIso))
            client->shownIso = slot->shownIso;
        }
        surface = r.iso && client->shownIso;
        AdaptiveQuality& quality = client->quality(surface);
        if (r.interacting) {
          level = quality.chooseInteractiveLevel();
          client->refine.clear();
        } else {
          client->refine = quality.refinement();
          client->refineSurface = surface;
          std::reverse(client->refine.begin(), client->refine.end());
          level = client->refine.back();
          client->refine.pop_back();
        }
      } else {
        level = client->refine.back();
        client->refine.pop_back();
      }
      const FrameRequest request = *client->current;
      const bool final = !request.interacting && client->refine.empty() && level == 0;
      const std::optional<float> iso = request.iso ? client->shownIso : std::nullopt;
      const QualityLevel& rung = client->quality(surface).ladder()[size_t(level)];
      lock.unlock();
      std::string message;
      double ms = 0.0;
      bool cold = false;
      try {
        message = renderFrame(*slot, request, rung, level, final, iso, arrival, &ms, &cold);
      } catch (const std::exception& e) {
        message.clear();
        client->send(errorMessage(e.what(), request.seq), false);
      }
      lock.lock();
      if (!message.empty()) {  // (a failed frame's time says nothing of its level)
        client->quality(surface).record(level, ms, cold);
        client->send(std::move(message), true);
      }
    }
    // The renderers' OpenGL contexts are this thread's: they are destroyed here, the lock released
    // for builders that still want it.
    std::map<std::string, std::unique_ptr<SceneSlot>> gone = std::move(scenes);
    std::vector<std::unique_ptr<SceneSlot>> old = std::move(retired);
    scenes.clear();
    retired.clear();
    lock.unlock();
    gone.clear();
    old.clear();
  }

  // When a frame's request came from the page: its wait for the render thread, and its arrival's
  // wall clock.
  struct Arrival {
    double waitMs = 0.0, epochMs = 0.0;
  };

  // One frame at @p level of the ladder, encoded with its header (render thread, unlocked); @p cold
  // says whether it uploaded most of its textures.
  std::string renderFrame(SceneSlot& slot, const FrameRequest& r, const QualityLevel& q, int level, bool final, std::optional<float> iso,
                          const std::optional<Arrival>& arrival, double* ms, bool* cold) {
    const auto t0 = Clock::now();
    View view;
    view.camera = r.camera;
    view.camera.width = std::max(kMinImageEdge, int(std::lround(r.camera.width * q.scale)));
    view.camera.height = std::max(kMinImageEdge, int(std::lround(r.camera.height * q.scale)));
    Look look;
    look.tf = r.transferFunction();
    look.iso = iso;
    look.surfaceColor = r.surfaceColor;
    look.shading = r.shading;
    look.cut = r.cut;
    look.voi = r.voi;
    Quality quality;
    if (level > 0) {
      quality.budgetPercent = q.budgetPercent < 100.0 ? q.budgetPercent : 0.0;
      quality.step = q.step;
      quality.reuseViewErrors = r.interacting;
      // The refining frame too: it comes between the motion and the final frame, which it delays.
      quality.simplifiedSurface = true;
      quality.cutToSlabs = false;
      quality.maxBrickEdge = kInteractiveBrickEdge;
    }
    const RenderedFrame frame = slot.renderer->render(view, look, quality);
    const double renderMs = msSince(t0);
    const auto t1 = Clock::now();
    const std::vector<uint8_t> rgba = toRgba8(frame.image, glm::vec3(0.0f));
    const std::vector<uint8_t> bytes = final ? encodePng(rgba, frame.image.width, frame.image.height)
                                             : encodeJpeg(rgba, frame.image.width, frame.image.height, 95);
    const double encodeMs = msSince(t1);
    *ms = msSince(t0);
    const FrameStats& st = frame.stats;
    *cold = 2 * st.slices.uploadedBricks > st.slices.bricks;
    json header = {{"type", "frame"},
                   {"seq", r.seq},
                   {"quality", r.interacting ? "interactive" : final ? "final" : "refining"},
                   {"level", level},
                   {"ladder", iso ? "surface" : "volume"},
                   {"levelText", q.describe()},
                   {"format", final ? "png" : "jpeg"},
                   {"width", frame.image.width},
                   {"height", frame.image.height},
                   {"waitMs", arrival ? json(arrival->waitMs) : json(nullptr)},
                   {"requestEpochMs", arrival ? json(arrival->epochMs) : json(nullptr)},
                   {"sentEpochMs", epochMs()},
                   {"renderMs", renderMs},
                   {"encodeMs", encodeMs},
                   {"textureBytes", st.slices.textureBytes},
                   {"bricks", st.slices.bricks},
                   {"maxError", frame.selection.maxError},
                   {"iso", iso ? json(*iso) : json(nullptr)},
                   {"surfaceReady", iso == r.iso},  // false: the surface asked for is still being built
                   {"camera", cameraToJson(r.camera)}};
    if (final && iso == r.iso) {  // (while the surface asked for is built, the frame is not the command's)
      header["command"] = renderCommand(slot.path, slot.series, r, "view.tf");
      if (r.preset.empty() || r.opacityScale != 1.0f) header["tfText"] = tfText(look.tf);
    }
    return frameMessage(header.dump(-1, ' ', false, json::error_handler_t::replace), bytes);
  }

  // A mesh of the scene's isosurface in patient coordinates, as `export --surface octree` writes.
  void runExport(const Export& e, std::unique_lock<std::mutex>& lock) {
    SceneSlot* slot = scenes.count(e.sceneKey) ? scenes[e.sceneKey].get() : nullptr;
    if (!slot) {
      e.reply("", "no such scene");
      return;
    }
    ++slot->busy;
    lock.unlock();
    std::string body, error;
    try {
      const Scene& scene = slot->renderer->scene();
      const Volume& v = scene.volume;
      const bool stored = scene.surface && scene.surface->isovalue() == e.iso;
      const SurfaceOctree so = stored ? *scene.surface : SurfaceOctree::build(v, scene.octree, e.iso);
      TriangleMesh mesh = fineMeshToTriangles(so.reconstruct(kMaxDim), v.spacing());
      if (mesh.triangles.empty())
        HYB_THROW(ValueError, "iso: no surface at ", e.iso, " (the data's values are ", v.minValue(), " to ", v.maxValue(), ")");
      toPatientSpace(v.frame(), &mesh);
      const std::filesystem::path tmp =
          std::filesystem::temp_directory_path() / ("hybrid-octree-view-" + makeToken() + "." + e.format);
      writeMesh(tmp.string(), mesh, MeshWriteOptions{false, "LPS"});
      std::ifstream in(tmp, std::ios::binary);
      body.assign(std::istreambuf_iterator<char>(in), {});
      std::filesystem::remove(tmp);
    } catch (const std::exception& ex) {
      error = ex.what();
    }
    lock.lock();
    --slot->busy;
    e.reply(std::move(body), std::move(error));
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
    clients.push_back(c);
    if (!options.volume.empty()) {
      const std::string key = keyOf(options.volume, options.series);
      c->sceneKey = key;
      c->send(infoFor(*scenes[key]).dump(), false);
    } else {
      c->send(json{{"type", "volumes"}, {"volumes", volumesJson()}}.dump(), false);
    }
    return true;
  }

  void removeClient(const std::shared_ptr<Client>& c) {
    const std::lock_guard<std::mutex> lock(mutex);
    c->open = false;
    clients.remove(c);
  }

  void onMessage(const std::shared_ptr<Client>& c, const std::string& text) {
    Request request;
    try {
      request = parseRequest(text);
    } catch (const Error& e) {
      c->send(errorMessage(e.what()), false);
      return;
    }
    const std::lock_guard<std::mutex> lock(mutex);
    if (auto* frame = std::get_if<FrameRequest>(&request)) {
      if (c->sceneKey.empty()) {
        c->send(errorMessage("no volume is open (send an open message first)", frame->seq), false);
        return;
      }
      c->pending = std::move(*frame);  // replaces an older one not yet rendered
      c->pendingSince = Clock::now();
      c->pendingEpochMs = epochMs();
    } else {
      const auto& open = std::get<OpenRequest>(request);
      if (options.dataDir.empty()) {
        c->send(errorMessage("open: the server has no data directory (start it with --data-dir)"), false);
        return;
      }
      opens.emplace_back(c, open);
    }
    wake.notify_all();
  }

  void queueExport(const std::string& sceneKey, float iso, const std::string& format, std::function<void(std::string, std::string)> reply) {
    const std::lock_guard<std::mutex> lock(mutex);
    exports.push_back(Export{sceneKey, iso, format, std::move(reply)});
    wake.notify_all();
  }

  std::string defaultSceneKey() const { return options.volume.empty() ? "" : keyOf(options.volume, options.series); }
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

  void read() { mWs.async_read(mBuffer, beast::bind_front_handler(&WsSession::onRead, shared_from_this())); }

  void onRead(beast::error_code ec, size_t) {
    if (ec) {
      if (ec == websocket::error::message_too_big) mServer.log("client sent a message over the limit: closed");
      close();
      return;
    }
    if (!mWs.got_text()) {
      queue(errorMessage("message: expected JSON text, not binary"), false);
    } else {
      mServer.onMessage(mClient, beast::buffers_to_string(mBuffer.data()));
    }
    mBuffer.consume(mBuffer.size());
    read();
  }

  void close() {
    if (mClient) {
      mServer.removeClient(mClient);
      mServer.log("client disconnected");
      mClient.reset();
    }
  }

  // Text messages all go; of frames only the newest waiting one (a slow link drops stale frames).
  void queue(std::string message, bool binary) {
    if (!mClient) return;
    if (binary)
      for (auto it = mQueue.begin() + (mWriting ? 1 : 0); it != mQueue.end();)
        it = it->second ? mQueue.erase(it) : it + 1;
    mQueue.emplace_back(std::move(message), binary);
    if (!mWriting) write();
  }

  void write() {
    mWriting = true;
    mWs.binary(mQueue.front().second);
    mWs.async_write(net::buffer(mQueue.front().first), beast::bind_front_handler(&WsSession::onWrite, shared_from_this()));
  }

  void onWrite(beast::error_code ec, size_t) {
    mQueue.pop_front();
    mWriting = false;
    if (ec) {
      close();
      return;
    }
    if (!mQueue.empty()) write();
  }

  websocket::stream<beast::tcp_stream> mWs;
  ServerState& mServer;
  beast::flat_buffer mBuffer;
  std::shared_ptr<Client> mClient;
  std::deque<std::pair<std::string, bool>> mQueue;
  bool mWriting = false;
};

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
        respond(http::status::bad_request, "text/plain", "bad request\n", false, 11);
      }
      return;
    }
    http::request<http::string_body> req = mParser->release();
    const std::string target(req.target());
    const std::string path(targetPath(target));
    if (!mServer.authorised(req)) {
      respond(http::status::forbidden, "text/plain", "403: this page needs its access token (the URL hybrid-octree view printed)\n", false, req.version());
      return;
    }
    if (websocket::is_upgrade(req)) {
      // Pages of other origins may not drive the viewer with the cookie this one holds.
      const auto origin = req.find(http::field::origin);
      const auto host = req.find(http::field::host);
      if (path != "/ws" || (origin != req.end() && (host == req.end() || std::string(origin->value()) != "http://" + std::string(host->value())))) {
        respond(http::status::forbidden, "text/plain", "403: not this page's socket\n", false, req.version());
        return;
      }
      std::make_shared<WsSession>(mStream.release_socket(), mServer)->run(std::move(req));
      return;
    }
    if (req.method() != http::verb::get && req.method() != http::verb::head) {
      respond(http::status::method_not_allowed, "text/plain", "405: only GET\n", req.keep_alive(), req.version());
      return;
    }
    const bool setCookie = queryParam(target, "token").has_value();
    if (path == "/api/mesh") {
      exportMesh(target, req.version(), req.keep_alive());
      return;
    }
    const Asset* asset = findAsset(path);
    if (!asset) {
      respond(http::status::not_found, "text/plain", "404: no such page\n", req.keep_alive(), req.version());
      return;
    }
    respond(http::status::ok, std::string(asset->contentType), std::string(asset->bytes), req.keep_alive(), req.version(), setCookie,
            req.method() == http::verb::head);
  }

  void exportMesh(const std::string& target, unsigned version, bool keepAlive) {
    const auto iso = queryParam(target, "iso");
    const auto format = queryParam(target, "format").value_or("ply");
    std::string scene = queryParam(target, "scene").value_or(mServer.defaultSceneKey());
    double value = 0;
    try {
      size_t used = 0;
      value = iso ? std::stod(*iso, &used) : NAN;
      if (!iso || used != iso->size() || !std::isfinite(value)) throw std::invalid_argument("iso");
    } catch (const std::exception&) {
      respond(http::status::bad_request, "text/plain", "400: iso: expected a number\n", keepAlive, version);
      return;
    }
    if (format != "ply" && format != "stl" && format != "obj") {
      respond(http::status::bad_request, "text/plain", "400: format: expected ply, stl or obj\n", keepAlive, version);
      return;
    }
    auto self = shared_from_this();
    net::any_io_executor executor = mStream.get_executor();
    std::ostringstream name;  // the file's name says its isovalue
    name << "surface-" << float(value) << "." << format;
    mServer.queueExport(scene, float(value), format, [self, executor, version, keepAlive, file = name.str()](std::string body, std::string error) {
      net::post(executor, [self, body = std::move(body), error = std::move(error), version, keepAlive, file]() {
        if (!error.empty()) self->respond(http::status::bad_request, "text/plain", "400: " + error + "\n", keepAlive, version);
        else self->respond(http::status::ok, "application/octet-stream", body, keepAlive, version, false, false, file);
      });
    });
  }

  void respond(http::status status, const std::string& type, std::string body, bool keepAlive, unsigned version, bool setCookie = false,
               bool headOnly = false, const std::string& download = "") {
    auto res = std::make_shared<http::response<http::string_body>>(status, version);
    res->set(http::field::server, "hybrid-octree");
    res->set(http::field::content_type, type);
    res->set(http::field::cache_control, "no-store");
    res->set("X-Content-Type-Options", "nosniff");
    res->set("Content-Security-Policy", "default-src 'self'; img-src 'self' blob: data:; connect-src 'self'");
    if (setCookie) res->set(http::field::set_cookie, "hyb_token=" + mServer.token + "; Path=/; HttpOnly; SameSite=Strict");
    if (!download.empty()) res->set(http::field::content_disposition, "attachment; filename=\"" + download + "\"");
    res->keep_alive(keepAlive);
    const size_t size = body.size();
    if (!headOnly) res->body() = std::move(body);
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
  if (!s.options.dataDir.empty()) s.listing = listDataDir(s.options.dataDir);
  if (!s.options.volume.empty()) {
    auto slot = s.makeSlot(s.options.volume, s.options.series, std::filesystem::path(s.options.volume).filename().string());
    s.scenes[slot->key] = std::move(slot);
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
  s.loaderThread = std::thread([&s] { s.loaderLoop(); });
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
  for (std::thread* t : {&s.netThread, &s.renderThread, &s.loaderThread})
    if (t->joinable() && t->get_id() != std::this_thread::get_id()) t->join();
  s.scenes.clear();  // never started: no context was made
}

}  // namespace hyb::viewer
