// A minimal reader for Apple XML property lists, the metadata format of InVesalius projects.
// Supports dict, array, string, integer, real, true/false, and the empty-element forms.
#pragma once

#include <map>
#include <memory>
#include <string>
#include <vector>

namespace hyb::detail {

struct PlistValue {
  enum class Kind { Dict, Array, String, Integer, Real, Bool };
  Kind kind = Kind::String;
  std::string text;                        ///< String content, or the number's literal text
  std::vector<PlistValue> items;           ///< Array elements
  std::map<std::string, PlistValue> dict;  ///< Dict entries

  /// Entry @p key of a dict, or nullptr when absent or this is not a dict.
  const PlistValue* find(const std::string& key) const;
  /// Numeric value of an Integer or Real; false when not numeric.
  bool number(double* out) const;
};

/// Deepest nesting of dicts and arrays accepted (InVesalius writes 3 or 4 levels).
inline constexpr int kMaxPlistDepth = 64;
/// Longest document accepted, in bytes.
inline constexpr size_t kMaxPlistBytes = size_t(16) << 20;

/// Parses the XML plist in @p xml; @p source names it in error messages.
/// @throw IoError naming @p source when the document is not a well-formed plist, is longer than
///        kMaxPlistBytes or nests deeper than kMaxPlistDepth.
PlistValue parsePlist(const std::string& xml, const std::string& source);

}  // namespace hyb::detail
