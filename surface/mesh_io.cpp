// OpenMesh lives in this translation unit only (STYLE 6).
#include <OpenMesh/Core/IO/MeshIO.hh>  // first, so the readers and writers register
#include <OpenMesh/Core/Mesh/TriMesh_ArrayKernelT.hh>

#include "surface/mesh_io.h"

#include <algorithm>
#include <bit>
#include <charconv>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <sstream>
#include <string_view>

#include "volume/core/error.h"
#include "volume/core/file_util.h"
#include "volume/core/memory_limit.h"

namespace hyb {

namespace {

using OMesh = OpenMesh::TriMesh_ArrayKernelT<>;

// Silences OpenMesh's logs while it lives: its readers and writers print what they do, and its
// mesh reports rejected faces; failures reach us as return values, reported in our own words.
class Quiet {
 public:
  Quiet() : mLog(omlog().is_enabled()), mOut(omout().is_enabled()), mErr(omerr().is_enabled()) {
    omlog().disable();
    omout().disable();
    omerr().disable();
  }
  Quiet(const Quiet&) = delete;
  Quiet& operator=(const Quiet&) = delete;
  ~Quiet() {
    if (mLog) omlog().enable();
    if (mOut) omout().enable();
    if (mErr) omerr().enable();
  }

 private:
  bool mLog, mOut, mErr;
};

// OpenMesh does not write a file for a mesh without vertices: the format's empty form.
std::string emptyBytes(const std::string& ext) {
  if (ext == ".ply")
    return "ply\nformat binary_little_endian 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
           "property float z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n";
  if (ext == ".off") return "OFF\n0 0 0\n";
  if (ext == ".obj") return "# empty mesh\n";
  // binary STL: 80-byte header and a zero triangle count
  return std::string(80, ' ') + std::string(4, '\0');
}

// Records the coordinates' space where 3D Slicer looks for it: a PLY "comment SPACE=LPS" header
// line, an OBJ "# SPACE=LPS" line, or the STL's 80-byte header.
void recordSpace(std::string* bytes, const std::string& ext, const std::string& space, const std::string& path) {
  if (ext == ".off") return;
  const std::string tag = "SPACE=" + space;
  if (ext == ".stl") {
    if (bytes->size() < 84) HYB_THROW(IoError, path, ": the STL writer produced ", bytes->size(), " bytes (expected at least 84)");
    std::string header = "hybrid-octree " + tag;
    header.resize(80, ' ');
    bytes->replace(0, 80, header);
    return;
  }
  size_t at = 0;
  if (ext == ".ply") {  // after "ply" and the "format" line
    for (int l = 0; l < 2; ++l) {
      const size_t nl = bytes->find('\n', at);
      if (nl == std::string::npos) HYB_THROW(IoError, path, ": the PLY writer produced no header");
      at = nl + 1;
    }
  }
  bytes->insert(at, ext == ".ply" ? "comment " + tag + "\n" : "# " + tag + "\n");
}

// ---- Records OpenMesh would drop without a word
// OpenMesh's importer drops a face naming a vertex it does not hold, its only word going to the
// silenced omerr, and drops or stops at a vertex that is not finite; these scans of the records
// refuse such a file instead, naming the face or vertex, and a header declaring more rows than the
// file has bytes or more faces than the memory limit allows. A record they cannot parse ends the
// scan quietly: OpenMesh's reader judges the rest.

[[noreturn]] void badIndex(const std::string& path, uint64_t face, long long index, uint64_t vertices) {
  HYB_THROW(IoError, path, ": face ", face, " uses vertex ", index, " (expected indices below ", vertices, ")");
}

// Refuses a header's count of @p count @p rows that the file's @p bytes cannot hold: OpenMesh would
// reserve memory for them or step through them one by one.
void tooManyRows(const std::string& path, const std::string& rows, uint64_t count, uint64_t bytes) {
  if (count > bytes) HYB_THROW(IoError, path, ": the header declares ", count, " ", rows, " (expected at most the file's ", bytes, " bytes)");
}

// A number as a text mesh writes it, "nan" and "inf" included (a leading '+' too, as >> reads it);
// false when @p w is not one.
bool numberOf(std::string_view w, double* out) {
  if (w.starts_with('+')) w.remove_prefix(1);
  const auto [stop, error] = std::from_chars(w.data(), w.data() + w.size(), *out);
  return error == std::errc() && stop == w.data() + w.size();
}

// Refuses vertex @p v (its @p where, e.g. " (line 7)") at @p p unless each coordinate is finite:
// OpenMesh's readers drop such a vertex, or stop there, without a word.
void finiteVertex(const std::string& path, uint64_t v, const std::string& where, const double p[3]) {
  if (std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2])) return;
  HYB_THROW(IoError, path, ": vertex ", v, where, " is not finite (", p[0], ", ", p[1], ", ", p[2], ")");
}

