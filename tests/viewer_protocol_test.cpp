#include "apps/viewer_protocol.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <string>

#include "volume/error.h"

namespace hyb::viewer {
namespace {

using ::testing::HasSubstr;

const std::string kCamera = R"("camera":{"eye":[0,-500,0],"center":[0,0,0],"up":[0,0,1],"fov":30,"pixels":[256,128]})";

std::string frame(const std::string& extra) { return R"({"type":"frame","seq":7,)" + kCamera + R"(,"tf":{"preset":"ct-bone"})" + extra + "}"; }

// The message the parser refuses @p text with.
std::string refusal(const std::string& text) {
  try {
    parseRequest(text);
  } catch (const ValueError& e) {
    return e.what();
  }
  return "(accepted)";
}

TEST(ViewerProtocol, AFrameRequestCarriesTheWholeState) {
  const Request r = parseRequest(frame(R"(,"interacting":true,"surface":{"iso":400,"color":[1,0.5,0.25,0.5]},)"
                                       R"("cut":{"point":[1,2,3],"normal":[0,2,0]},"voi":{"min":[-10,-10,-10],"max":[10,20,30],"outside":0.2},"shading":false,)"
                                       R"("classification":"preintegrated")"));
  const FrameRequest& f = std::get<FrameRequest>(r);
  EXPECT_EQ(f.seq, 7u);
  EXPECT_TRUE(f.interacting);
  EXPECT_EQ(f.camera.eye, glm::dvec3(0, -500, 0));
  EXPECT_EQ(f.camera.width, 256);
  EXPECT_EQ(f.camera.height, 128);
  EXPECT_EQ(f.preset, "ct-bone");
  ASSERT_TRUE(f.iso.has_value());
  EXPECT_EQ(*f.iso, 400.0f);
  EXPECT_EQ(f.surfaceColor, glm::vec4(1, 0.5f, 0.25f, 0.5f));
  ASSERT_TRUE(f.cut.has_value());
  EXPECT_EQ(f.cut->normal, glm::dvec3(0, 2, 0));
  ASSERT_TRUE(f.voi.has_value());
  EXPECT_EQ(f.voi->hi, glm::dvec3(10, 20, 30));
  EXPECT_DOUBLE_EQ(f.voi->outside, 0.2);
  EXPECT_FALSE(f.shading);
  EXPECT_EQ(f.classification, Classification::PreIntegrated);
  // Points and an opacity scale: the transfer function scaled, clamped at 1.
  const FrameRequest p = std::get<FrameRequest>(parseRequest(
      R"({"type":"frame","seq":1,)" + kCamera + R"(,"tf":{"points":[[0,1,1,1,0],[100,1,0,0,0.4]],"opacity":3}})"));
  const TransferFunction tf = p.transferFunction();
  ASSERT_EQ(tf.points().size(), 2u);
  EXPECT_FLOAT_EQ(tf.points()[1].alpha, 1.0f);
  EXPECT_FLOAT_EQ(tf.lookup(50).a, 0.5f);
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
      {frame(R"(,"colour":1)"), "'colour': expected no such field"},
      {frame(R"(,"classification":"pre")"), "'classification'"},
      {frame(R"(,"classification":1)"), "'classification'"},
      {R"({"type":"frame","seq":-1,)" + kCamera + R"(,"tf":{"preset":"ct-bone"}})", "'seq'"},
      {R"({"type":"frame","seq":1.5,)" + kCamera + R"(,"tf":{"preset":"ct-bone"}})", "'seq'"},
      {R"({"type":"frame","seq":1,"tf":{"preset":"ct-bone"}})", "'camera'"},
      {R"({"type":"frame","seq":1,"camera":{"eye":[0,0,1e400],"center":[0,0,0],"up":[0,1,0],"pixels":[64,64]},"tf":{"preset":"ct-bone"}})", "number overflow"},
      {R"({"type":"frame","seq":1,"camera":{"eye":[0,0,0],"center":[0,0,0],"up":[0,1,0],"pixels":[64,64]},"tf":{"preset":"ct-bone"}})", "'camera.eye'"},
      {R"({"type":"frame","seq":1,"camera":{"eye":[0,0,5],"center":[0,0,0],"up":[0,0,1],"pixels":[64,64]},"tf":{"preset":"ct-bone"}})", "'camera.up'"},
      {R"({"type":"frame","seq":1,"camera":{"eye":[0,0,5],"center":[0,0,0],"up":[0,1,0],"pixels":[100000,64]},"tf":{"preset":"ct-bone"}})", "'camera.pixels[0]'"},
      {R"({"type":"frame","seq":1,"camera":{"eye":[0,0,5],"center":[0,0,0],"up":[0,1,0],"pixels":[64.5,64]},"tf":{"preset":"ct-bone"}})", "'camera.pixels'"},
      {R"({"type":"frame","seq":1,"camera":{"eye":[0,0,5],"center":[0,0,0],"up":[0,1,0],"fov":0,"pixels":[64,64]},"tf":{"preset":"ct-bone"}})", "'camera.fov'"},
      {R"({"type":"frame","seq":1,"camera":{"eye":"here","center":[0,0,0],"up":[0,1,0],"pixels":[64,64]},"tf":{"preset":"ct-bone"}})", "'camera.eye'"},
      {R"({"type":"frame","seq":1,)" + kCamera + R"(,"tf":{"preset":"ct-lungs"}})", "'tf.preset'"},
      {R"({"type":"frame","seq":1,)" + kCamera + R"(,"tf":{}})", "'tf'"},
      {R"({"type":"frame","seq":1,)" + kCamera + R"(,"tf":{"points":[[0,1,1,1,2]]}})", "'tf.points[0][4]'"},
      {R"({"type":"frame","seq":1,)" + kCamera + R"(,"tf":{"points":[[5,1,1,1,0],[1,1,1,1,0]]}})", "'tf.points[1]'"},
      {R"({"type":"frame","seq":1,)" + kCamera + R"(,"tf":{"preset":"ct-bone","opacity":11}})", "'tf.opacity'"},
      {frame(R"(,"surface":{"color":[1,1,1,1]})"), "'surface.iso'"},
      {frame(R"(,"surface":{"iso":1,"color":[1,1,1]})"), "'surface.color'"},
      {frame(R"(,"cut":{"point":[0,0,0],"normal":[0,0,0]})"), "'cut.normal'"},
      {frame(R"(,"voi":{"min":[0,0,0],"max":[1,1,0]})"), "'voi.max'"},
      {frame(R"(,"voi":{"min":[0,0,0],"max":[1,1,1],"inside":-1})"), "'voi.inside'"},
      {R"({"type":"open"})", "'path'"},
      {R"({"type":"open","path":""})", "'path'"},
      {R"({"type":"frame","seq":1,"camera":{"eye":[[[[[[[[[[1]]]]]]]]]]}})", "nested deeper"},
  };
  for (const auto& [text, expected] : cases) EXPECT_THAT(refusal(text), HasSubstr(expected)) << text;
  // Too many points, and a message over the size limit.
  std::string many = R"({"type":"frame","seq":1,)" + kCamera + R"(,"tf":{"points":[)";
  for (int i = 0; i < 65; ++i) many += (i ? "," : "") + std::string("[") + std::to_string(i) + ",1,1,1,0]";
  EXPECT_THAT(refusal(many + "]}}"), HasSubstr("'tf.points'"));
  EXPECT_THAT(refusal(std::string(kMaxMessageBytes + 1, ' ')), HasSubstr("at most"));
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
