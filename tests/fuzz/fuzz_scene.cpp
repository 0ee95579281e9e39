// libFuzzer target: the scene-file loader.
#include <vector>

#include "fuzz_util.h"
#include "hybrid_octree/hybrid_io.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = hyb::fuzz::writeInput("s.hoct", data, size);
  hyb::fuzz::refuseOrSucceed([&] { hyb::loadScene(path); });
  // Paged: every knot of every spacing read through the store's cache.
  hyb::fuzz::refuseOrSucceed([&] {
    const hyb::Scene scene = hyb::loadScene(path, hyb::SceneLoadOptions{false, 1 << 16});
    for (const hyb::StoreLevel& l : scene.knots->levels()) {
      std::vector<float> values(size_t(l.counts.x) * size_t(l.counts.y) * size_t(l.counts.z));
      std::vector<glm::vec3> gradients(l.gradients ? values.size() : 0);
      scene.knots->read(l.spacing, glm::ivec3(0), l.counts, values.data(), l.gradients ? gradients.data() : nullptr);
    }
  });
  return 0;
}
