#include "apps/viewer/frame_scheduler.h"

#include <turbojpeg.h>

#include <algorithm>
#include <cmath>
#include <sstream>

#include "render/patient_view.h"
#include "render/scene_renderer.h"
#include "volume/core/error.h"

namespace hyb::viewer {

// Frames before the final one draw the surface simplified, its finest level within blocks of this edge: with
// bricks no smaller, each of its triangles lies inside one brick and is drawn in the right order (coarser
// levels, drawn where pixels are larger than their error, are placed by their triangles' centroids).
static_assert(kInteractiveBrickEdge == kSimplifiedBlockVoxels);

namespace {

double msSince(Clock::time_point t0) { return std::chrono::duration<double, std::milli>(Clock::now() - t0).count(); }

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

// The image a frame of @p r at rung @p q draws: the page's size scaled by the rung.
glm::ivec2 scaledSize(const FrameRequest& r, const QualityLevel& q) {
  return glm::max(glm::ivec2(kMinImageEdge), glm::ivec2(glm::round(glm::dvec2(r.size()) * q.scale)));
}

// Whether a frame of @p size is drawn in bands (kBandPixels).
bool drawnInBands(glm::ivec2 size) { return int64_t(size.x) * size.y > kBandPixels; }

// A frame's message: its header and the image, as JPEG or PNG (FrameHeader::png(); render thread,
// unlocked); @p ms receives the frame's time from @p t0, encoding included.
std::string encodeFrame(const FrameHeader& h, const Image& image, Clock::time_point t0, double* ms) {
  const auto t1 = Clock::now();
  const std::vector<uint8_t> rgba = toRgba8(image, glm::vec3(0.0f));
  const std::vector<uint8_t> bytes = h.png() ? encodePng(rgba, image.width, image.height) : encodeJpeg(rgba, image.width, image.height, 95);
  const double encodeMs = msSince(t1);
  *ms = msSince(t0);
  return frameMessage(h.text(image.width, image.height, encodeMs), bytes);
}

// The image of a banded frame of @p size from its @p bands, top first.
Image joinBands(glm::ivec2 size, const std::vector<Image>& bands) {
  int rows = 0;
  for (const Image& band : bands) {
    HYB_CHECK(band.width == size.x);
    rows += band.height;
  }
  HYB_CHECK(rows == size.y);
  Image image(size.x, size.y);
  auto at = image.pixels.begin();
  for (const Image& band : bands) at = std::copy(band.pixels.begin(), band.pixels.end(), at);
  return image;
}

}  // namespace

FrameSetup frameParts(const FrameRequest& r, const Scene& scene, const FrameRung& rung, std::optional<float> iso, UserGeometryMemo& memo) {
  const QualityLevel& q = rung.q;
  std::ostringstream warnings;  // (an isovalue outside the data: the page's info says so)
  FrameSetup p = setUpFrame(r.settings, scene, warnings, &memo);
  const glm::ivec2 size = scaledSize(r, q);
  p.view.camera.width = size.x;
  p.view.camera.height = size.y;
  p.look.iso = iso;
  p.quality.waitForSurface = false;  // the pool's builder makes it; meanwhile its preview, or none
  if (q.rays) p.quality.renderer = Renderer::Raycast;
  if (rung.level > 0) {
    p.quality.budgetPercent = q.budgetPercent < 100.0 ? q.budgetPercent : 0.0;
    p.quality.step = q.step;
    p.quality.reuseViewErrors = r.interacting;
    if (!rung.finalBricks) {
      // The refining frame too: it comes between the motion and the final frame, which it delays.
      p.quality.simplifiedSurface = true;
      p.quality.surfaceErrorPixels = kInteractiveSurfaceErrorPixels;
      p.quality.cutToSlabs = false;
      p.quality.maxBrickEdge = kInteractiveBrickEdge;
      p.quality.lodPixels = kInteractiveLodPixels;
      p.quality.waitForBricks = false;  // a paged scene's bricks not cached yet are drawn coarser meanwhile
      p.quality.packTexels = kInteractivePackTexels;
    } else {  // the sharper step: the final frame's bricks and surface at its rung's spacing
      p.quality.lodPixels = kFinalLodPixels;
    }
    p.quality.interactiveRays = true;  // a ray-traced rung's frame by the moving frames' tracer
  } else {
    p.quality.lodPixels = kFinalLodPixels;
  }
  return p;
}

FrameEncoder::FrameEncoder()
    : mThread([this] {
        std::unique_lock<std::mutex> lock(mMutex);
        for (;;) {
          mWake.wait(lock, [&] { return mStopping || !mJobs.empty(); });
          if (mStopping) return;
          const std::function<void()> job = std::move(mJobs.front());
          mJobs.pop_front();
          lock.unlock();
          job();
          lock.lock();
        }
      }) {}

FrameEncoder::~FrameEncoder() {
  {
    const std::lock_guard<std::mutex> lock(mMutex);
    mStopping = true;
  }
  mWake.notify_all();
  mThread.join();
}

void FrameEncoder::add(std::function<void()> job) {
  {
    const std::lock_guard<std::mutex> lock(mMutex);
    mJobs.push_back(std::move(job));
  }
  mWake.notify_one();
}

void Client::ask(FrameRequest request, uint64_t renders) {
  pending = std::move(request);
  pendingRenders = renders;
  pendingSince = lastAsked = Clock::now();
  pendingEpochMs = std::chrono::duration<double, std::milli>(std::chrono::system_clock::now().time_since_epoch()).count();
}

void Client::showScene(const std::string& key) {
  sceneKey = key;
  pending.reset();
  current.reset();
  refine.clear();
  sharperStep = -1;
  banded.reset();
  volumeQuality.reset();
  surfaceQuality.reset();
  surfaceRayQuality.reset();
  bandMsPerPixel = 0.0;
  bandLevel = -1;
  bandRowMs.clear();
}

bool FrameScheduler::hasWork(const Clients& clients) {
  return std::any_of(clients.begin(), clients.end(), [](const auto& c) { return c.second->hasWork(); });
}

void FrameScheduler::refineAgain(const Clients& clients, const std::string& key) {
  for (const auto& entry : clients) {
    Client& c = *entry.second;
    if (c.sceneKey == key && c.current && !c.pending) {
      c.pending = c.current;
      c.pending->interacting = false;
      c.pendingSince.reset();
    }
  }
}

void FrameScheduler::serveNext(const Clients& clients, std::unique_lock<std::mutex>& lock) {
  std::vector<std::shared_ptr<Client>> moving, waiting;
  for (const auto& entry : clients) {
    if (entry.second->moving()) moving.push_back(entry.second);
    if (entry.second->hasWork()) waiting.push_back(entry.second);
  }
  if (moving.empty() && waiting.empty()) return;
  // The moving frame asked first, else the client served longest ago: none waits behind another's
  // turns; other work deferred kLongestDeferMs goes before the moving frames.
  const Clock::time_point now = Clock::now();
  const auto asked = [&](const std::shared_ptr<Client>& c) { return c->pendingSince.value_or(now); };
  const auto servedFirst = [](const auto& a, const auto& b) { return a->lastServed < b->lastServed; };
  // (one such step in each kLongestDeferMs, whatever the clients waiting: each of several would
  // otherwise become overdue in turn, and the movers wait for all of them)
  const auto overdue = [&](const std::shared_ptr<Client>& c) {
    const Clock::time_point since = std::max({c->lastServed, c->pendingSince.value_or(c->lastServed), mLastDeferred});
    return !c->moving() && now - since >= std::chrono::duration<double, std::milli>(kLongestDeferMs);
  };
  const bool moversWait = !moving.empty();
  std::erase_if(waiting, [&](const auto& c) { return moversWait && !overdue(c); });
  const std::shared_ptr<Client> client =  // (held: it may leave while its frame is drawn)
      !waiting.empty() ? *std::min_element(waiting.begin(), waiting.end(), servedFirst)
                       : *std::min_element(moving.begin(), moving.end(), [&](const auto& a, const auto& b) { return asked(a) < asked(b); });
  const bool deferred = moversWait && !client->moving();
  // Whether another client drags; a mover's next request comes while a band is drawn: the window spans a few of them.
  const double windowMs = std::max(1000.0, 3.0 * (client->banded ? client->banded->longestBandMs : 0.0));
  const auto window = std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double, std::milli>(windowMs));
  const int othersDragging = int(std::count_if(clients.begin(), clients.end(), [&](const auto& c) { return c.second != client && c.second->dragging(now, window); }));
  serve(*client, othersDragging, lock);
  client->lastServed = Clock::now();
  if (deferred) mLastDeferred = client->lastServed;
}

