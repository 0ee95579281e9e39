#include "volume/core/number_text.h"

#include <sstream>

#include "volume/core/error.h"

namespace hyb {

std::vector<double> parseNumbers(const std::string& text, const std::string& flag, size_t n, const char* expected) {
  std::string t = text;
  for (char& c : t)
    if (c == ',') c = ' ';
  std::istringstream s(t);
  std::vector<double> x;
  double e = 0;
  while (s >> e && std::isfinite(e)) x.push_back(e);
  if (!s.eof() || x.empty() || (n > 0 && x.size() != n)) HYB_THROW(ValueError, flag, " '", text, "' invalid (expected ", expected, ")");
  return x;
}

glm::dvec3 parseVec3(const std::string& text, const std::string& flag) {
  const std::vector<double> x = parseNumbers(text, flag, 3, "three finite numbers x,y,z");
  return {x[0], x[1], x[2]};
}

}  // namespace hyb
