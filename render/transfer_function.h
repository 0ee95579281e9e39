// 1D transfer function: data value → colour and opacity per millimetre (docs/renderer.md, Conventions).
#pragma once

#include <glm/glm.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

namespace hyb {

/// Piecewise-linear transfer function. Opacity is that of one millimetre of material, so a sample
/// spanning d mm has α = 1 − (1 − a)^d and images do not depend on the sampling rate.
class TransferFunction {
 public:
  struct Point {
    float value;      ///< data units
    glm::vec3 color;  ///< [0, 1]
    float alpha;      ///< opacity of 1 mm, [0, 1]
  };

  TransferFunction() = default;
  /// @throw ValueError naming @p source when points are unsorted, empty, or outside [0, 1].
  TransferFunction(std::vector<Point> points, const std::string& source = "transfer function");

  /// Longest transfer-function file accepted, and longest line in it.
  static constexpr uint64_t kMaxFileBytes = uint64_t(1) << 20;
  static constexpr size_t kMaxLineBytes = 4096;

  /// Reads "value r g b a" lines ('#' comments) from a regular file of at most kMaxFileBytes with
  /// lines of at most kMaxLineBytes.
  /// @throw IoError / ValueError naming @p path and the line; IoError when @p path is not a
  ///        regular file (a FIFO, a directory) or is longer than the limits.
  static TransferFunction fromFile(const std::string& path);
  /// A named transfer function in Hounsfield units (presets()).
  struct Preset {
    const char* name;
    const char* shows;  ///< what it shows, for help texts and the viewer's menu
    std::vector<Point> points;
  };
  /// The presets, in the order menus list them: ct-skin-bone (CT's default), ct-bone, ct-skin,
  /// ct-soft-tissue, ct-vessels. The one table that the flags' help, the viewer and Python read.
  static const std::vector<Preset>& presets();
  /// The preset named @p name. @throw ValueError listing the presets when @p name is unknown.
  static TransferFunction preset(const std::string& name);
  static std::vector<std::string> presetNames();
  /// The preset data of this range gets by default: ct-skin-bone for CT (air at -900 HU or below
  /// and bone, 200 HU or above, present), or "" for a ramp over the data's range. The one decision
  /// the command line, the viewer and its page share.
  static std::string defaultPresetFor(float minValue, float maxValue);
  /// The isovalue first offered for data over [minValue, maxValue]: bone (400 HU) for CT, as
  /// defaultPresetFor decides, else the middle of the range.
  static float defaultIsoFor(float minValue, float maxValue);
  /// The default transfer function of data of this range: its default preset, or a warm ramp from
  /// the 40th to the 100th percentile of [min, max] with opacity up to 0.1/mm.
  static TransferFunction defaultFor(float minValue, float maxValue);

  /// Colour and opacity per mm at @p v (clamped to the end points).
  glm::vec4 lookup(float v) const;
  /// Largest opacity per mm over [lo, hi] (exact for the piecewise-linear function).
  float maxAlpha(float lo, float hi) const;
  /// Largest rate of change, per data unit, of the opacity plus the opacity-weighted colour over
  /// [lo, hi]: how much an error of one data unit in that range can change the image.
  float maxSlope(float lo, float hi) const;
  /// Bound on how much an error of @p error data units in values within [lo, hi] changes the
  /// classified opacity plus opacity-weighted colour: error · maxSlope, and never more than the
  /// largest opacity the range reaches (a change cannot exceed what is there; this keeps edges of
  /// saturated material, such as bone, from hiding thin translucent structures).
  double distortion(float lo, float hi, float error) const;
  /// Opacity of a segment of @p mm millimetres with opacity @p alphaPerMm per mm.
  static float segmentAlpha(float alphaPerMm, float mm);

  const std::vector<Point>& points() const { return mPoints; }

 private:
  std::vector<Point> mPoints;
};

/// The transfer function's lookup table as the renderers read it: 4096 entries, read at the
/// nearest entry (in the slice shader texelFetch costs less than a filtered read).
struct LutLayout {
  static constexpr int kSize = 4096;
  float vmin, vmax, scale;  ///< the entry of value v is round((v − vmin) · scale), clamped
  /// Over the part of the data's range [@p dataMin, @p dataMax] where the transfer function
  /// changes: it is constant beyond its first and last points, so no entries go to padding values
  /// (CT's −3024 outside the scanned disc) or outliers. When the two do not overlap every value
  /// reads entry 0.
  LutLayout(float dataMin, float dataMax, const TransferFunction& tf)
      : vmin(std::clamp(tf.points().front().value, dataMin, dataMax)),
        vmax(std::clamp(tf.points().back().value, dataMin, dataMax)),
        scale(vmax > vmin ? float(kSize - 1) / (vmax - vmin) : 0.0f) {
    if (!std::isfinite(scale)) scale = 0.0f;  // a domain narrower than float can divide by
  }
  /// The value entry @p entry stands for.
  float value(int entry) const { return vmin + (vmax - vmin) * float(entry) / float(kSize - 1); }
  /// The entry value @p v reads.
  int entry(float v) const { return int(std::clamp((v - vmin) * scale + 0.5f, 0.0f, float(kSize - 1))); }
  /// The entries values in [lo, hi] can read, with one of margin each side for the shader's rounding.
  std::array<uint16_t, 2> entries(float lo, float hi) const {
    auto at = [&](double e) { return uint16_t(std::clamp(e, 0.0, double(kSize - 1))); };
    return {at(std::floor(double(lo - vmin) * scale) - 1.0), at(std::ceil(double(hi - vmin) * scale) + 1.0)};
  }
};

}  // namespace hyb
