#include "render/image.h"

#include <png.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <cmath>
#include <cstdio>
#include <limits>
#include <memory>

#include "volume/core/error.h"
#include "volume/core/file_util.h"

namespace hyb {

Image resampled(const Image& image, int width, int height) {
  Image out(width, height);
  if (image.width <= 0 || image.height <= 0) return out;
  const double sx = double(image.width) / width, sy = double(image.height) / height;
  for (int y = 0; y < height; ++y) {
    const double fy = std::clamp((y + 0.5) * sy - 0.5, 0.0, double(image.height - 1));
    const int y0 = int(fy), y1 = std::min(y0 + 1, image.height - 1);
    const float ty = float(fy - y0);
    for (int x = 0; x < width; ++x) {
      const double fx = std::clamp((x + 0.5) * sx - 0.5, 0.0, double(image.width - 1));
      const int x0 = int(fx), x1 = std::min(x0 + 1, image.width - 1);
      const float tx = float(fx - x0);
      const glm::vec4 top = glm::mix(image.at(x0, y0), image.at(x1, y0), tx), bottom = glm::mix(image.at(x0, y1), image.at(x1, y1), tx);
      out.at(x, y) = glm::mix(top, bottom, ty);
    }
  }
  return out;
}

std::vector<uint8_t> toRgba8(const Image& image, const glm::vec3& background) {
  std::vector<uint8_t> out(image.pixels.size() * 4);
  for (size_t i = 0; i < image.pixels.size(); ++i) {
    const glm::vec4 p = image.pixels[i];
    const glm::vec3 c = glm::vec3(p) + (1.0f - p.a) * background;  // premultiplied "over"
    for (int k = 0; k < 3; ++k) out[4 * i + size_t(k)] = uint8_t(std::lround(std::clamp(c[k], 0.0f, 1.0f) * 255.0f));
    out[4 * i + 3] = 255;
  }
  return out;
}

void writePng(const std::string& path, const Image& image, const glm::vec3& background) {
  const std::vector<uint8_t> rgba = toRgba8(image, background);
  writeFileAtomicallyByName(path, [&](const std::string& tmp) {
    errno = 0;
    FILE* f = std::fopen(tmp.c_str(), "wb");
    if (!f) HYB_THROW(IoError, path, ": cannot create file (", std::strerror(errno), ")");
    png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, nullptr, nullptr, nullptr);
    png_infop info = png ? png_create_info_struct(png) : nullptr;
    if (!png || !info || setjmp(png_jmpbuf(png))) {
      png_destroy_write_struct(&png, &info);
      const int err = errno;  // libpng stops here on a short write too (a full disk)
      std::fclose(f);
      HYB_THROW(IoError, path, ": PNG encoding or writing failed (", err ? std::strerror(err) : "libpng error", ")");
    }
    png_init_io(png, f);
    png_set_IHDR(png, info, png_uint_32(image.width), png_uint_32(image.height), 8, PNG_COLOR_TYPE_RGBA, PNG_INTERLACE_NONE,
                 PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
    png_write_info(png, info);
    for (int y = 0; y < image.height; ++y) png_write_row(png, &rgba[size_t(y) * size_t(image.width) * 4]);
    png_write_end(png, nullptr);
    png_destroy_write_struct(&png, &info);
    if (std::fclose(f) != 0) HYB_THROW(IoError, path, ": write failed (", std::strerror(errno), ")");
  });
}

std::vector<uint8_t> encodePng(const std::vector<uint8_t>& rgba, int width, int height) {
  std::vector<uint8_t> out;
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, nullptr, nullptr, nullptr);
  png_infop info = png ? png_create_info_struct(png) : nullptr;
  if (!png || !info || setjmp(png_jmpbuf(png))) {
    png_destroy_write_struct(&png, &info);
    HYB_THROW(RuntimeError, "PNG encoding failed");
  }
  png_set_write_fn(
      png, &out,
      [](png_structp p, png_bytep data, png_size_t n) {
        auto* o = static_cast<std::vector<uint8_t>*>(png_get_io_ptr(p));
        o->insert(o->end(), data, data + n);
      },
      nullptr);
  // Fast compression: a viewer sends this while the user waits (a file written once takes the default).
  png_set_compression_level(png, 2);
  png_set_IHDR(png, info, png_uint_32(width), png_uint_32(height), 8, PNG_COLOR_TYPE_RGBA, PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT,
               PNG_FILTER_TYPE_DEFAULT);
  png_write_info(png, info);
  for (int y = 0; y < height; ++y) png_write_row(png, &rgba[size_t(y) * size_t(width) * 4]);
  png_write_end(png, nullptr);
  png_destroy_write_struct(&png, &info);
  return out;
}

std::vector<uint8_t> readPng(const std::string& path, int* width, int* height) {
  png_image img{};
  img.version = PNG_IMAGE_VERSION;
  errno = 0;  // libpng says only that it failed: a file that cannot be opened is named as such
  if (FILE* f = std::fopen(path.c_str(), "rb"))
    std::fclose(f);
  else
    HYB_THROW(IoError, path, ": cannot open (", std::strerror(errno), "; expected a PNG image)");
  if (!png_image_begin_read_from_file(&img, path.c_str())) HYB_THROW(IoError, path, ": not a readable PNG");
  img.format = PNG_FORMAT_RGBA;
  std::vector<uint8_t> out(PNG_IMAGE_SIZE(img));
  if (!png_image_finish_read(&img, nullptr, out.data(), 0, nullptr)) HYB_THROW(IoError, path, ": PNG decoding failed");
  *width = int(img.width);
  *height = int(img.height);
  return out;
}

double psnr(const std::vector<uint8_t>& a, const std::vector<uint8_t>& b) {
  HYB_CHECK(a.size() == b.size() && a.size() % 4 == 0);
  double se = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    if (i % 4 == 3) continue;
    const double d = double(a[i]) - double(b[i]);
    se += d * d;
  }
  const double mse = se / double(a.size() / 4 * 3);
  return mse == 0 ? std::numeric_limits<double>::infinity() : 10.0 * std::log10(255.0 * 255.0 / mse);
}

double ssim(const std::vector<uint8_t>& a, const std::vector<uint8_t>& b, int width, int height) {
  HYB_CHECK(a.size() == b.size() && a.size() == size_t(width) * size_t(height) * 4);
  constexpr double kC1 = (0.01 * 255) * (0.01 * 255), kC2 = (0.03 * 255) * (0.03 * 255);
  const int wx = std::min(8, width), wy = std::min(8, height);
  double sum = 0;
  long count = 0;
  for (int y0 = 0; y0 + wy <= height; y0 += 4)
    for (int x0 = 0; x0 + wx <= width; x0 += 4)
      for (int c = 0; c < 3; ++c) {
        double sa = 0, sb = 0, saa = 0, sbb = 0, sab = 0;
        for (int y = y0; y < y0 + wy; ++y)
          for (int x = x0; x < x0 + wx; ++x) {
            const size_t i = (size_t(y) * size_t(width) + size_t(x)) * 4 + size_t(c);
            const double p = a[i], q = b[i];
            sa += p;
            sb += q;
            saa += p * p;
            sbb += q * q;
            sab += p * q;
          }
        const double n = double(wx * wy), ma = sa / n, mb = sb / n;
        const double va = saa / n - ma * ma, vb = sbb / n - mb * mb, cov = sab / n - ma * mb;
        sum += (2 * ma * mb + kC1) * (2 * cov + kC2) / ((ma * ma + mb * mb + kC1) * (va + vb + kC2));
        ++count;
      }
  return count ? sum / double(count) : 1.0;
}

}  // namespace hyb