// Refuses a file of @p faces faces whose reading would take more than memoryLimit(): OpenMesh's
// half-edge mesh and the TriangleMesh made of it take about kReadBytesPerFace a face (docs/user-geometry.md).
constexpr uint64_t kReadBytesPerFace = 128;
void checkFaceMemory(const std::string& path, uint64_t faces) {
  const uint64_t bytes = faces * kReadBytesPerFace, limit = memoryLimit();
  if (bytes > limit)
    HYB_THROW(IoError, path, ": its ", faces, " faces need about ", formatBytes(bytes), " to read, more than the memory limit of ", formatBytes(limit),
              " (--memory-limit MB on the command line; by default half the physical memory)");
}

// A text file's bytes read word by word, as a stream's >> reads them.
class Words {
 public:
  explicit Words(std::string_view text) : mText(text) {}
  /// The next word; empty at the end.
  std::string_view word() {
    const size_t start = std::min(mText.find_first_not_of(" \t\r\n\f\v", mAt), mText.size());
    mAt = std::min(mText.find_first_of(" \t\r\n\f\v", start), mText.size());
    return mText.substr(start, mAt - start);
  }
  /// The next word as an integer (false when it is not one).
  bool integer(long long* out) {
    const std::string_view w = word();
    return !w.empty() && std::from_chars(w.data(), w.data() + w.size(), *out).ptr == w.data() + w.size();
  }
  /// The rest of the current line, its end included.
  std::string_view line() {
    const size_t start = mAt;
    const size_t nl = mText.find('\n', mAt);
    mAt = nl == std::string_view::npos ? mText.size() : nl + 1;
    return mText.substr(start, mAt - start);
  }
  bool atEnd() const { return mAt >= mText.size(); }

 private:
  std::string_view mText;
  size_t mAt = 0;
};

// OFF as OpenMesh's ASCII reader reads it: [ST][C][N]OFF on the first line, the counts, each vertex
// as its coordinates (and normal) and the rest of its line, each face as its count and indices (and,
// with C, the rest of its line). Binary and higher-dimensional OFF are not scanned.
void checkOffFaces(const std::string& path, std::string_view text) {
  Words in(text);
  const std::string_view header = in.line();
  size_t p = header.starts_with("ST") ? 2 : 0;
  const bool colors = header.substr(p).starts_with("C");
  p += colors;
  const bool normals = header.substr(p).starts_with("N");
  p += normals;
  if (!header.substr(p).starts_with("OFF") || header.find("BINARY") != std::string_view::npos) return;
  long long vertices = 0, faces = 0, edges = 0;
  if (!in.integer(&vertices) || !in.integer(&faces) || !in.integer(&edges) || vertices < 0 || faces < 0) return;
  tooManyRows(path, "vertices", uint64_t(vertices), text.size());
  tooManyRows(path, "faces", uint64_t(faces), text.size());
  checkFaceMemory(path, uint64_t(faces));
  for (long long v = 0; v < vertices; ++v) {
    double corner[3];
    bool numbers = true;
    for (double& x : corner) numbers = numberOf(in.word(), &x) && numbers;
    if (numbers) finiteVertex(path, uint64_t(v), "", corner);
    for (int c = 3; c < (normals ? 6 : 3); ++c) in.word();
    in.line();
  }
  for (long long f = 0; f < faces; ++f) {
    long long n = 0, index = 0;
    if (!in.integer(&n) || n < 0) return;
    for (long long k = 0; k < n; ++k) {
      if (!in.integer(&index)) return;
      if (index < 0 || index >= vertices) badIndex(path, uint64_t(f), index, uint64_t(vertices));
    }
    if (colors) in.line();
  }
}

