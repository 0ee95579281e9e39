// Numbers written as text by a user (a flag's, a keyword's, a query's): parsed once, where they
// enter, with a message naming where they came from.
#pragma once

#include <glm/glm.hpp>

#include <cmath>
#include <cstddef>
#include <limits>
#include <string>
#include <vector>

namespace hyb {

/// Whether @p x is finite as a float too (an isovalue or ε beyond 3.4e38 would become infinite).
inline bool isFloat(double x) { return std::abs(x) <= double(std::numeric_limits<float>::max()); }

/// Parses @p n comma-separated finite numbers (any count ≥ 1 when @p n is 0).
/// @throw ValueError naming @p flag (the flag or keyword the text came from) and @p expected.
std::vector<double> parseNumbers(const std::string& text, const std::string& flag, size_t n, const char* expected);

/// Parses "a,b,c" into three finite numbers. @throw ValueError naming @p flag.
glm::dvec3 parseVec3(const std::string& text, const std::string& flag);

}  // namespace hyb