int rowsWithin(std::span<const float> rowMs, int first, double ms, glm::ivec2 limits) {
  const int last = int(rowMs.size());
  int r = first;
  for (double sum = 0.0; r < last && r - first < limits.y && (r - first < limits.x || sum + rowMs[size_t(r)] <= ms); ++r) sum += rowMs[size_t(r)];
  return r - first;
}

bool waitsForSurface(int level, int sharperStep, bool interacting, bool building, bool shown) {
  return (level == 0 || level == sharperStep) && !interacting && building && !shown;
}

int bandRows(const BandedFrame& b, double ms, bool othersDrag) {
  const int standard = std::max(16, kBandPixels / b.size.x);
  const glm::ivec2 limits(std::min(kMinBandRows, standard), standard);
  if (!b.predicted.empty()) {
    // The last frame's row times, scaled by how this frame's bands compared with them: all of them
    // so far, or the last one where it took longer (the view moved the costly rows).
    auto ratio = [&b](int from) {
      double done = 0.0, was = 0.0;
      for (int r = from; r < b.next; ++r) {
        done += b.rowMs[size_t(r)];
        was += b.predicted[size_t(r)];
      }
      return done > 0.0 && was > 0.0 ? done / was : 1.0;
    };
    const double scale = std::clamp(std::max(ratio(0), ratio(b.lastBand)), 0.25, 4.0);
    glm::ivec2 within = limits;
    if (othersDrag && b.costliestRowMs > 0.0f) within.y = std::clamp(int(ms / (scale * double(b.costliestRowMs))), limits.x, limits.y);
    return rowsWithin(b.predicted, b.next, ms / scale, within);
  }
  // Not measured yet at this level: the narrowest band while another moves (a final frame's rows
  // can cost ten times a moving frame's).
  if (b.msPerRow <= 0.0) return othersDrag ? limits.x : standard;
  // Rows growing costlier (down into the skull) are taken to go on growing as the last two bands
  // did, up to twice the last one's time a row.
  const double growth = b.lastMsPerRow > 0.0 ? std::clamp(b.msPerRow / b.lastMsPerRow, 1.0, 2.0) : 1.0;
  return std::clamp(int(ms / (b.msPerRow * growth)), limits.x, othersDrag ? std::min(limits.y, kUnmeasuredBandRows) : limits.y);
}

