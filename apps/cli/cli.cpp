#include "apps/cli/cli.h"

#include "apps/cli/bench.h"
#include "apps/cli/frame.h"
#include "apps/ranks/ranks.h"
#include "apps/cli/outputs.h"
#include "apps/cli/pacs_command.h"
#include "apps/cli/progress_display.h"
#include "apps/viewer/viewer_server.h"

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <pthread.h>
#include <signal.h>
#include <unistd.h>

#include <chrono>
#include <iostream>
#include <filesystem>
#include <cmath>
#include <iomanip>
#include <limits>
#include <map>
#include <optional>
#include <ostream>
#include <sstream>

#include "hybrid_octree/hybrid_io.h"
#include "hybrid_octree/scene_cache.h"
#include "hybrid_octree/selection.h"
#include "hybrid_octree/surface_export.h"
#include "hybrid_octree/volume_octree.h"
#include "render/orientation_marker.h"
#include "render/raycast.h"
#include "render/slices.h"
#include "render/geometry_channel.h"
#include "surface/cgal_geometry.h"
#include "surface/dmc.h"
#include "surface/mesh_io.h"
#include "surface/mesh_ops.h"
#include "volume/core/file_util.h"
#include "volume/core/memory_limit.h"
#include "volume/dicomweb.h"
#include "volume/core/file_util.h"
#include "volume/core/memory_limit.h"
#include "volume/volume_io.h"

