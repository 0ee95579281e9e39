#include "apps/viewer/viewer_protocol.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <string>

#include "volume/core/error.h"

namespace hyb::viewer {
namespace {

using ::testing::HasSubstr;

const std::string kCamera = R"("eye":[0,-500,0],"center":[0,0,0],"up":[0,0,1],"fov":30,"size":[256,128])";

std::string frame(const std::string& extra) { return R"({"type":"frame","seq":7,)" + kCamera + R"(,"preset":"ct-bone")" + extra + "}"; }
// A frame with the camera's fields @p camera and the preset.
std::string framed(const std::string& camera) { return R"({"type":"frame","seq":1,)" + camera + R"(,"preset":"ct-bone"})"; }

// The message the parser refuses @p text with.
std::string refusal(const std::string& text) {
  try {
    parseRequest(text);
  } catch (const ValueError& e) {
    return e.what();
  }
  return "(accepted)";
}

TEST(ViewerProtocol, AFrameRequestCarriesTheWholeStateInTheFrameTablesFields) {
  const Request r = parseRequest(frame(R"(,"interacting":true,"iso":400,"surface_color":[1,0.5,0.25,0.5],)"
                                       R"("cut":[1,2,3,0,2,0],"voi":[-10,-10,-10,10,20,30],"voi_outside":0.2,"shading":false,)"
                                       R"("classification":"preintegrated","opacity":3)"));
  const FrameRequest& f = std::get<FrameRequest>(r);
  EXPECT_EQ(f.seq, 7u);
  EXPECT_TRUE(f.interacting);
  const FrameSettings& s = f.settings;
  EXPECT_EQ(*s.eye, glm::dvec3(0, -500, 0));
  EXPECT_EQ(f.size(), glm::ivec2(256, 128));
  EXPECT_EQ(s.preset, "ct-bone");
  ASSERT_TRUE(f.iso().has_value());
  EXPECT_EQ(*f.iso(), 400.0f);
  EXPECT_EQ(s.surfaceColor, glm::vec4(1, 0.5f, 0.25f, 0.5f));
  ASSERT_TRUE(s.cut.has_value());
  EXPECT_EQ(s.cut->normal, glm::dvec3(0, 2, 0));
  ASSERT_TRUE(s.voi.has_value());
  EXPECT_EQ((*s.voi)[5], 30.0);
  EXPECT_DOUBLE_EQ(s.voiOutside, 0.2);
  EXPECT_FALSE(s.shading);
  EXPECT_EQ(s.quality.classification, Classification::PreIntegrated);
  EXPECT_DOUBLE_EQ(s.opacity, 3.0);
  // The command line those settings are: the flags a user types for the same frame.
  EXPECT_EQ(commandLineOf(s),
            " --eye 0,-500,0 --center 0,0,0 --up 0,0,1 --size 256x128 --preset ct-bone --opacity 3 --iso 400 --surface-color 1,0.5,0.25,0.5 --shading off"
            " --cut 1,2,3,0,2,0 --voi -10,-10,-10,10,20,30 --voi-outside 0.2 --classification preintegrated");
  // Points instead of a preset; a field given null is unset.
  const FrameRequest p = std::get<FrameRequest>(parseRequest(R"({"type":"frame","seq":1,)" + kCamera + R"(,"tf_points":[[0,1,1,1,0],[100,1,0,0,0.4]],"iso":null})"));
  ASSERT_EQ(p.settings.tfPoints.size(), 2u);
  EXPECT_FLOAT_EQ(p.settings.tfPoints[1].alpha, 0.4f);
  EXPECT_FALSE(p.iso().has_value());
  const OpenRequest o = std::get<OpenRequest>(parseRequest(R"({"type":"open","path":"a/b.nrrd","series":"1.2"})"));
  EXPECT_EQ(o.path, "a/b.nrrd");
  EXPECT_EQ(o.series, "1.2");
}

TEST(ViewerProtocol, EveryBadMessageIsRefusedNamingItsField) {
  const std::pair<std::string, std::string> cases[] = {
      {"not json", "not JSON"},
      {"[1,2]", "'message'"},
      {R"({"type":"paint"})", "'type'"},
      {R"({"seq":1})", "'type'"},
      {frame(R"(,"colour":1)"), "field 'colour': no such field"},
      {frame(R"(,"budget":10)"), "field 'budget': no such field"},  // (the command line's and Python's, not the viewer's)
      {frame(R"(,"classification":"pre")"), "'classification'"},
      {frame(R"(,"classification":1)"), "'classification'"},
      {R"({"type":"frame","seq":-1,)" + kCamera + R"(,"preset":"ct-bone"})", "'seq'"},
      {R"({"type":"frame","seq":1.5,)" + kCamera + R"(,"preset":"ct-bone"})", "'seq'"},
      {R"({"type":"frame","seq":1,"preset":"ct-bone"})", "'eye'"},
      {framed(R"("eye":[0,0,1e400],"center":[0,0,0],"up":[0,1,0],"size":[64,64])"), "number overflow"},
      {framed(R"("eye":[0,0,0],"center":[0,0,0],"up":[0,1,0],"size":[64,64])"), "--eye and --center must differ"},
      {framed(R"("eye":[0,0,5],"center":[0,0,0],"up":[0,0,1],"size":[64,64])"), "--up must be non-zero and not parallel"},
      {framed(R"("eye":[0,0,5],"center":[0,0,0],"up":[0,1,0],"size":[100000,64])"), "'size'"},
      {framed(R"("eye":[0,0,5],"center":[0,0,0],"up":[0,1,0],"size":[8,64])"), "'size'"},
      {framed(R"("eye":[0,0,5],"center":[0,0,0],"up":[0,1,0],"size":[64.5,64])"), "'size'"},
      {framed(R"("eye":[0,0,5],"center":[0,0,0],"up":[0,1,0],"fov":0,"size":[64,64])"), "'fov' '0' invalid (expected a number in [0.1, 179) degrees)"},
      {framed(R"("eye":"here","center":[0,0,0],"up":[0,1,0],"size":[64,64])"), "'eye': expected an array"},
      {R"({"type":"frame","seq":1,)" + kCamera + R"(,"preset":"ct-lungs"})", "'preset'"},
      {R"({"type":"frame","seq":1,)" + kCamera + R"(})", "either preset or tf_points"},
      {R"({"type":"frame","seq":1,)" + kCamera + R"(,"preset":"ct-bone","tf_points":[[0,1,1,1,0]]})", "either preset or tf_points"},
      {R"({"type":"frame","seq":1,)" + kCamera + R"(,"tf_points":[[0,1,1,1,2]]})", "'tf_points'"},
      {R"({"type":"frame","seq":1,)" + kCamera + R"(,"tf_points":[[5,1,1,1,0],[1,1,1,1,0]]})", "'tf_points'"},
      {frame(R"(,"opacity":11)"), "'opacity'"},
      {frame(R"(,"surface_color":[1,1,1])"), "'surface_color'"},
      {frame(R"(,"cut":[0,0,0,0,0,0])"), "'cut'"},
      {frame(R"(,"voi":[0,0,0,1,1,0])"), "'voi'"},
      {frame(R"(,"voi_inside":-1)"), "'voi_inside'"},
      {R"({"type":"open"})", "'path'"},
      {R"({"type":"open","path":""})", "'path'"},
      {R"({"type":"open","url":"file:///etc/passwd"})", "'url': expected a DICOMweb series address"},
      {R"({"type":"open","url":"http://pacs/dicom-web/studies/1/series/2","path":"a"})", "'url': expected no path or series beside it"},
      {R"({"type":"pacs-search","patient":1})", "'patient': expected a string"},
      {R"({"type":"pacs-search","study_date":"20240101-20240202-2"})", "'study_date': expected at most 17 bytes"},
      {R"({"type":"pacs-search","host":"evil"})", "'host': expected no such field"},
      {R"({"type":"frame","seq":1,"eye":[[[[[[[[[[1]]]]]]]]]]})", "nested deeper"},
  };
  for (const auto& [text, expected] : cases) EXPECT_THAT(refusal(text), HasSubstr(expected)) << text;
  // Too many points, and a message over the size limit.
  std::string many = R"({"type":"frame","seq":1,)" + kCamera + R"(,"tf_points":[)";
  for (int i = 0; i < 257; ++i) many += (i ? "," : "") + std::string("[") + std::to_string(i) + ",1,1,1,0]";
  EXPECT_THAT(refusal(many + "]}"), HasSubstr("'tf_points'"));
  EXPECT_THAT(refusal(std::string(kMaxMessageBytes + 1, ' ')), HasSubstr("at most"));
}

TEST(ViewerProtocol, APacsSearchAndAnOpenByAddressParse) {
  const auto search = std::get<PacsSearchRequest>(parseRequest(R"({"type":"pacs-search","patient":"DOE*","study_date":"2024-","modality":"CT"})"));
  EXPECT_EQ(search.patient, "DOE*");
  EXPECT_EQ(search.studyDate, "2024-");
  EXPECT_EQ(search.modality, "CT");
  const auto all = std::get<PacsSearchRequest>(parseRequest(R"({"type":"pacs-search"})"));
  EXPECT_TRUE(all.patient.empty() && all.studyDate.empty() && all.modality.empty());
  const auto open = std::get<OpenRequest>(parseRequest(R"({"type":"open","url":"https://pacs/dicom-web/studies/1.2/series/1.2.3"})"));
  EXPECT_EQ(open.url, "https://pacs/dicom-web/studies/1.2/series/1.2.3");
  EXPECT_TRUE(open.path.empty());
}

TEST(ViewerProtocol, FrameMessagesSplitBackIntoHeaderAndImage) {
  const std::vector<uint8_t> image = {0, 1, 2, 255};
  const std::string m = frameMessage(R"({"seq":3})", image);
  std::string header, bytes;
  ASSERT_TRUE(splitFrameMessage(m, &header, &bytes));
  EXPECT_EQ(header, R"({"seq":3})");
  EXPECT_EQ(bytes, std::string("\x00\x01\x02\xff", 4));
  EXPECT_FALSE(splitFrameMessage("ab", &header, &bytes));
  EXPECT_FALSE(splitFrameMessage(std::string("\xff\x00\x00\x00x", 5), &header, &bytes));
  EXPECT_THAT(errorMessage("bad \xff byte", 4), HasSubstr(R"("seq":4)"));  // invalid UTF-8 replaced, not thrown
}

}  // namespace
}  // namespace hyb::viewer
