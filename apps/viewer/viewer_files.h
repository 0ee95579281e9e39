// What the viewer's server reads from outside: the access token, request targets and cookies, the
// page's own assets (compiled into the program: nothing else can be served), and the volumes of a
// data directory, which no path may leave (no "..", no absolute path, no symbolic link out).
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace hyb::viewer {

/// A random access token: 32 hexadecimal digits from the system's entropy source.
std::string makeToken();
/// Compares in time independent of where they differ.
bool tokenMatches(std::string_view given, std::string_view token);

/// The path of a request target ("/a/b?x=1" -> "/a/b"), undecoded.
std::string_view targetPath(std::string_view target);
/// The percent-decoded value of query parameter @p name of @p target; none when absent or badly encoded.
std::optional<std::string> queryParam(std::string_view target, std::string_view name);
/// The value of cookie @p name in a Cookie header; none when absent.
std::optional<std::string> cookieValue(std::string_view header, std::string_view name);

/// One of the page's files, compiled in from web/.
struct Asset {
  std::string_view path;         ///< "/index.html", "/viewer.js", ...
  std::string_view contentType;
  std::string_view bytes;
};
/// The asset served at request path @p path ("/" is "/index.html"); null for anything else.
const Asset* findAsset(std::string_view path);

/// A volume the page may open: a file of a known format or a DICOM directory (one entry a series).
struct DataEntry {
  std::string path;    ///< relative to the data directory, '/'-separated
  std::string series;  ///< a DICOM series' UID, or empty
  std::string label;   ///< what the page shows
};
/// The volumes under @p dir (at most @p maxEntries, at most 6 directories deep), sorted by path;
/// with @p meshes, the mesh files there too (.ply .obj .stl .off, paths as DataEntry's, as many at most).
std::vector<DataEntry> listDataDir(const std::filesystem::path& dir, size_t maxEntries = 500, std::vector<std::string>* meshes = nullptr);

/// The file or directory @p relative names under @p dir, with every symbolic link followed.
/// @throw ValueError naming @p relative when it is absolute, has a ".." or empty component, does not
/// exist, or resolves outside @p dir.
std::filesystem::path resolveInDataDir(const std::filesystem::path& dir, const std::string& relative);

}  // namespace hyb::viewer