namespace hyb::app {

namespace {

std::string octreeSummary(const Volume& v, const VolumeOctree& t) {
  std::ostringstream s;
  size_t leaves = 0;
  for (const OctreeNode& n : t.nodes()) leaves += n.isLeaf();
  s << "octree   depth " << t.depth() << ", leaf edge " << t.leafEdge() << ", " << t.nodes().size() << " nodes (" << leaves
    << " leaves), " << t.errorData().size() << " nodal errors, coarse knots " << (t.prefiltered() ? "prefiltered" : "point-subsampled")
    << "\n";
  s << "memory   " << t.bytesUsed() << " bytes = " << std::fixed << std::setprecision(2)
    << 100.0 * double(t.bytesUsed()) / double(v.voxelCount() * scalarSize(v.storedType())) << " % of the " << scalarName(v.storedType())
    << " samples\n";
  const auto e = t.errors(t.root());
  s << "root     min " << t.root().minValue << "  max " << t.root().maxValue << "  errors";
  for (float x : e) s << " " << std::setprecision(1) << x;
  s << "\n";
  return s.str();
}

// --------------------------------------------------------------------------------------------
// Subcommands

struct InfoOptions {
  VolumeInput input;
  int bins = 24;
  std::string validate() const { return bins < 1 || bins > 4096 ? "--bins must be in 1..4096" : ""; }
};

// A DICOM folder's patients, studies and series, the default marked, and what was skipped.
std::string dicomListingText(const DicomListing& l) {
  std::ostringstream s;
  std::set<std::string> studies;
  for (const DicomSeriesInfo& x : l.series) studies.insert(x.studyUid);
  s << "series   " << l.series.size() << " in " << studies.size() << (studies.size() == 1 ? " study" : " studies") << " in " << l.dir
    << (l.dicomdir ? " (from its DICOMDIR)" : "") << "; the first is read by default, --series UID reads another:\n";
  // Grouped by patient and study, in the order of their first series.
  std::vector<std::string> order;
  for (const DicomSeriesInfo& x : l.series)
    if (std::find(order.begin(), order.end(), x.studyUid) == order.end()) order.push_back(x.studyUid);
  std::string patient = "\x01";
  for (const std::string& study : order) {
    const auto firstOf = std::find_if(l.series.begin(), l.series.end(), [&](const DicomSeriesInfo& x) { return x.studyUid == study; });
    const std::string who = (firstOf->patientName.empty() ? "(no name)" : firstOf->patientName) +
                            (firstOf->patientId.empty() ? "" : " (ID " + firstOf->patientId + ")");
    if (who != patient) s << "patient  " << (patient = who) << "\n";
    s << "  study  " << (firstOf->studyDate.empty() ? "(no date)" : firstOf->studyDate)
      << (firstOf->studyDescription.empty() ? "" : "  " + firstOf->studyDescription) << "  (" << (study.empty() ? "no UID" : study) << ")\n";
    for (const DicomSeriesInfo& x : l.series) {
      if (x.studyUid != study) continue;
      s << "    " << x.uid << "  " << (x.modality.empty() ? "?" : x.modality) << (x.number.empty() ? "" : "  #" + x.number) << "  " << x.slices
        << (x.slices == 1 ? " slice" : " slices") << " of " << x.columns << "x" << x.rows << "  " << formatBytes(x.bytes)
        << (x.date.empty() ? "" : "  " + x.date) << (x.description.empty() ? "" : "  " + x.description) << (x.localizer ? "  (localizer)" : "")
        << (&x == &l.series.front() ? "  (read by default)" : "") << "\n";
    }
  }
  size_t skipped = 0;
  std::string why;
  for (const auto& [reason, n] : l.skipped) {
    skipped += n;
    why += (why.empty() ? "" : ", ") + std::to_string(n) + " " + reason;
  }
  if (skipped) s << "skipped  " << skipped << " of " << l.files << " files: " << why << "\n";
  return s.str();
}

int runInfo(const InfoOptions& o, std::ostream& out, std::ostream& err) {
  if (std::error_code ec; !o.input.rawLayout()) {
    if (std::filesystem::is_directory(o.input.path, ec)) out << dicomListingText(listDicomSeries(o.input.path, o.input.progress));
    else if (const std::optional<DicomFolder> folder = dicomFolderOf(o.input.path, o.input.series))
      out << dicomListingText(listDicomSeries(folder->dir, o.input.progress, folder->recursive));
  }
  if (!o.input.rawLayout() && isSceneFile(o.input.path)) {
    if (!o.input.series.empty()) HYB_THROW(ValueError, "--series needs a DICOM directory (", o.input.path, " is a scene file)");
    Scene scene = loadScene(o.input.path, SceneLoadOptions{false, 0});
    const KnotStore& store = *scene.knots;
    const double stored = double(scene.volume.voxelCount() * scalarSize(scene.volume.storedType()));
    out << "file     " << o.input.path << " (scene)\n" << scene.volume.toString();
    out << "octree   " << scene.octree.nodes().size() << " nodes, " << scene.octree.bytesUsed() << " bytes\n";
    out << "store    " << store.levels().size() << " spacings (1.." << store.levels().back().spacing << ") in blocks of " << kStoreBlock
        << "^3 knots, " << formatBytes(store.compressedBytes()) << " compressed (" << std::fixed << std::setprecision(2)
        << double(store.compressedBytes()) / stored << "x the samples)\n";
    out << (scene.surface ? surfaceOctreeLine(*scene.surface, std::nullopt) : "surface  none (build --iso adds one)\n");
    // Every sample, a block at a time: the samples are never held.
    const Volume& v = scene.volume;
    out << "histogram (" << o.bins << " bins)\n"
        << formatHistogram(computeHistogram(v.voxelCount(), v.minValue(), v.maxValue(), o.bins, [&](const auto& use) { store.forEachValue(1, use); }));
    return 0;
  }
  const Volume v = o.input.read(err);
  out << "file     " << o.input.path << "\n" << v.toString();
  out << "histogram (" << o.bins << " bins)\n" << formatHistogram(computeHistogram(v, o.bins));
  return 0;
}

struct BuildOptions {
  VolumeInput input;
  std::string output;
  std::optional<double> iso;
  int leafEdge = 8;
  bool prefilter = true;
  std::string validate() const {
    if (output.empty()) return "-o missing (expected the scene file to write, e.g. -o scene.hoct)";
    if (std::string e = outputsError({{output, "-o"}}, {input.path}); !e.empty()) return e;
    if (leafEdge < 1 || leafEdge > 256 || (leafEdge & (leafEdge - 1))) return "--leaf-edge must be a power of two in 1..256";
    if (iso && !isFloat(*iso)) return "--iso must be a finite number within the float range (|x| <= 3.4e38)";
    return "";
  }
};


int runBuild(const BuildOptions& o, std::ostream& out, std::ostream& err) {
  if (!o.input.rawLayout() && isSceneFile(o.input.path))
    HYB_THROW(ValueError, o.input.path, ": a scene file, built already (build reads a volume; render, export, info and view read the scene)");
  // The build streams its input plane by plane: twice for the octree and its store, once more for
  // an isosurface.
  const std::unique_ptr<PlaneSource> planes = o.input.openPlanes(err);
  checkSceneGrid(planes->description().dims(), planes->name());
  KnotStoreWriter store = storeWriterFor(o.output, *planes);
  const auto t0 = Clock::now();
  const VolumeOctree t = VolumeOctree::build(*planes, VolumeOctreeOptions{o.leafEdge, o.prefilter, o.input.progress}, &store);
  const double ms = msSince(t0);
  const Volume v = planes->description().withRange(t.root().minValue, t.root().maxValue, planes->name());
  out << v.toString() << octreeSummary(v, t);
  out << "build    " << std::fixed << std::setprecision(1) << ms << " ms (" << double(v.voxelCount()) / (ms * 1e3)
      << " Mvoxels/s; " << (planes->whole() ? "read whole" : "streamed plane by plane") << ")\n";
  if (o.iso) {  // its nodes wait in a temporary file beside the scene, as the store's blocks do
    const auto t1 = Clock::now();
    const SpooledSurfaceOctree so = SpooledSurfaceOctree::build(*planes, t, float(*o.iso), spoolDirectoryFor(o.output),
                                                                SurfaceOctreeOptions{kMaxNodePlanes, 0, o.input.progress});
    out << surfaceOctreeLine(so, msSince(t1));
    saveScene(o.output, v, t, store, so);
  } else {
    saveScene(o.output, v, t, store);
  }
  out << "wrote    " << o.output << "\n";
  return 0;
}

// out.png -> out_<k>.png, the k-th image of a progressive sequence.
std::string progressivePath(const std::string& output, int k) {
  const std::filesystem::path p(output);
  return (p.parent_path() / (p.stem().string() + "_" + std::to_string(k) + p.extension().string())).string();
}

// The selection's summary: bricks, texels, the largest nodal error used, and per voxel-to-texel
// ratio the visible bricks and their texels.
void printSelection(const RenderJob& job, const RenderedFrame& f, std::ostream& out) {
  const Selection& sel = f.selection;
  std::map<int, std::pair<int, uint64_t>> perLevel;  // voxel-to-texel ratio -> (visible bricks, texels)
  size_t hidden = 0;
  for (const Brick& b : sel.bricks) {
    if (b.hidden) {
      ++hidden;
      continue;
    }
    auto& e = perLevel[1 << resolutionLevel(job.renderer->octree(), b)];
    ++e.first;
    e.second += b.texelCount();
  }
  const uint64_t bytesPerT = bytesPerTexel(job.quality.texelBits);
  out << "selection: epsilon " << job.quality.epsilon << ", " << sel.bricks.size() << " bricks (" << hidden << " transparent or culled), " << sel.texels
      << " texels (" << std::fixed << std::setprecision(2) << double(sel.texels * bytesPerT) / (1024.0 * 1024.0) << " MB; " << sel.blendedBricks
      << " bricks blend), max nodal error used " << sel.maxError << ", " << std::setprecision(3) << f.stats.selectMs << " ms\n";
  for (const auto& [ratio, e] : perLevel) out << "  voxel:texel " << ratio << ":1  " << e.first << " bricks, " << e.second << " texels\n";
}

// The frames of a render run: the last, and its times (--repeat: the fastest and the first).
struct RenderRun {
  RenderedFrame frame;
  double renderMs = std::numeric_limits<double>::infinity(), firstMs = 0, tableMs = 0, geometryMs = 0;
};

// The run's "render" line (and its classification's): what the frame drew and in what time.
void printRenderLines(const RenderJob& job, const RenderRun& run, int repeat, std::ostream& out) {
  const bool slices = job.quality.renderer == Renderer::Slices;
  const int pixels = job.view.camera.width * job.view.camera.height;
  const double renderMs = run.renderMs, firstMs = run.firstMs, tableMs = run.tableMs;
  const FrameStats& st = run.frame.stats;
  std::ostringstream timing;
  timing << std::fixed << std::setprecision(1);
  if (repeat > 1) timing << "first frame " << firstMs << " ms, best of " << repeat << " ";
  timing << renderMs << " ms";
  const glm::ivec2 size(job.view.camera.width, job.view.camera.height);
  if (slices) {
    out << "render   slices " << size.x << "x" << size.y << ", " << st.slices.bricks << " textured bricks (" << st.slices.blendedBricks << " blended), "
        << st.slices.textureBytes << " texture bytes, " << st.slices.slices << " slices, " << st.slices.slabPolygonDraws << " slab polygon draws";
    if (st.slices.unseenTriangles > 0) out << ", " << st.slices.unseenTriangles << " surface triangles between pixel centres left out";
    out << ", " << timing.str() << "\n";
  } else {
    out << "render   raycast " << size.x << "x" << size.y << ", " << st.rays.rays << " rays (" << std::setprecision(1)
        << 100.0 * double(st.rays.rays) / pixels << " % of the pixels), " << st.rays.samples << " samples, " << st.rays.skippedLeaves
        << " empty-space skips, " << st.rays.surfaceHits << " surface crossings, " << timing.str() << "\n";
  }
  if (job.quality.classification == Classification::PreIntegrated)
    out << "classify pre-integrated, table made in " << std::fixed << std::setprecision(1) << tableMs << " ms\n";
}

// --stats: the frame's report (FrameReport) with the command's own times and, across ranks, theirs.
std::string statsJson(const RenderJob& job, const RenderRun& run, const FrameStats& surface, const std::string& ranksJson) {
  const FrameReport report{run.frame, job.quality, job.view.camera, job.renderer->scene().knots.get(), run.renderMs, run.tableMs, run.geometryMs};
  nlohmann::ordered_json j = nlohmann::ordered_json::parse(report.json());
  j["build_ms"] = job.buildMs + surface.surfaceBuildMs;
  j["surface_polygons_ms"] = surface.surfacePolygonsMs;
  j["first_render_ms"] = run.firstMs;
  if (!ranksJson.empty()) j["ranks"] = nlohmann::ordered_json::parse(ranksJson);
  return j.dump(2);
}

int runRender(const RenderOptions& o, std::ostream& out, std::ostream& err) {
  // One frame keeps no brick texture beyond its draw; repeated frames reuse them.
  RenderJob job = prepareRender(o, out, err, o.repeat > 1 || o.settings.quality.progressive > 1);
  CommandOutputs outputs;  // the images and --stats, renamed into place together at the end
  const bool slices = job.quality.renderer == Renderer::Slices;
  const bool fromScene = job.renderer->scene().surface && job.look.iso && job.renderer->scene().surface->isovalue() == *job.look.iso;
  const int pixels = job.view.camera.width * job.view.camera.height;
  FrameStats surface = job.renderer->prepare(job.view, job.look, job.quality);
  if (job.look.iso) out << surfaceLine(surface, *job.look.iso, fromScene);
  // Across MPI ranks: this rank's region of the frame, composited with the others' by IceT.
  std::unique_ptr<RankFrame> rankFrame;
  if (ranks().mpi) {
    rankFrame = std::make_unique<RankFrame>(*job.renderer, job.view, job.look, &job.quality, o.input.progress);
  }
  // Progressive refinement: the images before the last (slices: coarser selections; the reference:
  // rays on sparser grids).
  const LevelCallback onLevel = [&](int level, int levels, const Image& image, const FrameStats& st) {
    const std::string path = progressivePath(o.output, level);
    Image shown = image;
    if (o.settings.marker) drawOrientationMarker(job.view.camera, &shown);
    outputs.write(path, [&](const std::string& to) { writePng(to, shown, job.background); });
    out << "progressive " << level << "/" << levels << ": " << std::fixed;
    if (slices)
      out << std::setprecision(2) << double(st.slices.textureBytes) / 1048576.0 << " MB, " << std::setprecision(1) << st.renderMs << " ms -> " << path << "\n";
    else
      out << st.rays.rays << " rays (" << std::setprecision(1) << 100.0 * double(st.rays.rays) / pixels << " % of the pixels), " << st.renderMs
          << " ms -> " << path << "\n";
  };
  // --repeat: the same view again; brick textures are uploaded once (as an interactive viewer would).
  RenderRun run;
  RenderedFrame& frame = run.frame;
  for (int r = 0; r < o.repeat; ++r) {
    const auto f0 = Clock::now();
    frame = job.renderer->render(job.view, job.look, job.quality, r == 0 && job.quality.progressive > 1 ? onLevel : LevelCallback{});
    if (rankFrame) {
      rankFrame->composite(&frame);
      frame.stats.renderMs = msSince(f0);  // the whole frame's, to the end of the compositing
    }
    if (r == 0) {
      if (job.look.iso && frame.stats.surfaceRegionsMade + frame.stats.surfaceRegionsKept > 0) {  // made by the frame, region by region
        surface = frame.stats;
        out << surfaceLine(surface, *job.look.iso, fromScene);
      }
      if (job.quality.budgetPercent > 0) {
        auto mb = [&](uint64_t texels) { return double(texels * bytesPerTexel(job.quality.texelBits)) / (1024.0 * 1024.0); };
        std::ostringstream line;
        line << "budget:  " << job.quality.budgetPercent << " % of the full-resolution " << std::fixed << std::setprecision(2)
             << mb(frame.stats.fullTexels) << " MB = " << mb(frame.stats.budgetTexels) << " MB\n";
        out << line.str();
      }
      if (slices) printSelection(job, frame, out);
      if (slices && !frame.selection.budgetMet)
        err << "hybrid-octree: warning: --budget " << o.settings.budget << (job.quality.budgetPercent > 0 ? "" : " MB") << " cannot be met; using "
            << frame.selection.texels << " texels\n";
      run.firstMs = frame.stats.renderMs;
      run.tableMs = frame.stats.preintegrationMs;
      run.geometryMs = frame.stats.geometryMs;
    }
    run.renderMs = std::min(run.renderMs, frame.stats.renderMs);
  }
  std::string ranksJson;
  if (rankFrame) {
    out << rankFrame->report(&ranksJson);
    if (!ranks().root()) return 0;  // rank 0 writes the frame
  }
  printRenderLines(job, run, o.repeat, out);
  Image image = std::move(run.frame.image);
  if (o.settings.marker) drawOrientationMarker(job.view.camera, &image);
  if (job.quality.progressive > 1)
    outputs.write(progressivePath(o.output, job.quality.progressive), [&](const std::string& to) { writePng(to, image, job.background); });
  outputs.write(o.output, [&](const std::string& to) { writePng(to, image, job.background); });
  if (!o.stats.empty()) {
    const std::string text = statsJson(job, run, surface, ranksJson);
    outputs.write(o.stats, [&](const std::string& to) { writeFileAtomically(to, [&](std::ostream& s) { s << text << "\n"; }); });
  }
  outputs.commit();
  out << "wrote    " << o.output << "\n";
  return 0;
}

struct ExportOptions {
  VolumeInput input;
  std::string output, surface = "dmc";
  std::optional<double> iso;
  bool check = false, closed = false, normals = false;
  std::optional<double> memoryMb;  // a scene file read paged (--surface octree): its octrees and cache
  // The user geometry scan-converted as a label or fraction volume on the CT's grid.
  std::vector<std::string> meshes, primitives;
  std::string meshSpace = "lps", labelVolume;
  bool fraction = false;
  FrameSettings geometry;  // the meshes and primitives, parsed by the frame table's rows
  /// Only the Surface Octree's surface is made through a scene's cache; the others need its samples.
  bool paged() const { return labelVolume.empty() && surface == "octree" && !closed && !check && !input.rawLayout() && isSceneFile(input.path); }
  std::string validate() {
    try {
      auto joined = [](const std::vector<std::string>& v) {
        std::string t;
        for (const std::string& x : v) t += (t.empty() ? "" : "\n") + x;
        return t;
      };
      if (!meshes.empty()) frameField("mesh")->parse(geometry, joined(meshes), "--mesh");
      if (!primitives.empty()) frameField("primitive")->parse(geometry, joined(primitives), "--primitive");
      frameField("mesh_space")->parse(geometry, meshSpace, "--mesh-space");
    } catch (const ValueError& e) {
      return e.what();
    }
    if (fraction && labelVolume.empty()) return "--fraction needs --label-volume";
    if (!labelVolume.empty()) {
      if (meshes.empty() && primitives.empty()) return "--label-volume needs --mesh or --primitive (the geometry it holds)";
      if (!writableVolume(labelVolume)) return "--label-volume '" + labelVolume + "' invalid (expected one of " + writableVolumeExtensionsText() + ")";
      if (std::string e = outputsError({{labelVolume, "--label-volume"}}, {input.path}); !e.empty()) return e;
      if (!iso && output.empty()) return "";  // the volume alone
    } else if (!meshes.empty() || !primitives.empty()) {
      return "--mesh and --primitive need --label-volume (export writes the isosurface's mesh, or the geometry's volume)";
    }
    if (!iso) return "--iso missing (expected the isovalue in data units)";
    if (memoryMb && !(*memoryMb >= 1.0 && *memoryMb <= 1e9)) return "--memory must be megabytes in [1, 1e9]";
    if (!isFloat(*iso)) return "--iso must be a finite number within the float range (|x| <= 3.4e38)";
    if (output.empty()) return "-o missing (expected mesh" + meshExtensionsText() + ")";
    const MeshFormat* format = meshFormatOf(output);
    if (!format) return "-o '" + output + "' has an unknown extension (expected " + meshExtensionsText() + ")";
    if (normals && !format->normals) return "--normals needs a " + meshExtensionsText(true) + " file (STL keeps facet normals, OFF none)";
    if (std::string e = outputsError({{output, "-o"}}, {input.path}); !e.empty()) return e;
    if (!isSurfaceKind(surface)) return "--surface '" + surface + "' invalid (expected " + kSurfaceKindsText + ")";
    return "";
  }
};

// One line of a mesh check that took @p ms.
std::string checkLine(const MeshCheck& c, double ms) {
  std::ostringstream time;
  time << std::fixed << std::setprecision(1) << ms / 1000.0;
  return std::string("check    manifold ") + (c.manifold ? "yes" : "no") + ", closed " + (c.closed ? "yes" : "no") + " (" +
         std::to_string(c.boundaryEdges) + " boundary edges), self-intersections " +
         (c.manifold ? (c.selfIntersecting ? "yes" : "no") : "not tested") + (c.closed ? std::string(", outward ") + (c.outward ? "yes" : "no") : "") +
         ", " + time.str() + " s\n";
}

int runExport(const ExportOptions& o, std::ostream& out, std::ostream& err) {
  double buildMs = 0;
  const uint64_t memoryBytes = sceneMemoryBytes(o.memoryMb);
  const Scene scene = loadOrBuild(o.input, out, err, &buildMs, VolumeOctreeOptions{}, SceneLoadOptions{!o.paged(), memoryBytes});
  if (!o.labelVolume.empty()) {
    // The meshes and primitives filtered (a box of one voxel) and scan-converted on the CT's grid.
    const auto t0 = Clock::now();
    std::vector<std::string> warnings;
    const Volume label = geometryVolume(userGeometry(o.geometry, scene.volume, err), scene.volume, o.fraction, &warnings);
    for (const std::string& w : warnings) err << "hybrid-octree: warning: " << w << "\n";
    size_t inside = 0;
    double sum = 0.0;
    for (size_t n = 0; n < label.voxelCount(); ++n) {
      inside += label.value(n) >= (o.fraction ? 0.5f : 1.0f);
      sum += label.value(n);
    }
    writeVolume(label, o.labelVolume);
    const glm::dvec3 s = scene.volume.spacing();
    out << "wrote    " << o.labelVolume << " (" << (o.fraction ? "float32 fraction" : "uint8 label, 1 where the coverage is >= 0.5") << ", the CT's grid and frame; "
        << inside << " voxels labelled, " << (o.fraction ? sum : double(inside)) * s.x * s.y * s.z << " mm^3; " << msSince(t0) << " ms)\n";
    if (!o.iso) return 0;
  }
  const float iso = float(*o.iso);
  if (iso <= scene.volume.minValue() || iso > scene.volume.maxValue())
    err << "hybrid-octree: warning: --iso " << iso << " is outside the data's crossing range (" << scene.volume.minValue() << ", "
        << scene.volume.maxValue() << "]: the surface is empty\n";
  const ExportedSurface e = exportSurface(scene, ExportRequest{iso, o.surface, o.closed, o.normals, o.check}, o.input.progress, out);
  const TriangleMesh& mesh = e.mesh;
  const TriangleMesh& mc = e.mc;
  const Volume& v = scene.volume;
  writeMesh(o.output, mesh, MeshWriteOptions{o.normals, "LPS"});
  out << "wrote    " << o.output << " (patient coordinates, LPS mm" << (o.normals ? ", with vertex normals" : "") << ")\n";
  if (o.check) {
    const auto tc = Clock::now();
    const MeshCheck c = checkMesh(mesh);
    out << checkLine(c, msSince(tc));
    if (o.surface != "mc") {
      // Sampled, at a cost that follows the surface's area (the exact bracket's follows its shape):
      // no patch the size of a voxel's disc farther than the largest distance found, at 99.9 %.
      const glm::dvec3 voxel = v.spacing();
      const SampledHausdorffOptions options{std::max({voxel.x, voxel.y, voxel.z}), 0.999};
      const auto th = Clock::now();
      const SampledHausdorff h = sampledHausdorffDistance(mesh, mc, options, o.input.progress);
      out << "check    Hausdorff distance to mc at least " << std::setprecision(4) << h.lower << " mm (exact: the farthest of every vertex and "
          << h.samples << " sampled points), at most " << h.upper << " mm (exact: from each triangle's corners and size), " << std::setprecision(1)
          << msSince(th) / 1000.0 << " s\n";
      out << "check    sampled, " << 100.0 * h.confidence << " % confidence: less than " << std::setprecision(3) << h.patchArea
          << " mm² of either surface (a disc of one voxel's radius, " << options.patchRadius << " mm) lies farther than " << std::setprecision(4)
          << h.lower << " mm from the other\n";
    }
  }
  return 0;
}

struct CompareOptions {
  std::string reference, image, diff;
  std::string validate() const {
    if (reference.empty() || image.empty()) return "compare needs two PNG files (expected: compare REFERENCE.png IMAGE.png)";
    if (!diff.empty() && fileExtension(diff) != ".png") return "--diff '" + diff + "' must be a .png file";
    if (std::string e = outputsError({{diff, "--diff"}}, {reference, image}); !e.empty()) return e;
    return "";
  }
};

// PSNR and SSIM of an image against a reference (as `bench` measures them), where the largest
// difference is, and optionally the difference as a grey image (1/255 of RMS difference over RGB
// is 8/255 of grey: small errors show).
int runCompare(const CompareOptions& o, std::ostream& out) {
  int w = 0, h = 0, w2 = 0, h2 = 0;
  const std::vector<uint8_t> a = readPng(o.reference, &w, &h), b = readPng(o.image, &w2, &h2);
  if (w != w2 || h != h2)
    HYB_THROW(ValueError, o.image, " is ", w2, "x", h2, " pixels, ", o.reference, " is ", w, "x", h, " (expected images of the same size)");
  double largest = -1.0;
  glm::ivec2 at(0);
  Image d(w, h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      double sum = 0.0;
      for (int c = 0; c < 3; ++c) {
        const double e = double(a[(size_t(y) * w + x) * 4 + c]) - double(b[(size_t(y) * w + x) * 4 + c]);
        sum += e * e;
      }
      const double rms = std::sqrt(sum / 3.0);
      if (rms > largest) largest = rms, at = glm::ivec2(x, y);
      const float g = float(std::min(1.0, 8.0 * rms / 255.0));
      d.at(x, y) = glm::vec4(g, g, g, 1.0f);
    }
  const double p = psnr(a, b);
  out << "compare  " << o.image << " against " << o.reference << " (" << w << "x" << h << "): ";
  if (std::isinf(p)) out << "identical\n";
  else
    out << "PSNR " << std::fixed << std::setprecision(2) << p << " dB, SSIM " << std::setprecision(4) << ssim(a, b, w, h)
        << ", largest difference " << std::setprecision(1) << largest << "/255 (RMS over RGB) at pixel " << at.x << "," << at.y << "\n";
  if (!o.diff.empty()) {
    writePng(o.diff, d, glm::vec3(0.0f));
    out << "wrote    " << o.diff << "\n";
  }
  return 0;
}

struct ViewOptions {
  VolumeInput input;
  bool volumeGiven = false;
  std::string host = "127.0.0.1";
  int port = 8080;
  std::string dataDir, token;
  double frameMs = 80.0, textureMb = 512.0;
  std::optional<double> memoryMb;  // a scene file's block cache, per scene
  std::string pacs, pacsCache;     // the PACS the page searches; where its series' scenes are kept
  double pacsCacheMb = 8192.0;
  int pacsPreview = DicomWebPreview{}.planes;  // instances a PACS series' preview retrieves (0: none)
  std::string validate() const {
    if (port < 0 || port > 65535) return "--port must be in 0..65535 (0: any free port)";
    if (!pacs.empty() && !isDicomWebUrl(pacs)) return "--pacs '" + redactUrl(pacs) + "' invalid (expected a DICOMweb root, http(s)://HOST:PORT/ROOT)";
    if (!(pacsCacheMb >= 16.0 && pacsCacheMb <= 1e9)) return "--pacs-cache-mb must be in [16, 1e9]";
    if (pacsPreview != 0 && (pacsPreview < 2 || pacsPreview > 1024)) return "--pacs-preview must be 0 (no preview) or instances in 2..1024";
    if (!dataDir.empty() && !std::filesystem::is_directory(dataDir)) return "--data-dir " + dataDir + ": not a directory";
    if (!(frameMs >= 10.0 && frameMs <= 1000.0)) return "--frame-ms must be in [10, 1000]";
    if (!(textureMb >= 16.0 && textureMb <= 65536.0)) return "--texture-mb must be in [16, 65536]";
    if (memoryMb && !(*memoryMb >= 1.0 && *memoryMb <= 1e9)) return "--memory must be megabytes in [1, 1e9]";
    if (!token.empty() && (token.size() < 16 || token.find_first_not_of("0123456789abcdefABCDEF") != std::string::npos))
      return "--token must be at least 16 hexadecimal digits";
    return "";
  }
};

// Where the viewer keeps the scenes it built from PACS series, by the XDG base directories.
std::filesystem::path defaultSceneCacheDir() {
  if (const char* xdg = std::getenv("XDG_CACHE_HOME"); xdg && *xdg == '/') return std::filesystem::path(xdg) / "hybrid-octree" / "scenes";
  const char* home = std::getenv("HOME");
  return std::filesystem::path(home && *home ? home : "/tmp") / ".cache" / "hybrid-octree" / "scenes";
}

// A series of the PACS that is not in @p cache is shown as a preview of a few of its instances
// while it is retrieved and built: seconds, where the series itself takes tens.
ScenePool::Previewer pacsPreviewer(const ViewOptions& o, SceneCache& cache) {
  return [&o, &cache](const std::string& path, const std::string&, const Progress* progress) -> std::optional<Scene> {
    if (!isDicomWebUrl(path)) return std::nullopt;
    setDicomWebAuthFile(o.input.pacsAuthFile);
    const std::pair<std::string, std::vector<std::string>> listed = dicomWebInstances(path);
    if (cache.holds(listed.first, listed.second)) return std::nullopt;
    DicomWebPreview size;
    size.planes = o.pacsPreview;
    std::optional<Volume> v = readDicomWebPreview(path, size, progress);
    if (!v) return std::nullopt;
    Scene scene;
    scene.volume = std::move(*v);
    VolumeOctreeOptions options;
    options.progress = progress;
    scene.octree = VolumeOctree::build(scene.volume, options);
    return scene;
  };
}

int runView(const ViewOptions& o, std::ostream& out, std::ostream& err) {
  viewer::ServerOptions so;
  so.host = o.host;
  so.port = uint16_t(o.port);
  so.dataDir = o.dataDir;
  so.token = o.token;
  so.frameTargetMs = o.frameMs;
  so.textureLimitBytes = uint64_t(o.textureMb * 1024 * 1024);
  // A scene file is read paged within --memory, as render reads it: a study larger than memory
  // opens; the surfaces made of it and the brick textures kept count against it too.
  so.memoryBytes = sceneMemoryBytes(o.memoryMb);
  if (o.volumeGiven || (o.dataDir.empty() && o.pacs.empty())) {
    so.volume = o.input.path;
    so.series = o.input.series;
  }
  so.pacs = o.pacs;
  // A series of a PACS is built once into a scene file of the cache, then read from it paged (the
  // next open of the same instances reads no network).
  std::unique_ptr<SceneCache> cache;
  if (!o.pacs.empty() || isDicomWebUrl(so.volume))
    cache = std::make_unique<SceneCache>(o.pacsCache.empty() ? defaultSceneCacheDir() : std::filesystem::path(o.pacsCache), uint64_t(o.pacsCacheMb * 1024 * 1024));
  so.loader = [&o, &err, &cache, memoryBytes = so.memoryBytes](const std::string& path, const std::string& series, const Progress* progress) {
    VolumeInput in = o.input;
    in.path = path;
    in.series = series;
    in.progress = progress ? progress : o.input.progress;  // the page hears of a load it waits for
    std::ostringstream quiet;
    if (cache && isDicomWebUrl(path)) {
      setDicomWebAuthFile(in.pacsAuthFile);
      const std::pair<std::string, std::vector<std::string>> listed = dicomWebInstances(path);
      in.path = cache->scene(listed.first, listed.second, [&](const std::string& to) {
        BuildOptions build;
        build.input = in;
        build.input.path = path;
        build.output = to;
        runBuild(build, quiet, err);
      });
      in.series.clear();
    }
    double ms = 0;
    return loadOrBuild(in, quiet, err, &ms, {}, SceneLoadOptions{false, memoryBytes});
  };
  if (cache && o.pacsPreview > 0) so.previewer = pacsPreviewer(o, *cache);
  so.log = &out;
  // SIGINT and SIGTERM end the server: blocked in every thread, awaited here.
  sigset_t stopSignals;
  sigemptyset(&stopSignals);
  sigaddset(&stopSignals, SIGINT);
  sigaddset(&stopSignals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &stopSignals, nullptr);
  viewer::Server server(std::move(so));
  server.start();
  out << "view     open " << server.url() << " in a browser (Ctrl+C stops the server)" << std::endl;
  int signal = 0;
  sigwait(&stopSignals, &signal);
  server.stop();
  out << "view     stopped" << std::endl;
  return 0;
}

}  // namespace

// The subcommands and their options, as the command line fills them (the options' flags point
// into it: made in place, never copied).
struct Commands {
  InfoOptions info;
  BuildOptions build;
  RenderOptions render;
  BenchOptions bench;
  ExportOptions exportOpts;
  CompareOptions compare;
  ViewOptions view;
  CLI::App *infoCmd = nullptr, *buildCmd = nullptr, *renderCmd = nullptr, *benchCmd = nullptr, *exportCmd = nullptr, *compareCmd = nullptr, *viewCmd = nullptr;

