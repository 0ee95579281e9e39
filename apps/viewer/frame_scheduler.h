// The viewer's frame scheduler: each client's newest request, its ladder of refinements and its
// final frame drawn band by band, served in turn on the render thread so that no client's large
// frame holds the others' for longer than a band. State shared with the network thread lives in
// Client, under the server's mutex.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <deque>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include "apps/viewer/viewer_protocol.h"
#include "apps/viewer/viewer_quality.h"
#include "apps/viewer/viewer_replies.h"
#include "render/frame_settings.h"
#include "render/scene_pool.h"

namespace hyb::viewer {

using Clock = std::chrono::steady_clock;

/// A final frame larger than this is drawn band by band, other clients' frames between its bands,
/// so that it holds the render thread for one band at a time (the pixels are the whole frame's:
/// SlicesOptions::rows). While another client moves, a band is sized to kMovingBandMs (or the frame
/// target, if longer) from the client's last large frame's row times (rowsWithin), or else the time
/// per pixel its last band took, so that the mover waits
/// about that at most; otherwise to kIdleBandMs, so that a client starting to drag waits at most
/// about that for its first frame: narrower bands would cost the large frame more than they save
/// the mover (each band selects and draws every brick it crosses again).
inline constexpr int kBandPixels = 512 * 512;
inline constexpr int kMinBandRows = 8;
inline constexpr double kMovingBandMs = 150.0;
inline constexpr double kIdleBandMs = 250.0;
/// How long other work (a client's refinement or band) waits behind moving frames: one such step,
/// whichever client's, goes first once it and the last one are kLongestDeferMs old. Movers asking
/// again as soon as their frame comes would otherwise hold it back for as long as they drag; with
/// it, such work gets about a third of the render thread (a band of kMovingBandMs in each
/// kLongestDeferMs of moving frames), and a mover's gap grows by one band (or a refinement frame,
/// which is not cut) in each kLongestDeferMs.
inline constexpr double kLongestDeferMs = 300.0;

/// The rows from @p first whose times in @p rowMs add up to at most @p ms, at least @p limits.x and
/// at most @p limits.y (and no further than the last row): a band sized by where the frame's cost
/// lies, as the client's last large frame at the same level and size measured it row by row (a
/// frame's rows through the skull cost many times those beside it, and the band after a cheap one
/// would otherwise be sized by the cheap one's time).
int rowsWithin(std::span<const float> rowMs, int first, double ms, glm::ivec2 limits);

/// A frame's level of its ladder, that level's rung, and whether it draws the final frame's bricks:
/// the sharper step before a slow final frame (AdaptiveQuality::sharperStep), whose textures the
/// last final frame left in the cache, where the moving frames' 32-texel bricks at 0.7 pixels were
/// mostly new at its size and drawn coarser beyond the packing bound.
struct FrameRung {
  const QualityLevel& q;
  int level = 0;
  bool finalBricks = false;
};

/// What a frame of @p r at @p rung draws and how (its size, spacing, surface, bricks), its meshes
/// from @p memo.
FrameSetup frameParts(const FrameRequest& r, const Scene& scene, const FrameRung& rung, std::optional<float> iso, UserGeometryMemo& memo);

/// A large frame (final, or a refinement as large) part drawn.
struct BandedFrame {
  BandedFrame(FrameRequest r, const SurfaceShown& s) : request(std::move(r)), surface(s) {}
  FrameRequest request;
  SurfaceShown surface;
  std::optional<Arrival> arrival;
  int level = 0;       ///< the ladder's level it is drawn at
  bool final = true;   ///< the request's last frame
  glm::ivec2 size{0};     ///< its pixels
  /// Each band's rows, top first: the encoder puts them together (a whole 2048² image made on the
  /// render thread would hold the other clients' frames for its page faults).
  std::vector<Image> bands;
  int next = 0;           ///< the first row not drawn yet
  int lastBand = 0;       ///< the first row of the last band drawn
  double renderMs = 0.0;  ///< the bands' render times so far
  double msPerRow = 0.0;  ///< the last band's time per row
  double lastMsPerRow = 0.0;  ///< the band's before it
  std::vector<float> rowMs;      ///< each drawn row's share of its band's time
  std::vector<float> predicted;  ///< the client's last large frame's rowMs at this level and size; empty: none
  float costliestRowMs = 0.0f;   ///< predicted's 90th percentile (bandRows)
  double longestBandMs = 0.0;
  FrameStats stats;       ///< the last band's
  double maxError = 0.0;
};

/// The rows of @p b's next band, to take about @p ms (at least kMinBandRows, at most kBandPixels'
/// worth): by the client's last large frame's row times (rowsWithin, scaled by how this frame's
/// bands compared with them), else by the time a row of its last band took. While another client
/// moves (@p othersDrag) a band also holds no more rows than would fit if each cost the last
/// frame's costliest (its 90th percentile: the view may have moved them here), or without row
/// times kUnmeasuredBandRows: the rows where the head begins cost ten times those above it, a jump
/// that no band's time foresees, and a band of kBandPixels' worth met it at twice its time.
int bandRows(const BandedFrame& b, double ms, bool othersDrag);
inline constexpr int kUnmeasuredBandRows = 48;

/// Whether a frame at @p level of a request not @p interacting waits for the surface asked for
/// while it is @p building and nothing of it is @p shown: the final frame (level 0) and the sharper
/// step drawn as it is (@p sharperStep) take seconds on a large volume and would hold the surface's
/// first look back; the coarser frames before them are drawn, and the pool refines again when
/// the surface comes.
bool waitsForSurface(int level, int sharperStep, bool interacting, bool building, bool shown);

/// A client: what its page asked for last, and how well its frames are made. Shared by its socket
/// (network thread) and the render thread, under the server's mutex.
struct Client : std::enable_shared_from_this<Client> {
  uint64_t id = 0;
  std::string sceneKey;                 ///< the scene its frames are of; empty before one is open
  std::optional<FrameRequest> pending;  ///< the newest request not yet rendered
  std::optional<Clock::time_point> pendingSince;  ///< when the page sent it (none: the server asks again)
  double pendingEpochMs = 0.0;          ///< the same, wall clock
  uint64_t pendingRenders = 0;          ///< the scheduler's render count when it came
  Clock::time_point lastAsked;          ///< when the page last asked for a frame
  Clock::time_point lastServed;         ///< when the scheduler last drew for it (the end of that render)
  std::optional<FrameRequest> current;  ///< the request being refined
  std::vector<int> refine;              ///< levels still to render for it, next last
  bool refineSurface = false;           ///< ... of the surface's ladder
  std::optional<BandedFrame> banded;    ///< its large frame (final, or a refinement as large), part drawn
  double bandMsPerPixel = 0.0;          ///< its last band's time per pixel (a new large frame's first band is sized by it) ...
  int bandLevel = -1;                   ///< ... at this level of the ladder (another level's pixels cost differently)
  /// Per level of the ladder: its last whole large frame's width and BandedFrame::rowMs.
  std::map<int, std::pair<int, std::vector<float>>> bandRowMs;
  AdaptiveQuality volumeQuality, surfaceQuality, surfaceRayQuality;
  bool raysForSurface = false;  ///< the surface's ladder ray-traces small frames (surfaceRaysFit)
  int sharperStep = -1;         ///< the current request's refinement level drawn with the final frame's bricks
  uint64_t framesSent = 0;  ///< frames gone out (one encoded late is dropped when others went out since)
  std::atomic<bool> open{true};
  std::function<void(std::string message, bool binary)> send;  ///< posts to the socket; drops when closed

