// What the render and bench subcommands share: the input and render flags, parsed into the scene
// renderer's types as they are read (a flag's text is checked once, where it is parsed), and the
// render job they set up: the scene's renderer with the view, look and quality the flags ask for.
#pragma once

#include <CLI/CLI.hpp>

#include <chrono>
#include <cmath>
#include <iosfwd>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "hybrid_octree/hybrid_io.h"
#include "render/camera.h"
#include "render/image.h"
#include "render/patient_view.h"
#include "render/scene_renderer.h"
#include "render/transfer_function.h"
#include "volume/file_util.h"
#include "volume/plane_source.h"
#include "volume/progress.h"
#include "volume/volume_io.h"

namespace hyb::app {

using Clock = std::chrono::steady_clock;
/// Milliseconds since @p t0.
inline double msSince(Clock::time_point t0) { return std::chrono::duration<double, std::milli>(Clock::now() - t0).count(); }

/// Whether @p x is finite as a float too (an isovalue or ε beyond 3.4e38 would become infinite).
inline bool isFloat(double x) { return std::abs(x) <= double(std::numeric_limits<float>::max()); }

/// Parses "a,b,c" into three finite numbers. @throw ValueError naming @p flag.
glm::dvec3 parseVec3(const std::string& text, const std::string& flag);
/// Parses @p n comma-separated finite numbers (any count ≥ 1 when @p n is 0).
/// @throw ValueError naming @p flag and @p expected.
std::vector<double> parseNumbers(const std::string& text, const std::string& flag, size_t n, const char* expected);
/// Parses "WxH" into a positive size no larger than 16384. @throw ValueError naming --size.
glm::ivec2 parseSize(const std::string& text);
/// Parses @p n comma-separated numbers in [0, 1]. @throw ValueError naming @p flag.
glm::vec4 parseColor(const std::string& text, const std::string& flag, int n);

/// A texture budget: megabytes, or a percentage of the view's full-resolution texture bytes.
struct Budget {
  double value = 0.0;  ///< MB (0 = unlimited), or percent in (0, 100]
  bool percent = false;
};
/// Parses --budget: "MB" (>= 0) or "P%" (0 < P <= 100); none when @p text is neither.
std::optional<Budget> parseBudget(const std::string& text);

/// Adds flag @p name taking on|off into @p field; anything else is refused naming the flag.
CLI::Option* addSwitch(CLI::App* cmd, const std::string& name, bool* field, const std::string& help);

/// Where the volume comes from: a path (default: the Debian CT), an optional raw layout, and the
/// series of a DICOM directory.
struct VolumeInput {
  std::string path = kDefaultVolumePath;
  std::string rawDims, rawType, rawSpacing, rawEndian = "little";
  uint64_t rawHeader = 0;
  std::string series;  // DICOM Series Instance UID; empty: the largest series
  std::string pacsAuthFile;  // credentials for a DICOMweb address; empty: the environment's
  const Progress* progress = nullptr;  // where long steps report (runMain's display of --progress)