// OBJ as OpenMesh reads it: a face's vertex is the number before its first '/', counted from 1
// among all the file's vertices, or from -1 back from the last vertex defined above the face.
void checkObjFaces(const std::string& path, std::string_view text) {
  // Calls @p line with each line's number, its keyword ('v' or 'f') and the words after it.
  auto lines = [text](const std::function<void(uint64_t, char, Words&)>& line) {
    Words in(text);
    for (uint64_t number = 1; !in.atEnd(); ++number) {
      const std::string_view l = in.line();
      const size_t start = l.find_first_not_of(" \t");
      if (start != std::string_view::npos && l.size() > start + 1 && (l[start] == 'v' || l[start] == 'f') &&
          (l[start + 1] == ' ' || l[start + 1] == '\t')) {
        Words rest(l.substr(start + 2));
        line(number, l[start], rest);
      }
    }
  };
  // OpenMesh's first pass adds the vertices whose x, y and z are numbers; its second counts every
  // "v" line for the indices counted back.
  uint64_t vertices = 0, above = 0, faces = 0;
  lines([&](uint64_t number, char key, Words& rest) {
    if (key != 'v') return;
    double p[3];
    int numbers = 0;
    for (std::string_view w = rest.word(); numbers < 3 && !w.empty(); w = rest.word(), ++numbers) {
      if (w.starts_with('+')) w.remove_prefix(1);
      if (std::from_chars(w.data(), w.data() + w.size(), p[numbers]).ptr == w.data()) break;
    }
    if (numbers < 3) return;
    finiteVertex(path, vertices, detail::concat(" (line ", number, ")"), p);
    ++vertices;
  });
  lines([&](uint64_t number, char key, Words& rest) {
    if (key == 'v') {
      ++above;
      return;
    }
    for (std::string_view w = rest.word(); !w.empty(); w = rest.word()) {
      long long index = 0;
      const auto [stop, error] = std::from_chars(w.data(), w.data() + w.size(), index);
      if (error != std::errc() || (stop != w.data() + w.size() && *stop != '/')) continue;  // as OpenMesh: not a number, no vertex
      if (index > 0 ? uint64_t(index) <= vertices : index < 0 && uint64_t(0) - uint64_t(index) <= above) continue;
      HYB_THROW(IoError, path, ": face ", faces, " (line ", number, ") uses vertex ", index, " (expected 1 to ", vertices,
                above ? detail::concat(", or -1 to -", above, " counting back from the last vertex above it") : std::string(), ")");
    }
    ++faces;
  });
  checkFaceMemory(path, faces);
}

// A PLY value of type T from its bytes in the host's order.
template <class T>
double plyValue(const unsigned char* bytes) {
  T v;
  std::memcpy(&v, bytes, sizeof v);
  return double(v);
}

