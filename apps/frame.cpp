#include "apps/frame.h"

#include <chrono>
#include <cmath>
#include <filesystem>
#include <iomanip>
#include <ostream>
#include <sstream>

#include "apps/outputs.h"
#include "hybrid_octree/surface_octree.h"
#include "render/bvh.h"
#include "surface/mesh_ops.h"
#include "volume/dicomweb.h"
#include "volume/file_util.h"
#include "volume/memory_limit.h"

#include <nlohmann/json.hpp>

namespace hyb::app {

std::vector<double> parseNumbers(const std::string& text, const std::string& flag, size_t n, const char* expected) {
  std::string t = text;
  for (char& c : t)
    if (c == ',') c = ' ';
  std::istringstream s(t);
  std::vector<double> x;
  double e = 0;
  while (s >> e && std::isfinite(e)) x.push_back(e);
  if (!s.eof() || x.empty() || (n > 0 && x.size() != n)) HYB_THROW(ValueError, flag, " '", text, "' invalid (expected ", expected, ")");
  return x;
}

std::optional<Budget> parseBudget(const std::string& text) {
  Budget b;
  b.percent = !text.empty() && text.back() == '%';
  const std::string number = b.percent ? text.substr(0, text.size() - 1) : text;
  std::istringstream s(number);
  if (!(s >> b.value) || !s.eof() || !std::isfinite(b.value)) return std::nullopt;
  if (b.percent ? !(b.value > 0.0 && b.value <= 100.0) : b.value < 0.0) return std::nullopt;
  return b;
}

glm::dvec3 parseVec3(const std::string& text, const std::string& flag) {
  const std::vector<double> x = parseNumbers(text, flag, 3, "three finite numbers x,y,z");
  return {x[0], x[1], x[2]};
}

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
  cmd->add_option("--series", series, "DICOM directory: the Series Instance UID to read (default: the largest series; info lists them)");
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
  const auto t0 = Clock::now();
  Scene scene;
  if (!in.rawLayout() && isSceneFile(in.path)) {
    if (!in.series.empty()) HYB_THROW(ValueError, "--series needs a DICOM directory (", in.path, " is a scene file)");
    scene = loadScene(in.path, load);
    *buildMs = 0.0;
    out << "loaded scene " << in.path << " in " << std::fixed << std::setprecision(1) << msSince(t0) << " ms\n";
    return scene;
  }
  scene.volume = in.read(err);
  const auto t1 = Clock::now();
  VolumeOctreeOptions withProgress = options;
  withProgress.progress = in.progress;
  scene.octree = VolumeOctree::build(scene.volume, withProgress);
  *buildMs = msSince(t1);
  out << "read " << in.path << " in " << std::fixed << std::setprecision(1) << msSince(t0) - *buildMs
      << " ms, built volume octree in " << *buildMs << " ms\n";
  return scene;
}

std::string cameraJson(const Camera& c, int indent) {
  nlohmann::ordered_json j;
  j["space"] = "LPS";
  j["eye"] = {c.eye.x, c.eye.y, c.eye.z};
  j["center"] = {c.center.x, c.center.y, c.center.z};
  j["up"] = {c.up.x, c.up.y, c.up.z};
  j["fov_deg"] = c.fovDeg;
  j["ortho"] = c.ortho;
  j["ortho_height"] = c.orthoHeight;
  j["width"] = c.width;
  j["height"] = c.height;
  return j.dump(indent);
}