int FrameScheduler::start(Client& client, int movers, std::optional<Arrival>* arrival, bool* surface) {
  if (client.pendingSince) *arrival = Arrival{msSince(*client.pendingSince), client.pendingEpochMs, mRenders - client.pendingRenders};
  client.pendingSince.reset();
  client.current = std::move(client.pending);
  client.pending.reset();
  client.banded.reset();
  client.refine.clear();
  const FrameRequest& r = *client.current;
  if (!r.scene.empty() && r.scene != client.sceneKey) {  // asked of the scene shown before this one
    client.current.reset();
    return -1;
  }
  const ScenePool::Frame shown = mPool.forFrame(client.id, r.iso());
  *surface = shown.iso.has_value();
  // (once the full surface is ready: the ray tracer draws no preview, it would build it here)
  client.raysForSurface =
      shown.renderer && shown.surfaceReady && surfaceRaysFit(shown.renderer->volume().dims(), shown.renderer->volume().spacing());
  AdaptiveQuality& quality = client.quality(*surface);
  quality.share(movers);
  quality.canvas(double(r.size().x) * double(r.size().y));
  if (r.interacting) return quality.chooseInteractiveLevel();
  client.refine = quality.refinement();
  // A banded final frame's target is made on another thread while the steps before it are drawn.
  if (const glm::ivec2 size = scaledSize(r, quality.ladder().front()); drawnInBands(size) && shown.renderer) {
    try {
      shown.renderer->prepareTarget(size.x, size.y);
    } catch (const std::exception&) {  // (no thread: the first band makes it)
    }
  }
  client.sharperStep = quality.sharperStep();
  client.refineSurface = *surface;
  std::reverse(client.refine.begin(), client.refine.end());
  const int level = client.refine.back();
  client.refine.pop_back();
  return level;
}

