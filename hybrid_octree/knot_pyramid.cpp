#include "hybrid_octree/knot_pyramid.h"

#include <algorithm>
#include <bit>
#include <cstdlib>
#include <memory>

#include "volume/core/error.h"

namespace hyb {

namespace {

// Extended sample i of a line of n samples extended by odd reflection about its end samples:
// a·line[0] + b·line[n − 1] + sign·line[index].
struct OddTerm {
  int index, sign, a, b;
};
OddTerm oddTerm(int i, int n) {
  OddTerm t{0, 1, 0, 0};
  while (n > 1 && (i < 0 || i > n - 1)) {  // each reflection brings i closer to the line
    const bool low = i < 0;
    (low ? t.a : t.b) += 2 * t.sign;
    t.sign = -t.sign;
    i = low ? -i : 2 * (n - 1) - i;
  }
  t.index = n > 1 ? i : 0;
  return t;
}

// Lines of n samples extended by odd reflection about their end samples, pad samples either side:
// extended sample i is a·line[0] + b·line[n − 1] + sign·line[index], the same terms for every line.
// As second prefix sums (p2[k] = Σ_{m<k} Σ_{l<m} g[l], g[k] the extended sample k − pad) a tent sum
// costs three reads whatever its width (the tent is a box convolved with a box).
class OddExtension {
 public:
  OddExtension(int n, int pad) : mN(n), mPad(pad) {
    for (int side = 0; side < 2; ++side)
      for (int k = 0; k < pad; ++k) mTerms.push_back(oddTerm(side == 0 ? k - pad : n + k, n));
  }

  static constexpr int kLanes = 4;

  // Second prefix sums of @p count ≤ kLanes lines (stride apart sample to sample) at once, four
  // independent pairs of sums in registers hiding the additions' latency: p2[k·kLanes + r] for line r.
  void secondPrefixSums(const float* const* lines, int count, ptrdiff_t stride, std::vector<double>* p2) const {
    static_assert(kLanes == 4);
    const int length = mN + 2 * mPad;
    p2->resize((size_t(length) + 2) * kLanes);
    double* out = p2->data();
    const float* l[kLanes];
    for (int r = 0; r < kLanes; ++r) l[r] = lines[std::min(r, count - 1)];
    const ptrdiff_t end = ptrdiff_t(mN - 1) * stride;
    const double f0 = l[0][0], f1 = l[1][0], f2 = l[2][0], f3 = l[3][0];
    const double e0 = l[0][end], e1 = l[1][end], e2 = l[2][end], e3 = l[3][end];
    double o0 = 0, o1 = 0, o2 = 0, o3 = 0, t0 = 0, t1 = 0, t2 = 0, t3 = 0;
    out[0] = out[1] = out[2] = out[3] = 0.0;
    double* w = out + kLanes;
    auto push = [&](double g0, double g1, double g2, double g3) {
      t0 += o0, t1 += o1, t2 += o2, t3 += o3;
      w[0] = t0, w[1] = t1, w[2] = t2, w[3] = t3;
      w += kLanes;
      o0 += g0, o1 += g1, o2 += g2, o3 += g3;
    };
    auto outside = [&](const OddTerm& t) {
      const ptrdiff_t i = ptrdiff_t(t.index) * stride;
      push(t.a * f0 + t.b * e0 + t.sign * double(l[0][i]), t.a * f1 + t.b * e1 + t.sign * double(l[1][i]),
           t.a * f2 + t.b * e2 + t.sign * double(l[2][i]), t.a * f3 + t.b * e3 + t.sign * double(l[3][i]));
    };
    for (int k = 0; k < mPad; ++k) outside(mTerms[size_t(k)]);
    for (ptrdiff_t i = 0; i <= end; i += stride) push(l[0][i], l[1][i], l[2][i], l[3][i]);
    for (int k = mPad; k < 2 * mPad; ++k) outside(mTerms[size_t(k)]);
    push(0.0, 0.0, 0.0, 0.0);
  }

  // The tent of half-width s ≤ pad + 1 at sample q of line r behind @p p2.
  float tentAt(const std::vector<double>& p2, int r, int q, int s) const {
    const size_t k = size_t(q - s + 1 + mPad);
    auto at = [&](size_t i) { return p2[i * kLanes + size_t(r)]; };
    return float((at(k + 2 * size_t(s)) - 2.0 * at(k + size_t(s)) + at(k)) / (double(s) * double(s)));
  }

