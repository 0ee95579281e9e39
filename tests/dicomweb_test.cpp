// DICOMweb against a real archive: Debian's Orthanc with its DICOMweb plugin, started on 127.0.0.1
// with a port and a storage folder of its own the first time a test needs it, and stopped when the
// tests end (a failed test too; were the process to die, the kernel ends Orthanc with it). Series
// written by tests/dicom_writer are uploaded, listed (QIDO-RS), read (WADO-RS) and compared with the
// same files read from a folder. Faults Orthanc does not make (a 5xx, a body cut short, a stall)
// come from a small fake archive in this file.
#include <arpa/inet.h>
#include <curl/curl.h>
#include <netinet/in.h>
#include <poll.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <set>
#include <algorithm>
#include <thread>

#include "cli_util.h"
#include "dicom_writer.h"
#include "render/image.h"
#include "test_util.h"
#include "volume/core/progress.h"
#include "volume/dicomweb.h"
#include "volume/plane_source.h"
#include "volume/plane_stack.h"
#include "volume/volume_io.h"

namespace hyb {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;
using ::testing::Not;
using test::DicomImage;
using test::DicomStudy;
using test::TempDir;

constexpr const char* kUser = "hyb";
constexpr const char* kPassword = "pacs-secret-1";

// A TCP port nobody listens on now (bound, read, released).
int freePort() {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  ::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a);
  socklen_t len = sizeof a;
  ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len);
  ::close(fd);
  return ntohs(a.sin_port);
}

// GET (or POST @p body to) @p url with the archive's credentials; the HTTP status.
long httpStatus(const std::string& url, const std::string* body = nullptr) {
  CURL* c = curl_easy_init();
  curl_easy_setopt(c, CURLOPT_URL, url.c_str());
  curl_easy_setopt(c, CURLOPT_USERNAME, kUser);
  curl_easy_setopt(c, CURLOPT_PASSWORD, kPassword);
  curl_easy_setopt(c, CURLOPT_TIMEOUT, 30L);
  curl_easy_setopt(c, CURLOPT_WRITEFUNCTION, +[](char*, size_t s, size_t n, void*) { return s * n; });
  if (body) {
    curl_easy_setopt(c, CURLOPT_POSTFIELDS, body->data());
    curl_easy_setopt(c, CURLOPT_POSTFIELDSIZE_LARGE, curl_off_t(body->size()));
  }
  long status = 0;
  if (curl_easy_perform(c) == CURLE_OK) curl_easy_getinfo(c, CURLINFO_RESPONSE_CODE, &status);
  curl_easy_cleanup(c);
  return status;
}

