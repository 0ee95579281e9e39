// libFuzzer target: `hybrid-octree build` and `info` run in-process on what the input lays out on
// disk, through the command line's own input handling (raw flags, the scene check, the streamed
// planes, the octree's range), as a user runs them.
//
// The input: a 13-byte header, then the payload.
//   [0] kind: 0 a raw file, 1 a file with a header (NRRD, MetaImage, NIfTI, .inv3), 2 a DICOM
//       directory of 2 or 3 slices, 3 a FIFO, 4 a directory under a volume's name holding the
//       payload as a file, 5 the payload as a .hoct (a scene or not)
//   [1] options: bit 0 info (else build), bit 1 --iso, bits 2-3 --leaf-edge 8/1/2/4, bit 4 the raw
//       flags for a kind other than raw
//   [2] the isovalue: int8 x 8
//   [3..7] raw flags: X, Y, Z (1..16 each), the type, and bit 0 big endian, bits 1-6 header bytes
//   [8] the kind's choice: the name (FIFO, directory), the extension (header file), the slice
//       count (DICOM: 2 + bit 0)
//   [9..12] DICOM: the first two slices' lengths (uint16 little endian); the last takes the rest
// The mutator rewrites, one time in four, one component of a DICOM DS value (a rescale, a spacing,
// a position) to an extreme number padded to its length (see rewriteDecimalString).
// A finding is a crash, a sanitizer report, a timeout (a FIFO that blocks a reader), an exit
// status other than 0 or 2, diagnostics that are not one error line after warnings, or a scene
// built that fails to load.
// HYB_FUZZ_VERBOSE=1 prints each input's command line, status and diagnostics (to replay a finding).
#include <omp.h>
#include <signal.h>
#include <sys/stat.h>

#include <cstdlib>
#include <cstring>
#include <random>
#include <sstream>
#include <vector>

#include "apps/cli/cli.h"
#include "fuzz_util.h"
#include "hybrid_octree/hybrid_io.h"

namespace {

namespace fs = std::filesystem;

constexpr size_t kHeader = 13;
const char* const kTypes[] = {"uint8", "int8", "uint16", "int16", "uint32", "int32", "float32", "float64"};
const char* const kHeaderFiles[] = {"v.nrrd", "v.mha", "v.nii", "v.nii.gz", "v.inv3"};
const char* const kNames[] = {"v.raw", "v.nrrd", "v.mha", "v.nii", "v.hoct", "v.dcm", "series", "v.inv3"};

struct Run {
  int status;
  std::string out, err;
};

// As tests/cli_util.h's test::run: `hybrid-octree args...` in this process.
Run run(std::vector<std::string> args) {
  args.insert(args.begin(), {"hybrid-octree", "--memory-limit", "512"});  // runMain sets the ceiling per run
  std::vector<const char*> argv;
  for (const std::string& a : args) argv.push_back(a.c_str());
  std::ostringstream out, err;
  const int status = hyb::app::runMain(int(argv.size()), argv.data(), out, err);
  return {status, out.str(), err.str()};
}

// Aborts (a finding) unless @p r is a success, or a refusal in one error line after any warnings.
void expectCleanEnd(const Run& r, const std::vector<std::string>& args) {
  std::istringstream lines(r.err);
  int errors = 0;
  bool stray = false;
  for (std::string line; std::getline(lines, line);) {
    if (line.rfind("hybrid-octree: error: ", 0) == 0) ++errors;
    else if (line.rfind("hybrid-octree: warning: ", 0) != 0) stray = true;
  }
  if ((r.status == 0 && errors == 0 && !stray) || (r.status == 2 && errors == 1 && !stray)) return;
  std::string command;
  for (const std::string& a : args) command += " " + a;
  std::fprintf(stderr, "hybrid-octree%s: exit status %d, expected 0, or 2 with one error line; stderr:\n%s", command.c_str(), r.status, r.err.c_str());
  std::abort();
}

// libFuzzer's alarm (every -timeout/2 + 1 s) interrupts a blocked open() (EINTR): a reader waiting
// for a FIFO's writer would fail and go on, where a user's process waits for ever. Restarted, the
// open stays blocked and -timeout reports it.
void restartSyscallsOnAlarm() {
  struct sigaction action {};
  if (::sigaction(SIGALRM, nullptr, &action) != 0 || action.sa_handler == SIG_DFL || action.sa_handler == SIG_IGN) return;
  action.sa_flags |= SA_RESTART;
  ::sigaction(SIGALRM, &action, nullptr);
}

// The scratch directory emptied: a FIFO or directory an input left must not meet the next one.
void clearScratch() {
  std::error_code ec;
  for (const fs::directory_entry& e : fs::directory_iterator(hyb::fuzz::scratch())) fs::remove_all(e.path(), ec);
}

std::vector<std::string> rawFlags(const uint8_t* h) {
  const int headerBytes = (h[4] >> 1) & 63;
  return {"--raw-dims", std::to_string(1 + h[0] % 16) + "," + std::to_string(1 + h[1] % 16) + "," + std::to_string(1 + h[2] % 16),
          "--raw-type", kTypes[h[3] % 8], "--raw-endian", (h[4] & 1) ? "big" : "little", "--raw-header", std::to_string(headerBytes)};
}

// Numbers past float's range or none at all, short enough for a 4- or 6-byte DS value.
const char* const kExtremes[] = {"1e308", "-1e39", "3e38", "-9e99", "1e-45", "nan", "inf", "-inf", "0", "-0"};

// Overwrites one component of one explicit-VR DS element in @p data with a kExtremes number padded
// with spaces; false if there is none. DICOM numbers are text: byte mutations seldom write an
// extreme of the element's length at the start of its value (docs/reliability.md).
bool rewriteDecimalString(uint8_t* data, size_t size, std::minstd_rand& random) {
  std::vector<std::pair<size_t, size_t>> values;  // offset, length
  for (size_t i = kHeader + 4; i + 4 <= size; ++i) {
    const size_t length = data[i + 2] | data[i + 3] << 8;
    if (data[i] == 'D' && data[i + 1] == 'S' && length > 0 && i + 4 + length <= size) values.push_back({i + 4, length});
  }
  if (values.empty()) return false;
  const std::pair<size_t, size_t> value = values[random() % values.size()];
  std::vector<std::pair<size_t, size_t>> components;  // of "0\0\2.5": offset, length
  for (size_t begin = value.first, i = begin; i <= value.first + value.second; ++i) {
    if (i == value.first + value.second || data[i] == '\\') {
      components.push_back({begin, i - begin});
      begin = i + 1;
    }
  }
  const std::pair<size_t, size_t> component = components[random() % components.size()];
  const char* word = kExtremes[random() % std::size(kExtremes)];
  if (std::strlen(word) > component.second) return false;
  std::memset(data + component.first, ' ', component.second);
  std::memcpy(data + component.first, word, std::strlen(word));
  return true;
}

}  // namespace

