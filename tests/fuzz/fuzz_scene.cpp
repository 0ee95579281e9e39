// libFuzzer target: the scene-file loader.
#include "fuzz_util.h"
#include "hybrid_octree/hybrid_io.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = hyb::fuzz::writeInput("s.hoct", data, size);
  hyb::fuzz::refuseOrSucceed([&] { hyb::loadScene(path); });
  return 0;
}
