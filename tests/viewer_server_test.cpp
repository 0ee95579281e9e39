#include "apps/viewer/viewer_server.h"

#include <sys/socket.h>

#include <boost/asio.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/websocket.hpp>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <atomic>
#include <condition_variable>
#include <chrono>
#include <filesystem>
#include <map>
#include <mutex>
#include <thread>
#include <optional>
#include <set>
#include <string>

#include "apps/viewer/frame_scheduler.h"
#include "apps/viewer/viewer_protocol.h"
#include "apps/viewer/viewer_quality.h"
#include "render/image.h"
#include "render/scene_renderer.h"
#include "surface/mesh_io.h"
#include "surface/scan_convert.h"
#include "render_util.h"
#include "test_util.h"
#include "volume/core/progress.h"

namespace hyb::viewer {
namespace {

namespace net = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
using tcp = net::ip::tcp;
using nlohmann::json;
using ::testing::HasSubstr;

using test::sphereScene;

// A server of the analytic sphere on a free port, for the test's duration; with @p dataDir, of the
// volumes there instead (any file's scene is the sphere, or the one @p scenes names for it).
struct TestServer {
  std::atomic<int> loads{0};
  std::map<std::string, int> loadsOf;  // by file name (under the loader's own count)
  std::mutex loadsMutex;
  std::unique_ptr<Server> server;
  explicit TestServer(double frameMs = 60.0, int maxClients = 8, std::function<void(ServerOptions&)> more = {}) {
    ServerOptions o;
    o.port = 0;
    o.maxClients = maxClients;
    o.volume = "sphere";
    o.frameTargetMs = frameMs;
    o.loader = [this](const std::string& path, const std::string&, const Progress* progress) {
      ++loads;
      {
        const std::lock_guard<std::mutex> lock(loadsMutex);
        ++loadsOf[std::filesystem::path(path).filename().string()];
      }
      ProgressTask task(progress, "reading", 4);
      for (int i = 0; i < 4; ++i) task.advance();
      return sphereScene();
    };
    if (more) more(o);
    server = std::make_unique<Server>(std::move(o));
    server->start();
  }
  uint16_t port() const { return server->port(); }
  std::string token() const { return server->token(); }
  int loadsOfFile(const std::string& name) {
    const std::lock_guard<std::mutex> lock(loadsMutex);
    return loadsOf[name];
  }
};

// Reads on the socket give up after 60 s instead of hanging a failing test.
void limitReads(tcp::socket& socket) {
  timeval tv{60, 0};
  ::setsockopt(socket.native_handle(), SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
}

struct Reply {
  unsigned status = 0;
  std::string body, cookie, disposition;
};

Reply httpRequest(uint16_t port, const std::string& target, const std::string& cookie = "", http::verb verb = http::verb::get) {
  net::io_context io;
  tcp::socket socket(io);
  socket.connect(tcp::endpoint(net::ip::make_address("127.0.0.1"), port));
  limitReads(socket);
  http::request<http::string_body> req(verb, target, 11);
  req.set(http::field::host, "127.0.0.1:" + std::to_string(port));
  if (!cookie.empty()) req.set(http::field::cookie, cookie);
  http::write(socket, req);
  beast::flat_buffer buffer;
  http::response<http::string_body> res;
  http::read(socket, buffer, res);
  Reply r{res.result_int(), res.body(), "", ""};
  if (res.count(http::field::set_cookie)) r.cookie = std::string(res[http::field::set_cookie]);
  if (res.count(http::field::content_disposition)) r.disposition = std::string(res[http::field::content_disposition]);
  return r;
}

// A WebSocket client of the viewer: the server's own page by default (its origin, as a browser
// sends it), another origin, or none ("").
struct Socket {
  net::io_context io;
  websocket::stream<tcp::socket> ws{io};
  Socket(uint16_t port, const std::string& target, std::optional<std::string> origin = std::nullopt) {
    ws.next_layer().connect(tcp::endpoint(net::ip::make_address("127.0.0.1"), port));
    limitReads(ws.next_layer());
    const std::string sent = origin.value_or("http://127.0.0.1:" + std::to_string(port));
    ws.set_option(websocket::stream_base::decorator([sent](websocket::request_type& req) {
      if (!sent.empty()) req.set(http::field::origin, sent);
    }));
    ws.read_message_max(64 << 20);
    ws.handshake("127.0.0.1:" + std::to_string(port), target);
  }
  // The next message: a text message's JSON, or a frame's header with its image.
  json next(std::string* image = nullptr) {
    beast::flat_buffer buffer;
    ws.read(buffer);
    const std::string data = beast::buffers_to_string(buffer.data());
    if (ws.got_text()) return json::parse(data);
    std::string header, bytes;
    EXPECT_TRUE(splitFrameMessage(data, &header, &bytes));
    if (image) *image = bytes;
    return json::parse(header);
  }
  // Skips text messages other than errors until a frame (or an error) arrives.
  json nextFrameOrError(std::string* image = nullptr) {
    for (;;) {
      json m = next(image);
      if (m["type"] == "frame" || m["type"] == "error") return m;
    }
  }
  void send(const std::string& text) {
    ws.text(true);
    ws.write(net::buffer(text));
  }
};

json frameRequest(uint64_t seq, bool interacting, int pixels = 64, double azimuth = 0.0) {
  const double a = azimuth * 3.14159265358979 / 180.0;
  return {{"type", "frame"},
          {"seq", seq},
          {"interacting", interacting},
          {"eye", {19.5 + 60 * std::sin(a), 17.5 - 60 * std::cos(a), 25}},
          {"center", {19.5, 17.5, 15.5}},
          {"up", {0, 0, 1}},
          {"fov", 40},
          {"size", {pixels, pixels}},
          {"tf_points", {{0, 1, 1, 1, 0}, {2, 1, 0.6, 0.3, 0.3}, {15, 0.3, 0.6, 1, 0.05}}},
          {"iso", 4.0},
          {"surface_color", {0.9, 0.9, 0.8, 0.5}}};
}

// Sends @p request to @p c and returns the message answering it (its frame, or an error).
json answer(Socket& c, const json& request) {
  c.send(request.dump());
  json f;
  do f = c.nextFrameOrError();
  while (f["type"] == "frame" && f["seq"] != request["seq"]);
  return f;
}

TEST(ViewerServer, EveryRequestNeedsTheTokenAndOnlyAssetsAreServed) {
  TestServer s;
  const uint16_t port = s.port();
  EXPECT_EQ(httpRequest(port, "/").status, 403u);
  EXPECT_EQ(httpRequest(port, "/viewer.js?token=0123456789abcdef0123456789abcdef").status, 403u);
  const Reply page = httpRequest(port, "/?token=" + s.token());
  EXPECT_EQ(page.status, 200u);
  EXPECT_THAT(page.body, HasSubstr("viewer.js"));
  EXPECT_THAT(page.cookie, HasSubstr("hyb_token=" + s.token()));
  EXPECT_THAT(page.cookie, HasSubstr("HttpOnly"));
  const std::string cookie = "hyb_token=" + s.token();
  EXPECT_EQ(httpRequest(port, "/viewer.js", cookie).status, 200u);
  EXPECT_EQ(httpRequest(port, "/viewer.js", "hyb_token=nope").status, 403u);
  for (const char* path : {"/../CMakeLists.txt", "/%2e%2e/%2e%2e/etc/passwd", "//etc/passwd", "/web/index.html", "/api/../CMakeLists.txt"})
    EXPECT_EQ(httpRequest(port, path, cookie).status, 404u) << path;
  EXPECT_EQ(httpRequest(port, "/", cookie, http::verb::post).status, 405u);
  // The mesh of an isosurface, in patient coordinates; a bad isovalue or format is refused.
  const Reply mesh = httpRequest(port, "/api/mesh?iso=4&format=ply", cookie);
  EXPECT_EQ(mesh.status, 200u);
  EXPECT_EQ(mesh.body.rfind("ply", 0), 0u);
  EXPECT_THAT(mesh.body, HasSubstr("SPACE=LPS"));
  EXPECT_THAT(mesh.disposition, HasSubstr("filename=\"surface-4.ply\""));
  // An isovalue beyond the data has no surface: said, not an empty file.
  const Reply none = httpRequest(port, "/api/mesh?iso=1e9&format=stl", cookie);
  EXPECT_EQ(none.status, 400u);
  EXPECT_THAT(none.body, HasSubstr("iso: no surface at 1e+09 (the data's values are"));
  EXPECT_EQ(httpRequest(port, "/api/mesh?iso=abc&format=ply", cookie).status, 400u);
  EXPECT_EQ(httpRequest(port, "/api/mesh?iso=4&format=exe", cookie).status, 400u);
  EXPECT_EQ(httpRequest(port, "/api/mesh?iso=4&format=ply").status, 403u);
  // The socket needs the token, and its own page's origin (a client without one is no browser's page).
  EXPECT_THROW(Socket(port, "/ws"), beast::system_error);
  EXPECT_THROW(Socket(port, "/ws?token=" + s.token(), "http://evil.example"), beast::system_error);
  EXPECT_THROW(Socket(port, "/ws?token=" + s.token(), ""), beast::system_error);
  EXPECT_THROW(Socket(port, "/other?token=" + s.token()), beast::system_error);
  Socket ok(port, "/ws?token=" + s.token(), "http://127.0.0.1:" + std::to_string(port));
  EXPECT_EQ(ok.next()["type"], "info");
}

// A scene file stays paged in the viewer: the mesh of an isovalue it does not store is extracted
// through its cache, the same file as from the scene in memory.
TEST(ViewerServer, TheMeshOfAPagedSceneIsExtractedThroughItsCache) {
  test::TempDir dir;
  saveScene(dir.file("s.hoct"), sphereScene().volume, sphereScene().octree);
  std::string bodies[2];
  for (const bool paged : {false, true}) {
    TestServer s(60.0, 8, [&](ServerOptions& o) {
      o.loader = [&](const std::string&, const std::string&, const Progress*) {
        return loadScene(dir.file("s.hoct"), SceneLoadOptions{!paged, 1 << 20});
      };
    });
    const Reply mesh = httpRequest(s.port(), "/api/mesh?iso=4&format=ply", "hyb_token=" + s.token());
    EXPECT_EQ(mesh.status, 200u) << paged;
    bodies[paged] = mesh.body;
  }
  EXPECT_EQ(bodies[0].rfind("ply", 0), 0u);
  EXPECT_EQ(bodies[1], bodies[0]);
}

TEST(ViewerServer, BadMessagesGetTheirErrorAndTheServerKeepsServing) {
  TestServer s;
  Socket c(s.port(), "/ws?token=" + s.token());
  const json info = c.next();
  ASSERT_EQ(info["type"], "info");
  EXPECT_EQ(info["dims"], json::array({40, 36, 32}));
  EXPECT_EQ(info["views"].size(), 6u);
  EXPECT_EQ(info["fields"], fieldsJson(kViewer));  // what the page's controls range over
  const json& anterior = info["views"]["anterior"];  // a camera: the table's camera fields, nothing of the look
  EXPECT_EQ(anterior.size(), 7u) << anterior.dump();
  for (const auto& [name, value] : anterior.items()) EXPECT_TRUE(isCameraField(*frameField(name))) << name;
  const std::pair<std::string, std::string> bad[] = {
      {"{", "not JSON"},
      {R"({"type":"frame","seq":1})", "field 'eye': expected a value (missing)"},
      {R"({"type":"open","path":"x.nrrd"})", "no data directory"},
      {R"({"type":"open","url":"http://127.0.0.1:1/dicom-web/studies/1/series/2"})", "open: the server has no PACS"},
      {R"({"type":"pacs-search","patient":"A*"})", "pacs: the server has no PACS"},
      {frameRequest(2, false).dump().replace(1, 0, R"("extra":1,)"), "'extra'"},
  };
  for (const auto& [text, expected] : bad) {
    c.send(text);
    const json e = c.next();
    EXPECT_EQ(e["type"], "error") << text;
    EXPECT_THAT(e["message"].get<std::string>(), HasSubstr(expected)) << text;
  }
  json huge = frameRequest(3, false, 4096);
  c.send(huge.dump());
  EXPECT_THAT(c.next()["message"].get<std::string>(), HasSubstr("field 'size'"));
  c.ws.binary(true);
  c.ws.write(net::buffer(std::string("\x01\x02", 2)));
  EXPECT_THAT(c.next()["message"].get<std::string>(), HasSubstr("not binary"));
  // Still serving: a valid request gets its frames.
  c.send(frameRequest(4, false).dump());
  json f = c.nextFrameOrError();
  EXPECT_EQ(f["type"], "frame");
  EXPECT_EQ(f["seq"], 4);
  // A message over the size limit closes that socket only.
  c.send(std::string(kMaxMessageBytes + 10, ' '));
  beast::flat_buffer sink;
  beast::error_code ec;
  for (int i = 0; i < 10 && !ec; ++i) c.ws.read(sink, ec);
  EXPECT_TRUE(ec);
  Socket again(s.port(), "/ws?token=" + s.token());
  EXPECT_EQ(again.next()["type"], "info");
}

TEST(ViewerServer, TheFinalFrameIsTheEnginesImageLossless) {
  TestServer s;
  Socket c(s.port(), "/ws?token=" + s.token());
  c.next();  // info
  c.send(frameRequest(9, false, 80, 30).dump());
  // Refining frames (JPEG), then the final one (PNG) once the surface is ready.
  std::string image;
  json f;
  for (int i = 0; i < 20; ++i) {
    f = c.nextFrameOrError(&image);
    ASSERT_EQ(f["type"], "frame") << f.dump();
    EXPECT_EQ(f["seq"], 9);
    if (f["quality"] == "final" && f["iso"] == 4.0) break;
  }
  ASSERT_EQ(f["quality"], "final");
  EXPECT_EQ(f["format"], "png");
  EXPECT_EQ(f["width"], 80);
  // Each value as its shortest text that reads back the same (0.9, not 0.89999997615814209).
  EXPECT_THAT(f["command"].get<std::string>(), HasSubstr("--iso 4 --surface-color 0.9,0.9,0.8,0.5 "));
  EXPECT_THAT(f["command"].get<std::string>(), HasSubstr(" --tf view.tf"));
  EXPECT_THAT(f["tfText"].get<std::string>(), HasSubstr("15 0.300000012 0.600000024 1 0.0500000007"));
  test::TempDir dir;
  test::writeBytes(dir.file("f.png"), std::vector<uint8_t>(image.begin(), image.end()));
  int w = 0, h = 0;
  const std::vector<uint8_t> got = readPng(dir.file("f.png"), &w, &h);
  // The same request through an engine of its own.
  SceneRenderer engine(sphereScene());
  const FrameRequest r = std::get<FrameRequest>(parseRequest(frameRequest(9, false, 80, 30).dump()));
  std::ostringstream warnings;
  const FrameSetup setup = setUpFrame(r.settings, engine.scene(), warnings);
  const RenderedFrame want = engine.render(setup.view, setup.look, Quality{});
  EXPECT_EQ(got, toRgba8(want.image, glm::vec3(0.0f)));
  // Pre-integrated: the engine's pre-integrated image, and the command says so.
  json pre = frameRequest(10, false, 80, 30);
  pre["classification"] = "preintegrated";
  c.send(pre.dump());
  for (int i = 0; i < 20; ++i) {
    f = c.nextFrameOrError(&image);
    ASSERT_EQ(f["type"], "frame") << f.dump();
    if (f["seq"] == 10 && f["quality"] == "final") break;
  }
  ASSERT_EQ(f["quality"], "final");
  EXPECT_THAT(f["command"].get<std::string>(), HasSubstr(" --classification preintegrated"));
  test::writeBytes(dir.file("p.png"), std::vector<uint8_t>(image.begin(), image.end()));
  Quality preintegrated;
  preintegrated.classification = Classification::PreIntegrated;
  const Image wantPre = engine.render(setup.view, setup.look, preintegrated).image;
  EXPECT_EQ(readPng(dir.file("p.png"), &w, &h), toRgba8(wantPre, glm::vec3(0.0f)));
  EXPECT_NE(toRgba8(wantPre, glm::vec3(0.0f)), toRgba8(want.image, glm::vec3(0.0f)));
}

// Each client draws the isosurface it asked for once it is ready (the one it drew before until
// then), whatever another client asks, and going back to a surface still kept shows it at once.
TEST(ViewerServer, EachClientDrawsItsOwnIsosurface) {
  TestServer s(1000.0);
  Socket a(s.port(), "/ws?token=" + s.token()), b(s.port(), "/ws?token=" + s.token());
  a.next();
  b.next();
  auto ask = [](Socket& c, uint64_t seq, double iso) {
    json r = frameRequest(seq, false, 48);
    r["iso"] = iso;
    c.send(r.dump());
  };
  // The final frame of request @p seq with isovalue @p iso; every frame before it draws one of @p drawn.
  auto finalOf = [](Socket& c, uint64_t seq, double iso, const std::set<double>& drawn) {
    for (int i = 0; i < 40; ++i) {
      const json f = c.nextFrameOrError();
      if (f["type"] != "frame") return f;
      if (f["seq"] != seq) continue;
      if (!f["iso"].is_null() && !drawn.count(f["iso"].get<double>())) return f;
      EXPECT_EQ(f["surfaceReady"], f["iso"] == iso) << f.dump();
      if (f["quality"] == "final" && f["iso"] == iso) return f;
    }
    return json{{"type", "error"}, {"message", "no final frame"}};
  };
  ask(a, 1, 4.0);
  EXPECT_EQ(finalOf(a, 1, 4.0, {4.0})["iso"], 4.0);
  ask(b, 1, 6.0);
  EXPECT_EQ(finalOf(b, 1, 6.0, {4.0, 6.0})["iso"], 6.0);
  // a asks again with its own isovalue: 4 still, not b's newer 6.
  ask(a, 2, 4.0);
  json again;
  do again = a.nextFrameOrError();  // (b's surface made the server refine a's last request again)
  while (again["type"] == "frame" && again["seq"] != 2);
  EXPECT_EQ(again["iso"], 4.0) << again.dump();
  // a goes to 6 (kept) and back to 4 (kept): each shown from the first frame.
  ask(a, 3, 6.0);
  EXPECT_EQ(finalOf(a, 3, 6.0, {6.0})["iso"], 6.0);
  ask(a, 4, 4.0);
  EXPECT_EQ(finalOf(a, 4, 4.0, {4.0})["iso"], 4.0);
}

// A new isovalue's final frame waits for its surface while nothing of it can be drawn (on a large
// study the final frame takes seconds and would hold the first look back); the frames refining
// towards it are drawn meanwhile, and a client asking no surface gets its final frame.
TEST(ViewerServer, ANewIsovaluesFinalFrameWaitsForItsSurface) {
  TestServer s(1000.0, 8, [](ServerOptions& o) {
    o.loader = [](const std::string&, const std::string&, const Progress*) { return sphereScene({128, 128, 128}, 48.0); };
  });
  Socket a(s.port(), "/ws?token=" + s.token()), b(s.port(), "/ws?token=" + s.token());
  a.next();
  b.next();
  json plain = frameRequest(1, false, 48);
  plain.erase("iso");
  a.send(plain.dump());  // (its bricks uploaded: the frames below take milliseconds, the surface a second)
  json f;
  do f = a.nextFrameOrError();
  while (f["type"] == "frame" && f["quality"] != "final");
  a.send(frameRequest(2, false, 48).dump());
  b.send(plain.dump());
  int before = 0;
  for (f = a.nextFrameOrError(); f["type"] == "frame" && f["quality"] != "final"; f = a.nextFrameOrError()) ++before;
  ASSERT_EQ(f["type"], "frame") << f.dump();
  EXPECT_EQ(f["iso"], 4.0) << "the first final frame draws the surface asked for: " << f.dump();
  EXPECT_EQ(f["surfaceReady"], true) << f.dump();
  EXPECT_GE(before, 1) << "the coarser frames before it are drawn";
  json g;
  do g = b.nextFrameOrError();
  while (g["type"] == "frame" && g["quality"] != "final");
  EXPECT_TRUE(g["type"] == "frame" && g["iso"].is_null()) << g.dump();
}

// The sharper step is drawn as the final frame is and takes seconds on a clinical study: it waits
// for a new surface as the final frame does (after a volume's orbit the surface's first look came
// after a sharper step of the volume alone); coarser refinements and moving frames do not wait.
TEST(ViewerServer, TheSharperStepWaitsForANewSurfaceAsTheFinalFrameDoes) {
  const int sharper = 1;
  EXPECT_TRUE(waitsForSurface(0, sharper, false, true, false));
  EXPECT_TRUE(waitsForSurface(sharper, sharper, false, true, false));
  EXPECT_FALSE(waitsForSurface(2, sharper, false, true, false)) << "a coarser refinement is drawn meanwhile";
  EXPECT_FALSE(waitsForSurface(1, -1, false, true, false)) << "without a sharper step, level 1 is a refinement";
  EXPECT_FALSE(waitsForSurface(sharper, sharper, true, true, false)) << "moving frames never wait";
  EXPECT_FALSE(waitsForSurface(0, sharper, false, false, false)) << "nothing on its way";
  EXPECT_FALSE(waitsForSurface(0, sharper, false, true, true)) << "something of it drawn";
}

// Interactive frames until one comes at the best interactive level (full size, no budget): the
// first of a volume just opened are the cheapest without a budget (nothing measured predicts the others), the
// first of them uploading its textures (not taken as the level's time). Returns that frame.
json warmUp(Socket& c, int pixels) {
  for (uint64_t seq = 1000; seq < 1010; ++seq) {
    const json f = answer(c, frameRequest(seq, true, pixels));
    EXPECT_EQ(f["type"], "frame") << f.dump();
    if (seq == 1000) {
      EXPECT_EQ(f["level"], AdaptiveQuality(kVolumeLadder).firstLevel()) << "the first frame: the cheapest without a budget";
    }
    if (f["type"] != "frame" || f["level"] == 1) return f;
  }
  ADD_FAILURE() << "no interactive frame at the best level";
  return {};
}

// In memory or paged (the ray tracer reads a scene file's cached blocks in place).
class SurfaceRays : public ::testing::TestWithParam<bool> {};

TEST_P(SurfaceRays, TheSurfacesSmallMovingFramesAreRayTraced) {
  const bool paged = GetParam();
  test::TempDir dir;
  saveScene(dir.file("s.hoct"), sphereScene().volume, sphereScene().octree);
  TestServer s(1.0, 8, [&](ServerOptions& o) {  // no rung fits: moving frames stay on the cheapest ones
    o.loader = [&](const std::string&, const std::string&, const Progress*) {
      return loadScene(dir.file("s.hoct"), SceneLoadOptions{!paged, 1 << 20});
    };
  });
  Socket c(s.port(), "/ws?token=" + s.token());
  c.next();  // info
  // Moving frames: once the surface is built, those of the surface's ladder are ray-traced (the
  // first may have been chosen before the surface was ready).
  json f;
  int surfaceFrames = 0, rayTraced = 0;
  for (uint64_t seq = 1; seq < 200 && surfaceFrames < 6; ++seq) {
    c.send(frameRequest(seq, true, 64).dump());
    do f = c.nextFrameOrError();
    while (f["type"] == "frame" && f["seq"] != seq);
    ASSERT_EQ(f["type"], "frame") << f.dump();
    if (f["ladder"] == "surface" && ++surfaceFrames > 1) {
      const bool rays = f["levelText"].get<std::string>().find("ray-traced") != std::string::npos;
      EXPECT_EQ(rays, kSurfaceRayLadder[f["level"].get<size_t>()].rays) << f["levelText"];
      rayTraced += rays;
    }
  }
  EXPECT_EQ(surfaceFrames, 6);
  EXPECT_GE(rayTraced, 1);  // (the ladder's first frame is its cheapest; a tiny scene's frames may climb)
  // The final frame is the slice frame.
  c.send(frameRequest(500, false, 64).dump());
  for (int i = 0; i < 20 && f["quality"] != "final"; ++i) {
    do f = c.nextFrameOrError();
    while (f["type"] == "frame" && f["seq"] != 500);
  }
  ASSERT_EQ(f["quality"], "final");
  EXPECT_THAT(f["levelText"].get<std::string>(), Not(HasSubstr("ray-traced")));
}

INSTANTIATE_TEST_SUITE_P(ViewerServer, SurfaceRays, ::testing::Values(false, true),
                         [](const ::testing::TestParamInfo<bool>& p) { return p.param ? "Paged" : "InMemory"; });

TEST(ViewerServer, InteractiveFramesUseLargerBricksAndTheScreenSpaceLevelOfDetail) {
  TestServer s(1000.0);
  Socket c(s.port(), "/ws?token=" + s.token());
  c.next();  // info
  // A small, wide view: a pixel spans about ten voxels, so texels of four voxels are finer than it.
  auto wide = [](uint64_t seq) {
    json q = frameRequest(seq, true, 16);
    q["fov"] = 120;
    return q;
  };
  json f;
  for (uint64_t seq = 1; seq < 10 && f["level"] != 1; ++seq) {
    c.send(wide(seq).dump());
    do f = c.nextFrameOrError();
    while (f["type"] == "frame" && f["seq"] != seq);
  }
  ASSERT_EQ(f["level"], 1) << f.dump();
  SceneRenderer engine(sphereScene());
  const FrameRequest r = std::get<FrameRequest>(parseRequest(wide(1).dump()));
  std::ostringstream warnings;
  const FrameSetup setup = setUpFrame(r.settings, engine.scene(), warnings);
  const View& view = setup.view;
  Look look = setup.look;
  look.iso.reset();
  Quality quality;
  quality.maxBrickEdge = kInteractiveBrickEdge;
  quality.lodPixels = kInteractiveLodPixels;
  const FrameStats interactive = engine.render(view, look, quality).stats;
  quality.lodPixels = 0.0;
  const FrameStats fullResolution = engine.render(view, look, quality).stats;
  quality.maxBrickEdge = Quality{}.maxBrickEdge;
  const size_t small = engine.render(view, look, quality).stats.slices.bricks;
  EXPECT_LT(fullResolution.slices.bricks, small);
  EXPECT_LT(interactive.slices.textureBytes, fullResolution.slices.textureBytes / 2);  // coarser bricks where texels are finer than pixels
  EXPECT_EQ(f["bricks"], interactive.slices.bricks);
  EXPECT_EQ(f["textureBytes"], interactive.slices.textureBytes);
  EXPECT_EQ(f["bricksNotResident"], 0);  // (samples in memory: every brick at hand)
  // The final frame of that view stops where texels are half a pixel apart: fewer texels than full
  // resolution, where a pixel spans ten voxels.
  json final = frameRequest(100, false, 16);
  final["fov"] = 120;
  c.send(final.dump());
  do f = c.nextFrameOrError();
  while (f["type"] == "frame" && (f["seq"] != 100 || f["quality"] != "final"));
  quality = Quality{};
  quality.lodPixels = kFinalLodPixels;
  const FrameStats finalStats = engine.render(view, look, quality).stats;
  EXPECT_EQ(f["textureBytes"], finalStats.slices.textureBytes) << f.dump();
  EXPECT_LT(finalStats.slices.textureBytes, engine.render(view, look, Quality{}).stats.slices.textureBytes);
}

TEST(ViewerServer, ClientsKeepTheirOwnViewsAndStaleRequestsAreDropped) {
  TestServer s(1000.0);  // a generous target: interactive frames at the first rung
  Socket a(s.port(), "/ws?token=" + s.token()), b(s.port(), "/ws?token=" + s.token());
  a.next();
  b.next();
  warmUp(a, 64);
  // Twenty requests in a burst: fewer frames come back than were asked for, the last answers the last.
  for (uint64_t seq = 1; seq <= 20; ++seq) a.send(frameRequest(seq, true, 64, double(seq)).dump());
  b.send(frameRequest(100, false, 48).dump());
  int frames = 0;
  json last;
  while (last.is_null() || last["seq"] != 20) {
    last = a.nextFrameOrError();
    ASSERT_EQ(last["type"], "frame");
    if (last["seq"] >= 1000) continue;  // the warm-up's last request, refined again (a surface came)
    EXPECT_EQ(last["width"], 64);
    EXPECT_EQ(last["quality"], "interactive");
    ++frames;
  }
  EXPECT_LT(frames, 20);
  json fb;
  do {
    fb = b.nextFrameOrError();
    ASSERT_EQ(fb["type"], "frame");
    EXPECT_EQ(fb["seq"], 100);
  } while (fb["quality"] != "final");
  EXPECT_EQ(fb["width"], 48);  // b's own size, not a's
  // A client that leaves mid-frame harms nothing: the next one is served.
  {
    Socket gone(s.port(), "/ws?token=" + s.token());
    gone.next();
    gone.send(frameRequest(1, false, 256).dump());
  }
  Socket next(s.port(), "/ws?token=" + s.token());
  next.next();
  next.send(frameRequest(5, true).dump());
  EXPECT_EQ(next.nextFrameOrError()["seq"], 5);
  EXPECT_EQ(s.loads, 1);  // the volume was loaded once for every client
}

TEST(ViewerServer, ClientsBeyondTheLimitAreToldAndClosed) {
  TestServer s(60.0, 1);
  Socket first(s.port(), "/ws?token=" + s.token());
  EXPECT_EQ(first.next()["type"], "info");
  Socket second(s.port(), "/ws?token=" + s.token());
  const json m = second.next();
  EXPECT_EQ(m["type"], "error");
  EXPECT_THAT(m["message"].get<std::string>(), HasSubstr("1 clients at most"));
  beast::flat_buffer sink;
  beast::error_code ec;
  second.ws.read(sink, ec);
  EXPECT_EQ(ec, websocket::error::closed);
  first.send(frameRequest(1, true).dump());  // the first is still served
  EXPECT_EQ(first.nextFrameOrError()["seq"], 1);
}

// A band sized by the last large frame's row times: the rows from the first whose times fit, at
// least the least and at most the most rows, never past the last row.
TEST(ViewerServer, ABandTakesTheRowsWhoseLastTimesFit) {
  const std::vector<float> rowMs = {1, 1, 1, 10, 10, 10, 1, 1};
  EXPECT_EQ(rowsWithin(rowMs, 0, 15.0, {1, 8}), 4);  // 1 + 1 + 1 + 10 = 13; a fifth row makes 23
  EXPECT_EQ(rowsWithin(rowMs, 3, 15.0, {1, 8}), 1);
  EXPECT_EQ(rowsWithin(rowMs, 3, 5.0, {1, 8}), 1);   // the least, though it takes longer
  EXPECT_EQ(rowsWithin(rowMs, 3, 15.0, {2, 8}), 2);
  EXPECT_EQ(rowsWithin(rowMs, 0, 100.0, {1, 5}), 5);  // the most
  EXPECT_EQ(rowsWithin(rowMs, 6, 100.0, {1, 8}), 2);  // the last rows
  EXPECT_EQ(rowsWithin(rowMs, 0, 35.0, {1, 8}), 8);   // 35 exactly: all of them
}

// While another client moves, a band of a large frame never holds more rows than would fit if
// each cost the costliest rows known: a first frame's band stops at kUnmeasuredBandRows (after
// cheap rows the head may begin in the next), and a band sized by the last frame's row times stops
// where its costliest rows would fill the band's time. Nobody moving, the rows' times alone size it.
TEST(ViewerServer, ABandBesideAMoverStaysWithinItsTimeWhereTheCostlyRowsMayBegin) {
  BandedFrame b(std::get<FrameRequest>(parseRequest(frameRequest(1, false, 2048).dump())), SurfaceShown(ScenePool::Frame{}));
  b.size = {2048, 2048};
  b.rowMs.assign(2048, 0.0f);
  b.next = 256;
  b.msPerRow = b.lastMsPerRow = 0.1;  // empty rows so far: 150 ms would take 1,500 of them
  EXPECT_EQ(bandRows(b, 150.0, true), kUnmeasuredBandRows);
  EXPECT_EQ(bandRows(b, 150.0, false), kBandPixels / 2048);
  b.msPerRow = b.lastMsPerRow = 5.0;  // into the skull: its own time sizes the band
  EXPECT_EQ(bandRows(b, 150.0, true), 30);
  b.msPerRow = b.lastMsPerRow = 2.5;  // (60 rows' worth)
  EXPECT_EQ(bandRows(b, 150.0, true), kUnmeasuredBandRows);
  // Row times of the last frame: cheap rows above costly ones (3 ms a row from row 600).
  b.msPerRow = b.lastMsPerRow = 0.0;
  b.next = 0;
  b.predicted.assign(2048, 0.1f);
  std::fill(b.predicted.begin() + 600, b.predicted.begin() + 1400, 3.0f);
  b.costliestRowMs = 3.0f;
  EXPECT_EQ(bandRows(b, 150.0, true), 50);   // 150 / 3
  EXPECT_EQ(bandRows(b, 150.0, false), 128);  // the cheap rows' times: kBandPixels' worth
  b.costliestRowMs = 0.0f;                    // (the cap alone makes the difference)
  EXPECT_EQ(bandRows(b, 150.0, true), 128);
}

// The sharper step before a slow final frame is its rung's size and spacing, drawn as the final
// frame is: the final frame's bricks (their textures kept from the last final frame) and its
// surface, cut to the slabs; the same rung moving, or refining first, draws the moving frames'
// bricks within the packing bound and the simplified surface uncut.
TEST(ViewerServer, TheSharperStepDrawsTheFinalFramesBricksAndSurface) {
  const Scene scene = sphereScene();
  const FrameRequest r = std::get<FrameRequest>(parseRequest(frameRequest(1, false, 512).dump()));
  UserGeometryMemo memo;
  const FrameSetup final = frameParts(r, scene, {kSurfaceLadder[0], 0, false}, 6.0f, memo);
  const FrameSetup refining = frameParts(r, scene, {kSurfaceLadder[1], 1, false}, 6.0f, memo);
  const FrameSetup sharper = frameParts(r, scene, {kSurfaceLadder[1], 1, true}, 6.0f, memo);
  for (const FrameSetup* f : {&refining, &sharper}) {
    EXPECT_EQ(f->view.camera.width, 512);
    EXPECT_EQ(f->quality.step, 1.5);
  }
  EXPECT_EQ(final.view.camera.width, 512);
  EXPECT_EQ(sharper.quality.maxBrickEdge, final.quality.maxBrickEdge);
  EXPECT_EQ(sharper.quality.lodPixels, kFinalLodPixels);
  EXPECT_EQ(sharper.quality.packTexels, final.quality.packTexels);
  EXPECT_EQ(sharper.quality.waitForBricks, final.quality.waitForBricks);
  EXPECT_EQ(sharper.quality.simplifiedSurface, final.quality.simplifiedSurface);
  EXPECT_FALSE(sharper.quality.simplifiedSurface);
  EXPECT_EQ(sharper.quality.cutToSlabs, final.quality.cutToSlabs);
  EXPECT_TRUE(sharper.quality.cutToSlabs);
  EXPECT_EQ(refining.quality.maxBrickEdge, kInteractiveBrickEdge);
  EXPECT_NE(refining.quality.maxBrickEdge, final.quality.maxBrickEdge);
  EXPECT_EQ(refining.quality.lodPixels, kInteractiveLodPixels);
  EXPECT_EQ(refining.quality.packTexels, kInteractivePackTexels);
  EXPECT_FALSE(refining.quality.waitForBricks);
  EXPECT_TRUE(refining.quality.simplifiedSurface);
  EXPECT_FALSE(refining.quality.cutToSlabs);
}

// The sharper step goes out as PNG, as the final frame does: it differs from the final frame by
// less than JPEG would change it; the other frames before the final one are JPEG.
TEST(ViewerServer, TheSharperStepIsSentAsPng) {
  const SceneSummary summary;
  const FrameRequest r = std::get<FrameRequest>(parseRequest(frameRequest(1, false, 512).dump()));
  const SurfaceShown surface(ScenePool::Frame{});
  const std::optional<Arrival> arrival;
  const FrameStats stats;
  for (const bool sharper : {false, true}) {
    const FrameHeader h{summary, r, kSurfaceLadder[1], 1, false, surface, arrival, stats, 0.0, 10.0, 1, 10.0, sharper};
    const json text = json::parse(h.text(512, 512, 1.0));
    EXPECT_EQ(text["quality"], "refining");
    EXPECT_EQ(text["format"], sharper ? "png" : "jpeg");
  }
}

// A client's 2048² final frame is drawn band by band (16 of them), the other clients' frames between
// its bands: another client dragging meanwhile waits about a band for each of its frames, far less
// than the whole frame (the bound is relative, as the machine's load scales both), and the large
// frame still arrives whole.
TEST(ViewerServer, ALargeFinalFrameDoesNotHoldOtherClientsFrames) {
  TestServer s(60.0);
  Socket big(s.port(), "/ws?token=" + s.token()), mover(s.port(), "/ws?token=" + s.token());
  big.next();
  mover.next();
  warmUp(mover, 64);
  json close = frameRequest(1, false, 2048);
  close["eye"] = {19.5, -10.0, 20.0};  // near: the sphere fills the frame
  const auto sent = std::chrono::steady_clock::now();
  big.send(close.dump());
  std::atomic<bool> done{false};
  json final;
  std::thread reader([&] {
    for (;;) {
      const json f = big.nextFrameOrError();
      if (f["type"] != "frame" || f["quality"] == "final") {
        final = f;
        break;
      }
    }
    done = true;
  });
  double worst = 0.0;
  int frames = 0;
  for (uint64_t seq = 10; !done && seq < 400; ++seq) {
    const auto t0 = std::chrono::steady_clock::now();
    const json f = answer(mover, frameRequest(seq, true, 64, double(seq)));
    ASSERT_EQ(f["type"], "frame") << f.dump();
    worst = std::max(worst, std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
    // A moving frame goes before any refinement or band not deferred 300 ms yet: it waits for
    // the render under way only.
    EXPECT_LE(f["waitedRenders"].get<int>(), 1) << f.dump();
    ++frames;
  }
  reader.join();
  const double wholeMs = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - sent).count();
  ASSERT_EQ(final["type"], "frame") << final.dump();
  EXPECT_EQ(final["width"], 2048);
  EXPECT_EQ(final["format"], "png");
  // While the mover moved, the bands were cut to its frame target (60 ms) from the rows' measured time.
  EXPECT_GT(final["bands"].get<int>(), 2048 * 2048 / (512 * 512)) << final.dump();  // (kBandPixels each when nobody moves)
  EXPECT_GT(frames, 3) << "the mover was served while the large frame was drawn (" << wholeMs << " ms)";
  EXPECT_LE(worst, wholeMs / 4) << "a moving frame waited " << worst << " ms behind the large frame (" << wholeMs << " ms in all)";
}

// Four clients with four isovalues (and one without a surface) each draw their own surface once it
// is ready, never another's; each hears of its own surface's build only; the surfaces they show are
// all kept, so asking again draws each at once.
TEST(ViewerServer, FourClientsWithFourIsovaluesEachSeeTheirOwnSurface) {
  TestServer s(1000.0);
  const double isos[] = {2.0, 4.0, 6.0, 8.0};
  std::vector<std::unique_ptr<Socket>> clients;
  for (int k = 0; k < 5; ++k) {
    clients.push_back(std::make_unique<Socket>(s.port(), "/ws?token=" + s.token()));
    clients.back()->next();
  }
  auto ask = [&](int k, uint64_t seq) {
    json r = frameRequest(seq, false, 40);
    if (k < 4)
      r["iso"] = isos[k];
    else
      r["iso"] = nullptr;
    clients[size_t(k)]->send(r.dump());
  };
  for (int k = 0; k < 5; ++k) ask(k, 1);
  // Each until its final frame with its own surface; everything it hears on the way is its own.
  for (int k = 0; k < 5; ++k) {
    for (int i = 0; i < 60; ++i) {
      const json m = clients[size_t(k)]->next();
      if (m["type"] == "surface") {
        EXPECT_LT(k, 4) << "a client without a surface heard of a build: " << m.dump();
        if (k < 4) {
          EXPECT_EQ(m["iso"], isos[k]) << "client " << k << " heard of another's build: " << m.dump();
        }
        continue;
      }
      ASSERT_EQ(m["type"], "frame") << m.dump();
      if (k == 4) {
        EXPECT_TRUE(m["iso"].is_null()) << m.dump();
      } else if (!m["iso"].is_null()) {
        EXPECT_EQ(m["iso"], isos[k]) << "client " << k << " was shown another's surface";
      }
      if (m["quality"] == "final" && (k == 4 || m["iso"] == isos[k])) break;
    }
  }
  // Asked again: every surface is still there, drawn from the first frame on.
  for (int k = 0; k < 4; ++k) {
    ask(k, 2);
    json f;
    do f = clients[size_t(k)]->nextFrameOrError();
    while (f["type"] == "frame" && f["seq"] != 2);
    EXPECT_EQ(f["iso"], isos[k]) << f.dump();
    EXPECT_EQ(f["surfaceReady"], true) << "client " << k << "'s surface was dropped and built again";
  }
}

// A socket that sends a message a byte at a time, too slowly, is closed once the message timeout
// (here 600 ms) has passed since its first byte; a socket idle for longer is not, and is served.
TEST(ViewerServer, ATricklingSocketIsClosedAnIdleOneIsNot) {
  TestServer s(60.0, 8, [](ServerOptions& o) { o.messageTimeout = std::chrono::milliseconds(600); });
  Socket trickle(s.port(), "/ws?token=" + s.token()), idle(s.port(), "/ws?token=" + s.token());
  trickle.next();
  idle.next();
  const std::string text = frameRequest(1, true).dump();
  trickle.ws.text(true);
  const auto t0 = std::chrono::steady_clock::now();
  beast::error_code ec;
  for (size_t i = 0; i < text.size() && !ec; ++i) {
    trickle.ws.write_some(false, net::buffer(text.data() + i, 1), ec);
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  beast::flat_buffer sink;
  for (int i = 0; i < 10 && !ec; ++i) trickle.ws.read(sink, ec);
  const double closedAfter = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  EXPECT_TRUE(ec) << "the trickling socket stayed open";
  EXPECT_GE(closedAfter, 500.0);
  EXPECT_LE(closedAfter, 3000.0);
  // The idle socket waited as long, and is still served.
  idle.send(frameRequest(2, true).dump());
  EXPECT_EQ(idle.nextFrameOrError()["seq"], 2);
}

// Text frames of one byte ("x": not JSON), masked as a client's must be (with a zero key).
std::string invalidMessages(int count) {
  std::string out;
  for (int i = 0; i < count; ++i) out += std::string("\x81\x81\0\0\0\0x", 7);
  return out;
}

// Asks @p c for a moving frame and returns the message answering it (a frame, or an error).
json askFrame(Socket& c, uint64_t seq) { return answer(c, frameRequest(seq, true, 32, double(seq))); }

// A client with the token floods the server with up to 100,000 invalid one-byte messages without
// reading the error replies, then resets its connection (SO_LINGER 0). Another client gets a frame
// after each thousand of them, and five more after the reset; new clients are served afterwards.
// (The flood ends early if the server closes the flooding client first: its replies past the bound.)
TEST(ViewerServer, AClientFloodingAndResettingHarmsNoOther) {
  TestServer s(1000.0);
  Socket calm(s.port(), "/ws?token=" + s.token());
  calm.next();  // info
  uint64_t seq = 0;
  {
    Socket flood(s.port(), "/ws?token=" + s.token());
    const std::string batch = invalidMessages(1000);
    beast::error_code ec;
    int sent = 0;
    while (sent < 100000) {
      net::write(flood.ws.next_layer(), net::buffer(batch), ec);
      if (ec) break;
      sent += 1000;
      ASSERT_EQ(askFrame(calm, ++seq)["type"], "frame") << "after " << sent << " invalid messages";
    }
    const linger reset{1, 0};
    ::setsockopt(flood.ws.next_layer().native_handle(), SOL_SOCKET, SO_LINGER, &reset, sizeof reset);
    flood.ws.next_layer().close(ec);
  }
  for (int i = 0; i < 5; ++i) ASSERT_EQ(askFrame(calm, ++seq)["type"], "frame");
  Socket next(s.port(), "/ws?token=" + s.token());
  EXPECT_EQ(next.next()["type"], "info");
  EXPECT_EQ(askFrame(next, 1)["type"], "frame");
}

// A client that sends invalid messages without reading the replies has at most
// kMaxQueuedTextBytes of them waiting: past that it is closed, its replies cut short (what the
// sockets' buffers held reaches it, then the end).
TEST(ViewerServer, AClientThatDoesNotReadItsRepliesIsClosed) {
  TestServer s;
  Socket f(s.port(), "/ws?token=" + s.token());
  const std::string batch = invalidMessages(1000);
  beast::error_code ec;
  int sent = 0;
  for (; sent < 100000 && !ec; sent += 1000) net::write(f.ws.next_layer(), net::buffer(batch), ec);
  // The info, then the replies until the end.
  int messages = 0;
  beast::flat_buffer sink;
  for (ec = {}; messages <= sent; ++messages) {
    f.ws.read(sink, ec);
    if (ec) break;
    sink.consume(sink.size());
  }
  EXPECT_TRUE(ec) << "the socket stayed open";
  EXPECT_LT(messages, sent) << "every reply came: nothing bounded them";
  Socket next(s.port(), "/ws?token=" + s.token());
  EXPECT_EQ(next.next()["type"], "info");
}

// Volumes opened from the data directory: every message names its volume, a request for the one
// shown before is dropped, the load's progress is told to the client waiting for it, and a volume
// no client shows is released after the stated delay (opened again, it is read again).
TEST(ViewerServer, SwitchingVolumesTagsEveryMessageAndReleasesTheOneLeft) {
  test::TempDir dir;
  for (const char* name : {"a.nrrd", "b.nrrd"}) test::writeText(dir.file(name), "NRRD0004\n");
  TestServer s(60.0, 8, [&](ServerOptions& o) {
    o.volume.clear();
    o.dataDir = dir.path();
    o.releaseAfter = std::chrono::milliseconds(300);
  });
  Socket c(s.port(), "/ws?token=" + s.token());
  EXPECT_EQ(c.next()["type"], "volumes");
  // Opens @p name: until its info comes, the client hears of its load, or of the volume it showed
  // (@p shown), each message saying which.
  auto open = [&](const std::string& name, const std::string& shown) {
    c.send(json{{"type", "open"}, {"path", name}}.dump());
    std::vector<json> loading;
    for (;;) {
      const json m = c.next();
      if (m["type"] == "info") {
        EXPECT_EQ(m["scene"], name);
        return loading;
      }
      if (m["type"] == "loading") {
        EXPECT_EQ(m["scene"], name);
        loading.push_back(m);
      } else {
        EXPECT_EQ(m["scene"], shown) << m.dump();
      }
    }
  };
  const std::vector<json> loads = open("a.nrrd", "");
  ASSERT_GE(loads.size(), 2u);  // the start and the loader's own task
  EXPECT_EQ(loads.back()["task"], "reading");
  json r = frameRequest(1, false, 32);
  r["scene"] = "a.nrrd";
  c.send(r.dump());
  json f;
  do f = c.nextFrameOrError();
  while (f["type"] == "frame" && f["quality"] != "final");
  EXPECT_EQ(f["scene"], "a.nrrd");
  open("b.nrrd", "a.nrrd");
  r["seq"] = 2;  // still of a: dropped
  c.send(r.dump());
  r["seq"] = 3;
  r["scene"] = "b.nrrd";
  c.send(r.dump());
  do f = c.nextFrameOrError();
  while (f["type"] == "frame" && f["scene"] == "a.nrrd");  // (a frame of a under way when b opened)
  EXPECT_EQ(f["seq"], 3) << "the request of the volume shown before was answered";
  EXPECT_EQ(f["scene"], "b.nrrd");
  // a is released 300 ms after the client left it: opened again, it is read again.
  std::this_thread::sleep_for(std::chrono::milliseconds(700));
  EXPECT_EQ(s.loadsOfFile("a.nrrd"), 1);
  open("a.nrrd", "b.nrrd");
  EXPECT_EQ(s.loadsOfFile("a.nrrd"), 2);
  EXPECT_EQ(s.loadsOfFile("b.nrrd"), 1);
}

// A volume of the data directory that cannot be read: the client hears why, in the words of the
// listing and with the data directory's own path left out, and keeps the volume it showed.
// The server fetches only from its own PACS: an address elsewhere is refused before any request;
// a search the archive cannot answer is one error message (the archive here refuses connections).
TEST(ViewerServer, APacsServerOpensOnlyItsOwnSeries) {
  const std::string root = "http://127.0.0.1:1/dicom-web";
  TestServer s(60.0, 8, [&](ServerOptions& o) { o.pacs = root + "/"; });
  Socket c(s.port(), "/ws?token=" + s.token());
  const json info = c.next();
  ASSERT_EQ(info["type"], "info");
  EXPECT_EQ(info["pacs"], root + "/");
  for (const std::string& url : std::vector<std::string>{"http://evil.example/dicom-web/studies/1/series/2", root + "x/studies/1/series/2", root + "/studies/1"}) {
    c.send(json{{"type", "open"}, {"url", url}}.dump());
    const json e = c.next();
    EXPECT_EQ(e["type"], "error") << url;
    EXPECT_THAT(e["message"].get<std::string>(), HasSubstr("open: url must be a series of " + root + " (ROOT/studies/UID/series/UID)")) << url;
  }
  EXPECT_EQ(s.loads, 1);  // the sphere only: nothing was fetched
  c.send(R"({"type":"pacs-search","modality":"CT"})");
  const json refused = c.next();
  EXPECT_EQ(refused["type"], "error");
  EXPECT_THAT(refused["message"].get<std::string>(), HasSubstr("pacs: " + root));
  // An address of the PACS goes to the loader, which is what reads it.
  c.send(json{{"type", "open"}, {"url", root + "/studies/1.2/series/1.2.3"}}.dump());
  for (json m = c.next();; m = c.next())
    if (m["type"] == "info") {
      EXPECT_EQ(m["scene"], root + "/studies/1.2/series/1.2.3");
      EXPECT_EQ(m["name"], "studies/1.2/series/1.2.3");  // (no search named it)
      break;
    }
  EXPECT_EQ(s.loadsOfFile("1.2.3"), 1);
}

TEST(ViewerServer, AFailedOpenSaysWhyAndKeepsTheVolumeShown) {
  test::TempDir dir;
  for (const char* name : {"a.nrrd", "bad.nrrd"}) test::writeText(dir.file(name), "NRRD0004\n");
  TestServer s(60.0, 8, [&](ServerOptions& o) {
    o.volume.clear();
    o.dataDir = dir.path();
    o.loader = [](const std::string& path, const std::string&, const Progress*) {
      if (std::filesystem::path(path).filename() == "bad.nrrd") HYB_THROW(IoError, path, ": no 'sizes' field");
      return sphereScene();
    };
  });
  Socket c(s.port(), "/ws?token=" + s.token());
  EXPECT_EQ(c.next()["type"], "volumes");
  c.send(json{{"type", "open"}, {"path", "a.nrrd"}}.dump());
  json m;
  do m = c.next();
  while (m["type"] != "info");
  c.send(json{{"type", "open"}, {"path", "bad.nrrd"}}.dump());
  do m = c.next();
  while (m["type"] == "loading");
  ASSERT_EQ(m["type"], "error") << m.dump();
  EXPECT_EQ(m["scene"], "bad.nrrd");
  EXPECT_EQ(m["message"], "cannot open bad.nrrd: bad.nrrd: no 'sizes' field");
  json r = frameRequest(1, false, 32);
  r["scene"] = "a.nrrd";
  c.send(r.dump());
  const json f = c.nextFrameOrError();
  EXPECT_EQ(f["type"], "frame") << f.dump();
  EXPECT_EQ(f["scene"], "a.nrrd");
}


// A volume slow to load shows its preview first, under its own key and marked as one (its frames
// too, and no mesh is made of it), while the load's progress goes on; the scene then takes its
// place under the same key. A load that fails after its preview closes the preview with the error.
TEST(ViewerServer, ASlowVolumeShowsItsPreviewThenTheSceneInItsPlace) {
  test::TempDir dir;
  for (const char* name : {"slow.nrrd", "bad.nrrd"}) test::writeText(dir.file(name), "NRRD0004\n");
  std::mutex m;
  std::condition_variable cv;
  bool release = false;
  TestServer s(60.0, 8, [&](ServerOptions& o) {
    o.volume.clear();
    o.dataDir = dir.path();
    o.previewer = [](const std::string&, const std::string&, const Progress*) { return std::optional<Scene>(sphereScene({20, 18, 16}, 6.5)); };
    o.loader = [&](const std::string& path, const std::string&, const Progress* progress) {
      ProgressTask task(progress, "reading", 1);
      std::unique_lock<std::mutex> lock(m);
      cv.wait(lock, [&] { return release; });
      if (std::filesystem::path(path).filename() == "bad.nrrd") HYB_THROW(IoError, path, ": no 'sizes' field");
      return sphereScene();
    };
  });
  Socket c(s.port(), "/ws?token=" + s.token());
  EXPECT_EQ(c.next()["type"], "volumes");
  auto nextInfo = [&](const std::string& scene) {
    for (json i = c.next();; i = c.next()) {
      if (i["type"] == "info") return i;
      EXPECT_EQ(i["type"], "loading") << i.dump();
      EXPECT_EQ(i["scene"], scene);
    }
  };
  c.send(json{{"type", "open"}, {"path", "slow.nrrd"}}.dump());
  const json preview = nextInfo("slow.nrrd");
  EXPECT_EQ(preview["scene"], "slow.nrrd");
  EXPECT_EQ(preview["preview"], true);
  EXPECT_EQ(preview["dims"], json::array({20, 18, 16}));
  json r = frameRequest(1, false, 32);
  r["scene"] = "slow.nrrd";
  c.send(r.dump());
  json f;
  do f = c.nextFrameOrError();
  while (f["type"] == "frame" && f["quality"] != "final");
  EXPECT_EQ(f["preview"], true) << f.dump();
  EXPECT_FALSE(f.contains("command")) << "a preview's frame is not the render command's";
  const Reply mesh = httpRequest(s.port(), "/api/mesh?scene=slow.nrrd&iso=4&format=stl", "hyb_token=" + s.token());
  EXPECT_EQ(mesh.status, 400u) << mesh.body;  // (not of the preview: of the scene, once it is open)
  EXPECT_EQ(mesh.body, "400: slow.nrrd is still loading (a preview is shown): its mesh can be exported once it is open\n");
  {
    const std::lock_guard<std::mutex> lock(m);
    release = true;
  }
  cv.notify_all();
  json full;
  do full = c.next();
  while (full["type"] != "info");
  EXPECT_EQ(full["scene"], "slow.nrrd");
  EXPECT_EQ(full["preview"], false);
  EXPECT_EQ(full["dims"], json::array({40, 36, 32}));
  r["seq"] = 2;
  c.send(r.dump());
  do f = c.nextFrameOrError();
  while (f["type"] == "frame" && (f["seq"] != 2 || f["quality"] != "final"));
  EXPECT_EQ(f["preview"], false) << f.dump();
  EXPECT_TRUE(f.contains("command"));
  EXPECT_EQ(s.loads, 0);  // (this server's loader counts nothing: both loads are the lambda's above)

  c.send(json{{"type", "open"}, {"path", "bad.nrrd"}}.dump());
  EXPECT_EQ(nextInfo("bad.nrrd")["preview"], true);
  json e;
  do e = c.next();
  while (e["type"] == "loading");
  EXPECT_EQ(e["type"], "error") << e.dump();
  EXPECT_EQ(e["scene"], "bad.nrrd");
  EXPECT_EQ(e["message"], "cannot open bad.nrrd: bad.nrrd: no 'sizes' field");
  r["seq"] = 3;
  r["scene"] = "bad.nrrd";
  c.send(r.dump());
  const json closed = c.nextFrameOrError();
  EXPECT_EQ(closed["type"], "error") << "the preview of a volume that failed is closed: " << closed.dump();
}


// The user's geometry through the viewer's door: primitives as they are, mesh files only from the
// data directory (listed for the page; a path elsewhere, or without a data directory, refused in one
// line that names no server path), drawn by both methods; the frame differs from the one without.
TEST(ViewerServer, TheUsersGeometryIsDrawnAndItsFilesComeFromTheDataDirectoryOnly) {
  test::TempDir dir;
  test::writeText(dir.file("a.nrrd"), "NRRD0004\n");
  std::filesystem::create_directories(dir.file("models"));
  writeMesh(dir.file("models/implant.stl"), uvSphere({19.5, 17.5, 15.5}, 6.0, 12));
  test::writeText(dir.file("../outside.stl"), "solid x\nendsolid x\n");
  TestServer s(60.0, 8, [&](ServerOptions& o) {
    o.volume.clear();
    o.dataDir = dir.path();
  });
  Socket c(s.port(), "/ws?token=" + s.token());
  const json volumes = c.next();
  EXPECT_EQ(volumes["meshes"], json::array({"models/implant.stl"}));
  c.send(json{{"type", "open"}, {"path", "a.nrrd"}}.dump());
  json m;
  do m = c.next();
  while (m["type"] != "info");
  EXPECT_EQ(m["meshes"], json::array({"models/implant.stl"}));
  // The final frame of @p extra's request, its image in @p image (or the error).
  uint64_t seq = 0;
  auto finalFrame = [&](const json& extra, std::string* image) {
    json r = frameRequest(++seq, false, 64);
    r["scene"] = "a.nrrd";
    r.erase("iso");
    r.update(extra);
    c.send(r.dump());
    json f;
    do f = c.nextFrameOrError(image);
    while (f["type"] == "frame" && (f["seq"] != seq || f["quality"] != "final"));
    return f;
  };
  std::string plain, withMesh, scanned, withSphere;
  ASSERT_EQ(finalFrame(json::object(), &plain)["type"], "frame");
  ASSERT_EQ(finalFrame({{"mesh", "models/implant.stl:1,0,0,0.8"}}, &withMesh)["type"], "frame");
  ASSERT_EQ(finalFrame({{"mesh", "models/implant.stl:1,0,0,0.8"}, {"mesh_method", "scan-convert"}}, &scanned)["type"], "frame");
  ASSERT_EQ(finalFrame({{"primitive", "sphere:19.5,17.5,15.5,8:0,1,0,0.8"}}, &withSphere)["type"], "frame");
  EXPECT_NE(withMesh, plain);
  EXPECT_NE(scanned, withMesh);
  EXPECT_NE(withSphere, plain);
  for (const std::string& path : {std::string("../outside.stl"), dir.file("models/implant.stl"), std::string("models/none.stl")}) {
    const json e = finalFrame({{"mesh", path}}, nullptr);
    EXPECT_EQ(e["type"], "error") << path;
    EXPECT_THAT(e["message"].get<std::string>(), HasSubstr("mesh: path '")) << path;
  }
  const json bad = finalFrame({{"primitive", "sphere:1,2,3,-4"}}, nullptr);
  EXPECT_EQ(bad["type"], "error");
  EXPECT_THAT(bad["message"].get<std::string>(), HasSubstr("a sphere's radius > 0 mm"));

  TestServer noDir;
  Socket d(noDir.port(), "/ws?token=" + noDir.token());
  EXPECT_EQ(d.next()["type"], "info");
  json r = frameRequest(1, false, 32);
  r["mesh"] = "implant.stl";
  d.send(r.dump());
  const json refused = d.nextFrameOrError();
  EXPECT_EQ(refused["type"], "error");
  EXPECT_EQ(refused["message"], "mesh: the server has no data directory (a mesh is a file in it: start the server with --data-dir)");
}


// Movers are served in the order they asked: with four clients dragging at once, a moving frame
// waits behind at most the others' frames under way (one each), however their requests interleave.
TEST(ViewerServer, ClientsDraggingTogetherAreServedInTheOrderTheyAsked) {
  TestServer s(60.0);
  constexpr int kMovers = 4;
  std::vector<std::unique_ptr<Socket>> movers;
  for (int i = 0; i < kMovers; ++i) {
    movers.push_back(std::make_unique<Socket>(s.port(), "/ws?token=" + s.token()));
    movers.back()->next();
  }
  std::vector<std::thread> threads;
  std::vector<int> worst(kMovers, 0), frames(kMovers, 0);
  for (int i = 0; i < kMovers; ++i)
    threads.emplace_back([&, i] {
      for (uint64_t seq = 1; seq <= 25; ++seq) {
        const json f = answer(*movers[size_t(i)], frameRequest(seq, true, 64, double(seq * 7 + uint64_t(i))));
        if (f["type"] != "frame") return;
        ++frames[size_t(i)];
        worst[size_t(i)] = std::max(worst[size_t(i)], f["waitedRenders"].get<int>());
      }
    });
  for (std::thread& t : threads) t.join();
  for (int i = 0; i < kMovers; ++i) {
    EXPECT_EQ(frames[size_t(i)], 25) << "mover " << i;
    EXPECT_LE(worst[size_t(i)], kMovers - 1) << "mover " << i << " waited behind more than the others' frames";
  }
}

// Movers that ask again as soon as their frame comes keep a moving frame pending all the time; a
// large final frame of another client still gets a band once it has waited kLongestDeferMs, so it
// comes while they drag, and each moving frame waits behind the others' and a band or so.
TEST(ViewerServer, MoversAskingWithoutPauseDoNotStarveALargeFinalFrame) {
  TestServer s(60.0);
  constexpr int kMovers = 3;
  constexpr uint64_t kMostFrames = 2000;  // a mover's: then it stops, and the large frame comes anyway
  Socket big(s.port(), "/ws?token=" + s.token());
  big.next();
  std::vector<std::unique_ptr<Socket>> movers;
  for (int i = 0; i < kMovers; ++i) {
    movers.push_back(std::make_unique<Socket>(s.port(), "/ws?token=" + s.token()));
    movers.back()->next();
  }
  warmUp(*movers.front(), 64);  // (the surface built)
  std::atomic<bool> done{false};
  std::vector<std::atomic<int>> frames(kMovers);
  std::vector<int> worst(kMovers, 0);  // (each written by its mover's thread only)
  std::vector<std::thread> threads;
  const auto stop = [&] {
    done = true;
    for (std::thread& t : threads)
      if (t.joinable()) t.join();
  };
  const std::unique_ptr<void, std::function<void(void*)>> joined(&done, [&](void*) { stop(); });  // (also when a frame fails)
  for (int i = 0; i < kMovers; ++i)
    threads.emplace_back([&, i] {
      for (uint64_t seq = 10; !done && seq < 10 + kMostFrames; ++seq) {
        const json f = answer(*movers[size_t(i)], frameRequest(seq, true, 64, double(seq * 3 + uint64_t(i) * 40)));
        if (f["type"] != "frame") return;
        ++frames[size_t(i)];
        worst[size_t(i)] = std::max(worst[size_t(i)], f["waitedRenders"].get<int>());
      }
    });
  std::this_thread::sleep_for(std::chrono::milliseconds(200));  // all of them dragging
  std::vector<int> atRequest(kMovers), atFinal(kMovers);
  for (int i = 0; i < kMovers; ++i) atRequest[size_t(i)] = frames[size_t(i)];
  big.send(frameRequest(1, false, 1024).dump());
  json final;
  do final = big.nextFrameOrError();
  while (final["type"] == "frame" && final["quality"] != "final");
  for (int i = 0; i < kMovers; ++i) atFinal[size_t(i)] = frames[size_t(i)];
  stop();
  ASSERT_EQ(final["type"], "frame") << final.dump();
  EXPECT_EQ(final["width"], 1024);
  EXPECT_GT(final["bands"].get<int>(), 1) << final.dump();
  for (int i = 0; i < kMovers; ++i) {
    EXPECT_LT(atFinal[size_t(i)], int(kMostFrames) - 5) << "mover " << i << " stopped before the final frame came";
    EXPECT_GT(atFinal[size_t(i)] - atRequest[size_t(i)], 3) << "mover " << i << " was served while the large frame was drawn";
    // The others' frames and the band under way, and on a loaded machine one more step deferred.
    EXPECT_LE(worst[size_t(i)], kMovers + 1) << "mover " << i << " waited behind more than the others' frames and a band or so";
  }
}

}  // namespace
}  // namespace hyb::viewer
