#include "volume/core/file_util.h"

#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>

#include "volume/core/error.h"
#include "volume/core/memory_limit.h"

namespace hyb {

namespace fs = std::filesystem;

namespace {

// What a file that is not regular is, for a message; "" for a regular file.
const char* nonRegularKind(mode_t mode) {
  if (S_ISREG(mode)) return "";
  if (S_ISDIR(mode)) return "a directory";
  if (S_ISFIFO(mode)) return "a FIFO (named pipe)";
  if (S_ISCHR(mode) || S_ISBLK(mode)) return "a device";
  if (S_ISSOCK(mode)) return "a socket";
  return "not a regular file";
}

[[noreturn]] void refuseKind(const std::string& path, const char* kind) {
  HYB_THROW(IoError, path, ": expected a regular file, found ", kind);
}

}  // namespace

InputFile::InputFile(const std::string& path) : mPath(path) {
  // stat first: opening a FIFO for reading would block until a writer appears.
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) {
    if (errno == ENOENT || errno == ENOTDIR) HYB_THROW(IoError, path, ": file does not exist");
    HYB_THROW(IoError, path, ": cannot open file (", std::strerror(errno), ")");
  }
  if (const char* kind = nonRegularKind(st.st_mode); *kind) refuseKind(path, kind);
  // O_NONBLOCK and fstat: the path may have been replaced by a FIFO since the stat.
  mFd = ::open(path.c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC);
  if (mFd < 0) HYB_THROW(IoError, path, ": cannot open file (", std::strerror(errno), ")");
  if (::fstat(mFd, &st) != 0 || !S_ISREG(st.st_mode)) {
    const char* kind = nonRegularKind(st.st_mode);
    ::close(mFd);
    mFd = -1;
    refuseKind(path, *kind ? kind : "a file it cannot inspect");
  }
  mSize = uint64_t(st.st_size);
}

InputFile::~InputFile() {
  if (mFd >= 0) ::close(mFd);
}

InputFile::InputFile(InputFile&& other) noexcept : mPath(std::move(other.mPath)), mFd(other.mFd), mSize(other.mSize) { other.mFd = -1; }

void InputFile::read(uint64_t offset, uint64_t count, uint8_t* out) const {
  uint64_t done = 0;
  while (done < count) {
    const size_t chunk = size_t(std::min<uint64_t>(count - done, uint64_t(1) << 30));
    const ssize_t n = ::pread(mFd, out + done, chunk, off_t(offset + done));
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) HYB_THROW(IoError, mPath, ": read failed at byte ", offset + done, " (", std::strerror(errno), ")");
    if (n == 0)
      HYB_THROW(IoError, mPath, ": file ends at byte ", offset + done, " (expected ", count, " bytes from byte ", offset, ")");
    done += uint64_t(n);
  }
}

std::vector<uint8_t> InputFile::bytes(uint64_t offset, uint64_t count) const {
  checkMemory(mPath, count, "its bytes");
  std::vector<uint8_t> out(static_cast<size_t>(count));
  read(offset, count, out.data());
  return out;
}

std::shared_ptr<const InputFile::Mapping> InputFile::map(uint64_t offset, uint64_t count) const {
  if (offset > mSize || count > mSize - offset)
    HYB_THROW(IoError, mPath, ": file ends at byte ", mSize, " (expected ", count, " bytes from byte ", offset, ")");
  const uint64_t page = uint64_t(::sysconf(_SC_PAGESIZE));
  const uint64_t start = offset / page * page;
  const size_t length = size_t(std::max<uint64_t>(offset + count - start, 1));
  void* base = ::mmap(nullptr, length, PROT_READ, MAP_PRIVATE, mFd, off_t(start));
  if (base == MAP_FAILED) return std::make_shared<const Mapping>(Mapping::Key{}, bytes(offset, count));
  return std::make_shared<const Mapping>(Mapping::Key{}, base, length, static_cast<const uint8_t*>(base) + (offset - start), count);
}

InputFile::Mapping::~Mapping() {
  if (mBase) ::munmap(mBase, mLength);
}

void InputFile::Mapping::release() const {
  if (mBase) ::madvise(mBase, mLength, MADV_DONTNEED);
}

std::vector<uint8_t> readFileBytes(const std::string& path) {
  const InputFile file(path);
  return file.bytes(0, file.size());
}

size_t longLine(std::string_view text, size_t maxLineBytes) {
  size_t line = 1, start = 0;
  for (;;) {
    const size_t nl = text.find('\n', start);
    const size_t end = nl == std::string_view::npos ? text.size() : nl;
    if (end - start > maxLineBytes) return line;
    if (nl == std::string_view::npos) return 0;
    start = nl + 1;
    ++line;
  }
}

std::string readTextFile(const std::string& path, uint64_t maxBytes, size_t maxLineBytes, const std::string& what) {
  const InputFile file(path);
  if (file.size() > maxBytes)
    HYB_THROW(IoError, path, ": ", what, " of ", formatBytes(file.size()), " is longer than the limit of ", formatBytes(maxBytes),
              " (expected a short text file)");
  const std::vector<uint8_t> b = file.bytes(0, file.size());
  std::string text(b.begin(), b.end());
  if (const size_t line = longLine(text, maxLineBytes))
    HYB_THROW(IoError, path, ": line ", line, " of the ", what, " is longer than ", maxLineBytes, " bytes (expected lines of text)");
  return text;
}

