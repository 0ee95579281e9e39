#include "volume/patient_frame.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>

#include "volume/core/error.h"

namespace hyb {
namespace {

using ::testing::HasSubstr;

TEST(PatientFrame, CodesNameWhereEachAxisPoints) {
  EXPECT_EQ(orientationCode(glm::dmat3(1.0)), "LPS");
  const glm::dmat3 ras(glm::dvec3(-1, 0, 0), glm::dvec3(0, -1, 0), glm::dvec3(0, 0, 1));
  EXPECT_EQ(orientationCode(ras), "RAS");
  // i towards inferior, j towards the left, k towards anterior.
  const glm::dmat3 ila(glm::dvec3(0, 0, -1), glm::dvec3(1, 0, 0), glm::dvec3(0, -1, 0));
  EXPECT_EQ(orientationCode(ila), "ILA");
  glm::dmat3 parsed;
  ASSERT_TRUE(directionFromCode("ila", &parsed));
  EXPECT_EQ(parsed, ila);
  ASSERT_TRUE(directionFromCode("RAS", &parsed));
  EXPECT_EQ(parsed, ras);
  EXPECT_FALSE(directionFromCode("LLS", &parsed));  // two axes along one patient axis
  EXPECT_FALSE(directionFromCode("LPX", &parsed));
  EXPECT_FALSE(directionFromCode("LP", &parsed));
  // Ten degrees about z: oblique, nearest LPS.
  const double a = glm::radians(10.0);
  const glm::dmat3 tilted(glm::dvec3(std::cos(a), std::sin(a), 0), glm::dvec3(-std::sin(a), std::cos(a), 0), glm::dvec3(0, 0, 1));
  EXPECT_EQ(orientationCode(tilted), "oblique (nearest LPS)");
}

TEST(PatientFrame, MapsGridToPatientRigidly) {
  const glm::dmat3 las(glm::dvec3(1, 0, 0), glm::dvec3(0, -1, 0), glm::dvec3(0, 0, 1));
  const PatientFrame f = makePatientFrame(las, glm::dvec3(10, 20, -30), "test");
  EXPECT_TRUE(f.mirrored());
  EXPECT_TRUE(f.axisAligned());
  EXPECT_EQ(f.toPatient(glm::dvec3(1, 2, 3)), glm::dvec3(11, 18, -27));
  EXPECT_EQ(f.toGrid(glm::dvec3(11, 18, -27)), glm::dvec3(1, 2, 3));
  EXPECT_EQ(f.vectorToGrid(glm::dvec3(0, 1, 0)), glm::dvec3(0, -1, 0));
  EXPECT_FALSE(makePatientFrame(glm::dmat3(1.0), glm::dvec3(0.0), "test").mirrored());
}

TEST(PatientFrame, CosinesPrintedToFewDigitsAreMadeOrthonormal) {
  // Thirty degrees about x, cosines rounded to five digits as headers print them.
  const glm::dmat3 rounded(glm::dvec3(1, 0, 0), glm::dvec3(0, 0.86603, 0.5), glm::dvec3(0, -0.5, 0.86603));
  const PatientFrame f = makePatientFrame(rounded, glm::dvec3(0.0), "test");
  const glm::dmat3 g = glm::transpose(f.direction) * f.direction;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(g[c][r], r == c ? 1.0 : 0.0, 1e-14);
  EXPECT_NEAR(f.direction[1].y, std::cos(glm::radians(30.0)), 1e-5);
  EXPECT_FALSE(f.axisAligned());
}

TEST(PatientFrame, ShearedOrDegenerateAxesAreRefusedNamingTheSource) {
  const glm::dmat3 sheared(glm::dvec3(1, 0, 0), glm::dvec3(0, 1, 0), glm::dvec3(0, 0.2, 1));  // 11 degrees of gantry tilt
  try {
    makePatientFrame(sheared, glm::dvec3(0.0), "scan.nrrd");
    ADD_FAILURE() << "a sheared grid was accepted";
  } catch (const ValueError& e) {
    EXPECT_THAT(e.what(), HasSubstr("scan.nrrd"));
    EXPECT_THAT(e.what(), HasSubstr("not orthogonal"));
    EXPECT_THAT(e.what(), HasSubstr("78.69"));  // acos(0.2 / |(0, 0.2, 1)|) in degrees
  }
  EXPECT_THROW(makePatientFrame(glm::dmat3(glm::dvec3(1, 0, 0), glm::dvec3(0.0), glm::dvec3(0, 0, 1)), glm::dvec3(0.0), "z"), ValueError);
  EXPECT_THROW(makePatientFrame(glm::dmat3(1.0), glm::dvec3(NAN, 0, 0), "nan"), ValueError);
}

}  // namespace
}  // namespace hyb
