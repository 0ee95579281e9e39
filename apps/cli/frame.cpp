#include "apps/cli/frame.h"

#include <chrono>
#include <cmath>
#include <filesystem>
#include <iomanip>
#include <ostream>
#include <sstream>

#include "apps/cli/outputs.h"
#include "hybrid_octree/surface_octree.h"
#include "render/bvh.h"
#include "surface/mesh_ops.h"
#include "volume/core/file_util.h"
#include "volume/core/memory_limit.h"
#include "volume/dicomweb.h"

#include <nlohmann/json.hpp>

namespace hyb::app {

void VolumeInput::add(CLI::App* cmd, bool scenes) {
  cmd->add_option("volume", path,
                  "volume file (" + volumeExtensionsText() + "), DICOM directory (a series, a folder tree, a CD with its DICOMDIR), " +
                      "DICOMweb series (http(s)://HOST:PORT/ROOT/studies/UID/series/UID; `pacs` lists them), raw file" + (scenes ? ", or scene.hoct" : ""))
      ->capture_default_str();
  cmd->add_option("--raw-dims", rawDims, "raw input: samples per axis X,Y,Z");
  cmd->add_option("--raw-type", rawType, "raw input: int16|uint16|uint8|int8|int32|uint32|float32|float64");
  cmd->add_option("--raw-spacing", rawSpacing, "raw input: voxel spacing sx,sy,sz in mm (default 1,1,1)");
  cmd->add_option("--raw-endian", rawEndian, "raw input: little|big (default little)");
  cmd->add_option("--raw-header", rawHeader, "raw input: bytes to skip before the samples");
  cmd->add_option("--series", series, "DICOM directory: the Series Instance UID to read, or its Series Number when no other series has it (default: the largest series; info lists them)");
  cmd->add_option("--pacs-auth-file", pacsAuthFile,
                  "DICOMweb: file whose first line is 'Bearer TOKEN' or 'USER:PASSWORD' (default: HYB_DICOMWEB_TOKEN or HYB_DICOMWEB_USER=USER:PASSWORD)");
}

std::optional<RawLayout> VolumeInput::rawLayout() const {
  if (rawDims.empty() && rawType.empty() && rawSpacing.empty()) return std::nullopt;
  // A file that describes itself is never read as raw: its header would be taken for samples.
  std::error_code ec;
  const std::string described = volumeFormatOf(path) != VolumeFormat::None ? fileExtension(path) + " file"
                                : isSceneFile(path)                        ? "scene file"
                                : std::filesystem::is_directory(path, ec)  ? "directory (DICOM)"
                                                                           : "";
  if (!described.empty())
    HYB_THROW(ValueError, path, ": a ", described, " carries its own layout (--raw-dims, --raw-type and --raw-spacing are for headerless raw data)");
  RawLayout l;
  if (!rawDims.empty()) {
    const glm::dvec3 d = parseVec3(rawDims, "--raw-dims");
    for (int a = 0; a < 3; ++a)
      if (d[a] != std::floor(d[a]) || d[a] < 1 || d[a] > kMaxDim)
        HYB_THROW(ValueError, "--raw-dims '", rawDims, "' invalid (expected positive integers up to ", kMaxDim, ")");
    l.dims = glm::ivec3(d);
  }
  if (!rawType.empty() && !parseScalarName(rawType, &l.type))
    HYB_THROW(ValueError, "--raw-type '", rawType, "' unknown (expected int16|uint16|uint8|int8|int32|uint32|float32|float64)");
  if (rawDims.empty()) HYB_THROW(ValueError, "--raw-dims missing (expected X,Y,Z with --raw-type)");
  if (rawType.empty()) HYB_THROW(ValueError, "--raw-type missing (expected int16|uint16|uint8|float32...)");
  if (!rawSpacing.empty()) l.spacing = parseVec3(rawSpacing, "--raw-spacing");
  validateSpacing(l.spacing, "--raw-spacing");
  if (rawEndian != "little" && rawEndian != "big") HYB_THROW(ValueError, "--raw-endian '", rawEndian, "' invalid (expected little or big)");
  l.bigEndian = rawEndian == "big";
  l.headerBytes = rawHeader;
  return l;
}

Volume VolumeInput::read(std::ostream& err) const {
  const std::optional<RawLayout> raw = rawLayout();
  setDicomWebAuthFile(pacsAuthFile);
  Volume v = readVolume(path, raw ? &*raw : nullptr, series, progress);
  printWarnings(v, err);
  return v;
}

std::unique_ptr<PlaneSource> VolumeInput::openPlanes(std::ostream& err) const {
  const std::optional<RawLayout> raw = rawLayout();
  setDicomWebAuthFile(pacsAuthFile);
  std::unique_ptr<PlaneSource> planes = hyb::openPlanes(path, raw ? &*raw : nullptr, series, progress);
  printWarnings(planes->description(), err);
  return planes;
}

void printWarnings(const Volume& v, std::ostream& err) {
  for (const std::string& w : v.warnings()) err << "hybrid-octree: warning: " << w << "\n";
}

Scene loadOrBuild(const VolumeInput& in, std::ostream& out, std::ostream& err, double* buildMs, const VolumeOctreeOptions& options,
                  const SceneLoadOptions& load) {
  const std::optional<RawLayout> raw = in.rawLayout();
  if (!raw && !in.series.empty() && isSceneFile(in.path)) HYB_THROW(ValueError, "--series needs a DICOM directory (", in.path, " is a scene file)");
  setDicomWebAuthFile(in.pacsAuthFile);
  OpenedScene o = openScene(SceneSource{in.path, raw ? &*raw : nullptr, in.series, in.progress}, options, load);
  *buildMs = o.buildMs;
  if (o.loaded) {
    out << "loaded scene " << in.path << " in " << std::fixed << std::setprecision(1) << o.readMs << " ms\n";
    return std::move(o.scene);
  }
  printWarnings(o.scene.volume, err);
  out << "read " << in.path << " in " << std::fixed << std::setprecision(1) << o.readMs << " ms, built volume octree in " << o.buildMs << " ms\n";
  return std::move(o.scene);
}

CLI::Option* addSwitch(CLI::App* cmd, const std::string& name, bool* field, const std::string& help) {
  return cmd->add_option_function<std::string>(
      name,
      [=](const std::string& text) {
        if (text != "on" && text != "off") HYB_THROW(ValueError, name, " '", text, "' invalid (expected on or off)");
        *field = text == "on";
      },
      help + " (on|off)");
}

std::string RenderOptions::validate() const {
  if (std::string e = settings.validate(); !e.empty()) return e;
  if (memoryMb && !(*memoryMb >= 1.0 && *memoryMb <= 1e9)) return "--memory must be megabytes in [1, 1e9]";
  if (repeat < 1 || repeat > 100) return "--repeat must be in 1..100 frames";
  if (!output.empty() && fileExtension(output) != ".png") return "-o '" + output + "' must be a .png file (render writes PNG images)";
  return outputsError({{output, "-o"}, {stats, "--stats"}}, {input.path, settings.tf, settings.cameraFile});
}

void RenderOptions::add(CLI::App* cmd) {
  input.add(cmd);
  // The frame's settings: a flag for every field of the table the command line takes.
  for (const FrameField& f : frameFields()) {
    if (!(f.doors & kCommandLine)) continue;
    std::string help = f.help;
    if (!f.unit.empty()) help += " (" + f.unit + ")";
    if (const std::optional<std::string> d = f.defaultText(); d && f.kind != FieldKind::Flag) help += " [default " + *d + "]";
    if (f.kind == FieldKind::Flag) {
      cmd->add_flag_function(f.flag(), [this, &f](int64_t) { f.parse(settings, "on", f.flag()); }, help);
      continue;
    }
    if (!f.choices.empty()) {
      std::string words;
      for (const std::string& c : f.choices) words += (words.empty() ? "" : "|") + c;
      help += " (" + words + ")";
    }
    CLI::Option* option = cmd->add_option_function<std::string>(f.flag(), [this, &f](const std::string& text) { f.parse(settings, text, f.flag()); }, help);
    if (f.repeatable) option->multi_option_policy(CLI::MultiOptionPolicy::Join);
  }
  cmd->add_option("--memory", memoryMb,
                  "MB a scene file read paged holds: its octree, the surface made of it, and the cache of decompressed blocks its bricks are read through, which gets what they leave, at least a quarter (default: an eighth of the physical memory)");
  addSwitch(cmd, "--prefilter", &prefilter,
            "coarse levels (texels 4+ voxels apart) hold the data smoothed by their tent filter instead of point samples; a scene file "
            "keeps the choice it was built with (default on)");
}

uint64_t sceneMemoryBytes(const std::optional<double>& memoryMb) {
  return memoryMb ? uint64_t(*memoryMb * 1024.0 * 1024.0) : defaultMemoryLimit() / 4;
}

RenderJob prepareRender(const RenderOptions& o, std::ostream& out, std::ostream& err, bool keepTextures) {
  RenderJob job;
  VolumeOctreeOptions octree;
  octree.prefilter = o.prefilter;
  // A scene file is read paged: its octrees and the cache its bricks come through hold --memory.
  const uint64_t memoryBytes = sceneMemoryBytes(o.memoryMb);
  Scene scene = loadOrBuild(o.input, out, err, &job.buildMs, octree, SceneLoadOptions{false, memoryBytes});
  if (scene.knots) {
    const uint64_t cache = scene.knots->cacheStats().limit, octreeBytes = scene.octree.bytesUsed();
    if (cache + octreeBytes > memoryBytes)
      err << "hybrid-octree: warning: --memory " << memoryBytes / (1024 * 1024) << " MB: the scene's octree alone takes " << octreeBytes / (1024 * 1024)
          << " MB; its block cache gets " << cache / (1024 * 1024) << " MB, and the process more than --memory\n";
  }
  static_cast<FrameSetup&>(job) = setUpFrame(o.settings, scene, err);
  SceneRenderer::Options ro{0, o.input.progress, keepTextures};
  ro.memoryBytes = memoryBytes;
  job.renderer = std::make_unique<SceneRenderer>(std::move(scene), ro);
  return job;
}

std::string surfaceLine(const FrameStats& stats, float iso, bool fromScene) {
  if (stats.surfacePolygonsMs == 0 && !stats.surfaceBuilt) return "";
  std::ostringstream line;
  line << std::fixed << std::setprecision(1) << "surface  iso " << iso << ": ";
  if (stats.surfaceSpacing > 1) {
    line << "clustered by cubes of " << stats.surfaceSpacing << " voxels (--lod-pixels), " << stats.surfaceTriangles << " triangles made in "
         << stats.surfaceBuildMs << " ms\n";
    return line.str();
  }
  line << "Surface Octree ";
  if (stats.surfaceBuilt)
    line << "built in " << stats.surfaceBuildMs << " ms";
  else
    line << (fromScene ? "from the scene" : "kept");
  line << ", " << stats.surfacePolygons << " polygons (" << stats.surfaceTriangles << " triangles) reconstructed in " << stats.surfacePolygonsMs
       << " ms";
  if (stats.surfaceRegionsMade + stats.surfaceRegionsKept > 0)
    line << " by regions (" << stats.surfaceRegionsMade << " made, " << stats.surfaceRegionsKept << " kept; the polygons the frame draws kept)";
  line << "\n";
  return line.str();
}

}  // namespace hyb::app
