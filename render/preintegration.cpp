// Pre-integrated classification: K. Engel, M. Kraus, T. Ertl, "High-Quality Pre-Integrated Volume
// Rendering Using Hardware-Accelerated Pixel Shading", Graphics Hardware 2001; the exact O(n²)
// table of docs/renderer.md.
#include "render/preintegration.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>

#include "volume/core/error.h"

namespace hyb {

namespace {

// Optical depth per mm of an opacity @p a per mm.
double tauOf(double a) {
  if (a <= 0.0) return 0.0;
  if (a >= 1.0) return PreIntegrationTable::kMaxTau;
  return std::min(-std::log1p(-a), PreIntegrationTable::kMaxTau);
}

std::atomic<uint64_t> nextId{0};

constexpr int kMinLayer = -40, kMaxLayer = 40;  // 2^−20 … 2^20 mm

// The layers either side of a thickness (the two a segment of it reads).
double layerCoordinate(double mm) { return std::clamp(2.0 * std::log2(std::max(mm, 1e-30)), double(kMinLayer), double(kMaxLayer)); }
int layerBelow(double mm) { return int(std::floor(layerCoordinate(mm))); }
int layerAbove(double mm) { return int(std::ceil(layerCoordinate(mm))); }

}  // namespace

int PreIntegrationTable::layerOf(double mm) { return int(std::lround(layerCoordinate(mm))); }

double PreIntegrationTable::layerMm(int k) { return std::exp2(0.5 * double(k)); }

PreIntegrationTable::PreIntegrationTable(const TransferFunction& tf, float vmin, float vmax, double minMm, double maxMm, int bins)
    : mBins(bins), mVmin(vmin), mVmax(std::max(vmin, vmax)), mId(nextId.fetch_add(1) + 1) {
  if (bins < 2 || bins > 4096) HYB_THROW(ValueError, "pre-integration table of ", bins, " bins (expected 2 to 4096)");
  if (!(minMm > 0.0 && maxMm >= minMm && std::isfinite(maxMm)))
    HYB_THROW(ValueError, "pre-integration thicknesses [", minMm, ", ", maxMm, "] mm (expected 0 < min <= max, finite)");
  const auto t0 = std::chrono::steady_clock::now();
  mScale = mVmax > mVmin ? float(bins - 1) / (mVmax - mVmin) : 0.0f;
  if (!std::isfinite(mScale)) mScale = 0.0f;
  mFirst = layerBelow(minMm);
  mLayers = layerAbove(maxMm) - mFirst + 1;
  mTexels.assign(size_t(mLayers) * size_t(bins) * size_t(bins), glm::vec4(0.0f));
  // The pieces between bins: their optical depth per mm and colour at their midpoints.
  const int pieces = (bins - 1) * kPieces;
  std::vector<double> tau(static_cast<size_t>(pieces));
  std::vector<glm::dvec3> color(static_cast<size_t>(pieces));
  for (int j = 0; j < pieces; ++j) {
    const glm::vec4 c = tf.lookup(float(double(mVmin) + (double(mVmax) - double(mVmin)) * (j + 0.5) / pieces));
    tau[size_t(j)] = tauOf(c.a);
    color[size_t(j)] = glm::dvec3(c);
  }
  for (int layer = 0; layer < mLayers; ++layer) buildLayer(tau, color, tf, layer);
  mBuildMs = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

void PreIntegrationTable::buildLayer(const std::vector<double>& tau, const std::vector<glm::dvec3>& color, const TransferFunction& tf, int layer) {
  const double d = layerMm(mFirst + layer);
  const int n = mBins, m = int(tau.size());
  glm::vec4* out = &mTexels[size_t(layer) * size_t(n) * size_t(n)];
  auto entry = [&](int front, int back) -> glm::vec4& { return out[size_t(back) * size_t(n) + size_t(front)]; };
  // Equal values: the homogeneous segment, its colour and optical depth per mm those of its value.
  for (int u = 0; u < n; ++u) {
    const glm::vec4 c = tf.lookup(mVmin + (mVmax - mVmin) * float(u) / float(n - 1));
    entry(u, u) = glm::vec4(glm::vec3(c), float(tauOf(c.a)));
  }
  // Optical depth of pieces [0, j), and of each piece weighting its colour: a segment's opacity,
  // and its colour where it is nearly transparent (the limit of C/α as the opacity vanishes).
  std::vector<double> depth(size_t(m) + 1, 0.0);
  std::vector<glm::dvec3> depthColor(size_t(m) + 1, glm::dvec3(0.0));
  for (int j = 0; j < m; ++j) {
    depth[size_t(j) + 1] = depth[size_t(j)] + tau[size_t(j)];
    depthColor[size_t(j) + 1] = depthColor[size_t(j)] + tau[size_t(j)] * color[size_t(j)];
  }
#pragma omp parallel
  {
    std::vector<glm::dvec3> back(size_t(m) + 1), front(size_t(m) + 1);
#pragma omp for schedule(dynamic)
    for (int k = 1; k < n; ++k) {
      // Bins k apart: the segment crosses k·kPieces pieces, each d/(k·kPieces) mm long.
      const double piece = d / (double(k) * kPieces);
      // back[j]: pieces j, j+1, … composited front to back (values rising away from the eye);
      // front[j]: pieces j − 1, j − 2, … (values falling away from the eye).
      back[size_t(m)] = glm::dvec3(0.0);
      for (int j = m - 1; j >= 0; --j) {
        const double a = -std::expm1(-tau[size_t(j)] * piece);
        back[size_t(j)] = a * color[size_t(j)] + (1.0 - a) * back[size_t(j) + 1];
      }
      front[0] = glm::dvec3(0.0);
      for (int j = 0; j < m; ++j) {
        const double a = -std::expm1(-tau[size_t(j)] * piece);
        front[size_t(j) + 1] = a * color[size_t(j)] + (1.0 - a) * front[size_t(j)];
      }
      for (int lo = 0; lo + k < n; ++lo) {
        const int hi = lo + k;
        const size_t pl = size_t(lo) * kPieces, ph = size_t(hi) * kPieces;
        const double sum = depth[ph] - depth[pl], alpha = -std::expm1(-sum * piece), t = 1.0 - alpha;
        const float perMm = float(sum / (double(k) * kPieces));
        // Colour C / α: exact where the segment is visible, its limit where it is (nearly) not.
        glm::dvec3 rising, falling;
        if (alpha > 1e-6) {
          rising = (back[pl] - t * back[ph]) / alpha;
          falling = (front[ph] - t * front[pl]) / alpha;
        } else {
          rising = falling = sum > 0.0 ? (depthColor[ph] - depthColor[pl]) / sum : color[(pl + ph) / 2];
        }
        entry(lo, hi) = glm::vec4(glm::vec3(rising), perMm);
        entry(hi, lo) = glm::vec4(glm::vec3(falling), perMm);
      }
    }
  }
}

bool PreIntegrationTable::covers(double minMm, double maxMm) const {
  return layerBelow(minMm) >= mFirst && layerAbove(maxMm) < mFirst + mLayers;
}

glm::vec4 PreIntegrationTable::lookup(float front, float back, double mm, double depthScale) const {
  // Trilinear, as the slice shader's texture read: bins bilinearly, layers linearly in log mm.
  auto coord = [&](float v) { return std::clamp((v - mVmin) * mScale, 0.0f, float(mBins - 1)); };
  const float x = coord(front), y = coord(back);
  const int x0 = std::min(int(x), mBins - 2), y0 = std::min(int(y), mBins - 2);
  const float fx = x - float(x0), fy = y - float(y0);
  auto read = [&](int layer) {
    return glm::mix(glm::mix(at(layer, x0, y0), at(layer, x0 + 1, y0), fx), glm::mix(at(layer, x0, y0 + 1), at(layer, x0 + 1, y0 + 1), fx), fy);
  };
  const double k = std::clamp(layerCoordinate(mm) - mFirst, 0.0, double(mLayers - 1));
  const int k0 = std::min(int(k), std::max(mLayers - 2, 0));
  const glm::vec4 e = mLayers == 1 ? read(0) : glm::mix(read(k0), read(k0 + 1), float(k - k0));
  const double alpha = -std::expm1(-std::max(mm, 0.0) * depthScale * double(e.a));
  return glm::vec4(glm::vec3(glm::dvec3(e) * alpha), float(alpha));
}

PreIntegrationTable preintegrationFor(const TransferFunction& tf, float dataMin, float dataMax, double minMm, double maxMm) {
  // Over every value the data take: a segment's ends are integrated between them, and an end
  // clamped to a narrower domain would stretch the rest over the whole segment.
  return PreIntegrationTable(tf, dataMin, dataMax, minMm, maxMm);
}

}  // namespace hyb