  /// Adds the volume argument and the raw and DICOM flags; @p scenes: the command also reads scene files.
  void add(CLI::App* cmd, bool scenes = true);
  /// The raw layout when any raw flag is given (then --raw-dims and --raw-type are required).
  /// @throw ValueError naming the flag.
  std::optional<RawLayout> rawLayout() const;
  /// Reads the volume, printing what the reader had to assume on @p err as warnings.
  Volume read(std::ostream& err) const;
  /// Opens the volume plane by plane (openPlanes), printing its warnings on @p err.
  std::unique_ptr<PlaneSource> openPlanes(std::ostream& err) const;
};

/// Prints @p v's reader warnings on @p err, one "hybrid-octree: warning:" line each.
void printWarnings(const Volume& v, std::ostream& err);

/// Loads a scene file, or reads a volume and builds its octree (printing what it did on @p out,
/// warnings on @p err).
/// A scene file is loaded as @p load says (paged or whole).
Scene loadOrBuild(const VolumeInput& in, std::ostream& out, std::ostream& err, double* buildMs, const VolumeOctreeOptions& options = {},
                  const SceneLoadOptions& load = {});

/// The camera as JSON (patient space, LPS mm): space, eye, center, up, fov_deg, ortho,
/// ortho_height, width, height. --stats records it; --camera-file reads it back.
std::string cameraJson(const Camera& patientCamera, int indent = 2);
/// Reads a camera from @p path: a file of cameraJson's form, or a --stats file holding one under
/// "camera". @throw IoError naming the file and the field when it is not one.
Camera readCameraFile(const std::string& path);

/// Render flags (DESIGN 2), shared by render and bench, each held in its type.
struct RenderOptions {
  VolumeInput input;
  std::string output, stats;
  // What is shown.
  std::string tfFile, preset;
  std::optional<double> iso;
  glm::vec4 surfaceColor{0.95f, 0.92f, 0.85f, 1.0f};
  SurfaceNormals surfaceNormals = SurfaceNormals::Gradient;
  glm::vec3 background{0.0f};
  bool shading = true, cutLine = true;
  std::optional<CutPlane> cut;                              // patient mm
  std::optional<std::pair<glm::dvec3, glm::dvec3>> voiBox;  // patient mm
  double voiInside = 1.0, voiOutside = 0.1, voiRamp = 4.0;
  // Where from.
  std::optional<glm::dvec3> eye, center;
  glm::dvec3 up{0, 0, 1};
  std::optional<glm::dvec2> orbit;  // azimuth, elevation
  std::optional<AnatomicalView> view;
  std::string cameraFile;
  double zoom = 1.0, fov = 30.0;
  bool ortho = false, marker = false;
  std::optional<glm::ivec2> size;
  // How well.
  Quality quality;
  std::string budgetText;  // as given, for messages
  bool prefilter = true;
  std::optional<double> memoryMb;  // --memory: a scene's block cache (default: an eighth of physical memory)
  int repeat = 1;  // render: frames of the same view; brick textures are kept, the fastest counts

  /// Checks what the flags say together; empty when valid, else a message naming the flag.
  std::string validate() const;
  /// The flags shared by render and bench.
  void add(CLI::App* cmd);
};

/// A render job: the scene's renderer and the view, look and quality of the flags.
struct RenderJob {
  std::unique_ptr<SceneRenderer> renderer;
  View view;  // patient space
  Look look;
  Quality quality;
  glm::vec3 background{0.0f};
  double buildMs = 0;  // the octree's build (0: a scene file's)
};

/// The bytes `--memory MB` gives a scene file read paged: its octrees, its surfaces and its cache
/// (default: an eighth of the physical memory).
uint64_t sceneMemoryBytes(const std::optional<double>& memoryMb);

/// Loads the scene, chooses the transfer function (file, preset, or one for the data's range) and
/// sets up the camera (a file's, the --eye given, or the view framing what is visible), printing
/// what it did on @p out and warnings (the readers', an isovalue outside the data) on @p err.
/// @p keepTextures: brick textures are kept for later frames (SceneRenderer::Options::keepTextures).
RenderJob prepareRender(const RenderOptions& o, std::ostream& out, std::ostream& err, bool keepTextures = true);

/// An isosurface as `export` writes it, in patient coordinates (LPS mm): @p kind dmc (DiscMC),
/// octree (the Surface Octree's, coplanar polygons merged) or mc (classic Marching Cubes), capped on
/// the volume's faces when @p closed, with gradient normals when @p normals; and, when
/// @p againstMc, classic Marching Cubes' surface beside it (`export --check` compares them; not
/// made otherwise: it doubles the extraction's time and memory). Prints what it made on @p out.
/// @throw ValueError for another kind, or a scene without its samples.
struct ExportedSurface {
  TriangleMesh mesh, mc;
  size_t polygons = 0;
  double ms = 0, mcMs = 0;
};
ExportedSurface exportedSurface(const Scene& scene, float iso, const std::string& kind, bool closed, bool normals, bool againstMc,
                                const Progress* progress, std::ostream& out);

/// Sets @p job's view, look, quality and background from @p o's flags for @p scene: the transfer
/// function (file, preset, or one for the data's range) and the camera (a file's, the --eye given,
/// or the view framing what is visible), warnings (an isovalue outside the data) on @p err.
/// @throw ValueError naming the flag, IoError naming a camera or transfer-function file.
/// @p tf, when given, replaces the flags' transfer function (the camera frames what it shows).
void setUpFrame(const RenderOptions& o, const Scene& scene, RenderJob* job, std::ostream& err, const TransferFunction* tf = nullptr);

/// One line on the surface of a frame that built or reconstructed it (empty when it was kept).
std::string surfaceLine(const FrameStats& stats, float iso, bool fromScene);

}  // namespace hyb::app
