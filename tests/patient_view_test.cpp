// Patient space in the renderers: anatomical views, framing, and the same anatomy stored with any
// axis flip or permutation (or obliquely) rendering the same image, left on the correct side.
#include "render/patient_view.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <iomanip>
#include <set>
#include <sstream>
#include <tuple>

#include "cli_util.h"
#include "render/image.h"
#include "render/orientation_marker.h"
#include "test_util.h"

namespace hyb {
namespace {

using ::testing::HasSubstr;

// LPS axes.
const glm::dvec3 kL(1, 0, 0), kP(0, 1, 0), kS(0, 0, 1);

TEST(PatientView, AnteriorViewPutsThePatientsLeftOnTheImagesRight) {
  // The camera's right in each view, in the radiological conventions.
  struct Case {
    AnatomicalView view;
    glm::dvec3 right, up;
  };
  for (const Case& c : {Case{AnatomicalView::Anterior, kL, kS}, Case{AnatomicalView::Posterior, -kL, kS},
                        Case{AnatomicalView::Left, kP, kS}, Case{AnatomicalView::Right, -kP, kS},
                        Case{AnatomicalView::Superior, -kL, -kP}, Case{AnatomicalView::Inferior, kL, -kP}}) {
    const ViewDirection d = viewDirection(c.view);
    Camera cam;
    cam.center = glm::dvec3(0.0);
    cam.eye = d.toEye * 100.0;
    cam.up = d.up;
    EXPECT_EQ(cam.right(), c.right) << int(c.view);
    EXPECT_EQ(cam.trueUp(), c.up) << int(c.view);
  }
  AnatomicalView v;
  EXPECT_TRUE(parseAnatomicalView("superior", &v));
  EXPECT_EQ(v, AnatomicalView::Superior);
  EXPECT_FALSE(parseAnatomicalView("front", &v));
}

TEST(PatientView, OrbitsAreRelativeToTheAnteriorView) {
  auto near = [](const glm::dvec3& a, const glm::dvec3& b) { return glm::length(a - b) < 1e-12; };
  EXPECT_TRUE(near(orbitDirection(0, 0).toEye, viewDirection(AnatomicalView::Anterior).toEye));
  EXPECT_TRUE(near(orbitDirection(90, 0).toEye, viewDirection(AnatomicalView::Left).toEye));
  EXPECT_TRUE(near(orbitDirection(180, 0).toEye, viewDirection(AnatomicalView::Posterior).toEye));
  EXPECT_TRUE(near(orbitDirection(270, 0).toEye, viewDirection(AnatomicalView::Right).toEye));
  EXPECT_TRUE(near(orbitDirection(0, 90).toEye, kS));
  EXPECT_TRUE(near(orbitDirection(30, 45).toEye, glm::dvec3(std::sin(glm::radians(30.0)) * std::sqrt(0.5),
                                                            -std::cos(glm::radians(30.0)) * std::sqrt(0.5), std::sqrt(0.5))));
  // Over a pole up turns continuously: just below it the image's up is (nearly) posterior.
  EXPECT_TRUE(near(orbitDirection(0, 88.5).up, kS));
  EXPECT_TRUE(near(orbitDirection(0, 89.5).up, kP));
}

TEST(PatientView, FitFramesEveryPointWithTheMargin) {
  // A box 200 x 100 x 50 mm off the origin, seen from anterior and at an angle.
  std::vector<glm::dvec3> points;
  for (int c = 0; c < 8; ++c) points.push_back(glm::dvec3(30 + 200 * (c & 1), -40 + 100 * ((c >> 1) & 1), 10 + 50 * ((c >> 2) & 1)));
  for (const bool ortho : {false, true})
    for (const ViewDirection& d : {viewDirection(AnatomicalView::Anterior), orbitDirection(35, 20)}) {
      const Camera cam = fitCamera(points, d, {30.0, ortho, 320, 200}, 0.05);
      double maxX = 0, maxY = 0, minX = 1e9, minY = 1e9;
      for (const glm::dvec3& p : points) {
        // The point's image position, from the camera's own rays: project with its frame.
        const glm::dvec3 q = p - cam.eye, f = cam.forward(), r = cam.right(), u = cam.trueUp();
        const double z = glm::dot(q, f);
        ASSERT_GT(z, 0.0);
        const double sx = ortho ? glm::dot(q, r) / (0.5 * cam.orthoHeight * 1.6) : glm::dot(q, r) / z / (std::tan(glm::radians(15.0)) * 1.6);
        const double sy = ortho ? glm::dot(q, u) / (0.5 * cam.orthoHeight) : glm::dot(q, u) / z / std::tan(glm::radians(15.0));
        maxX = std::max(maxX, sx), minX = std::min(minX, sx), maxY = std::max(maxY, sy), minY = std::min(minY, sy);
      }
      // Inside the image with 5 % to spare on the tighter side, and centred.
      EXPECT_LE(std::max(maxX, maxY), 0.95 + 1e-9);
      EXPECT_GE(std::min(minX, minY), -0.95 - 1e-9);
      EXPECT_NEAR(std::max(maxX - minX, maxY - minY), 1.9, 1e-3) << ortho;
      EXPECT_NEAR(maxX + minX, 0.0, 1e-3) << ortho;
      EXPECT_NEAR(maxY + minY, 0.0, 1e-3) << ortho;
    }
}

TEST(PatientView, ZoomMagnifiesAboutTheCentre) {
  Camera c;
  c.fovDeg = 30.0;
  zoomCamera(&c, 2.0);
  EXPECT_NEAR(std::tan(glm::radians(c.fovDeg) * 0.5), 0.5 * std::tan(glm::radians(15.0)), 1e-12);
  c.ortho = true;
  c.orthoHeight = 100;
  zoomCamera(&c, 4.0);
  EXPECT_EQ(c.orthoHeight, 25.0);
}

TEST(PatientView, GridCameraOfALeftHandedGridIsMirrored) {
  const glm::dmat3 las(kL, -kP, kS);
  const PatientFrame frame = makePatientFrame(las, glm::dvec3(5, 6, 7), "t");
  Camera patient;
  patient.eye = glm::dvec3(0, -300, 0);
  patient.center = glm::dvec3(0.0);
  patient.up = kS;
  const Camera grid = toGridCamera(patient, frame);
  EXPECT_TRUE(grid.mirrored);
  // The image's right is the same physical direction in both frames.
  EXPECT_EQ(frame.vectorToPatient(grid.right()), patient.right());
  EXPECT_EQ(frame.vectorToPatient(grid.trueUp()), patient.trueUp());
  // A ray through a pixel is the same physical ray.
  glm::dvec3 o1, d1, o2, d2;
  patient.ray(100.5, 20.5, &o1, &d1);
  grid.ray(100.5, 20.5, &o2, &d2);
  EXPECT_LT(glm::length(frame.toPatient(o2) - o1), 1e-9);
  EXPECT_LT(glm::length(frame.vectorToPatient(d2) - d1), 1e-12);
}

// ---------------------------------------------------------------------------------------------
// The same anatomy stored in different grids. A head-like phantom in patient space (LPS mm): a
// ball of value 1, a marker blob of value 2 in front of its centre and one of value −2 on the
// patient's left (its edges cross no other material's values).

double phantom(const glm::dvec3& p) {
  auto bump = [](double d, double r) { return std::clamp(1.0 - (d - r) / 1.5, 0.0, 1.0); };  // smooth edge 1.5 mm wide
  return bump(glm::length(p), 12.0) + bump(glm::length(p + 10.0 * kP), 3.0) - 3.0 * bump(glm::length(p - 10.0 * kL), 3.5);
}

// A stored copy: index (a, b, c) of a grid with these dims, spacing, axes and origin.
struct Copy {
  std::string name;
  glm::ivec3 dims;
  glm::dvec3 spacing;
  glm::dmat3 direction;
  glm::dvec3 origin;
};

// The base lattice: LPS-aligned, 34 x 30 x 28 voxels of 1 x 1.2 x 1.1 mm centred on the phantom.
const glm::ivec3 kN(34, 30, 28);
const glm::dvec3 kSp(1.0, 1.2, 1.1);
const glm::dvec3 kO = -0.5 * glm::dvec3(kN - 1) * kSp;
glm::dvec3 lattice(int i, int j, int k) { return kO + glm::dvec3(i, j, k) * kSp; }

// The lattice stored RAS (x and y flipped), LAS (y flipped) and permuted (file axes k, i, j).
std::vector<Copy> copies() {
  return {{"LPS", kN, kSp, glm::dmat3(kL, kP, kS), lattice(0, 0, 0)},
          {"RAS", kN, kSp, glm::dmat3(-kL, -kP, kS), lattice(kN.x - 1, kN.y - 1, 0)},
          {"LAS", kN, kSp, glm::dmat3(kL, -kP, kS), lattice(0, kN.y - 1, 0)},
          {"SLP", {kN.z, kN.x, kN.y}, {kSp.z, kSp.x, kSp.y}, glm::dmat3(kS, kL, kP), lattice(0, 0, 0)}};
}

std::string vec(const glm::dvec3& v) {
  std::ostringstream s;
  s << std::setprecision(17) << "(" << v.x << "," << v.y << "," << v.z << ")";
  return s.str();
}

// Writes @p copy of @p field as a NRRD (RAS copies in a right-anterior-superior space, the others LPS).
std::string writeCopy(const test::TempDir& dir, const Copy& copy, const std::function<double(const glm::dvec3&)>& field) {
  std::vector<float> samples;
  for (int c = 0; c < copy.dims.z; ++c)
    for (int b = 0; b < copy.dims.y; ++b)
      for (int a = 0; a < copy.dims.x; ++a)
        samples.push_back(float(field(copy.origin + copy.direction * (glm::dvec3(a, b, c) * copy.spacing))));
  const bool ras = copy.name == "RAS";
  const glm::dvec3 sign = ras ? glm::dvec3(-1, -1, 1) : glm::dvec3(1.0);
  std::string header = "NRRD0005\ntype: float\ndimension: 3\nsizes: " + std::to_string(copy.dims.x) + " " + std::to_string(copy.dims.y) + " " +
                       std::to_string(copy.dims.z) + "\nspace: " + (ras ? "right-anterior-superior" : "left-posterior-superior") + "\nspace directions:";
  for (int a = 0; a < 3; ++a) header.append(" ").append(vec(copy.direction[a] * copy.spacing[a] * sign));
  header.append("\nspace origin: ").append(vec(copy.origin * sign)).append("\nendian: little\nencoding: raw\n\n");
  const std::vector<uint8_t> data = test::toBytes(samples);
  std::vector<uint8_t> bytes(header.begin(), header.end());
  bytes.insert(bytes.end(), data.begin(), data.end());
  const std::string path = dir.file(copy.name + ".nrrd");
  test::writeBytes(path, bytes);
  return path;
}

// Ball grey, the front blob green, the left blob red; opacity per mm.
void writeTf(const std::string& path) {
  test::writeText(path, "-3 1 0.1 0.1 0.9\n-1.5 1 0.1 0.1 0.9\n-1.2 0 0 0 0\n0.2 0.5 0.5 0.5 0\n0.5 0.6 0.6 0.6 0.08\n1.2 0.6 0.6 0.6 0.08\n"
                        "1.6 0.1 0.9 0.1 0.6\n2.4 0.1 0.9 0.1 0.6\n");
}

std::vector<uint8_t> render(const std::string& volume, std::vector<std::string> args, int* w, int* h) {
  test::TempDir out;
  std::vector<std::string> cmd = {"render", volume, "-o", out.file("i.png")};
  cmd.insert(cmd.end(), args.begin(), args.end());
  const test::CliRun r = test::run(cmd);
  EXPECT_EQ(r.status, 0) << r.err;
  if (r.status != 0) return {};
  return readPng(out.file("i.png"), w, h);
}

// The mean x of the red (left blob) pixels, as a fraction of the width.
double redCentroid(const std::vector<uint8_t>& rgba, int w) {
  if (rgba.empty() || w <= 0) return -1.0;
  double sum = 0, n = 0;
  for (size_t i = 0; i < rgba.size(); i += 4)
    if (rgba[i] > 60 && rgba[i] > rgba[i + 1] + 40) {  // red: the left blob, seen through the ball's grey
      sum += double((i / 4) % size_t(w));
      ++n;
    }
  EXPECT_GT(n, 10.0);
  return (sum / std::max(n, 1.0) + 0.5) / w;
}

TEST(PatientView, TheSameAnatomyInAnyStoredOrientationRendersTheSameImage) {
  test::TempDir dir;
  writeTf(dir.file("tf.txt"));
  std::vector<std::string> paths;
  for (const Copy& c : copies()) paths.push_back(writeCopy(dir, c, phantom));
  // A camera in front, a little to the left and above (patient mm).
  const std::vector<std::string> camera = {"--eye", "40,-120,30", "--center", "0,0,0", "--up", "0,0,1", "--size", "64x64", "--tf", dir.file("tf.txt")};
  for (const char* renderer : {"raycast", "slices"}) {
    std::vector<std::string> args = camera;
    args.insert(args.end(), {"--renderer", renderer});
    int w = 0, h = 0;
    const std::vector<uint8_t> base = render(paths[0], args, &w, &h);
    ASSERT_FALSE(base.empty());
    for (size_t c = 1; c < paths.size(); ++c) {
      const std::vector<uint8_t> other = render(paths[c], args, &w, &h);
      ASSERT_EQ(other.size(), base.size());
      // The reference samples the same field at the same points: only float rounding differs.
      // The slices' bricks and their 8-bit quantisation depend on the grid.
      EXPECT_GE(psnr(base, other), std::string(renderer) == "raycast" ? 50.0 : 40.0) << renderer << " " << copies()[c].name;
    }
  }
}

// The default camera frames what is visible in the patient, so copies of the anatomy stored
// flipped or with their axes permuted get the same camera for every view (an octree's leaves
// follow the storage order: framing their corners moved the camera by a millimetre).
TEST(PatientView, TheDefaultCameraDoesNotDependOnTheStorageOrder) {
  const TransferFunction tf({{0.3f, {1, 1, 1}, 0.0f}, {0.5f, {1, 1, 1}, 0.1f}, {3.0f, {1, 1, 1}, 0.1f}}, "ball");
  const TransferFunction clear({{0.0f, {1, 1, 1}, 0.0f}, {1.0f, {1, 1, 1}, 0.0f}}, "clear");  // the isosurface alone
  std::vector<std::vector<Camera>> cameras;  // per copy: the six views framing the transfer function's, then the isosurface's
  for (const Copy& c : copies()) {
    Volume v = test::makeVolume(c.dims, [&](int a, int b, int k) { return phantom(c.origin + c.direction * (glm::dvec3(a, b, k) * c.spacing)); }, c.spacing);
    v.setFrame(makePatientFrame(c.direction, c.origin, c.name));
    const VolumeOctree octree = VolumeOctree::build(v);
    const std::vector<glm::dvec3> byTf = visiblePoints(v, octree, tf), byIso = visiblePoints(v, octree, clear, 1.5f);
    ASSERT_FALSE(byTf.empty());
    ASSERT_FALSE(byIso.empty());
    cameras.emplace_back();
    for (const std::vector<glm::dvec3>* points : {&byTf, &byIso})
      for (int view = 0; view < 6; ++view) cameras.back().push_back(fitCamera(*points, viewDirection(AnatomicalView(view)), {30.0, false, 64, 48}));
  }
  for (size_t c = 1; c < cameras.size(); ++c)
    for (size_t k = 0; k < cameras[0].size(); ++k) {
      const Camera &a = cameras[0][k], &b = cameras[c][k];
      EXPECT_LT(glm::length(a.eye - b.eye), 1e-6) << copies()[c].name << " camera " << k << ": " << vec(a.eye) << " vs " << vec(b.eye);
      EXPECT_LT(glm::length(a.center - b.center), 1e-6) << copies()[c].name << " camera " << k;
      EXPECT_LT(glm::length(a.up - b.up), 1e-9) << copies()[c].name << " camera " << k;
    }
}

// visiblePoints keeps the vertices of the visible cells' hull plane by plane, not every row's end
// corners: the default camera is the one every visible corner frames (each view, perspective and
// orthographic), from far fewer points, each a corner of a visible cell.
TEST(PatientView, VisiblePointsCarryTheHullOfEveryVisibleCorner) {
  const TransferFunction tf({{0.3f, {1, 1, 1}, 0.0f}, {0.5f, {1, 1, 1}, 0.1f}, {3.0f, {1, 1, 1}, 0.1f}}, "ball");
  const Copy c = copies()[3];  // permuted and oblique to the grid's planes
  Volume v = test::makeVolume(c.dims, [&](int a, int b, int k) { return phantom(c.origin + c.direction * (glm::dvec3(a, b, k) * c.spacing)); }, c.spacing);
  v.setFrame(makePatientFrame(c.direction, c.origin, c.name));
  const std::vector<glm::dvec3> hull = visiblePoints(v, VolumeOctree::build(v), tf);
  // Every corner of every cell whose range the transfer function makes visible.
  std::vector<glm::dvec3> corners;
  std::set<std::tuple<double, double, double>> cornerSet;
  const glm::ivec3 d = v.dims();
  for (int k = 0; k + 1 < d.z; ++k)
    for (int j = 0; j + 1 < d.y; ++j)
      for (int i = 0; i + 1 < d.x; ++i) {
        float lo = 1e30f, hi = -1e30f;
        for (int q = 0; q < 8; ++q) {
          const float x = v.at(i + (q & 1), j + (q >> 1 & 1), k + (q >> 2 & 1));
          lo = std::min(lo, x);
          hi = std::max(hi, x);
        }
        if (tf.maxAlpha(lo, hi) <= 0.0f) continue;
        for (int q = 0; q < 8; ++q) {
          const glm::dvec3 p = v.frame().toPatient(glm::dvec3(i + (q & 1), j + (q >> 1 & 1), k + (q >> 2 & 1)) * v.spacing());
          if (cornerSet.insert({p.x, p.y, p.z}).second) corners.push_back(p);
        }
      }
  ASSERT_GT(corners.size(), 1000u);
  EXPECT_LT(hull.size() * 4, corners.size());
  for (const glm::dvec3& p : hull) EXPECT_TRUE(cornerSet.contains({p.x, p.y, p.z})) << vec(p);
  for (const bool ortho : {false, true})
    for (int view = 0; view < 6; ++view)
      for (const double azimuth : {0.0, 37.0}) {
        ViewDirection dir = viewDirection(AnatomicalView(view));
        if (azimuth != 0.0) dir = orbitDirection(azimuth, 21.0);
        const Camera a = fitCamera(hull, dir, {30.0, ortho, 64, 48}), b = fitCamera(corners, dir, {30.0, ortho, 64, 48});
        EXPECT_LT(glm::length(a.eye - b.eye), 1e-9) << view << " " << ortho << ": " << vec(a.eye) << " vs " << vec(b.eye);
        EXPECT_LT(glm::length(a.center - b.center), 1e-9) << view << " " << ortho;
        EXPECT_NEAR(a.orthoHeight, b.orthoHeight, 1e-9);
      }
}

TEST(PatientView, TheLeftMarkerIsOnTheImagesRightFromTheFrontAndLeftFromBehind) {
  test::TempDir dir;
  writeTf(dir.file("tf.txt"));
  for (const Copy& c : copies()) {
    const std::string path = writeCopy(dir, c, phantom);
    for (const char* renderer : {"raycast", "slices"}) {
      int w = 0, h = 0;
      const std::vector<std::string> look = {"--size", "64x64", "--tf", dir.file("tf.txt"), "--renderer", renderer};
      std::vector<std::string> front = look, back = look;
      front.insert(front.end(), {"--view", "anterior"});
      back.insert(back.end(), {"--view", "posterior"});
      const std::vector<uint8_t> fromFront = render(path, front, &w, &h);
      EXPECT_GT(redCentroid(fromFront, w), 0.6) << c.name << " " << renderer;
      const std::vector<uint8_t> fromBehind = render(path, back, &w, &h);
      EXPECT_LT(redCentroid(fromBehind, w), 0.4) << c.name << " " << renderer;
    }
  }
}

TEST(PatientView, ObliqueGridsRenderTheirAnatomyInPlace) {
  // The phantom sampled on a grid rotated 25 degrees about x and 40 about z, against the
  // axis-aligned one: the images differ by the two grids' interpolation only.
  test::TempDir dir;
  writeTf(dir.file("tf.txt"));
  const double a = glm::radians(25.0), b = glm::radians(40.0);
  const glm::dmat3 rx(glm::dvec3(1, 0, 0), glm::dvec3(0, std::cos(a), std::sin(a)), glm::dvec3(0, -std::sin(a), std::cos(a)));
  const glm::dmat3 rz(glm::dvec3(std::cos(b), std::sin(b), 0), glm::dvec3(-std::sin(b), std::cos(b), 0), glm::dvec3(0, 0, 1));
  const glm::dmat3 r = rx * rz;
  const glm::ivec3 n(40, 40, 40);
  const glm::dvec3 sp(0.9);
  const Copy oblique{"oblique", n, sp, r, -(r * (0.5 * glm::dvec3(n - 1) * sp))};
  const std::string straight = writeCopy(dir, copies()[0], phantom), tilted = writeCopy(dir, oblique, phantom);
  const std::vector<std::string> camera = {"--eye", "40,-120,30", "--center", "0,0,0", "--up", "0,0,1", "--size", "64x64", "--tf", dir.file("tf.txt")};
  for (const char* renderer : {"raycast", "slices"}) {
    std::vector<std::string> args = camera;
    args.insert(args.end(), {"--renderer", renderer});
    int w = 0, h = 0;
    const std::vector<uint8_t> x = render(straight, args, &w, &h), y = render(tilted, args, &w, &h);
    EXPECT_GE(psnr(x, y), 30.0) << renderer;
    EXPECT_NEAR(redCentroid(x, w), redCentroid(y, w), 1.5 / w) << renderer;
  }
}

TEST(PatientView, CutAtAPatientCoordinateShowsTheVoxelItNames) {
  // Values 10 · (the lattice's z index): a cut across z at the patient z of index 17 shows 170,
  // in every stored orientation, through both renderers.
  test::TempDir dir;
  test::writeText(dir.file("ramp.txt"), "0 0 0 0 1\n300 1 1 1 1\n");
  const int k = 17;
  const double z = lattice(0, 0, k).z;
  for (const Copy& c : copies()) {
    const std::string path = writeCopy(dir, c, [](const glm::dvec3& p) { return 10.0 * std::round((p.z - kO.z) / kSp.z); });
    for (const char* renderer : {"raycast", "slices"}) {
      int w = 0, h = 0;
      std::ostringstream cut;
      cut << std::setprecision(17) << "0,0," << z << ",0,0,1";
      const std::vector<uint8_t> img = render(path, {"--tf", dir.file("ramp.txt"), "--cut", cut.str(), "--view", "superior", "--size", "16x16",
                                                     "--renderer", renderer, "--shading", "off"}, &w, &h);
      ASSERT_FALSE(img.empty());
      const size_t centre = (size_t(h / 2) * size_t(w) + size_t(w / 2)) * 4;
      EXPECT_NEAR(img[centre], 170.0 / 300.0 * 255.0, 1.5) << c.name << " " << renderer;
    }
  }
}

TEST(PatientView, DefaultFramingFillsTheImageWithWhatIsVisible) {
  // The phantom in a volume twice its size (transparent around it): the frame fits the visible
  // part, not the box (whose bounding sphere would leave the ball a quarter of the height).
  test::TempDir dir;
  writeTf(dir.file("tf.txt"));
  const std::string path = writeCopy(dir, {"big", glm::ivec3(64), glm::dvec3(1.0), glm::dmat3(1.0), glm::dvec3(-31.5)}, phantom);
  int w = 0, h = 0;
  const std::vector<uint8_t> img = render(path, {"--size", "64x64", "--tf", dir.file("tf.txt"), "--renderer", "raycast"}, &w, &h);
  int top = h, bottom = -1;
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      if (img[(size_t(y) * w + x) * 4 + 1] > 20) top = std::min(top, y), bottom = std::max(bottom, y);
  EXPECT_GE(bottom - top + 1, int(0.6 * h));
  EXPECT_LE(bottom - top + 1, h - 2);  // the margin
}

TEST(PatientView, MarkerLabelsFollowTheCamera) {
  Camera c;
  c.width = c.height = 256;
  const ViewDirection d = viewDirection(AnatomicalView::Anterior);
  c.center = glm::dvec3(0.0);
  c.eye = d.toEye * 500.0;
  c.up = d.up;
  const std::array<MarkerLabel, 6> labels = markerLabels(c);
  auto at = [&](char letter) { return std::find_if(labels.begin(), labels.end(), [&](const MarkerLabel& l) { return l.letter == letter; })->pixel; };
  EXPECT_GT(at('L').x, at('R').x);  // anterior view: the patient's left on the right
  EXPECT_LT(at('S').y, at('I').y);  // superior up
  EXPECT_NEAR(at('P').x, at('A').x, 1e-9);  // seen end on
  Image image(256, 256);
  drawOrientationMarker(c, &image);
  // Drawn in the lower-left corner only.
  double left = 0, right = 0;
  for (int y = 0; y < 256; ++y)
    for (int x = 0; x < 256; ++x) (x < 128 && y >= 128 ? left : right) += image.at(x, y).a;
  EXPECT_GT(left, 100.0);
  EXPECT_EQ(right, 0.0);
}

}  // namespace
}  // namespace hyb