// PLY, ASCII or binary: every element read property by property (lists as their count and items),
// the indices of the face element's vertex_indices (or vertex_index) list checked.
void checkPlyFaces(const std::string& path) {
  struct Type {
    const char* name;
    int size;
    double (*read)(const unsigned char*);  // the value of its bytes in the host's order
  };
  static constexpr Type kTypes[] = {
      {"char", 1, plyValue<int8_t>},     {"int8", 1, plyValue<int8_t>},      {"uchar", 1, plyValue<uint8_t>},   {"uint8", 1, plyValue<uint8_t>},
      {"short", 2, plyValue<int16_t>},   {"int16", 2, plyValue<int16_t>},    {"ushort", 2, plyValue<uint16_t>}, {"uint16", 2, plyValue<uint16_t>},
      {"int", 4, plyValue<int32_t>},     {"int32", 4, plyValue<int32_t>},    {"uint", 4, plyValue<uint32_t>},   {"uint32", 4, plyValue<uint32_t>},
      {"float", 4, plyValue<float>},     {"float32", 4, plyValue<float>},    {"double", 8, plyValue<double>},   {"float64", 8, plyValue<double>}};
  auto typeOf = [](const std::string& name) -> const Type* {
    for (const Type& t : kTypes)
      if (name == t.name) return &t;
    return nullptr;
  };
  struct Property {
    const Type* type = nullptr;
    const Type* count = nullptr;  // a list's count; null: not a list
    bool indices = false;         // the face element's vertex list
    int axis = -1;                // the vertex element's x, y or z: 0, 1, 2
  };
  struct Element {
    std::string name;
    uint64_t count = 0;
    std::vector<Property> properties;
  };
  std::ifstream in(path, std::ios::binary);
  std::string line, format;
  std::vector<Element> elements;
  while (std::getline(in, line)) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream words(line);
    std::string word, type, countType, name;
    words >> word;
    if (word == "format") {
      words >> format;
    } else if (word == "element") {
      elements.emplace_back();
      if (!(words >> elements.back().name >> elements.back().count)) return;
    } else if (word == "property" && !elements.empty()) {
      Property p;
      if (!(words >> type)) return;
      if (type == "list" && !(words >> countType && (p.count = typeOf(countType)))) return;
      if (type == "list" && !(words >> type)) return;
      if (!(words >> name) || !(p.type = typeOf(type))) return;
      p.indices = elements.back().name == "face" && p.count && (name == "vertex_indices" || name == "vertex_index");
      if (elements.back().name == "vertex" && !p.count && name.size() == 1 && name[0] >= 'x' && name[0] <= 'z') p.axis = name[0] - 'x';
      elements.back().properties.push_back(p);
    } else if (word == "end_header") {
      break;
    }
  }
  const bool ascii = format == "ascii";
  const bool swap = (format == "binary_big_endian") != (std::endian::native == std::endian::big);
  if (!in || (!ascii && format != "binary_little_endian" && format != "binary_big_endian")) return;
  uint64_t vertices = 0;
  std::error_code ec;
  const uint64_t bytes = std::filesystem::file_size(path, ec);
  for (const Element& e : elements) {
    tooManyRows(path, "'" + e.name + "' rows", e.count, bytes);
    if (e.name == "vertex") vertices = e.count;
    if (e.name == "face") checkFaceMemory(path, e.count);
  }
  // One value (false at the file's end, or on a word that is not a number).
  auto value = [&](const Type& t, double* out) {
    if (ascii) {
      std::string w;
      return in >> w && numberOf(w, out);
    }
    unsigned char b[8];
    if (!in.read(reinterpret_cast<char*>(b), t.size)) return false;
    if (swap) std::reverse(b, b + t.size);
    *out = t.read(b);
    return true;
  };
  uint64_t face = 0;
  for (const Element& e : elements) {
    const bool corners = e.name == "vertex";
    if (!ascii && !corners && std::none_of(e.properties.begin(), e.properties.end(), [](const Property& p) { return p.count; })) {
      int64_t row = 0;  // no list: the element's rows are skipped whole
      for (const Property& p : e.properties) row += p.type->size;
      in.seekg(std::streamoff(row * int64_t(e.count)), std::ios::cur);
      continue;
    }
    for (uint64_t i = 0; i < e.count; ++i) {
      double corner[3] = {0.0, 0.0, 0.0};
      for (const Property& p : e.properties) {
        double items = 1, item = 0;
        if (p.count && (!value(*p.count, &items) || !(items >= 0))) return;
        for (double k = 0; k < items; ++k) {
          if (!value(*p.type, &item)) return;
          if (p.axis >= 0) corner[p.axis] = item;
          if (p.indices && !(item >= 0 && item < double(vertices))) {
            if (!(std::abs(item) < 9e18)) return;  // no integer: OpenMesh's to judge
            badIndex(path, face, (long long)item, vertices);
          }
        }
      }
      if (corners) finiteVertex(path, i, "", corner);
      face += e.name == "face";
    }
  }
}

