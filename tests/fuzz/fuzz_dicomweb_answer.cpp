// libFuzzer target: what a hostile DICOMweb archive answers a retrieval (WADO-RS). The first byte
// picks how many bytes the network hands over at a time (1-256), the first line is the answer's
// Content-Type, the rest its body: split into instance files, which are then listed as a series.
#include <filesystem>
#include <string_view>

#include "fuzz_util.h"
#include "volume/dicomweb.h"
#include "volume/volume_io.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 1) return 0;
  const size_t chunk = size_t(data[0]) + 1;
  const std::string_view text(reinterpret_cast<const char*>(data + 1), size - 1);
  const size_t eol = text.find('\n');
  const std::string type(text.substr(0, eol));
  const std::string_view body = eol == std::string_view::npos ? std::string_view() : text.substr(eol + 1);
  const std::filesystem::path dir = hyb::fuzz::scratch() / "answer";
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  hyb::fuzz::refuseOrSucceed([&] {
    hyb::detail::splitMultipart(type, body, dir.string(), chunk);
    hyb::listDicomSeries(dir.string());
  });
  return 0;
}
