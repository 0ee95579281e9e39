// Sort-last rendering across MPI ranks (apps/ranks/ranks.h). IceT is ParaView's (Debian's paraview and
// paraview-dev: libvtkIceTCore/MPI-pv5.11, IceT 2.2's plain C API).
#include "apps/ranks/ranks.h"

#include <sys/resource.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <iomanip>
#include <numeric>
#include <sstream>

#include "volume/core/error.h"

#if HYB_MPI
#include <IceT.h>
#include <IceTMPI.h>
#include <mpi.h>
#endif

namespace hyb::app {

namespace {

using Clock = std::chrono::steady_clock;
[[maybe_unused]] double msSince(Clock::time_point t0) { return std::chrono::duration<double, std::milli>(Clock::now() - t0).count(); }

Ranks gRanks;

}  // namespace

const Ranks& ranks() { return gRanks; }

#if HYB_MPI

namespace {

// What a rank reports of its part, gathered on rank 0.
struct RankLine {
  double bricks = 0, texels = 0, blocksRead = 0, renderMs = 0, waitMs = 0, compositeMs = 0, rssMb = 0, cost = 0;
  double lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0};
};

// What identifies a selection: every rank must draw its part of the same one.
uint64_t selectionHash(const Selection& s) {
  uint64_t h = 1469598103934665603ull;  // FNV-1a
  auto mix = [&](uint64_t v) { h = (h ^ v) * 1099511628211ull; };
  for (const Brick& b : s.bricks) mix(uint64_t(b.node) << 8 | uint64_t(b.p) << 1 | uint64_t(b.hidden));
  return h;
}

double peakRssMb() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return double(u.ru_maxrss) / 1024.0;
}

}  // namespace

Ranks startRanks(int* argc, char*** argv) {
  // Open MPI, MPICH/Hydra and Slurm's PMI tell a process it was launched as a rank.
  const bool launched = std::getenv("OMPI_COMM_WORLD_SIZE") || std::getenv("PMI_SIZE") || std::getenv("PMIX_RANK");
  if (!launched) return gRanks;
  MPI_Init(argc, argv);
  MPI_Comm_rank(MPI_COMM_WORLD, &gRanks.rank);
  MPI_Comm_size(MPI_COMM_WORLD, &gRanks.size);
  gRanks.mpi = true;
  return gRanks;
}

void endRanks(const Ranks& r, int exitCode) {
  if (!r.mpi) return;
  if (exitCode != 0 && r.size > 1) MPI_Abort(MPI_COMM_WORLD, exitCode);  // ends every rank, never a hang
  MPI_Finalize();
}

struct RankFrame::State {
  const SceneRenderer* renderer = nullptr;
  const Progress* progress = nullptr;
  SceneRenderer::SortLast split;
  IceTCommunicator comm = nullptr;
  IceTContext context = nullptr;
  std::vector<double> renderMs, waitMs, compositeMs;
  double cost = 0;
};

RankFrame::RankFrame(SceneRenderer& renderer, const View& view, const Look& look, Quality* quality, const Progress* progress)
    : m(std::make_unique<State>()) {
  HYB_CHECK(gRanks.mpi);
  m->renderer = &renderer;
  m->progress = progress;
  m->split = renderer.sortLast(view, look, *quality, gRanks.size);
  quality->region = m->split.regions.boxes[size_t(gRanks.rank)];
  m->cost = m->split.regions.cost[size_t(gRanks.rank)];
  // The same selection in every rank, or the regions would not make one frame.
  const uint64_t hash = selectionHash(m->split.selection);
  std::vector<uint64_t> hashes(size_t(gRanks.size));
  MPI_Allgather(&hash, 1, MPI_UINT64_T, hashes.data(), 1, MPI_UINT64_T, MPI_COMM_WORLD);
  std::string differ;
  for (int r = 1; r < gRanks.size; ++r)
    if (hashes[size_t(r)] != hashes[0]) differ += (differ.empty() ? "" : ", ") + std::to_string(r);
  if (!differ.empty()) HYB_THROW(RuntimeError, "MPI ranks ", differ, " of ", gRanks.size, " selected other bricks than rank 0 for one frame");
  // Every rank draws its part of that selection, not one it would make again.
  if (quality->renderer == Renderer::Slices) quality->selection = std::make_shared<const Selection>(m->split.selection);
  m->comm = icetCreateMPICommunicator(MPI_COMM_WORLD);
  m->context = icetCreateContext(m->comm);
  icetDiagnostics(ICET_DIAG_ERRORS | ICET_DIAG_ALL_NODES);
  icetResetTiles();
  icetAddTile(0, 0, view.camera.width, view.camera.height, 0);  // one image, on rank 0
  icetSetColorFormat(ICET_IMAGE_COLOR_RGBA_FLOAT);
  icetSetDepthFormat(ICET_IMAGE_DEPTH_NONE);
  icetCompositeMode(ICET_COMPOSITE_MODE_BLEND);  // premultiplied "over"
  icetStrategy(ICET_STRATEGY_REDUCE);
  icetSingleImageStrategy(ICET_SINGLE_IMAGE_STRATEGY_AUTOMATIC);
  icetEnable(ICET_ORDERED_COMPOSITE);
  std::vector<IceTInt> order(m->split.frontToBack.begin(), m->split.frontToBack.end());
  icetCompositeOrder(order.data());  // the first rank's image in front
}

