#include "apps/viewer/viewer_files.h"

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <random>

#include "surface/mesh_io.h"
#include "volume/core/error.h"
#include "volume/core/file_util.h"
#include "volume/volume_io.h"

namespace hyb::viewer {

namespace fs = std::filesystem;

// The assets compiled in by CMake (web_assets.cpp, generated from web/).
extern const Asset kAssets[];
extern const size_t kAssetCount;

std::string makeToken() {
  std::random_device entropy;
  std::string token;
  for (int i = 0; i < 4; ++i) {
    char part[9];
    std::snprintf(part, sizeof part, "%08x", unsigned(entropy()));
    token += part;
  }
  return token;
}

bool tokenMatches(std::string_view given, std::string_view token) {
  unsigned diff = unsigned(given.size() ^ token.size());
  for (size_t i = 0; i < given.size(); ++i) diff |= unsigned(uint8_t(given[i]) ^ uint8_t(token.empty() ? 0 : token[i % token.size()]));
  return diff == 0 && !token.empty();
}

std::string_view targetPath(std::string_view target) { return target.substr(0, target.find('?')); }

namespace {

std::optional<std::string> percentDecode(std::string_view s) {
  std::string out;
  for (size_t i = 0; i < s.size(); ++i) {
    if (s[i] == '+') {
      out += ' ';
    } else if (s[i] == '%') {
      if (i + 2 >= s.size() || !std::isxdigit(uint8_t(s[i + 1])) || !std::isxdigit(uint8_t(s[i + 2]))) return std::nullopt;
      out += char(std::stoi(std::string(s.substr(i + 1, 2)), nullptr, 16));
      i += 2;
    } else {
      out += s[i];
    }
  }
  return out;
}

// Whether @p real (canonical) lies inside @p root (canonical), the root itself excluded.
bool inside(const fs::path& root, const fs::path& real) {
  const fs::path r = real.lexically_relative(root);
  return !r.empty() && r != "." && *r.begin() != "..";
}

// A file the page may open: of a format the readers know (volume_io.h's table), or a scene.
bool isVolumeName(const fs::path& p) { return fileExtension(p.string()) == ".hoct" || volumeFormatRow(p.string()) != nullptr; }

// A DICOM file: the .dcm extension, or "DICM" at byte 128 (read without blocking: a FIFO is not one).
bool looksLikeDicom(const fs::path& p) {
  if (fileExtension(p.string()) == ".dcm") return true;
  try {
    const InputFile f(p.string());
    uint8_t magic[4] = {};
    if (f.size() < 132) return false;
    f.read(128, 4, magic);
    return std::memcmp(magic, "DICM", 4) == 0;
  } catch (const Error&) {
    return false;
  }
}

// What the page shows for a DICOM series: its folder, study and series, modality and size.
std::string seriesLabel(const std::string& folder, const DicomSeriesInfo& s) {
  std::string label = folder + "/ ";
  if (!s.studyDate.empty()) label += s.studyDate + " ";
  if (!s.studyDescription.empty()) label += s.studyDescription + ": ";
  label += s.description.empty() ? "series " + s.number : s.description;
  label += " (" + (s.modality.empty() ? std::string("?") : s.modality) + ", " + std::to_string(s.slices) + (s.slices == 1 ? " slice" : " slices") +
           (s.localizer ? ", localizer" : "") + ")";
  return label;
}

}  // namespace

std::optional<std::string> queryParam(std::string_view target, std::string_view name) {
  const size_t q = target.find('?');
  if (q == std::string_view::npos) return std::nullopt;
  std::string_view query = target.substr(q + 1);
  while (!query.empty()) {
    const size_t amp = query.find('&');
    const std::string_view pair = query.substr(0, amp);
    const size_t eq = pair.find('=');
    if (pair.substr(0, eq) == name) return eq == std::string_view::npos ? std::string() : percentDecode(pair.substr(eq + 1));
    if (amp == std::string_view::npos) break;
    query = query.substr(amp + 1);
  }
  return std::nullopt;
}

std::optional<std::string> cookieValue(std::string_view header, std::string_view name) {
  while (!header.empty()) {
    const size_t semi = header.find(';');
    std::string_view pair = header.substr(0, semi);
    while (!pair.empty() && pair.front() == ' ') pair.remove_prefix(1);
    const size_t eq = pair.find('=');
    if (eq != std::string_view::npos && pair.substr(0, eq) == name) return std::string(pair.substr(eq + 1));
    if (semi == std::string_view::npos) break;
    header = header.substr(semi + 1);
  }
  return std::nullopt;
}

const Asset* findAsset(std::string_view path) {
  if (path == "/") path = "/index.html";
  for (size_t i = 0; i < kAssetCount; ++i)
    if (kAssets[i].path == path) return &kAssets[i];
  return nullptr;
}

std::vector<DataEntry> listDataDir(const fs::path& dir, size_t maxEntries, std::vector<std::string>* meshes) {
  std::vector<DataEntry> out;
  std::error_code ec;
  const fs::path root = fs::canonical(dir, ec);
  if (ec) HYB_THROW(IoError, dir.string(), ": cannot read the data directory (", ec.message(), ")");
  auto relative = [&](const fs::path& p) { return p.lexically_relative(root).generic_string(); };
  auto visit = [&](auto&& self, const fs::path& d, int depth) -> void {
    std::vector<fs::path> children;
    for (auto it = fs::directory_iterator(d, fs::directory_options::skip_permission_denied, ec); !ec && it != fs::directory_iterator();
         it.increment(ec))
      children.push_back(it->path());
    std::sort(children.begin(), children.end());
    // A patient CD: its DICOMDIR lists every series of the tree below it.
    const bool cd = std::any_of(children.begin(), children.end(), [](const fs::path& c) {
      std::string name = c.filename().string();
      std::transform(name.begin(), name.end(), name.begin(), [](unsigned char ch) { return char(std::toupper(ch)); });
      return name == "DICOMDIR";
    });
    bool dicomHere = cd;
    for (const fs::path& c : children) {
      if (out.size() >= maxEntries) return;
      std::error_code e;
      // Links are followed only while they stay inside the directory.
      const fs::path real = fs::canonical(c, e);
      if (e) continue;
      if (!inside(root, real)) continue;
      if (fs::is_directory(real, e)) {
        if (depth < 6 && !fs::is_symlink(c) && !cd) self(self, real, depth + 1);
      } else if (fs::is_regular_file(real, e) && !cd) {
        if (isVolumeName(c)) out.push_back({relative(c), "", relative(c)});
        else if (meshFormatOf(c.string())) { if (meshes && meshes->size() < maxEntries) meshes->push_back(relative(c)); }
        else dicomHere = dicomHere || looksLikeDicom(real);
      }
    }
    if (dicomHere && out.size() < maxEntries) {
      try {  // the folder's own files (its subfolders are listed as folders), or the CD's whole tree
        for (const DicomSeriesInfo& s : listDicomSeries(d.string(), nullptr, cd).series)
          out.push_back({relative(d), s.uid, seriesLabel(relative(d), s)});
      } catch (const Error&) {  // no image series after all: not listed
      }
    }
  };
  visit(visit, root, 0);
  if (out.size() > maxEntries) out.resize(maxEntries);
  return out;
}

fs::path resolveInDataDir(const fs::path& dir, const std::string& relative) {
  const fs::path rel(relative);
  if (relative.empty() || rel.is_absolute() || relative.front() == '/' || relative.front() == '\\')
    HYB_THROW(ValueError, "path '", relative, "': expected a path relative to the data directory");
  for (const fs::path& part : rel)
    if (part == ".." || part.empty()) HYB_THROW(ValueError, "path '", relative, "': expected no '..' component");
  std::error_code ec;
  const fs::path root = fs::canonical(dir, ec);
  if (ec) HYB_THROW(IoError, dir.string(), ": cannot read the data directory (", ec.message(), ")");
  const fs::path real = fs::canonical(root / rel, ec);
  if (ec) HYB_THROW(ValueError, "path '", relative, "': no such file in the data directory");
  if (!inside(root, real)) HYB_THROW(ValueError, "path '", relative, "': leaves the data directory");
  return real;
}

}  // namespace hyb::viewer
