// Whole-file reads and atomic writes.
#pragma once

#include <cstdint>
#include <functional>
#include <iosfwd>
#include <string>
#include <vector>

namespace hyb {

/// Reads the whole file into memory.
/// @throw IoError naming @p path when it cannot be opened or read.
std::vector<uint8_t> readFileBytes(const std::string& path);

/// Writes a file atomically: @p write fills a temporary file beside @p path, which is renamed over
/// @p path only when @p write returns and the stream is still good. On any failure the temporary
/// is removed and @p path is left untouched.
/// @throw IoError naming @p path when the file cannot be created or written; rethrows what
///        @p write throws.
void writeFileAtomically(const std::string& path, const std::function<void(std::ostream&)>& write);

/// Like writeFileAtomically, for writers that need a file name (libraries that open files
/// themselves). @p write receives the temporary path, which keeps @p path's extension.
void writeFileAtomicallyByName(const std::string& path,
                               const std::function<void(const std::string& tmpPath)>& write);

/// Checks, before any work, that output @p path given by flag @p flag can be created: its
/// directory exists. Returns an empty string when it does, else one message naming both.
std::string outputPathError(const std::string& path, const std::string& flag);

/// Lower-cased file-name extension including compound ones such as ".nii.gz"; "" if none.
std::string fileExtension(const std::string& path);

}  // namespace hyb
