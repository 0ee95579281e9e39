// DICOMweb through libcurl: QIDO-RS (DICOM JSON, PS3.18 F.2) and WADO-RS series retrieval
// (multipart/related, PS3.18 8.6.1). The multipart body is split as it arrives: each part goes
// straight to its file, so memory holds one network buffer, never the series.
#include "volume/dicomweb.h"

#include <curl/curl.h>
#include <nlohmann/json.hpp>
#include <stdlib.h>
#include <sys/stat.h>

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <optional>
#include <variant>

#include "volume/core/file_util.h"
#include "volume/dicom_scan.h"
#include "volume/plane_source.h"
#include "volume/reader_util.h"

namespace hyb {

namespace fs = std::filesystem;
using detail::concat;

namespace {

std::mutex gAuthFileMutex;
std::string gAuthFile;  // setDicomWebAuthFile's

// The address's user information ("user:password@"), or none.
std::optional<std::pair<size_t, size_t>> userInfo(const std::string& url) {
  const size_t scheme = url.find("://");
  if (scheme == std::string::npos) return std::nullopt;
  const size_t start = scheme + 3;
  const size_t end = std::min(url.size(), url.find_first_of("/?#", start));
  const size_t at = url.rfind('@', end == 0 ? 0 : end - 1);
  if (at == std::string::npos || at < start || at >= end) return std::nullopt;
  return std::pair{start, at};
}

// Refuses an address this client does not send: credentials in it, or characters an address does not hold.
void checkUrl(const std::string& url, const std::string& what) {
  if (!isDicomWebUrl(url)) HYB_THROW(ValueError, what, " ", quotedExcerpt(redactUrl(url)), ": not a DICOMweb address (expected http(s)://HOST:PORT/ROOT...)");
  if (userInfo(url))
    HYB_THROW(ValueError, what, " ", redactUrl(url), ": credentials in the address are refused (expected them in HYB_DICOMWEB_USER, HYB_DICOMWEB_TOKEN or --pacs-auth-file)");
  for (const char c : url)
    if (static_cast<unsigned char>(c) <= 0x20 || c == 0x7f || c == '#')
      HYB_THROW(ValueError, what, " ", quotedExcerpt(url), ": spaces, control characters and '#' are not allowed in the address");
}

// The address without a trailing '/'.
std::string trimmedUrl(std::string url) {
  while (!url.empty() && url.back() == '/') url.pop_back();
  return url;
}

// The credentials: Bearer TOKEN, or USER:PASSWORD for HTTP basic.
struct Credentials {
  std::string bearer, user, password;
  bool any() const { return !bearer.empty() || !user.empty(); }
};

Credentials parseCredentials(const std::string& line, const std::string& where) {
  Credentials c;
  const std::string t = detail::trim(line);
  if (t.rfind("Bearer ", 0) == 0 || t.rfind("bearer ", 0) == 0) {
    c.bearer = detail::trim(t.substr(7));
    if (c.bearer.empty()) HYB_THROW(ValueError, where, ": empty bearer token (expected 'Bearer TOKEN')");
    return c;
  }
  const size_t colon = t.find(':');
  if (colon == std::string::npos || colon == 0)
    HYB_THROW(ValueError, where, ": neither 'Bearer TOKEN' nor 'USER:PASSWORD' (the value is not shown)");
  c.user = t.substr(0, colon);
  c.password = t.substr(colon + 1);
  return c;
}

Credentials credentials(const DicomWebOptions& o) {
  if (!o.authFile.empty()) {
    const InputFile file(o.authFile);
    if (file.size() > 65536) HYB_THROW(ValueError, "--pacs-auth-file ", o.authFile, ": ", file.size(), " bytes (expected one line of credentials)");
    const std::vector<uint8_t> bytes = file.bytes(0, file.size());
    std::string text(bytes.begin(), bytes.end());
    text = text.substr(0, text.find('\n'));
    return parseCredentials(text, "--pacs-auth-file " + o.authFile);
  }
  if (const char* token = std::getenv("HYB_DICOMWEB_TOKEN"); token && *token) return parseCredentials(std::string("Bearer ") + token, "HYB_DICOMWEB_TOKEN");
  if (const char* user = std::getenv("HYB_DICOMWEB_USER"); user && *user) return parseCredentials(user, "HYB_DICOMWEB_USER");
  return {};
}

// ---------------------------------------------------------------------------------------------
// HTTP

// What receives a response's body; its calls may throw (the transfer then stops and rethrows).
class BodySink {
 public:
  virtual ~BodySink() = default;
  /// Called once, before the first byte of a successful (2xx) response's body.
  virtual void start(const std::string& contentType, int64_t contentLength) = 0;
  virtual void data(const char* p, size_t n) = 0;
  /// What was received so far, for a message about a transfer cut short.
  virtual std::string received() const = 0;
};

// The reason phrase and what to do for an HTTP error status.
std::string statusText(long status, bool withCredentials) {
  switch (status) {
    case 400: return "400 Bad Request (the server refused the query)";
    case 401:
      return withCredentials ? "401 Unauthorized (the credentials given were refused)"
                             : "401 Unauthorized (expected credentials: HYB_DICOMWEB_USER=USER:PASSWORD, HYB_DICOMWEB_TOKEN or --pacs-auth-file)";
    case 403: return "403 Forbidden (the credentials given may not read this)";
    case 404: return "404 Not Found (no such study, series or DICOMweb root on the server; `hybrid-octree pacs ROOT` lists what it holds)";
    case 406: return "406 Not Acceptable (the server does not offer this as DICOM)";
    default:
      return status >= 500 ? concat(status, " (a server error; expected 200: the archive failed, try again or ask its administrator)")
                           : concat(status, " (expected 200)");
  }
}

struct Transfer {
  BodySink* sink;
  CURL* curl;
  const DicomWebOptions* options;
  bool started = false;
  long status = 0;
  std::exception_ptr error;
  std::chrono::steady_clock::time_point lastByte;  // or the start
  bool stalled = false;
};

size_t onData(char* p, size_t size, size_t count, void* user) {
  Transfer& t = *static_cast<Transfer*>(user);
  const size_t n = size * count;
  t.lastByte = std::chrono::steady_clock::now();
  try {
    if (!t.started) {
      t.started = true;
      curl_easy_getinfo(t.curl, CURLINFO_RESPONSE_CODE, &t.status);
      if (t.status < 200 || t.status >= 300) return n;  // an error's body is not shown: the status says it
      char* type = nullptr;
      curl_easy_getinfo(t.curl, CURLINFO_CONTENT_TYPE, &type);
      curl_off_t length = -1;
      curl_easy_getinfo(t.curl, CURLINFO_CONTENT_LENGTH_DOWNLOAD_T, &length);
      t.sink->start(type ? type : "", int64_t(length));
    }
    if (t.status < 200 || t.status >= 300) return n;
    t.sink->data(p, n);
    return n;
  } catch (...) {
    t.error = std::current_exception();
    return CURL_WRITEFUNC_ERROR;
  }
}

// Stops a cancelled or stalled transfer (libcurl calls it at least once a second). libcurl's own
// low-speed limit averages over seconds of history: a burst then a stall would outlast the limit.
int onProgress(void* user, curl_off_t, curl_off_t, curl_off_t, curl_off_t) {
  Transfer& t = *static_cast<Transfer*>(user);
  if (t.options->cancel && t.options->cancel->load()) return 1;
  t.stalled = std::chrono::duration<double>(std::chrono::steady_clock::now() - t.lastByte).count() > t.options->stallSeconds;
  return t.stalled ? 1 : 0;
}

std::once_flag gCurlInit;

// GETs @p url (Accept: @p accept) into @p sink; HTTP errors, transport faults and timeouts thrown
// as one line starting with @p where (the redacted address the user gave).
void httpGet(const std::string& url, const std::string& where, const std::string& accept, const DicomWebOptions& o, BodySink* sink) {
  std::call_once(gCurlInit, [] { curl_global_init(CURL_GLOBAL_DEFAULT); });
  const Credentials cred = credentials(o);
  const std::unique_ptr<CURL, void (*)(CURL*)> curl(curl_easy_init(), curl_easy_cleanup);
  if (!curl) HYB_THROW(RuntimeError, redactUrl(url), ": libcurl could not start a transfer");
  CURL* c = curl.get();
  char errorText[CURL_ERROR_SIZE] = {};
  Transfer t{sink, c, &o, false, 0, nullptr, std::chrono::steady_clock::now(), false};
  const std::string acceptHeader = "Accept: " + accept;
  const std::unique_ptr<curl_slist, void (*)(curl_slist*)> headers(curl_slist_append(nullptr, acceptHeader.c_str()), curl_slist_free_all);
  curl_easy_setopt(c, CURLOPT_URL, url.c_str());
  curl_easy_setopt(c, CURLOPT_HTTPHEADER, headers.get());
  curl_easy_setopt(c, CURLOPT_PROTOCOLS_STR, "http,https");
  curl_easy_setopt(c, CURLOPT_REDIR_PROTOCOLS_STR, "http,https");
  curl_easy_setopt(c, CURLOPT_FOLLOWLOCATION, 1L);  // credentials are not sent on to another host (libcurl's default)
  curl_easy_setopt(c, CURLOPT_MAXREDIRS, 5L);
  curl_easy_setopt(c, CURLOPT_CONNECTTIMEOUT_MS, long(o.connectSeconds * 1000));
  curl_easy_setopt(c, CURLOPT_NOSIGNAL, 1L);  // threads: no SIGALRM for DNS timeouts
  curl_easy_setopt(c, CURLOPT_ERRORBUFFER, errorText);
  curl_easy_setopt(c, CURLOPT_WRITEFUNCTION, onData);
  curl_easy_setopt(c, CURLOPT_WRITEDATA, &t);
  curl_easy_setopt(c, CURLOPT_XFERINFOFUNCTION, onProgress);
  curl_easy_setopt(c, CURLOPT_XFERINFODATA, &t);
  curl_easy_setopt(c, CURLOPT_NOPROGRESS, 0L);
  curl_easy_setopt(c, CURLOPT_USERAGENT, "hybrid-octree");
  if (!cred.bearer.empty()) {
    curl_easy_setopt(c, CURLOPT_HTTPAUTH, long(CURLAUTH_BEARER));
    curl_easy_setopt(c, CURLOPT_XOAUTH2_BEARER, cred.bearer.c_str());
  } else if (!cred.user.empty()) {
    curl_easy_setopt(c, CURLOPT_HTTPAUTH, long(CURLAUTH_BASIC));
    curl_easy_setopt(c, CURLOPT_USERNAME, cred.user.c_str());
    curl_easy_setopt(c, CURLOPT_PASSWORD, cred.password.c_str());
  }
  const CURLcode rc = curl_easy_perform(c);
  if (t.error) std::rethrow_exception(t.error);
  if (rc == CURLE_ABORTED_BY_CALLBACK && !t.stalled) HYB_THROW(RuntimeError, where, ": cancelled");
  if (t.stalled || rc == CURLE_OPERATION_TIMEDOUT)
    HYB_THROW(IoError, where, ": timed out: nothing received for ", o.stallSeconds, " s", t.started ? " after " + sink->received() : std::string(" (no response)"));
  if (rc == CURLE_PARTIAL_FILE || rc == CURLE_RECV_ERROR)
    HYB_THROW(IoError, where, ": the connection closed mid-transfer after ", sink->received(), " (", errorText, ")");
  if (rc != CURLE_OK) HYB_THROW(IoError, where, ": ", *errorText ? errorText : curl_easy_strerror(rc));
  if (!t.started) curl_easy_getinfo(c, CURLINFO_RESPONSE_CODE, &t.status);
  if (t.status < 200 || t.status >= 300) HYB_THROW(IoError, where, ": HTTP ", statusText(t.status, cred.any()));
}

// A body kept in memory, bounded: QIDO-RS answers.
class StringSink final : public BodySink {
 public:
  void start(const std::string& contentType, int64_t) override { type = contentType; }
  void data(const char* p, size_t n) override {
    if (body.size() + n > (size_t(64) << 20)) throw IoError("answer larger than 64 MB (expected a QIDO-RS listing)");
    body.append(p, n);
  }
  std::string received() const override { return concat(body.size(), " bytes"); }
  std::string body, type;
};

// ---------------------------------------------------------------------------------------------
// QIDO-RS

// The first value of @p tag (8 hex digits) of a DICOM JSON object, as text: strings, numbers and
// person names' alphabetic form.
std::string jsonValue(const nlohmann::json& object, const char* tag) {
  const auto e = object.find(tag);
  if (e == object.end() || !e->is_object()) return "";
  const auto v = e->find("Value");
  if (v == e->end() || !v->is_array() || v->empty()) return "";
  const nlohmann::json& first = v->front();
  if (first.is_string()) return first.get<std::string>();
  if (first.is_number_integer()) return std::to_string(first.get<long long>());
  if (first.is_number()) return concat(first.get<double>());
  if (first.is_object() && first.contains("Alphabetic") && first["Alphabetic"].is_string()) return first["Alphabetic"].get<std::string>();
  return "";
}

// GETs a QIDO-RS listing: a JSON array of objects; messages start with @p where.
nlohmann::json qido(const std::string& url, const std::string& where, const DicomWebOptions& o) {
  StringSink sink;
  httpGet(url, where, "application/dicom+json, application/json", o, &sink);
  if (sink.body.empty()) return nlohmann::json::array();  // 204 No Content: nothing matched
  nlohmann::json j = nlohmann::json::parse(sink.body, nullptr, false);
  if (j.is_discarded() || !j.is_array() || !std::all_of(j.begin(), j.end(), [](const nlohmann::json& x) { return x.is_object(); }))
    HYB_THROW(IoError, where, ": answer is not DICOM JSON (expected an array of objects, QIDO-RS; Content-Type ", quotedExcerpt(sink.type), ")");
  return j;
}

std::string escaped(const std::string& s) {
  std::string out;
  for (const unsigned char c : s) {
    // ('^' of person names as it is: Orthanc matches it only so.)
    if (std::isalnum(c) || c == '-' || c == '.' || c == '_' || c == '~' || c == '*' || c == '?' || c == '^') out += char(c);
    else out += concat("%", "0123456789ABCDEF"[c >> 4], "0123456789ABCDEF"[c & 15]);
  }
  return out;
}

// ---------------------------------------------------------------------------------------------
// WADO-RS: multipart/related; type="application/dicom"

// The value of parameter @p name of a Content-Type, unquoted; empty when absent.
std::string typeParameter(const std::string& contentType, const std::string& name) {
  std::string lower = contentType;
  std::transform(lower.begin(), lower.end(), lower.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  size_t at = 0;
  while ((at = lower.find(name, at)) != std::string::npos) {
    const bool starts = at > 0 && (lower[at - 1] == ';' || lower[at - 1] == ' ');
    size_t v = at + name.size();
    while (v < lower.size() && lower[v] == ' ') ++v;
    if (!starts || v >= lower.size() || lower[v] != '=') {
      at = v;
      continue;
    }
    ++v;
    while (v < lower.size() && lower[v] == ' ') ++v;
    if (v < contentType.size() && contentType[v] == '"') return contentType.substr(v + 1, contentType.find('"', v + 1) - v - 1);
    return detail::trim(contentType.substr(v, contentType.find(';', v) - v));
  }
  return "";
}

// The parts of a multipart/related body, each written to its file in @p dir as it arrives.
class MultipartFiles final : public BodySink {
 public:
  /// @p expected: the instances the archive lists for the series (0: unknown), for progress and messages.
  /// Parts are written to files named @p partName and their number until their UID names them.
  MultipartFiles(std::string where, std::string dir, size_t expected, const Progress* progress, std::string partName = "part")
      : mWhere(std::move(where)), mDir(std::move(dir)), mPartName(std::move(partName)), mExpected(expected), mProgress(progress) {}

  void start(const std::string& contentType, int64_t contentLength) override {
    std::string type = detail::trim(contentType.substr(0, contentType.find(';')));
    std::transform(type.begin(), type.end(), type.begin(), [](unsigned char c) { return char(std::tolower(c)); });
    const std::string boundary = typeParameter(contentType, "boundary");
    if (type != "multipart/related" || boundary.empty())
      HYB_THROW(IoError, mWhere, ": answer is ", quotedExcerpt(contentType), " (expected multipart/related; type=\"application/dicom\" with a boundary, WADO-RS)");
    mDelimiter = "\r\n--" + boundary;
    mBuffer = "\r\n";  // the first delimiter may start the body without a line break before it
    mByBytes = contentLength > 0 || mExpected == 0;
    mTask = std::make_unique<ProgressTask>(mProgress, "DICOMweb series", mByBytes ? uint64_t(std::max<int64_t>(contentLength, 0)) : mExpected);
  }

  void data(const char* p, size_t n) override {
    mBuffer.append(p, n);
    if (mTask && mByBytes) mTask->advance(n);
    for (;;) {
      if (mState == State::Body) {
        const size_t at = mBuffer.find(mDelimiter);
        const size_t keep = at != std::string::npos ? at : mBuffer.size() > mDelimiter.size() ? mBuffer.size() - mDelimiter.size() : 0;
        write(mBuffer.data(), keep);
        mBuffer.erase(0, keep);
        if (at == std::string::npos) return;
        closePart();
        mBuffer.erase(0, mDelimiter.size());
        mState = State::AfterDelimiter;
      } else if (mState == State::Preamble) {
        const size_t at = mBuffer.find(mDelimiter);
        if (at == std::string::npos) {  // keep what may be the start of the delimiter
          if (mBuffer.size() > mDelimiter.size()) mBuffer.erase(0, mBuffer.size() - mDelimiter.size());
          return;
        }
        mBuffer.erase(0, at + mDelimiter.size());
        mState = State::AfterDelimiter;
      } else if (mState == State::AfterDelimiter) {
        if (mBuffer.size() < 2) return;
        if (mBuffer.compare(0, 2, "--") == 0) {
          mState = State::Closed;
          return;
        }
        const size_t eol = mBuffer.find("\r\n");
        if (eol == std::string::npos) return;
        mBuffer.erase(0, eol + 2);  // (transport padding after the delimiter)
        mState = State::Headers;
      } else if (mState == State::Headers) {
        const size_t end = mBuffer.find("\r\n\r\n");
        if (end == std::string::npos) {
          if (mBuffer.size() > 65536) HYB_THROW(IoError, mWhere, ": part ", mParts + 1, "'s headers run past 64 KB (expected a multipart body)");
          return;
        }
        openPart(mBuffer.substr(0, end));
        mBuffer.erase(0, end + 4);
        mState = State::Body;
      } else {
        return;  // the epilogue
      }
    }
  }

  std::string received() const override {
    return concat(mParts, mExpected ? concat(" of ", mExpected) : "", mParts == 1 && !mExpected ? " instance" : " instances", " whole",
                  mState == State::Body ? concat(" and ", mPartBytes + mBuffer.size(), " bytes of the next") : "");
  }

  /// Checks that the body ended where a multipart body ends.
  void finish() {
    if (mState == State::Closed) return;
    if (mDelimiter.empty()) HYB_THROW(IoError, mWhere, ": empty answer (expected the series' instances, multipart/related)");
    HYB_THROW(IoError, mWhere, ": multipart body cut short after ", received(), " (expected its closing boundary)");
  }

  DicomWebFetch fetched() const { return {mParts, mBytes}; }

 private:
  enum class State { Preamble, AfterDelimiter, Headers, Body, Closed };

  void openPart(const std::string& headers) {
    std::string type;
    for (size_t line = 0; line < headers.size();) {
      const size_t eol = std::min(headers.size(), headers.find("\r\n", line));
      const std::string h = headers.substr(line, eol - line);
      const size_t colon = h.find(':');
      if (colon != std::string::npos) {
        std::string name = h.substr(0, colon);
        std::transform(name.begin(), name.end(), name.begin(), [](unsigned char c) { return char(std::tolower(c)); });
        if (name == "content-type") type = detail::trim(h.substr(colon + 1));
      }
      line = eol + 2;
    }
    std::string bare = detail::trim(type.substr(0, type.find(';')));
    std::transform(bare.begin(), bare.end(), bare.begin(), [](unsigned char c) { return char(std::tolower(c)); });
    if (!bare.empty() && bare != "application/dicom")
      HYB_THROW(IoError, mWhere, ": part ", mParts + 1, " is ", quotedExcerpt(type), " (expected application/dicom: an instance)");
    mPath = (fs::path(mDir) / concat(mPartName, mParts + 1)).string();
    mFile.open(mPath, std::ios::binary | std::ios::trunc);
    if (!mFile) HYB_THROW(IoError, mPath, ": cannot write (expected a writable temporary folder for the series)");
    mPartBytes = 0;
  }

  void write(const char* p, size_t n) {
    if (mState != State::Body || n == 0) return;
    mFile.write(p, std::streamsize(n));
    if (!mFile) HYB_THROW(IoError, mPath, ": write failed after ", mPartBytes, " bytes (disk full?)");
    mPartBytes += n;
  }

  // A whole part: DICOM, named by its SOP Instance UID (what an error message then names).
  void closePart() {
    mFile.close();
    if (!mFile) HYB_THROW(IoError, mPath, ": write failed (disk full?)");
    ++mParts;
    mBytes += mPartBytes;
    if (mTask && !mByBytes) mTask->advance();
    std::string why;
    const std::optional<detail::DicomHeader> h = detail::readDicomHeader(mPath, &why);
    if (!h) HYB_THROW(IoError, mWhere, ": part ", mParts, " (", mPartBytes, " bytes) is ", why, " (expected a DICOM instance)");
    const std::string uid = h->data.text(detail::dicomTag(0x0008, 0x0018));
    const bool plain = !uid.empty() && uid.size() <= 64 && uid.find_first_not_of("0123456789.") == std::string::npos;
    std::error_code ec;
    if (plain && !fs::exists(fs::path(mDir) / uid, ec)) fs::rename(mPath, fs::path(mDir) / uid);
  }

  std::string mWhere, mDir, mPartName;
  size_t mExpected;
  const Progress* mProgress;
  bool mByBytes = true;  // progress counts bytes (of a Content-Length), else instances
  std::unique_ptr<ProgressTask> mTask;
  std::string mDelimiter, mBuffer, mPath;
  State mState = State::Preamble;
  std::ofstream mFile;
  size_t mParts = 0;
  uint64_t mPartBytes = 0, mBytes = 0;
};

// The Study and Series Instance UIDs the address ROOT/studies/UID/series/UID names.
std::pair<std::string, std::string> seriesUids(const std::string& url) {
  checkUrl(url, "DICOMweb series");
  const std::string u = trimmedUrl(url.substr(0, url.find('?')));
  std::vector<std::string> parts;
  for (size_t at = u.find("://") + 3; at <= u.size();) {
    const size_t slash = std::min(u.size(), u.find('/', at));
    parts.push_back(u.substr(at, slash - at));
    at = slash + 1;
  }
  const size_t n = parts.size();
  auto uid = [](const std::string& s) { return !s.empty() && s.size() <= 64 && s.find_first_not_of("0123456789.") == std::string::npos; };
  if (url.find('?') != std::string::npos || n < 5 || parts[n - 4] != "studies" || parts[n - 2] != "series" || !uid(parts[n - 3]) || !uid(parts[n - 1]))
    HYB_THROW(ValueError, redactUrl(url), ": not a DICOMweb series address (expected http(s)://HOST:PORT/ROOT/studies/UID/series/UID; "
              "`hybrid-octree pacs http(s)://HOST:PORT/ROOT` lists them)");
  return {parts[n - 3], parts[n - 1]};
}

// A private folder (mode 0700) under the temporary directory, removed with everything in it.
class TempFolder {
 public:
  TempFolder() {
    std::string pattern = (fs::temp_directory_path() / "hyb-dicomweb-XXXXXX").string();
    if (!::mkdtemp(pattern.data())) HYB_THROW(IoError, pattern, ": cannot make a temporary folder for the series (", std::strerror(errno), ")");
    mPath = pattern;
  }
  ~TempFolder() {
    std::error_code ec;
    fs::remove_all(mPath, ec);
  }
  TempFolder(const TempFolder&) = delete;
  TempFolder& operator=(const TempFolder&) = delete;
  const std::string& path() const { return mPath; }

 private:
  std::string mPath;
};

// @p text with the temporary folder's files named by their instance addresses under @p url.
std::string addressed(std::string text, const std::string& folder, const std::string& url) {
  for (const auto& [from, to] : {std::pair{folder + "/", url + "/instances/"}, {folder, url}})
    for (size_t at = 0; (at = text.find(from, at)) != std::string::npos; at += to.size()) text.replace(at, from.size(), to);
  return text;
}

// Runs @p read with its messages naming instances by their addresses.
template <class Read>
auto addressedErrors(const std::string& folder, const std::string& url, const Read& read) {
  try {
    return read();
  } catch (const IoError& e) {
    throw IoError(addressed(e.what(), folder, url));
  } catch (const ValueError& e) {
    throw ValueError(addressed(e.what(), folder, url));
  }
}

// @p v's frame and info, and its warnings addressed, on @p out.
Volume addressedAs(Volume out, const Volume& v, const std::string& folder, const std::string& url) {
  out.setFrame(v.frame());
  for (const auto& [key, value] : v.info()) out.addInfo(key, addressed(value, folder, url));
  for (const std::string& w : v.warnings()) out.addWarning(addressed(w, folder, url));
  return out;
}

// A retrieved series' planes: its temporary folder lives as long as they do.
class DicomWebPlanes final : public PlaneSource {
 public:
  DicomWebPlanes(std::unique_ptr<PlaneSource> inner, std::unique_ptr<TempFolder> folder, const std::string& url)
      : PlaneSource(addressedAs(Volume::withoutSamples({inner->dims(), inner->description().spacing(), inner->description().sourceType(),
                                                        inner->storedType()},
                                                       0.0f, 0.0f, url),
                                inner->description(), folder->path(), url),
                    url),
        mInner(std::move(inner)),
        mFolder(std::move(folder)),
        mUrl(url) {}
  bool whole() const override { return mInner->whole(); }
  void rewind() override { mInner->rewind(); }
  void read(int count, SampleArray* out, size_t first) override {
    addressedErrors(mFolder->path(), mUrl, [&] {
      mInner->read(count, out, first);
      return 0;
    });
  }

 private:
  std::unique_ptr<PlaneSource> mInner;
  std::unique_ptr<TempFolder> mFolder;
  std::string mUrl;
};

}  // namespace

DicomWebOptions dicomWebDefaults() {
  DicomWebOptions o;
  const std::lock_guard<std::mutex> lock(gAuthFileMutex);
  o.authFile = gAuthFile;
  return o;
}

void setDicomWebAuthFile(const std::string& path) {
  const std::lock_guard<std::mutex> lock(gAuthFileMutex);
  gAuthFile = path;
}

bool isDicomWebUrl(const std::string& path) {
  std::string head = path.substr(0, 8);
  std::transform(head.begin(), head.end(), head.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return head.rfind("http://", 0) == 0 || head.rfind("https://", 0) == 0;
}

std::string redactUrl(const std::string& url) {
  const auto info = userInfo(url);
  return info ? url.substr(0, info->first) + "***" + url.substr(info->second) : url;
}

std::vector<DicomWebSeries> queryDicomWeb(const std::string& rootUrl, const DicomWebQuery& query, const DicomWebOptions& options) {
  checkUrl(rootUrl, "DICOMweb root");
  if (rootUrl.find('?') != std::string::npos) HYB_THROW(ValueError, redactUrl(rootUrl), ": a DICOMweb root has no query (expected http(s)://HOST:PORT/ROOT)");
  if (!query.studyDate.empty() && query.studyDate.find_first_not_of("0123456789-") != std::string::npos)
    HYB_THROW(ValueError, "--study-date ", quotedExcerpt(query.studyDate), " invalid (expected YYYYMMDD or a range YYYYMMDD-YYYYMMDD, either end open)");
  const std::string root = trimmedUrl(rootUrl);
  std::string filter;
  if (!query.patient.empty()) filter += "&PatientName=" + escaped(query.patient);
  if (!query.studyDate.empty()) filter += "&StudyDate=" + escaped(query.studyDate);
  if (!query.modality.empty()) filter += "&ModalitiesInStudy=" + escaped(query.modality);
  const nlohmann::json studies = qido(root + "/studies?includefield=00081030&includefield=00100010&includefield=00100020&includefield=00080020" + filter,
                                             redactUrl(root), options);
  std::vector<DicomWebSeries> out;
  for (const nlohmann::json& study : studies) {
    const std::string studyUid = jsonValue(study, "0020000D");
    if (studyUid.empty()) continue;
    const nlohmann::json series = qido(root + "/studies/" + escaped(studyUid) + "/series?includefield=0008103E&includefield=00080021&includefield=00201209" +
                                           "&includefield=00200011" + (query.modality.empty() ? "" : "&Modality=" + escaped(query.modality)),
                                       redactUrl(root + "/studies/" + studyUid), options);
    for (const nlohmann::json& s : series) {
      DicomWebSeries r;
      DicomSeriesInfo& i = r.info;
      i.uid = jsonValue(s, "0020000E");
      if (i.uid.empty()) continue;
      i.studyUid = studyUid;
      i.patientName = jsonValue(study, "00100010");
      i.patientId = jsonValue(study, "00100020");
      i.studyDate = jsonValue(study, "00080020");
      i.studyDescription = jsonValue(study, "00081030");
      i.modality = jsonValue(s, "00080060");
      i.description = jsonValue(s, "0008103E");
      i.date = jsonValue(s, "00080021");
      i.number = jsonValue(s, "00200011");
      i.slices = i.files = size_t(std::strtoull(jsonValue(s, "00201209").c_str(), nullptr, 10));
      r.url = root + "/studies/" + studyUid + "/series/" + i.uid;
      out.push_back(std::move(r));
    }
  }
  return out;
}

std::pair<std::string, std::vector<std::string>> dicomWebInstances(const std::string& seriesUrl, const DicomWebOptions& options) {
  const std::pair<std::string, std::string> uids = seriesUids(seriesUrl);
  const std::string url = trimmedUrl(seriesUrl);
  std::vector<std::string> instances;
  for (const nlohmann::json& i : qido(url + "/instances?includefield=00080018", redactUrl(url), options))
    if (std::string uid = jsonValue(i, "00080018"); !uid.empty()) instances.push_back(std::move(uid));
  std::sort(instances.begin(), instances.end());
  return {uids.second, std::move(instances)};
}

DicomWebFetch detail::splitMultipart(const std::string& contentType, std::string_view body, const std::string& dir, size_t chunk) {
  MultipartFiles files("answer", dir, 0, nullptr);
  files.start(contentType, int64_t(body.size()));
  for (size_t at = 0; at < body.size(); at += std::max<size_t>(chunk, 1)) files.data(body.data() + at, std::min(std::max<size_t>(chunk, 1), body.size() - at));
  files.finish();
  return files.fetched();
}

DicomWebFetch fetchDicomWebSeries(const std::string& seriesUrl, const std::string& dir, const DicomWebOptions& options, const Progress* progress) {
  const auto [studyUid, seriesUid] = seriesUids(seriesUrl);
  const std::string url = trimmedUrl(seriesUrl);
  // The instances the archive lists (QIDO-RS): what progress counts when the body's length is not given.
  const std::string root = url.substr(0, url.rfind("/studies/"));
  const nlohmann::json listed = qido(root + "/studies/" + studyUid + "/series?SeriesInstanceUID=" + seriesUid + "&includefield=00201209", redactUrl(url), options);
  const size_t expected = listed.size() == 1 ? size_t(std::strtoull(jsonValue(listed.front(), "00201209").c_str(), nullptr, 10)) : 0;
  MultipartFiles files(redactUrl(url), dir, expected, progress);
  // The instances as stored (transfer-syntax=*): the bytes a folder of the same files holds, compressed or not.
  httpGet(url, redactUrl(url), "multipart/related; type=\"application/dicom\"; transfer-syntax=*", options, &files);
  files.finish();
  return files.fetched();
}

namespace {

// The numbers of @p tag (8 hex digits) of a DICOM JSON object: JSON numbers, or decimal strings
// as some archives give DS values.
std::vector<double> jsonNumbers(const nlohmann::json& object, const char* tag) {
  std::vector<double> out;
  const auto e = object.find(tag);
  if (e == object.end() || !e->is_object() || !e->contains("Value") || !(*e)["Value"].is_array()) return out;
  for (const nlohmann::json& v : (*e)["Value"]) {
    if (v.is_number()) {
      out.push_back(v.get<double>());
    } else if (v.is_string()) {
      char* end = nullptr;
      const std::string text = v.get<std::string>();
      out.push_back(std::strtod(text.c_str(), &end));
      if (end == text.c_str()) return {};
    } else {
      return {};
    }
  }
  return out;
}

// The instances of the series at @p url that a preview of about @p planes retrieves: of the
// orientation most instances share, by depth along its normal, every stride-th, centred; empty when
// the series is too small for a preview to gain or its instances lack what the choice needs.
std::vector<std::string> previewInstances(const nlohmann::json& listed, int planes) {
  struct Listed {
    std::string uid;
    double depth = 0.0;
  };
  std::map<std::vector<long long>, std::vector<Listed>> byOrientation;  // orientations to 10⁻⁴
  for (const nlohmann::json& i : listed) {
    const std::string uid = jsonValue(i, "00080018");
    const std::vector<double> p = jsonNumbers(i, "00200032"), o = jsonNumbers(i, "00200037");
    const std::vector<double> frames = jsonNumbers(i, "00280008");
    if (!frames.empty() && frames.front() > 1) return {};
    if (uid.empty() || p.size() != 3 || o.size() != 6) return {};
    std::vector<long long> key;
    for (const double c : o) key.push_back(std::llround(c * 1e4));
    const glm::dvec3 normal = glm::cross(glm::dvec3(o[0], o[1], o[2]), glm::dvec3(o[3], o[4], o[5]));
    byOrientation[key].push_back({uid, glm::dot(normal, glm::dvec3(p[0], p[1], p[2]))});
  }
  std::vector<Listed>* stack = nullptr;
  for (auto& group : byOrientation)
    if (!stack || group.second.size() > stack->size()) stack = &group.second;
  if (!stack || stack->size() <= size_t(2 * planes)) return {};
  std::sort(stack->begin(), stack->end(), [](const Listed& a, const Listed& b) { return a.depth < b.depth; });
  const size_t n = stack->size(), stride = (n + size_t(planes) - 1) / size_t(planes);
  std::vector<std::string> chosen;
  for (size_t at = ((n - 1) % stride) / 2; at < n; at += stride) chosen.push_back((*stack)[at].uid);
  return chosen;
}

}  // namespace

std::optional<Volume> readDicomWebPreview(const std::string& seriesUrl, const DicomWebPreview& size, const Progress* progress,
                                          const DicomWebOptions& options) {
  if (size.planes < 2 || size.edge < 2) HYB_THROW(ValueError, "preview of ", size.planes, " planes of ", size.edge, " samples invalid (expected at least 2 of each)");
  const std::string seriesUid = seriesUids(seriesUrl).second;
  const std::string url = trimmedUrl(seriesUrl);
  const std::vector<std::string> chosen = previewInstances(
      qido(url + "/instances?includefield=00080018&includefield=00200032&includefield=00200037&includefield=00280008", redactUrl(url), options), size.planes);
  if (chosen.empty()) return std::nullopt;
  const TempFolder folder;
  ProgressTask task(progress, "DICOMweb preview", chosen.size());
  for (size_t i = 0; i < chosen.size(); ++i) {
    const std::string instance = url + "/instances/" + chosen[i];
    MultipartFiles files(redactUrl(instance), folder.path(), 1, nullptr, concat("instance", i + 1, "-part"));
    httpGet(instance, redactUrl(instance), "multipart/related; type=\"application/dicom\"; transfer-syntax=*", options, &files);
    files.finish();
    task.advance();
  }
  const Volume planes = addressedErrors(folder.path(), url, [&] { return readDicomSeries(folder.path(), seriesUid); });
  const int edge = std::max(planes.dims().x, planes.dims().y);
  const int factor = (edge + size.edge - 1) / size.edge;
  return factor > 1 ? boxAveraged(planes, {factor, factor, 1}) : planes;
}

Volume readDicomWebSeries(const std::string& seriesUrl, const Progress* progress, const DicomWebOptions& options) {
  const std::string seriesUid = seriesUids(seriesUrl).second;
  const std::string url = trimmedUrl(seriesUrl);
  const TempFolder folder;
  fetchDicomWebSeries(url, folder.path(), options, progress);
  const auto v = std::make_shared<const Volume>(addressedErrors(folder.path(), url, [&] { return readDicomSeries(folder.path(), seriesUid, progress); }));
  // The same samples, borrowed: the volume is renamed, never copied.
  const void* data = std::visit([](const auto& s) -> const void* { return s.data(); }, v->samples());
  return addressedAs(Volume::borrowing(v->layout(), data, v, url), *v, folder.path(), url);
}

std::unique_ptr<PlaneSource> detail::dicomWebPlanes(const std::string& seriesUrl, const Progress* progress, const DicomWebOptions& options) {
  const std::string seriesUid = seriesUids(seriesUrl).second;
  const std::string url = trimmedUrl(seriesUrl);
  auto folder = std::make_unique<TempFolder>();
  fetchDicomWebSeries(url, folder->path(), options, progress);
  std::unique_ptr<PlaneSource> inner = addressedErrors(folder->path(), url, [&] { return dicomPlanes(folder->path(), seriesUid); });
  return std::make_unique<DicomWebPlanes>(std::move(inner), std::move(folder), url);
}

}  // namespace hyb
