// The one table of a frame's settings (render/frame_settings.h): every field reaches each of its
// front doors (the command line, the viewer's messages, Python: tests/python) with one range, one
// default and one message, and its value round-trips through the command line, JSON and the camera file.
#include "render/frame_settings.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>

#include "apps/cli/frame.h"
#include "apps/viewer/viewer_protocol.h"
#include "cli_util.h"
#include "render/user_meshes.h"
#include "surface/mesh_io.h"
#include "surface/scan_convert.h"
#include "test_util.h"
#include "volume/core/error.h"

namespace hyb {
namespace {

using ::testing::HasSubstr;
using nlohmann::json;

// A valid value of @p f other than its default, as its text.
std::string sampleText(const FrameField& f) {
  const auto within = [&](int k, int of) {  // a number strictly inside the field's range, the k-th of @p of
    const double lo = std::max(f.lo, -1000.0), hi = std::min(f.hi, 1000.0);
    const double x = lo + (hi - lo) * (k + 1) / (of + 1);
    return f.kind == FieldKind::Number ? x : std::round(x);
  };
  const auto number = [](double x) {
    std::ostringstream s;
    s << x;
    return s.str();
  };
  switch (f.kind) {
    case FieldKind::Number:
    case FieldKind::Integer:  // the first of a few that the field takes (a brick edge: a power of two)
      for (const double x : {within(0, 3), within(1, 3), f.lo * 2, f.lo + 1}) {
        FrameSettings s;
        try {
          f.parse(s, number(x), f.flag());
          if (f.text(s) != f.defaultText()) return number(x);
        } catch (const ValueError&) {
        }
      }
      return "";
    case FieldKind::Numbers: {  // increasing: a VOI's corners ordered, a normal not zero
      std::string t;
      for (int k = 0; k < f.count; ++k) t += (k ? "," : "") + number(within(k, f.count));
      return t;
    }
    case FieldKind::Size: return "64x48";
    case FieldKind::Switch: return f.defaultText() == "on" ? "off" : "on";
    case FieldKind::Flag: return "on";
    case FieldKind::Choice: return f.choices.back() != f.defaultText() ? f.choices.back() : f.choices.front();
    case FieldKind::Text: return f.name == "primitive" ? "plane:1,2,3,0,0,1,2:1,0,0,0.5;sphere:4,5,6,7" : "some dir/file.json";
    case FieldKind::Budget: return "25%";
    case FieldKind::Points: return "0,1,1,1,0;100,1,0.5,0,0.25";
  }
  return "";
}

// Settings with every field of @p door set to its sample value.
FrameSettings everyFieldSet(unsigned door) {
  FrameSettings s;
  for (const FrameField& f : frameFields())
    if (f.doors & door) f.parse(s, sampleText(f), f.flag());
  return s;
}

// A value @p f refuses (beyond its range, or not of its kind), as its text.
std::string badText(const FrameField& f) {
  switch (f.kind) {
    case FieldKind::Number:
    case FieldKind::Integer: return std::isfinite(f.hi) && f.hi < 1e300 ? "1e308" : "nan";
    case FieldKind::Numbers: return "1";
    case FieldKind::Size: return "0x0";
    case FieldKind::Switch:
    case FieldKind::Flag: return "maybe";
    case FieldKind::Choice: return "nothing-of-the-kind";
    case FieldKind::Text: return std::string(5000, 'a');
    case FieldKind::Budget: return "150%";
    case FieldKind::Points: return "5,1,1,1,0;1,1,1,1,0";
  }
  return "";
}

// Splits a command line written by commandLineOf (words, single-quoted where needed).
std::vector<std::string> words(const std::string& line) {
  std::vector<std::string> out;
  std::string w;
  bool quoted = false, any = false;
  for (size_t i = 0; i < line.size(); ++i) {
    const char c = line[i];
    if (c == '\'') {
      quoted = !quoted;
      any = true;
    } else if (c == ' ' && !quoted) {
      if (any) out.push_back(w);
      w.clear();
      any = false;
    } else {
      w += c;
      any = true;
    }
  }
  if (any) out.push_back(w);
  return out;
}

TEST(FrameSettings, EveryFieldReachesEachOfItsDoorsWithOneRangeDefaultAndMessage) {
  const std::string help = test::run({"render", "--help"}).out;
  const json viewer = fieldsJson(kViewer), python = fieldsJson(kPython);
  const auto row = [](const json& rows, const std::string& name) {
    for (const json& r : rows)
      if (r["name"] == name) return r;
    return json();
  };
  const std::string frame = R"({"type":"frame","seq":1,"eye":[0,-500,0],"center":[0,0,0],"up":[0,0,1],"size":[64,64],"preset":"ct-bone")";
  int viewerFields = 0, pythonFields = 0;
  for (const FrameField& f : frameFields()) {
    SCOPED_TRACE(f.name);
    const json d = f.defaultText() ? fieldJson(f, *f.defaultText()) : json(nullptr);
    for (const auto& [door, rows] : {std::pair(kViewer, &viewer), std::pair(kPython, &python)}) {
      const json r = row(*rows, f.name);
      ASSERT_EQ(!r.is_null(), (f.doors & door) != 0);
      if (r.is_null()) continue;
      (door == kViewer ? viewerFields : pythonFields)++;
      EXPECT_EQ(r["default"], d);
      if (r.contains("min")) {
        EXPECT_EQ(r["min"].get<double>(), f.lo);
        EXPECT_EQ(r["max"].get<double>(), f.hi);
      }
    }
    // A value outside the field: each door refuses it in the field's own words.
    const std::string bad = badText(f);
    if (f.doors & kCommandLine) {
      EXPECT_THAT(help, HasSubstr(f.flag() + " "));
      if (f.kind != FieldKind::Flag) {
        const test::CliRun r = test::run({"render", f.flag(), bad, "-o", "/nonexistent/x.png"});
        EXPECT_EQ(r.status, 2);
        EXPECT_THAT(r.err, HasSubstr(f.flag() + " "));
        EXPECT_THAT(r.err, HasSubstr(f.expected()));
      }
    }
    if (f.doors & kViewer) {
      json m = json::parse(frame + "}");
      m[f.name] = bad == "5,1,1,1,0;1,1,1,1,0" ? json::array({json::array({5, 1, 1, 1, 0}), json::array({1, 1, 1, 1, 0})}) : json(bad);
      try {
        viewer::parseRequest(m.dump());
        ADD_FAILURE() << "accepted " << m.dump();
      } catch (const ValueError& e) {
        EXPECT_THAT(e.what(), HasSubstr("field '" + f.name + "'"));
      }
    }
  }
  EXPECT_EQ(viewerFields, int(viewer.size()));
  EXPECT_EQ(pythonFields, int(python.size()));
  EXPECT_GE(viewerFields, 20);
}

TEST(FrameSettings, EveryFieldsTextJsonAndFlagRoundTrip) {
  const FrameSettings all = everyFieldSet(kEveryDoor);
  for (const FrameField& f : frameFields()) {
    SCOPED_TRACE(f.name);
    // Its text and its default's text read back as themselves.
    EXPECT_EQ(f.text(all), sampleText(f));
    if (const std::optional<std::string> d = f.defaultText()) {
      FrameSettings s = all;
      f.parse(s, *d, f.flag());
      EXPECT_EQ(f.text(s), d);
    }
  }
  // JSON: what settingsJson writes, applyJson reads back, at every door.
  for (const unsigned door : {unsigned(kCommandLine), unsigned(kViewer), unsigned(kPython)}) {
    const json j = settingsJson(all, door);
    FrameSettings back;
    applyJson(&back, j, door);
    EXPECT_EQ(settingsJson(back, door), j) << door;
  }
  // The command line: the flags commandLineOf writes parse back into the same settings.
  const FrameSettings cli = everyFieldSet(kCommandLine);
  const std::string line = commandLineOf(cli);
  app::RenderOptions o;
  CLI::App parser;
  o.add(&parser);
  std::vector<std::string> args = words(line);
  std::reverse(args.begin(), args.end());  // (CLI11 takes them last first)
  parser.parse(args);
  EXPECT_EQ(settingsJson(o.settings, kCommandLine), settingsJson(cli, kCommandLine)) << line;
}

// A viewer's frames share the meshes of the same set of files and primitives (the renderer knows
// them by their objects): read once, read again when a file changes or the set does.
TEST(FrameSettings, TheMemoGivesTheSameMeshesForTheSameFilesAndPrimitives) {
  test::TempDir dir;
  const Volume v = test::sphereVolume({20, 20, 20}, 6.0);
  writeMesh(dir.file("a.stl"), uvSphere({10, 10, 10}, 4.0, 8));
  FrameSettings s;
  s.meshes = {{dir.file("a.stl"), glm::vec4(1, 0, 0, 0.5f)}};
  s.primitives = {"sphere:10,10,10,3"};
  UserGeometryMemo memo;
  std::ostringstream warnings;
  const std::vector<UserMesh> first = memo.of(s, v, warnings);
  ASSERT_EQ(first.size(), 2u);
  const std::vector<UserMesh> again = memo.of(s, v, warnings);
  EXPECT_EQ(again[0].mesh, first[0].mesh);
  EXPECT_EQ(again[1].mesh, first[1].mesh);
  s.meshes[0].color.a = 0.6f;  // another colour: another set
  EXPECT_NE(memo.of(s, v, warnings)[0].mesh, first[0].mesh);
  s.meshes[0].color.a = 0.5f;
  EXPECT_EQ(memo.of(s, v, warnings)[0].mesh, first[0].mesh);  // (still kept)
  writeMesh(dir.file("a.stl"), uvSphere({10, 10, 10}, 5.0, 8));
  std::filesystem::last_write_time(dir.file("a.stl"), std::filesystem::last_write_time(dir.file("a.stl")) + std::chrono::seconds(2));
  EXPECT_NE(memo.of(s, v, warnings)[0].mesh, first[0].mesh);  // the file changed: read again
  s.meshes.clear();
  s.primitives.clear();
  EXPECT_TRUE(memo.of(s, v, warnings).empty());
}

TEST(FrameSettings, OneCameraFormatWrittenAndReadEverywhere) {
  Camera c;
  c.eye = {1.5, -400.25, 30};
  c.center = {0, 0.125, 10};
  c.up = {0, 0.6, 0.8};
  c.fovDeg = 22.5;
  c.ortho = true;
  c.orthoHeight = 312.5;
  c.width = 320;
  c.height = 200;
  test::TempDir dir;
  // As --stats writes it, under "camera", and alone.
  const std::string camera = cameraJson(c);
  std::ofstream(dir.file("alone.json")) << camera;
  std::ofstream(dir.file("stats.json")) << R"({"frame_ms": 3, "camera": )" << camera << "}";
  // The earlier form (fov_deg, width, height) still reads.
  std::ofstream(dir.file("old.json")) << R"({"eye":[1.5,-400.25,30],"center":[0,0.125,10],"up":[0,0.6,0.8],"fov_deg":22.5,"ortho":true,)"
                                         R"("ortho_height":312.5,"width":320,"height":200})";
  for (const char* name : {"alone.json", "stats.json", "old.json"}) {
    const Camera r = readCameraFile(dir.file(name));
    EXPECT_EQ(r.eye, c.eye) << name;
    EXPECT_EQ(r.center, c.center) << name;
    EXPECT_EQ(r.up, c.up) << name;
    EXPECT_EQ(r.fovDeg, c.fovDeg) << name;
    EXPECT_EQ(r.ortho, c.ortho) << name;
    EXPECT_EQ(r.orthoHeight, c.orthoHeight) << name;
    EXPECT_EQ(r.width, c.width) << name;
    EXPECT_EQ(r.height, c.height) << name;
  }
  // The viewer's frame message holds the same fields: the camera file's JSON is a valid frame.
  json frame = json::parse(camera);
  frame.erase("space");
  frame.update({{"type", "frame"}, {"seq", 1}, {"preset", "ct-bone"}});
  const viewer::FrameRequest r = std::get<viewer::FrameRequest>(viewer::parseRequest(frame.dump()));
  EXPECT_EQ(explicitCamera(r.settings).eye, c.eye);
  EXPECT_EQ(r.size(), glm::ivec2(320, 200));
  // A camera file missing a field, or holding a bad one, is refused naming the file and the field.
  std::ofstream(dir.file("bad.json")) << R"({"eye":[0,0,1],"center":[0,0,0],"up":[0,1,0],"fov":500,"ortho":false,"size":[8,8]})";
  try {
    readCameraFile(dir.file("bad.json"));
    ADD_FAILURE() << "accepted";
  } catch (const IoError& e) {
    EXPECT_THAT(e.what(), HasSubstr("bad.json"));
    EXPECT_THAT(e.what(), HasSubstr("'fov'"));
  }
}

}  // namespace
}  // namespace hyb
