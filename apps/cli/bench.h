// `hybrid-octree bench`: the speed/accuracy trade, measured (DESIGN 6).
#pragma once

#include <cstdint>
#include <iosfwd>
#include <string>
#include <vector>

#include "apps/cli/frame.h"

namespace hyb::app {

/// Options of the sweep; the render flags choose the scene (renderer: always slices, against the
/// reference ray tracer).
struct BenchOptions {
  RenderOptions render;
  std::string outDir;
  std::string epsilons;                            ///< ε_u values (data units); empty: where this view's selection halves, six times
  std::string budgets = "0.5,0.25,0.125,0.0625";  ///< fractions of the full-resolution texture bytes
  int repeat = 4;                                  ///< frames per point: the first uploads, the fastest of the others counts
  int rounds = 3;                                  ///< passes over all the points; each point keeps its fastest frames
  bool plot = true;                                ///< draw trade.png with gnuplot

  std::string validate() const;
  void add(CLI::App* cmd);
};

/// One point of a sweep as the monotonicity check sees it.
struct TradePoint {
  std::string label;  ///< e.g. "epsilon 401"
  double psnrDb = 0;
  uint64_t textureBytes = 0;
};

/// Where a sweep ordered from the most to the least accurate setting (ε_u growing, or the budget
/// shrinking) gains more than @p toleranceDb of PSNR or any texture bytes from one point to the
/// next: one line per such step ("epsilon 200 -> epsilon 401: PSNR +1.43 dB"); empty when the
/// trade is monotonic.
std::vector<std::string> monotonicityBreaks(const std::vector<TradePoint>& sweep, double toleranceDb = 0.2);

/// Sweeps ε_u (blending on) and the budget (blending on and off), and for each point records the
/// texture bytes, bricks, select time, frame time (the best warm frame) and first frame (the brick
/// textures' upload included) and PSNR/SSIM against the reference into
/// outDir/trade.csv, with the images and a plot outDir/trade.png. Prints progress and a summary on
/// @p out, warnings on @p err.
/// @throw ValueError / IoError for bad flags or unwritable outputs; RuntimeError when gnuplot fails.
int runBench(const BenchOptions& o, std::ostream& out, std::ostream& err);

}  // namespace hyb::app