RankFrame::~RankFrame() {
  if (m->context) icetDestroyContext(m->context);
  if (m->comm) icetDestroyMPICommunicator(m->comm);
}

void RankFrame::composite(RenderedFrame* frame) {
  // The whole frame's counts, in every rank.
  SlicesStats& sl = frame->stats.slices;
  RaycastStats& ra = frame->stats.rays;
  uint64_t* counts[] = {&sl.bricks, &sl.uploadedBricks, &sl.blendedBricks, &sl.texels, &sl.textureBytes, &sl.slices, &sl.shellBricks,
                        &sl.surfaceTriangles, &sl.unseenTriangles, &sl.slabPolygonDraws, &sl.fragments, &sl.cutPolygons, &sl.cutLineSegments,
                        &ra.samples, &ra.skippedLeaves, &ra.surfaceHits, &ra.rays};
  std::vector<uint64_t> mine, sum(std::size(counts));
  for (const uint64_t* c : counts) mine.push_back(*c);
  MPI_Allreduce(mine.data(), sum.data(), int(mine.size()), MPI_UINT64_T, MPI_SUM, MPI_COMM_WORLD);
  for (size_t i = 0; i < sum.size(); ++i) *counts[i] = sum[i];
  Image& image = frame->image;
  // Rank 0 hears of each rank's region done, as they come (the run's progress); then all meet, so
  // that the wait for the slowest rank is measured apart from the compositing.
  const auto w0 = Clock::now();
  constexpr int kDoneTag = 7;
  if (gRanks.root()) {
    ProgressTask task(m->progress, "ranks rendered", uint64_t(gRanks.size));
    task.advance();
    for (int k = 1; k < gRanks.size; ++k) {
      double ms = 0;
      MPI_Recv(&ms, 1, MPI_DOUBLE, MPI_ANY_SOURCE, kDoneTag, MPI_COMM_WORLD, MPI_STATUS_IGNORE);
      task.advance();
    }
  } else {
    const double ms = frame->stats.renderMs;
    MPI_Send(&ms, 1, MPI_DOUBLE, 0, kDoneTag, MPI_COMM_WORLD);
  }
  MPI_Barrier(MPI_COMM_WORLD);
  m->waitMs.push_back(msSince(w0));
  const auto t0 = Clock::now();
  // IceT images are bottom-up; ours are top-down: neither is turned, so the composite is ours.
  const IceTInt viewport[4] = {0, 0, image.width, image.height};
  const IceTDouble identity[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
  const IceTFloat background[4] = {0, 0, 0, 0};
  const IceTImage result = icetCompositeImage(image.pixels.data(), nullptr, viewport, identity, identity, background);
  if (gRanks.root()) {
    if (icetImageIsNull(result) || icetImageGetNumPixels(result) != IceTSizeType(image.pixels.size()))
      HYB_THROW(RuntimeError, "IceT returned no image of ", image.width, "x", image.height, " on rank 0");
    const IceTFloat* c = icetImageGetColorcf(result);
    std::copy(c, c + 4 * image.pixels.size(), &image.pixels.front().r);
  }
  m->renderMs.push_back(frame->stats.renderMs);
  m->compositeMs.push_back(msSince(t0));
}

std::string RankFrame::report(std::string* json) {
  RankLine mine;
  const RegionBox& box = m->split.regions.boxes[size_t(gRanks.rank)];
  const Selection& selection = m->split.selection;  // the reference's frames carry none
  for (size_t b = 0; b < selection.bricks.size(); ++b)
    if (m->split.regions.brickRegion[b] == uint32_t(gRanks.rank) && !selection.bricks[b].hidden) {
      ++mine.bricks;
      mine.texels += double(selection.bricks[b].texelCount());
    }
  if (const auto& store = m->renderer->scene().knots) mine.blocksRead = double(store->cacheStats().misses);
  // The best frame's times (--repeat).
  const size_t best = size_t(std::min_element(m->renderMs.begin(), m->renderMs.end()) - m->renderMs.begin());
  mine.waitMs = m->waitMs[best];
  mine.compositeMs = m->compositeMs[best];
  mine.renderMs = m->renderMs[best];
  mine.rssMb = peakRssMb();
  mine.cost = m->cost;
  for (int a = 0; a < 3; ++a) {
    mine.lo[a] = box.lo[a];
    mine.hi[a] = box.hi[a];
  }
  constexpr int kDoubles = sizeof(RankLine) / sizeof(double);
  std::vector<RankLine> all(size_t(gRanks.size));
  MPI_Gather(&mine, kDoubles, MPI_DOUBLE, all.data(), kDoubles, MPI_DOUBLE, 0, MPI_COMM_WORLD);
  if (!gRanks.root()) return "";
  std::ostringstream text, j;
  text << std::fixed;
  j << "[";
  double slowest = 0, sum = 0;
  auto mm = [](double lo, double hi) {
    std::ostringstream s;
    s << std::fixed << std::setprecision(0);
    if (std::isinf(lo)) s << "-"; else s << lo;
    s << "..";
    if (std::isinf(hi)) s << "-"; else s << hi;
    return s.str();
  };
  for (int r = 0; r < gRanks.size; ++r) {
    const RankLine& l = all[size_t(r)];
    text << std::setprecision(1) << "rank     " << r << "/" << gRanks.size << ": region x " << mm(l.lo[0], l.hi[0]) << ", y " << mm(l.lo[1], l.hi[1])
         << ", z " << mm(l.lo[2], l.hi[2]) << " mm (grid), " << std::setprecision(0) << l.bricks << " bricks, " << l.texels << " texels, " << l.blocksRead << " blocks read, render "
         << std::setprecision(1) << l.renderMs << " ms, wait " << l.waitMs << " ms, composite " << l.compositeMs << " ms, peak RSS " << std::setprecision(0) << l.rssMb << " MB\n";
    j << (r ? "," : "") << "{\"rank\":" << r << ",\"bricks\":" << l.bricks << ",\"texels\":" << l.texels << ",\"blocks_read\":" << l.blocksRead << ",\"cost\":" << l.cost
      << ",\"render_ms\":" << l.renderMs << ",\"wait_ms\":" << l.waitMs << ",\"composite_ms\":" << l.compositeMs << ",\"peak_rss_mb\":" << l.rssMb << "}";
    slowest = std::max(slowest, l.renderMs);
    sum += l.renderMs;
  }
  j << "]";
  text << std::setprecision(2) << "ranks    " << gRanks.size << ", the slowest render " << (sum > 0 ? slowest / (sum / gRanks.size) : 1.0)
       << "x the mean; composited by IceT in visibility order\n";
  if (json) *json = j.str();
  return text.str();
}

RenderedFrame renderFrame(SceneRenderer& renderer, const View& view, const Look& look, const Quality& quality, const Progress* progress) {
  if (!gRanks.mpi) return renderer.render(view, look, quality);
  Quality q = quality;
  RankFrame ranked(renderer, view, look, &q, progress);
  const auto t0 = Clock::now();
  RenderedFrame frame = renderer.render(view, look, q);
  ranked.composite(&frame);
  frame.stats.renderMs = msSince(t0);
  return frame;
}

#else

RenderedFrame renderFrame(SceneRenderer& renderer, const View& view, const Look& look, const Quality& quality, const Progress*) {
  return renderer.render(view, look, quality);
}

Ranks startRanks(int*, char***) {
  if (std::getenv("OMPI_COMM_WORLD_SIZE") || std::getenv("PMI_SIZE") || std::getenv("PMIX_RANK"))
    std::fprintf(stderr, "hybrid-octree: warning: started by an MPI launcher, but built without MPI (-DHYB_MPI=ON): each process runs the whole command\n");
  return gRanks;
}
void endRanks(const Ranks&, int) {}
struct RankFrame::State {};
RankFrame::RankFrame(SceneRenderer&, const View&, const Look&, Quality*, const Progress*) { HYB_THROW(ValueError, "this build has no MPI (configure with -DHYB_MPI=ON)"); }
RankFrame::~RankFrame() = default;
void RankFrame::composite(RenderedFrame*) {}
std::string RankFrame::report(std::string*) { return ""; }

#endif

}  // namespace hyb::app
