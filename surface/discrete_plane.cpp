#include "surface/discrete_plane.h"

#include <array>
#include <numeric>

namespace hyb {

namespace {
constexpr std::array<glm::ivec3, kOrientationCount> kNormals = {{
    {1, 0, 0}, {0, 1, 0}, {0, 0, 1},                                  // axis
    {1, 1, 0}, {1, -1, 0}, {1, 0, 1}, {1, 0, -1}, {0, 1, 1}, {0, 1, -1},  // face diagonals
    {1, 1, 1}, {1, 1, -1}, {1, -1, 1}, {1, -1, -1}}};                  // body diagonals
}  // namespace

const glm::ivec3& orientationNormal(int o) { return kNormals[size_t(o)]; }

int orientationOf(const glm::ivec3& n, int* sign) {
  const int g = std::gcd(std::gcd(std::abs(n.x), std::abs(n.y)), std::abs(n.z));
  if (g == 0) return -1;
  const glm::ivec3 u = n / g;
  for (int o = 0; o < kOrientationCount; ++o) {
    if (u == kNormals[size_t(o)]) return *sign = 1, o;
    if (u == -kNormals[size_t(o)]) return *sign = -1, o;
  }
  return -1;
}

}  // namespace hyb
