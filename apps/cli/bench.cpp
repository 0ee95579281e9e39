#include "apps/cli/bench.h"
#include "apps/ranks/ranks.h"

#include <spawn.h>
#include <sys/wait.h>

#include <algorithm>
#include <filesystem>
#include <iomanip>
#include <limits>
#include <ostream>
#include <sstream>

#include "render/gl_context.h"
#include "render/slices/brick_textures.h"
#include "volume/core/file_util.h"

extern char** environ;

namespace hyb::app {

namespace {

// "a,b,c" into numbers, each checked by @p ok; throws ValueError naming @p flag.
std::vector<double> parseList(const std::string& text, const std::string& flag, bool (*ok)(double), const char* expected) {
  const std::vector<double> out = parseNumbers(text, flag, 0, expected);
  for (double x : out)
    if (!ok(x)) HYB_THROW(ValueError, flag, " '", text, "' invalid (expected ", expected, ")");
  return out;
}

// The default ε sweep: for each of 1/2, 1/4, … 1/64 of this view's full-resolution texels, the
// smallest nodal error whose selection holds no more (a selection changes only where ε passes a
// nodal error, or, with a focus, a nodal error over a node's importance: the search still finds
// where the texels halve, at a nearby error), each once, none beyond what the coarsest selection
// reaches (none at all for a constant volume, whose every error is 0).
std::vector<double> epsilonsOfTheView(SceneRenderer& renderer, const View& view, const Look& look, Quality quality) {
  std::vector<float> errors;
  for (const float e : renderer.octree().errorData())
    if (e > 0.0f && std::isfinite(e)) errors.push_back(e);
  std::sort(errors.begin(), errors.end());
  errors.erase(std::unique(errors.begin(), errors.end()), errors.end());
  quality.renderer = Renderer::Slices;
  quality.budgetMb = quality.budgetPercent = 0.0;
  auto texels = [&](double epsilon) {
    quality.epsilon = epsilon;
    return renderer.select(view, look, quality).texels;
  };
  const double full = double(texels(0.0));
  std::vector<double> out;
  size_t first = 0;
  for (int k = 1; k <= 6; ++k) {
    size_t a = first, b = errors.size();  // the first error whose selection holds at most full / 2^k
    while (a < b) {
      const size_t mid = a + (b - a) / 2;
      if (double(texels(errors[mid])) <= full / double(1 << k))
        b = mid;
      else
        a = mid + 1;
    }
    if (a == errors.size()) break;
    if (out.empty() || double(errors[a]) != out.back()) out.push_back(errors[a]);
    first = a;
  }
  return out;
}

// One measured point of the sweep.
struct Point {
  std::string sweep;  // full, epsilon or budget
  double epsilon = 0, budgetFraction = 0, budgetMb = 0;
  bool blend = true;
  size_t bricks = 0, textured = 0, blended = 0;
  uint64_t textureBytes = 0;
  float maxError = 0;
  double selectMs = 0, frameMs = 0, firstFrameMs = 0, psnrDb = 0, ssim = 0;
  float seam = 0;  // with blending: the largest step it removes between levels (data units)
  std::string image;
};

// Columns of trade.csv, 1-based as gnuplot counts them.
constexpr int kColumnTextureBytes = 9, kColumnFrameMs = 12, kColumnPsnr = 14;

// Runs gnuplot on @p script; false when it cannot be started or fails.
bool runGnuplot(const std::string& script) {
  const char* argv[] = {"gnuplot", script.c_str(), nullptr};
  pid_t pid = 0;
  if (posix_spawnp(&pid, "gnuplot", nullptr, nullptr, const_cast<char* const*>(argv), environ) != 0) return false;
  int status = 0;
  if (waitpid(pid, &status, 0) != pid) return false;
  return WIFEXITED(status) && WEXITSTATUS(status) == 0;
}

// Labels of the epsilon sweep's points (full resolution first) in one panel, @p y giving a point's
// value there. Points that would overprint the previous label share it, as "first-last" epsilon:
// texture bytes within 3 % and either the same image (PSNR within 0.05 dB; their frame times differ
// by noise only) or a value within 5 % of the panel's range.
std::string epsilonLabels(const std::vector<Point>& sweep, double (*y)(const Point&)) {
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  for (const Point& p : sweep) lo = std::min(lo, y(p)), hi = std::max(hi, y(p));
  const double near = 0.05 * std::max(hi - lo, 1e-9);
  std::ostringstream g;
  for (size_t i = 0; i < sweep.size();) {
    const Point& first = sweep[i];
    size_t j = i + 1;
    while (j < sweep.size() && std::abs(double(sweep[j].textureBytes) / double(std::max<uint64_t>(first.textureBytes, 1)) - 1.0) < 0.03 &&
           (std::abs(sweep[j].psnrDb - first.psnrDb) < 0.05 || std::abs(y(sweep[j]) - y(first)) < near))
      ++j;
    std::ostringstream text;
    text << std::setprecision(3) << first.epsilon;
    if (j - i > 1) text << "-" << sweep[j - 1].epsilon;
    g << "set label '" << text.str() << "' at " << std::fixed << std::setprecision(6) << double(first.textureBytes) / 1048576.0 << "," << y(first)
      << " center offset 0,0.9 tc rgb '#555555' front\n";
    i = j;
  }
  return g.str();
}

// The gnuplot script of the two panels: PSNR and frame time against texture memory.
std::string plotScript(const std::string& csv, const std::string& png, const std::string& title, const std::vector<Point>& points) {
  std::vector<Point> sweep;  // full resolution and the epsilon sweep, in order
  for (const Point& p : points)
    if (p.sweep != "budget") sweep.push_back(p);
  std::ostringstream g;
  auto series = [&](int column, double (*y)(const Point&)) {
    g << "unset label\n" << epsilonLabels(sweep, y);
    g << "plot f u ((strcol(1) eq 'full' || strcol(1) eq 'epsilon') ? $" << kColumnTextureBytes << "/1048576 : NaN):" << column
      << " w lp pt 7 lw 2 t 'epsilon_u sweep (blend on)', \\\n"
      << "     f u (strcol(1) eq 'budget' && strcol(5) eq 'on' ? $" << kColumnTextureBytes << "/1048576 : NaN):" << column
      << " w lp pt 5 lw 2 t 'budget sweep, blend on', \\\n"
      << "     f u (strcol(1) eq 'budget' && strcol(5) eq 'off' ? $" << kColumnTextureBytes << "/1048576 : NaN):" << column
      << " w lp pt 4 lw 1 dt 2 t 'budget sweep, blend off'\n";
  };
  g << "set terminal pngcairo size 1280,540 font 'sans,11'\n"
    << "set output '" << png << "'\n"
    << "set datafile separator ','\nset datafile columnheaders\nf = '" << csv << "'\n"
    << "set multiplot layout 1,2 title '" << title << "' noenhanced\n"
    << "set grid\nset logscale x 2\nset offsets graph 0.03, graph 0.03, graph 0.1, graph 0.03\nset xlabel 'texture memory (MB)'\nset key bottom right\n"
    << "set ylabel 'PSNR against the reference ray tracer (dB)'\n";
  series(kColumnPsnr, [](const Point& p) { return p.psnrDb; });
  g << "set ylabel 'frame time (ms)'\nset key top left\n";
  series(kColumnFrameMs, [](const Point& p) { return p.frameMs; });
  g << "unset multiplot\n";
  return g.str();
}

}  // namespace

std::string BenchOptions::validate() const {
  if (outDir.empty()) return "-o missing (expected the output directory)";
  if (repeat < 1 || repeat > 100) return "--repeat must be in 1..100";
  if (rounds < 1 || rounds > 100) return "--rounds must be in 1..100";
  // The directory is made last, but where it goes must take files now, before the frames.
  namespace fs = std::filesystem;
  std::error_code ec;
  fs::path at = fs::absolute(outDir, ec);
  while (!at.empty() && !fs::exists(at, ec) && at != at.parent_path()) at = at.parent_path();
  if (std::string e = outputPathError((fs::is_directory(at, ec) ? at / "trade.csv" : at).string(), "-o"); !e.empty()) return e;
  return render.validate();
}

void BenchOptions::add(CLI::App* cmd) {
  render.add(cmd);
  cmd->add_option("-o,--output", outDir, "directory for trade.csv, trade.png and the images");
  cmd->add_option("--epsilons", epsilons, "epsilon_u values in data units, comma-separated (default: the smallest nodal errors at which this view's selection holds 1/2, 1/4, ... 1/64 of the full-resolution texels)");
  cmd->add_option("--budgets", budgets, "texture budgets as fractions of the full-resolution bytes")->capture_default_str();
  cmd->add_option("--repeat", repeat, "frames per point: the first packs and uploads the brick textures, the fastest of the others (warm) counts; 1: the first")->capture_default_str();
  cmd->add_option("--rounds", rounds, "passes over all the points, each keeping its fastest frames (a slow spell of a shared machine then does not land on one point)")
      ->capture_default_str();
  cmd->add_flag("!--no-plot", plot, "skip the gnuplot plot");
}

namespace {

// The epsilons the sweep chose from the view's nodal errors.
void printEpsilons(const std::vector<double>& epsilons, std::ostream& out) {
  if (epsilons.empty()) {
    out << "epsilons: none (every nodal error is 0: each selection is the full resolution)\n";
    return;
  }
  out << "epsilons";
  for (const double e : epsilons) out << " " << e;
  out << ": the smallest nodal errors whose selection holds at most 1/2, 1/4, ... of this view's full-resolution texels (up to 1/64)\n";
}

// A point's frame quality: the slice renderer at the point's epsilon, budget and blending.
Quality sliceQuality(const Quality& base, const Point& p) {
  Quality q = base;
  q.renderer = Renderer::Slices;
  q.epsilon = p.epsilon;
  q.budgetMb = p.budgetMb;
  q.budgetPercent = 0.0;
  q.blend = p.blend;
  q.progressive = 1;
  return q;
}

// The sweep's table: one row per point.
void writeTradeCsv(const std::string& path, const std::vector<Point>& points) {
  writeFileAtomically(path, [&](std::ostream& s) {
    s << "sweep,epsilon,budget_fraction,budget_mb,blend,bricks,textured_bricks,blended_bricks,texture_bytes,max_error,select_ms,frame_ms,"
         "first_frame_ms,psnr_db,ssim,image\n";
    for (const Point& p : points)
      s << std::setprecision(6) << p.sweep << "," << p.epsilon << "," << p.budgetFraction << "," << p.budgetMb << "," << (p.blend ? "on" : "off")
        << "," << p.bricks << "," << p.textured << "," << p.blended << "," << p.textureBytes << "," << p.maxError << "," << p.selectMs << ","
        << p.frameMs << "," << p.firstFrameMs << "," << p.psnrDb << "," << p.ssim << "," << p.image << "\n";
  });
}

// The summary: the full resolution's and each budget's trade, what a paged scene read, and whether
// the trade only loses accuracy and bytes along each sweep.
void printSummary(const std::vector<Point>& points, size_t budgets, double fullMb, double referenceMs, const Scene& scene, std::ostream& out) {
  const Point& base = points[0];
  out << std::setprecision(2) << "summary  full resolution: " << fullMb << " MB, " << std::setprecision(1) << base.frameMs << " ms, "
      << std::setprecision(2) << base.psnrDb << " dB; reference " << std::setprecision(1) << referenceMs << " ms\n";
  const size_t firstBudget = points.size() - 2 * budgets;
  for (size_t i = 0; i < budgets; ++i) {
    const Point &on = points[firstBudget + i], &off = points[firstBudget + budgets + i];
    out << "  budget " << std::setprecision(4) << on.budgetFraction << ": " << std::setprecision(2) << base.frameMs / on.frameMs
        << "x faster than full, " << on.psnrDb << " dB; blending costs " << std::setprecision(1) << 100.0 * (on.frameMs / off.frameMs - 1.0)
        << " % frame time, " << 100.0 * (double(on.textureBytes) / double(std::max<uint64_t>(off.textureBytes, 1)) - 1.0)
        << " % texture bytes, " << std::setprecision(2) << on.psnrDb - off.psnrDb << " dB, and removes steps of up to "
        << std::setprecision(1) << on.seam << " between levels (data units)\n";
  }
  if (const auto& store = scene.knots) {
    // What the paged scene read through its cache over the whole run.
    const StoreCacheStats c = store->cacheStats();
    out << std::setprecision(1) << std::fixed << "store    " << c.misses << " blocks read (" << double(c.bytesRead) / 1048576.0
        << " MB compressed), " << c.hits << " from the cache, " << c.evicted << " evicted; the cache holds "
        << double(c.bytesHeld) / 1048576.0 << " of " << double(c.limit) / 1048576.0 << " MB\n"
        << std::defaultfloat;
  }
  // The trade should only lose accuracy and bytes along each sweep.
  std::vector<TradePoint> epsilonSweep{{"full resolution", base.psnrDb, base.textureBytes}}, budgetSweep = epsilonSweep;
  for (const Point& p : points) {
    std::ostringstream label;
    label << std::setprecision(6) << p.sweep << " " << (p.sweep == "epsilon" ? p.epsilon : p.budgetFraction);
    if (p.sweep == "epsilon") epsilonSweep.push_back({label.str(), p.psnrDb, p.textureBytes});
    if (p.sweep == "budget" && p.blend) budgetSweep.push_back({label.str(), p.psnrDb, p.textureBytes});
  }
  std::vector<std::string> breaks = monotonicityBreaks(epsilonSweep);
  for (const std::string& b : monotonicityBreaks(budgetSweep)) breaks.push_back(b);
  if (breaks.empty()) out << "  monotonic: PSNR and texture bytes fall as epsilon grows and as the budget shrinks (0.2 dB tolerance)\n";
  for (const std::string& b : breaks) out << "  not monotonic: " << b << "\n";
}

// The plot of the table (gnuplot), written beside it.
void writePlot(const BenchOptions& o, const Camera& camera, const std::string& dir, const std::vector<Point>& points, std::ostream& out) {
  namespace fs = std::filesystem;
  auto file = [&](const std::string& name) { return (fs::path(dir) / name).string(); };
  std::error_code ec;
  std::ostringstream title;
  title << "hybrid-octree speed/accuracy: " << fs::path(o.render.input.path).filename().string() << ", " << camera.width << "x"
        << camera.height << (camera.ortho ? ", orthographic" : ", perspective");
  const std::string png = file("trade.png"), tmp = file(".trade.png.tmp");
  writeFileAtomically(file("trade.gp"), [&](std::ostream& s) { s << plotScript(file("trade.csv"), tmp, title.str(), points); });
  if (!runGnuplot(file("trade.gp"))) {
    fs::remove(tmp, ec);
    HYB_THROW(RuntimeError, file("trade.gp"), ": gnuplot failed or is not installed (apt-get install gnuplot-nox); the CSV is written");
  }
  fs::rename(tmp, png, ec);
  if (ec) HYB_THROW(IoError, png, ": cannot write the plot (", ec.message(), ")");
  out << "wrote    " << png << "\n";
}

}  // namespace

int runBench(const BenchOptions& o, std::ostream& out, std::ostream& err) {
  namespace fs = std::filesystem;
  // Bad lists or a bad volume leave no output directory behind: it is created last.
  const std::vector<double> budgets =
      parseList(o.budgets, "--budgets", [](double x) { return x > 0.0 && x <= 1.0; }, "fractions in (0, 1]");
  std::vector<double> epsilons;
  if (!o.epsilons.empty())
    epsilons = parseList(o.epsilons, "--epsilons", [](double x) { return std::isfinite(x) && x >= 0.0; }, "finite values >= 0");
  RenderJob job = prepareRender(o.render, out, err);
  if (o.epsilons.empty()) {
    epsilons = epsilonsOfTheView(*job.renderer, job.view, job.look, job.quality);
    printEpsilons(epsilons, out);
  }
  std::error_code ec;
  const bool root = ranks().root();  // across MPI ranks, rank 0 writes the files
  if (root) fs::create_directories(o.outDir, ec);
  if (root && (ec || !fs::is_directory(o.outDir))) HYB_THROW(IoError, o.outDir, ": cannot create the output directory (", ec.message(), ")");
  const std::string dir = fs::path(o.outDir).string();
  auto file = [&](const std::string& name) { return (fs::path(dir) / name).string(); };

  if (job.look.iso) out << surfaceLine(job.renderer->prepare(job.view, job.look, Quality{}), *job.look.iso, false);
  // The reference: the CPU hybrid ray tracer at full resolution.
  Quality reference = job.quality;
  reference.renderer = Renderer::Raycast;
  reference.step.reset();
  reference.progressive = 1;
  reference.adaptive = 0;
  auto t0 = Clock::now();
  const Image referenceImage = renderFrame(*job.renderer, job.view, job.look, reference, o.render.input.progress).image;
  const double referenceMs = msSince(t0);
  if (root) writePng(file("reference.png"), referenceImage, job.background);
  const std::vector<uint8_t> refRgba = toRgba8(referenceImage, job.background);
  out << "reference ray tracer: " << std::fixed << std::setprecision(1) << referenceMs << " ms -> " << file("reference.png") << "\n";

  const size_t total = 1 + size_t(std::count_if(epsilons.begin(), epsilons.end(), [](double e) { return e > 0.0; })) + 2 * budgets.size();
  std::vector<Point> points;
  // The point's frames: the first packs and uploads the brick textures (and compiles the program);
  // the frames after it reuse them, and the fastest of those is the point's frame time.
  auto frames = [&](Point* p) {
    RenderedFrame f;
    for (int r = 0; r < o.repeat; ++r) {
      if (r == 0) job.renderer->dropTextures();
      f = renderFrame(*job.renderer, job.view, job.look, sliceQuality(job.quality, *p), o.render.input.progress);
      const double ms = f.stats.renderMs;
      if (r == 0) {
        p->firstFrameMs = std::min(p->firstFrameMs, ms);
        p->selectMs = std::min(p->selectMs, f.stats.selectMs);
      }
      if (r > 0 || o.repeat == 1) p->frameMs = std::min(p->frameMs, ms);
    }
    return f;
  };
  auto measure = [&](Point p) {
    p.frameMs = p.firstFrameMs = p.selectMs = std::numeric_limits<double>::infinity();
    const RenderedFrame f = frames(&p);
    const std::vector<uint8_t> rgba = toRgba8(f.image, job.background);
    p.psnrDb = std::min(99.0, psnr(rgba, refRgba));  // 99: identical
    p.ssim = ssim(rgba, refRgba, f.image.width, f.image.height);
    p.bricks = f.selection.bricks.size();
    p.textured = f.stats.slices.bricks;
    p.blended = f.stats.slices.blendedBricks;
    p.textureBytes = f.stats.slices.textureBytes;
    p.maxError = f.selection.maxError;
    if (p.blend) {
      const Scene& scene = job.renderer->scene();
      const VolumeKnots inMemory(scene.volume, scene.octree);
      const KnotSource& knots = scene.knots ? static_cast<const KnotSource&>(*scene.knots) : inMemory;
      for (const Brick& b : f.selection.bricks)
        if (!b.hidden) p.seam = std::max(p.seam, seamHeight(knots, scene.octree, b));
    }
    std::ostringstream name;
    name << p.sweep;
    if (p.sweep == "epsilon") name << "_" << p.epsilon;
    if (p.sweep == "budget") name << "_" << p.budgetFraction << "_blend_" << (p.blend ? "on" : "off");
    p.image = name.str() + ".png";
    if (root) writePng(file(p.image), f.image, job.background);
    points.push_back(p);
    out << "[" << points.size() << "/" << total << "] " << std::left << std::setw(28) << name.str() << std::right << std::setprecision(2)
        << std::setw(8) << double(p.textureBytes) / 1048576.0 << " MB " << std::setw(5) << p.textured << " bricks " << std::setprecision(1)
        << std::setw(8) << p.frameMs << " ms (first " << std::setw(6) << p.firstFrameMs << ") " << std::setprecision(2) << std::setw(6) << p.psnrDb
        << " dB  SSIM " << std::setprecision(4) << p.ssim << std::endl;
  };
  Point full;
  full.sweep = "full";
  measure(full);
  for (double e : epsilons) {
    if (e == 0.0) continue;
    Point p;
    p.sweep = "epsilon";
    p.epsilon = e;
    measure(p);
  }
  const double fullMb = double(points[0].textureBytes) / 1048576.0;
  for (bool blend : {true, false})  // one run of rows per series, so the plot joins them
    for (double b : budgets) {
      Point p;
      p.sweep = "budget";
      p.budgetFraction = b;
      p.budgetMb = b * fullMb;
      p.blend = blend;
      measure(p);
    }

  // Later rounds take every point's frames again, in the same order.
  for (int round = 2; round <= o.rounds; ++round) {
    for (Point& p : points) frames(&p);
    out << "round " << round << "/" << o.rounds << ": fastest frames so far, full resolution " << std::setprecision(1) << points[0].frameMs
        << " ms, last point " << points.back().frameMs << " ms" << std::endl;
  }

  // The table and the plot.
  if (!root) return 0;
  writeTradeCsv(file("trade.csv"), points);
  out << "wrote    " << file("trade.csv") << "\n";
  printSummary(points, budgets.size(), fullMb, referenceMs, job.renderer->scene(), out);
  if (o.plot) writePlot(o, job.view.camera, dir, points, out);
  return 0;
}

std::vector<std::string> monotonicityBreaks(const std::vector<TradePoint>& sweep, double toleranceDb) {
  std::vector<std::string> breaks;
  for (size_t i = 1; i < sweep.size(); ++i) {
    const TradePoint &a = sweep[i - 1], &b = sweep[i];
    std::ostringstream line;
    line << std::fixed << std::setprecision(2) << a.label << " -> " << b.label << ":";
    if (b.psnrDb > a.psnrDb + toleranceDb) line << " PSNR +" << b.psnrDb - a.psnrDb << " dB";
    if (b.textureBytes > a.textureBytes) line << " texture bytes +" << b.textureBytes - a.textureBytes;
    if (b.psnrDb > a.psnrDb + toleranceDb || b.textureBytes > a.textureBytes) breaks.push_back(line.str());
  }
  return breaks;
}

}  // namespace hyb::app
