#include "apps/cli.h"

#include <CLI/CLI.hpp>

#include <chrono>
#include <cmath>
#include <iomanip>
#include <map>
#include <optional>
#include <ostream>
#include <sstream>

#include "hybrid_octree/hybrid_io.h"
#include "hybrid_octree/selection.h"
#include "hybrid_octree/volume_octree.h"
#include "render/raycast.h"
#include "render/slices.h"
#include "surface/cgal_geometry.h"
#include "surface/dmc.h"
#include "surface/mesh_io.h"
#include "volume/file_util.h"
#include "volume/volume_io.h"

namespace hyb::app {

namespace {

using Clock = std::chrono::steady_clock;
double msSince(Clock::time_point t0) { return std::chrono::duration<double, std::milli>(Clock::now() - t0).count(); }

// Parses "a,b,c" into three finite numbers; throws ValueError naming @p flag.
glm::dvec3 parseVec3(const std::string& text, const std::string& flag) {
  std::istringstream s(text);
  glm::dvec3 v;
  char c1 = 0, c2 = 0;
  std::string rest;
  if (!(s >> v.x >> c1 >> v.y >> c2 >> v.z) || c1 != ',' || c2 != ',' || (s >> rest) ||
      !std::isfinite(v.x) || !std::isfinite(v.y) || !std::isfinite(v.z))
    HYB_THROW(ValueError, flag, " '", text, "' invalid (expected three finite numbers x,y,z)");
  return v;
}

// Where the volume comes from: a path (default: the Debian CT) and an optional raw layout.
struct VolumeInput {
  std::string path = kDefaultVolumePath;
  std::string rawDims, rawType, rawSpacing, rawEndian = "little";
  uint64_t rawHeader = 0;

  void add(CLI::App* cmd) {
    cmd->add_option("volume", path, "volume file (.nrrd .nhdr .mhd .mha .nii .nii.gz .inv3), DICOM directory, raw file, or scene.hoct")
        ->capture_default_str();
    cmd->add_option("--raw-dims", rawDims, "raw input: samples per axis X,Y,Z");
    cmd->add_option("--raw-type", rawType, "raw input: int16|uint16|uint8|int8|int32|uint32|float32|float64");
    cmd->add_option("--raw-spacing", rawSpacing, "raw input: voxel spacing sx,sy,sz in mm (default 1,1,1)");
    cmd->add_option("--raw-endian", rawEndian, "raw input: little|big (default little)");
    cmd->add_option("--raw-header", rawHeader, "raw input: bytes to skip before the samples");
  }

  // Builds the raw layout when any raw flag is given (then --raw-dims and --raw-type are required).
  std::optional<RawLayout> rawLayout() const {
    if (rawDims.empty() && rawType.empty() && rawSpacing.empty()) return std::nullopt;
    if (rawDims.empty()) HYB_THROW(ValueError, "--raw-dims missing (expected X,Y,Z with --raw-type)");
    if (rawType.empty()) HYB_THROW(ValueError, "--raw-type missing (expected int16|uint16|uint8|float32...)");
    RawLayout l;
    const glm::dvec3 d = parseVec3(rawDims, "--raw-dims");
    for (int a = 0; a < 3; ++a)
      if (d[a] != std::floor(d[a]) || d[a] < 1 || d[a] > kMaxDim)
        HYB_THROW(ValueError, "--raw-dims '", rawDims, "' invalid (expected positive integers up to ", kMaxDim, ")");
    l.dims = glm::ivec3(d);
    if (!parseScalarName(rawType, &l.type))
      HYB_THROW(ValueError, "--raw-type '", rawType, "' unknown (expected int16|uint16|uint8|int8|int32|uint32|float32|float64)");
    if (!rawSpacing.empty()) l.spacing = parseVec3(rawSpacing, "--raw-spacing");
    validateSpacing(l.spacing, "--raw-spacing");
    if (rawEndian != "little" && rawEndian != "big")
      HYB_THROW(ValueError, "--raw-endian '", rawEndian, "' invalid (expected little or big)");
    l.bigEndian = rawEndian == "big";
    l.headerBytes = rawHeader;
    return l;
  }

