#include "render/orientation_marker.h"

#include <algorithm>
#include <cmath>

namespace hyb {

namespace {

// 5x7 glyphs, one row a byte (bit 4 the leftmost column).
struct Glyph {
  char letter;
  uint8_t rows[7];
};
constexpr Glyph kGlyphs[] = {
    {'L', {0x10, 0x10, 0x10, 0x10, 0x10, 0x10, 0x1f}}, {'R', {0x1e, 0x11, 0x11, 0x1e, 0x14, 0x12, 0x11}},
    {'A', {0x0e, 0x11, 0x11, 0x1f, 0x11, 0x11, 0x11}}, {'P', {0x1e, 0x11, 0x11, 0x1e, 0x10, 0x10, 0x10}},
    {'S', {0x0f, 0x10, 0x10, 0x0e, 0x01, 0x01, 0x1e}}, {'I', {0x0e, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0e}}};

// The marker's scale: pixels of one glyph cell, and the axis length, for an image of this size.
int cellPixels(const Image& image) { return std::max(1, std::min(image.width, image.height) / 256); }
double axisPixels(int width, int height) { return 0.07 * std::min(width, height) + 6.0; }

glm::dvec2 markerCentre(int width, int height) {
  const double reach = axisPixels(width, height) + 10.0 * std::max(1, std::min(width, height) / 256);
  return {reach + 2.0, double(height) - reach - 2.0};
}

// Paints an opaque colour over pixel (x, y) with coverage @p c.
void blend(Image* image, int x, int y, const glm::vec3& colour, float c) {
  if (x < 0 || y < 0 || x >= image->width || y >= image->height || c <= 0.0f) return;
  glm::vec4& p = image->at(x, y);
  p = glm::mix(p, glm::vec4(colour, 1.0f), std::min(c, 1.0f));
}

// An anti-aliased line @p width pixels wide.
void line(Image* image, glm::dvec2 a, glm::dvec2 b, double width, const glm::vec3& colour) {
  const glm::dvec2 lo = glm::floor(glm::min(a, b) - width), hi = glm::ceil(glm::max(a, b) + width);
  const glm::dvec2 ab = b - a;
  const double len2 = std::max(glm::dot(ab, ab), 1e-12);
  for (int y = int(lo.y); y <= int(hi.y); ++y)
    for (int x = int(lo.x); x <= int(hi.x); ++x) {
      const glm::dvec2 p(x + 0.5, y + 0.5);
      const double t = std::clamp(glm::dot(p - a, ab) / len2, 0.0, 1.0);
      const double d = glm::length(p - (a + t * ab));
      blend(image, x, y, colour, float(std::clamp(0.5 * width + 0.5 - d, 0.0, 1.0)));
    }
}

void letter(Image* image, char c, glm::dvec2 centre, int cell, const glm::vec3& colour) {
  for (const Glyph& g : kGlyphs) {
    if (g.letter != c) continue;
    const int x0 = int(std::lround(centre.x - 2.5 * cell)), y0 = int(std::lround(centre.y - 3.5 * cell));
    for (int row = 0; row < 7; ++row)
      for (int col = 0; col < 5; ++col)
        if (g.rows[row] & (0x10 >> col))
          for (int dy = 0; dy < cell; ++dy)
            for (int dx = 0; dx < cell; ++dx) blend(image, x0 + col * cell + dx, y0 + row * cell + dy, colour, 1.0f);
  }
}

}  // namespace

std::array<MarkerLabel, 6> markerLabels(const Camera& patientCamera) {
  const glm::dvec3 f = patientCamera.forward(), r = patientCamera.right(), u = patientCamera.trueUp();
  const glm::dvec2 centre = markerCentre(patientCamera.width, patientCamera.height);
  const double length = axisPixels(patientCamera.width, patientCamera.height);
  static constexpr char kLetters[6] = {'L', 'R', 'P', 'A', 'S', 'I'};
  std::array<MarkerLabel, 6> out{};
  for (int k = 0; k < 6; ++k) {
    glm::dvec3 axis(0.0);
    axis[k / 2] = k % 2 ? -1.0 : 1.0;  // LPS: +x left, +y posterior, +z superior
    const glm::dvec2 onScreen(glm::dot(axis, r), -glm::dot(axis, u));
    out[size_t(k)] = {kLetters[k], centre + onScreen * (length + 7.0), glm::dot(axis, f)};
  }
  return out;
}

void drawOrientationMarker(const Camera& patientCamera, Image* image) {
  const std::array<MarkerLabel, 6> labels = markerLabels(patientCamera);
  const glm::dvec2 centre = markerCentre(image->width, image->height);
  const int cell = cellPixels(*image);
  const double length = axisPixels(image->width, image->height);
  // Slicer's colours: left-right red, posterior-anterior green, superior-inferior blue.
  const glm::vec3 colours[3] = {{0.95f, 0.3f, 0.25f}, {0.35f, 0.85f, 0.35f}, {0.35f, 0.55f, 1.0f}};
  std::array<int, 6> order = {0, 1, 2, 3, 4, 5};
  std::sort(order.begin(), order.end(), [&](int a, int b) { return labels[size_t(a)].depth > labels[size_t(b)].depth; });
  for (int k : order) {
    const MarkerLabel& l = labels[size_t(k)];
    // Ends pointing away from the viewer are dimmer.
    const glm::vec3 c = colours[k / 2] * float(l.depth > 0.0 ? 0.55 : 1.0);
    const glm::dvec2 tip = centre + (l.pixel - centre) * (length / (length + 7.0));
    line(image, centre, tip, 1.5 * cell, c);
    letter(image, l.letter, l.pixel, cell, c);
  }
}

}  // namespace hyb
