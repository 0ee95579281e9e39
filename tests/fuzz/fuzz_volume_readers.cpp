// libFuzzer target: every volume reader. The first byte picks the format, the rest is the file.
#include "fuzz_util.h"
#include "volume/plane_source.h"
#include "volume/sample_window.h"
#include "volume/volume_io.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 1) return 0;
  static const char* const kNames[] = {"v.nrrd", "v.mha", "v.nii", "v.nii.gz", "v.inv3", "dicom/slice.dcm"};
  const std::string name = kNames[data[0] % 6];
  if (name.rfind("dicom/", 0) == 0) std::filesystem::create_directories(hyb::fuzz::scratch() / "dicom");
  const std::string file = hyb::fuzz::writeInput(name, data + 1, size - 1);
  // A DICOM series is its directory.
  const std::string path = name.rfind("dicom/", 0) == 0 ? (hyb::fuzz::scratch() / "dicom").string() : file;
  hyb::fuzz::refuseOrSucceed([&] { hyb::readVolume(path); });
  // The same file read plane by plane, as a streamed build reads it.
  hyb::fuzz::refuseOrSucceed([&] {
    const std::unique_ptr<hyb::PlaneSource> planes = hyb::openPlanes(path);
    hyb::SampleWindow window(*planes, 1);
    for (int z = 0; z < planes->dims().z; ++z) window.load(*planes);
  });
  return 0;
}