  Volume read() const {
    const std::optional<RawLayout> raw = rawLayout();
    return readVolume(path, raw ? &*raw : nullptr);
  }
};

// Loads a scene file, or reads a volume and builds its octree.
Scene loadOrBuild(const VolumeInput& in, std::ostream& out, double* buildMs) {
  const auto t0 = Clock::now();
  Scene scene;
  if (!in.rawLayout() && isSceneFile(in.path)) {
    scene = loadScene(in.path);
    *buildMs = 0.0;
    out << "loaded scene " << in.path << " in " << std::fixed << std::setprecision(1) << msSince(t0) << " ms\n";
    return scene;
  }
  scene.volume = in.read();
  const auto t1 = Clock::now();
  scene.octree = VolumeOctree::build(scene.volume);
  *buildMs = msSince(t1);
  out << "read " << in.path << " in " << std::fixed << std::setprecision(1) << msSince(t0) - *buildMs
      << " ms, built volume octree in " << *buildMs << " ms\n";
  return scene;
}

std::string octreeSummary(const Volume& v, const VolumeOctree& t) {
  std::ostringstream s;
  size_t leaves = 0;
  for (const OctreeNode& n : t.nodes()) leaves += n.isLeaf();
  s << "octree   depth " << t.depth() << ", leaf edge " << t.leafEdge() << ", " << t.nodes().size() << " nodes (" << leaves
    << " leaves), " << t.errorData().size() << " nodal errors\n";
  s << "memory   " << t.bytesUsed() << " bytes = " << std::fixed << std::setprecision(2)
    << 100.0 * double(t.bytesUsed()) / double(v.sourceBytes()) << " % of the " << scalarName(v.sourceType()) << " volume\n";
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

int runInfo(const InfoOptions& o, std::ostream& out) {
  const Volume v = o.input.read();
  out << "file     " << o.input.path << "\n" << v.toString();
  out << "histogram (" << o.bins << " bins)\n" << formatHistogram(computeHistogram(v, o.bins));
  return 0;
}

struct BuildOptions {
  VolumeInput input;
  std::string output;
  std::optional<double> iso;
  int leafEdge = 8;
  std::string validate() const {
    if (output.empty()) return "-o missing (expected the scene file to write, e.g. -o scene.hoct)";
    if (leafEdge < 1 || leafEdge > 256 || (leafEdge & (leafEdge - 1))) return "--leaf-edge must be a power of two in 1..256";
    if (iso && !std::isfinite(*iso)) return "--iso must be a finite number";
    return "";
  }
};

// One line on a Surface Octree, with its build time when it was just built.
std::string surfaceSummary(const SurfaceOctree& so, std::optional<double> buildMs) {
  std::ostringstream s;
  size_t planes = 0;
  for (const SurfaceNode& n : so.nodes()) planes += n.planeCount;
  s << "surface  iso " << so.isovalue() << ": " << so.cellCount() << " DiscMC cells merged into " << so.nodes().size()
    << " terminal nodes (" << planes << " plane ids, " << so.bytesUsed() << " bytes)";
  if (buildMs) s << ", " << std::fixed << std::setprecision(1) << *buildMs << " ms";
  else s << " (from the scene)";
  return s.str() + "\n";
}

int runBuild(const BuildOptions& o, std::ostream& out) {
  const Volume v = o.input.read();
  const auto t0 = Clock::now();
  const VolumeOctree t = VolumeOctree::build(v, VolumeOctreeOptions{o.leafEdge});
  const double ms = msSince(t0);
  out << v.toString() << octreeSummary(v, t);
  out << "build    " << std::fixed << std::setprecision(1) << ms << " ms (" << double(v.voxelCount()) / (ms * 1e3)
      << " Mvoxels/s)\n";
  std::optional<SurfaceOctree> so;
  if (o.iso) {
    const auto t1 = Clock::now();
    so = SurfaceOctree::build(v, t, float(*o.iso));
    out << surfaceSummary(*so, msSince(t1));
  }
  saveScene(o.output, v, t, so ? &*so : nullptr);
  out << "wrote    " << o.output << "\n";
  return 0;
}

struct RenderOptions {
  VolumeInput input;
  std::string output, stats, focus, renderer = "slices", tfFile, preset, surfaceColor = "0.95,0.92,0.85,1";
  std::string eye, center, up = "0,0,1", orbit = "180,10", size = "512x512", background = "0,0,0", shading = "on";
  std::string blend = "on";
  std::optional<double> iso;
  double epsilon = 0.0, budgetMb = 0.0, fov = 30.0;
  std::optional<double> step;  // default: 0.5 voxel for slices, 0.25 for the reference
  bool ortho = false;
  int maxBrick = 64;
  std::string validate() const {
    if (!std::isfinite(epsilon) || epsilon < 0) return "--epsilon must be a finite value >= 0 (data units)";
    if (!std::isfinite(budgetMb) || budgetMb < 0) return "--budget must be a finite number of MB >= 0";
    if (iso && !std::isfinite(*iso)) return "--iso must be a finite number";
    if (renderer != "raycast" && renderer != "slices") return "--renderer '" + renderer + "' invalid (expected slices or raycast)";
    if (!(fov > 0 && fov < 179)) return "--fov must be in (0, 179) degrees";
    if (step && !(*step > 0.01 && *step <= 4)) return "--step must be in (0.01, 4] voxels";
    if (shading != "on" && shading != "off") return "--shading must be on or off";
    if (blend != "on" && blend != "off") return "--blend must be on or off";
    if (!tfFile.empty() && !preset.empty()) return "--tf and --preset are exclusive";
    return "";
  }

  // The flags shared by render and bench.
  void add(CLI::App* cmd) {
    input.add(cmd);
    cmd->add_option("--iso", iso, "isovalue of the embedded surface (data units; none = volume only)");
    cmd->add_option("--surface-color", surfaceColor, "surface r,g,b,a in [0,1]; a < 1 is translucent")->capture_default_str();
    cmd->add_option("--tf", tfFile, "transfer function file: 'value r g b a' lines, a = opacity of 1 mm");
    cmd->add_option("--preset", preset, "ct-bone, ct-skin, ct-soft-tissue, ct-vessels, ct-skin-bone (default for CT; other data: a ramp)");
    cmd->add_option("--focus", focus, "region of interest x,y,z in world mm");
    cmd->add_option("--eye", eye, "camera position x,y,z in mm (with --center, --up)");
    cmd->add_option("--center", center, "point looked at, x,y,z in mm (default: the volume centre)");
    cmd->add_option("--up", up, "up direction x,y,z")->capture_default_str();
    cmd->add_option("--orbit", orbit, "azimuth,elevation in degrees around the volume centre")->capture_default_str();
    cmd->add_option("--fov", fov, "vertical field of view in degrees")->capture_default_str();
    cmd->add_flag("--ortho", ortho, "orthographic projection");
    cmd->add_option("--size", size, "image size WxH")->capture_default_str();
    cmd->add_option("--background", background, "background r,g,b in [0,1]")->capture_default_str();
    cmd->add_option("--shading", shading, "gradient shading of the volume: on|off")->capture_default_str();
    cmd->add_option("--blend", blend, "blend bricks towards coarser neighbours (Carmona et al.): on|off")->capture_default_str();
    cmd->add_option("--step", step, "slice / sample spacing in voxels (default 0.5 for slices, 0.25 for raycast)");
    cmd->add_option("--max-brick", maxBrick, "brick edge in texels (power of two)")->capture_default_str();
  }
};

// Parses "WxH" into a positive size no larger than 16384.
glm::ivec2 parseSize(const std::string& text) {
  int w = 0, h = 0;
  char x = 0;
  std::istringstream s(text);
  std::string rest;
  if (!(s >> w >> x >> h) || (x != 'x' && x != 'X') || (s >> rest) || w < 1 || h < 1 || w > 16384 || h > 16384)
    HYB_THROW(ValueError, "--size '", text, "' invalid (expected WxH, 1..16384 each)");
  return {w, h};
}

glm::vec4 parseColor(const std::string& text, const std::string& flag, int n) {
  std::string t = text;
  for (char& c : t)
    if (c == ',') c = ' ';
  std::istringstream s(t);
  glm::vec4 c(1.0f);
  for (int k = 0; k < n; ++k)
    if (!(s >> c[k]) || !(c[k] >= 0.0f && c[k] <= 1.0f))
      HYB_THROW(ValueError, flag, " '", text, "' invalid (expected ", n, " numbers in [0, 1])");
  std::string rest;
  if (s >> rest) HYB_THROW(ValueError, flag, " '", text, "' invalid (expected ", n, " numbers in [0, 1])");
  return c;
}

// Everything a frame needs besides the selection: the scene, transfer function, camera, surface.
struct Frame {
  Scene scene;
  double buildMs = 0, surfaceMs = 0;
  TransferFunction tf;
  Camera camera;
  std::optional<SurfaceOctree> builtSurface;
  const SurfaceOctree* so = nullptr;
  TriangleMesh mesh;
  size_t polygons = 0;
  glm::vec4 surfaceColor{1.0f};
  glm::vec3 background{0.0f};
};

void prepareFrame(const RenderOptions& o, std::ostream& out, Frame* f) {
  f->scene = loadOrBuild(o.input, out, &f->buildMs);
  const Volume& v = f->scene.volume;
  // Transfer function: file, preset, or a default chosen from the data's range.
  f->tf = !o.tfFile.empty()   ? TransferFunction::fromFile(o.tfFile)
          : !o.preset.empty() ? TransferFunction::preset(o.preset)
                              : TransferFunction::defaultFor(v.minValue(), v.maxValue());
  const glm::ivec2 size = parseSize(o.size);
  Camera& camera = f->camera;
  if (!o.eye.empty()) {
    camera.eye = parseVec3(o.eye, "--eye");
    camera.center = o.center.empty() ? 0.5 * v.extentMm() : parseVec3(o.center, "--center");
    camera.up = parseVec3(o.up, "--up");
    if (glm::length(camera.eye - camera.center) == 0 || glm::length(glm::cross(camera.center - camera.eye, camera.up)) == 0)
      HYB_THROW(ValueError, "--eye, --center and --up must give a view direction not parallel to up");
    camera.fovDeg = o.fov;
    camera.ortho = o.ortho;
    camera.orthoHeight = glm::length(v.extentMm()) * 1.05;
    camera.width = size.x;
    camera.height = size.y;
  } else {
    const glm::dvec3 ae = parseVec3(o.orbit + ",0", "--orbit");
    camera = Camera::orbit(glm::dvec3(0.0), v.extentMm(), ae.x, ae.y, o.fov, o.ortho, size.x, size.y);
  }
  f->surfaceColor = parseColor(o.surfaceColor, "--surface-color", 4);
  f->background = glm::vec3(parseColor(o.background, "--background", 3));
  // Surface: the scene's when the isovalue matches, else built now.
  if (o.iso) {
    if (f->scene.surface && f->scene.surface->isovalue() == float(*o.iso)) {
      f->so = &*f->scene.surface;
    } else {
      const auto t0 = Clock::now();
      f->builtSurface = SurfaceOctree::build(v, f->scene.octree, float(*o.iso));
      f->surfaceMs = msSince(t0);
      f->so = &*f->builtSurface;
    }
    const DiscreteMesh d = f->so->reconstruct();
    f->polygons = d.faceCount();
    f->mesh = fineMeshToTriangles(d, v.spacing());
  }
}

// Selection parameters for a frame: ε, budget, focus, the eye, the transfer function's opacity
// and slope, frustum culling and blending.
SelectionParams selectionParams(const RenderOptions& o, const Frame& f, double epsilon, double budgetMb) {
  const Volume& v = f.scene.volume;
  SelectionParams params;
  params.epsilon = float(epsilon);
  params.spacing = v.spacing();
  params.maxBrickEdge = o.maxBrick;
  if (!o.focus.empty()) params.focus = parseVec3(o.focus, "--focus");
  params.eye = f.camera.eye;
  // Texture memory is counted at 4 bytes a texel (R32F textures, which hold the extrapolated texels).
  params.texelBudget = uint64_t(budgetMb * 1024.0 * 1024.0 / 4.0);
  if (budgetMb > 0 && params.texelBudget == 0) HYB_THROW(ValueError, "--budget ", budgetMb, " MB is smaller than one texel");
  params.blend = o.blend == "on";
  const TransferFunction* tf = &f.tf;
  const Camera* camera = &f.camera;
  params.opacity = [tf](float lo, float hi) { return tf->maxAlpha(lo, hi); };
  params.sensitivity = [tf](float lo, float hi) { return tf->maxSlope(lo, hi); };
  params.inView = [camera](const glm::dvec3& lo, const glm::dvec3& hi) { return camera->seesBox(lo, hi); };
  return params;
}

// Renders one frame with the chosen renderer; needs a current GlContext for slices.
Image renderFrame(const RenderOptions& o, const Frame& f, const Selection& sel, SlicesStats* ss, RaycastStats* rs) {
  const Volume& v = f.scene.volume;
  if (o.renderer == "slices") {
    SlicesOptions opt;
    opt.stepVoxels = o.step.value_or(0.5);
    opt.shading = o.shading == "on";
    opt.surface = f.so ? &f.mesh : nullptr;
    opt.surfaceColor = f.surfaceColor;
    return renderSlices(v, f.scene.octree, sel, f.tf, f.camera, opt, ss);
  }
  const Bvh bvh(f.mesh);
  RaycastOptions ro;
  ro.stepVoxels = o.step.value_or(0.25);
  ro.shading = o.shading == "on";
  ro.surface = f.so ? &bvh : nullptr;
  ro.surfaceColor = f.surfaceColor;
  return raycast(v, f.scene.octree, f.tf, f.camera, ro, rs);
}

int runRender(const RenderOptions& o, std::ostream& out, std::ostream& err) {
  Frame f;
  prepareFrame(o, out, &f);
  const Volume& v = f.scene.volume;
  auto t0 = Clock::now();
  const Selection sel = selectNodes(f.scene.octree, selectionParams(o, f, o.epsilon, o.budgetMb));
  const double selectMs = msSince(t0);

  std::map<int, std::pair<int, uint64_t>> perLevel;  // voxel-to-texel ratio -> (visible bricks, texels)
  size_t hidden = 0;
  for (const Brick& b : sel.bricks) {
    if (b.hidden) {
      ++hidden;
      continue;
    }
    auto& e = perLevel[1 << resolutionLevel(f.scene.octree, b)];
    ++e.first;
    e.second += b.texelCount() + b.coarseTexelCount();
  }
  out << "selection: epsilon " << o.epsilon << ", " << sel.bricks.size() << " bricks (" << hidden << " transparent or culled), "
      << sel.texels << " texels (" << std::fixed << std::setprecision(2) << double(sel.texels) * 4.0 / (1024.0 * 1024.0)
      << " MB, blending " << sel.blendTexels << "), max nodal error used " << sel.maxError << ", " << std::setprecision(3) << selectMs
      << " ms\n";
  for (const auto& [ratio, e] : perLevel)
    out << "  voxel:texel " << ratio << ":1  " << e.first << " bricks, " << e.second << " texels\n";
  if (!sel.budgetMet) err << "hybrid-octree: warning: --budget " << o.budgetMb << " MB cannot be met; using " << sel.texels << " texels\n";

  const glm::ivec2 size(f.camera.width, f.camera.height);
  RaycastStats rs;
  SlicesStats ss;
  std::optional<GlContext> gl;
  if (o.renderer == "slices") gl.emplace();
  t0 = Clock::now();
  const Image image = renderFrame(o, f, sel, &ss, &rs);
  const double renderMs = msSince(t0);
  if (o.renderer == "slices")
    out << "render   slices " << size.x << "x" << size.y << ", " << ss.bricks << " textured bricks (" << ss.blendedBricks << " blended), "
        << ss.textureBytes << " texture bytes, " << ss.slices << " slices, " << ss.slabPolygonDraws << " slab polygon draws, "
        << std::setprecision(1) << renderMs << " ms\n";
  else
    out << "render   raycast " << size.x << "x" << size.y << ", " << rs.samples << " samples, " << rs.skippedLeaves
        << " empty-space skips, " << rs.surfaceHits << " surface crossings, " << std::setprecision(1) << renderMs << " ms\n";
  if (!o.output.empty()) {
    writePng(o.output, image, f.background);
    out << "wrote    " << o.output << "\n";
  }
  if (!o.stats.empty()) {
    writeFileAtomically(o.stats, [&](std::ostream& s) {
      s << std::setprecision(9) << "{\n  \"renderer\": \"" << o.renderer << "\",\n  \"nodes_selected\": " << sel.bricks.size()
        << ",\n  \"nodes_hidden\": " << hidden << ",\n  \"texels\": " << sel.texels << ",\n  \"blend_texels\": " << sel.blendTexels
        << ",\n  \"texture_bytes\": " << (o.renderer == "slices" ? ss.textureBytes : sel.texels * 4) << ",\n  \"slices\": " << ss.slices
        << ",\n  \"surface_polygons\": " << f.polygons << ",\n  \"surface_triangles\": " << f.mesh.triangles.size()
        << ",\n  \"slab_polygon_draws\": " << ss.slabPolygonDraws << ",\n  \"build_ms\": " << f.buildMs + f.surfaceMs
        << ",\n  \"select_ms\": " << selectMs << ",\n  \"render_ms\": " << renderMs << ",\n  \"samples\": " << rs.samples
        << ",\n  \"epsilon\": " << o.epsilon << ",\n  \"max_nodal_error_used\": " << sel.maxError
        << ",\n  \"budget_met\": " << (sel.budgetMet ? "true" : "false") << "\n}\n";
    });
  }
  return 0;
}

struct ExportOptions {
  VolumeInput input;
  std::string output, surface = "dmc";
  std::optional<double> iso;
  bool check = false;
  std::string validate() const {
    if (!iso) return "--iso missing (expected the isovalue in data units)";
    if (!std::isfinite(*iso)) return "--iso must be a finite number";
    if (output.empty()) return "-o missing (expected mesh.ply, .obj, .stl or .off)";
    const std::string ext = fileExtension(output);
    if (ext != ".ply" && ext != ".obj" && ext != ".stl" && ext != ".off")
      return "-o '" + output + "' has an unknown extension (expected .ply, .obj, .stl or .off)";
    if (surface != "dmc" && surface != "mc" && surface != "octree")
      return "--surface '" + surface + "' invalid (expected dmc, octree or mc)";
    return "";
  }
};

int runExport(const ExportOptions& o, std::ostream& out) {
  double buildMs = 0;
  const Scene scene = loadOrBuild(o.input, out, &buildMs);
  const Volume& v = scene.volume;
  const float iso = float(*o.iso);
  if (iso <= v.minValue() || iso > v.maxValue())
    out << "note: --iso " << iso << " is outside the data's crossing range (" << v.minValue() << ", " << v.maxValue()
        << "]: the surface is empty\n";
  const std::vector<VoxelBlock> blocks = isoBlocks(scene.octree, iso);
  auto t0 = Clock::now();
  const TriangleMesh mc = extractMarchingCubes(v, iso, blocks);
  const double mcMs = msSince(t0);
  t0 = Clock::now();
  TriangleMesh mesh;
  size_t polygons = 0;
  if (o.surface == "mc") {
    mesh = mc;
    polygons = mc.triangles.size();
    scaleToMillimetres(&mesh, v.spacing());
  } else if (o.surface == "dmc") {
    const DiscreteMesh d = extractDiscMC(v, iso, blocks);
    polygons = d.faceCount();
    mesh = toTriangleMesh(d, v.spacing());
  } else {
    const bool stored = scene.surface && scene.surface->isovalue() == iso;
    const auto ts = Clock::now();
    const SurfaceOctree so = stored ? *scene.surface : SurfaceOctree::build(v, scene.octree, iso);
    out << surfaceSummary(so, stored ? std::nullopt : std::optional<double>(msSince(ts)));
    const DiscreteMesh d = so.reconstruct(kMaxDim);  // one mesh: merge coplanar polygons across bricks too
    polygons = d.faceCount();
    mesh = fineMeshToTriangles(d, v.spacing());
  }
  const double ms = o.surface == "mc" ? mcMs : msSince(t0);
  out << std::fixed << std::setprecision(1) << "surface  " << o.surface << " at iso " << iso << ": " << polygons << " polygons, "
      << mesh.triangles.size() << " triangles, " << mesh.vertices.size() << " vertices, " << ms << " ms\n";
  out << "vs mc    " << mc.triangles.size() << " triangles in " << mcMs << " ms; triangles ratio "
      << std::setprecision(3) << (mc.triangles.empty() ? 1.0 : double(mesh.triangles.size()) / double(mc.triangles.size())) << "\n";
  writeMesh(o.output, mesh);
  out << "wrote    " << o.output << "\n";
  if (o.check) {
    const MeshCheck c = checkMesh(mesh);
    out << "check    manifold " << (c.manifold ? "yes" : "no") << ", closed " << (c.closed ? "yes" : "no") << " ("
        << c.boundaryEdges << " boundary edges), self-intersections " << (c.manifold ? (c.selfIntersecting ? "yes" : "no") : "not tested")
        << (c.closed ? std::string(", outward ") + (c.outward ? "yes" : "no") : std::string()) << "\n";
    if (o.surface != "mc") {
      TriangleMesh mcMm = mc;
      scaleToMillimetres(&mcMm, v.spacing());
      const double cell = std::max({v.spacing().x, v.spacing().y, v.spacing().z});
      out << "check    Hausdorff distance to mc " << std::setprecision(4) << hausdorffDistance(mesh, mcMm, 0.01 * cell)
          << " mm (bound 0.01 cell)\n";
    }
  }
  return 0;
}

}  // namespace

int runMain(int argc, const char* const* argv, std::ostream& out, std::ostream& err) {
  CLI::App app("hybrid-octree: CT volume and isosurface rendering with the Hybrid Octree", "hybrid-octree");
  app.require_subcommand(1);
  app.set_help_all_flag("--help-all", "show help for every subcommand");

  InfoOptions info;
  CLI::App* infoCmd = app.add_subcommand("info", "print dims, spacing, type, value range and a histogram");
  info.input.add(infoCmd);
  infoCmd->add_option("--bins", info.bins, "histogram bins")->capture_default_str();

  BuildOptions build;
  CLI::App* buildCmd = app.add_subcommand("build", "build the Hybrid Octree once and save it as a scene file");
  build.input.add(buildCmd);
  buildCmd->add_option("-o,--output", build.output, "scene file to write (.hoct)");
  buildCmd->add_option("--iso", build.iso, "isovalue of the Surface Octree to build (data units; none = volume only)");
  buildCmd->add_option("--leaf-edge", build.leafEdge, "edge in voxels of the smallest octree nodes")->capture_default_str();

  RenderOptions render;
  CLI::App* renderCmd = app.add_subcommand("render", "render one image (slice renderer or reference ray tracer)");
  render.add(renderCmd);
  renderCmd->add_option("-o,--output", render.output, "PNG to write");
  renderCmd->add_option("--epsilon", render.epsilon, "user error epsilon_u in data units (0 = exact)")->capture_default_str();
  renderCmd->add_option("--budget", render.budgetMb, "texture memory budget in MB, blend textures included (0 = unlimited)");
  renderCmd->add_option("--renderer", render.renderer, "slices|raycast")->capture_default_str();
  renderCmd->add_option("--stats", render.stats, "write statistics as JSON");

  ExportOptions exportOpts;
  CLI::App* exportCmd = app.add_subcommand("export", "write the isosurface as a mesh in millimetres");
  exportOpts.input.add(exportCmd);
  exportCmd->add_option("--iso", exportOpts.iso, "isovalue in data units (samples >= iso are inside)");
  exportCmd->add_option("-o,--output", exportOpts.output, "mesh file: .ply .obj .stl .off");
  exportCmd->add_option("--surface", exportOpts.surface, "dmc (Discretized Marching Cubes), octree (Surface Octree, merged) or mc (classic)")
      ->capture_default_str();
  exportCmd->add_flag("--check", exportOpts.check, "check manifold, closed, self-intersections and Hausdorff distance to mc (CGAL)");

  try {
    try {
      const auto known = app.get_subcommands([](const CLI::App*) { return true; });
      if (argc > 1 && argv[1][0] != '-' &&
          std::none_of(known.begin(), known.end(), [&](const CLI::App* c) { return c->get_name() == argv[1]; }))
        HYB_THROW(ValueError, "unknown subcommand '", argv[1], "' (expected info, build, render or export; see --help)");
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
    if (infoCmd->parsed()) return check(info.validate()), runInfo(info, out);
    if (buildCmd->parsed()) return check(build.validate()), runBuild(build, out);
    if (renderCmd->parsed()) return check(render.validate()), runRender(render, out, err);
    if (exportCmd->parsed()) return check(exportOpts.validate()), runExport(exportOpts, out);
    return 2;
  } catch (const IoError& e) {
    err << "hybrid-octree: error: " << e.what() << "\n";
    return 2;
  } catch (const ValueError& e) {
    err << "hybrid-octree: error: " << e.what() << "\n";
    return 2;
  } catch (const std::bad_alloc&) {
    err << "hybrid-octree: error: out of memory\n";
    return 1;
  } catch (const std::exception& e) {
    err << "hybrid-octree: error: " << e.what() << "\n";
    return 1;
  }
}

}  // namespace hyb::app