  Commands() = default;
  Commands(const Commands&) = delete;
  Commands& operator=(const Commands&) = delete;

  // info, build, render and bench: the commands that read a volume and build its octree.
  void addScenes(CLI::App* app) {
    infoCmd = app->add_subcommand("info", "print dims, spacing, type, value range and a histogram");
    info.input.add(infoCmd);
    infoCmd->add_option("--bins", info.bins, "histogram bins")->capture_default_str();

    buildCmd = app->add_subcommand("build", "build the Hybrid Octree once and save it as a scene file");
    build.input.add(buildCmd, false);
    buildCmd->add_option("-o,--output", build.output, "scene file to write (.hoct)");
    buildCmd->add_option("--iso", build.iso, "isovalue of the Surface Octree to build (data units; none = volume only)");
    buildCmd->add_option("--leaf-edge", build.leafEdge, "edge in voxels of the smallest octree nodes")->capture_default_str();
    addSwitch(buildCmd, "--prefilter", &build.prefilter,
              "coarse levels (texels 4+ voxels apart) hold the data smoothed by their tent filter (default on)");

    renderCmd = app->add_subcommand("render", "render one image (slice renderer or reference ray tracer)");
    render.add(renderCmd);
    renderCmd->add_option("-o,--output", render.output, "PNG to write");
    renderCmd->add_option("--stats", render.stats, "write statistics as JSON");
    renderCmd->add_option("--repeat", render.repeat, "render the view N times, brick textures kept; report the fastest frame")
        ->capture_default_str();

    benchCmd = app->add_subcommand("bench", "speed/accuracy sweep over epsilon and budget: CSV, plot and images");
    bench.add(benchCmd);
  }

