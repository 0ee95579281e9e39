#include "hybrid_octree/knot_pyramid.h"

#include <algorithm>
#include <bit>

#include "volume/error.h"

namespace hyb {

namespace {

// Lines of n samples extended by odd reflection about their end samples, pad samples either side:
// extended sample i is a·line[0] + b·line[n − 1] + sign·line[index], the same terms for every line.
// As second prefix sums (p2[k] = Σ_{m<k} Σ_{l<m} g[l], g[k] the extended sample k − pad) a tent sum
// costs three reads whatever its width (the tent is a box convolved with a box).
class OddExtension {
 public:
  OddExtension(int n, int pad) : mN(n), mPad(pad) {
    for (int side = 0; side < 2; ++side)
      for (int k = 0; k < pad; ++k) {
        int i = side == 0 ? k - pad : n + k;
        Term t{0, 1, 0, 0};
        while (n > 1 && (i < 0 || i > n - 1)) {  // each reflection brings i closer to the line
          const bool low = i < 0;
          (low ? t.a : t.b) += 2 * t.sign;
          t.sign = -t.sign;
          i = low ? -i : 2 * (n - 1) - i;
        }
        t.index = n > 1 ? i : 0;
        mTerms.push_back(t);
      }
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
    auto outside = [&](const Term& t) {
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
  struct Term {
    int index, sign, a, b;
  };
  int mN, mPad;
  std::vector<Term> mTerms;  // extended samples −pad…−1, then n…n + pad − 1
};

}  // namespace

KnotPyramid::KnotPyramid(const Volume& volume) : mDims(volume.dims()) {
  const glm::ivec3 n = mDims;
  for (int s = kPrefilterSpacing; s <= kPrefilterMaxSpacing; s *= 2) {
    Level level;
    level.spacing = s;
    level.count = glm::ivec3(knotCount(n.x, s), knotCount(n.y, s), knotCount(n.z, s));
    mLevels.push_back(std::move(level));
  }
  // Separably, z-slice by z-slice: x along each row for all spacings at once (one pair of prefix
  // sums a row), then y at each spacing's x knots; last, per spacing, z at its (x, y) knots. Only
  // the (x, y)-filtered slices are kept (a sixteenth of the samples or less), not whole passes.
  const size_t levels = mLevels.size();
  const OddExtension rows(n.x, mLevels.back().spacing);
  std::vector<std::vector<float>> ay(levels);  // per spacing: count.x · count.y · n.z
  std::vector<OddExtension> columns;
  for (size_t l = 0; l < levels; ++l) {
    ay[l].resize(size_t(mLevels[l].count.x) * mLevels[l].count.y * n.z);
    columns.emplace_back(n.y, mLevels[l].spacing);
  }
  constexpr int L = OddExtension::kLanes;
#pragma omp parallel
  {
    std::vector<double> p2;
    std::vector<std::vector<float>> ax(levels);  // this slice's x-filtered rows, per spacing
    for (size_t l = 0; l < levels; ++l) ax[l].resize(size_t(mLevels[l].count.x) * n.y);
    const float* lines[L];
    std::vector<float> rowValues(size_t(L) * size_t(n.x));  // this group's rows as float
#pragma omp for schedule(dynamic, 1)
    for (int z = 0; z < n.z; ++z) {
      for (int first = 0; first < n.y; first += L) {
        const int count = std::min(L, n.y - first);
        for (int r = 0; r < count; ++r) {
          float* row = &rowValues[size_t(r) * size_t(n.x)];
          volume.readRow(0, first + r, z, n.x, row);
          lines[r] = row;
        }
        rows.secondPrefixSums(lines, count, 1, &p2);
        for (int r = 0; r < count; ++r)
          for (size_t l = 0; l < levels; ++l) {
            const int s = mLevels[l].spacing, cx = mLevels[l].count.x;
            for (int j = 0; j < cx; ++j) ax[l][size_t(first + r) * cx + j] = rows.tentAt(p2, r, knotPosition(j, s, n.x), s);
          }
      }
      for (size_t l = 0; l < levels; ++l) {
        const int s = mLevels[l].spacing;
        const glm::ivec3 c = mLevels[l].count;
        for (int first = 0; first < c.x; first += L) {
          const int count = std::min(L, c.x - first);
          for (int r = 0; r < count; ++r) lines[r] = &ax[l][size_t(first + r)];
          columns[l].secondPrefixSums(lines, count, c.x, &p2);
          for (int r = 0; r < count; ++r)
            for (int j = 0; j < c.y; ++j)
              ay[l][size_t(first + r) + size_t(c.x) * (j + size_t(c.y) * z)] = columns[l].tentAt(p2, r, knotPosition(j, s, n.y), s);
        }
      }
    }
  }
  for (size_t l = 0; l < levels; ++l) {
    Level& level = mLevels[l];
    const int s = level.spacing;
    const glm::ivec3 c = level.count;
    std::vector<float> values(size_t(c.x) * c.y * c.z);
    const ptrdiff_t plane = ptrdiff_t(c.x) * c.y;
    const OddExtension pillars(n.z, s);
#pragma omp parallel
    {
      std::vector<double> p2;
      const float* lines[L];
#pragma omp for schedule(static)
      for (int first = 0; first < c.x * c.y; first += L) {
        const int count = std::min(L, c.x * c.y - first);
        for (int r = 0; r < count; ++r) lines[r] = &ay[l][size_t(first + r)];
        pillars.secondPrefixSums(lines, count, plane, &p2);
        for (int r = 0; r < count; ++r)
          for (int j = 0; j < c.z; ++j) values[size_t(first + r) + size_t(plane) * j] = pillars.tentAt(p2, r, knotPosition(j, s, n.z), s);
      }
    }
    std::vector<float>().swap(ay[l]);
    // Stored in 16 bits over the level's range: half the memory, and the knots a brick shows and
    // the nodal errors are computed from are the stored ones, so nothing is approximated twice.
    const auto [lo, hi] = std::minmax_element(values.begin(), values.end());
    level.offset = *lo;
    level.scale = *hi > *lo ? (*hi - *lo) / 65535.0f : 0.0f;
    level.codes.resize(values.size());
    for (size_t i = 0; i < values.size(); ++i)
      level.codes[i] = level.scale > 0.0f ? uint16_t(std::min(65535.0f, (values[i] - level.offset) / level.scale + 0.5f)) : 0;
  }
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
