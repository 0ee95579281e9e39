// Images: linear float RGBA while compositing, 8-bit RGBA PNG on disk, and error metrics.
#pragma once

#include <glm/glm.hpp>

#include <string>
#include <vector>

namespace hyb {

/// A width × height image of premultiplied RGBA floats, row 0 at the top.
struct Image {
  int width = 0, height = 0;
  std::vector<glm::vec4> pixels;

  Image() = default;
  Image(int w, int h) : width(w), height(h), pixels(size_t(w) * size_t(h), glm::vec4(0.0f)) {}
  glm::vec4& at(int x, int y) { return pixels[size_t(y) * size_t(width) + size_t(x)]; }
  const glm::vec4& at(int x, int y) const { return pixels[size_t(y) * size_t(width) + size_t(x)]; }
};

/// @p image resampled to @p width × @p height by bilinear interpolation of its premultiplied
/// pixels, pixel centres aligned (a source pixel's centre at (x + ½)·w/W − ½ of the result's): a
/// frame rendered at a fraction of its size, magnified (Quality::imageScale).
Image resampled(const Image& image, int width, int height);

/// Composites @p image over an opaque @p background and rounds to 8 bits: what the PNG holds.
std::vector<uint8_t> toRgba8(const Image& image, const glm::vec3& background);

/// Writes the composited image as an 8-bit RGBA PNG (alpha 255) atomically.
/// @throw IoError naming @p path when it cannot be written.
void writePng(const std::string& path, const Image& image, const glm::vec3& background);

/// The PNG bytes of 8-bit RGBA pixels @p rgba (width × height), written in memory.
/// @throw RuntimeError when libpng fails.
std::vector<uint8_t> encodePng(const std::vector<uint8_t>& rgba, int width, int height);

/// Reads an 8-bit PNG (RGB or RGBA) into RGBA bytes. For tests and comparisons.
/// @throw IoError naming @p path when it cannot be read.
std::vector<uint8_t> readPng(const std::string& path, int* width, int* height);

/// PSNR in dB over RGB of two equal-size RGBA8 images (infinity when identical).
double psnr(const std::vector<uint8_t>& a, const std::vector<uint8_t>& b);

/// Mean structural similarity (Wang et al. 2004) over RGB of two equal-size RGBA8 images: 8x8
/// windows every 4 pixels (one window over the whole image when smaller), C1 = (0.01·255)²,
/// C2 = (0.03·255)², averaged over windows and channels. 1 when identical.
double ssim(const std::vector<uint8_t>& a, const std::vector<uint8_t>& b, int width, int height);

}  // namespace hyb
