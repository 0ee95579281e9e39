#include "apps/viewer_protocol.h"

#include <nlohmann/json.hpp>

#include <cmath>
#include <cstring>
#include <set>

#include "volume/error.h"

namespace hyb::viewer {

namespace {

using nlohmann::json;

// Nesting deeper than any valid message is refused while parsing, before it is built.
constexpr int kMaxDepth = 6;
constexpr double kMaxCoordinate = kMaxCameraMm;

[[noreturn]] void fail(const std::string& field, const std::string& expected) {
  throw ValueError("message field '" + field + "': expected " + expected);
}

void onlyFields(const json& object, const std::string& where, std::initializer_list<const char*> allowed) {
  for (const auto& [key, value] : object.items()) {
    bool known = false;
    for (const char* a : allowed) known = known || key == a;
    if (!known) fail(where.empty() ? key : where + "." + key, "no such field");
  }
}

const json& objectAt(const json& j, const std::string& name) {
  if (!j.is_object()) fail(name, "an object");
  return j;
}

double numberAt(const json& j, const std::string& name, double lo, double hi) {
  if (!j.is_number()) fail(name, "a number");
  const double x = j.get<double>();
  if (!std::isfinite(x) || x < lo || x > hi) fail(name, "a number in [" + json(lo).dump() + ", " + json(hi).dump() + "]");
  return x;
}

bool boolAt(const json& j, const std::string& name) {
  if (!j.is_boolean()) fail(name, "true or false");
  return j.get<bool>();
}

std::string stringAt(const json& j, const std::string& name, size_t maxBytes) {
  if (!j.is_string()) fail(name, "a string");
  std::string s = j.get<std::string>();
  if (s.size() > maxBytes) fail(name, "at most " + std::to_string(maxBytes) + " bytes");
  return s;
}

glm::dvec3 vec3At(const json& j, const std::string& name, double lo, double hi) {
  if (!j.is_array() || j.size() != 3) fail(name, "an array of 3 numbers");
  return {numberAt(j[0], name + "[0]", lo, hi), numberAt(j[1], name + "[1]", lo, hi), numberAt(j[2], name + "[2]", lo, hi)};
}

glm::dvec3 directionAt(const json& j, const std::string& name) {
  const glm::dvec3 d = vec3At(j, name, -kMaxCoordinate, kMaxCoordinate);
  if (!(glm::length(d) > 1e-9)) fail(name, "a direction (not zero)");
  return d;
}

Camera cameraAt(const json& j) {
  objectAt(j, "camera");
  onlyFields(j, "camera", {"eye", "center", "up", "fov", "ortho", "height", "width", "pixels"});
  Camera c;
  for (const char* required : {"eye", "center", "up", "pixels"})
    if (!j.contains(required)) fail(std::string("camera.") + required, "a value (missing)");
  c.eye = vec3At(j["eye"], "camera.eye", -kMaxCoordinate, kMaxCoordinate);
  c.center = vec3At(j["center"], "camera.center", -kMaxCoordinate, kMaxCoordinate);
  c.up = directionAt(j["up"], "camera.up");
  if (!(glm::length(c.center - c.eye) > 1e-6)) fail("camera.eye", "a point other than camera.center");
  if (glm::length(glm::cross(glm::normalize(c.center - c.eye), glm::normalize(c.up))) < 1e-6) fail("camera.up", "a direction not along the view");
  if (j.contains("fov")) c.fovDeg = numberAt(j["fov"], "camera.fov", 1.0, 120.0);
  if (j.contains("ortho")) c.ortho = boolAt(j["ortho"], "camera.ortho");
  if (j.contains("height")) c.orthoHeight = numberAt(j["height"], "camera.height", 1e-3, kMaxCoordinate);
  const json& px = j["pixels"];
  if (!px.is_array() || px.size() != 2) fail("camera.pixels", "an array [width, height]");
  c.width = int(numberAt(px[0], "camera.pixels[0]", kMinImageEdge, kMaxImageEdge));
  c.height = int(numberAt(px[1], "camera.pixels[1]", kMinImageEdge, kMaxImageEdge));
  if (px[0].get<double>() != c.width || px[1].get<double>() != c.height) fail("camera.pixels", "whole numbers");
  return c;
}

std::vector<TransferFunction::Point> pointsAt(const json& j) {
  if (!j.is_array() || j.empty() || j.size() > kMaxTfPoints)
    fail("tf.points", "an array of 1 to " + std::to_string(kMaxTfPoints) + " [value, r, g, b, a] points");
  std::vector<TransferFunction::Point> points;
  for (size_t i = 0; i < j.size(); ++i) {
    const std::string name = "tf.points[" + std::to_string(i) + "]";
    const json& p = j[i];
    if (!p.is_array() || p.size() != 5) fail(name, "[value, r, g, b, a]");
    TransferFunction::Point q;
    q.value = float(numberAt(p[0], name + "[0]", -1e30, 1e30));
    q.color = glm::vec3(float(numberAt(p[1], name + "[1]", 0, 1)), float(numberAt(p[2], name + "[2]", 0, 1)), float(numberAt(p[3], name + "[3]", 0, 1)));
    q.alpha = float(numberAt(p[4], name + "[4]", 0, 1));
    if (!points.empty() && q.value < points.back().value) fail(name, "values in increasing order");
    points.push_back(q);
  }
  return points;
}

FrameRequest frameAt(const json& j) {
  onlyFields(j, "", {"type", "seq", "scene", "interacting", "camera", "tf", "shading", "classification", "surface", "cut", "voi"});
  FrameRequest r;
  if (!j.contains("seq") || !j["seq"].is_number_unsigned()) fail("seq", "a whole number ≥ 0");
  r.seq = j["seq"].get<uint64_t>();
  if (j.contains("scene")) r.scene = stringAt(j["scene"], "scene", kMaxPathBytes + 256);
  if (j.contains("interacting")) r.interacting = boolAt(j["interacting"], "interacting");
  if (!j.contains("camera")) fail("camera", "a value (missing)");
  r.camera = cameraAt(j["camera"]);
  if (!j.contains("tf")) fail("tf", "a value (missing)");
  const json& tf = objectAt(j["tf"], "tf");
  onlyFields(tf, "tf", {"preset", "points", "opacity"});
  if (tf.contains("preset") == tf.contains("points")) fail("tf", "either preset or points");
  if (tf.contains("preset")) {
    r.preset = stringAt(tf["preset"], "tf.preset", 64);
    const std::vector<std::string> names = TransferFunction::presetNames();
    if (std::find(names.begin(), names.end(), r.preset) == names.end()) fail("tf.preset", "a preset name");
  } else {
    r.points = pointsAt(tf["points"]);
  }
  if (tf.contains("opacity")) r.opacityScale = float(numberAt(tf["opacity"], "tf.opacity", 0, 10));
  if (j.contains("shading")) r.shading = boolAt(j["shading"], "shading");
  if (j.contains("classification")) {
    const std::string c = stringAt(j["classification"], "classification", 32);
    if (c != "post" && c != "preintegrated") fail("classification", "\"post\" or \"preintegrated\"");
    r.classification = c == "post" ? Classification::Post : Classification::PreIntegrated;
  }
  if (j.contains("surface") && !j["surface"].is_null()) {
    const json& s = objectAt(j["surface"], "surface");
    onlyFields(s, "surface", {"iso", "color"});
    if (!s.contains("iso")) fail("surface.iso", "a value (missing)");
    r.iso = float(numberAt(s["iso"], "surface.iso", -1e30, 1e30));
    if (s.contains("color")) {
      const json& c = s["color"];
      if (!c.is_array() || c.size() != 4) fail("surface.color", "[r, g, b, a]");
      for (int k = 0; k < 4; ++k) r.surfaceColor[k] = float(numberAt(c[size_t(k)], "surface.color[" + std::to_string(k) + "]", 0, 1));
    }
  }
  if (j.contains("cut") && !j["cut"].is_null()) {
    const json& c = objectAt(j["cut"], "cut");
    onlyFields(c, "cut", {"point", "normal"});
    if (!c.contains("point") || !c.contains("normal")) fail("cut", "point and normal");
    r.cut = CutPlane{vec3At(c["point"], "cut.point", -kMaxCoordinate, kMaxCoordinate), directionAt(c["normal"], "cut.normal")};
  }
  if (j.contains("voi") && !j["voi"].is_null()) {
    const json& v = objectAt(j["voi"], "voi");
    onlyFields(v, "voi", {"min", "max", "inside", "outside", "ramp"});
    if (!v.contains("min") || !v.contains("max")) fail("voi", "min and max corners");
    VolumeOfInterest voi;
    voi.lo = vec3At(v["min"], "voi.min", -kMaxCoordinate, kMaxCoordinate);
    voi.hi = vec3At(v["max"], "voi.max", -kMaxCoordinate, kMaxCoordinate);
    if (glm::any(glm::greaterThanEqual(voi.lo, voi.hi))) fail("voi.max", "each coordinate above voi.min's");
    if (v.contains("inside")) voi.inside = numberAt(v["inside"], "voi.inside", 0, 1);
    if (v.contains("outside")) voi.outside = numberAt(v["outside"], "voi.outside", 0, 1);
    if (v.contains("ramp")) voi.ramp = numberAt(v["ramp"], "voi.ramp", 0, 1000);
    r.voi = voi;
  }
  return r;
}

OpenRequest openAt(const json& j) {
  onlyFields(j, "", {"type", "path", "series"});
  OpenRequest r;
  if (!j.contains("path")) fail("path", "a value (missing)");
  r.path = stringAt(j["path"], "path", kMaxPathBytes);
  if (r.path.empty() || r.path.find('\0') != std::string::npos) fail("path", "a relative path in the data directory");
  if (j.contains("series")) r.series = stringAt(j["series"], "series", 128);
  return r;
}

}  // namespace

TransferFunction FrameRequest::transferFunction() const {
  std::vector<TransferFunction::Point> p = preset.empty() ? points : TransferFunction::preset(preset).points();
  for (TransferFunction::Point& q : p) q.alpha = std::min(1.0f, q.alpha * opacityScale);
  return TransferFunction(std::move(p), preset.empty() ? "tf.points" : preset);
}

Request parseRequest(const std::string& text) {
  if (text.size() > kMaxMessageBytes) throw ValueError("message: expected at most " + std::to_string(kMaxMessageBytes) + " bytes");
  json j;
  try {
    j = json::parse(text, [](int depth, json::parse_event_t, json&) {
      if (depth > kMaxDepth) throw ValueError("message: nested deeper than " + std::to_string(kMaxDepth) + " levels");
      return true;
    });
  } catch (const json::exception& e) {
    // The parser's own words say where (clipped: they quote the offending token).
    throw ValueError("message: not JSON (" + std::string(e.what()).substr(0, 160) + ")");
  }
  if (!j.is_object()) fail("message", "a JSON object");
  if (!j.contains("type") || !j["type"].is_string()) fail("type", "\"frame\" or \"open\"");
  const std::string type = j["type"].get<std::string>();
  if (type == "frame") return frameAt(j);
  if (type == "open") return openAt(j);
  fail("type", "\"frame\" or \"open\"");
}

std::string errorMessage(const std::string& message, std::optional<uint64_t> seq) {
  json j = {{"type", "error"}, {"message", message}};
  if (seq) j["seq"] = *seq;
  return j.dump(-1, ' ', false, json::error_handler_t::replace);
}

std::string frameMessage(const std::string& headerJson, const std::vector<uint8_t>& image) {
  std::string out(4, '\0');
  const uint32_t n = uint32_t(headerJson.size());
  for (int k = 0; k < 4; ++k) out[size_t(k)] = char((n >> (8 * k)) & 0xff);
  out += headerJson;
  out.append(reinterpret_cast<const char*>(image.data()), image.size());
  return out;
}

bool splitFrameMessage(const std::string& message, std::string* headerJson, std::string* image) {
  if (message.size() < 4) return false;
  uint32_t n = 0;
  for (int k = 0; k < 4; ++k) n |= uint32_t(uint8_t(message[size_t(k)])) << (8 * k);
  if (n > message.size() - 4) return false;
  *headerJson = message.substr(4, n);
  *image = message.substr(4 + n);
  return true;
}

}  // namespace hyb::viewer