// Orthanc on 127.0.0.1, HTTP basic authentication required, DICOM networking off.
class Orthanc {
 public:
  Orthanc() : mPort(freePort()) {
    const char* candidates[] = {"/usr/sbin/Orthanc", "/usr/bin/Orthanc"};
    std::string exe;
    for (const char* c : candidates)
      if (fs::exists(c)) exe = c;
    if (exe.empty()) throw std::runtime_error("Orthanc is not installed (scripts/setup.sh installs orthanc and orthanc-dicomweb)");
    const std::string plugin = "/usr/share/orthanc/plugins/libOrthancDicomWeb.so";
    if (!fs::exists(plugin)) throw std::runtime_error(plugin + " missing (scripts/setup.sh installs orthanc-dicomweb)");
    fs::create_directories(mDir.path() / "storage");
    const std::string config = mDir.file("orthanc.json");
    std::ofstream(config) << "{ \"Name\": \"hyb-test\", \"HttpPort\": " << mPort << ", \"DicomServerEnabled\": false,\n"
                          << "  \"StorageDirectory\": \"" << mDir.file("storage") << "\", \"IndexDirectory\": \"" << mDir.file("storage") << "\",\n"
                          << "  \"RemoteAccessAllowed\": false, \"AuthenticationEnabled\": true, \"RegisteredUsers\": { \"" << kUser << "\": \""
                          << kPassword << "\" },\n"
                          << "  \"HttpCompressionEnabled\": false, \"StorageCompression\": false, \"SaveJobs\": false,\n"
                          << "  \"Plugins\": [ \"" << plugin << "\" ], \"DicomWeb\": { \"Enable\": true, \"Root\": \"/dicom-web/\" } }\n";
    const std::string log = mDir.file("orthanc.log");
    mPid = ::fork();
    if (mPid == 0) {
      ::prctl(PR_SET_PDEATHSIG, SIGKILL);  // never outlives the tests
      if (FILE* f = std::freopen(log.c_str(), "w", stdout)) ::dup2(::fileno(f), 2);
      ::execl(exe.c_str(), "Orthanc", config.c_str(), static_cast<char*>(nullptr));
      ::_exit(127);
    }
    for (int k = 0; k < 300 && httpStatus(url("/system")) != 200; ++k) std::this_thread::sleep_for(std::chrono::milliseconds(50));
    if (httpStatus(url("/system")) != 200) throw std::runtime_error("Orthanc did not start on port " + std::to_string(mPort) + " (see " + log + ")");
  }
  ~Orthanc() {
    ::kill(mPid, SIGTERM);
    int status = 0;
    for (int k = 0; k < 200 && ::waitpid(mPid, &status, WNOHANG) == 0; ++k) std::this_thread::sleep_for(std::chrono::milliseconds(50));
    if (::waitpid(mPid, &status, WNOHANG) == 0) {
      ::kill(mPid, SIGKILL);
      ::waitpid(mPid, &status, 0);
    }
  }
  std::string url(const std::string& path) const { return "http://127.0.0.1:" + std::to_string(mPort) + path; }
  std::string root() const { return url("/dicom-web"); }
  std::string series(const std::string& study, const std::string& series) const { return root() + "/studies/" + study + "/series/" + series; }
  /// Uploads every file under @p dir (POST /instances).
  void upload(const std::string& dir) const {
    for (const fs::directory_entry& e : fs::recursive_directory_iterator(dir)) {
      if (!e.is_regular_file()) continue;
      std::ifstream in(e.path(), std::ios::binary);
      const std::string body((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
      const long status = httpStatus(url("/instances"), &body);
      if (status != 200) throw std::runtime_error(e.path().string() + ": Orthanc refused it (HTTP " + std::to_string(status) + ")");
    }
  }

  /// The archive of this process, started on first use; stopped by the environment below.
  static Orthanc& shared() {
    if (!sInstance) sInstance = std::make_unique<Orthanc>();
    return *sInstance;
  }
  static void stop() { sInstance.reset(); }

 private:
  static inline std::unique_ptr<Orthanc> sInstance;
  TempDir mDir;
  int mPort;
  pid_t mPid = -1;
};

// Stops the archive once the tests are over, whether they passed or not.
class OrthancEnvironment : public ::testing::Environment {
 public:
  void TearDown() override { Orthanc::stop(); }
};
const auto* const kOrthancEnvironment = ::testing::AddGlobalTestEnvironment(new OrthancEnvironment);

// The archive's credentials in the environment, as a user sets them, for the life of a test.
class Credentials {
 public:
  explicit Credentials(const std::string& value = std::string(kUser) + ":" + kPassword) { ::setenv("HYB_DICOMWEB_USER", value.c_str(), 1); }
  ~Credentials() { ::unsetenv("HYB_DICOMWEB_USER"); }
};

// An analytic head: a ball of bone (1000 HU, radius 10 mm) in water, 1 mm edges.
double head(const glm::dvec3& p) { return 1000.0 * std::clamp(10.0 - glm::length(p), -1.0, 1.0) + 0.0; }

DicomImage model(const std::string& seriesUid, int size = 32) {
  DicomImage m;
  m.seriesUid = seriesUid;
  m.size = {size, size};
  m.spacing = {1.0, 1.0};
  return m;
}

std::vector<glm::dvec3> positions(const std::vector<double>& zs, double y = -16.0) {
  std::vector<glm::dvec3> out;
  for (const double z : zs) out.push_back({-16.0, y, z});
  return out;
}

std::vector<double> evenly(double first, double step, int count) {
  std::vector<double> z;
  for (int k = 0; k < count; ++k) z.push_back(first + step * k);
  return z;
}

// Study A (patient LIST^A): an axial series with a coronal localizer among its images, a
// thicker axial series and a localizer series; study B (patient LIST^B, 2023): one series.
struct Studies {
  DicomStudy a, b;
  std::string axial = "1.2.826.0.1.3680043.8.498.100.1", thick = "1.2.826.0.1.3680043.8.498.100.2", scout = "1.2.826.0.1.3680043.8.498.100.3",
              other = "1.2.826.0.1.3680043.8.498.101.1";
  Studies() {
    a.uid = "1.2.826.0.1.3680043.8.498.100";
    a.patientName = "LIST^A";
    b.uid = "1.2.826.0.1.3680043.8.498.101";
    b.patientName = "LIST^B";
    b.patientId = "HYB002";
    b.date = "20230115";
    b.description = "CT CHEST";
  }
};

DicomImage localizerImage(const std::string& seriesUid, int instance) {
  DicomImage s = model(seriesUid);
  s.imageType = "ORIGINAL\\PRIMARY\\LOCALIZER";
  s.instance = instance;
  const double coronal[6] = {1, 0, 0, 0, 0, -1};
  std::copy(std::begin(coronal), std::end(coronal), s.cosines);
  s.position = {-16.0, 0.0, 16.0};
  test::sampleField(&s, head);
  return s;
}

// Writes the studies under @p dir (a folder per series) and uploads them once per archive.
const Studies& uploadedStudies(const TempDir& dir) {
  static const Studies s;
  static bool uploaded = false;
  const std::string root = dir.file("studies");
  DicomImage m = model(s.axial);
  test::writeSeries(root + "/axial", "I", s.a, m, positions(evenly(-12.0, 2.0, 12)), head);
  test::writeCtImage(root + "/axial/scout", s.a, localizerImage(s.axial, 100));
  m = model(s.thick);
  m.seriesNumber = 3;
  m.seriesDescription = "HEAD 5";
  test::writeSeries(root + "/thick", "I", s.a, m, positions(evenly(-10.0, 5.0, 5)), head);
  test::writeCtImage(root + "/scout/I1", s.a, [&] {
    DicomImage l = localizerImage(s.scout, 1);
    l.seriesNumber = 1;
    l.seriesDescription = "SCOUT";
    return l;
  }());
  m = model(s.other);
  m.seriesDescription = "CHEST";
  test::writeSeries(root + "/other", "I", s.b, m, positions(evenly(-6.0, 3.0, 4)), head);
  if (!uploaded) Orthanc::shared().upload(root);
  uploaded = true;
  return s;
}

size_t count(const std::string& text, const std::string& what) {
  size_t n = 0;
  for (size_t at = 0; (at = text.find(what, at)) != std::string::npos; at += what.size()) ++n;
  return n;
}

// `pacs ROOT` lists what QIDO-RS finds: both patients, their studies, every series with its
// modality, instance count, description and address; the filters narrow it.
TEST(DicomWeb, ListingFindsTheUploadedStudiesAndSeries) {
  TempDir dir;
  const Studies& s = uploadedStudies(dir);
  const Orthanc& o = Orthanc::shared();
  const Credentials credentials;
  const test::CliRun all = test::run({"pacs", o.root(), "--patient", "LIST*"});
  ASSERT_EQ(all.status, 0) << all.err;
  EXPECT_THAT(all.out, HasSubstr("4 series in 2 studies"));
  EXPECT_THAT(all.out, HasSubstr("patient  LIST^A (ID HYB001)\n"));
  EXPECT_THAT(all.out, HasSubstr("patient  LIST^B (ID HYB002)\n"));
  EXPECT_THAT(all.out, HasSubstr("  study  20240301  CT HEAD  (" + s.a.uid + ")\n"));
  EXPECT_THAT(all.out, HasSubstr("    CT  #2  13 instances  HEAD 2.5\n      " + o.series(s.a.uid, s.axial) + "\n"));
  EXPECT_THAT(all.out, HasSubstr("    CT  #3  5 instances  HEAD 5\n      " + o.series(s.a.uid, s.thick) + "\n"));
  EXPECT_THAT(all.out, HasSubstr("    CT  #1  1 instance  SCOUT\n      " + o.series(s.a.uid, s.scout) + "\n"));
  EXPECT_THAT(all.out, HasSubstr("    CT  #2  4 instances  CHEST\n      " + o.series(s.b.uid, s.other) + "\n"));
  EXPECT_EQ(count(all.out, "      http://"), 4u);
  const test::CliRun byPatient = test::run({"pacs", o.root() + "/", "--patient", "LIST^B"});
  ASSERT_EQ(byPatient.status, 0) << byPatient.err;
  EXPECT_THAT(byPatient.out, HasSubstr("1 series in 1 study"));
  EXPECT_THAT(byPatient.out, HasSubstr(o.series(s.b.uid, s.other)));
  const test::CliRun byDate = test::run({"pacs", o.root(), "--patient", "LIST*", "--study-date", "20240101-"});
  ASSERT_EQ(byDate.status, 0) << byDate.err;
  EXPECT_THAT(byDate.out, HasSubstr("3 series in 1 study"));
  const test::CliRun mr = test::run({"pacs", o.root(), "--patient", "LIST*", "--modality", "MR"});
  ASSERT_EQ(mr.status, 0) << mr.err;
  EXPECT_THAT(mr.out, HasSubstr("0 series in 0 studies"));
  test::expectBadInput({"pacs", o.root(), "--study-date", "March"}, "--study-date 'March' invalid");
  test::expectBadInput({"pacs"}, "pacs needs the archive's DICOMweb root");
}

// Whether @p a and @p b hold the same samples (a volume read whole from an address borrows its samples).
bool sameSamples(const Volume& a, const Volume& b) {
  if (a.voxelCount() != b.voxelCount() || a.storedType() != b.storedType()) return false;
  for (size_t n = 0; n < a.voxelCount(); ++n)
    if (a.value(n) != b.value(n)) return false;
  return true;
}

// The samples of @p url and of @p folder, read whole and streamed: the same volume, bit for bit,
// in the same place, with the same warnings where the folder's name the address instead.
void expectSameAsFolder(const std::string& url, const std::string& folder, const std::string& series, size_t warnings) {
  const Volume fromFolder = readVolume(folder, nullptr, series);
  const Volume whole = readVolume(url);
  const std::unique_ptr<PlaneSource> planes = openPlanes(url);
  EXPECT_FALSE(planes->whole());
  EXPECT_EQ(planes->name(), url);
  const Volume streamed = detail::readAllPlanes(*planes);
  for (const Volume* v : {&whole, &streamed}) {
    EXPECT_EQ(v->dims(), fromFolder.dims()) << url;
    EXPECT_EQ(v->spacing(), fromFolder.spacing()) << url;
    EXPECT_TRUE(v->frame() == fromFolder.frame()) << url;
    EXPECT_TRUE(sameSamples(*v, fromFolder)) << url;
    ASSERT_EQ(v->warnings().size(), warnings) << url;
    ASSERT_EQ(fromFolder.warnings().size(), warnings) << url;
    for (size_t k = 0; k < warnings; ++k) {
      EXPECT_THAT(v->warnings()[k], HasSubstr(url));
      EXPECT_THAT(v->warnings()[k], Not(HasSubstr("hyb-dicomweb")));
      // The folder's message with its name replaced by the address.
      std::string expected = fromFolder.warnings()[k];
      for (size_t at = 0; (at = expected.find(folder)) != std::string::npos;) expected.replace(at, folder.size(), url);
      EXPECT_EQ(v->warnings()[k], expected);
    }
  }
}

// What the folder reader makes of a gantry tilt, uneven spacing, an enhanced multi-frame image and
// a localizer among a series' images, it makes of the same series retrieved from the archive.
// An Enhanced CT series under @p dir: one instance of 9 frames, 2 mm apart.
void writeEnhanced(const std::string& dir, const DicomStudy& study, const std::string& seriesUid) {
  std::vector<DicomImage> frames;
  for (const double z : evenly(-8.0, 2.0, 9)) {
    DicomImage f = model(seriesUid);
    f.position = {-16.0, -16.0, z};
    test::sampleField(&f, head);
    frames.push_back(f);
  }
  fs::create_directories(dir);
  test::writeEnhancedCt(dir + "/E1", study, frames);
}

TEST(DicomWeb, ASeriesReadsAsItsFilesDoInAFolder) {
  TempDir dir;
  const Studies& s = uploadedStudies(dir);
  const Orthanc& o = Orthanc::shared();
  const Credentials credentials;
  DicomStudy study;
  study.uid = "1.2.826.0.1.3680043.8.498.102";
  const std::string tiltedUid = study.uid + ".1", unevenUid = study.uid + ".2", enhancedUid = study.uid + ".3";
  DicomImage tilted = model(tiltedUid);
  const double t = 18.5 * 3.14159265358979323846 / 180.0;
  const double cosines[6] = {1, 0, 0, 0, std::cos(t), std::sin(t)};
  std::copy(std::begin(cosines), std::end(cosines), tilted.cosines);
  tilted.tilt = 18.5;
  test::writeSeries(dir.file("tilted"), "I", study, tilted, positions(evenly(-12.0, 2.0, 12)), head);
  test::writeSeries(dir.file("uneven"), "I", study, model(unevenUid), positions({-12, -10, -7, -5, -2, 0, 3, 5, 8}), head);
  writeEnhanced(dir.file("enhanced"), study, enhancedUid);
  for (const char* d : {"tilted", "uneven", "enhanced"}) o.upload(dir.file(d));

  expectSameAsFolder(o.series(study.uid, tiltedUid), dir.file("tilted"), "", 1);    // the tilt resampled
  expectSameAsFolder(o.series(study.uid, unevenUid), dir.file("uneven"), "", 1);    // the gaps resampled
  expectSameAsFolder(o.series(study.uid, enhancedUid), dir.file("enhanced"), "", 0);
  // The localizer among the axial images is left out; the folder holds the study's other series too.
  const Volume axial = readVolume(o.series(s.a.uid, s.axial));
  EXPECT_EQ(axial.dims(), glm::ivec3(32, 32, 12));
  ASSERT_EQ(axial.warnings().size(), 1u);
  EXPECT_EQ(axial.warnings()[0], o.series(s.a.uid, s.axial) + ": 1 localizer image of series '" + s.axial + "' left out");
}

// A preview retrieves every stride-th instance of the stack by its position, the localizer left
// out, and averages them in blocks: each sample is the mean of the series' samples of its block,
// where they lie. A series a preview would not shorten much, or of multi-frame instances, has none.
TEST(DicomWeb, APreviewIsEveryStrideThPlaneOfTheSeriesAveraged) {
  TempDir dir;
  const Studies& s = uploadedStudies(dir);
  const Orthanc& o = Orthanc::shared();
  const Credentials credentials;
  const std::string url = o.series(s.a.uid, s.axial);
  const Volume full = readVolume(url);  // 32×32×12, z from −12 mm by 2
  std::vector<double> told;  // the preview's fractions
  const Progress progress([&](const std::string& task, double f) {
    if (task == "DICOMweb preview") told.push_back(f);
  });
  const std::optional<Volume> p = readDicomWebPreview(url, {4, 16}, &progress);
  ASSERT_TRUE(p);
  // 12 planes by a stride of 3, centred: planes 1, 4, 7 and 10 (z −10, −4, 2, 8).
  EXPECT_EQ(p->dims(), glm::ivec3(16, 16, 4));
  EXPECT_EQ(p->spacing(), glm::dvec3(2.0, 2.0, 6.0));
  EXPECT_NEAR(glm::length(p->frame().origin - full.frame().toPatient({0.5, 0.5, 2.0})), 0.0, 1e-9);
  double worst = 0.0;
  for (int k = 0; k < 4; ++k)
    for (int j = 0; j < 16; ++j)
      for (int i = 0; i < 16; ++i) {
        const int z = 1 + 3 * k;
        const double mean = (full.at(2 * i, 2 * j, z) + full.at(2 * i + 1, 2 * j, z) + full.at(2 * i, 2 * j + 1, z) + full.at(2 * i + 1, 2 * j + 1, z)) / 4.0;
        worst = std::max(worst, std::abs(p->at(i, j, k) - mean));
      }
  EXPECT_LT(worst, 1e-3);
  ASSERT_FALSE(told.empty());
  EXPECT_EQ(told.back(), 1.0);
  EXPECT_FALSE(readDicomWebPreview(url, {6, 16}));  // 12 planes: not more than twice 6
  // A gantry-tilted series (18.5°): the preview's planes are put on the grid as the series' are,
  // and the ball lands where the series puts it (its bone's centroid in the patient).
  DicomStudy tiltedStudy;
  tiltedStudy.uid = "1.2.826.0.1.3680043.8.498.106";
  DicomImage tilted = model(tiltedStudy.uid + ".1");
  const double t = 18.5 * 3.14159265358979323846 / 180.0;
  const double cosines[6] = {1, 0, 0, 0, std::cos(t), std::sin(t)};
  std::copy(std::begin(cosines), std::end(cosines), tilted.cosines);
  tilted.tilt = 18.5;
  test::writeSeries(dir.file("tilted"), "I", tiltedStudy, tilted, positions(evenly(-12.0, 2.0, 12)), head);
  o.upload(dir.file("tilted"));
  const std::string tiltedUrl = o.series(tiltedStudy.uid, tilted.seriesUid);
  const Volume tiltedSeries = readVolume(tiltedUrl);
  const std::optional<Volume> tiltedPreview = readDicomWebPreview(tiltedUrl, {4, 16});
  ASSERT_TRUE(tiltedPreview);
  EXPECT_EQ(tiltedPreview->frame().direction, tiltedSeries.frame().direction);
  auto boneCentroid = [](const Volume& v) {
    glm::dvec3 sum(0.0);
    double weight = 0.0;
    for (int k = 0; k < v.dims().z; ++k)
      for (int j = 0; j < v.dims().y; ++j)
        for (int i = 0; i < v.dims().x; ++i)
          if (const double w = std::max(0.0, double(v.at(i, j, k))); w > 0.0) {
            sum += w * v.frame().toPatient(glm::dvec3(i, j, k) * v.spacing());
            weight += w;
          }
    return sum / weight;
  };
  EXPECT_LT(glm::length(boneCentroid(*tiltedPreview) - boneCentroid(tiltedSeries)), 1.0);
  DicomStudy study;
  study.uid = "1.2.826.0.1.3680043.8.498.105";
  writeEnhanced(dir.file("enhanced"), study, study.uid + ".1");
  o.upload(dir.file("enhanced"));
  EXPECT_FALSE(readDicomWebPreview(o.series(study.uid, study.uid + ".1"), {2, 16}));
  EXPECT_THROW(readDicomWebPreview(url, {1, 16}), ValueError);
}

// What a cache of built scenes is keyed by: the series' UID and its instances as the archive lists
// them, sorted (the localizer among the axial images too: it is an instance of the series).
TEST(DicomWeb, TheInstancesOfASeriesAreListedSorted) {
  TempDir dir;
  const Studies& s = uploadedStudies(dir);
  const Orthanc& o = Orthanc::shared();
  const Credentials credentials;
  const std::pair<std::string, std::vector<std::string>> listed = dicomWebInstances(o.series(s.a.uid, s.axial));
  EXPECT_EQ(listed.first, s.axial);
  ASSERT_EQ(listed.second.size(), 13u);  // 12 axial images and the localizer
  EXPECT_TRUE(std::is_sorted(listed.second.begin(), listed.second.end()));
  EXPECT_EQ(std::set<std::string>(listed.second.begin(), listed.second.end()).size(), 13u);
  EXPECT_THROW(dicomWebInstances(o.root() + "/studies/" + s.a.uid), ValueError);  // a study's address, not a series'
}

#ifdef HYB_PYTHON_DIR
// Python's open() takes a series' address as the command line does: the same samples.
TEST(DicomWeb, PythonOpensASeriesByItsAddress) {
  TempDir dir;
  const Studies& s = uploadedStudies(dir);
  const Orthanc& o = Orthanc::shared();
  const Credentials credentials;
  const std::string url = o.series(s.b.uid, s.other), out = dir.file("python.txt");
  const std::string script = "import sys, hybrid_octree as ho; a = ho.open(sys.argv[1]).array; "
                             "open(sys.argv[2], 'w').write('%s %d %d' % (a.shape, a.min(), a.max()))";
  const std::string command = "PYTHONPATH=" HYB_PYTHON_DIR " /usr/bin/python3 -c \"" + script + "\" '" + url + "' '" + out + "' 2>" + dir.file("err.txt");
  ASSERT_EQ(std::system(command.c_str()), 0) << test::readText(dir.file("err.txt"));
  const Volume v = readVolume(url);
  // numpy's shape is (z, y, x).
  EXPECT_EQ(test::readText(out), "(" + std::to_string(v.dims().z) + ", " + std::to_string(v.dims().y) + ", " + std::to_string(v.dims().x) + ") " +
                                     std::to_string(int(v.minValue())) + " " + std::to_string(int(v.maxValue())));
}
#endif

// InVesalius' cranium written as a CT series: built and rendered from the archive as from its
// folder, the same image (identical, or at least 60 dB).
TEST(DicomWeb, TheCraniumRendersAsFromItsFolder) {
  TempDir dir;
  const Volume cranium = readVolume(kDefaultVolumePath);
  DicomStudy study;
  study.uid = "1.2.826.0.1.3680043.8.498.103";
  study.description = "CRANIUM";
  DicomImage m = model(study.uid + ".1", 0);
  m.size = {cranium.dims().x, cranium.dims().y};
  m.spacing = {cranium.spacing().x, cranium.spacing().y};
  m.thickness = cranium.spacing().z;
  const glm::dmat3& axes = cranium.frame().direction;
  const double cosines[6] = {axes[0].x, axes[0].y, axes[0].z, axes[1].x, axes[1].y, axes[1].z};
  std::copy(std::begin(cosines), std::end(cosines), m.cosines);
  fs::create_directories(dir.file("cranium"));
  for (int k = 0; k < cranium.dims().z; ++k) {
    DicomImage slice = m;
    slice.instance = k + 1;
    slice.position = cranium.frame().toPatient(glm::dvec3(0, 0, k) * cranium.spacing());
    slice.pixels.resize(size_t(m.size.x) * size_t(m.size.y));
    for (int j = 0; j < m.size.y; ++j)
      for (int i = 0; i < m.size.x; ++i) slice.pixels[size_t(i) + size_t(m.size.x) * size_t(j)] = int16_t(cranium.at(i, j, k) + 1024.0f);
    test::writeCtImage(dir.file("cranium/I" + std::to_string(k + 1)), study, slice);
  }
  const Orthanc& o = Orthanc::shared();
  o.upload(dir.file("cranium"));
  const Credentials credentials;
  const std::string url = o.series(study.uid, m.seriesUid);
  for (const std::string& from : {dir.file("cranium"), url}) {
    const test::CliRun r = test::run({"render", from, "-o", dir.file(from == url ? "archive.png" : "folder.png"), "--size", "256x256", "--iso", "300"});
    ASSERT_EQ(r.status, 0) << r.err;
  }
  int w = 0, h = 0;
  const std::vector<uint8_t> a = readPng(dir.file("folder.png"), &w, &h), b = readPng(dir.file("archive.png"), &w, &h);
  EXPECT_GE(psnr(a, b), 60.0);
  const test::CliRun built = test::run({"build", url, "-o", dir.file("cranium.hoct")});
  ASSERT_EQ(built.status, 0) << built.err;
  EXPECT_THAT(built.out, HasSubstr("dims     256 x 256 x 108"));
  EXPECT_THAT(built.out, HasSubstr("range    -1024 .. 2986"));
  EXPECT_THAT(built.out, HasSubstr("streamed plane by plane"));
  // Its preview: 27 of the 108 slices (a stride of 4, centred) averaged 2×2, where the series lies.
  const Volume series = readVolume(url);
  const std::optional<Volume> preview = readDicomWebPreview(url, {32, 128});
  ASSERT_TRUE(preview);
  EXPECT_EQ(preview->dims(), glm::ivec3(128, 128, 27));
  EXPECT_NEAR(preview->spacing().z, 4.0 * series.spacing().z, 1e-6);
  EXPECT_LT(glm::length(preview->frame().origin - series.frame().toPatient(glm::dvec3(0.5, 0.5, 1.0) * series.spacing())), 1e-3);
  for (const glm::ivec3 p : {glm::ivec3(64, 64, 13), glm::ivec3(20, 100, 3), glm::ivec3(127, 0, 26)}) {
    const int z = 1 + 4 * p.z;
    const float mean = (series.at(2 * p.x, 2 * p.y, z) + series.at(2 * p.x + 1, 2 * p.y, z) + series.at(2 * p.x, 2 * p.y + 1, z) +
                        series.at(2 * p.x + 1, 2 * p.y + 1, z)) / 4.0f;
    EXPECT_NEAR(preview->at(p.x, p.y, p.z), mean, 1e-3) << p.x << " " << p.y << " " << p.z;
  }
}

// The archive's refusals, each one line naming the redacted address and what was expected.
TEST(DicomWeb, TheArchiveRefusingIsOneLine) {
  TempDir dir;
  const Studies& s = uploadedStudies(dir);
  const Orthanc& o = Orthanc::shared();
  const std::string axial = o.series(s.a.uid, s.axial);
  test::expectBadInput({"info", axial}, "HTTP 401 Unauthorized (expected credentials: HYB_DICOMWEB_USER=USER:PASSWORD");
  {
    const Credentials wrong(std::string(kUser) + ":not-the-password");
    test::expectBadInput({"info", axial}, "HTTP 401 Unauthorized (the credentials given were refused)");
    const test::CliRun r = test::run({"info", axial});
    EXPECT_THAT(r.err, Not(HasSubstr("not-the-password")));
  }
  // The credentials from a file; the file's content is never shown.
  std::ofstream(dir.file("auth")) << kUser << ":" << kPassword << "\n";
  const test::CliRun fromFile = test::run({"info", axial, "--pacs-auth-file", dir.file("auth")});
  EXPECT_EQ(fromFile.status, 0) << fromFile.err;
  std::ofstream(dir.file("bad-auth")) << "s3cr3t-without-colon\n";
  test::expectBadInput({"info", axial, "--pacs-auth-file", dir.file("bad-auth")}, "neither 'Bearer TOKEN' nor 'USER:PASSWORD'");
  EXPECT_THAT(test::run({"info", axial, "--pacs-auth-file", dir.file("bad-auth")}).err, Not(HasSubstr("s3cr3t")));

  const Credentials credentials;
  test::expectBadInput({"info", o.series(s.a.uid, "1.2.3.4.5")}, "HTTP 404 Not Found");
  // Credentials in the address: refused, and redacted in the message.
  const std::string withPassword = "http://" + std::string(kUser) + ":" + kPassword + "@" + axial.substr(7);
  test::expectBadInput({"info", withPassword}, "http://***@127.0.0.1");
  EXPECT_THAT(test::run({"build", withPassword, "-o", dir.file("x.hoct")}).err, Not(HasSubstr(kPassword)));
  EXPECT_THAT(test::run({"pacs", "https://u:" + std::string(kPassword) + "@127.0.0.1:1/dicom-web"}).err, Not(HasSubstr(kPassword)));
  // Nobody listening.
  const std::string closed = "http://127.0.0.1:" + std::to_string(freePort()) + "/dicom-web";
  test::expectBadInput({"pacs", closed}, "Couldn't connect to server");
  test::expectBadInput({"info", closed + "/studies/1.2/series/1.2.3"}, "Couldn't connect to server");
  test::expectBadInput({"info", o.root() + "/studies/1.2"}, "not a DICOMweb series address (expected http(s)://HOST:PORT/ROOT/studies/UID/series/UID");
  test::expectBadInput({"info", axial, "--series", s.axial}, "--series is for DICOM directories");

  // Instances of two sizes in one series; a series holding no image.
  DicomStudy study;
  study.uid = "1.2.826.0.1.3680043.8.498.104";
  const std::string mixed = study.uid + ".1", report = study.uid + ".2";
  test::writeSeries(dir.file("mixed/a"), "I", study, model(mixed, 32), positions({0, 2, 4}), head);
  DicomImage big = model(mixed, 48);
  big.instance = 10;
  big.position = {-16, -16, 6};
  test::sampleField(&big, head);
  test::writeCtImage(dir.file("mixed/big"), study, big);
  fs::create_directories(dir.file("report"));
  test::writeStructuredReport(dir.file("report/SR"), study, report);
  o.upload(dir.file("mixed"));
  o.upload(dir.file("report"));
  const std::string mixedUrl = o.series(study.uid, mixed);
  test::expectBadInput({"info", mixedUrl}, mixedUrl + ": series '" + mixed + "' holds images of two sizes, 32x32 (" + mixedUrl + "/instances/");
  test::expectBadInput({"build", o.series(study.uid, report), "-o", dir.file("r.hoct")},
                       o.series(study.uid, report) + ": no DICOM image series found (1 file: 1 structured report;");
}

// ---------------------------------------------------------------------------------------------
// A fake archive: answers each request with what a test asks, for the faults Orthanc does not make.

class FakeArchive {
 public:
  /// @p answer writes the response to a connection, given the request's head.
  explicit FakeArchive(std::function<void(int fd, const std::string& request)> answer) : mAnswer(std::move(answer)) {
    mListen = ::socket(AF_INET, SOCK_STREAM, 0);
    const int one = 1;
    ::setsockopt(mListen, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    ::bind(mListen, reinterpret_cast<sockaddr*>(&a), sizeof a);
    ::listen(mListen, 8);
    socklen_t len = sizeof a;
    ::getsockname(mListen, reinterpret_cast<sockaddr*>(&a), &len);
    mPort = ntohs(a.sin_port);
    mThread = std::thread([this] { serve(); });
  }
  ~FakeArchive() {
    mStop = true;
    mThread.join();
    ::close(mListen);
  }
  std::string root() const { return "http://127.0.0.1:" + std::to_string(mPort) + "/dicom-web"; }
  std::string series() const { return root() + "/studies/1.2.3/series/1.2.3.4"; }
  /// The heads of the requests received.
  std::vector<std::string> requests() const {
    const std::lock_guard<std::mutex> lock(mMutex);
    return mRequests;
  }
  const std::atomic<bool>& stopping() const { return mStop; }

 private:
  void serve() {
    while (!mStop) {
      pollfd p{mListen, POLLIN, 0};
      if (::poll(&p, 1, 50) <= 0) continue;
      const int fd = ::accept(mListen, nullptr, nullptr);
      if (fd < 0) continue;
      std::string head;
      char c;
      while (head.find("\r\n\r\n") == std::string::npos && ::read(fd, &c, 1) == 1) head += c;
      {
        const std::lock_guard<std::mutex> lock(mMutex);
        mRequests.push_back(head);
      }
      mAnswer(fd, head);
      ::close(fd);
    }
  }

  std::function<void(int, const std::string&)> mAnswer;
  int mListen = -1, mPort = 0;
  std::atomic<bool> mStop{false};
  mutable std::mutex mMutex;
  std::vector<std::string> mRequests;
  std::thread mThread;
};

void send(int fd, const std::string& s) {
  for (size_t at = 0; at < s.size();) {
    const ssize_t n = ::send(fd, s.data() + at, s.size() - at, MSG_NOSIGNAL);
    if (n <= 0) return;
    at += size_t(n);
  }
}

const std::string kBoundary = "hyb-boundary-42";

std::string multipartHead() {
  return "HTTP/1.1 200 OK\r\nConnection: close\r\nContent-Type: multipart/related; type=\"application/dicom\"; boundary=" + kBoundary + "\r\n\r\n";
}
std::string part(const std::string& bytes, const std::string& type = "application/dicom") {
  return "--" + kBoundary + "\r\nContent-Type: " + type + "\r\n\r\n" + bytes + "\r\n";
}
std::string fileBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}
bool isQido(const std::string& request) { return request.find("?") != std::string::npos && request.find("GET ") == 0; }
void answerQido(int fd) { send(fd, "HTTP/1.1 200 OK\r\nConnection: close\r\nContent-Type: application/dicom+json\r\nContent-Length: 2\r\n\r\n[]"); }

// One line for each fault mid-transfer, naming the address; nothing left in the temporary folder.
TEST(DicomWeb, FaultsMidTransferAreOneLine) {
  TempDir dir;
  test::writeSeries(dir.file("s"), "I", DicomStudy{}, model("1.2.3.4"), positions({0, 2}), head);
  const std::string one = fileBytes(dir.file("s/I1")), two = fileBytes(dir.file("s/I2"));
  fs::create_directories(dir.file("tmp"));
  ::setenv("TMPDIR", dir.file("tmp").c_str(), 1);
  struct Case {
    std::string name;
    std::function<void(int, const std::string&)> answer;
    std::string expected;
  };
  const std::vector<Case> cases = {
      {"5xx", [](int fd, const std::string&) { send(fd, "HTTP/1.1 503 Service Unavailable\r\nContent-Length: 0\r\nConnection: close\r\n\r\n"); },
       "HTTP 503 (a server error; expected 200"},
      {"403", [](int fd, const std::string&) { send(fd, "HTTP/1.1 403 Forbidden\r\nContent-Length: 0\r\nConnection: close\r\n\r\n"); },
       "HTTP 403 Forbidden (the credentials given may not read this)"},
      {"truncated",
       [&](int fd, const std::string& r) {
         if (isQido(r)) return answerQido(fd);
         send(fd, multipartHead() + part(one) + "--" + kBoundary + "\r\nContent-Type: application/dicom\r\n\r\n" + two.substr(0, 1000));
       },
       ": multipart body cut short after 1 instance whole and 1000 bytes of the next (expected its closing boundary)"},
      {"not DICOM",
       [&](int fd, const std::string& r) {
         if (isQido(r)) return answerQido(fd);
         send(fd, multipartHead() + part(one) + part("hello, world") + "--" + kBoundary + "--\r\n");
       },
       ": part 2 (12 bytes) is not DICOM (expected a DICOM instance)"},
      {"not an instance",
       [&](int fd, const std::string& r) {
         if (isQido(r)) return answerQido(fd);
         send(fd, multipartHead() + part("{}", "application/json") + "--" + kBoundary + "--\r\n");
       },
       ": part 1 is 'application/json' (expected application/dicom: an instance)"},
      {"not multipart",
       [&](int fd, const std::string& r) {
         if (isQido(r)) return answerQido(fd);
         send(fd, "HTTP/1.1 200 OK\r\nContent-Type: text/html\r\nContent-Length: 5\r\nConnection: close\r\n\r\nhello");
       },
       ": answer is 'text/html' (expected multipart/related; type=\"application/dicom\" with a boundary, WADO-RS)"},
  };
  for (const Case& c : cases) {
    FakeArchive archive(c.answer);
    try {
      readVolume(archive.series());
      ADD_FAILURE() << c.name << ": no error";
    } catch (const IoError& e) {
      EXPECT_THAT(e.what(), HasSubstr(archive.series())) << c.name;
      EXPECT_THAT(e.what(), HasSubstr(c.expected)) << c.name;
      EXPECT_THAT(e.what(), Not(HasSubstr("\n"))) << c.name;
    }
    EXPECT_TRUE(fs::is_empty(dir.file("tmp"))) << c.name << ": a temporary folder left behind";
  }
  // A stall mid-series: timed out after the stall time, naming what had arrived.
  FakeArchive stalled([&](int fd, const std::string& r) {
    if (isQido(r)) return answerQido(fd);
    send(fd, multipartHead() + part(one) + "--" + kBoundary);
    std::this_thread::sleep_for(std::chrono::seconds(3));
  });
  DicomWebOptions quick;
  quick.stallSeconds = 1.0;
  try {
    fetchDicomWebSeries(stalled.series(), dir.file("tmp"), quick);
    ADD_FAILURE() << "a stall: no error";
  } catch (const IoError& e) {
    EXPECT_THAT(e.what(), HasSubstr(stalled.series() + ": timed out: nothing received for 1 s after 1 instance whole"));
  }
  ::unsetenv("TMPDIR");
}

// A bearer token from the environment goes in the Authorization header and in no message;
// cancelling stops a retrieval; progress counts the instances the archive lists.
TEST(DicomWeb, BearerTokensCancellationAndProgress) {
  TempDir dir;
  test::writeSeries(dir.file("s"), "I", DicomStudy{}, model("1.2.3.4"), positions({0, 2, 4}), head);
  std::string body;
  for (const char* f : {"s/I1", "s/I2", "s/I3"}) body += part(fileBytes(dir.file(f)));
  body += "--" + kBoundary + "--\r\n";
  FakeArchive archive([&](int fd, const std::string& r) {
    if (r.find("Authorization: Bearer tok-123456") == std::string::npos)
      return send(fd, "HTTP/1.1 401 Unauthorized\r\nContent-Length: 0\r\nConnection: close\r\n\r\n");
    if (isQido(r))
      return send(fd, "HTTP/1.1 200 OK\r\nConnection: close\r\nContent-Type: application/dicom+json\r\n\r\n[{\"00201209\": {\"vr\": \"IS\", \"Value\": [3]}}]");
    send(fd, multipartHead() + body);
  });
  EXPECT_THROW(readVolume(archive.series()), IoError);
  ::setenv("HYB_DICOMWEB_TOKEN", "tok-123456", 1);
  std::vector<double> reported;
  const Progress progress([&](const std::string& task, double f) {
    if (task == "DICOMweb series") reported.push_back(f);
  });
  const Volume v = readVolume(archive.series(), nullptr, "", &progress);
  EXPECT_EQ(v.dims(), glm::ivec3(32, 32, 3));
  EXPECT_EQ(reported, (std::vector<double>{0.0, 0.33, 0.66, 0.99, 1.0}));
  // Cancelled: from another thread, as the viewer will.
  std::atomic<bool> cancel{true};
  DicomWebOptions options;
  options.cancel = &cancel;
  fs::create_directories(dir.file("fetched"));
  try {
    fetchDicomWebSeries(archive.series(), dir.file("fetched"), options);
    ADD_FAILURE() << "not cancelled";
  } catch (const RuntimeError& e) {
    EXPECT_THAT(e.what(), HasSubstr(": cancelled"));
  }
  ::setenv("HYB_DICOMWEB_TOKEN", "tok-wrong", 1);
  try {
    readVolume(archive.series());
    ADD_FAILURE() << "a wrong token accepted";
  } catch (const IoError& e) {
    EXPECT_THAT(e.what(), HasSubstr("HTTP 401 Unauthorized (the credentials given were refused)"));
    EXPECT_THAT(e.what(), Not(HasSubstr("tok-wrong")));
  }
  ::unsetenv("HYB_DICOMWEB_TOKEN");
  for (const std::string& r : archive.requests()) EXPECT_THAT(r, HasSubstr("Accept: ")) << r;
}

}  // namespace
}  // namespace hyb
