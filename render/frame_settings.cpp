#include "render/frame_settings.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <charconv>
#include <cstdio>
#include <filesystem>
#include <cmath>
#include <limits>
#include <ostream>
#include <sstream>

#include "hybrid_octree/hybrid_io.h"
#include "hybrid_octree/knot_store.h"
#include "render/geometry_channel.h"
#include "render/scene_renderer.h"
#include "volume/core/error.h"
#include "volume/core/file_util.h"

namespace hyb {

using nlohmann::json;

namespace {

constexpr double kFloatMax = double(std::numeric_limits<float>::max());
const char* const kViews[] = {"anterior", "posterior", "left", "right", "superior", "inferior"};

// The shortest text that reads back as the same double.
std::string exact(double x) {
  char t[32];
  return std::string(t, std::to_chars(t, t + sizeof t, x).ptr);
}

// A float as the double of its shortest text (0.9f as 0.9): what a field held as a float writes,
// so that the text reads back as the same float and the echo shows what the user typed.
double typed(float x) {
  char t[32];
  double d = 0;
  std::from_chars(t, std::to_chars(t, t + sizeof t, x).ptr, d);
  return d;
}

std::string joined(const std::vector<double>& v) {
  std::string s;
  for (const double x : v) {
    if (!s.empty()) s += ',';
    s += exact(x);
  }
  return s;
}

// Separator-separated finite numbers (a comma, or an 'x' in a size), or none.
std::optional<std::vector<double>> numbersIn(const std::string& text, char separator = ',') {
  std::vector<double> out;
  if (text.empty()) return std::nullopt;
  for (size_t at = 0; at <= text.size();) {
    const size_t end = std::min(text.find(separator, at), text.size());
    std::string word = text.substr(at, end - at);
    while (!word.empty() && word.front() == ' ') word.erase(word.begin());
    while (!word.empty() && word.back() == ' ') word.pop_back();
    double x = 0;
    const auto [stop, ec] = std::from_chars(word.data(), word.data() + word.size(), x);
    if (word.empty() || ec != std::errc() || stop != word.data() + word.size() || !std::isfinite(x)) return std::nullopt;
    out.push_back(x);
    at = end + 1;
  }
  return out;
}

// Control points "value,r,g,b,a;...", each colour and opacity in [0, 1], values increasing; or none.
std::optional<std::vector<TransferFunction::Point>> pointsIn(const std::string& text) {
  std::vector<TransferFunction::Point> points;
  std::istringstream in(text);
  for (std::string item; std::getline(in, item, ';');) {
    const std::optional<std::vector<double>> v = numbersIn(item);
    if (!v || v->size() != 5 || std::abs((*v)[0]) > kFloatMax) return std::nullopt;
    for (int k = 1; k < 5; ++k)
      if (!((*v)[size_t(k)] >= 0.0 && (*v)[size_t(k)] <= 1.0)) return std::nullopt;
    if (!points.empty() && (*v)[0] < points.back().value) return std::nullopt;
    points.push_back({float((*v)[0]), glm::vec3(float((*v)[1]), float((*v)[2]), float((*v)[3])), float((*v)[4])});
  }
  if (points.empty() || points.size() > 256) return std::nullopt;
  return points;
}

std::string pointsText(const std::vector<TransferFunction::Point>& points) {
  std::string s;
  for (const TransferFunction::Point& p : points) {
    if (!s.empty()) s += ';';
    s += joined({typed(p.value), typed(p.color.r), typed(p.color.g), typed(p.color.b), typed(p.alpha)});
  }
  return s;
}

// A budget's text: megabytes, or "P%" of the view's full-resolution bytes; none when it is not one number.
struct Budget {
  bool percent = false;
  double value = 0.0;
};
std::optional<Budget> budgetIn(const std::string& text) {
  const bool percent = !text.empty() && text.back() == '%';
  const std::optional<std::vector<double>> v = numbersIn(percent ? text.substr(0, text.size() - 1) : text);
  if (!v || v->size() != 1) return std::nullopt;
  return Budget{percent, v->front()};
}

std::string budgetError(const std::string& text) {
  const std::optional<Budget> b = budgetIn(text);
  if (!b) return "not a number";
  if (b->percent ? !(b->value > 0.0 && b->value <= 100.0) : b->value < 0.0) return b->percent ? "a percentage in (0, 100]" : "megabytes >= 0";
  return "";
}

// Items separated by ';' or newlines (a repeated flag's), empty ones dropped.
std::vector<std::string> itemsIn(const std::string& text) {
  std::vector<std::string> items;
  for (size_t at = 0; at <= text.size();) {
    const size_t end = std::min(text.find_first_of(";\n", at), text.size());
    if (end > at) items.push_back(text.substr(at, end - at));
    at = end + 1;
  }
  return items;
}

// Mesh files "FILE[:r,g,b,a]" separated by ';' or newlines (a repeated flag's), or why not.
std::string meshFilesIn(const std::string& text, std::vector<FrameSettings::MeshFile>* out) {
  std::vector<FrameSettings::MeshFile> files;
  for (const std::string& item : itemsIn(text)) {
    FrameSettings::MeshFile m{item};
    if (const size_t colon = item.rfind(':'); colon != std::string::npos) {
      const std::string tail = item.substr(colon + 1);
      if (const std::optional<std::vector<double>> v = numbersIn(tail)) {
        if (v->size() != 4 || std::any_of(v->begin(), v->end(), [](double x) { return !(x >= 0.0 && x <= 1.0); }))
          return "the colour after ':' is r,g,b,a, each in [0, 1]";
        m = {item.substr(0, colon), glm::vec4(float((*v)[0]), float((*v)[1]), float((*v)[2]), float((*v)[3]))};
      }
    }
    if (m.path.empty()) return "a file before the colour";
    files.push_back(m);
  }
  if (files.size() > size_t(kMaxUserMeshes)) return "at most " + std::to_string(kMaxUserMeshes) + " meshes";
  if (out) *out = std::move(files);
  return "";
}

std::string meshFilesText(const std::vector<FrameSettings::MeshFile>& files) {
  std::string s;
  for (const FrameSettings::MeshFile& m : files) {
    s += (s.empty() ? "" : ";") + m.path;
    if (m.color != FrameSettings::MeshFile{}.color) s += ":" + joined({typed(m.color.r), typed(m.color.g), typed(m.color.b), typed(m.color.a)});
  }
  return s;
}

// Every --primitive item of @p text, or why one is not (naming it).
std::string primitivesIn(const std::string& text, std::vector<std::string>* out) {
  const std::vector<std::string> items = itemsIn(text);
  if (items.size() > size_t(kMaxUserMeshes)) return "at most " + std::to_string(kMaxUserMeshes) + " meshes and primitives";
  for (const std::string& item : items) {
    UserPrimitive p;
    glm::vec4 color;
    if (const std::string why = primitiveIn(item, &p, &color); !why.empty()) return quotedExcerpt(item, 60) + ": " + why;
  }
  if (out) *out = items;
  return "";
}

// Builders of the table's rows: @p f holds the row's words (name, kind where it is not the
// builder's, range, unit, help, doors), the builder where its value is held.
using SetNumbers = std::function<void(FrameSettings&, const std::optional<std::vector<double>>&)>;
using GetNumbers = std::function<std::optional<std::vector<double>>(const FrameSettings&)>;
using SetWord = std::function<void(FrameSettings&, const std::optional<std::string>&)>;
using GetWord = std::function<std::optional<std::string>(const FrameSettings&)>;

// A number (or a whole number: f.kind Integer) held in @p at; an optional one is unset by default.
template <class At>
FrameField number(FrameField f, At at) {
  using Held = std::remove_reference_t<decltype(at(std::declval<FrameSettings&>()))>;
  f.optional = !std::is_arithmetic_v<Held>;
  f.setNumbers = [at](FrameSettings& s, const std::optional<std::vector<double>>& v) {
    if constexpr (std::is_arithmetic_v<Held>) at(s) = Held(v->front());
    else at(s) = v ? std::optional<typename Held::value_type>(typename Held::value_type(v->front())) : std::nullopt;
  };
  f.get = [at](const FrameSettings& s) -> std::optional<std::string> {
    const auto& held = at(const_cast<FrameSettings&>(s));
    const auto text = [](auto x) { return exact(std::is_same_v<decltype(x), float> ? typed(float(x)) : double(x)); };
    if constexpr (std::is_arithmetic_v<Held>) return text(held);
    else return held ? std::optional(text(*held)) : std::nullopt;
  };
  return f;
}

// f.count numbers (f.kind Numbers), each in the row's range, held by @p set and given by @p get.
FrameField numbers(FrameField f, SetNumbers set, GetNumbers get, std::function<std::string(const std::vector<double>&)> check = {}) {
  f.kind = FieldKind::Numbers;
  f.setNumbers = std::move(set);
  f.check = std::move(check);
  f.get = [get](const FrameSettings& s) -> std::optional<std::string> {
    const std::optional<std::vector<double>> v = get(s);
    return v ? std::optional(joined(*v)) : std::nullopt;
  };
  return f;
}

// A word (f.kind Switch, Flag, Choice, Text, Budget or Points).
FrameField word(FrameField f, SetWord set, GetWord get) {
  f.setWord = std::move(set);
  f.get = std::move(get);
  return f;
}

FrameField onOff(FrameField f, bool FrameSettings::*member) {
  f.kind = FieldKind::Switch;
  f.choices = {"on", "off"};
  return word(std::move(f), [member](FrameSettings& s, const std::optional<std::string>& w) { s.*member = *w == "on"; },
              [member](const FrameSettings& s) { return std::optional<std::string>(s.*member ? "on" : "off"); });
}

// A text held in @p member, unset when empty.
FrameField textField(FrameField f, std::string FrameSettings::*member) {
  f.optional = true;
  return word(std::move(f), [member](FrameSettings& s, const std::optional<std::string>& w) { s.*member = w.value_or(""); },
              [member](const FrameSettings& s) { return (s.*member).empty() ? std::nullopt : std::optional(s.*member); });
}

std::optional<std::vector<double>> vec(const std::optional<glm::dvec3>& v) {
  return v ? std::optional(std::vector<double>{v->x, v->y, v->z}) : std::nullopt;
}
std::optional<glm::dvec3> vec3(const std::optional<std::vector<double>>& v) {
  return v ? std::optional(glm::dvec3((*v)[0], (*v)[1], (*v)[2])) : std::nullopt;
}

// A point in patient mm (eye, center, focus).
FrameField point(FrameField f, std::optional<glm::dvec3>& (*at)(FrameSettings&)) {
  f.count = 3;
  f.lo = -kMaxCameraMm;
  f.hi = kMaxCameraMm;
  f.unit = "mm";
  f.shape = "x,y,z";
  f.optional = true;
  return numbers(std::move(f), [at](FrameSettings& s, const std::optional<std::vector<double>>& v) { at(s) = vec3(v); },
                 [at](const FrameSettings& s) { return vec(at(const_cast<FrameSettings&>(s))); });
}

std::string nonZero(const std::vector<double>& v) {
  return v[0] == 0 && v[1] == 0 && v[2] == 0 ? "a direction, not zero" : "";
}

template <class Enum>
FrameField choice(FrameField f, std::vector<std::pair<std::string, Enum>> words, Enum& (*at)(FrameSettings&)) {
  f.kind = FieldKind::Choice;
  for (const auto& w : words) f.choices.push_back(w.first);
  return word(
      std::move(f),
      [at, words](FrameSettings& s, const std::optional<std::string>& w) {
        for (const auto& [text, value] : words)
          if (text == *w) at(s) = value;
      },
      [at, words](const FrameSettings& s) -> std::optional<std::string> {
        for (const auto& [text, value] : words)
          if (value == at(const_cast<FrameSettings&>(s))) return text;
        return std::nullopt;
      });
}

constexpr unsigned kCliPy = kCommandLine | kPython;

// Where from: the camera.
void addCameraFields(std::vector<FrameField>& f) {
  f.push_back(point({.name = "eye", .help = "camera position x,y,z (LPS: x towards the patient's left, y posterior, z superior; with center and up)"},
                    [](FrameSettings& s) -> auto& { return s.eye; }));
  f.push_back(point({.name = "center", .help = "point looked at x,y,z (default: the volume's centre); needs eye"}, [](FrameSettings& s) -> auto& { return s.center; }));
  f.push_back(numbers({.name = "up", .count = 3, .lo = -kMaxCameraMm, .hi = kMaxCameraMm, .shape = "x,y,z",
                       .help = "up direction x,y,z in patient axes (default 0,0,1, superior); needs eye", .optional = true},
                      [](FrameSettings& s, const std::optional<std::vector<double>>& v) { s.up = vec3(v); }, [](const FrameSettings& s) { return vec(s.up); },
                      nonZero));
  f.push_back(word(
      {.name = "view", .kind = FieldKind::Choice,
       .help = "anatomical view: anterior (default; the patient's left on the image's right), posterior, left, right, superior, inferior",
       .choices = std::vector<std::string>(std::begin(kViews), std::end(kViews)), .doors = kCliPy, .optional = true},
      [](FrameSettings& s, const std::optional<std::string>& w) {
        AnatomicalView v{};
        s.view = w && parseAnatomicalView(*w, &v) ? std::optional(v) : std::nullopt;
      },
      [](const FrameSettings& s) { return s.view ? std::optional<std::string>(kViews[int(*s.view)]) : std::nullopt; }));
  f.push_back(numbers(
      {.name = "orbit", .count = 2, .lo = -1e6, .hi = 1e6, .unit = "degrees", .shape = "azimuth,elevation",
       .help = "azimuth,elevation from the anterior view: azimuth towards the patient's left (90 = left view), elevation towards superior",
       .doors = kCliPy, .optional = true},
      [](FrameSettings& s, const std::optional<std::vector<double>>& v) { s.orbit = v ? std::optional(glm::dvec2((*v)[0], (*v)[1])) : std::nullopt; },
      [](const FrameSettings& s) { return s.orbit ? std::optional(std::vector<double>{s.orbit->x, s.orbit->y}) : std::nullopt; }));
  f.push_back(number({.name = "zoom", .lo = 0.0, .hi = 1000.0, .loOpen = true,
                      .help = "magnify the image about its centre (2 = twice as large; the default framing fits what is visible)", .doors = kCliPy},
                     [](FrameSettings& s) -> auto& { return s.zoom; }));
  f.push_back(number({.name = "fov", .lo = kMinFovDeg, .hi = kMaxFovDeg, .hiOpen = true, .unit = "degrees", .help = "vertical field of view"},
                     [](FrameSettings& s) -> auto& { return s.fov; }));
  f.push_back(word({.name = "ortho", .kind = FieldKind::Flag, .help = "orthographic projection", .choices = {"on", "off"}},
                   [](FrameSettings& s, const std::optional<std::string>& w) { s.ortho = *w == "on"; },
                   [](const FrameSettings& s) { return std::optional<std::string>(s.ortho ? "on" : "off"); }));
  f.push_back(number({.name = "ortho_height", .lo = 0.0, .hi = kMaxCameraMm, .loOpen = true, .unit = "mm",
                      .help = "height an orthographic view spans (default: what frames the volume)"},
                     [](FrameSettings& s) -> auto& { return s.orthoHeight; }));
  FrameField size = numbers(
      {.name = "size", .count = 2, .lo = 1, .hi = kMaxRenderEdge, .unit = "pixels", .shape = "WxH",
       .help = "image size WxH (default 512x512, or the camera file's)", .optional = true},
      [](FrameSettings& s, const std::optional<std::vector<double>>& v) { s.size = v ? std::optional(glm::ivec2(int((*v)[0]), int((*v)[1]))) : std::nullopt; },
      {});
  size.kind = FieldKind::Size;
  size.get = [](const FrameSettings& s) { return s.size ? std::optional(std::to_string(s.size->x) + "x" + std::to_string(s.size->y)) : std::nullopt; };
  f.push_back(size);
  f.push_back(textField({.name = "camera_file", .kind = FieldKind::Text, .help = "read the camera from a JSON file written by --stats (or its \"camera\" object alone)",
                    .doors = kCliPy},
                   &FrameSettings::cameraFile));
  f.push_back(onOff({.name = "marker", .help = "orientation marker (patient axes L/R, P/A, S/I) in the lower-left corner (default off)", .doors = kCliPy},
                    &FrameSettings::marker));
}


// What is shown: the transfer function, the surface, the cut, the volume of interest.
void addLookFields(std::vector<FrameField>& f) {
  std::string presets;
  for (const TransferFunction::Preset& p : TransferFunction::presets()) presets += (presets.empty() ? "" : ", ") + std::string(p.name) + " (" + p.shows + ")";
  f.push_back(textField({.name = "preset", .kind = FieldKind::Choice,
                    .help = "transfer function: " + presets + "; default " + TransferFunction::presets().front().name +
                            " for CT, a ramp over the data's range for other data",
                    .choices = TransferFunction::presetNames()},
                   &FrameSettings::preset));
  f.push_back(textField({.name = "tf", .kind = FieldKind::Text, .help = "transfer function file: 'value r g b a' lines, a = opacity of 1 mm", .doors = kCliPy},
                   &FrameSettings::tf));
  f.push_back(word(
      {.name = "tf_points", .kind = FieldKind::Points,
       .help = "transfer function control points value,r,g,b,a;... (opacity of 1 mm), values increasing", .doors = kViewer, .optional = true},
      [](FrameSettings& s, const std::optional<std::string>& w) { s.tfPoints = w ? *pointsIn(*w) : std::vector<TransferFunction::Point>{}; },
      [](const FrameSettings& s) { return s.tfPoints.empty() ? std::nullopt : std::optional(pointsText(s.tfPoints)); }));
  f.push_back(number({.name = "opacity", .lo = 0.0, .hi = 10.0, .help = "multiplies every opacity of the transfer function (at most 1 each)"},
                     [](FrameSettings& s) -> auto& { return s.opacity; }));
  f.push_back(number({.name = "iso", .lo = -kFloatMax, .hi = kFloatMax, .unit = "data units", .help = "isovalue of the embedded surface (none: volume only)"},
                     [](FrameSettings& s) -> auto& { return s.iso; }));
  f.push_back(numbers(
      {.name = "surface_color", .count = 4, .lo = 0.0, .hi = 1.0, .shape = "r,g,b,a", .help = "surface r,g,b,a; a < 1 is translucent (default 0.95,0.92,0.85,1)"},
      [](FrameSettings& s, const std::optional<std::vector<double>>& v) {
        s.surfaceColor = glm::vec4(float((*v)[0]), float((*v)[1]), float((*v)[2]), float((*v)[3]));
      },
      [](const FrameSettings& s) {
        return std::optional(std::vector<double>{typed(s.surfaceColor.r), typed(s.surfaceColor.g), typed(s.surfaceColor.b), typed(s.surfaceColor.a)});
      }));
  f.push_back(choice<SurfaceNormals>(
      {.name = "surface_normals", .help = "surface shading: the volume's gradient at each vertex (smooth, default) or each polygon's own plane"},
      {{"gradient", SurfaceNormals::Gradient}, {"facet", SurfaceNormals::Facet}}, [](FrameSettings& s) -> auto& { return s.surfaceNormals; }));
  f.push_back(onOff({.name = "shading", .help = "gradient shading of the volume (default on)"}, &FrameSettings::shading));
  f.push_back(numbers(
      {.name = "cut", .count = 6, .lo = -kMaxCameraMm, .hi = kMaxCameraMm, .unit = "mm", .shape = "px,py,pz,nx,ny,nz",
       .help = "cutting plane px,py,pz,nx,ny,nz (a point and a normal): removes the eye's side, shows the data on it", .optional = true},
      [](FrameSettings& s, const std::optional<std::vector<double>>& v) {
        s.cut = v ? std::optional(CutPlane{glm::dvec3((*v)[0], (*v)[1], (*v)[2]), glm::dvec3((*v)[3], (*v)[4], (*v)[5])}) : std::nullopt;
      },
      [](const FrameSettings& s) {
        if (!s.cut) return std::optional<std::vector<double>>();
        const CutPlane& c = *s.cut;
        return std::optional(std::vector<double>{c.point.x, c.point.y, c.point.z, c.normal.x, c.normal.y, c.normal.z});
      },
      [](const std::vector<double>& v) { return nonZero({v[3], v[4], v[5]}).empty() ? "" : "a non-zero normal"; }));
  f.push_back(onOff({.name = "cut_line", .help = "draw the isosurface's intersection with the cutting plane (default on)"}, &FrameSettings::cutLine));
  f.push_back(numbers(
      {.name = "voi", .count = 6, .lo = -kMaxCameraMm, .hi = kMaxCameraMm, .unit = "mm", .shape = "x0,y0,z0,x1,y1,z1",
       .help = "volume of interest x0,y0,z0,x1,y1,z1 (its box's corners): opacity scaled inside and outside (Levoy)", .optional = true},
      [](FrameSettings& s, const std::optional<std::vector<double>>& v) {
        s.voi = v ? std::optional(std::array<double, 6>{(*v)[0], (*v)[1], (*v)[2], (*v)[3], (*v)[4], (*v)[5]}) : std::nullopt;
      },
      [](const FrameSettings& s) { return s.voi ? std::optional(std::vector<double>(s.voi->begin(), s.voi->end())) : std::nullopt; },
      [](const std::vector<double>& v) { return v[0] < v[3] && v[1] < v[4] && v[2] < v[5] ? "" : "x0 < x1, y0 < y1, z0 < z1"; }));
  f.push_back(number({.name = "voi_inside", .lo = 0.0, .hi = 100.0, .help = "opacity factor inside the volume of interest"},
                     [](FrameSettings& s) -> auto& { return s.voiInside; }));
  f.push_back(number({.name = "voi_outside", .lo = 0.0, .hi = 100.0, .help = "opacity factor outside the volume of interest"},
                     [](FrameSettings& s) -> auto& { return s.voiOutside; }));
  f.push_back(number({.name = "voi_ramp", .lo = 0.0, .hi = kMaxCameraMm, .unit = "mm", .help = "width of the smooth transition across the box's surface"},
                     [](FrameSettings& s) -> auto& { return s.voiRamp; }));
  f.push_back(numbers(
      {.name = "background", .count = 3, .lo = 0.0, .hi = 1.0, .shape = "r,g,b", .help = "background r,g,b (default 0,0,0)", .doors = kCliPy},
      [](FrameSettings& s, const std::optional<std::vector<double>>& v) { s.background = glm::vec3(float((*v)[0]), float((*v)[1]), float((*v)[2])); },
      [](const FrameSettings& s) { return std::optional(std::vector<double>{typed(s.background.r), typed(s.background.g), typed(s.background.b)}); }));
  // The viewer reads a mesh's path in its data directory (the server resolves it there).
  FrameField mesh = word(
      {.name = "mesh", .kind = FieldKind::Text,
       .help = "a mesh drawn inside the volume, FILE[:r,g,b,a] (.ply .obj .stl .off, patient mm; a < 1 translucent; default colour 0.4,0.7,1,0.5); "
               "the flag may be repeated, or files separated by ';'",
       .optional = true, .repeatable = true},
      [](FrameSettings& s, const std::optional<std::string>& w) {
        s.meshes.clear();
        if (w) meshFilesIn(*w, &s.meshes);
      },
      [](const FrameSettings& s) { return s.meshes.empty() ? std::nullopt : std::optional(meshFilesText(s.meshes)); });
  mesh.checkText = [](const std::string& text) { return meshFilesIn(text, nullptr); };
  f.push_back(mesh);
  FrameField primitive = word(
      {.name = "primitive", .kind = FieldKind::Text, .unit = "mm",
       .shape = "plane:PX,PY,PZ,NX,NY,NZ[,THICK][:r,g,b,a], sphere:CX,CY,CZ,R[:r,g,b,a] or polygon:X1,Y1,Z1,X2,Y2,Z2,X3,Y3,Z3,...[:r,g,b,a] (patient mm, LPS)",
       .help = "an analytic primitive drawn inside the volume (Levoy): plane:PX,PY,PZ,NX,NY,NZ[,THICK] (a point and a normal; THICK mm when "
               "scan-converted, default one voxel), sphere:CX,CY,CZ,R, polygon:X1,Y1,Z1,X2,Y2,Z2,X3,Y3,Z3,... (its corners, convex), each "
               "[:r,g,b,a] (default 0.4,0.7,1,0.5), patient mm (LPS); the flag may be repeated, or items separated by ';'",
       .optional = true, .repeatable = true},
      [](FrameSettings& s, const std::optional<std::string>& w) {
        s.primitives.clear();
        if (w) primitivesIn(*w, &s.primitives);
      },
      [](const FrameSettings& s) {
        std::string t;
        for (const std::string& item : s.primitives) t += (t.empty() ? "" : ";") + item;
        return s.primitives.empty() ? std::nullopt : std::optional(t);
      });
  primitive.checkText = [](const std::string& text) { return primitivesIn(text, nullptr); };
  f.push_back(primitive);
  f.push_back(choice<MeshMethod>({.name = "mesh_method",
                                  .help = "how meshes and primitives are drawn: polygons (default; exact, in the SlabPolygon lists and crossed by the "
                                          "reference's rays) or scan-convert (Levoy: filtered and scan-converted into a coverage channel on the "
                                          "volume's grid, composited with the data's samples)"},
                                 {{"polygons", MeshMethod::Polygons}, {"scan-convert", MeshMethod::ScanConvert}},
                                 [](FrameSettings& s) -> auto& { return s.meshMethod; }));
  f.push_back(choice<double>({.name = "mesh_filter",
                              .help = "scan-convert's kernel: box (default; each voxel the fraction of its cell covered), box1.5 or box2 (a box "
                                      "of 1.5 or 2 cells: softer, less aliased), or none (the voxel centre point-sampled: binary, shimmers as "
                                      "the geometry moves)"},
                             {{"box", 1.0}, {"box1.5", 1.5}, {"box2", 2.0}, {"none", 0.0}}, [](FrameSettings& s) -> auto& { return s.meshFilter; }));
  f.push_back(choice<MeshSpace>({.name = "mesh_space", .help = "the space of mesh files whose header does not name one (3D Slicer writes SPACE=RAS or SPACE=LPS): lps (default) or ras"},
                                {{"lps", MeshSpace::LPS}, {"ras", MeshSpace::RAS}}, [](FrameSettings& s) -> auto& { return s.meshSpace; }));
}

// How well: the renderer and its quality knobs (the viewer's scheduler sets its own).
void addQualityFields(std::vector<FrameField>& f) {
  f.push_back(choice<Renderer>({.name = "renderer", .help = "the slice renderer (default) or the reference ray tracer", .doors = kCliPy},
                               {{"slices", Renderer::Slices}, {"raycast", Renderer::Raycast}}, [](FrameSettings& s) -> auto& { return s.quality.renderer; }));
  f.push_back(number({.name = "epsilon", .lo = 0.0, .hi = kFloatMax, .unit = "data units",
                      .help = "user error epsilon_u: the largest nodal error of a brick drawn (0 = exact)", .doors = kCliPy},
                     [](FrameSettings& s) -> auto& { return s.quality.epsilon; }));
  f.push_back(textField({.name = "budget", .kind = FieldKind::Budget,
                    .help = "texture memory budget in MB, blend textures included (0 = unlimited), or P% of this view's full-resolution bytes",
                    .doors = kCliPy},
                   &FrameSettings::budget));
  f.push_back(number({.name = "step", .lo = 0.01, .hi = 4.0, .loOpen = true, .unit = "voxels",
                      .help = "slice / sample spacing (default 0.5 for slices, 0.25 for raycast)", .doors = kCliPy},
                     [](FrameSettings& s) -> auto& { return s.quality.step; }));
  f.push_back(choice<Proxy>({.name = "proxy", .help = "slice geometry: view-aligned planes (default) or spherical shells around the eye (perspective)", .doors = kCliPy},
                            {{"planes", Proxy::Planes}, {"shells", Proxy::Shells}}, [](FrameSettings& s) -> auto& { return s.quality.proxy; }));
  f.push_back(word({.name = "blend", .kind = FieldKind::Switch, .help = "blend bricks towards coarser neighbours, Carmona et al. (default on)",
                    .choices = {"on", "off"}, .doors = kCliPy},
                   [](FrameSettings& s, const std::optional<std::string>& w) { s.quality.blend = *w == "on"; },
                   [](const FrameSettings& s) { return std::optional<std::string>(s.quality.blend ? "on" : "off"); }));
  f.push_back(choice<Classification>(
      {.name = "classification",
       .help = "post-classified samples (default) or segments pre-integrated between their ends' values (finds narrow transfer-function features "
               "between samples; two brick reads a fragment)"},
      {{"post", Classification::Post}, {"preintegrated", Classification::PreIntegrated}}, [](FrameSettings& s) -> auto& { return s.quality.classification; }));
  f.push_back(number({.name = "image_scale", .lo = 0.0, .hi = 1.0, .loOpen = true,
                      .help = "render at this fraction of the size and magnify bilinearly (as VTK's image sample distance 1/S); 1 renders every pixel",
                      .doors = kCliPy},
                     [](FrameSettings& s) -> auto& { return s.quality.imageScale; }));
  f.push_back(number({.name = "lod_pixels", .lo = 0.0, .hi = 1e6, .unit = "pixels",
                      .help = "stop refining where texels are at most this many pixels apart on screen, and draw the surface with its vertices clustered by "
                              "the largest cubes no wider (0 = off: full resolution)",
                      .doors = kCliPy},
                     [](FrameSettings& s) -> auto& { return s.quality.lodPixels; }));
  FrameField brick = number({.name = "max_brick", .kind = FieldKind::Integer, .lo = 1, .hi = 256, .unit = "texels", .help = "brick edge (a power of two)",
                             .doors = kCliPy},
                            [](FrameSettings& s) -> auto& { return s.quality.maxBrickEdge; });
  brick.check = [](const std::vector<double>& v) { return (int(v[0]) & (int(v[0]) - 1)) == 0 ? "" : "a power of two"; };
  f.push_back(brick);
  f.push_back(choice<TexelBits>({.name = "texel_bits",
                                 .help = "brick precision: value and gradient in 8 bits (default, fastest) or 16 (twice the memory, slower frames; for transfer "
                                         "functions narrow against a brick's values, e.g. soft tissue)",
                                 .doors = kCliPy},
                                {{"8", TexelBits::Eight}, {"16", TexelBits::Sixteen}}, [](FrameSettings& s) -> auto& { return s.quality.texelBits; }));
  f.push_back(point({.name = "focus", .help = "region of interest x,y,z: bricks away from it may be coarser", .doors = kCliPy},
                    [](FrameSettings& s) -> auto& { return s.quality.focus; }));
  f.push_back(number({.name = "progressive", .kind = FieldKind::Integer, .lo = 1, .hi = 8, .unit = "images",
                      .help = "write N images coarse to fine (out_1.png ... out_N.png, and out.png): slices one level coarser each, the reference's "
                              "rays on a grid 2^(N-k) pixels apart, refined where colours differ (Levoy's progressive refinement)",
                      .doors = kCommandLine},
                     [](FrameSettings& s) -> auto& { return s.quality.progressive; }));
  f.push_back(number({.name = "adaptive", .lo = 0.0, .hi = 255.0, .unit = "1/255",
                      .help = "reference only: Levoy's adaptive refinement, rays 8 pixels apart first and more only where neighbouring colours differ by "
                              "more than this, the rest interpolated (0 = every pixel, exact)",
                      .doors = kCommandLine},
                     [](FrameSettings& s) -> auto& { return s.quality.adaptive; }));
}

std::vector<FrameField> makeFields() {
  std::vector<FrameField> f;
  addCameraFields(f);
  addLookFields(f);
  addQualityFields(f);
  return f;
}

}  // namespace

void FrameField::parse(FrameSettings& s, const std::string& text, const std::string& as) const {
  const auto refuse = [&](const std::string& why) {
    HYB_THROW(ValueError, as, " ", quotedExcerpt(text, 80), " invalid (expected ", expected(), why.empty() ? "" : "; " + why, ")");
  };
  if (text.empty() && optional) {
    if (setNumbers) setNumbers(s, std::nullopt);
    else setWord(s, std::nullopt);
    return;
  }
  switch (kind) {
    case FieldKind::Number:
    case FieldKind::Integer:
    case FieldKind::Numbers:
    case FieldKind::Size: {
      std::string t = text;
      if (kind == FieldKind::Size) std::replace(t.begin(), t.end(), 'X', 'x');  // 512X512 as well
      const std::optional<std::vector<double>> v = numbersIn(t, kind == FieldKind::Size ? 'x' : ',');
      if (!v || int(v->size()) != count) refuse("");
      for (const double x : *v) {
        const bool whole = kind == FieldKind::Integer || kind == FieldKind::Size;
        if ((loOpen ? !(x > lo) : !(x >= lo)) || (hiOpen ? !(x < hi) : !(x <= hi)) || (whole && x != std::floor(x))) refuse("");
      }
      if (check)
        if (const std::string why = check(*v); !why.empty()) refuse(why);
      setNumbers(s, v);
      return;
    }
    case FieldKind::Switch:
    case FieldKind::Flag: {
      const bool flag = kind == FieldKind::Flag;
      if (text == "on" || (flag && text == "true")) return setWord(s, "on");
      if (text == "off" || (flag && text == "false")) return setWord(s, "off");
      refuse("");
      return;
    }
    case FieldKind::Choice:
      if (std::find(choices.begin(), choices.end(), text) == choices.end()) refuse("");
      return setWord(s, text);
    case FieldKind::Text:
      if (text.find('\0') != std::string::npos || text.size() > 4096) refuse("");
      if (checkText)
        if (const std::string why = checkText(text); !why.empty()) refuse(why);
      return setWord(s, text);
    case FieldKind::Budget:
      if (const std::string why = budgetError(text); !why.empty()) refuse(why);
      return setWord(s, text);
    case FieldKind::Points:
      if (!pointsIn(text)) refuse("");
      return setWord(s, text);
  }
}

std::string FrameField::flag() const {
  std::string f = "--" + name;
  std::replace(f.begin(), f.end(), '_', '-');
  return f;
}

std::string FrameField::expected() const {
  const auto number = [](double x) {  // whole numbers as they are, the rest to three digits
    char t[32];
    std::snprintf(t, sizeof t, x == std::floor(x) && std::abs(x) < 1e5 ? "%.0f" : "%.3g", x);
    return std::string(t);
  };
  const auto range = [&] {
    return std::string(loOpen ? "(" : "[") + number(lo) + ", " + number(hi) + (hiOpen ? ")" : "]") + (unit.empty() ? "" : " " + unit);
  };
  switch (kind) {
    case FieldKind::Number: return "a number in " + range();
    case FieldKind::Integer: return "a whole number in " + range();
    case FieldKind::Numbers: return shape + ": " + std::to_string(count) + " numbers, each in " + range();
    case FieldKind::Size: return "WxH, each a whole number in " + range();
    case FieldKind::Switch: return "on or off";
    case FieldKind::Flag: return "true or false";
    case FieldKind::Choice: {
      std::string c;
      for (size_t i = 0; i < choices.size(); ++i) c += (i == 0 ? "" : i + 1 == choices.size() ? " or " : ", ") + choices[i];
      return c;
    }
    case FieldKind::Text: return shape.empty() ? "a path" : shape;
    case FieldKind::Budget: return "megabytes >= 0, or a percentage of the full-resolution texture bytes: 0 < P <= 100 followed by %";
    case FieldKind::Points: return "1 to 256 points value,r,g,b,a separated by ';', colours and opacities in [0, 1], values increasing";
  }
  return "";
}

std::optional<std::string> FrameField::defaultText() const { return get(FrameSettings{}); }

const std::vector<FrameField>& frameFields() {
  static const std::vector<FrameField> kFields = makeFields();
  return kFields;
}

const FrameField* frameField(std::string_view name) {
  for (const FrameField& f : frameFields())
    if (f.name == name) return &f;
  return nullptr;
}

std::string primitiveIn(const std::string& item, UserPrimitive* p, glm::vec4* color) {
  const size_t colon = item.find(':');
  const std::string kind = item.substr(0, colon);
  if (colon == std::string::npos) return "a kind (plane, sphere or polygon) and its numbers after ':'";
  std::string numbers = item.substr(colon + 1);
  *color = UserMesh{}.color;
  if (const size_t second = numbers.find(':'); second != std::string::npos) {
    const std::optional<std::vector<double>> c = numbersIn(numbers.substr(second + 1));
    if (!c || c->size() != 4 || std::any_of(c->begin(), c->end(), [](double x) { return !(x >= 0.0 && x <= 1.0); }))
      return "the colour after the second ':' is r,g,b,a, each in [0, 1]";
    *color = glm::vec4(float((*c)[0]), float((*c)[1]), float((*c)[2]), float((*c)[3]));
    numbers.resize(second);
  }
  const std::optional<std::vector<double>> v = numbersIn(numbers);
  if (!v) return "finite numbers separated by ','";
  for (const double x : *v)
    if (std::abs(x) > kMaxCameraMm) return "coordinates within " + exact(kMaxCameraMm) + " mm";
  const auto at = [&](size_t i) { return glm::dvec3((*v)[i], (*v)[i + 1], (*v)[i + 2]); };
  *p = UserPrimitive{};
  if (kind == "plane") {
    if (v->size() != 6 && v->size() != 7) return "a plane is PX,PY,PZ,NX,NY,NZ[,THICK]";
    p->kind = UserPrimitive::Kind::Plane;
    p->points = {at(0)};
    p->normal = at(3);
    if (p->normal == glm::dvec3(0.0)) return "a plane's normal is not zero";
    if (v->size() == 7 && !((*v)[6] > 0.0)) return "a plane's thickness > 0 mm";
    if (v->size() == 7) p->thickness = (*v)[6];
    return "";
  }
  if (kind == "sphere") {
    if (v->size() != 4) return "a sphere is CX,CY,CZ,R";
    p->kind = UserPrimitive::Kind::Sphere;
    p->points = {at(0)};
    p->radius = (*v)[3];
    return p->radius > 0.0 ? "" : "a sphere's radius > 0 mm";
  }
  if (kind == "polygon") {
    if (v->size() % 3 != 0 || v->size() < 9) return "a polygon is at least 3 corners X,Y,Z";
    p->kind = UserPrimitive::Kind::Polygon;
    for (size_t i = 0; i < v->size(); i += 3) p->points.push_back(at(i));
    // Newell's normal: the corners enclose an area, lie in its plane and turn one way (convex).
    glm::dvec3 normal(0.0), centre(0.0);
    double size = 0.0;
    const size_t n = p->points.size();
    for (size_t i = 0; i < n; ++i) {
      const glm::dvec3 &a = p->points[i], &b = p->points[(i + 1) % n];
      normal += glm::dvec3((a.y - b.y) * (a.z + b.z), (a.z - b.z) * (a.x + b.x), (a.x - b.x) * (a.y + b.y));
      centre += a / double(n);
      size = std::max(size, glm::length(b - a));
    }
    if (!(glm::length(normal) > 1e-12 * size * size)) return "a polygon's corners enclose an area";
    normal = glm::normalize(normal);
    for (size_t i = 0; i < n; ++i) {
      if (std::abs(glm::dot(normal, p->points[i] - centre)) > 1e-6 * size) return "a polygon's corners in one plane";
      if (i >= 2 && glm::dot(glm::cross(p->points[i - 1] - p->points[0], p->points[i] - p->points[0]), normal) < 0.0) return "a convex polygon";
    }
    return "";
  }
  return "a kind: plane, sphere or polygon";
}

std::string FrameSettings::validate() const {
  if (int(!tf.empty()) + int(!preset.empty()) + int(!tfPoints.empty()) > 1) return "--tf and --preset are exclusive";
  if (!cameraFile.empty() && (eye || orbit || view)) return "--camera-file sets the whole camera (it excludes --eye, --orbit and --view)";
  if ((center || up) && !eye) return "--center and --up need --eye (without it the view frames what is visible)";
  if (view && (eye || orbit)) return "--view excludes --eye and --orbit (each sets the camera's direction)";
  if (orbit && eye) return "--orbit excludes --eye (each sets the camera's direction)";
  if (eye && center && glm::length(*eye - *center) == 0) return "--eye and --center must differ (the view direction runs from the eye to the center)";
  if (eye && center && glm::length(glm::cross(*center - *eye, up.value_or(glm::dvec3(0, 0, 1)))) == 0)
    return "--up must be non-zero and not parallel to the view direction (--eye to --center)";
  return quality.validate();
}

// ---------------------------------------------------------------------------------------------
// JSON, the command line and the camera.

json fieldJson(const FrameField& f, const std::string& text) {
  switch (f.kind) {
    case FieldKind::Number: return numbersIn(text)->front();
    case FieldKind::Integer: return int64_t(numbersIn(text)->front());
    case FieldKind::Numbers: return *numbersIn(text);
    case FieldKind::Size: {
      const std::vector<double> v = *numbersIn(text, 'x');
      return json::array({int64_t(v[0]), int64_t(v[1])});
    }
    case FieldKind::Switch:
    case FieldKind::Flag: return text == "on";
    case FieldKind::Choice:
    case FieldKind::Text: return text;
    case FieldKind::Budget: return text.ends_with('%') ? json(text) : json(numbersIn(text)->front());
    case FieldKind::Points: {
      json a = json::array();
      const std::optional<std::vector<TransferFunction::Point>> points = pointsIn(text);
      for (const TransferFunction::Point& p : *points) a.push_back({p.value, p.color.r, p.color.g, p.color.b, p.alpha});
      return a;
    }
  }
  return nullptr;
}

namespace {

// The text of JSON value @p v for field @p f, or none when it is of the wrong JSON type.
std::optional<std::string> textOf(const FrameField& f, const json& v) {
  if (v.is_null()) return std::string();
  auto numbersOf = [&](const json& a, char separator) -> std::optional<std::string> {
    if (!a.is_array()) return std::nullopt;
    std::string s;
    for (const json& x : a) {
      if (!x.is_number()) return std::nullopt;
      s += (s.empty() ? "" : std::string(1, separator)) + exact(x.get<double>());
    }
    return s;
  };
  switch (f.kind) {
    case FieldKind::Number:
    case FieldKind::Integer: return v.is_number() ? std::optional(exact(v.get<double>())) : std::nullopt;
    case FieldKind::Numbers: return numbersOf(v, ',');
    case FieldKind::Size: return numbersOf(v, 'x');
    case FieldKind::Switch:
    case FieldKind::Flag: return v.is_boolean() ? std::optional<std::string>(v.get<bool>() ? "on" : "off") : std::nullopt;
    case FieldKind::Choice:
    case FieldKind::Text: return v.is_string() ? std::optional(v.get<std::string>()) : std::nullopt;
    case FieldKind::Budget:
      return v.is_number() ? std::optional(exact(v.get<double>())) : v.is_string() ? std::optional(v.get<std::string>()) : std::nullopt;
    case FieldKind::Points: {
      if (!v.is_array()) return std::nullopt;
      std::string s;
      for (const json& p : v) {
        const std::optional<std::string> one = numbersOf(p, ',');
        if (!one) return std::nullopt;
        s += (s.empty() ? "" : ";") + *one;
      }
      return s;
    }
  }
  return std::nullopt;
}

const char* jsonType(const FrameField& f) {
  switch (f.kind) {
    case FieldKind::Number:
    case FieldKind::Integer: return "a number";
    case FieldKind::Numbers: return "an array of numbers";
    case FieldKind::Size: return "an array [width, height]";
    case FieldKind::Switch:
    case FieldKind::Flag: return "true or false";
    case FieldKind::Choice:
    case FieldKind::Text: return "a string";
    case FieldKind::Budget: return "a number or a string \"P%\"";
    case FieldKind::Points: return "an array of [value, r, g, b, a]";
  }
  return "";
}

}  // namespace

void applyJson(FrameSettings* settings, const json& object, unsigned door, const std::vector<std::string>& skip, const std::string& where) {
  if (!object.is_object()) HYB_THROW(ValueError, where, "expected a JSON object");
  for (const auto& [key, value] : object.items()) {
    if (std::find(skip.begin(), skip.end(), key) != skip.end()) continue;
    const FrameField* f = frameField(key);
    const std::string as = where + "field " + quotedExcerpt(key, 40);
    if (!f || !(f->doors & door)) HYB_THROW(ValueError, as, ": no such field");
    const std::optional<std::string> text = textOf(*f, value);
    if (!text) HYB_THROW(ValueError, as, ": expected ", jsonType(*f), " (", f->expected(), ")");
    if (text->empty() && !f->optional) HYB_THROW(ValueError, as, ": expected ", f->expected(), " (it cannot be unset)");
    f->parse(*settings, *text, as);
  }
}

json settingsJson(const FrameSettings& settings, unsigned door, const std::function<bool(const FrameField&)>& keep) {
  json j = json::object();
  for (const FrameField& f : frameFields()) {
    if (!(f.doors & door) || (keep && !keep(f))) continue;
    if (const std::optional<std::string> t = f.text(settings)) j[f.name] = fieldJson(f, *t);
  }
  return j;
}

json fieldsJson(unsigned door) {
  json a = json::array();
  for (const FrameField& f : frameFields()) {
    if (!(f.doors & door)) continue;
    static const char* kKinds[] = {"number", "integer", "numbers", "size", "switch", "flag", "choice", "text", "budget", "points"};
    json row = {{"name", f.name}, {"kind", kKinds[int(f.kind)]}, {"unit", f.unit}, {"help", f.help}};
    if (f.kind == FieldKind::Number || f.kind == FieldKind::Integer || f.kind == FieldKind::Numbers || f.kind == FieldKind::Size)
      row.update({{"count", f.count}, {"min", f.lo}, {"max", f.hi}, {"min_open", f.loOpen}, {"max_open", f.hiOpen}});
    if (!f.choices.empty()) row["choices"] = f.choices;
    const std::optional<std::string> d = f.defaultText();
    row["default"] = d ? fieldJson(f, *d) : json(nullptr);
    a.push_back(row);
  }
  return a;
}

std::string shellQuote(const std::string& s) {
  if (!s.empty() && s.find_first_not_of("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789-_./,:=%+") == std::string::npos) return s;
  std::string out = "'";
  for (char c : s) out += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return out + "'";
}

std::string commandLineOf(const FrameSettings& settings) {
  std::string out;
  for (const FrameField& f : frameFields()) {
    if (!(f.doors & kCommandLine)) continue;
    const std::optional<std::string> t = f.text(settings);
    if (!t || t == f.defaultText()) continue;
    out += ' ';
    out += f.flag();
    if (f.kind == FieldKind::Flag) continue;
    out += ' ';
    out += shellQuote(*t);
  }
  return out;
}

namespace {
const char* const kCameraFields[] = {"eye", "center", "up", "fov", "ortho", "ortho_height", "size"};
}

bool isCameraField(const FrameField& f) {
  return std::find(std::begin(kCameraFields), std::end(kCameraFields), f.name) != std::end(kCameraFields);
}

FrameSettings cameraSettings(const Camera& c) {
  FrameSettings s;
  s.eye = c.eye;
  s.center = c.center;
  s.up = c.up;
  s.fov = c.fovDeg;
  s.ortho = c.ortho;
  s.orthoHeight = c.orthoHeight;
  s.size = glm::ivec2(c.width, c.height);
  return s;
}

Camera explicitCamera(const FrameSettings& s) {
  if (!s.eye || !s.center) HYB_THROW(ValueError, "a camera needs its eye and center");
  Camera c;
  c.eye = *s.eye;
  c.center = *s.center;
  c.up = s.up.value_or(glm::dvec3(0, 0, 1));
  c.fovDeg = s.fov;
  c.ortho = s.ortho;
  if (s.orthoHeight) c.orthoHeight = *s.orthoHeight;
  const glm::ivec2 size = s.size.value_or(glm::ivec2(512, 512));
  c.width = size.x;
  c.height = size.y;
  return c;
}

std::string cameraJson(const Camera& camera, int indent) {
  nlohmann::ordered_json j;
  j["space"] = "LPS";
  const FrameSettings s = cameraSettings(camera);
  for (const char* name : kCameraFields) {
    const FrameField& f = *frameField(name);
    j[name] = fieldJson(f, *f.text(s));
  }
  return j.dump(indent);
}

Camera readCameraFile(const std::string& path) {
  const std::vector<uint8_t> bytes = readFileBytes(path);
  json j = json::parse(bytes.begin(), bytes.end(), nullptr, false);
  if (j.is_discarded() || !j.is_object()) HYB_THROW(IoError, path, ": not a JSON object (expected a camera written by --stats)");
  if (j.contains("camera")) j = j["camera"];
  if (!j.is_object()) HYB_THROW(IoError, path, ": \"camera\" is not a JSON object");
  if (j.contains("space") && j["space"] != "LPS") HYB_THROW(IoError, path, ": camera space ", j["space"].dump(), " unsupported (expected \"LPS\")");
  // The earlier form: fov_deg, width and height.
  if (j.contains("fov_deg") && !j.contains("fov")) j["fov"] = j["fov_deg"];
  if (j.contains("width") && j.contains("height") && !j.contains("size")) j["size"] = json::array({j["width"], j["height"]});
  json camera = json::object();
  for (const char* name : kCameraFields)
    if (j.contains(name)) camera[name] = j[name];
  FrameSettings s;
  try {
    applyJson(&s, camera, kEveryDoor, {}, "camera ");
  } catch (const ValueError& e) {
    HYB_THROW(IoError, path, ": ", e.what());
  }
  for (const char* name : kCameraFields)
    if (!frameField(name)->text(s)) HYB_THROW(IoError, path, ": camera field '", name, "' missing");
  if (const std::string e = s.validate(); !e.empty()) HYB_THROW(IoError, path, ": camera: ", e);
  return explicitCamera(s);
}

// ---------------------------------------------------------------------------------------------
// The frame a front door renders.

namespace {

// The transfer function the settings name, its opacities scaled.
TransferFunction transferFunctionOf(const FrameSettings& s, const Volume& v) {
  TransferFunction tf = !s.tfPoints.empty() ? TransferFunction(s.tfPoints, "tf_points")
                        : !s.tf.empty()     ? TransferFunction::fromFile(s.tf)
                        : !s.preset.empty() ? TransferFunction::preset(s.preset)
                                            : TransferFunction::defaultFor(v.minValue(), v.maxValue());
  if (s.opacity == 1.0) return tf;
  std::vector<TransferFunction::Point> p = tf.points();
  for (TransferFunction::Point& q : p) q.alpha = std::min(1.0f, q.alpha * float(s.opacity));
  return TransferFunction(std::move(p), "opacity-scaled transfer function");
}

}  // namespace

std::vector<UserMesh> userGeometry(const FrameSettings& s, const Volume& v, std::ostream& warnings) {
  std::vector<UserMesh> meshes;
  for (const FrameSettings::MeshFile& m : s.meshes) {
    meshes.push_back(readUserMesh(m.path, m.color, s.meshSpace));
    for (const std::string& w : userMeshWarnings(meshes.back(), v)) warnings << "hybrid-octree: warning: " << w << "\n";
  }
  for (const std::string& item : s.primitives) {
    auto p = std::make_shared<UserPrimitive>();
    UserMesh m;
    if (const std::string why = primitiveIn(item, p.get(), &m.color); !why.empty())
      HYB_THROW(ValueError, "--primitive ", quotedExcerpt(item, 60), " invalid (", why, ")");
    m.name = "--primitive " + item.substr(0, item.find(':'));
    m.mesh = std::make_shared<TriangleMesh>(tessellatePrimitive(*p, v));
    m.primitive = std::move(p);
    if (m.mesh->triangles.empty()) {
      warnings << "hybrid-octree: warning: " << m.name << " misses the volume's box (nothing drawn)\n";
      continue;
    }
    meshes.push_back(std::move(m));
  }
  if (meshes.size() > size_t(kMaxUserMeshes)) HYB_THROW(ValueError, "--mesh and --primitive: at most ", kMaxUserMeshes, " together");
  return meshes;
}

std::vector<UserMesh> UserGeometryMemo::of(const FrameSettings& s, const Volume& v, std::ostream& warnings) {
  if (s.meshes.empty() && s.primitives.empty()) return {};
  std::ostringstream key;  // (the volume by its object and grid: a scene released and another read may share an address)
  key << &v << ' ' << v.dims().x << ' ' << v.dims().y << ' ' << v.dims().z << ' ' << int(s.meshSpace);
  for (const FrameSettings::MeshFile& m : s.meshes) {
    std::error_code ec;
    const auto changed = std::filesystem::last_write_time(m.path, ec);
    key << '\n' << m.path << ' ' << m.color.r << ',' << m.color.g << ',' << m.color.b << ',' << m.color.a << ' '
        << (ec ? 0 : changed.time_since_epoch().count());
  }
  for (const std::string& item : s.primitives) key << "\n" << item;
  const auto hit = std::find_if(mKept.begin(), mKept.end(), [&](const auto& e) { return e.first == key.str(); });
  if (hit != mKept.end()) {
    std::rotate(hit, hit + 1, mKept.end());
    return mKept.back().second;
  }
  std::vector<UserMesh> made = userGeometry(s, v, warnings);
  if (mKept.size() == kKept) mKept.erase(mKept.begin());
  mKept.emplace_back(key.str(), made);
  return made;
}

FrameSetup setUpFrame(const FrameSettings& s, const Scene& scene, std::ostream& warnings, UserGeometryMemo* memo) {
  if (const std::string e = s.validate(); !e.empty()) throw ValueError(e);
  std::optional<Camera> fromFile;
  if (!s.cameraFile.empty()) fromFile = readCameraFile(s.cameraFile);
  FrameSetup job;
  const Volume& v = scene.volume;
  const PatientFrame& frame = v.frame();
  // What is shown.
  Look& look = job.look;
  look.tf = transferFunctionOf(s, v);
  if (s.iso) {
    look.iso = float(*s.iso);
    if (*s.iso <= v.minValue() || *s.iso > v.maxValue())
      warnings << "hybrid-octree: warning: --iso " << *s.iso << " is outside the data's crossing range (" << v.minValue() << ", " << v.maxValue()
               << "]: the surface is empty\n";
  }
  look.surfaceColor = s.surfaceColor;
  look.normals = s.surfaceNormals;
  look.shading = s.shading;
  look.cut = s.cut;
  look.cutLine = s.cutLine;
  if (s.voi) {
    VolumeOfInterest voi;
    voi.lo = glm::dvec3((*s.voi)[0], (*s.voi)[1], (*s.voi)[2]);
    voi.hi = glm::dvec3((*s.voi)[3], (*s.voi)[4], (*s.voi)[5]);
    voi.inside = s.voiInside;
    voi.outside = s.voiOutside;
    voi.ramp = s.voiRamp;
    look.voi = voi;
  }
  look.meshes = memo ? memo->of(s, v, warnings) : userGeometry(s, v, warnings);
  look.meshMethod = s.meshMethod;
  look.meshFilter = s.meshFilter;
  // Where from, in patient space: a camera file's, the eye given, or the view framing what the
  // transfer function (or the isosurface) makes visible.
  Camera& camera = job.view.camera;
  const glm::ivec2 pixels = s.size.value_or(fromFile ? glm::ivec2(fromFile->width, fromFile->height) : glm::ivec2(512, 512));
  if (fromFile) {
    camera = *fromFile;
  } else if (s.eye) {
    FrameSettings explicitOne = s;
    if (!explicitOne.center) explicitOne.center = frame.toPatient(0.5 * v.extentMm());
    camera = explicitCamera(explicitOne);
    if (!s.orthoHeight) camera.orthoHeight = glm::length(v.extentMm()) * 1.05;
  } else {
    const ViewDirection direction = s.orbit ? orbitDirection(s.orbit->x, s.orbit->y) : viewDirection(s.view.value_or(AnatomicalView::Anterior));
    std::vector<glm::dvec3> points = visiblePoints(v, scene.octree, look.tf, look.iso, scene.knots.get());
    if (points.empty())  // nothing visible: the data's box
      for (int c = 0; c < 8; ++c) points.push_back(frame.toPatient(glm::dvec3(c & 1, (c >> 1) & 1, (c >> 2) & 1) * v.extentMm()));
    camera = fitCamera(points, direction, {s.fov, s.ortho, pixels.x, pixels.y});
    if (s.orthoHeight) camera.orthoHeight = *s.orthoHeight;
    scene.octree.releasePages();  // the fit walked every visible leaf; the frame reads far fewer
  }
  camera.width = pixels.x;
  camera.height = pixels.y;
  if (s.zoom != 1.0) zoomCamera(&camera, s.zoom);
  if (!camera.ortho && !(camera.fovDeg >= kMinFovDeg && camera.fovDeg < kMaxFovDeg))
    HYB_THROW(ValueError, "--zoom ", s.zoom, " makes a field of view of ", camera.fovDeg, " degrees (expected a zoom keeping it in [0.1, 179))");
  job.quality = s.quality;
  if (!s.budget.empty()) {
    const Budget b = *budgetIn(s.budget);  // (checked when it was set)
    (b.percent ? job.quality.budgetPercent : job.quality.budgetMb) = b.value;
  }
  job.background = s.background;
  return job;
}

std::string FrameReport::json() const {
  const bool slices = quality.renderer == Renderer::Slices;
  const FrameStats& st = frame.stats;
  const Selection& sel = frame.selection;
  nlohmann::ordered_json j;
  j["renderer"] = slices ? "slices" : "raycast";
  j["nodes_selected"] = sel.bricks.size();
  j["nodes_hidden"] = std::count_if(sel.bricks.begin(), sel.bricks.end(), [](const Brick& b) { return b.hidden; });
  j["textured_bricks"] = st.slices.bricks;
  j["texels"] = sel.texels;
  j["blended_bricks"] = sel.blendedBricks;
  j["texture_bytes"] = slices ? st.slices.textureBytes : sel.texels * bytesPerTexel(quality.texelBits);
  j["slices"] = st.slices.slices;
  j["surface_polygons"] = st.surfacePolygons;
  j["surface_triangles"] = st.surfaceTriangles;
  j["surface_spacing"] = st.surfaceSpacing;
  j["slab_polygon_draws"] = st.slices.slabPolygonDraws;
  j["unseen_triangles"] = st.slices.unseenTriangles;
  j["fragments"] = st.slices.fragments;
  j["shell_bricks"] = st.slices.shellBricks;
  j["cut_polygons"] = st.slices.cutPolygons;
  j["cut_line_segments"] = st.slices.cutLineSegments;
  j["select_ms"] = st.selectMs;
  j["render_ms"] = renderMs;
  j["classification"] = quality.classification == Classification::PreIntegrated ? "preintegrated" : "post";
  j["preintegration_ms"] = preintegrationMs;
  if (st.geometryBytes > 0) {  // a scan-converted channel (its node maxima alone are never empty)
    j["geometry_ms"] = geometryMs;
    j["geometry_bytes"] = st.geometryBytes;
  }
  j["samples"] = st.rays.samples;
  j["rays"] = st.rays.rays;
  j["epsilon"] = quality.epsilon;
  j["max_nodal_error_used"] = sel.maxError;
  j["budget_met"] = sel.budgetMet;
  if (store) {
    const StoreCacheStats c = store->cacheStats();
    j["store"] = {{"blocks_read", c.misses}, {"bytes_read", c.bytesRead}, {"cache_hits", c.hits}, {"cache_bytes", c.bytesHeld},
                  {"cache_limit", c.limit}, {"evicted", c.evicted}};
  }
  j["camera"] = nlohmann::ordered_json::parse(cameraJson(camera));
  return j.dump(2);
}

}  // namespace hyb
