// The trade between the two methods of drawing user geometry (docs/user-geometry.md): a geodesic
// sphere mesh (R = 20 mm), a screw (a mesh, its shaft 2 mm across) and a plate (a large polygon
// primitive) inside a soft ball of data, on grids of N³ voxels over the same 64 mm box. Against
// the exact image (the reference ray tracer crossing the polygons): the PSNR (the whole image's,
// the screw's and the plate's pixels') and warm frame time of `polygons` and of `scan-convert`
// (each filter --mesh-filter names: boxes of 1, 1.5 and 2 cells and point sampling) in the slice
// renderer, and the scan-conversion's time and bytes; with --images, each frame as a PNG.
//
//   hyb_geometry_trade_bench [--size 256] [--runs 3] [--grids 32,64,128] [--images DIR]
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <charconv>
#include <filesystem>
#include <string>
#include <vector>

#include "render/frame_settings.h"
#include "render/geometry_channel.h"
#include "render/image.h"
#include "render/scene_renderer.h"
#include "volume/core/error.h"

namespace {

using Clock = std::chrono::steady_clock;

// Over the pixels @p mask holds (all when it is empty), the RGB channels composited over black.
double psnr(const hyb::Image& a, const hyb::Image& b, const std::vector<bool>& mask = {}) {
  const std::vector<uint8_t> x = hyb::toRgba8(a, glm::vec3(0)), y = hyb::toRgba8(b, glm::vec3(0));
  double se = 0.0;
  size_t n = 0;
  for (size_t p = 0; p < x.size(); p += 4)
    if (mask.empty() || mask[p / 4])
      for (size_t c = 0; c < 3; ++c, ++n) se += std::pow(double(x[p + c]) - double(y[p + c]), 2);
  return 10.0 * std::log10(255.0 * 255.0 / std::max(se / double(std::max<size_t>(n, 1)), 1e-12));
}

// The pixels where @p with and @p without differ: a part's footprint in the exact image.
std::vector<bool> footprint(const hyb::Image& with, const hyb::Image& without) {
  const std::vector<uint8_t> x = hyb::toRgba8(with, glm::vec3(0)), y = hyb::toRgba8(without, glm::vec3(0));
  std::vector<bool> mask(x.size() / 4);
  for (size_t p = 0; p < x.size(); p += 4) mask[p / 4] = x[p] != y[p] || x[p + 1] != y[p + 1] || x[p + 2] != y[p + 2];
  return mask;
}

// A screw along +z from its tip at @p tip: a cone of 1.5 mm, a shaft of radius 1 mm to @p length mm,
// a head of radius 2 mm and 1.5 mm; a surface of revolution wound outward.
hyb::TriangleMesh screw(const glm::vec3& tip, float length) {
  const glm::vec2 profile[] = {{0.0f, 0.0f}, {1.0f, 1.5f}, {1.0f, length}, {2.0f, length}, {2.0f, length + 1.5f}, {0.0f, length + 1.5f}};
  constexpr int kSides = 24;
  hyb::TriangleMesh m;
  std::vector<uint32_t> first;  // each profile point's first vertex (one vertex where r = 0)
  for (const glm::vec2& p : profile) {
    first.push_back(uint32_t(m.vertices.size()));
    for (int j = 0; j < (p.x > 0.0f ? kSides : 1); ++j) {
      const float a = 2.0f * float(M_PI) * float(j) / kSides;
      m.vertices.push_back(tip + glm::vec3(p.x * std::cos(a), p.x * std::sin(a), p.y));
    }
  }
  for (size_t i = 0; i + 1 < std::size(profile); ++i)
    for (uint32_t j = 0; j < kSides; ++j) {
      const uint32_t k = (j + 1) % kSides;
      const bool ring0 = profile[i].x > 0.0f, ring1 = profile[i + 1].x > 0.0f;
      const uint32_t a = first[i] + (ring0 ? j : 0), b = first[i] + (ring0 ? k : 0);
      const uint32_t c = first[i + 1] + (ring1 ? k : 0), d = first[i + 1] + (ring1 ? j : 0);
      if (ring0) m.triangles.push_back({a, b, c});
      if (ring1) m.triangles.push_back({a, c, d});
    }
  return m;
}

constexpr const char* kUsage =
    "usage: hyb_geometry_trade_bench [--size N] [--runs N] [--grids N,N,...] [--images DIR]\n"
    "  --size N      the image's width and height in pixels, 16 to 4096 (256)\n"
    "  --runs N      warm frames timed per method, the best kept, 1 to 100 (3)\n"
    "  --grids LIST  the grids' N (N^3 voxels over the 64 mm box), each 8 to 256 (32,64,128)\n"
    "  --images DIR  writes each frame as DIR/trade-N-METHOD.png (METHOD: reference, polygons, box, box1.5, box2, none)\n"
    "  -h, --help    this text\n";

struct Options {
  int size = 256;
  int runs = 3;
  std::vector<int> grids = {32, 64, 128};
  std::string images;  // a directory, or empty: no images
  bool help = false;
};

// A whole decimal integer in [lo, hi], else a ValueError naming the flag.
int intIn(const std::string& flag, const std::string& text, int lo, int hi) {
  int v = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
  if (ec != std::errc() || end != text.data() + text.size() || v < lo || v > hi)
    HYB_THROW(hyb::ValueError, flag, " '", text, "' invalid (expected an integer from ", lo, " to ", hi, ")");
  return v;
}

// @throw ValueError naming the flag or argument that is not understood.
Options parseOptions(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto value = [&] {
      if (i + 1 >= argc) HYB_THROW(hyb::ValueError, a, " needs a value");
      return std::string(argv[++i]);
    };
    if (a == "-h" || a == "--help") {
      o.help = true;
    } else if (a == "--size") {
      o.size = intIn(a, value(), 16, 4096);
    } else if (a == "--runs") {
      o.runs = intIn(a, value(), 1, 100);
    } else if (a == "--grids") {
      const std::string list = value();
      o.grids.clear();
      for (size_t start = 0;;) {
        const size_t comma = list.find(',', start);
        o.grids.push_back(intIn(a, list.substr(start, comma - start), 8, 256));
        if (comma == std::string::npos) break;
        start = comma + 1;
      }
    } else if (a == "--images") {
      o.images = value();
      if (o.images.empty()) HYB_THROW(hyb::ValueError, "--images needs a directory");
    } else {
      HYB_THROW(hyb::ValueError, "unknown argument '", a, "' (expected --size, --runs, --grids, --images or --help)");
    }
  }
  return o;
}

