#include "apps/viewer/viewer_replies.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <set>
#include <string>

namespace hyb::viewer {
namespace {

using nlohmann::json;

SceneSummary summary() {
  SceneSummary s;
  s.key = "head/ct#1.2.3";
  s.path = "/data/head/ct";
  s.series = "1.2.3";
  s.name = "head/ct";
  s.dims = {4, 5, 6};
  s.spacing = {0.5, 0.5, 2.0};
  s.minValue = -1024.0f;
  s.maxValue = 2000.0f;
  s.histogram.minValue = -1024.0;
  s.histogram.maxValue = 2000.0;
  s.histogram.counts = {3, 0, 7};
  s.orientation = "LPS";
  s.boundsLo = {-1, -2, -3};
  s.boundsHi = {1, 2, 9};
  return s;
}

TEST(ViewerReplies, InfoCarriesTheSummaryTheViewsTheSurfacesAndTheFrameTablesFields) {
  const SceneSummary s = summary();
  const std::vector<DataEntry> volumes{{"head/ct", "1.2.3", "head/ct (CT, 6 slices)"}};
  const json info = json::parse(InfoReply{s, {400.0f}, volumes, true, "http://pacs:8042/dicom-web"}.text());
  EXPECT_EQ(info["type"], "info");
  EXPECT_EQ(info["scene"], s.key);
  EXPECT_EQ(info["dims"], json::array({4, 5, 6}));
  EXPECT_EQ(info["center"], json::array({0.0, 0.0, 3.0}));
  EXPECT_EQ(info["histogram"]["counts"], json::array({3, 0, 7}));
  EXPECT_EQ(info["surfaces"], json::array({400.0}));
  EXPECT_EQ(info["volumes"][0]["label"], "head/ct (CT, 6 slices)");
  EXPECT_EQ(info["open"]["series"], "1.2.3");
  EXPECT_EQ(info["pacs"], "http://pacs:8042/dicom-web");
  for (const char* view : {"anterior", "posterior", "left", "right", "superior", "inferior"}) {
    EXPECT_TRUE(info["views"].contains(view)) << view;
  }
  std::set<std::string> fields;  // the page's controls' rows: every field the viewer takes, once
  for (const json& row : info["fields"]) fields.insert(row["name"].get<std::string>());
  EXPECT_EQ(fields.size(), info["fields"].size());
  for (const FrameField& f : frameFields()) EXPECT_EQ(fields.count(f.name), (f.doors & kViewer) ? 1u : 0u) << f.name;
  EXPECT_FALSE(json::parse(InfoReply{s, {}, volumes, false, ""}.text()).contains("open"));  // (a --volume scene: no menu entry)
}

TEST(ViewerReplies, EachProgressReplyHasItsTypeAndFields) {
  const json loading = json::parse(LoadingReply{"a", "reading slices", 0.25}.text());
  EXPECT_EQ(loading, (json{{"type", "loading"}, {"scene", "a"}, {"task", "reading slices"}, {"progress", 0.25}}));
  const json building = json::parse(SurfaceReply{"a", 400.0f, ScenePool::SurfaceState::Building, "surface", 0.5}.text());
  EXPECT_EQ(building["state"], "building");
  EXPECT_EQ(building["progress"], 0.5);
  const json ready = json::parse(SurfaceReply{"a", 400.0f, ScenePool::SurfaceState::Ready, "", 0.0}.text());
  EXPECT_EQ(ready["state"], "ready");
  EXPECT_FALSE(ready.contains("progress"));  // (only while building)
  EXPECT_EQ(json::parse(SurfaceReply{"a", 400.0f, ScenePool::SurfaceState::Failed, "", 0.0}.text())["state"], "failed");
  const std::vector<DataEntry> none;
  EXPECT_EQ(json::parse(VolumesReply{none, ""}.text()), (json{{"type", "volumes"}, {"volumes", json::array()}, {"pacs", nullptr}, {"meshes", json::array()}}));
  EXPECT_EQ(json::parse(VolumesReply{none, "http://pacs/dicom-web"}.text())["pacs"], "http://pacs/dicom-web");
}

TEST(ViewerReplies, APacsSearchListsEachSeriesWithItsLabelAndAddress) {
  DicomWebSeries a;
  a.info.patientName = "DOE^JANE";
  a.info.studyDate = "20240102";
  a.info.modality = "CT";
  a.info.description = "HEAD 1.0";
  a.info.slices = 212;
  a.url = "http://pacs/dicom-web/studies/1.2/series/1.2.3";
  DicomWebSeries b;
  b.info.slices = 1;
  b.url = "http://pacs/dicom-web/studies/1.2/series/1.2.4";
  const std::vector<DicomWebSeries> found{a, b};
  const json m = json::parse(PacsReply{found}.text());
  EXPECT_EQ(m["type"], "pacs");
  ASSERT_EQ(m["series"].size(), 2u);
  EXPECT_EQ(m["series"][0]["url"], a.url);
  EXPECT_EQ(m["series"][0]["label"], "DOE^JANE · 20240102 · CT · HEAD 1.0 · 212 instances");
  EXPECT_EQ(m["series"][0]["instances"], 212);
  EXPECT_EQ(m["series"][1]["label"], "(no name) · 1 instance");
}

TEST(ViewerReplies, AFailedOpenIsAnErrorNamingTheSceneAndBadTextIsReplacedNotThrown) {
  const json failed = json::parse(OpenFailedReply{"x", "cannot open x: truncated"}.text());
  EXPECT_EQ(failed["type"], "error");
  EXPECT_EQ(failed["scene"], "x");
  EXPECT_EQ(failed["message"], "cannot open x: truncated");
  // A file name that is not UTF-8 (Latin-1 from an old CD): the reply still goes out.
  const json latin1 = json::parse(LoadingReply{"sch\xe4""del", "reading", 0.0}.text());
  EXPECT_EQ(latin1["scene"], "sch\xef\xbf\xbd""del");
}

TEST(ViewerReplies, TheRenderCommandQuotesThePathAndNamesTheSeriesAndTheTfFile) {
  FrameRequest r;
  r.settings.eye = glm::dvec3(0, -500, 0);
  r.settings.center = glm::dvec3(0);
  r.settings.size = glm::ivec2(64, 32);
  r.settings.tfPoints = {{-100.0f, glm::vec3(1.0f), 0.0f}, {300.0f, glm::vec3(1.0f), 0.5f}};
  const std::string cmd = renderCommand("/data/my ct", "1.2.3", r, "view.tf");
  EXPECT_EQ(cmd.rfind("hybrid-octree render '/data/my ct' --series 1.2.3", 0), 0u) << cmd;
  EXPECT_NE(cmd.find("--tf view.tf"), std::string::npos) << cmd;
  EXPECT_NE(cmd.find("-o view.png"), std::string::npos) << cmd;
  EXPECT_EQ(tfText(r.settings.tfPoints), "# value r g b a (opacity of 1 mm)\n-100 1 1 1 0\n300 1 1 1 0.5\n");
}

}  // namespace
}  // namespace hyb::viewer