  explicit Client(double targetMs)
      : volumeQuality(kVolumeLadder, targetMs), surfaceQuality(kSurfaceLadder, targetMs), surfaceRayQuality(kSurfaceRayLadder, targetMs) {}
  /// The ladder of frames with a surface or without: they cost and lose accuracy differently.
  AdaptiveQuality& quality(bool surface) { return surface ? (raysForSurface ? surfaceRayQuality : surfaceQuality) : volumeQuality; }
  bool hasWork() const { return open && !sceneKey.empty() && (pending || !refine.empty() || banded); }
  /// A new request from the page, when the scheduler had made @p renders renders: it replaces an
  /// older one not yet rendered.
  void ask(FrameRequest request, uint64_t renders);
  /// Whether its next work is a moving frame (served before refinements and bands of any client).
  bool moving() const { return open && !sceneKey.empty() && pending && pending->interacting; }
  /// Whether the user is dragging: its last request moved and came within @p window of @p now
  /// (between its frames too, while the next request is on its way).
  bool dragging(Clock::time_point now, Clock::duration window) const {
    const std::optional<FrameRequest>& last = pending ? pending : current;
    return open && last && last->interacting && now - lastAsked < window;
  }
  /// A new scene: nothing of the last one's requests, refinement or measured times applies to it.
  void showScene(const std::string& key);
};

using Clients = std::map<uint64_t, std::shared_ptr<Client>>;

/// Runs jobs in the order given on a thread of its own: a large frame's encoding (a 2048² PNG takes
/// a few hundred milliseconds) that the other clients' frames need not wait for.
class FrameEncoder {
 public:
  FrameEncoder();
  ~FrameEncoder();  ///< the jobs not started are dropped
  FrameEncoder(const FrameEncoder&) = delete;
  FrameEncoder& operator=(const FrameEncoder&) = delete;
  void add(std::function<void()> job);

