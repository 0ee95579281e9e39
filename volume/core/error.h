// Error types and invariant checks shared by every hybrid-octree module.
//
// Two tiers (STYLE 5): files, flags and parameters are validated where they enter and rejected
// with a typed exception whose message names the file or flag and what was expected; internal
// invariants use HYB_CHECK (always on) and HYB_DCHECK (debug builds only).
#pragma once

#include <sstream>
#include <stdexcept>
#include <string>

namespace hyb {

/// Base of every error the project throws on purpose.
class Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// A file could not be read or written, or its contents are malformed. Bad input: exit status 2.
class IoError : public Error {
 public:
  using Error::Error;
};

/// A flag or parameter has an impossible value. Bad input: exit status 2.
class ValueError : public Error {
 public:
  using Error::Error;
};

/// The environment failed (OpenGL context, out of memory for a valid request). Exit status 1.
class RuntimeError : public Error {
 public:
  using Error::Error;
};

namespace detail {
/// Concatenates the streamable arguments into one string.
template <typename... Args>
std::string concat(const Args&... args) {
  std::ostringstream s;
  (s << ... << args);
  return s.str();
}
[[noreturn]] void checkFailed(const char* expr, const char* file, int line);
}  // namespace detail

}  // namespace hyb

/// Throws ExceptionType with the concatenation of the remaining arguments as its message.
#define HYB_THROW(ExceptionType, ...) throw ExceptionType(::hyb::detail::concat(__VA_ARGS__))

/// Aborts with file and line when an internal invariant is broken (never for user input).
#define HYB_CHECK(expr) \
  ((expr) ? (void)0 : ::hyb::detail::checkFailed(#expr, __FILE__, __LINE__))

#ifdef NDEBUG
#define HYB_DCHECK(expr) ((void)0)
#else
#define HYB_DCHECK(expr) HYB_CHECK(expr)
#endif
