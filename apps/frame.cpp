#include "apps/frame.h"

#include <chrono>
#include <cmath>
#include <iomanip>
#include <ostream>
#include <sstream>

#include "hybrid_octree/surface_octree.h"
#include "render/bvh.h"
#include "surface/mesh_ops.h"

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

Volume VolumeInput::read(std::ostream& err) const {
  const std::optional<RawLayout> raw = rawLayout();
  Volume v = readVolume(path, raw ? &*raw : nullptr, series, progress);
  printWarnings(v, err);
  return v;
}

void printWarnings(const Volume& v, std::ostream& err) {
  for (const std::string& w : v.warnings()) err << "hybrid-octree: warning: " << w << "\n";
}

Scene loadOrBuild(const VolumeInput& in, std::ostream& out, std::ostream& err, double* buildMs, const VolumeOctreeOptions& options) {
  const auto t0 = Clock::now();
  Scene scene;
  if (!in.rawLayout() && isSceneFile(in.path)) {
    if (!in.series.empty()) HYB_THROW(ValueError, "--series needs a DICOM directory (", in.path, " is a scene file)");
    scene = loadScene(in.path);
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
  if (w != std::floor(w) || h != std::floor(h) || w < 1 || h < 1 || w > 16384 || h > 16384)
    HYB_THROW(IoError, path, ": camera width and height must be whole numbers of pixels in 1..16384");
  c.width = int(w);
  c.height = int(h);
  if (!(c.fovDeg > 0 && c.fovDeg < 179)) HYB_THROW(IoError, path, ": camera field 'fov_deg' must be in (0, 179) degrees");
  if (!(c.orthoHeight > 0)) HYB_THROW(IoError, path, ": camera field 'ortho_height' must be positive");
  if (glm::length(c.eye - c.center) == 0 || glm::length(glm::cross(c.center - c.eye, c.up)) == 0)
    HYB_THROW(IoError, path, ": camera eye, center and up must give a view direction not parallel to up");
  return c;
}

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

void prepareFrame(const RenderOptions& o, std::ostream& out, std::ostream& err, Frame* f) {
  // Flags that need no data first, so that a typo fails before the volume is read.
  f->surfaceColor = parseColor(o.surfaceColor, "--surface-color", 4);
  std::optional<CutPlane> cut;
  if (!o.cut.empty()) {
    const char* expected = "px,py,pz,nx,ny,nz: a point and a non-zero normal, finite patient mm";
    const std::vector<double> x = parseNumbers(o.cut, "--cut", 6, expected);
    if (x[3] == 0 && x[4] == 0 && x[5] == 0) HYB_THROW(ValueError, "--cut '", o.cut, "' invalid (expected ", expected, ")");
    cut = CutPlane{glm::dvec3(x[0], x[1], x[2]), glm::dvec3(x[3], x[4], x[5])};
  }
  if (!o.voi.empty()) {
    const char* expected = "x0,y0,z0,x1,y1,z1: the box's corners in patient mm, x0 < x1, y0 < y1, z0 < z1";
    const std::vector<double> x = parseNumbers(o.voi, "--voi", 6, expected);
    VolumeOfInterest voi;
    voi.lo = glm::dvec3(x[0], x[1], x[2]);
    voi.hi = glm::dvec3(x[3], x[4], x[5]);
    if (!glm::all(glm::lessThan(voi.lo, voi.hi))) HYB_THROW(ValueError, "--voi '", o.voi, "' invalid (expected ", expected, ")");
    voi.inside = o.voiInside;
    voi.outside = o.voiOutside;
    voi.ramp = o.voiRamp;
    f->voi = voi;
  }
  std::optional<glm::dvec3> focus;
  if (!o.focus.empty()) focus = parseVec3(o.focus, "--focus");
  f->background = glm::vec3(parseColor(o.background, "--background", 3));
  std::optional<glm::ivec2> size;
  if (!o.size.empty()) size = parseSize(o.size);
  std::optional<Camera> fromFile;
  if (!o.cameraFile.empty()) fromFile = readCameraFile(o.cameraFile);
  ViewDirection direction = viewDirection(AnatomicalView::Anterior);
  if (!o.orbit.empty()) {
    const std::vector<double> orbit = parseNumbers(o.orbit, "--orbit", 2, "two finite numbers azimuth,elevation in degrees");
    direction = orbitDirection(orbit[0], orbit[1]);
  } else if (AnatomicalView view; parseAnatomicalView(o.view, &view)) {
    direction = viewDirection(view);
  }
  VolumeOctreeOptions octree;
  octree.prefilter = o.prefilter == "on";
  f->scene = loadOrBuild(o.input, out, err, &f->buildMs, octree);
  const Volume& v = f->scene.volume;
  const PatientFrame& frame = v.frame();
  // Transfer function: file, preset, or a default chosen from the data's range.
  f->tf = !o.tfFile.empty()   ? TransferFunction::fromFile(o.tfFile)
          : !o.preset.empty() ? TransferFunction::preset(o.preset)
                              : TransferFunction::defaultFor(v.minValue(), v.maxValue());
  // Surface: the scene's when the isovalue matches, else built now.
  if (o.iso) {
    if (*o.iso <= v.minValue() || *o.iso > v.maxValue())
      err << "hybrid-octree: warning: --iso " << *o.iso << " is outside the data's crossing range (" << v.minValue() << ", " << v.maxValue()
          << "]: the surface is empty\n";
    if (f->scene.surface && f->scene.surface->isovalue() == float(*o.iso)) {
      f->so = &*f->scene.surface;
    } else {
      const auto t0 = Clock::now();
      f->builtSurface = SurfaceOctree::build(v, f->scene.octree, float(*o.iso));
      f->surfaceMs = msSince(t0);
      f->so = &*f->builtSurface;
    }
    const auto t0 = Clock::now();
    const DiscreteMesh d = f->so->reconstruct(0, o.input.progress);
    f->polygons = d.faceCount();
    f->mesh = fineMeshToTriangles(d, v.spacing());
    if (o.surfaceNormals == "gradient") setGradientNormals(v, &f->mesh);
    f->polygonsMs = msSince(t0);
    std::ostringstream line;
    line << std::fixed << std::setprecision(1) << "surface  iso " << *o.iso << ": Surface Octree ";
    if (f->builtSurface)
      line << "built in " << f->surfaceMs << " ms";
    else
      line << "from the scene";
    line << ", " << f->polygons << " polygons (" << f->mesh.triangles.size() << " triangles) reconstructed in " << f->polygonsMs << " ms\n";
    out << line.str();
  }
  // The camera, in patient space: from a file, explicit, or the view framing what is visible.
  Camera& camera = f->patientCamera;
  const glm::ivec2 pixels = size.value_or(fromFile ? glm::ivec2(fromFile->width, fromFile->height) : glm::ivec2(512, 512));
  const glm::dvec3 volumeCentre = frame.toPatient(0.5 * v.extentMm());
  if (fromFile) {
    camera = *fromFile;
  } else if (!o.eye.empty()) {
    camera.eye = parseVec3(o.eye, "--eye");
    camera.center = o.center.empty() ? volumeCentre : parseVec3(o.center, "--center");
    camera.up = parseVec3(o.up, "--up");
    if (glm::length(camera.eye - camera.center) == 0 || glm::length(glm::cross(camera.center - camera.eye, camera.up)) == 0)
      HYB_THROW(ValueError, "--eye, --center and --up must give a view direction not parallel to up");
    camera.fovDeg = o.fov;
    camera.ortho = o.ortho;
    camera.orthoHeight = glm::length(v.extentMm()) * 1.05;
  } else {
    std::vector<glm::dvec3> points =
        visiblePoints(v, f->scene.octree, f->tf, o.iso ? std::optional<float>(float(*o.iso)) : std::nullopt);
    if (points.empty())  // nothing visible: the data's box
      for (int c = 0; c < 8; ++c) points.push_back(frame.toPatient(glm::dvec3(c & 1, (c >> 1) & 1, (c >> 2) & 1) * v.extentMm()));
    camera = fitCamera(points, direction, o.fov, o.ortho, pixels.x, pixels.y);
  }
  camera.width = pixels.x;
  camera.height = pixels.y;
  if (o.zoom != 1.0) zoomCamera(&camera, o.zoom);
  f->camera = toGridCamera(camera, frame);
  // The user's other coordinates, patient mm, into the grid frame.
  if (cut) f->cut = CutPlane{frame.toGrid(cut->point), frame.vectorToGrid(cut->normal)};
  if (focus) f->focus = frame.toGrid(*focus);
  if (f->voi) {
    f->voi->toBox = frame.direction;
    f->voi->offset = frame.origin;
  }
}

SelectionParams selectionParams(const RenderOptions& o, const Frame& f, double epsilon, double budgetMb) {
  const Volume& v = f.scene.volume;
  SelectionParams params;
  params.epsilon = float(epsilon);
  params.spacing = v.spacing();
  params.maxBrickEdge = o.maxBrick;
  params.focus = f.focus;
  params.eye = f.camera.eye;
  // Texture memory is counted at the bricks' bytes a texel (value and gradient; the extrapolated
  // texels included).
  // A budget beyond 2^62 texels limits nothing (and would overflow the count): unlimited.
  const double texels = budgetMb * 1024.0 * 1024.0 / double(bytesPerTexel(o.bits()));
  params.texelBudget = texels < 0x1p62 ? uint64_t(texels) : 0;
  if (budgetMb > 0 && texels < 1.0) HYB_THROW(ValueError, "--budget ", budgetMb, " MB is smaller than one texel");
  params.blend = o.blend == "on";
  const TransferFunction* tf = &f.tf;
  const Camera* camera = &f.camera;
  params.opacity = [tf](float lo, float hi) { return tf->maxAlpha(lo, hi); };
  // LaMar's screen-space stop: the size of a pixel at a box's nearest point.
  params.lodPixels = o.lodPixels;
  params.pixelSize = [camera](const glm::dvec3& lo, const glm::dvec3& hi) {
    if (camera->ortho) return camera->orthoHeight / camera->height;
    const double d = glm::length(camera->eye - glm::clamp(camera->eye, lo, hi));
    return 2.0 * d * std::tan(glm::radians(camera->fovDeg) * 0.5) / camera->height;
  };
  params.distortion = [tf](float lo, float hi, float error) { return tf->distortion(lo, hi, error); };
  // Frustum culling, and nodes wholly on the removed side of the cutting plane.
  const glm::dvec4 cut = f.cut ? f.cut->keptSide(f.camera) : glm::dvec4(0, 0, 0, 1);
  // And nodes the volume of interest scales to zero opacity.
  const VolumeOfInterest* voi = f.voi ? &*f.voi : nullptr;
  // Within a budget, texels go where they change this image most (measured per brick, on first use).
  auto estimate = [frame = &f, cut, voi]() -> BrickImageError& {
    if (!frame->brickError)
      frame->brickError = std::make_shared<BrickImageError>(frame->scene.volume, frame->scene.octree, frame->tf, frame->camera, cut, voi);
    return *frame->brickError;
  };
  params.brickError = [estimate](uint32_t node, int p) { return estimate()(node, p); };
  params.prefetchBrickErrors = [estimate](const std::vector<std::pair<uint32_t, int>>& bricks) { estimate().prefetch(bricks); };
  params.inView = [camera, cut, voi](const glm::dvec3& lo, const glm::dvec3& hi) {
    const glm::dvec3 far = glm::mix(lo, hi, glm::dvec3(glm::greaterThan(glm::dvec3(cut), glm::dvec3(0.0))));
    return glm::dot(glm::dvec3(cut), far) + cut.w >= 0.0 && camera->seesBox(lo, hi) && !(voi && voi->hides(lo, hi));
  };
  return params;
}

Image renderFrame(const RenderOptions& o, const Frame& f, const Selection& sel, SlicesStats* ss, RaycastStats* rs,
                  BrickTextureCache* textures, const std::function<void(int, const Image&, uint64_t)>& onLevel) {
  const Volume& v = f.scene.volume;
  if (o.renderer == "slices") {
    SlicesOptions opt;
    opt.stepVoxels = o.step.value_or(0.5);
    opt.shading = o.shading == "on";
    opt.texelBits = o.bits();
    opt.surface = f.so ? &f.mesh : nullptr;
    opt.surfaceColor = f.surfaceColor;
    opt.cut = f.cut ? &*f.cut : nullptr;
    opt.cutLine = o.cutLine == "on";
    opt.voi = f.voi ? &*f.voi : nullptr;
    opt.proxy = o.proxy == "shells" ? Proxy::Shells : Proxy::Planes;
    opt.textures = textures;
    return renderSlices(v, f.scene.octree, sel, f.tf, f.camera, opt, ss);
  }
  const Bvh bvh(f.mesh);
  RaycastOptions ro;
  ro.stepVoxels = o.step.value_or(0.25);
  ro.shading = o.shading == "on";
  ro.surface = f.so ? &bvh : nullptr;
  ro.surfaceColor = f.surfaceColor;
  ro.cut = f.cut ? &*f.cut : nullptr;
  ro.voi = f.voi ? &*f.voi : nullptr;
  // Levoy's refinement: --progressive N levels (the first grid 2^(N−1) pixels apart), or four with
  // --adaptive alone; the last level is exact unless --adaptive is given.
  ro.refineLevels = o.progressive > 1 ? o.progressive : o.adaptive > 0 ? 4 : 1;
  ro.refineTolerance = float(o.adaptive / 255.0);
  ro.onLevel = onLevel;
  ro.progress = o.input.progress;
  return raycast(v, f.scene.octree, f.tf, f.camera, ro, rs);
}

}  // namespace hyb::app