void run(const Options& o) {
  using namespace hyb;
  const int size = o.size, runs = o.runs;
  std::error_code error;
  if (!o.images.empty() && (std::filesystem::create_directories(o.images, error), error))
    HYB_THROW(IoError, "--images ", o.images, ": cannot create the directory (", error.message(), ")");
  auto image = [&](int n, const std::string& method, const Image& frame) {
    if (!o.images.empty()) writePng(o.images + "/trade-" + std::to_string(n) + "-" + method + ".png", frame, glm::vec3(0));
  };
  std::printf("| grid | method | frame ms (slices) | PSNR dB | screw's pixels dB | plate's pixels dB | scan-conversion ms | channel bytes |\n"
              "|---|---|---|---|---|---|---|---|\n");
  for (const int n : o.grids) {
    const double s = 64.0 / n;
    std::vector<float> values(size_t(n) * size_t(n) * size_t(n));
    for (int k = 0; k < n; ++k)
      for (int j = 0; j < n; ++j)
        for (int i = 0; i < n; ++i)
          values[size_t(i) + size_t(n) * (size_t(j) + size_t(n) * size_t(k))] = float(26.0 - glm::length(glm::dvec3(i, j, k) * s - 32.0)) * 0.5f;
    Scene scene;
    scene.volume = Volume({n, n, n}, glm::dvec3(s), ScalarType::Float32, std::move(values), "soft ball");
    scene.octree = VolumeOctree::build(scene.volume);
    SceneRenderer r(std::move(scene));
    const Volume& v = r.volume();
    View view;
    view.camera.eye = {-40.0, -70.0, 90.0};
    view.camera.center = {32.0, 32.0, 32.0};
    view.camera.up = {0, 0, 1};
    view.camera.fovDeg = 40.0;
    view.camera.width = view.camera.height = size;
    Look look;
    look.tf = TransferFunction({{0.0f, {1, 1, 1}, 0.0f}, {2.0f, {1.0f, 0.6f, 0.3f}, 0.05f}, {13.0f, {0.3f, 0.6f, 1.0f}, 0.02f}}, "soft");
    look.meshes.push_back(UserMesh{"sphere", std::make_shared<const TriangleMesh>(geodesicSphere({36.0, 30.0, 34.0}, 20.0, 32)),
                                   glm::vec4(1.0f, 0.25f, 0.2f, 0.4f), nullptr});
    look.meshes.push_back(UserMesh{"screw", std::make_shared<const TriangleMesh>(screw({14.0f, 14.0f, 6.0f}, 36.0f)),
                                   glm::vec4(1.0f, 0.8f, 0.2f, 0.8f), nullptr});
    auto plate = std::make_shared<UserPrimitive>();
    glm::vec4 color;
    primitiveIn("polygon:6,6,20,58,6,30,58,58,40,6,58,30:0.2,0.9,0.3,0.5", plate.get(), &color);
    look.meshes.push_back(UserMesh{"plate", std::make_shared<const TriangleMesh>(tessellatePrimitive(*plate, v)), color, plate});
    Quality reference;
    reference.renderer = Renderer::Raycast;
    const Image exact = r.render(view, look, reference).image;
    image(n, "reference", exact);
    // Each thin part's footprint: where the exact image changes without it.
    auto without = [&](size_t part) {
      Look l = look;
      l.meshes.erase(l.meshes.begin() + std::ptrdiff_t(part));
      return footprint(exact, r.render(view, l, reference).image);
    };
    const std::vector<bool> screwPixels = without(1), platePixels = without(2);  // look.meshes' order
    // polygons, then scan-convert with each filter of --mesh-filter (box, box1.5, box2, none).
    const FrameField& filters = *frameField("mesh_filter");
    std::vector<std::string> methods = {"polygons"};
    methods.insert(methods.end(), filters.choices.begin(), filters.choices.end());
    for (const std::string& method : methods) {
      Look l = look;
      l.meshMethod = method == "polygons" ? MeshMethod::Polygons : MeshMethod::ScanConvert;
      if (l.meshMethod == MeshMethod::ScanConvert) {
        FrameSettings settings;
        filters.parse(settings, method, filters.flag());
        l.meshFilter = settings.meshFilter;
      }
      double best = 1e300;
      RenderedFrame f;
      for (int k = 0; k <= runs; ++k) {  // the first frame makes the channel and the textures
        const auto t0 = Clock::now();
        f = r.render(view, l, Quality{});
        if (k > 0) best = std::min(best, std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
      }
      const RenderedFrame first = r.render(view, Look(l), Quality{});  // kept: geometryBytes
      const std::string name = l.meshMethod == MeshMethod::Polygons ? method : "scan-convert, " + method;
      double convertMs = 0.0;
      if (l.meshMethod == MeshMethod::ScanConvert) {
        const auto t0 = Clock::now();
        const GeometryChannel g = scanConvertGeometry(l.meshes, v, r.scene().octree, l.meshFilter);
        convertMs = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
      }
      image(n, method, f.image);
      std::printf("| %d³ (%.2f mm) | %s | %.1f | %.2f | %.2f | %.2f | %.1f | %llu |\n", n, s, name.c_str(), best, psnr(f.image, exact),
                  psnr(f.image, exact, screwPixels), psnr(f.image, exact, platePixels), convertMs,
                  (unsigned long long)first.stats.geometryBytes);
    }
  }
}

}  // namespace

int main(int argc, char** argv) {
  Options options;
  try {
    options = parseOptions(argc, argv);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "hyb_geometry_trade_bench: %s\n", e.what());
    return 2;
  }
  if (options.help) {
    std::fputs(kUsage, stdout);
    return 0;
  }
  try {
    run(options);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "hyb_geometry_trade_bench: %s\n", e.what());
    return 1;
  }
  return 0;
}
