#include "apps/viewer/viewer_replies.h"

#include <nlohmann/json.hpp>

#include <chrono>
#include <iomanip>
#include <sstream>

namespace hyb::viewer {

using nlohmann::json;

namespace {

// Text the page parses: invalid UTF-8 (a file name, a DICOM description) replaced, never thrown on.
std::string dumped(const json& j) { return j.dump(-1, ' ', false, json::error_handler_t::replace); }

json vec3Json(const glm::dvec3& v) { return json::array({v.x, v.y, v.z}); }

// The camera in the frame table's viewer fields (eye, center, up, fov, ortho, ortho_height, size).
json viewerCamera(const Camera& c) { return settingsJson(cameraSettings(c), kViewer, isCameraField); }

json pointsJson(const TransferFunction& tf) {
  json pts = json::array();
  for (const TransferFunction::Point& q : tf.points()) pts.push_back(json::array({q.value, q.color.r, q.color.g, q.color.b, q.alpha}));
  return pts;
}

json volumesJson(const std::vector<DataEntry>& volumes) {
  json list = json::array();
  for (const DataEntry& e : volumes) list.push_back({{"path", e.path}, {"series", e.series}, {"label", e.label}});
  return list;
}

double epochMs() { return std::chrono::duration<double, std::milli>(std::chrono::system_clock::now().time_since_epoch()).count(); }

}  // namespace

std::string InfoReply::text() const {
  const SceneSummary& s = scene;
  json views = json::object();
  const char* names[] = {"anterior", "posterior", "left", "right", "superior", "inferior"};
  for (int v = 0; v < 6; ++v) views[names[v]] = viewerCamera(s.views[size_t(v)]);
  const Histogram& h = s.histogram;
  json presets = json::object();
  for (const std::string& p : TransferFunction::presetNames()) presets[p] = pointsJson(TransferFunction::preset(p));
  json info = {{"type", "info"},
               {"scene", s.key},
               {"name", s.name},
               {"dims", json::array({s.dims.x, s.dims.y, s.dims.z})},
               {"spacing", vec3Json(s.spacing)},
               {"range", json::array({s.minValue, s.maxValue})},
               {"histogram", {{"min", h.minValue}, {"max", h.maxValue}, {"counts", h.counts}}},
               {"orientation", s.orientation},
               {"orientationAssumed", s.orientationAssumed},
               {"bounds", {{"min", vec3Json(s.boundsLo)}, {"max", vec3Json(s.boundsHi)}}},
               {"center", vec3Json(0.5 * (s.boundsLo + s.boundsHi))},
               {"views", views},
               {"presets", presets},
               {"defaultPreset", TransferFunction::defaultPresetFor(s.minValue, s.maxValue)},
               {"defaultTf", pointsJson(TransferFunction::defaultFor(s.minValue, s.maxValue))},
               {"iso", s.sceneIso ? json(*s.sceneIso) : json(nullptr)},
               {"defaultIso", TransferFunction::defaultIsoFor(s.minValue, s.maxValue)},
               {"surfaces", surfaces},
               {"volumes", volumesJson(volumes)},
               {"fields", fieldsJson(kViewer)},
               {"preview", s.preview},
               {"meshes", meshes}};
  if (fromDataDir) info["open"] = {{"path", s.name}, {"series", s.series}};
  info["pacs"] = pacs.empty() ? json(nullptr) : json(pacs);
  return dumped(info);
}

std::string VolumesReply::text() const {
  return dumped({{"type", "volumes"}, {"volumes", volumesJson(volumes)}, {"pacs", pacs.empty() ? json(nullptr) : json(pacs)}, {"meshes", meshes}});
}

std::string PacsReply::label(const DicomWebSeries& s) {
  const DicomSeriesInfo& i = s.info;
  std::string text = i.patientName.empty() ? "(no name)" : i.patientName;
  for (const std::string& part : {i.studyDate, i.modality, i.description})
    if (!part.empty()) text += " · " + part;
  return text + " · " + std::to_string(i.slices) + (i.slices == 1 ? " instance" : " instances");
}

std::string PacsReply::text() const {
  json list = json::array();
  for (const DicomWebSeries& s : series) {
    const DicomSeriesInfo& i = s.info;
    list.push_back({{"url", s.url}, {"label", label(s)}, {"patient", i.patientName}, {"patient_id", i.patientId}, {"study_date", i.studyDate},
                    {"study", i.studyDescription}, {"modality", i.modality}, {"description", i.description}, {"number", i.number},
                    {"instances", i.slices}});
  }
  return dumped({{"type", "pacs"}, {"series", list}});
}

std::string LoadingReply::text() const { return dumped({{"type", "loading"}, {"scene", scene}, {"task", task}, {"progress", progress}}); }

std::string OpenFailedReply::text() const {
  json m = json::parse(errorMessage(message));
  m["scene"] = scene;
  return dumped(m);
}

std::string SurfaceReply::text() const {
  using State = ScenePool::SurfaceState;
  json m = {{"type", "surface"}, {"scene", scene}, {"iso", iso}, {"state", state == State::Building ? "building" : state == State::Ready ? "ready" : "failed"}};
  if (state == State::Building) m["task"] = task, m["progress"] = progress;
  return dumped(m);
}

std::string FrameHeader::text(int width, int height, double encodeMs) const {
  const std::optional<float> iso = surface.drawn(r);
  json header = {{"type", "frame"},
                 {"scene", scene.key},
                 {"seq", r.seq},
                 {"quality", r.interacting ? "interactive" : final ? "final" : "refining"},
                 {"level", level},
                 {"ladder", iso ? "surface" : "volume"},
                 {"levelText", q.describe()},
                 {"format", png() ? "png" : "jpeg"},
                 {"width", width},
                 {"height", height},
                 {"waitMs", arrival ? json(arrival->waitMs) : json(nullptr)},
                 {"requestEpochMs", arrival ? json(arrival->epochMs) : json(nullptr)},
                 // other clients' frames or bands drawn between the request's arrival and its frame
                 {"waitedRenders", arrival ? json(arrival->waitedRenders) : json(nullptr)},
                 {"bands", bands},
                 {"longestBandMs", longestBandMs},
                 {"sentEpochMs", epochMs()},
                 {"renderMs", renderMs},
                 {"encodeMs", encodeMs},
                 {"textureBytes", st.slices.textureBytes},
                 {"bricks", st.slices.bricks},
                 {"maxError", maxError},
                 {"bricksNotResident", st.bricksNotResident},  // > 0: bricks drawn coarser (beyond the packing bound, or loading)
                 {"iso", iso ? json(*iso) : json(nullptr)},
                 {"surfaceReady", !r.settings.iso || surface.ready},  // false: the surface asked for is still being built
                 // > 1: the surface drawn is clustered by cubes this many voxels wide (a preview, or the level of detail)
                 {"surfaceSpacing", iso ? json(st.surfaceSpacing) : json(nullptr)},
                 {"surfaceBuilding", surface.building},  // the surface asked for, or its levels for moving frames, on its way
                 {"camera", viewerCamera(explicitCamera(r.settings))},
                 {"preview", scene.preview}};  // of the coarse stand-in shown while the scene loads
  // (while the surface asked for is built, or of a preview, the frame is not the command's)
  if (final && !scene.preview && (!r.settings.iso || surface.ready)) {
    header["command"] = renderCommand(scene.path, scene.series, r, "view.tf");
    if (!r.settings.tfPoints.empty()) header["tfText"] = tfText(r.settings.tfPoints);
  }
  return dumped(header);
}

std::string renderCommand(const std::string& path, const std::string& series, const FrameRequest& r, const std::string& tfFile) {
  FrameSettings s = r.settings;
  if (!s.tfPoints.empty()) {
    s.tfPoints.clear();
    s.tf = tfFile;
  }
  if (!s.iso) s.surfaceColor = kDefaultSurfaceColor;  // (no surface: its colour says nothing)
  std::string cmd = "hybrid-octree render " + shellQuote(path);
  if (!series.empty()) cmd += " --series " + shellQuote(series);
  return cmd + commandLineOf(s) + " -o view.png";
}

std::string tfText(const std::vector<TransferFunction::Point>& points) {
  std::ostringstream s;
  s << "# value r g b a (opacity of 1 mm)\n" << std::setprecision(9);
  for (const TransferFunction::Point& p : points) s << p.value << " " << p.color.r << " " << p.color.g << " " << p.color.b << " " << p.alpha << "\n";
  return s.str();
}

}  // namespace hyb::viewer
