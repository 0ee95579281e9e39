// The one vocabulary of a frame: every setting a user gives (the camera, what a frame shows, how
// well it is made) described once, in one table of fields (name, type, range, default, unit,
// help), from which every front door derives: the command line's flags and their help, the
// viewer's JSON requests and camera, the --stats and --camera-file camera, Python's keywords,
// the viewer's command-line echo and the page's controls' ranges (docs/architecture.md). A new
// look field is one row here and its use in the renderer. As pbrt-v4's ParameterDictionary and
// Neuroglancer's TrackableValue keep a parameter's validation, text and default together, a
// field here parses and writes its own text, and whatever a front door is given that no field
// takes is refused by name.
#pragma once

#include <glm/glm.hpp>
#include <nlohmann/json_fwd.hpp>

#include <array>
#include <functional>
#include <iosfwd>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "render/frame_request.h"
#include "render/patient_view.h"
#include "render/user_meshes.h"

namespace hyb {

struct RenderedFrame;
class KnotStore;

struct Scene;

/// What a user sets of a frame, by any front door, in patient space (LPS mm).
struct FrameSettings {
  // Where from: an explicit camera (eye, center, up), an anatomical view or an orbit from the
  // anterior view (then the view frames what is visible), or a camera file.
  std::optional<glm::dvec3> eye, center, up;  ///< up: none is 0,0,1 (superior)
  std::optional<AnatomicalView> view;
  std::optional<glm::dvec2> orbit;  ///< azimuth, elevation (degrees)
  double zoom = 1.0;
  double fov = 30.0;                ///< vertical, degrees
  bool ortho = false;
  std::optional<double> orthoHeight;  ///< mm the orthographic view spans vertically; none: the framing's
  std::optional<glm::ivec2> size;     ///< none: 512x512, or the camera file's
  std::string cameraFile;
  bool marker = false;
  // What it shows.
  std::string tf, preset;                          ///< a transfer-function file, or a preset's name
  std::vector<TransferFunction::Point> tfPoints;   ///< control points given directly (the viewer's editor, Python)
  double opacity = 1.0;                            ///< multiplies every opacity
  std::optional<double> iso;
  glm::vec4 surfaceColor = kDefaultSurfaceColor;
  SurfaceNormals surfaceNormals = SurfaceNormals::Gradient;
  bool shading = true, cutLine = true;
  std::optional<CutPlane> cut;
  std::optional<std::array<double, 6>> voi;  ///< x0,y0,z0,x1,y1,z1
  double voiInside = 1.0, voiOutside = 0.1, voiRamp = 4.0;
  glm::vec3 background{0.0f};
  /// A mesh file drawn inside the volume, with its colour.
  struct MeshFile {
    std::string path;
    glm::vec4 color = UserMesh{}.color;
  };
  std::vector<MeshFile> meshes;
  MeshSpace meshSpace = MeshSpace::LPS;  ///< of mesh files whose header does not say (Slicer's SPACE=)
  /// Levoy's analytic primitives as given ("plane:...", "sphere:...", "polygon:..."; checked when set).
  std::vector<std::string> primitives;
  MeshMethod meshMethod = MeshMethod::Polygons;
  double meshFilter = 1.0;  ///< scan-convert: the box filter's side in voxel cells, 0 point sampling (Look::meshFilter)
  // How well.
  Quality quality;
  std::string budget;  ///< as given: megabytes, or P% of the view's full-resolution bytes

