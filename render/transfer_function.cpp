#include "render/transfer_function.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "volume/core/error.h"
#include "volume/core/file_util.h"

namespace hyb {

TransferFunction::TransferFunction(std::vector<Point> points, const std::string& source) : mPoints(std::move(points)) {
  if (mPoints.empty()) HYB_THROW(ValueError, source, ": no control points (expected lines 'value r g b a')");
  for (size_t i = 0; i < mPoints.size(); ++i) {
    const Point& p = mPoints[i];
    if (!std::isfinite(p.value) || (i > 0 && p.value < mPoints[i - 1].value))
      HYB_THROW(ValueError, source, ": control point ", i + 1, " value ", p.value, " must be finite and not below the previous one");
    for (float c : {p.color.r, p.color.g, p.color.b, p.alpha})
      if (!(c >= 0.0f && c <= 1.0f)) HYB_THROW(ValueError, source, ": control point ", i + 1, " has a component outside [0, 1]");
  }
}

TransferFunction TransferFunction::fromFile(const std::string& path) {
  // A regular file of bounded size and lines: a FIFO would block, a huge file be read whole.
  std::istringstream in(readTextFile(path, kMaxFileBytes, kMaxLineBytes, "transfer function"));
  std::vector<Point> pts;
  std::string line;
  for (int n = 1; std::getline(in, line); ++n) {
    const size_t hash = line.find('#');
    if (hash != std::string::npos) line.resize(hash);
    std::istringstream s(line);
    Point p;
    if (!(s >> p.value)) continue;  // blank
    std::string rest;
    if (!(s >> p.color.r >> p.color.g >> p.color.b >> p.alpha) || (s >> rest))
      HYB_THROW(IoError, path, ": line ", n, " malformed (expected 'value r g b a')");
    pts.push_back(p);
  }
  return TransferFunction(std::move(pts), path);
}

const std::vector<TransferFunction::Preset>& TransferFunction::presets() {
  static const glm::vec3 skin(0.93f, 0.72f, 0.60f), bone(1.0f, 0.96f, 0.86f), soft(0.85f, 0.45f, 0.40f), vessel(0.85f, 0.15f, 0.12f);
  static const std::vector<Preset> kPresets = {
      {"ct-skin-bone", "skin translucent over bone",
       {{-700, skin, 0.0f}, {-500, skin, 0.08f}, {-300, skin, 0.12f}, {-100, skin, 0.0f}, {150, bone, 0.0f}, {400, bone, 0.2f}, {3000, bone, 0.6f}}},
      {"ct-bone", "bone", {{150, bone, 0.0f}, {300, bone, 0.08f}, {700, bone, 0.35f}, {3000, bone, 0.6f}}},
      {"ct-skin", "skin", {{-700, skin, 0.0f}, {-500, skin, 0.2f}, {-300, skin, 0.35f}, {-100, skin, 0.05f}, {0, skin, 0.0f}}},
      {"ct-soft-tissue", "soft tissue", {{-150, soft, 0.0f}, {0, soft, 0.03f}, {80, soft, 0.06f}, {200, soft, 0.0f}}},
      {"ct-vessels", "contrast-filled vessels, bone faint",
       {{100, vessel, 0.0f}, {200, vessel, 0.25f}, {350, vessel, 0.3f}, {450, bone, 0.05f}, {3000, bone, 0.05f}}}};
  return kPresets;
}

std::vector<std::string> TransferFunction::presetNames() {
  std::vector<std::string> names;
  for (const Preset& p : presets()) names.push_back(p.name);
  return names;
}

TransferFunction TransferFunction::preset(const std::string& name) {
  for (const Preset& p : presets())
    if (name == p.name) return TransferFunction(p.points, name);
  std::string list;
  for (const auto& n : presetNames()) list += (list.empty() ? "" : ", ") + n;
  HYB_THROW(ValueError, "--preset '", name, "' unknown (expected one of ", list, ")");
}

std::string TransferFunction::defaultPresetFor(float minValue, float maxValue) {
  return minValue <= -900.0f && maxValue >= 200.0f ? "ct-skin-bone" : "";
}

float TransferFunction::defaultIsoFor(float minValue, float maxValue) {
  return defaultPresetFor(minValue, maxValue).empty() ? 0.5f * (minValue + maxValue) : 400.0f;
}

TransferFunction TransferFunction::defaultFor(float minValue, float maxValue) {
  if (const std::string name = defaultPresetFor(minValue, maxValue); !name.empty()) return preset(name);
  const float lo = minValue + 0.4f * (maxValue - minValue), hi = std::max(maxValue, lo + 1e-3f);
  return TransferFunction({{lo, {0.9f, 0.6f, 0.3f}, 0.0f}, {hi, {1.0f, 0.95f, 0.85f}, 0.1f}}, "default ramp");
}

glm::vec4 TransferFunction::lookup(float v) const {
  if (v <= mPoints.front().value) return glm::vec4(mPoints.front().color, mPoints.front().alpha);
  if (v >= mPoints.back().value) return glm::vec4(mPoints.back().color, mPoints.back().alpha);
  const auto it = std::upper_bound(mPoints.begin(), mPoints.end(), v, [](float x, const Point& p) { return x < p.value; });
  const Point& b = *it;
  const Point& a = *(it - 1);
  const float t = b.value > a.value ? (v - a.value) / (b.value - a.value) : 1.0f;
  return glm::mix(glm::vec4(a.color, a.alpha), glm::vec4(b.color, b.alpha), t);
}

float TransferFunction::maxAlpha(float lo, float hi) const {
  float m = std::max(lookup(lo).a, lookup(hi).a);
  for (const Point& p : mPoints)
    if (p.value > lo && p.value < hi) m = std::max(m, p.alpha);
  return m;
}

float TransferFunction::maxSlope(float lo, float hi) const {
  float m = 0.0f;
  for (size_t i = 1; i < mPoints.size(); ++i) {
    const Point &a = mPoints[i - 1], &b = mPoints[i];
    if (b.value <= lo || a.value >= hi || b.value <= a.value) continue;
    const glm::vec3 dc = glm::abs(b.color * b.alpha - a.color * a.alpha);
    const float change = std::abs(b.alpha - a.alpha) + std::max({dc.r, dc.g, dc.b});
    m = std::max(m, change / (b.value - a.value));
  }
  return m;
}

double TransferFunction::distortion(float lo, float hi, float error) const {
  return std::min(double(error) * double(maxSlope(lo, hi)), double(maxAlpha(lo, hi)));
}

float TransferFunction::segmentAlpha(float alphaPerMm, float mm) {
  if (alphaPerMm <= 0.0f || mm <= 0.0f) return 0.0f;
  if (alphaPerMm >= 1.0f) return 1.0f;
  return 1.0f - std::pow(1.0f - alphaPerMm, mm);
}

}  // namespace hyb
