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

/// Parses the XML plist in @p xml; @p source names it in error messages.
/// @throw IoError naming @p source when the document is not a well-formed plist.
PlistValue parsePlist(const std::string& xml, const std::string& source);

}  // namespace hyb::detail
