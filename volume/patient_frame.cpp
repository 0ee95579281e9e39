#include "volume/patient_frame.h"

#include <algorithm>
#include <cmath>

#include "volume/core/error.h"

namespace hyb {

namespace {

// The letter of the LPS axis @p a (0..2) at sign @p positive.
char axisLetter(int a, bool positive) {
  static constexpr char kPositive[] = "LPS", kNegative[] = "RAI";
  return positive ? kPositive[a] : kNegative[a];
}

// Off-axis tolerance of an axis-aligned frame's cosines.
constexpr double kAxisTolerance = 1e-4;

}  // namespace

bool PatientFrame::axisAligned() const {
  for (int c = 0; c < 3; ++c) {
    const glm::dvec3 a = glm::abs(direction[c]);
    if (std::max({a.x, a.y, a.z}) < 1.0 - kAxisTolerance) return false;
  }
  return true;
}

std::string orientationCode(const glm::dmat3& direction) {
  std::string code;
  bool oblique = false;
  for (int c = 0; c < 3; ++c) {
    const glm::dvec3 d = direction[c];
    const glm::dvec3 a = glm::abs(d);
    const int axis = a.x >= a.y && a.x >= a.z ? 0 : (a.y >= a.z ? 1 : 2);
    oblique = oblique || a[axis] < 1.0 - kAxisTolerance;
    code += axisLetter(axis, d[axis] > 0.0);
  }
  return oblique ? "oblique (nearest " + code + ")" : code;
}

bool directionFromCode(const std::string& code, glm::dmat3* direction) {
  if (code.size() != 3) return false;
  glm::dmat3 d(0.0);
  bool used[3] = {false, false, false};
  for (int c = 0; c < 3; ++c) {
    const char letter = char(std::toupper(static_cast<unsigned char>(code[size_t(c)])));
    int axis = -1;
    double sign = 0;
    for (int a = 0; a < 3; ++a) {
      if (letter == axisLetter(a, true)) axis = a, sign = 1;
      if (letter == axisLetter(a, false)) axis = a, sign = -1;
    }
    if (axis < 0 || used[axis]) return false;
    used[axis] = true;
    d[c][axis] = sign;
  }
  *direction = d;
  return true;
}

PatientFrame makePatientFrame(const glm::dmat3& direction, const glm::dvec3& origin, const std::string& what) {
  for (int a = 0; a < 3; ++a)
    if (!std::isfinite(origin[a])) HYB_THROW(ValueError, what, ": origin ", origin.x, ",", origin.y, ",", origin.z, " is not finite");
  glm::dmat3 d = direction;
  for (int c = 0; c < 3; ++c) {
    const double len = glm::length(d[c]);
    if (!std::isfinite(len) || len == 0.0)
      HYB_THROW(ValueError, what, ": direction of axis ", c, " (", d[c].x, ",", d[c].y, ",", d[c].z, ") is zero or not finite");
    d[c] /= len;
  }
  double worst = 0.0;
  for (int c = 0; c < 3; ++c) worst = std::max(worst, std::abs(glm::dot(d[c], d[(c + 1) % 3])));
  if (worst > 1e-3)
    HYB_THROW(ValueError, what, ": grid axes are not orthogonal (two meet at ", glm::degrees(std::acos(std::min(1.0, worst))),
              " degrees instead of 90: a sheared grid, e.g. a gantry tilt); expected orthogonal direction cosines");
  // Polar decomposition by Newton's iteration (X <- (X + X^-T) / 2): the nearest orthonormal
  // matrix, with the same handedness, in a few steps from cosines this close.
  for (int it = 0; it < 8; ++it) d = 0.5 * (d + glm::transpose(glm::inverse(d)));
  PatientFrame f;
  f.direction = d;
  f.origin = origin;
  return f;
}

}  // namespace hyb
