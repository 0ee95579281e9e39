#include "render/camera.h"

#include <gtest/gtest.h>

namespace hyb {
namespace {

TEST(Camera, SeesBoxCullsOnlyBoxesOutsideTheFrustum) {
  Camera cam;  // perspective at (0, 0, 10) looking down -z, 30 degrees, square
  cam.eye = glm::dvec3(0, 0, 10);
  cam.center = glm::dvec3(0, 0, 0);
  cam.up = glm::dvec3(0, 1, 0);
  EXPECT_TRUE(cam.seesBox(glm::dvec3(-1), glm::dvec3(1)));                       // in front, centred
  EXPECT_FALSE(cam.seesBox(glm::dvec3(-1, -1, 11), glm::dvec3(1, 1, 12)));       // behind the eye
  EXPECT_FALSE(cam.seesBox(glm::dvec3(6, -1, -1), glm::dvec3(8, 1, 1)));         // right of the frustum (tan 15° · 11 ≈ 2.9)
  EXPECT_TRUE(cam.seesBox(glm::dvec3(2, -1, -1), glm::dvec3(8, 1, 1)));          // straddling its side
  EXPECT_TRUE(cam.seesBox(glm::dvec3(-50, -50, -50), glm::dvec3(50, 50, 50)));   // holding the eye
  cam.ortho = true;
  cam.orthoHeight = 4.0;  // |x|, |y| <= 2
  EXPECT_FALSE(cam.seesBox(glm::dvec3(2.5, -1, -1), glm::dvec3(3, 1, 1)));
  EXPECT_TRUE(cam.seesBox(glm::dvec3(-1, -1, 11), glm::dvec3(1, 1, 12)));  // no near side for ortho
}

}  // namespace
}  // namespace hyb
