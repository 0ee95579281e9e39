// libFuzzer target: the viewer's message parser (what a hostile client sends).
#include "apps/viewer/viewer_protocol.h"
#include "fuzz_util.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  hyb::fuzz::refuseOrSucceed([&] { hyb::viewer::parseRequest(text); });
  return 0;
}