Camera readCameraFile(const std::string& path) {
  const std::vector<uint8_t> bytes = readFileBytes(path);
  nlohmann::json j = nlohmann::json::parse(bytes.begin(), bytes.end(), nullptr, false);
  if (j.is_discarded() || !j.is_object()) HYB_THROW(IoError, path, ": not a JSON object (expected a camera written by --stats)");
  if (j.contains("camera")) j = j["camera"];
  auto number = [&](const char* key) {
    if (!j.contains(key) || !j[key].is_number() || !std::isfinite(j[key].get<double>()))
      HYB_THROW(IoError, path, ": camera field '", key, "' missing or not a finite number");
    return j[key].get<double>();
  };
  auto vector = [&](const char* key) {
    if (!j.contains(key) || !j[key].is_array() || j[key].size() != 3)
      HYB_THROW(IoError, path, ": camera field '", key, "' missing or not three numbers");
    glm::dvec3 v;
    for (int a = 0; a < 3; ++a) {
      if (!j[key][size_t(a)].is_number() || !std::isfinite(j[key][size_t(a)].get<double>()))
        HYB_THROW(IoError, path, ": camera field '", key, "' missing or not three numbers");
      v[a] = j[key][size_t(a)].get<double>();
    }
    return v;
  };
  if (j.contains("space") && j["space"] != "LPS") HYB_THROW(IoError, path, ": camera space ", j["space"].dump(), " unsupported (expected \"LPS\")");
  Camera c;
  c.eye = vector("eye");
  c.center = vector("center");
  c.up = vector("up");
  c.fovDeg = number("fov_deg");
  if (!j.contains("ortho") || !j["ortho"].is_boolean()) HYB_THROW(IoError, path, ": camera field 'ortho' missing or not true/false");
  c.ortho = j["ortho"].get<bool>();
  c.orthoHeight = number("ortho_height");
  const double w = number("width"), h = number("height");
  if (w != std::floor(w) || h != std::floor(h) || w < 1 || h < 1 || w > kMaxRenderEdge || h > kMaxRenderEdge)
    HYB_THROW(IoError, path, ": camera width and height must be whole numbers of pixels in 1..", kMaxRenderEdge);
  c.width = int(w);
  c.height = int(h);
  if (!(c.fovDeg >= kMinFovDeg && c.fovDeg < kMaxFovDeg)) HYB_THROW(IoError, path, ": camera field 'fov_deg' must be in [0.1, 179) degrees");
  if (!(c.orthoHeight >= 1e-3 && c.orthoHeight <= kMaxCameraMm)) HYB_THROW(IoError, path, ": camera field 'ortho_height' must be in [0.001, 1e6] mm");
  for (const auto& [p, key] : {std::pair{c.eye, "eye"}, std::pair{c.center, "center"}})
    if (!withinCameraRange(p)) HYB_THROW(IoError, path, ": camera field '", key, "' must be within 1e6 mm of the patient origin");
  if (glm::length(c.eye - c.center) == 0) HYB_THROW(IoError, path, ": camera fields 'eye' and 'center' must differ");
  if (glm::length(glm::cross(c.center - c.eye, c.up)) == 0) HYB_THROW(IoError, path, ": camera field 'up' must be non-zero and not parallel to the view direction (eye to center)");
  return c;
}