void FrameScheduler::serve(Client& client, int othersDragging, std::unique_lock<std::mutex>& lock) {
  const bool othersDrag = othersDragging > 0;
  int level = 0;
  std::optional<Arrival> arrival;
  bool surface = client.refineSurface;
  if (client.pending) {
    level = start(client, 1 + othersDragging, &arrival, &surface);
    if (level < 0) return;
  } else if (!client.banded) {
    level = client.refine.back();
    client.refine.pop_back();
  }
  const ScenePool::Frame scene = mPool.forFrame(client.id, client.current->iso());
  if (!scene.renderer) {
    client.refine.clear();
    client.banded.reset();
    return;
  }
  if (!client.banded &&
      waitsForSurface(level, client.sharperStep, client.current->interacting, scene.surfaceBuilding, scene.iso == client.current->iso())) {
    client.refine.clear();
    return;
  }
  const FrameRequest request = client.banded ? client.banded->request : *client.current;
  const bool final = !request.interacting && client.refine.empty() && level == 0;
  const QualityLevel& rung = client.quality(surface).ladder()[size_t(level)];
  // A refinement as large as a final frame is banded too: it would hold the movers as long.
  const glm::ivec2 size = scaledSize(request, rung);
  if (!request.interacting && !client.banded && drawnInBands(size)) {
    BandedFrame b(request, SurfaceShown(scene));
    b.arrival = arrival;
    b.level = level;
    b.final = final;
    b.size = size;
    if (client.bandLevel == level) b.msPerRow = client.bandMsPerPixel * size.x;  // (its first band sized by the last one's time)
    if (const auto it = client.bandRowMs.find(level); it != client.bandRowMs.end() && it->second.first == size.x && int(it->second.second.size()) == size.y) {
      b.predicted = it->second.second;
      std::vector<float> sorted = b.predicted;
      const auto p90 = sorted.begin() + std::ptrdiff_t(sorted.size() * 9 / 10);
      std::nth_element(sorted.begin(), p90, sorted.end());
      b.costliestRowMs = *p90;
    }
    b.rowMs.assign(size_t(size.y), 0.0f);
    client.banded = std::move(b);
  }
  if (client.banded) {
    serveBand(client, *scene.renderer, *scene.summary, othersDrag, lock);
    return;
  }
  const SurfaceShown shown(scene);
  const SceneSummary summary = *scene.summary;
  const FrameRung frameRung{rung, level, !request.interacting && level == client.sharperStep};
  ++mRenders;
  lock.unlock();
  std::string message;
  double ms = 0.0;
  bool cold = false;
  double coarser = 0.0;  // share of the bricks drawn coarser
  try {
    const auto t0 = Clock::now();
    const FrameSetup parts = frameParts(request, scene.renderer->scene(), frameRung, shown.drawn(request), mGeometry);
    const RenderedFrame frame = scene.renderer->render(parts.view, parts.look, parts.quality);
    const double renderMs = msSince(t0);
    const FrameStats& st = frame.stats;
    // (also a ray-traced frame that made the surface's BVH, or one that made a pre-integration table)
    cold = 2 * st.slices.uploadedBricks > st.slices.bricks || st.bvhMs > 0.0 || st.preintegrationMs > 0.0;
    coarser = double(st.bricksNotResident) / double(std::max<size_t>(1, st.slices.bricks + st.bricksNotResident));
    const FrameHeader header{summary, request, rung, level, final, shown, arrival, st, frame.selection.maxError, renderMs, 1, renderMs,
                             frameRung.finalBricks};
    message = encodeFrame(header, frame.image, t0, &ms);
  } catch (const std::exception& e) {
    message.clear();
    client.send(errorMessage(mScrub(e.what()), request.seq), false);
  }
  lock.lock();
  if (!message.empty()) {  // (a failed frame's time says nothing of its level)
    client.quality(surface).record(level, ms, cold, coarser);
    sendFrame(client, std::move(message));
  }
}

