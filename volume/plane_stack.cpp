#include "volume/plane_stack.h"

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <limits>
#include <sstream>

#include "volume/core/error.h"
#include "volume/reader_util.h"

namespace hyb {

using detail::concat;

namespace {

// @p x with @p digits significant digits, for messages.
std::string shortNumber(double x, int digits = 3) {
  std::ostringstream s;
  s << std::setprecision(digits) << x;
  return s.str();
}

// The step that spaces a resampled grid, and how it was chosen: the smallest that occurs at least
// twice (within 1 %) and is at least a quarter of the mean, else the median.
std::pair<double, const char*> gridStep(std::vector<double> steps, double mean) {
  std::sort(steps.begin(), steps.end());
  for (size_t i = 0; i + 1 < steps.size(); ++i)
    if (steps[i] >= 0.25 * mean && steps[i + 1] <= steps[i] * 1.01) return {steps[i], "the smallest step that recurs"};
  return {steps[steps.size() / 2], "the median step: none recurs"};
}

}  // namespace

StackGrid stackGrid(const PlaneStack& stack, const std::string& what, const std::string& tiltNote) {
  const size_t n = stack.origins.size();
  HYB_CHECK(n >= 1 && stack.names.size() == n);
  const glm::dvec3 r = stack.axes[0], c = stack.axes[1], normal = stack.axes[2];
  std::vector<double> depth(n);
  std::vector<glm::dvec2> offset(n);  // in-plane position of each plane's origin relative to the first's, mm
  for (size_t k = 0; k < n; ++k) {
    if (!std::isfinite(glm::dot(stack.origins[k], glm::dvec3(1.0))))
      HYB_THROW(IoError, stack.names[k], ": position not finite (expected a plane's position in millimetres)");
    depth[k] = glm::dot(stack.origins[k], normal);
    const glm::dvec3 d = stack.origins[k] - stack.origins[0];
    offset[k] = {glm::dot(d, r), glm::dot(d, c)};
  }
  std::vector<double> steps;
  for (size_t k = 1; k < n; ++k) {
    steps.push_back(depth[k] - depth[k - 1]);
    HYB_CHECK(steps.back() >= 0.0);  // the stack is ordered by depth
    if (steps.back() <= 1e-3 * std::max((depth[n - 1] - depth[0]) / double(n - 1), 1e-3))
      HYB_THROW(IoError, stack.names[k], ": at the same position as ", stack.names[k - 1], " along the slice normal (expected one slice per position)");
  }
  StackGrid g;
  g.frame.direction = stack.axes;
  g.frame.origin = stack.origins[0];
  if (n == 1) {
    g.dims = {stack.size.x, stack.size.y, 1};
    g.spacing = {stack.pixelSpacing.x, stack.pixelSpacing.y, stack.singleSpacing};
    return g;
  }
  const double mean = (depth[n - 1] - depth[0]) / double(n - 1);
  bool even = true, onLine = true;
  double maxShift = 0.0;
  for (size_t k = 1; k < n; ++k) {
    even = even && std::abs(steps[k - 1] - mean) <= std::max(1e-3, 1e-2 * mean);
    const double along = std::abs(depth[k] - depth[0]);
    onLine = onLine && glm::length(offset[k]) <= std::max(1e-2, 1e-3 * along);
    maxShift = std::max(maxShift, glm::length(offset[k]));
  }
  if (even && onLine) {
    g.dims = {stack.size.x, stack.size.y, int(n)};
    g.spacing = {stack.pixelSpacing.x, stack.pixelSpacing.y, mean};
    return g;
  }
  // A missing slice: a step well over the steps beside it (a change of spacing between blocks is not).
  if (!even)
    for (size_t k = 0; k < steps.size(); ++k) {
      double beside = 0.0;
      if (k > 0) beside = std::max(beside, steps[k - 1]);
      if (k + 1 < steps.size()) beside = std::max(beside, steps[k + 1]);
      if (beside > 0.0 && steps[k] > 1.75 * beside)
        HYB_THROW(IoError, what, ": a slice is missing between ", stack.names[k], " and ", stack.names[k + 1], " (", shortNumber(steps[k], 4),
                  " mm apart where the slices beside them are ", shortNumber(beside, 4),
                  " mm apart; expected no step over 1.75 times its neighbours': a gap is not interpolated across)");
    }
  g.resampled = true;
  const auto [dz, rule] = even ? std::pair<double, const char*>{mean, ""} : gridStep(steps, mean);
  const int planes = int(std::lround((depth[n - 1] - depth[0]) / dz)) + 1;
  // The in-plane lattice of the first plane, widened to hold every plane's pixels.
  glm::dvec2 lo(0.0), hi(0.0);
  for (const glm::dvec2& o : offset) {
    lo = glm::min(lo, o / stack.pixelSpacing);
    hi = glm::max(hi, o / stack.pixelSpacing);
  }
  const glm::ivec2 first(int(std::floor(lo.x + 1e-6)), int(std::floor(lo.y + 1e-6)));
  const glm::ivec2 last(int(std::ceil(hi.x - 1e-6)), int(std::ceil(hi.y - 1e-6)));
  g.dims = {stack.size.x + last.x - first.x, stack.size.y + last.y - first.y, planes};
  validateDims(g.dims, what);
  g.spacing = {stack.pixelSpacing.x, stack.pixelSpacing.y, dz};
  g.frame.origin = stack.origins[0] + double(first.x) * stack.pixelSpacing.x * r + double(first.y) * stack.pixelSpacing.y * c;
  for (int k = 0; k < planes; ++k) {
    const double at = depth[0] + double(k) * dz;
    size_t a = 0;
    while (a + 1 < n && depth[a + 1] <= at + 1e-6 * dz) ++a;
    StackGrid::Plane p;
    p.a = p.b = int(a);
    if (a + 1 < n) {
      const double t = std::clamp((at - depth[a]) / (depth[a + 1] - depth[a]), 0.0, 1.0);
      if (t > 1e-6) {
        p.b = int(a + 1);
        p.t = t;
      }
    }
    p.shiftA = glm::dvec2(first) - offset[size_t(p.a)] / stack.pixelSpacing;
    p.shiftB = glm::dvec2(first) - offset[size_t(p.b)] / stack.pixelSpacing;
    g.planes.push_back(p);
  }
  const std::string grid = concat(g.dims.x, "x", g.dims.y, "x", g.dims.z);
  if (!onLine) {
    const glm::dvec2 drift = offset[n - 1];
    const double angle = std::atan2(glm::length(drift), depth[n - 1] - depth[0]) * 180.0 / M_PI;
    g.warnings.push_back(concat(what, ": gantry tilt of ", shortNumber(angle), " degrees", tiltNote.empty() ? "" : " (" + tiltNote + ")",
                                ": the slices' positions run off their normal, so they are resampled onto an orthogonal grid of ", grid,
                                ", each slice shifted in its plane by up to ", shortNumber(maxShift), " mm"));
  }
  if (!even) {
    const auto [minStep, maxStep] = std::minmax_element(steps.begin(), steps.end());
    g.warnings.push_back(concat(what, ": slices ", shortNumber(*minStep), " to ", shortNumber(*maxStep),
                                " mm apart along their normal: resampled onto a regular grid ", shortNumber(dz, 4), " mm apart (", rule,
                                "), ", planes, " planes from ", n, " slices"));
  }
  return g;
}

namespace {

// Planes of an orthogonal grid interpolated from a stack's planes (StackGrid::Plane).
class ResampledPlanes final : public PlaneSource {
 public:
  ResampledPlanes(std::unique_ptr<PlaneSource> source, StackGrid grid, Volume description)
      : PlaneSource(std::move(description), source->name()), mSource(std::move(source)), mGrid(std::move(grid)) {}
  void rewind() override {
    mSource->rewind();
    mNext = 0;
    mRead = 0;
    mHeld[0] = mHeld[1] = -1;
  }
  void read(int count, SampleArray* out, size_t first) override {
    HYB_CHECK(count >= 0 && mNext + count <= dims().z && first + size_t(count) * planeSize() <= sampleCount(*out));
    for (int k = 0; k < count; ++k, ++mNext) {
      const StackGrid::Plane& p = mGrid.planes[size_t(mNext)];
      hold(p.a);
      hold(p.b);
      std::visit(
          [&](auto& to) {
            using T = typename std::remove_reference_t<decltype(to)>::value_type;
            draw<T>(p, to.data() + first + size_t(k) * planeSize());
          },
          *out);
    }
  }