 private:
  int mN, mPad;
  std::vector<OddTerm> mTerms;  // extended samples −pad…−1, then n…n + pad − 1
};

// The tent of half-width s at knot q of a line of n samples extended by odd reflection, as weights
// of the line's own samples first … first + weights.size() − 1 (those within s − 1 of q).
struct ZKnot {
  int first = 0;
  std::vector<double> weights;
};
ZKnot tentWeights(int q, int s, int n) {
  ZKnot k;
  k.first = std::max(0, q - s + 1);
  const int last = std::min(n - 1, q + s - 1);
  k.weights.assign(size_t(last - k.first + 1), 0.0);
  auto add = [&](int i, double w) { k.weights[size_t(i - k.first)] += w; };
  for (int i = q - s + 1; i <= q + s - 1; ++i) {
    const double w = double(s - std::abs(i - q)) / (double(s) * double(s));
    const OddTerm t = oddTerm(i, n);
    add(t.index, w * t.sign);
    if (t.a) add(0, w * t.a);
    if (t.b) add(n - 1, w * t.b);
  }
  return k;
}

}  // namespace

// Separably, plane by plane: x along each row for all spacings at once (one pair of prefix sums a
// row), then y at each spacing's x knots; z last, each (x, y)-filtered plane added with its tent
// weight to the knot planes whose tent holds it. A plane is dropped once added: what is held is
// the knot planes still being summed, a few per spacing, and the finished knots.
struct KnotPyramid::Builder::Impl {
  struct LevelState {
    std::vector<ZKnot> z;                               // per knot plane
    std::vector<std::vector<double>> sums;              // per knot plane, while it is being summed
    std::vector<float> values;                          // finished knots, x fastest
    size_t nextKnot = 0;                                // first knot plane not finished
  };
  glm::ivec3 dims;
  std::vector<Level> levels;
  std::vector<LevelState> state;
  std::unique_ptr<OddExtension> rows;
  std::vector<OddExtension> columns;
  std::vector<std::vector<float>> ax, ay;  // this plane's x-filtered rows and x-y-filtered knots, per spacing
  int next = 0;
};

KnotPyramid::Builder::Builder(const glm::ivec3& dims) : mImpl(std::make_unique<Impl>()) {
  Impl& m = *mImpl;
  m.dims = dims;
  for (int s = kPrefilterSpacing; s <= kPrefilterMaxSpacing; s *= 2) {
    Level level;
    level.spacing = s;
    level.count = knotCounts(dims, s);
    Impl::LevelState st;
    for (int j = 0; j < level.count.z; ++j) st.z.push_back(tentWeights(knotPosition(j, s, dims.z), s, dims.z));
    st.sums.resize(size_t(level.count.z));
    st.values.resize(size_t(level.count.x) * size_t(level.count.y) * size_t(level.count.z));
    m.ax.emplace_back(size_t(level.count.x) * size_t(dims.y));
    m.ay.emplace_back(size_t(level.count.x) * size_t(level.count.y));
    m.columns.emplace_back(dims.y, s);
    m.levels.push_back(std::move(level));
    m.state.push_back(std::move(st));
  }
  m.rows = std::make_unique<OddExtension>(dims.x, m.levels.back().spacing);
}

KnotPyramid::Builder::~Builder() = default;

void KnotPyramid::Builder::add(const std::function<void(int y, float* out)>& readRow) {
  Impl& m = *mImpl;
  HYB_CHECK(m.next < m.dims.z);
  const int z = m.next++;
  const glm::ivec3 n = m.dims;
  const size_t levels = m.levels.size();
  constexpr int L = OddExtension::kLanes;
#pragma omp parallel
  {
    std::vector<double> p2;
    const float* lines[L];
    std::vector<float> rowValues(size_t(L) * size_t(n.x));  // this group's rows as float
#pragma omp for schedule(dynamic, 4)
    for (int first = 0; first < n.y; first += L) {
      const int count = std::min(L, n.y - first);
      for (int r = 0; r < count; ++r) {
        float* row = &rowValues[size_t(r) * size_t(n.x)];
        readRow(first + r, row);
        lines[r] = row;
      }
      m.rows->secondPrefixSums(lines, count, 1, &p2);
      for (int r = 0; r < count; ++r)
        for (size_t l = 0; l < levels; ++l) {
          const int s = m.levels[l].spacing, cx = m.levels[l].count.x;
          for (int j = 0; j < cx; ++j) m.ax[l][size_t(first + r) * size_t(cx) + size_t(j)] = m.rows->tentAt(p2, r, knotPosition(j, s, n.x), s);
        }
    }
    for (size_t l = 0; l < levels; ++l) {
      const int s = m.levels[l].spacing;
      const glm::ivec3 c = m.levels[l].count;
#pragma omp for schedule(dynamic, 4)
      for (int first = 0; first < c.x; first += L) {
        const int count = std::min(L, c.x - first);
        for (int r = 0; r < count; ++r) lines[r] = &m.ax[l][size_t(first + r)];
        m.columns[l].secondPrefixSums(lines, count, c.x, &p2);
        for (int r = 0; r < count; ++r)
          for (int j = 0; j < c.y; ++j) m.ay[l][size_t(first + r) + size_t(c.x) * size_t(j)] = m.columns[l].tentAt(p2, r, knotPosition(j, s, n.y), s);
      }
    }
  }
  for (size_t l = 0; l < levels; ++l) {
    Impl::LevelState& st = m.state[l];
    const size_t plane = m.ay[l].size();
    for (size_t j = st.nextKnot; j < st.z.size() && st.z[j].first <= z; ++j) {
      const ZKnot& k = st.z[j];
      std::vector<double>& sum = st.sums[j];
      if (sum.empty()) sum.assign(plane, 0.0);
      const double w = k.weights[size_t(z - k.first)];
      const float* a = m.ay[l].data();
#pragma omp parallel for schedule(static) if (plane > 4096)
      for (size_t i = 0; i < plane; ++i) sum[i] += w * double(a[i]);
      if (k.first + int(k.weights.size()) - 1 == z) {  // its last plane: the knot plane is done
        float* out = st.values.data() + plane * j;
        for (size_t i = 0; i < plane; ++i) out[i] = float(sum[i]);
        std::vector<double>().swap(sum);
        st.nextKnot = j + 1;
      }
    }
  }
}

KnotPyramid KnotPyramid::Builder::finish() {
  Impl& m = *mImpl;
  HYB_CHECK(m.next == m.dims.z);
  KnotPyramid p;
  p.mDims = m.dims;
  for (size_t l = 0; l < m.levels.size(); ++l) {
    Level& level = m.levels[l];
    std::vector<float>& values = m.state[l].values;
    // Stored in 16 bits over the level's range: half the memory, and the knots a brick shows and
    // the nodal errors are computed from are the stored ones, so nothing is approximated twice.
    const auto [lo, hi] = std::minmax_element(values.begin(), values.end());
    level.offset = *lo;
    level.scale = *hi > *lo ? (*hi - *lo) / 65535.0f : 0.0f;
    level.codes.resize(values.size());
    for (size_t i = 0; i < values.size(); ++i)
      level.codes[i] = level.scale > 0.0f ? uint16_t(std::min(65535.0f, (values[i] - level.offset) / level.scale + 0.5f)) : 0;
    std::vector<float>().swap(values);
    p.mLevels.push_back(std::move(level));
  }
  return p;
}

KnotPyramid::KnotPyramid(const Volume& volume) {
  Builder b(volume.dims());
  for (int z = 0; z < volume.dims().z; ++z) b.add([&](int y, float* out) { volume.readRow(0, y, z, volume.dims().x, out); });
  *this = b.finish();
}

const KnotPyramid::Level& KnotPyramid::level(int s) const {
  HYB_DCHECK(covers(s) && std::has_single_bit(unsigned(s)));
  return mLevels[size_t(std::countr_zero(unsigned(s / kPrefilterSpacing)))];
}

float KnotPyramid::at(int s, const glm::ivec3& p) const {
  const Level& level = this->level(s);
  glm::ivec3 j;
  for (int a = 0; a < 3; ++a) {
    HYB_DCHECK(p[a] >= 0 && p[a] < mDims[a] && (p[a] % s == 0 || p[a] == mDims[a] - 1));
    j[a] = p[a] == mDims[a] - 1 ? level.count[a] - 1 : p[a] / s;
  }
  return level.offset + level.scale * float(level.codes[size_t(j.x) + size_t(level.count.x) * (size_t(j.y) + size_t(level.count.y) * size_t(j.z))]);
}

size_t KnotPyramid::bytesUsed() const {
  size_t bytes = sizeof(*this);
  for (const Level& l : mLevels) bytes += l.codes.size() * sizeof(uint16_t) + sizeof(Level);
  return bytes;
}

}  // namespace hyb