std::string quotedExcerpt(std::string_view text, size_t maxChars) {
  std::string out = "'";
  size_t shown = 0;
  for (const char ch : text) {
    if (shown == maxChars) {
      out += "...";
      break;
    }
    const auto c = static_cast<unsigned char>(ch);
    if (c >= 0x20 && c < 0x7f) {
      out += char(c);
    } else {
      static const char* kHex = "0123456789abcdef";
      out += "\\x";
      out += kHex[c >> 4];
      out += kHex[c & 15];
    }
    ++shown;
  }
  return out + "'";
}

namespace {
// A unique temporary name in the same directory (so rename is atomic), keeping the extension.
std::string temporaryNameFor(const std::string& path) {
  const fs::path p(path);
  const std::string ext = fileExtension(path);
  std::string stem = p.filename().string();
  stem = stem.substr(0, stem.size() - ext.size());
  const fs::path tmp = p.parent_path() / ("." + stem + ".tmp" + std::to_string(::getpid()) + ext);
  return tmp.string();
}
}  // namespace

namespace {
// Why @p path, when it exists, is not a file a writer may replace ("" when it may).
std::string replaceRefusal(const std::string& path) {
  std::error_code ec;
  const fs::file_status st = fs::status(path, ec);
  if (ec || st.type() == fs::file_type::not_found || st.type() == fs::file_type::regular) return "";
  return st.type() == fs::file_type::directory ? "is a directory" : "is a device, FIFO or socket, not a regular file";
}

// Flushes @p path's data to the disk: a renamed file must not turn out empty after a crash.
void syncFile(const std::string& path, const std::string& shown) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) HYB_THROW(IoError, shown, ": cannot reopen the written file (", std::strerror(errno), ")");
  const int rc = ::fsync(fd);
  const int err = errno;
  ::close(fd);
  if (rc != 0 && err != EINVAL) HYB_THROW(IoError, shown, ": cannot flush to disk (", std::strerror(err), ")");
}
}  // namespace

void writeFileAtomicallyByName(const std::string& path,
                               const std::function<void(const std::string&)>& write) {
  if (path.empty()) HYB_THROW(IoError, "output path is empty");
  if (const std::string why = replaceRefusal(path); !why.empty()) HYB_THROW(IoError, path, ": ", why, " (expected a regular file to write)");
  const std::string tmp = temporaryNameFor(path);
  try {
    write(tmp);
    std::error_code ec;
    if (!fs::is_regular_file(tmp, ec)) HYB_THROW(IoError, path, ": writer produced no file");
    syncFile(tmp, path);
    fs::rename(tmp, path, ec);
    if (ec) HYB_THROW(IoError, path, ": cannot rename temporary file into place (", ec.message(), ")");
  } catch (...) {
    std::error_code ec;
    fs::remove(tmp, ec);
    throw;
  }
}

void writeFileAtomically(const std::string& path, const std::function<void(std::ostream&)>& write) {
  writeFileAtomicallyByName(path, [&](const std::string& tmp) {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    if (!out) HYB_THROW(IoError, path, ": cannot create file (", std::strerror(errno), ")");
    errno = 0;
    write(out);
    out.flush();
    if (!out) HYB_THROW(IoError, path, ": write failed (", errno ? std::strerror(errno) : "disk full or I/O error", ")");
    out.close();
    if (!out) HYB_THROW(IoError, path, ": write failed on close (", errno ? std::strerror(errno) : "disk full or I/O error", ")");
  });
}

std::string outputPathError(const std::string& path, const std::string& flag) {
  if (const std::string why = replaceRefusal(path); !why.empty()) return flag + " '" + path + "' " + why + " (expected a regular file to write)";
  const fs::path dir = fs::path(path).parent_path();
  std::error_code ec;
  if (!dir.empty() && !fs::is_directory(dir, ec)) return flag + " '" + path + "': directory '" + dir.string() + "' does not exist";
  // A file is created and removed there now, so a read-only directory fails before the work, not after it
  // (access() would not do: root passes it on a read-only mount).
  const std::string probe = temporaryNameFor(path) + ".probe";
  const int fd = ::open(probe.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0600);
  if (fd < 0)
    return flag + " '" + path + "': cannot create files in directory '" + (dir.empty() ? std::string(".") : dir.string()) + "' (" +
           std::strerror(errno) + ")";
  ::close(fd);
  ::unlink(probe.c_str());
  return "";
}

std::string sameFileError(const std::string& output, const std::string& flag, const std::string& input) {
  std::error_code ec;
  if (!fs::equivalent(output, input, ec) || ec) return "";
  return flag + " '" + output + "' is the input '" + input + "' (expected another file: the input would be overwritten)";
}

std::string fileExtension(const std::string& path) {
  std::string name = fs::path(path).filename().string();
  std::transform(name.begin(), name.end(), name.begin(), [](unsigned char c) { return std::tolower(c); });
  for (const char* compound : {".nii.gz", ".tar.gz"}) {
    const std::string c(compound);
    if (name.size() > c.size() && name.compare(name.size() - c.size(), c.size(), c) == 0) return c;
  }
  const size_t dot = name.rfind('.');
  return (dot == std::string::npos || dot == 0) ? std::string() : name.substr(dot);
}

}  // namespace hyb