 private:
  // Reads source planes forward until plane @p z is held (two slots: the two last read).
  void hold(int z) {
    if (mHeld[0] == z || mHeld[1] == z) return;
    HYB_CHECK(z >= mRead);
    const size_t size = mSource->planeSize();
    if (sampleCount(mPlanes) != 2 * size) mPlanes = detail::allocateSamples(mSource->storedType(), 2 * size);
    while (mRead <= z) {
      const int slot = mHeld[0] < mHeld[1] ? 0 : 1;  // the older one
      mSource->read(1, &mPlanes, size_t(slot) * size);
      mHeld[slot] = mRead;
      if (mRead == 0)  // the padding: the first plane's smallest value, a value of the stored type
        mPad = std::visit([&](const auto& s) { return double(*std::min_element(s.begin() + ptrdiff_t(size_t(slot) * size), s.begin() + ptrdiff_t((size_t(slot) + 1) * size))); },
                          mPlanes);
      ++mRead;
    }
  }
  int slotOf(int z) const { return mHeld[0] == z ? 0 : 1; }

  // Output plane @p p into @p to.
  template <class T>
  void draw(const StackGrid::Plane& p, T* to) const {
    const glm::ivec2 in = {mSource->dims().x, mSource->dims().y};
    const int nx = dims().x, ny = dims().y;
    const size_t size = mSource->planeSize();
    const T* planes = std::get<std::vector<T>>(mPlanes).data();
    const T* a = planes + size_t(slotOf(p.a)) * size;
    const T* b = planes + size_t(slotOf(p.b)) * size;
    // One source plane's taps: two columns and two rows around the shifted pixel, with their weights.
    struct Taps {
      const T* plane;
      double weight;
      int x0, y0;
      double fx, fy;
    };
    auto taps = [](const T* plane, double weight, const glm::dvec2& shift) {
      Taps t{plane, weight, int(std::floor(shift.x + 1e-9)), int(std::floor(shift.y + 1e-9)), 0.0, 0.0};
      t.fx = shift.x - t.x0;
      t.fy = shift.y - t.y0;
      if (t.fx < 1e-6) t.fx = 0.0;
      if (t.fy < 1e-6) t.fy = 0.0;
      return t;
    };
    const Taps sources[2] = {taps(a, 1.0 - p.t, p.shiftA), taps(b, p.t, p.shiftB)};
    const int used = p.t > 0.0 ? 2 : 1;
    const double pad = mPad;
    auto at = [&](const Taps& s, int x, int y) { return x >= 0 && y >= 0 && x < in.x && y < in.y ? double(s.plane[size_t(x) + size_t(in.x) * size_t(y)]) : pad; };
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i) {
        double v = 0.0;
        for (int s = 0; s < used; ++s) {
          const Taps& t = sources[s];
          const int x = i + t.x0, y = j + t.y0;
          double row0 = at(t, x, y), row1 = 0.0;
          if (t.fx > 0.0) row0 += t.fx * (at(t, x + 1, y) - row0);
          if (t.fy > 0.0) {
            row1 = at(t, x, y + 1);
            if (t.fx > 0.0) row1 += t.fx * (at(t, x + 1, y + 1) - row1);
            row0 += t.fy * (row1 - row0);
          }
          v += t.weight * row0;
        }
        if constexpr (std::is_floating_point_v<T>) {
          to[size_t(i) + size_t(nx) * size_t(j)] = T(v);
        } else {
          const double lo = double(std::numeric_limits<T>::min()), hi = double(std::numeric_limits<T>::max());
          to[size_t(i) + size_t(nx) * size_t(j)] = T(std::clamp(std::nearbyint(v), lo, hi));
        }
      }
  }

