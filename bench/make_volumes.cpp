// Makes the benchmarks' large test volumes (never checked in), as NRRD with a detached raw file so
// that every reader can stream them, written slice by slice (memory stays a few slices whatever
// the size):
//   clinical OUT.nhdr  the cranium of invesalius-examples resampled to 512×512×432 int16 (a head or
//                      chest study's size, 216 MB) with Gaussian noise of 15 HU, in its patient frame
//   phantom OUT.nhdr [X,Y,Z]  a head-like int16 phantom, 2048×2048×1024 by default (8 GiB): air,
//                      skin and soft tissue, a skull shell, brain, a denser core, noise of 20 HU
//   tiled OUT.nhdr [NX,NY,NZ]  the cranium of invesalius-examples repeated NX×NY×NZ times, 4×4×5 by
//                      default (1024×1024×540 int16, 1.1 GB: 80 skulls, a surface-heavy study)
//
// usage: hyb_make_volumes clinical|phantom|tiled OUT.nhdr [X,Y,Z]
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "volume/core/error.h"
#include "volume/volume.h"
#include "volume/volume_io.h"

namespace {

using namespace hyb;

// Writes the header and streams the slices made by @p slice(k, out) into OUT.raw, both under
// temporary names renamed at the end.
template <class Slice>
void writeNrrd(const std::string& headerPath, glm::ivec3 dims, const glm::dvec3& spacing, const PatientFrame& frame, Slice slice) {
  const std::filesystem::path header(headerPath);
  const std::filesystem::path raw = std::filesystem::path(headerPath).replace_extension(".raw");
  const std::string tmpRaw = raw.string() + ".part", tmpHeader = header.string() + ".part";
  {
    std::ofstream out(tmpRaw, std::ios::binary);
    std::vector<int16_t> s(size_t(dims.x) * size_t(dims.y));
    for (int k = 0; k < dims.z; ++k) {
      slice(k, &s);
      out.write(reinterpret_cast<const char*>(s.data()), std::streamsize(s.size() * sizeof(int16_t)));
      if (!out) HYB_THROW(IoError, tmpRaw, ": write failed at slice ", k);
      if (k % 64 == 0) std::cerr << "slice " << k << " of " << dims.z << "\n";
    }
  }
  std::ostringstream h;
  h.precision(17);
  h << "NRRD0004\ntype: short\ndimension: 3\nspace: left-posterior-superior\nsizes: " << dims.x << " " << dims.y << " " << dims.z
    << "\nspace directions:";
  for (int a = 0; a < 3; ++a) {
    const glm::dvec3 d = frame.direction[a] * spacing[a];
    h << " (" << d.x << "," << d.y << "," << d.z << ")";
  }
  h << "\nspace origin: (" << frame.origin.x << "," << frame.origin.y << "," << frame.origin.z << ")\nendian: little\nencoding: raw\ndata file: "
    << raw.filename().string() << "\n";
  std::ofstream(tmpHeader) << h.str();
  std::filesystem::rename(tmpRaw, raw);
  std::filesystem::rename(tmpHeader, header);
}

void clinical(const std::string& out) {
  const Volume v = readVolume(kDefaultVolumePath);
  const glm::ivec3 dims(512, 512, 432);
  const glm::dvec3 spacing = v.extentMm() / glm::dvec3(dims - 1);
  std::mt19937 rng(2026);
  std::normal_distribution<float> noise(0.0f, 15.0f);
  writeNrrd(out, dims, spacing, v.frame(), [&](int k, std::vector<int16_t>* s) {
    for (int j = 0; j < dims.y; ++j)
      for (int i = 0; i < dims.x; ++i) {
        const glm::vec3 p = glm::vec3(glm::dvec3(i, j, k) * spacing / v.spacing());  // in the cranium's voxels
        const float value = std::round(v.sample(p) + noise(rng));
        (*s)[size_t(i) + size_t(dims.x) * size_t(j)] = int16_t(std::clamp(value, -32768.0f, 32767.0f));
      }
  });
}

// A head: ellipsoidal shells (radii as fractions of the volume's half extents), smooth over a voxel.
void phantom(const std::string& out, glm::ivec3 dims) {
  const glm::dvec3 spacing(0.25, 0.25, 0.25);
  const glm::dvec3 centre = 0.5 * glm::dvec3(dims - 1);
  writeNrrd(out, dims, spacing, PatientFrame{}, [&](int k, std::vector<int16_t>* s) {
#pragma omp parallel for schedule(static)
    for (int j = 0; j < dims.y; ++j) {
      std::mt19937 local(uint32_t(j) * 2654435761u ^ uint32_t(k) * 40503u);  // a row's noise, whichever thread makes it
      std::normal_distribution<float> noise(0.0f, 20.0f);
      for (int i = 0; i < dims.x; ++i) {
        const glm::dvec3 q = (glm::dvec3(i, j, k) - centre) / centre;  // [-1, 1] per axis
        const double r = glm::length(q / glm::dvec3(0.9, 0.95, 0.9)), voxel = 1.0 / centre.x;
        auto inside = [&](double radius) { return std::clamp((radius - r) / voxel + 0.5, 0.0, 1.0); };
        double value = -1000.0;
        value += 1040.0 * inside(1.0);          // skin and soft tissue: 40 HU
        value += 1160.0 * inside(0.93);         // skull: 1200 HU
        value -= 1170.0 * inside(0.86);         // brain: 30 HU
        value += 40.0 * inside(0.3);            // a denser core: 70 HU
        value += 400.0 * inside(0.08);          // and a calcification at its centre: 470 HU
        value += double(noise(local));
        (*s)[size_t(i) + size_t(dims.x) * size_t(j)] = int16_t(std::clamp(std::round(value), -32768.0, 32767.0));
      }
    }
  });
}

// The cranium's samples repeated tiles.x × tiles.y × tiles.z times, in its spacing and frame.
void tiled(const std::string& out, glm::ivec3 tiles) {
  const Volume v = readVolume(kDefaultVolumePath);
  const glm::ivec3 d = v.dims(), dims = d * tiles;
  validateDims(dims, "tiled dims");
  writeNrrd(out, dims, v.spacing(), v.frame(), [&](int k, std::vector<int16_t>* s) {
    for (int j = 0; j < dims.y; ++j)
      for (int i = 0; i < dims.x; ++i)
        (*s)[size_t(i) + size_t(dims.x) * size_t(j)] = int16_t(std::clamp(v.at(i % d.x, j % d.y, k % d.z), -32768.0f, 32767.0f));
  });
}

}  // namespace