glm::ivec2 parseSize(const std::string& text) {
  int w = 0, h = 0;
  char x = 0;
  std::istringstream s(text);
  std::string rest;
  if (!(s >> w >> x >> h) || (x != 'x' && x != 'X') || (s >> rest) || w < 1 || h < 1 || w > kMaxRenderEdge || h > kMaxRenderEdge)
    HYB_THROW(ValueError, "--size '", text, "' invalid (expected WxH, 1..", kMaxRenderEdge, " each)");
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

namespace {

// Options that parse their text into a type when they are read: a bad value is refused right there,
// in one message naming the flag.
template <class T>
CLI::Option* addChoice(CLI::App* cmd, const std::string& name, T* field, std::vector<std::pair<std::string, T>> choices, const std::string& help) {
  std::string names;
  for (const auto& [word, value] : choices) names += (names.empty() ? "" : "|") + word;
  return cmd->add_option_function<std::string>(
      name,
      [=](const std::string& text) {
        for (const auto& [word, value] : choices)
          if (text == word) return void(*field = value);
        std::string expected;
        for (size_t i = 0; i < choices.size(); ++i)
          expected += (i == 0 ? "" : i + 1 == choices.size() ? " or " : ", ") + choices[i].first;
        HYB_THROW(ValueError, name, " '", text, "' invalid (expected ", expected, ")");
      },
      help + " (" + names + ")");
}
CLI::Option* addVec3(CLI::App* cmd, const std::string& name, std::optional<glm::dvec3>* field, const std::string& help) {
  return cmd->add_option_function<std::string>(name, [=](const std::string& text) { *field = parseVec3(text, name); }, help);
}

}  // namespace

CLI::Option* addSwitch(CLI::App* cmd, const std::string& name, bool* field, const std::string& help) {
  return addChoice<bool>(cmd, name, field, {{"on", true}, {"off", false}}, help);
}

std::string RenderOptions::validate() const {
  if (std::string e = quality.validate(); !e.empty()) return e;
  if (!(fov >= kMinFovDeg && fov < kMaxFovDeg)) return "--fov must be in [0.1, 179) degrees";
  if (memoryMb && !(*memoryMb >= 1.0 && *memoryMb <= 1e9)) return "--memory must be megabytes in [1, 1e9]";
  const auto far = [](const std::optional<glm::dvec3>& p) { return p && !withinCameraRange(*p); };
  const std::string range = " must be within 1e6 mm (1 km) of the patient origin in each coordinate";
  if (far(eye)) return "--eye" + range;
  if (far(center)) return "--center" + range;
  if (far(quality.focus)) return "--focus" + range;
  if (cut && !withinCameraRange(cut->point)) return "--cut's point" + range;
  if (voiBox && (!withinCameraRange(voiBox->first) || !withinCameraRange(voiBox->second))) return "--voi" + range;
  if (!(std::isfinite(zoom) && zoom > 0 && zoom <= 1000)) return "--zoom must be a magnification in (0, 1000]";
  if (!(std::isfinite(voiInside) && voiInside >= 0)) return "--voi-inside must be a finite factor >= 0";
  if (!(std::isfinite(voiOutside) && voiOutside >= 0)) return "--voi-outside must be a finite factor >= 0";
  if (!(std::isfinite(voiRamp) && voiRamp >= 0)) return "--voi-ramp must be a finite width >= 0 mm";
  if (iso && !isFloat(*iso)) return "--iso must be a finite number within the float range (|x| <= 3.4e38)";
  if (repeat < 1 || repeat > 100) return "--repeat must be in 1..100 frames";
  if (!tfFile.empty() && !preset.empty()) return "--tf and --preset are exclusive";
  if (!cameraFile.empty() && (eye || orbit || view)) return "--camera-file sets the whole camera (it excludes --eye, --orbit and --view)";
  if (!output.empty() && fileExtension(output) != ".png") return "-o '" + output + "' must be a .png file (render writes PNG images)";
  return outputsError({{output, "-o"}, {stats, "--stats"}}, {input.path, tfFile, cameraFile});
}

void RenderOptions::add(CLI::App* cmd) {
  input.add(cmd);
  // What is shown.
  cmd->add_option("--iso", iso, "isovalue of the embedded surface (data units; none = volume only)");
  cmd->add_option("--memory", memoryMb,
                  "MB a scene file read paged holds: its octree, the surface made of it, and the cache of decompressed blocks its bricks are read through, which gets what they leave, at least a quarter (default: an eighth of the physical memory)");
  cmd->add_option_function<std::string>("--surface-color", [this](const std::string& t) { surfaceColor = parseColor(t, "--surface-color", 4); },
                                        "surface r,g,b,a in [0,1]; a < 1 is translucent (default 0.95,0.92,0.85,1)");
  addChoice<SurfaceNormals>(cmd, "--surface-normals", &surfaceNormals, {{"gradient", SurfaceNormals::Gradient}, {"facet", SurfaceNormals::Facet}},
                            "surface shading: the volume's gradient at each vertex (smooth, default) or each polygon's own plane");
  cmd->add_option("--tf", tfFile, "transfer function file: 'value r g b a' lines, a = opacity of 1 mm");
  std::string presets;
  for (const TransferFunction::Preset& p : TransferFunction::presets()) presets += (presets.empty() ? "" : ", ") + std::string(p.name) + " (" + p.shows + ")";
  cmd->add_option("--preset", preset, "transfer function: " + presets + "; default: " + TransferFunction::presets().front().name +
                                           " for CT, a ramp over the data's range for other data");
  cmd->add_option_function<std::string>("--background", [this](const std::string& t) { background = glm::vec3(parseColor(t, "--background", 3)); },
                                        "background r,g,b in [0,1] (default 0,0,0)");
  addSwitch(cmd, "--shading", &shading, "gradient shading of the volume (default on)");
  cmd->add_option_function<std::string>(
      "--cut",
      [this](const std::string& t) {
        const char* expected = "px,py,pz,nx,ny,nz: a point and a non-zero normal, finite patient mm";
        const std::vector<double> x = parseNumbers(t, "--cut", 6, expected);
        if (x[3] == 0 && x[4] == 0 && x[5] == 0) HYB_THROW(ValueError, "--cut '", t, "' invalid (expected ", expected, ")");
        cut = CutPlane{glm::dvec3(x[0], x[1], x[2]), glm::dvec3(x[3], x[4], x[5])};
      },
      "cutting plane px,py,pz,nx,ny,nz (point and normal, patient mm): removes the eye's side, shows the data on it");
  addSwitch(cmd, "--cut-line", &cutLine, "draw the isosurface's intersection with the cutting plane (default on)");
  cmd->add_option_function<std::string>(
      "--voi",
      [this](const std::string& t) {
        const char* expected = "x0,y0,z0,x1,y1,z1: the box's corners in patient mm, x0 < x1, y0 < y1, z0 < z1";
        const std::vector<double> x = parseNumbers(t, "--voi", 6, expected);
        const glm::dvec3 lo(x[0], x[1], x[2]), hi(x[3], x[4], x[5]);
        if (!glm::all(glm::lessThan(lo, hi))) HYB_THROW(ValueError, "--voi '", t, "' invalid (expected ", expected, ")");
        voiBox = std::pair{lo, hi};
      },
      "volume of interest x0,y0,z0,x1,y1,z1 (patient mm): opacity scaled inside/outside the box (Levoy)");
  cmd->add_option("--voi-inside", voiInside, "opacity factor inside the volume of interest")->capture_default_str();
  cmd->add_option("--voi-outside", voiOutside, "opacity factor outside the volume of interest")->capture_default_str();
  cmd->add_option("--voi-ramp", voiRamp, "width of the smooth transition across the box's surface, mm")->capture_default_str();
  // Where from.
  CLI::Option* eyeOption = addVec3(cmd, "--eye", &eye, "camera position x,y,z, patient mm (LPS: x left, y posterior, z superior; with --center, --up)");
  // Without --eye the camera orbits, and a --center or --up would be silently ignored.
  addVec3(cmd, "--center", &center, "point looked at, x,y,z, patient mm (default: the volume's centre); needs --eye")->needs(eyeOption);
  cmd->add_option_function<std::string>("--up", [this](const std::string& t) { up = parseVec3(t, "--up"); },
                                        "up direction x,y,z in patient axes (LPS, default 0,0,1); needs --eye")
      ->needs(eyeOption);
  CLI::Option* viewOption = cmd->add_option_function<std::string>(
                      "--view",
                      [this](const std::string& t) {
                        AnatomicalView v;
                        if (!parseAnatomicalView(t, &v)) HYB_THROW(ValueError, "--view '", t, "' invalid (expected ", anatomicalViewNames(), ")");
                        view = v;
                      },
                      "anatomical view: anterior (default; the patient's left on the image's right), posterior, left, right, superior, inferior")
                   ->excludes(eyeOption);
  cmd->add_option_function<std::string>(
         "--orbit",
         [this](const std::string& t) {
           const std::vector<double> x = parseNumbers(t, "--orbit", 2, "two finite numbers azimuth,elevation in degrees");
           orbit = glm::dvec2(x[0], x[1]);
         },
         "azimuth,elevation in degrees from the anterior view: azimuth towards the patient's left (90 = left view), elevation towards superior")
      ->excludes(eyeOption)
      ->excludes(viewOption);
  cmd->add_option("--zoom", zoom, "magnify the image about its centre (2 = twice as large; default framing fits what is visible)")->capture_default_str();
  cmd->add_option("--camera-file", cameraFile, "read the camera from a JSON file written by --stats (or its \"camera\" object alone)");
  addSwitch(cmd, "--marker", &marker, "orientation marker (patient axes L/R, P/A, S/I) in the lower-left corner (default off)");
  cmd->add_option("--fov", fov, "vertical field of view in degrees")->capture_default_str();
  cmd->add_flag("--ortho", ortho, "orthographic projection");
  cmd->add_option_function<std::string>("--size", [this](const std::string& t) { size = parseSize(t); },
                                        "image size WxH (default 512x512, or the camera file's)");
  // How well.
  addChoice<Renderer>(cmd, "--renderer", &quality.renderer, {{"slices", Renderer::Slices}, {"raycast", Renderer::Raycast}},
                      "the slice renderer (default) or the reference ray tracer");
  cmd->add_option("--epsilon", quality.epsilon, "user error epsilon_u in data units (0 = exact)")->capture_default_str();
  cmd->add_option_function<std::string>(
      "--budget",
      [this](const std::string& t) {
        const std::optional<Budget> b = parseBudget(t);
        if (!b)
          HYB_THROW(ValueError, "--budget '", t,
                    "' invalid (expected megabytes >= 0, or a percentage of the full-resolution texture bytes: 0 < P <= 100 followed by %)");
        budgetText = t;
        (b->percent ? quality.budgetPercent : quality.budgetMb) = b->value;
      },
      "texture memory budget in MB, blend textures included (0 = unlimited), or P% of this view's full-resolution bytes");
  addChoice<Proxy>(cmd, "--proxy", &quality.proxy, {{"planes", Proxy::Planes}, {"shells", Proxy::Shells}},
                   "slice geometry: view-aligned planes (default) or spherical shells around the eye (perspective)");
  addSwitch(cmd, "--blend", &quality.blend, "blend bricks towards coarser neighbours, Carmona et al. (default on)");
  addSwitch(cmd, "--prefilter", &prefilter,
            "coarse levels (texels 4+ voxels apart) hold the data smoothed by their tent filter instead of point samples; a scene file "
            "keeps the choice it was built with (default on)");
  addChoice<Classification>(cmd, "--classification", &quality.classification,
                            {{"post", Classification::Post}, {"preintegrated", Classification::PreIntegrated}},
                            "post-classified samples (default) or segments pre-integrated between their ends' values (finds narrow transfer-function "
                            "features between samples; two brick reads a fragment)");
  cmd->add_option("--image-scale", quality.imageScale,
                  "render at this fraction of --size and magnify bilinearly (as VTK's image sample distance 1/S); 1 renders every pixel")
      ->capture_default_str();
  cmd->add_option("--step", quality.step, "slice / sample spacing in voxels (default 0.5 for slices, 0.25 for raycast)");
  cmd->add_option("--lod-pixels", quality.lodPixels, "stop refining where texels are at most this many pixels apart on screen, and draw the surface with its vertices clustered by the largest cubes no wider (0 = off: full resolution)")
      ->capture_default_str();
  cmd->add_option("--max-brick", quality.maxBrickEdge, "brick edge in texels (power of two)")->capture_default_str();
  addChoice<TexelBits>(cmd, "--texel-bits", &quality.texelBits, {{"8", TexelBits::Eight}, {"16", TexelBits::Sixteen}},
                       "brick precision: value and gradient in 8 bits (default, fastest) or 16 (twice the memory, slower frames; for "
                       "transfer functions narrow against a brick's values, e.g. soft tissue)");
  addVec3(cmd, "--focus", &quality.focus, "region of interest x,y,z, patient mm (LPS)");
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
  setUpFrame(o, scene, &job, err);
  SceneRenderer::Options ro{0, o.input.progress, keepTextures};
  ro.memoryBytes = memoryBytes;
  job.renderer = std::make_unique<SceneRenderer>(std::move(scene), ro);
  return job;
}

void setUpFrame(const RenderOptions& o, const Scene& scene, RenderJob* out, std::ostream& err, const TransferFunction* tf) {
  std::optional<Camera> fromFile;
  if (!o.cameraFile.empty()) fromFile = readCameraFile(o.cameraFile);
  RenderJob& job = *out;
  const Volume& v = scene.volume;
  const PatientFrame& frame = v.frame();
  // What is shown: the transfer function from a file, a preset, or chosen for the data's range.
  Look& look = job.look;
  look.tf = tf                  ? *tf
            : !o.tfFile.empty() ? TransferFunction::fromFile(o.tfFile)
            : !o.preset.empty() ? TransferFunction::preset(o.preset)
                                : TransferFunction::defaultFor(v.minValue(), v.maxValue());
  if (o.iso) {
    look.iso = float(*o.iso);
    if (*o.iso <= v.minValue() || *o.iso > v.maxValue())
      err << "hybrid-octree: warning: --iso " << *o.iso << " is outside the data's crossing range (" << v.minValue() << ", " << v.maxValue()
          << "]: the surface is empty\n";
  }
  look.surfaceColor = o.surfaceColor;
  look.normals = o.surfaceNormals;
  look.shading = o.shading;
  look.cut = o.cut;
  look.cutLine = o.cutLine;
  if (o.voiBox) {
    VolumeOfInterest voi;
    voi.lo = o.voiBox->first;
    voi.hi = o.voiBox->second;
    voi.inside = o.voiInside;
    voi.outside = o.voiOutside;
    voi.ramp = o.voiRamp;
    look.voi = voi;
  }
  // Where from, in patient space: a camera file's, the --eye given, or the view framing what the
  // transfer function (or the isosurface) makes visible.
  Camera& camera = job.view.camera;
  const glm::ivec2 pixels = o.size.value_or(fromFile ? glm::ivec2(fromFile->width, fromFile->height) : glm::ivec2(512, 512));
  if (fromFile) {
    camera = *fromFile;
  } else if (o.eye) {
    camera.eye = *o.eye;
    camera.center = o.center.value_or(frame.toPatient(0.5 * v.extentMm()));
    camera.up = o.up;
    if (glm::length(camera.eye - camera.center) == 0) HYB_THROW(ValueError, "--eye and --center must differ (the view direction runs from the eye to the center)");
    if (glm::length(glm::cross(camera.center - camera.eye, camera.up)) == 0)
      HYB_THROW(ValueError, "--up must be non-zero and not parallel to the view direction (--eye to --center)");
    camera.fovDeg = o.fov;
    camera.ortho = o.ortho;
    camera.orthoHeight = glm::length(v.extentMm()) * 1.05;
  } else {
    const ViewDirection direction =
        o.orbit ? orbitDirection(o.orbit->x, o.orbit->y) : viewDirection(o.view.value_or(AnatomicalView::Anterior));
    std::vector<glm::dvec3> points = visiblePoints(v, scene.octree, look.tf, look.iso, scene.knots.get());
    if (points.empty())  // nothing visible: the data's box
      for (int c = 0; c < 8; ++c) points.push_back(frame.toPatient(glm::dvec3(c & 1, (c >> 1) & 1, (c >> 2) & 1) * v.extentMm()));
    camera = fitCamera(points, direction, o.fov, o.ortho, pixels.x, pixels.y);
    scene.octree.releasePages();  // the fit walked every visible leaf; the frame reads far fewer
  }
  camera.width = pixels.x;
  camera.height = pixels.y;
  if (o.zoom != 1.0) zoomCamera(&camera, o.zoom);
  if (!camera.ortho && !(camera.fovDeg >= kMinFovDeg && camera.fovDeg < kMaxFovDeg))
    HYB_THROW(ValueError, "--zoom ", o.zoom, " makes a field of view of ", camera.fovDeg, " degrees (expected a zoom keeping it in [0.1, 179))");
  job.quality = o.quality;
  job.background = o.background;
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
       << " ms\n";
  return line.str();
}

}  // namespace hyb::app