  std::unique_ptr<PlaneSource> mSource;
  StackGrid mGrid;
  int mNext = 0, mRead = 0;
  int mHeld[2] = {-1, -1};
  SampleArray mPlanes;  // two source planes
  double mPad = 0.0;
};

// The planes of a volume read whole, kept alive by the source.
class OwningPlanes final : public PlaneSource {
 public:
  OwningPlanes(std::shared_ptr<const Volume> v, const std::string& name)
      : PlaneSource(detail::placedAs(Volume::withoutSamples(v->layout(), 0.0f, 0.0f, name), *v), name),
        mVolume(std::move(v)) {}
  bool whole() const override { return true; }
  void rewind() override { mNext = 0; }
  void read(int count, SampleArray* out, size_t first) override {
    const size_t n = size_t(count) * planeSize();
    HYB_CHECK(mNext + n <= mVolume->voxelCount() && first + n <= sampleCount(*out));
    mVolume->visitSamples([&](const auto* from) {
      using T = std::remove_cv_t<std::remove_pointer_t<decltype(from)>>;
      std::copy_n(from + mNext, n, std::get<std::vector<T>>(*out).data() + first);
    });
    mNext += n;
  }

 private:
  std::shared_ptr<const Volume> mVolume;
  size_t mNext = 0;
};

}  // namespace

std::unique_ptr<PlaneSource> resampledPlanes(std::unique_ptr<PlaneSource> source, StackGrid grid) {
  if (!grid.resampled) return source;
  const Volume& from = source->description();
  Volume description = Volume::withoutSamples({grid.dims, grid.spacing, from.sourceType(), from.storedType()}, 0.0f, 0.0f, source->name());
  description = detail::placed(std::move(description), grid.frame, {});
  for (const auto& [key, value] : from.info()) description.addInfo(key, value);
  for (const std::string& w : from.warnings()) description.addWarning(w);
  for (const std::string& w : grid.warnings) description.addWarning(w);
  description.addInfo("resampled", concat("onto an orthogonal grid of ", grid.dims.x, "x", grid.dims.y, "x", grid.dims.z, ", ", grid.spacing.z,
                                          " mm between planes (", from.dims().z, " source slices)"));
  return std::make_unique<ResampledPlanes>(std::move(source), std::move(grid), std::move(description));
}

namespace detail {

Volume readAllPlanes(PlaneSource& source) {
  const Volume& d = source.description();
  SampleArray all = allocateSamples(source.storedType(), d.voxelCount());
  source.rewind();
  for (int z = 0; z < d.dims().z; ++z) source.read(1, &all, size_t(z) * source.planeSize());
  return filled(d, std::move(all), source.name());
}

std::unique_ptr<PlaneSource> planesOwning(std::shared_ptr<const Volume> volume, const std::string& name) {
  return std::make_unique<OwningPlanes>(std::move(volume), name);
}

}  // namespace detail

}  // namespace hyb
