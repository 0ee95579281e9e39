// The process-wide ceiling on the memory one input file may make the readers allocate.
//
// Readers compare what a file's header claims (samples, decoded bytes, archive entries) with this
// ceiling before allocating, so a small file that declares a huge grid is refused with a message
// instead of exhausting memory.
#pragma once

#include <cstdint>
#include <string>

namespace hyb {

/// The default ceiling: half the physical memory (sysconf), or 4 GiB when it cannot be queried.
uint64_t defaultMemoryLimit();

/// Sets the ceiling, in bytes, on what reading one file may allocate (samples, decoded data,
/// buffers), for every reader in the process (thread-safe; takes effect for reads that start
/// afterwards). 0 restores defaultMemoryLimit(). Meant for a command-line flag such as
/// --memory-limit.
void setMemoryLimit(uint64_t bytes);

/// The ceiling in force, in bytes.
uint64_t memoryLimit();

/// Checks that allocating @p bytes for @p what (e.g. "4x3x5 int16 samples") stays within
/// memoryLimit().
/// @throw IoError "<file>: <what> needs N bytes (X GiB), more than the memory limit of ..."
void checkMemory(const std::string& file, uint64_t bytes, const std::string& what);

/// @p bytes as a short human-readable size ("1.5 GiB", "12 KiB", "300 bytes").
std::string formatBytes(uint64_t bytes);

}  // namespace hyb