// The next band of @p client's large frame (a final one, or a refinement as large); the frame goes out with its last.
void FrameScheduler::serveBand(Client& client, SceneRenderer& renderer, const SceneSummary& scene, bool othersDrag,
                               std::unique_lock<std::mutex>& lock) {
  BandedFrame& b = *client.banded;
  const double bandMs = othersDrag ? std::max(mTargetMs, kMovingBandMs) : kIdleBandMs;
  const glm::ivec2 rows(b.next, std::min(b.next + bandRows(b, bandMs, othersDrag), b.size.y));
  const QualityLevel& rung = client.quality(b.surface.iso.has_value()).ladder()[size_t(b.level)];
  const int level = b.level;
  const FrameRequest request = b.request;
  const FrameRung frameRung{rung, level, !request.interacting && level == client.sharperStep};
  const std::optional<float> iso = b.surface.drawn(request);
  const SceneSummary summary = scene;
  ++mRenders;
  lock.unlock();
  std::string error;
  RenderedFrame frame;
  const auto t0 = Clock::now();
  try {
    FrameSetup parts = frameParts(request, renderer.scene(), frameRung, iso, mGeometry);
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
    client.send(errorMessage(mScrub(error), request.seq), false);
    return;
  }
  b.bands.push_back(std::move(frame.image));  // (the band's rows only)
  b.renderMs += ms;
  b.lastMsPerRow = b.msPerRow;
  b.msPerRow = ms / (rows.y - rows.x);
  std::fill(b.rowMs.begin() + rows.x, b.rowMs.begin() + rows.y, float(b.msPerRow));
  b.lastBand = rows.x;
  client.bandMsPerPixel = b.msPerRow / b.size.x;
  client.bandLevel = b.level;
  b.longestBandMs = std::max(b.longestBandMs, ms);
  b.stats = frame.stats;
  b.maxError = std::max(b.maxError, double(frame.selection.maxError));
  b.next = rows.y;
  if (b.next < b.size.y) return;
  client.bandRowMs[b.level] = {b.size.x, b.rowMs};
  // Encoded beside the next renders: the image's PNG would hold the other clients' frames.
  mEncoder.add([this, to = client.shared_from_this(), sent = client.framesSent, sharper = frameRung.finalBricks,
                done = std::make_shared<BandedFrame>(std::move(b)), summary, rung] {
    std::string message, failed;
    double total = 0.0;
    try {
      const FrameHeader header{summary, done->request, rung, done->level, done->final, done->surface, done->arrival, done->stats, done->maxError,
                               done->renderMs, int(done->bands.size()), done->longestBandMs, sharper};
      message = encodeFrame(header, joinBands(done->size, done->bands), Clock::now(), &total);
    } catch (const std::exception& e) {
      failed = e.what();
    }
    const std::lock_guard<std::mutex> held(mMutex);
    if (to->framesSent != sent) return;  // the page shows a newer request's frame: this one would replace it
    if (!message.empty())
      sendFrame(*to, std::move(message));
    else
      to->send(errorMessage(mScrub(failed), done->request.seq), false);
  });
  client.banded.reset();
}

void FrameScheduler::sendFrame(Client& client, std::string message) {
  ++client.framesSent;
  client.send(std::move(message), true);
}

}  // namespace hyb::viewer