extern "C" size_t LLVMFuzzerMutate(uint8_t* data, size_t size, size_t maxSize);

extern "C" size_t LLVMFuzzerCustomMutator(uint8_t* data, size_t size, size_t maxSize, unsigned seed) {
  std::minstd_rand random(seed);
  if (random() % 4 == 0 && rewriteDecimalString(data, size, random)) return size;
  return LLVMFuzzerMutate(data, size, maxSize);
}

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  // One thread: on 2 shared cores OpenMP's barriers cost a tiny build 10-100x its work.
  omp_set_num_threads(1);
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const bool restarting = (restartSyscallsOnAlarm(), true);  // libFuzzer installs its handler after LLVMFuzzerInitialize
  (void)restarting;
  if (size < kHeader) return 0;
  const fs::path dir = hyb::fuzz::scratch();
  clearScratch();
  const uint8_t kind = data[0] % 6, options = data[1], choice = data[8];
  const uint8_t* payload = data + kHeader;
  const size_t payloadSize = size - kHeader;
  std::string path;
  bool raw = (options & 16) != 0;
  switch (kind) {
    case 0:
      path = hyb::fuzz::writeInput("v.raw", payload, payloadSize);
      raw = true;
      break;
    case 1:
      path = hyb::fuzz::writeInput(kHeaderFiles[choice % 5], payload, payloadSize);
      break;
    case 2: {
      path = (dir / "dicom").string();
      fs::create_directory(path);
      const int slices = 2 + (choice & 1);
      size_t at = 0;
      for (int s = 0; s < slices; ++s) {
        const size_t declared = s + 1 < slices ? size_t(data[9 + 2 * s] | data[10 + 2 * s] << 8) : payloadSize;
        const size_t n = std::min(declared, payloadSize - at);
        hyb::fuzz::writeInput("dicom/" + std::to_string(s) + ".dcm", payload + at, n);
        at += n;
      }
      break;
    }
    case 3:
      path = (dir / kNames[choice % 8]).string();
      ::mkfifo(path.c_str(), 0600);  // no writer ever opens it: a reader that opens it blocks, a timeout
      break;
    case 4:
      path = (dir / kNames[choice % 8]).string();
      fs::create_directory(path);
      hyb::fuzz::writeInput(kNames[choice % 8] + std::string("/slice.dcm"), payload, payloadSize);
      break;
    default:
      path = hyb::fuzz::writeInput("v.hoct", payload, payloadSize);
      break;
  }
  const std::string output = (dir / "out.hoct").string();
  std::vector<std::string> args = (options & 1) ? std::vector<std::string>{"info", path} : std::vector<std::string>{"build", path, "-o", output};
  if (!(options & 1)) {
    if (options & 2) args.insert(args.end(), {"--iso", std::to_string(int(int8_t(data[2])) * 8)});
    if (const int edge = (options >> 2) & 3) args.insert(args.end(), {"--leaf-edge", std::to_string(1 << (edge - 1))});
  }
  if (raw) {
    const std::vector<std::string> flags = rawFlags(data + 3);
    args.insert(args.end(), flags.begin(), flags.end());
  }
  const Run r = run(args);
  if (std::getenv("HYB_FUZZ_VERBOSE")) {
    for (const std::string& a : args) std::fprintf(stderr, "%s ", a.c_str());
    std::fprintf(stderr, "-> %d\n%s", r.status, r.err.c_str());
  }
  expectCleanEnd(r, args);
  // A scene just built loads whole, its octree checked against its samples (through the library:
  // info would add a histogram that costs more than the build).
  if (!(options & 1) && r.status == 0) {
    try {
      hyb::loadScene(output);
    } catch (const hyb::Error& e) {
      std::fprintf(stderr, "%s: the scene build wrote fails to load: %s\n", output.c_str(), e.what());
      std::abort();
    }
  }
  return 0;
}
