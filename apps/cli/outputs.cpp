#include "apps/cli/outputs.h"

#include <unistd.h>

#include <filesystem>

#include "volume/core/error.h"
#include "volume/core/file_util.h"

namespace hyb::app {

namespace fs = std::filesystem;

CommandOutputs::~CommandOutputs() {
  std::error_code ec;
  for (const auto& [tmp, path] : mFiles) fs::remove(tmp, ec);
}

void CommandOutputs::write(const std::string& path, const std::function<void(const std::string&)>& writeTo) {
  const fs::path p(path);
  const std::string ext = fileExtension(path);
  std::string stem = p.filename().string();
  stem = stem.substr(0, stem.size() - ext.size());
  const std::string tmp = (p.parent_path() / ("." + stem + ".part" + std::to_string(::getpid()) + "-" + std::to_string(mFiles.size()) + ext)).string();
  mFiles.push_back({tmp, path});
  try {
    writeTo(tmp);
  } catch (const IoError& e) {
    // The message names the file the user asked for, not its temporary.
    std::string what = e.what();
    for (size_t at = what.find(tmp); at != std::string::npos; at = what.find(tmp, at + path.size())) what.replace(at, tmp.size(), path);
    throw IoError(what);
  }
}

void CommandOutputs::commit() {
  for (size_t i = 0; i < mFiles.size(); ++i) {
    std::error_code ec;
    fs::rename(mFiles[i].first, mFiles[i].second, ec);
    if (ec) {
      for (size_t j = 0; j < i; ++j) fs::remove(mFiles[j].second, ec);
      HYB_THROW(IoError, mFiles[i].second, ": cannot rename temporary file into place (", ec.message(), ")");
    }
  }
  mFiles.clear();
}

std::string outputsError(const std::vector<std::pair<std::string, std::string>>& outputs, const std::vector<std::string>& inputs) {
  for (size_t i = 0; i < outputs.size(); ++i) {
    const auto& [path, flag] = outputs[i];
    if (path.empty()) continue;
    if (std::string e = outputPathError(path, flag); !e.empty()) return e;
    for (const std::string& in : inputs)
      if (!in.empty())
        if (std::string e = sameFileError(path, flag, in); !e.empty()) return e;
    for (size_t j = 0; j < i; ++j)
      if (path == outputs[j].first || !sameFileError(path, flag, outputs[j].first).empty())
        return flag + " '" + path + "' is also " + outputs[j].second + "'s file (expected two different files)";
  }
  return "";
}

}  // namespace hyb::app
