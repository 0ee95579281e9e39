#include "apps/viewer/viewer_protocol.h"

#include <nlohmann/json.hpp>

#include <cstring>

#include "volume/core/error.h"

namespace hyb::viewer {

namespace {

using nlohmann::json;

// Nesting deeper than any valid message is refused while parsing, before it is built.
constexpr int kMaxDepth = 6;

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

FrameRequest frameAt(const json& j) {
  FrameRequest r;
  if (!j.contains("seq") || !j["seq"].is_number_unsigned()) fail("seq", "a whole number ≥ 0");
  r.seq = j["seq"].get<uint64_t>();
  if (j.contains("scene")) r.scene = stringAt(j["scene"], "scene", kMaxPathBytes + 256);
  if (j.contains("interacting")) r.interacting = boolAt(j["interacting"], "interacting");
  applyJson(&r.settings, j, kViewer, {"type", "seq", "scene", "interacting"}, "message ");
  for (const char* required : {"eye", "center", "up", "size"})
    if (!frameField(required)->text(r.settings)) fail(required, "a value (missing)");
  if (r.settings.preset.empty() == r.settings.tfPoints.empty()) fail("preset", "either preset or tf_points");
  const glm::ivec2 size = r.size();
  if (glm::any(glm::lessThan(size, glm::ivec2(kMinImageEdge))) || glm::any(glm::greaterThan(size, glm::ivec2(kMaxImageEdge))))
    fail("size", "[width, height], each in [" + std::to_string(kMinImageEdge) + ", " + std::to_string(kMaxImageEdge) + "]");
  if (const std::string e = r.settings.validate(); !e.empty()) throw ValueError("message: " + e);
  return r;
}

OpenRequest openAt(const json& j) {
  onlyFields(j, "", {"type", "path", "series", "url"});
  OpenRequest r;
  if (j.contains("url")) {
    if (j.contains("path") || j.contains("series")) fail("url", "no path or series beside it");
    r.url = stringAt(j["url"], "url", kMaxPathBytes);
    if (r.url.rfind("http://", 0) != 0 && r.url.rfind("https://", 0) != 0) fail("url", "a DICOMweb series address, http(s)://HOST:PORT/ROOT/studies/UID/series/UID");
    return r;
  }
  if (!j.contains("path")) fail("path", "a value (missing)");
  r.path = stringAt(j["path"], "path", kMaxPathBytes);
  if (r.path.empty() || r.path.find('\0') != std::string::npos) fail("path", "a relative path in the data directory");
  if (j.contains("series")) r.series = stringAt(j["series"], "series", 128);
  return r;
}

PacsSearchRequest pacsSearchAt(const json& j) {
  onlyFields(j, "", {"type", "patient", "study_date", "modality"});
  PacsSearchRequest r;
  if (j.contains("patient")) r.patient = stringAt(j["patient"], "patient", 64);
  if (j.contains("study_date")) r.studyDate = stringAt(j["study_date"], "study_date", 17);
  if (j.contains("modality")) r.modality = stringAt(j["modality"], "modality", 16);
  return r;
}

}  // namespace

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
  constexpr const char* kTypes = "\"frame\", \"open\" or \"pacs-search\"";
  if (!j.contains("type") || !j["type"].is_string()) fail("type", kTypes);
  const std::string type = j["type"].get<std::string>();
  if (type == "frame") return frameAt(j);
  if (type == "open") return openAt(j);
  if (type == "pacs-search") return pacsSearchAt(j);
  fail("type", kTypes);
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
