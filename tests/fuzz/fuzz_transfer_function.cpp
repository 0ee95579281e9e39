// libFuzzer target: the transfer-function file parser.
#include "fuzz_util.h"
#include "render/transfer_function.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = hyb::fuzz::writeInput("f.tf", data, size);
  hyb::fuzz::refuseOrSucceed([&] { hyb::TransferFunction::fromFile(path); });
  return 0;
}
