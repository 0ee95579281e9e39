#include "volume/plist.h"

#include <cstdlib>

#include "volume/core/error.h"
#include "volume/core/file_util.h"

namespace hyb::detail {

const PlistValue* PlistValue::find(const std::string& key) const {
  if (kind != Kind::Dict) return nullptr;
  const auto it = dict.find(key);
  return it == dict.end() ? nullptr : &it->second;
}

bool PlistValue::number(double* out) const {
  if (kind != Kind::Integer && kind != Kind::Real) return false;
  char* end = nullptr;
  *out = std::strtod(text.c_str(), &end);
  return end != text.c_str();
}

namespace {

class PlistParser {
 public:
  PlistParser(const std::string& xml, const std::string& source) : mXml(xml), mSource(source) {}

  PlistValue parseDocument() {
    // Skip the prolog, doctype and comments up to <plist ...>.
    const size_t start = mXml.find("<plist");
    if (start == std::string::npos) fail("no <plist> element");
    mPos = mXml.find('>', start);
    if (mPos == std::string::npos) fail("unterminated <plist> tag");
    ++mPos;
    PlistValue v = parseValue(nextTag());
    if (nextTag() != "/plist") fail("expected </plist>");
    return v;
  }

 private:
  [[noreturn]] void fail(const std::string& what) const {
    HYB_THROW(IoError, mSource, ": malformed property list: ", what, " (at byte ", mPos, ")");
  }

  // Returns the next tag's name (with a leading '/' for end tags, a trailing '/' for empty ones),
  // skipping comments; text between tags is collected into mText.
  std::string nextTag() {
    for (;;) {
      const size_t lt = mXml.find('<', mPos);
      if (lt == std::string::npos) fail("unexpected end of document");
      mText = mXml.substr(mPos, lt - mPos);
      if (mXml.compare(lt, 4, "<!--") == 0) {
        const size_t end = mXml.find("-->", lt);
        if (end == std::string::npos) fail("unterminated comment");
        mPos = end + 3;
        continue;
      }
      const size_t gt = mXml.find('>', lt);
      if (gt == std::string::npos) fail("unterminated tag");
      std::string tag = mXml.substr(lt + 1, gt - lt - 1);
      mPos = gt + 1;
      const size_t space = tag.find_first_of(" \t\r\n");
      if (space != std::string::npos) tag = tag.substr(0, space) + (tag.back() == '/' ? "/" : "");
      return tag;
    }
  }

  std::string textUntil(const std::string& tag) {
    if (nextTag() != "/" + tag) fail("expected </" + tag + ">");
    return unescape(mText);
  }

  static std::string unescape(const std::string& s) {
    std::string out;
    for (size_t i = 0; i < s.size(); ++i) {
      if (s[i] != '&') {
        out += s[i];
        continue;
      }
      static const std::pair<const char*, char> kEntities[] = {
          {"&amp;", '&'}, {"&lt;", '<'}, {"&gt;", '>'}, {"&quot;", '"'}, {"&apos;", '\''}};
      bool matched = false;
      for (const auto& [name, ch] : kEntities)
        if (s.compare(i, std::char_traits<char>::length(name), name) == 0) {
          out += ch;
          i += std::char_traits<char>::length(name) - 1;
          matched = true;
          break;
        }
      if (!matched) out += '&';
    }
    return out;
  }

  PlistValue parseValue(const std::string& tag) {
    // Recursion depth is bounded: a small file of nested <array>s must not overflow the stack.
    if (mDepth == kMaxPlistDepth) fail(detail::concat("nested deeper than ", kMaxPlistDepth, " levels (expected a shallow document)"));
    const DepthGuard guard(&mDepth);
    PlistValue v;
    if (tag == "dict") {
      v.kind = PlistValue::Kind::Dict;
      for (std::string t = nextTag(); t != "/dict"; t = nextTag()) {
        if (t != "key") fail("expected <key> in <dict>, found <" + quotedExcerpt(t) + ">");
        const std::string key = textUntil("key");
        v.dict[key] = parseValue(nextTag());
      }
    } else if (tag == "array") {
      v.kind = PlistValue::Kind::Array;
      for (std::string t = nextTag(); t != "/array"; t = nextTag()) v.items.push_back(parseValue(t));
    } else if (tag == "dict/" || tag == "array/") {
      v.kind = tag == "dict/" ? PlistValue::Kind::Dict : PlistValue::Kind::Array;
    } else if (tag == "string" || tag == "date" || tag == "data") {
      v.text = textUntil(tag);
    } else if (tag == "string/") {
    } else if (tag == "integer" || tag == "real") {
      v.kind = tag == "integer" ? PlistValue::Kind::Integer : PlistValue::Kind::Real;
      v.text = textUntil(tag);
    } else if (tag == "true/" || tag == "false/") {
      v.kind = PlistValue::Kind::Bool;
      v.text = tag == "true/" ? "true" : "false";
    } else {
      fail("unexpected <" + quotedExcerpt(tag) + ">");
    }
    return v;
  }

  struct DepthGuard {
    explicit DepthGuard(int* d) : depth(d) { ++*depth; }
    ~DepthGuard() { --*depth; }
    int* depth;
  };

  const std::string& mXml;
  const std::string& mSource;
  int mDepth = 0;
  size_t mPos = 0;
  std::string mText;
};

}  // namespace

PlistValue parsePlist(const std::string& xml, const std::string& source) {
  if (xml.size() > kMaxPlistBytes)
    HYB_THROW(IoError, source, ": property list of ", xml.size(), " bytes is longer than the limit of ", kMaxPlistBytes,
              " (expected project metadata)");
  return PlistParser(xml, source).parseDocument();
}

}  // namespace hyb::detail