// STL as OpenMesh tells its forms apart: binary when the file is the 84 bytes of its header and
// count and 50 bytes a facet (a normal, three corners, two bytes), else text ("vertex x y z" lines).
// Each corner is checked; OpenMesh merges corners by position, so vertices are counted by corner.
void checkStlFaces(const std::string& path) {
  std::error_code ec;
  const uint64_t size = std::filesystem::file_size(path, ec);
  std::ifstream in(path, std::ios::binary);
  unsigned char head[84];
  uint32_t facets = 0;
  if (in.read(reinterpret_cast<char*>(head), 84)) std::memcpy(&facets, head + 80, 4);  // (little-endian hosts, as OpenMesh reads it)
  if (in && size == 84 + 50 * uint64_t(facets)) {
    checkFaceMemory(path, facets);
    std::vector<unsigned char> chunk(50 * 4096);
    for (uint64_t f = 0; f < facets;) {
      const uint64_t n = std::min<uint64_t>(4096, facets - f);
      if (!in.read(reinterpret_cast<char*>(chunk.data()), std::streamsize(50 * n))) return;
      for (uint64_t k = 0; k < n; ++k, ++f)
        for (int c = 0; c < 3; ++c) {
          float x[3];
          std::memcpy(x, &chunk[50 * k + 12 * (c + 1)], sizeof x);
          const double p[3] = {x[0], x[1], x[2]};
          finiteVertex(path, 3 * f + uint64_t(c), detail::concat(" (corner ", c, " of facet ", f, ")"), p);
        }
    }
    return;
  }
  const std::vector<uint8_t> bytes = readFileBytes(path);
  Words words(std::string_view(reinterpret_cast<const char*>(bytes.data()), bytes.size()));
  uint64_t corners = 0;
  for (std::string_view w = words.word(); !w.empty(); w = words.word()) {
    if (w != "vertex") continue;
    double p[3];
    bool numbers = true;
    for (double& x : p) numbers = numberOf(words.word(), &x) && numbers;
    if (numbers) finiteVertex(path, corners, detail::concat(" (corner ", corners % 3, " of facet ", corners / 3, ")"), p);
    ++corners;
  }
  checkFaceMemory(path, corners / 3);
}

// Refuses a face naming a vertex the file does not hold (STL has no indices), a vertex that is
// not finite, and a file too large to read within the memory limit.
void checkMeshRecords(const std::string& path) {
  const std::string ext = fileExtension(path);
  if (ext == ".ply") return checkPlyFaces(path);
  if (ext == ".stl") return checkStlFaces(path);
  if (ext != ".off" && ext != ".obj") return;
  const std::vector<uint8_t> bytes = readFileBytes(path);
  const std::string_view text(reinterpret_cast<const char*>(bytes.data()), bytes.size());
  if (ext == ".off") checkOffFaces(path, text);
  if (ext == ".obj") checkObjFaces(path, text);
}

}  // namespace

const std::vector<MeshFormat>& meshFormats() {
  static const std::vector<MeshFormat> formats = {{".ply", true, true}, {".obj", false, true}, {".stl", true, false}, {".off", false, false}};
  return formats;
}

const MeshFormat* meshFormatOf(const std::string& path) {
  const std::string ext = fileExtension(path);
  for (const MeshFormat& f : meshFormats())
    if (f.extension == ext) return &f;
  return nullptr;
}

std::string meshExtensionsText(bool withNormals, bool dots) {
  std::vector<std::string> names;
  for (const MeshFormat& f : meshFormats())
    if (!withNormals || f.normals) names.push_back(dots ? f.extension : f.extension.substr(1));
  std::string text;
  for (size_t i = 0; i < names.size(); ++i) text += (i == 0 ? "" : i + 1 == names.size() ? " or " : ", ") + names[i];
  return text;
}

void writeMesh(const std::string& path, const TriangleMesh& mesh, const MeshWriteOptions& options) {
  const MeshFormat* format = meshFormatOf(path);
  if (!format) HYB_THROW(IoError, path, ": unknown mesh format '", fileExtension(path), "' (expected ", meshExtensionsText(), ")");
  const std::string bytes = meshBytes(mesh, *format, options, path);
  writeFileAtomically(path, [&](std::ostream& out) { out.write(bytes.data(), std::streamsize(bytes.size())); });
}