  // export, compare and view.
  void addOthers(CLI::App* app) {
    exportCmd = app->add_subcommand("export", "write the isosurface as a mesh in millimetres");
    exportOpts.input.add(exportCmd);
    exportCmd->add_option("--iso", exportOpts.iso, "isovalue in data units (samples >= iso are inside)");
    exportCmd->add_option("-o,--output", exportOpts.output, "mesh file: " + meshExtensionsText());
    exportCmd->add_option("--surface", exportOpts.surface, "dmc (Discretized Marching Cubes), octree (Surface Octree, merged) or mc (classic)")
        ->capture_default_str();
    exportCmd->add_flag("--check", exportOpts.check,
                        "check manifold, closed, self-intersections (CGAL) and the Hausdorff distance to mc (exact bounds; sampled, 99.9 % confidence)");
    exportCmd->add_flag("--closed", exportOpts.closed,
                        "cap the surface where it meets the volume's faces (as if the volume were padded below the isovalue): a closed mesh to print");
    exportCmd->add_flag("--normals", exportOpts.normals, "write vertex normals from the volume's gradient (.ply and .obj)");
    exportCmd->add_option("--mesh", exportOpts.meshes, "a mesh FILE (.ply .obj .stl .off, patient mm) for --label-volume; repeatable")
        ->allow_extra_args(false)
        ->multi_option_policy(CLI::MultiOptionPolicy::TakeAll);
    exportCmd->add_option("--primitive", exportOpts.primitives,
                          "an analytic primitive for --label-volume (render's --primitive: plane:..., sphere:..., polygon:...); repeatable")
        ->allow_extra_args(false)
        ->multi_option_policy(CLI::MultiOptionPolicy::TakeAll);
    exportCmd->add_option("--mesh-space", exportOpts.meshSpace, "the space of mesh files whose header does not name one: lps or ras")->capture_default_str();
    exportCmd->add_option("--label-volume", exportOpts.labelVolume,
                          "write the meshes and primitives scan-converted on the CT's grid and frame (box filter of one voxel; closed meshes and "
                          "spheres solid, planes and polygons as sheets): a .nrrd, .nii or .nii.gz uint8 label, 1 where a voxel is at least half covered");
    exportCmd->add_flag("--fraction", exportOpts.fraction, "--label-volume holds each voxel's covered fraction (float32) instead of a label");
    exportCmd->add_option("--memory", exportOpts.memoryMb,
                          "MB a scene file holds when its Surface Octree's surface is exported (--surface octree, without --closed or --check): "
                          "its octrees and the cache of decompressed blocks the surface is extracted through (default: an eighth of the physical memory)");

    compareCmd = app->add_subcommand("compare", "PSNR and SSIM of an image against a reference image, and where they differ");
    compareCmd->add_option("reference", compare.reference, "reference PNG (e.g. from render --renderer raycast)");
    compareCmd->add_option("image", compare.image, "PNG to compare, of the same size");
    compareCmd->add_option("--diff", compare.diff, "write the per-pixel difference as a grey PNG (8x the RMS difference over RGB)");

    viewCmd = app->add_subcommand("view", "serve the interactive viewer: open the printed URL in a browser");
    view.input.add(viewCmd);
    viewCmd->add_option("--host", view.host, "address to listen on (127.0.0.1: this machine only)")->capture_default_str();
    viewCmd->add_option("--port", view.port, "TCP port (0: any free port)")->capture_default_str();
    viewCmd->add_option("--data-dir", view.dataDir, "the page lists the volumes and DICOM series under this directory and opens them");
    viewCmd->add_option("--token", view.token, "access token (default: a random one, printed in the URL)");
    viewCmd->add_option("--frame-ms", view.frameMs, "frame time interactive frames aim at, ms")->capture_default_str();
    viewCmd->add_option("--texture-mb", view.textureMb, "brick textures kept between frames, MB per volume")->capture_default_str();
    viewCmd->add_option("--pacs", view.pacs, "a PACS's DICOMweb root (http(s)://HOST:PORT/ROOT): the page searches it and opens its series "
                        "(credentials: --pacs-auth-file or the environment, as for a series' address)");
    viewCmd->add_option("--pacs-cache", view.pacsCache,
                        "folder of the scenes built from PACS series, reopened without the network while their instances are unchanged "
                        "(default: $XDG_CACHE_HOME/hybrid-octree/scenes, else ~/.cache/hybrid-octree/scenes)");
    viewCmd->add_option("--pacs-cache-mb", view.pacsCacheMb, "MB the scene cache keeps, least recently used out first")->capture_default_str();
    viewCmd->add_option("--pacs-preview", view.pacsPreview,
                        "instances of a PACS series retrieved first for a coarse preview, shown while the series is retrieved and built (0: none)")
        ->capture_default_str();
    viewCmd->add_option("--memory", view.memoryMb,
                        "MB a scene file read paged holds, per scene: its octree, the surfaces made of it, the brick textures kept (--texture-mb), and the cache of decompressed blocks its bricks are read through, which gets what they leave, at least a quarter (default: an eighth of the physical memory)");
  }
};

int runMain(int argc, const char* const* argv, std::ostream& out, std::ostream& err) {
  CLI::App app("hybrid-octree: CT volume and isosurface rendering with the Hybrid Octree", "hybrid-octree");
  app.require_subcommand(1);
  app.set_help_all_flag("--help-all", "show help for every subcommand");
  app.fallthrough();  // --progress may follow the subcommand
  std::string progressMode = "auto";
  std::string subject;  // the subcommand and its input, for the messages that have no file of their own
  std::optional<double> memoryMb;
  app.add_option("--memory-limit", memoryMb,
                 "most memory reading one input may take, MB; a file claiming more is refused (default: half the physical memory)");
  app.add_option("--progress", progressMode,
                 "progress of long steps on stderr: auto (a bar on a terminal, lines when piped), bar, lines, off")
      ->capture_default_str();

  Commands c;
  c.addScenes(&app);
  c.addOthers(&app);
  const PacsCommand pacs = addPacsCommand(app, out);

  try {
    try {
      const auto known = app.get_subcommands([](const CLI::App*) { return true; });
      if (argc > 1 && argv[1][0] != '-' &&
          std::none_of(known.begin(), known.end(), [&](const CLI::App* sub) { return sub->get_name() == argv[1]; }))
        HYB_THROW(ValueError, "unknown subcommand '", argv[1], "' (expected info, build, render, export, bench, compare, view or pacs; see --help)");
      app.parse(argc, argv);
    } catch (const CLI::CallForHelp&) {
      out << app.help();
      return 0;
    } catch (const CLI::CallForAllHelp&) {
      out << app.help("", CLI::AppFormatMode::All);
      return 0;
    } catch (const CLI::ParseError& e) {
      err << "hybrid-octree: error: " << e.what() << " (see --help)\n";
      return 2;
    }
    auto check = [&](const std::string& msg) {
      if (!msg.empty()) throw ValueError(msg);
    };
    if (memoryMb && !(*memoryMb > 0 && *memoryMb <= 1e9)) check("--memory-limit must be megabytes in (0, 1e9]");
    setMemoryLimit(memoryMb ? uint64_t(std::max(1.0, *memoryMb * 1024 * 1024)) : 0);  // per run: tests run many in one process
    ProgressMode mode;
    if (!parseProgressMode(progressMode, &mode)) check("--progress '" + progressMode + "' invalid (expected auto, bar, lines or off)");
    // Auto shows progress only on the process's own stderr (not on a caller's stream).
    const bool ownStderr = &err == &std::cerr;
    const ProgressDisplay display(mode == ProgressMode::Auto && !ownStderr ? ProgressMode::Off : mode, err, ownStderr && ::isatty(2));
    for (VolumeInput* in : {&c.info.input, &c.build.input, &c.render.input, &c.bench.render.input, &c.exportOpts.input, &c.view.input})
      in->progress = display.progress();
    for (const auto& [cmd, in] : {std::pair{c.infoCmd, &c.info.input}, {c.buildCmd, &c.build.input}, {c.renderCmd, &c.render.input},
                                  {c.benchCmd, &c.bench.render.input}, {c.exportCmd, &c.exportOpts.input}, {c.viewCmd, &c.view.input}})
      if (cmd->parsed()) subject = cmd->get_name() + " of " + in->path;
    if (ranks().mpi && !c.renderCmd->parsed() && !c.benchCmd->parsed())
      check("only render and bench run across MPI ranks; run " + (app.get_subcommands().empty() ? std::string("it") : app.get_subcommands().front()->get_name()) +
            " without mpirun");
    if (c.infoCmd->parsed()) return check(c.info.validate()), runInfo(c.info, out, err);
    if (c.buildCmd->parsed()) return check(c.build.validate()), runBuild(c.build, out, err);
    if (c.renderCmd->parsed()) {
      check(c.render.validate());
      if (c.render.output.empty()) check("-o missing (expected the PNG to write, e.g. -o out.png)");
      return runRender(c.render, out, err);
    }
    if (c.exportCmd->parsed()) return check(c.exportOpts.validate()), runExport(c.exportOpts, out, err);
    if (c.benchCmd->parsed()) return check(c.bench.validate()), runBench(c.bench, out, err);
    if (c.compareCmd->parsed()) return check(c.compare.validate()), runCompare(c.compare, out);
    if (c.viewCmd->parsed()) {
      c.view.volumeGiven = c.viewCmd->get_option("volume")->count() > 0;
      return check(c.view.validate()), runView(c.view, out, err);
    }
    if (pacs.cmd->parsed()) return pacs.run();
    return 2;
  } catch (const IoError& e) {
    err << "hybrid-octree: error: " << e.what() << "\n";
    return 2;
  } catch (const ValueError& e) {
    err << "hybrid-octree: error: " << e.what() << "\n";
    return 2;
  } catch (const std::bad_alloc&) {
    err << "hybrid-octree: error: out of memory" << (subject.empty() ? "" : " (" + subject + ")")
        << "; a smaller --size, a --budget or a smaller volume needs less\n";
    return 1;
  } catch (const std::exception& e) {
    err << "hybrid-octree: error: " << e.what() << "\n";
    return 1;
  }
}

}  // namespace hyb::app
