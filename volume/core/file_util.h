// Bounded reads of regular files, and atomic writes.
#pragma once

#include <cstdint>
#include <functional>
#include <iosfwd>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

namespace hyb {

/// An input file opened for reading: only a regular file (a FIFO, device, socket or directory is
/// refused by name before it is opened, so reading never blocks), with its size fixed at open.
/// Move-only; closes on destruction.
class InputFile {
 public:
  /// @throw IoError naming @p path when it does not exist, is not a regular file or cannot be opened.
  explicit InputFile(const std::string& path);
  ~InputFile();
  InputFile(InputFile&& other) noexcept;
  InputFile& operator=(InputFile&&) = delete;
  InputFile(const InputFile&) = delete;

  const std::string& path() const { return mPath; }
  /// Bytes in the file when it was opened.
  uint64_t size() const { return mSize; }
  /// Reads bytes [@p offset, @p offset + @p count) into @p out.
  /// @throw IoError naming the file when they are not all there (the file shrank, or an I/O error).
  void read(uint64_t offset, uint64_t count, uint8_t* out) const;
  /// The bytes [@p offset, @p offset + @p count); checks memoryLimit() first.
  /// @throw IoError as read(), or when the bytes exceed the memory limit.
  std::vector<uint8_t> bytes(uint64_t offset, uint64_t count) const;
  class Mapping;
  /// The bytes [@p offset, @p offset + @p count) mapped read-only: the kernel reads a page when it is
  /// first touched and, the pages being clean copies of the file, may drop them again under memory
  /// pressure, so what stays resident follows what is read. A page dropped is read again from the
  /// file: the file must be neither changed in place nor shrunk while mapped (replaced by a rename,
  /// as every writer here does, it is not): what was checked through the mapping holds only then,
  /// and a read past a shrunk file's end is a bus error. Where the file system cannot map it, the
  /// bytes are read into memory instead (release() then does nothing).
  /// @throw IoError naming the file when the range is outside it, or as bytes().
  std::shared_ptr<const Mapping> map(uint64_t offset, uint64_t count) const;

 private:
  std::string mPath;
  int mFd = -1;
  uint64_t mSize = 0;
};

/// A range of a file mapped by InputFile::map; unmapped when the last owner lets go.
class InputFile::Mapping {
  struct Key {  // only InputFile::map makes one: the destructor unmaps what it was given
    explicit Key() = default;
  };
  friend class InputFile;

 public:
  Mapping(Key, void* base, size_t length, const uint8_t* data, uint64_t size) : mBase(base), mLength(length), mData(data), mSize(size) {}
  /// The bytes read into memory (a file system that cannot map them).
  Mapping(Key, std::vector<uint8_t> bytes) : mBase(nullptr), mLength(0), mData(nullptr), mSize(bytes.size()), mCopy(std::move(bytes)) {
    mData = mCopy.data();
  }
  ~Mapping();
  Mapping(const Mapping&) = delete;
  Mapping& operator=(const Mapping&) = delete;
  const uint8_t* data() const { return mData; }
  uint64_t size() const { return mSize; }
  /// Gives the pages read so far back (madvise MADV_DONTNEED): the process's memory no longer holds
  /// them, and a later read faults them in again from the file (usually from the page cache).
  void release() const;

 private:
  void* mBase;
  size_t mLength;
  const uint8_t* mData;
  uint64_t mSize;
  std::vector<uint8_t> mCopy;
};

/// Reads the whole file (a regular file only) into memory, within memoryLimit().
/// @throw IoError naming @p path when it cannot be opened or read, is not a regular file, or is
///        larger than the memory limit.
std::vector<uint8_t> readFileBytes(const std::string& path);

/// Reads a text file (a regular file only) of at most @p maxBytes whose lines are at most
/// @p maxLineBytes long; @p what names it in messages ("transfer function").
/// @throw IoError naming @p path and the limit when the file or one of its lines is longer.
std::string readTextFile(const std::string& path, uint64_t maxBytes, size_t maxLineBytes, const std::string& what);

/// The first line longer than @p maxLineBytes in @p text (1-based), or 0 when none is.
size_t longLine(std::string_view text, size_t maxLineBytes);

/// Text quoted from a file, made safe for a one-line message: at most @p maxChars characters,
/// control and non-ASCII bytes escaped as \xNN, cut with "..." when longer, in single quotes.
std::string quotedExcerpt(std::string_view text, size_t maxChars = 60);

/// Writes a file atomically: @p write fills a temporary file beside @p path, which is flushed to the
/// disk (fsync) and renamed over @p path only when @p write returns and the stream is still good
/// after its close. An existing @p path that is not a regular file is refused. On any failure the temporary
/// is removed and @p path is left untouched.
/// @throw IoError naming @p path when the file cannot be created or written; rethrows what
///        @p write throws.
void writeFileAtomically(const std::string& path, const std::function<void(std::ostream&)>& write);

/// Like writeFileAtomically, for writers that need a file name (libraries that open files
/// themselves). @p write receives the temporary path, which keeps @p path's extension.
void writeFileAtomicallyByName(const std::string& path,
                               const std::function<void(const std::string& tmpPath)>& write);

/// Checks, before any work, that output @p path given by flag @p flag can be created: its
/// directory exists and, when it exists, it is a regular file (a device, FIFO or directory is never
/// replaced). Returns an empty string when it can, else one message naming both.
std::string outputPathError(const std::string& path, const std::string& flag);

/// One message naming @p flag when output @p output is the same file as @p input (by inode, links
/// and other spellings included), else an empty string.
std::string sameFileError(const std::string& output, const std::string& flag, const std::string& input);

/// Lower-cased file-name extension including compound ones such as ".nii.gz"; "" if none.
std::string fileExtension(const std::string& path);

}  // namespace hyb