 private:
  std::mutex mMutex;
  std::condition_variable mWake;
  std::deque<std::function<void()>> mJobs;
  bool mStopping = false;
  std::thread mThread;
};

/// Serves the clients' frames in turn (render thread, with the server's mutex held except while
/// it renders and encodes).
class FrameScheduler {
 public:
  /// Moving frames aim at @p frameTargetMs: a band drawn while another client moves takes about that.
  /// A frame's error goes to its client as @p scrub words it (the server's own paths left out).
  /// @p mutex is the server's (the encoder's thread takes it to send).
  FrameScheduler(ScenePool& pool, std::mutex& mutex, double frameTargetMs, std::function<std::string(std::string)> scrub)
      : mPool(pool), mMutex(mutex), mTargetMs(frameTargetMs), mScrub(std::move(scrub)) {}

  /// Whether a client of @p clients has a frame to make.
  static bool hasWork(const Clients& clients);
  /// Clients showing scene @p key refine again (a surface they asked for may have come).
  static void refineAgain(const Clients& clients, const std::string& key);
  /// One step of the next client with work: the moving frame asked for first, else the client
  /// served longest ago (its newest request's first frame, the next refinement, or the next band
  /// of its final frame), which goes first when deferred kLongestDeferMs.
  void serveNext(const Clients& clients, std::unique_lock<std::mutex>& lock);
  /// Frames and bands rendered so far (under the server's mutex).
  uint64_t renders() const { return mRenders; }

 private:
  /// @p othersDragging: how many other clients drag (a large frame's bands are then cut to
  /// kMovingBandMs, and a moving frame aims at the frame target shared among the movers).
  void serve(Client& client, int othersDragging, std::unique_lock<std::mutex>& lock);
  /// Takes @p client's pending request as its current one: the ladder's level of its first frame,
  /// one of @p movers clients dragging.
  int start(Client& client, int movers, std::optional<Arrival>* arrival, bool* surface);
  void serveBand(Client& client, SceneRenderer& renderer, const SceneSummary& scene, bool othersDrag, std::unique_lock<std::mutex>& lock);

  /// Sends @p message, a frame, to @p client (server's mutex held).
  static void sendFrame(Client& client, std::string message);

  ScenePool& mPool;
  std::mutex& mMutex;
  UserGeometryMemo mGeometry;  ///< the meshes of the frames asked for (render thread)
  double mTargetMs;
  std::function<std::string(std::string)> mScrub;
  uint64_t mRenders = 0;
  Clock::time_point mLastDeferred{};  ///< the end of the last step served before waiting moving frames
  FrameEncoder mEncoder;  ///< (last: its thread ends before the members its jobs use)
};

}  // namespace hyb::viewer