int main(int argc, char** argv) {
  try {
    if (argc < 3) {
      std::cerr << "usage: hyb_make_volumes clinical|phantom|tiled OUT.nhdr [X,Y,Z]\n";
      return 2;
    }
    const std::string kind = argv[1], out = argv[2];
    if (kind == "clinical") {
      clinical(out);
    } else if (kind == "phantom") {
      glm::ivec3 dims(2048, 2048, 1024);
      if (argc > 3 && std::sscanf(argv[3], "%d,%d,%d", &dims.x, &dims.y, &dims.z) != 3) {
        std::cerr << "hyb_make_volumes: dims '" << argv[3] << "' invalid (expected X,Y,Z)\n";
        return 2;
      }
      validateDims(dims, "dims");
      phantom(out, dims);
    } else if (kind == "tiled") {
      glm::ivec3 tiles(4, 4, 5);
      if (argc > 3 && (std::sscanf(argv[3], "%d,%d,%d", &tiles.x, &tiles.y, &tiles.z) != 3 || glm::any(glm::lessThan(tiles, glm::ivec3(1))))) {
        std::cerr << "hyb_make_volumes: tiles '" << argv[3] << "' invalid (expected NX,NY,NZ, each at least 1)\n";
        return 2;
      }
      tiled(out, tiles);
    } else {
      std::cerr << "hyb_make_volumes: '" << kind << "' unknown (expected clinical, phantom or tiled)\n";
      return 2;
    }
    std::cerr << "wrote " << out << "\n";
    return 0;
  } catch (const std::exception& e) {
    std::cerr << "hyb_make_volumes: " << e.what() << "\n";
    return 1;
  }
}