  /// What the fields say together: empty when consistent, else a message naming the flags.
  std::string validate() const;
};

/// How a field's value is written as text (the command line's form, which every front door reads).
enum class FieldKind {
  Number,   ///< a number: "1.5"; JSON a number
  Integer,  ///< a whole number
  Numbers,  ///< FrameField::count numbers, comma-separated: "1,2,3"; JSON an array
  Size,     ///< "WxH"; JSON [w, h]
  Switch,   ///< "on" or "off"; JSON true or false
  Flag,     ///< present or not (a flag without a value on the command line); JSON true or false
  Choice,   ///< one of FrameField::choices
  Text,     ///< a path or a word
  Budget,   ///< megabytes, or "P%" of the view's full-resolution bytes; JSON a number or "P%"
  Points,   ///< control points "value,r,g,b,a;..."; JSON [[value, r, g, b, a], ...]
};

/// The front doors a field is given through.
enum FieldDoor : unsigned { kCommandLine = 1, kViewer = 2, kPython = 4, kEveryDoor = 7 };

/// One setting of a frame.
struct FrameField {
  std::string name{};  ///< snake_case: the JSON key and the Python keyword; the flag is --name-with-dashes
  FieldKind kind = FieldKind::Number;
  int count = 1;                 ///< numbers of a Numbers field (2 for a Size)
  double lo = 0.0, hi = 0.0;     ///< each number's range (Number, Integer, Numbers, Size)
  bool loOpen = false, hiOpen = false;
  std::string unit{};            ///< "mm", "degrees", "data units"... or empty
  std::string shape{};           ///< how a Numbers field's numbers are written: "x,y,z", "r,g,b,a"
  std::string help{};
  std::vector<std::string> choices{};  ///< a Choice's words
  unsigned doors = kEveryDoor;
  bool optional = false;         ///< unset by default; an empty text (JSON null) unsets it
  bool repeatable = false;       ///< the flag may be given several times, its values joined by a newline

  /// Sets the field from its @p text (the command line's form); @p as names the field where the
  /// text came from (the flag, a JSON field, a keyword).
  /// @throw ValueError "<as> '<text>' invalid (expected <expected()>[; why])".
  void parse(FrameSettings& settings, const std::string& text, const std::string& as) const;
  /// The field's text, or none when it is not set.
  std::optional<std::string> text(const FrameSettings& settings) const { return get(settings); }
  /// "--surface-color".
  std::string flag() const;
  /// What a valid value is: "4 numbers in [0, 1] (r,g,b,a)", "a number in [0.1, 179) degrees".
  std::string expected() const;
  /// The text of the default settings, or none (the field unset by default).
  std::optional<std::string> defaultText() const;

