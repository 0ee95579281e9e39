// The files one command writes, all or none.
#pragma once

#include <functional>
#include <string>
#include <utility>
#include <vector>

namespace hyb::app {

/// The outputs of one command: each is written under a temporary name beside its own and all are
/// renamed into place by commit(), so a command that fails part way (a full disk while writing
/// --stats after the PNG) leaves none of them.
class CommandOutputs {
 public:
  CommandOutputs() = default;
  CommandOutputs(const CommandOutputs&) = delete;
  CommandOutputs& operator=(const CommandOutputs&) = delete;
  /// Removes whatever was staged and not committed.
  ~CommandOutputs();
  /// Writes @p path through @p writeTo, which is given the name to write under until commit() (it
  /// keeps @p path's extension). @throw what @p writeTo throws, an IoError naming @p path.
  void write(const std::string& path, const std::function<void(const std::string& tmpPath)>& writeTo);
  /// Renames every staged file into place.
  /// @throw IoError naming the file that could not be renamed; those renamed before it are removed.
  void commit();

 private:
  std::vector<std::pair<std::string, std::string>> mFiles;  // temporary, final
};

/// Checks a command's outputs before any work: each (path, flag) can be written (outputPathError),
/// none is one of @p inputs and no two are the same file. Empty when they are, else one message
/// naming the flag.
std::string outputsError(const std::vector<std::pair<std::string, std::string>>& outputs, const std::vector<std::string>& inputs);

}  // namespace hyb::app