std::string meshBytes(const TriangleMesh& mesh, const MeshFormat& format, const MeshWriteOptions& options, const std::string& name) {
  const std::string& ext = format.extension;
  const bool normals = options.normals && !mesh.normals.empty();
  if (options.normals && !format.normals)
    HYB_THROW(IoError, name, ": vertex normals can be written to ", meshExtensionsText(true), " files only (STL keeps facet normals, OFF none)");
  if (mesh.triangles.empty()) return emptyBytes(ext);
  OMesh om;
  if (normals) om.request_vertex_normals();
  om.reserve(mesh.vertices.size(), mesh.triangles.size() * 3 / 2, mesh.triangles.size());
  std::vector<OMesh::VertexHandle> vh;
  vh.reserve(mesh.vertices.size());
  for (size_t i = 0; i < mesh.vertices.size(); ++i) {
    const glm::vec3& p = mesh.vertices[i];
    vh.push_back(om.add_vertex(OMesh::Point(p.x, p.y, p.z)));
    if (normals) om.set_normal(vh.back(), OMesh::Normal(mesh.normals[i].x, mesh.normals[i].y, mesh.normals[i].z));
  }
  {
    // OpenMesh reports each face its half-edge structure rejects on omerr; those are expected here
    // (classic MC's non-manifold edges) and handled below.
    const Quiet quiet;
    for (const glm::uvec3& t : mesh.triangles)
      if (!om.add_face(vh[t.x], vh[t.y], vh[t.z]).is_valid()) {
        // A face OpenMesh's half-edge structure cannot take (non-manifold): keep it with own vertices.
        OMesh::VertexHandle copy[3];
        for (int k = 0; k < 3; ++k) {
          const OMesh::Point p = om.point(vh[t[k]]);  // a copy: adding a vertex may move the points
          copy[k] = om.add_vertex(p);
          if (normals) om.set_normal(copy[k], OMesh::Normal(mesh.normals[t[k]].x, mesh.normals[t[k]].y, mesh.normals[t[k]].z));
        }
        om.add_face(copy[0], copy[1], copy[2]);
      }
  }
  OpenMesh::IO::Options io;
  if (format.binary) io += OpenMesh::IO::Options::Binary;
  if (normals) io += OpenMesh::IO::Options::VertexNormal;
  // Written to memory, then to the file by our own stream: OpenMesh's file writers report success
  // on a full disk.
  std::ostringstream made(std::ios::binary);
  if (ext == ".obj") made << std::fixed;  // as OpenMesh's OBJ file writer formats its numbers
  {
    const Quiet quiet;  // the writers log what they write ("[STLWriter] : write binary file")
    if (!OpenMesh::IO::write_mesh(om, made, ext.substr(1), io) || !made)
      HYB_THROW(IoError, name, ": OpenMesh could not write the mesh");
  }
  std::string bytes = std::move(made).str();
  if (!options.space.empty()) recordSpace(&bytes, ext, options.space, name);
  return bytes;
}

TriangleMesh readMesh(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) HYB_THROW(IoError, path, ": file does not exist");
  TriangleMesh out;
  if (std::filesystem::file_size(path, ec) <= 84) {  // empty forms written above
    std::ifstream in(path, std::ios::binary);
    const std::string head((std::istreambuf_iterator<char>(in)), {});
    if (head.find("element vertex 0") != std::string::npos || head.rfind("OFF\n0 ", 0) == 0 || head.rfind("# empty", 0) == 0 ||
        head.size() == 84)
      return out;
  }
  checkMeshRecords(path);
  OMesh om;
  om.request_vertex_normals();
  OpenMesh::IO::Options options = OpenMesh::IO::Options::VertexNormal;
  const Quiet quiet;
  if (!OpenMesh::IO::read_mesh(om, path, options)) HYB_THROW(IoError, path, ": OpenMesh could not read the mesh");
  const bool normals = options.check(OpenMesh::IO::Options::VertexNormal);
  for (const auto& v : om.vertices()) {
    const auto p = om.point(v);
    out.vertices.push_back({p[0], p[1], p[2]});
    if (normals) {
      const auto n = om.normal(v);
      out.normals.push_back({n[0], n[1], n[2]});
    }
  }
  for (const auto& f : om.faces()) {
    glm::uvec3 t;
    int k = 0;
    for (const auto& v : om.fv_range(f)) t[k++] = uint32_t(v.idx());
    out.triangles.push_back(t);
  }
  return out;
}

}  // namespace hyb
