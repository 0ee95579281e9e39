#include "surface/discrete_plane.h"

#include <numeric>

namespace hyb {

int orientationOf(const glm::ivec3& n, int* sign) {
  const int g = std::gcd(std::gcd(std::abs(n.x), std::abs(n.y)), std::abs(n.z));
  if (g == 0) return -1;
  const glm::ivec3 u = n / g;
  for (int o = 0; o < kOrientationCount; ++o) {
    if (u == orientationNormal(o)) return *sign = 1, o;
    if (u == -orientationNormal(o)) return *sign = -1, o;
  }
  return -1;
}

}  // namespace hyb
