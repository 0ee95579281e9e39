// Pre-integrated classification (Engel, Kraus and Ertl, "High-Quality Pre-Integrated Volume
// Rendering Using Hardware-Accelerated Pixel Shading", 2001): a segment's colour and opacity read
// from a table of the transfer function integrated between the values at its two ends, so narrow
// transfer-function features between samples are not missed (docs/renderer.md).
#pragma once

#include <glm/glm.hpp>

#include <vector>

#include "render/transfer_function.h"

namespace hyb {

/// How a segment of a ray is classified: by the transfer function at one sample (post-
/// classification, LaMar's opacity correction for its length), or integrated between the values
/// at its ends (pre-integration).
enum class Classification { Post, PreIntegrated };

/// The pre-integration table of a transfer function over the value domain [vmin, vmax] (the
/// renderers': the data's range, preintegrationFor): for a segment of d mm along which the value goes linearly from sf
/// (front, nearer the eye) to sb (back), the premultiplied colour C = ∫ τ c e^(−∫τ) and opacity
/// α = 1 − e^(−∫τ), τ = −ln(1 − a) being the optical depth per mm of the per-millimetre opacity a.
///
/// Each entry holds the segment's optical depth per mm (the mean of τ between sf and sb: the same
/// at every length, so α = 1 − e^(−d·D) is exact at any d) and its colour C / α, which depends on
/// d through the attenuation inside the segment: one layer per thickness 2^(k/2) mm (k an
/// integer), covering the thicknesses asked, each the exact O(n²) table of docs/renderer.md (for
/// each bin distance the pieces between bins are composited back to front once, and every pair at
/// that distance is a difference of two running sums). A read is trilinear, as one 3D texture
/// read in the slice shader: bins bilinearly, layers linearly in log d (thicknesses beyond the
/// layers read the end layer's colour). Exact for a homogeneous segment at any d. The transfer
/// function is integrated on kPieces pieces between neighbouring bins (midpoint rule).
class PreIntegrationTable {
 public:
  static constexpr int kDefaultBins = 256;
  static constexpr int kPieces = 8;     ///< integration pieces between neighbouring bins
  static constexpr double kMaxTau = 1e4;  ///< optical depth per mm of an opacity of 1 (opaque in a micrometre)

  /// Layers covering segments of [minMm, maxMm] (each clamped to [2^−20, 2^20] mm).
  /// @throw ValueError when @p bins is outside [2, 4096] or the thicknesses are not positive and finite.
  PreIntegrationTable(const TransferFunction& tf, float vmin, float vmax, double minMm, double maxMm, int bins = kDefaultBins);

  /// The layer whose thickness is nearest @p mm (in ratio), and layer @p k's thickness.
  static int layerOf(double mm);
  static double layerMm(int k);

  /// Colour (premultiplied) and opacity of a segment of @p mm millimetres whose value goes from
  /// @p front to @p back, the optical depth scaled by @p depthScale (a volume of interest's
  /// opacity factor). Reads as the slice shader does.
  glm::vec4 lookup(float front, float back, double mm, double depthScale = 1.0) const;

  int bins() const { return mBins; }
  int firstLayer() const { return mFirst; }
  int layers() const { return mLayers; }
  bool covers(double minMm, double maxMm) const;
  float vmin() const { return mVmin; }
  /// A value's bin coordinate is (v − vmin) · scale, clamped to [0, bins − 1].
  float scale() const { return mScale; }
  /// Entries (colour C / α, optical depth per mm) layer by layer, each bins × bins with the front
  /// value's bin along rows.
  const std::vector<glm::vec4>& texels() const { return mTexels; }
  double buildMs() const { return mBuildMs; }
  /// Unique to this table (kept by its moves): what a texture made from it is kept under.
  uint64_t id() const { return mId; }

 private:
  void buildLayer(const std::vector<double>& tau, const std::vector<glm::dvec3>& color, const TransferFunction& tf, int layer);
  glm::vec4 at(int layer, int front, int back) const {
    return mTexels[(size_t(layer) * size_t(mBins) + size_t(back)) * size_t(mBins) + size_t(front)];
  }

  int mBins;
  float mVmin, mVmax, mScale;
  int mFirst = 0, mLayers = 0;
  std::vector<glm::vec4> mTexels;
  double mBuildMs = 0.0;
  uint64_t mId;
};

/// The table the renderers read for data with values in [@p dataMin, @p dataMax]: over that range
/// (a value outside the table's domain is clamped, which is exact only for a homogeneous segment),
/// layers covering segments of [minMm, maxMm].
PreIntegrationTable preintegrationFor(const TransferFunction& tf, float dataMin, float dataMax, double minMm, double maxMm);

}  // namespace hyb