  // How the value is held (by kind): numbers (none: unset) for Number, Integer, Numbers and Size;
  // a word for Switch and Flag ("on" or "off"), Choice, Text and Points. @p check refuses what the
  // range alone does not (a zero normal), saying why.
  std::function<void(FrameSettings&, const std::optional<std::vector<double>>&)> setNumbers{};
  std::function<void(FrameSettings&, const std::optional<std::string>&)> setWord{};
  std::function<std::string(const std::vector<double>&)> check{};
  std::function<std::string(const std::string&)> checkText{};  ///< a Text's: empty, or why it is refused
  std::function<std::optional<std::string>(const FrameSettings&)> get{};
};

/// Every field, in the order help texts list them: the camera, what is shown, how well.
const std::vector<FrameField>& frameFields();
/// The field named @p name (snake_case), or null.
const FrameField* frameField(std::string_view name);

/// @p settings with the field values of JSON object @p object applied, each converted to its text
/// (a number, an array, a boolean, a string; null unsets it) and parsed by its field; keys in
/// @p skip are left to the caller. Fields outside @p door are refused.
/// @throw ValueError "<where>field 'name': ..." for an unknown field, a value of the wrong JSON
///        type, or a value its field refuses.
void applyJson(FrameSettings* settings, const nlohmann::json& object, unsigned door, const std::vector<std::string>& skip = {},
               const std::string& where = "");
/// The fields of @p settings set (those in @p door and for which @p keep holds), as JSON values.
nlohmann::json settingsJson(const FrameSettings& settings, unsigned door, const std::function<bool(const FrameField&)>& keep = {});
/// The JSON value of a field's text (the inverse of what applyJson reads).
nlohmann::json fieldJson(const FrameField& field, const std::string& text);
/// The table as JSON for the viewer's page: name, kind, range, default, unit, choices of each field.
nlohmann::json fieldsJson(unsigned door);

/// The flags of the fields of @p settings that differ from their defaults, as the command line
/// writes them ("--eye 1,2,3 --fov 30 --iso 400"): the viewer's echo of a frame.
std::string commandLineOf(const FrameSettings& settings);

/// @p s quoted for a POSIX shell when it needs it.
std::string shellQuote(const std::string& s);

/// Whether @p field is one of the camera's (eye, center, up, fov, ortho, ortho_height, size).
bool isCameraField(const FrameField& field);
/// The camera fields of @p camera (eye, center, up, fov, ortho, ortho_height, size): the one camera
/// format that --stats writes, --camera-file reads and the viewer's frames carry.
FrameSettings cameraSettings(const Camera& camera);
/// The camera of @p settings' explicit camera fields (eye, center and up given; size, fov, ortho
/// and ortho_height as set, else the defaults). @throw ValueError when eye or center is not set.
Camera explicitCamera(const FrameSettings& settings);
/// The camera as JSON (patient space, LPS mm): {"space": "LPS", eye, center, up, fov, ortho, ortho_height, size}.
std::string cameraJson(const Camera& camera, int indent = 2);
/// What a frame drew and what it cost: the one format of a frame's statistics, which `--stats`
/// writes (with the command's own figures added) and Python's `render(stats=True)` returns.
struct FrameReport {
  const RenderedFrame& frame;
  const Quality& quality;
  const Camera& camera;
  const KnotStore* store = nullptr;  ///< a paged scene's: the blocks and bytes it read
  double renderMs = 0.0;             ///< the frame's time (the best of repeated frames)
  double preintegrationMs = 0.0;     ///< the pre-integration table's (the first frame's)
  double geometryMs = 0.0;           ///< scan-converting the look's geometry (the first frame's; 0 when kept)
  /// The statistics as a JSON object (ordered keys, camera last); geometry_ms and geometry_bytes
  /// only when the frame composites scan-converted geometry.
  std::string json() const;
};

/// Reads a camera from @p path: a file of cameraJson's form, or a --stats file holding one under
/// "camera"; files of the earlier form (fov_deg, width, height) are read too.
/// @throw IoError naming the file and the field when it is not one.
Camera readCameraFile(const std::string& path);

/// A frame set up from @p settings for @p scene: the transfer function (a file, a preset, points,
/// or the default for the data's range), the camera (a file's, the explicit one, or the view
/// framing what is visible), what is shown and how well; warnings (an isovalue outside the data)
/// on @p warnings. What every front door renders with.
/// @throw ValueError naming the flag, IoError naming a camera or transfer-function file.
struct FrameSetup {
  View view;
  Look look;
  Quality quality;
  glm::vec3 background{0.0f};
};
class UserGeometryMemo;
/// With @p memo, the meshes come from it (a viewer's frames).
FrameSetup setUpFrame(const FrameSettings& settings, const Scene& scene, std::ostream& warnings, UserGeometryMemo* memo = nullptr);

/// The meshes of @p settings' mesh files and primitives (tessellated on @p volume's box), with
/// their warnings (a mesh outside the volume, in metres?) on @p warnings.
/// @throw IoError naming a mesh file, ValueError naming --primitive or --mesh.
std::vector<UserMesh> userGeometry(const FrameSettings& settings, const Volume& volume, std::ostream& warnings);

/// The meshes of the last few sets of settings a series of frames asked for (files by path, space
/// and time of their last change, primitives by their text, on one volume): a frame asking for the
/// same set gets the same meshes, so no file is read nor primitive tessellated again and the
/// renderer keeps what it made of them (it knows them by their objects). One thread at a time.
class UserGeometryMemo {
 public:
  /// userGeometry(), or the meshes it gave for the same set (its warnings were told then).
  std::vector<UserMesh> of(const FrameSettings& settings, const Volume& volume, std::ostream& warnings);

 private:
  static constexpr size_t kKept = 8;
  std::vector<std::pair<std::string, std::vector<UserMesh>>> mKept;  // most recently used last
};

/// The primitive of one --primitive item "plane:PX,PY,PZ,NX,NY,NZ[,THICK][:r,g,b,a]",
/// "sphere:CX,CY,CZ,R[:r,g,b,a]" or "polygon:X1,Y1,Z1,...[:r,g,b,a]" (patient mm, LPS), with its
/// colour; or why it is not one (a number not finite, a zero normal, a radius or thickness not
/// positive, fewer than 3 corners, corners not coplanar or folding).
std::string primitiveIn(const std::string& item, UserPrimitive* primitive, glm::vec4* color);

}  // namespace hyb
