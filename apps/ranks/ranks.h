// Sort-last rendering across MPI ranks (docs/distributed.md): on an MPI build (-DHYB_MPI=ON)
// started by an MPI launcher (`mpirun -np N hybrid-octree render …`), each rank renders one region
// of the frame's selection (SceneRenderer::sortLast) and IceT composites the ranks' premultiplied
// images in the regions' visibility order (ICET_ORDERED_COMPOSITE, blend). Without MPI, or when
// the process was not launched by mpirun, a run is one process and nothing here does anything.
#pragma once

#include <iosfwd>
#include <memory>
#include <string>
#include <vector>

#include "render/scene_renderer.h"

namespace hyb::app {

/// This process's place in a run.
struct Ranks {
  int rank = 0, size = 1;
  bool mpi = false;  ///< MPI was started: the run is sort-last, even on one rank
  bool root() const { return rank == 0; }
};

/// Starts MPI when the build has it and an MPI launcher started this process (its environment
/// says so); a single process otherwise. Call once, first thing in main().
Ranks startRanks(int* argc, char*** argv);
/// Ends the run: MPI_Finalize after a success, MPI_Abort with @p exitCode after a failure (so
/// that no other rank waits for this one). No-op without MPI.
void endRanks(const Ranks& ranks, int exitCode);
/// The process's ranks (a single process before startRanks).
const Ranks& ranks();

/// One rank's part in a sort-last frame: its region, then its image composited with the others'.
class RankFrame {
 public:
  /// Splits the frame of @p view, @p look, @p quality into one region per rank and sets
  /// @p quality's region to this rank's. Every rank must call it with the same frame.
  /// @p progress (rank 0's, or none) hears of the ranks' regions done ("ranks rendered").
  /// @throw RuntimeError when the ranks' selections differ.
  RankFrame(SceneRenderer& renderer, const View& view, const Look& look, Quality* quality, const Progress* progress = nullptr);
  ~RankFrame();
  RankFrame(const RankFrame&) = delete;
  RankFrame& operator=(const RankFrame&) = delete;

  /// Composites every rank's @p frame image (collective): on rank 0 it becomes the whole frame's.
  /// Records this rank's render and compositing times.
  void composite(RenderedFrame* frame);
  /// What each rank did and how long it took, one line each, and the balance (collective; the
  /// text on rank 0, empty elsewhere). @p json receives the same per rank on rank 0.
  std::string report(std::string* json);

 private:
  struct State;
  std::unique_ptr<State> m;
};

/// Renders a frame: across the ranks when the run is sort-last (each rank its region, composited
/// on rank 0; stats.renderMs then runs from the start of the rank's render to the end of the
/// compositing, so that rank 0's is the whole frame's), else in this process.
RenderedFrame renderFrame(SceneRenderer& renderer, const View& view, const Look& look, const Quality& quality, const Progress* progress = nullptr);

}  // namespace hyb::app
