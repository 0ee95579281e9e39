#include "render/cut_plane.h"

#include <gtest/gtest.h>

#include <glm/glm.hpp>

namespace hyb {
namespace {

TEST(CutPlane, KeptSideFacesAwayFromTheEye) {
  Camera cam;
  cam.eye = glm::dvec3(0, 0, 10);
  cam.center = glm::dvec3(0, 0, 0);
  cam.up = glm::dvec3(0, 1, 0);
  for (double sign : {1.0, -1.0}) {
    const CutPlane cut{glm::dvec3(0, 0, 2), glm::dvec3(0, 0, 3 * sign)};  // any length, either way
    const glm::dvec4 k = cut.keptSide(cam);
    EXPECT_NEAR(glm::length(glm::dvec3(k)), 1.0, 1e-12);
    EXPECT_LT(glm::dot(glm::dvec3(k), cam.eye) + k.w, 0.0);                      // the eye's side is removed
    EXPECT_NEAR(glm::dot(glm::dvec3(k), glm::dvec3(5, 7, 2)) + k.w, 0.0, 1e-12);  // the plane itself
  }
  cam.ortho = true;
  const glm::dvec4 k = CutPlane{glm::dvec3(0), glm::dvec3(1, 0, 1)}.keptSide(cam);
  EXPECT_GT(glm::dot(glm::dvec3(k), cam.forward()), 0.0);
}

}  // namespace
}  // namespace hyb
