#include "volume/file_util.h"

#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>

#include "volume/error.h"

namespace hyb {

namespace fs = std::filesystem;

std::vector<uint8_t> readFileBytes(const std::string& path) {
  std::error_code ec;
  if (fs::is_directory(path, ec)) HYB_THROW(IoError, path, ": expected a file, found a directory");
  std::ifstream in(path, std::ios::binary);
  if (!in) HYB_THROW(IoError, path, ": cannot open file (", std::strerror(errno), ")");
  in.seekg(0, std::ios::end);
  const std::streamoff size = in.tellg();
  if (size < 0) HYB_THROW(IoError, path, ": cannot determine file size");
  in.seekg(0, std::ios::beg);
  std::vector<uint8_t> bytes(static_cast<size_t>(size));
  if (size > 0 && !in.read(reinterpret_cast<char*>(bytes.data()), size))
    HYB_THROW(IoError, path, ": read failed after ", in.gcount(), " of ", size, " bytes");
  return bytes;
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

void writeFileAtomicallyByName(const std::string& path,
                               const std::function<void(const std::string&)>& write) {
  if (path.empty()) HYB_THROW(IoError, "output path is empty");
  const std::string tmp = temporaryNameFor(path);
  try {
    write(tmp);
    std::error_code ec;
    if (!fs::exists(tmp, ec)) HYB_THROW(IoError, path, ": writer produced no file");
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
    write(out);
    out.flush();
    if (!out) HYB_THROW(IoError, path, ": write failed (disk full or I/O error)");
  });
}

std::string outputPathError(const std::string& path, const std::string& flag) {
  const fs::path dir = fs::path(path).parent_path();
  std::error_code ec;
  if (dir.empty() || fs::is_directory(dir, ec)) return "";
  return flag + " '" + path + "': directory '" + dir.string() + "' does not exist";
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
