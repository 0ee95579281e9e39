// What the render and bench subcommands share: input and render flags, and the pieces of a frame
// (scene, transfer function, camera, surface), its selection parameters and its rendering.
#pragma once

#include <CLI/CLI.hpp>

#include <chrono>
#include <functional>
#include <iosfwd>
#include <memory>
#include <optional>
#include <string>
#include <utility>

#include "hybrid_octree/hybrid_io.h"
#include "hybrid_octree/selection.h"
#include "render/brick_error.h"
#include "render/camera.h"
#include "render/image.h"
#include "render/patient_view.h"
#include "render/raycast.h"
#include "render/slices.h"
#include "render/transfer_function.h"
#include "volume/file_util.h"
#include "volume/volume_io.h"

namespace hyb::app {

using Clock = std::chrono::steady_clock;
/// Milliseconds since @p t0.
inline double msSince(Clock::time_point t0) { return std::chrono::duration<double, std::milli>(Clock::now() - t0).count(); }

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

/// Where the volume comes from: a path (default: the Debian CT), an optional raw layout, and the
/// series of a DICOM directory.
struct VolumeInput {
  std::string path = kDefaultVolumePath;
  std::string rawDims, rawType, rawSpacing, rawEndian = "little";
  uint64_t rawHeader = 0;
  std::string series;  // DICOM Series Instance UID; empty: the largest series
  const Progress* progress = nullptr;  // where long steps report (runMain's display of --progress)

  void add(CLI::App* cmd) {
    cmd->add_option("volume", path, "volume file (.nrrd .nhdr .mhd .mha .nii .nii.gz .inv3), DICOM directory, raw file, or scene.hoct")
        ->capture_default_str();
    cmd->add_option("--raw-dims", rawDims, "raw input: samples per axis X,Y,Z");
    cmd->add_option("--raw-type", rawType, "raw input: int16|uint16|uint8|int8|int32|uint32|float32|float64");
    cmd->add_option("--raw-spacing", rawSpacing, "raw input: voxel spacing sx,sy,sz in mm (default 1,1,1)");
    cmd->add_option("--raw-endian", rawEndian, "raw input: little|big (default little)");
    cmd->add_option("--raw-header", rawHeader, "raw input: bytes to skip before the samples");
    cmd->add_option("--series", series, "DICOM directory: the Series Instance UID to read (default: the largest series; info lists them)");
  }

  // Builds the raw layout when any raw flag is given (then --raw-dims and --raw-type are required).
  std::optional<RawLayout> rawLayout() const {
    if (rawDims.empty() && rawType.empty() && rawSpacing.empty()) return std::nullopt;
    if (rawDims.empty()) HYB_THROW(ValueError, "--raw-dims missing (expected X,Y,Z with --raw-type)");
    if (rawType.empty()) HYB_THROW(ValueError, "--raw-type missing (expected int16|uint16|uint8|float32...)");
    RawLayout l;
    const glm::dvec3 d = parseVec3(rawDims, "--raw-dims");
    for (int a = 0; a < 3; ++a)
      if (d[a] != std::floor(d[a]) || d[a] < 1 || d[a] > kMaxDim)
        HYB_THROW(ValueError, "--raw-dims '", rawDims, "' invalid (expected positive integers up to ", kMaxDim, ")");
    l.dims = glm::ivec3(d);
    if (!parseScalarName(rawType, &l.type))
      HYB_THROW(ValueError, "--raw-type '", rawType, "' unknown (expected int16|uint16|uint8|int8|int32|uint32|float32|float64)");
    if (!rawSpacing.empty()) l.spacing = parseVec3(rawSpacing, "--raw-spacing");
    validateSpacing(l.spacing, "--raw-spacing");
    if (rawEndian != "little" && rawEndian != "big")
      HYB_THROW(ValueError, "--raw-endian '", rawEndian, "' invalid (expected little or big)");
    l.bigEndian = rawEndian == "big";
    l.headerBytes = rawHeader;
    return l;
  }

  /// Reads the volume, printing what the reader had to assume on @p err as warnings.
  Volume read(std::ostream& err) const;
};

/// Prints @p v's reader warnings on @p err, one "hybrid-octree: warning:" line each.
void printWarnings(const Volume& v, std::ostream& err);

/// Loads a scene file, or reads a volume and builds its octree (printing what it did on @p out,
/// warnings on @p err).
Scene loadOrBuild(const VolumeInput& in, std::ostream& out, std::ostream& err, double* buildMs, const VolumeOctreeOptions& options = {});

/// The camera as JSON (patient space, LPS mm): space, eye, center, up, fov_deg, ortho,
/// ortho_height, width, height. --stats records it; --camera-file reads it back.
std::string cameraJson(const Camera& patientCamera, int indent = 2);
/// Reads a camera from @p path: a file of cameraJson's form, or a --stats file holding one under
/// "camera". @throw IoError naming the file and the field when it is not one.
Camera readCameraFile(const std::string& path);

/// Render flags (DESIGN 2), shared by render and bench.
struct RenderOptions {
  VolumeInput input;
  std::string output, stats, focus, renderer = "slices", tfFile, preset, surfaceColor = "0.95,0.92,0.85,1";
  std::string eye, center, up = "0,0,1", orbit, view, size, background = "0,0,0", shading = "on";
  std::string cameraFile, marker = "off", surfaceNormals = "gradient";
  double zoom = 1.0;
  std::string blend = "on", cut, cutLine = "on", voi, proxy = "planes", prefilter = "on";
  double voiInside = 1.0, voiOutside = 0.1, voiRamp = 4.0, lodPixels = 0.0;
  std::optional<double> iso;
  std::string budget;  // MB or "P%" of the full-resolution bytes (parseBudget); empty = unlimited
  double epsilon = 0.0, fov = 30.0;
  std::optional<double> step;  // default: 0.5 voxel for slices, 0.25 for the reference
  bool ortho = false;
  int maxBrick = 16;
  int texelBits = 8;  // brick texture precision: 8 or 16 bits a channel
  int progressive = 1;
  double adaptive = 0;  // raycast: refine where neighbouring colours differ by more than this (1/255 units); 0 = every pixel
  int repeat = 1;  // render: frames of the same view; brick textures are kept, the fastest counts
  std::string validate() const {
    if (!std::isfinite(epsilon) || epsilon < 0) return "--epsilon must be a finite value >= 0 (data units)";
    if (!budget.empty() && !parseBudget(budget))
      return "--budget '" + budget + "' invalid (expected megabytes >= 0, or a percentage of the full-resolution texture bytes: 0 < P <= 100 followed by %)";
    if (iso && !std::isfinite(*iso)) return "--iso must be a finite number";
    if (renderer != "raycast" && renderer != "slices") return "--renderer '" + renderer + "' invalid (expected slices or raycast)";
    if (!(fov > 0 && fov < 179)) return "--fov must be in (0, 179) degrees";
    if (step && !(*step > 0.01 && *step <= 4)) return "--step must be in (0.01, 4] voxels";
    if (shading != "on" && shading != "off") return "--shading must be on or off";
    if (blend != "on" && blend != "off") return "--blend must be on or off";
    if (prefilter != "on" && prefilter != "off") return "--prefilter must be on or off";
    if (proxy != "planes" && proxy != "shells") return "--proxy '" + proxy + "' invalid (expected planes or shells)";
    if (cutLine != "on" && cutLine != "off") return "--cut-line must be on or off";
    if (marker != "on" && marker != "off") return "--marker must be on or off";
    if (surfaceNormals != "gradient" && surfaceNormals != "facet") return "--surface-normals '" + surfaceNormals + "' invalid (expected gradient or facet)";
    if (AnatomicalView v; !view.empty() && !parseAnatomicalView(view, &v))
      return "--view '" + view + "' invalid (expected " + anatomicalViewNames() + ")";
    if (!(std::isfinite(zoom) && zoom > 0 && zoom <= 1000)) return "--zoom must be a magnification in (0, 1000]";
    if (!cameraFile.empty() && (!eye.empty() || !orbit.empty() || !view.empty()))
      return "--camera-file sets the whole camera (it excludes --eye, --orbit and --view)";
    if (progressive < 1 || progressive > 8) return "--progressive must be in 1..8 images";
    if (repeat < 1 || repeat > 100) return "--repeat must be in 1..100 frames";
    if (texelBits != 8 && texelBits != 16) return "--texel-bits must be 8 or 16";
    SelectionParams brickEdge;  // the library's own check, here before any file is read or written
    brickEdge.maxBrickEdge = maxBrick;
    if (std::string e = brickEdge.validate(); !e.empty()) return e;
    if (!(std::isfinite(lodPixels) && lodPixels >= 0)) return "--lod-pixels must be a finite number of pixels >= 0";
    if (!output.empty() && fileExtension(output) != ".png") return "-o '" + output + "' must be a .png file (render writes PNG images)";
    if (progressive > 1 && output.empty()) return "--progressive needs -o (the images are named after it)";
    if (!(std::isfinite(adaptive) && adaptive >= 0 && adaptive <= 255)) return "--adaptive must be a colour difference in [0, 255] (units of 1/255)";
    if (adaptive > 0 && renderer != "raycast") return "--adaptive needs --renderer raycast (Levoy's adaptive refinement of the reference's rays)";
    if (!(std::isfinite(voiInside) && voiInside >= 0)) return "--voi-inside must be a finite factor >= 0";
    if (!(std::isfinite(voiOutside) && voiOutside >= 0)) return "--voi-outside must be a finite factor >= 0";
    if (!(std::isfinite(voiRamp) && voiRamp >= 0)) return "--voi-ramp must be a finite width >= 0 mm";
    if (!tfFile.empty() && !preset.empty()) return "--tf and --preset are exclusive";
    for (const auto& [path, flag] : {std::pair{&output, "-o"}, std::pair{&stats, "--stats"}})
      if (std::string e = outputPathError(*path, flag); !e.empty()) return e;
    return "";
  }

  // The flags shared by render and bench.
  void add(CLI::App* cmd) {
    input.add(cmd);
    cmd->add_option("--iso", iso, "isovalue of the embedded surface (data units; none = volume only)");
    cmd->add_option("--surface-color", surfaceColor, "surface r,g,b,a in [0,1]; a < 1 is translucent")->capture_default_str();
    cmd->add_option("--surface-normals", surfaceNormals,
                    "surface shading: gradient (smooth, the volume's gradient at each vertex) or facet (each polygon's own plane)")
        ->capture_default_str();
    cmd->add_option("--tf", tfFile, "transfer function file: 'value r g b a' lines, a = opacity of 1 mm");
    cmd->add_option("--preset", preset, "ct-bone, ct-skin, ct-soft-tissue, ct-vessels, ct-skin-bone (default for CT; other data: a ramp)");
    cmd->add_option("--focus", focus, "region of interest x,y,z, patient mm (LPS)");
    CLI::Option* eyeOption = cmd->add_option("--eye", eye, "camera position x,y,z, patient mm (LPS: x left, y posterior, z superior; with --center, --up)");
    // Without --eye the camera orbits, and a --center or --up would be silently ignored.
    cmd->add_option("--center", center, "point looked at, x,y,z, patient mm (default: the volume's centre); needs --eye")->needs(eyeOption);
    cmd->add_option("--up", up, "up direction x,y,z in patient axes (LPS); needs --eye")->capture_default_str()->needs(eyeOption);
    CLI::Option* viewOption = cmd->add_option("--view", view,
                                              "anatomical view: anterior (default; the patient's left on the image's right), posterior, "
                                              "left, right, superior, inferior")->excludes(eyeOption);
    cmd->add_option("--orbit", orbit,
                    "azimuth,elevation in degrees from the anterior view: azimuth towards the patient's left (90 = left view), "
                    "elevation towards superior")
        ->excludes(eyeOption)
        ->excludes(viewOption);
    cmd->add_option("--zoom", zoom, "magnify the image about its centre (2 = twice as large; default framing fits what is visible)")
        ->capture_default_str();
    cmd->add_option("--camera-file", cameraFile, "read the camera from a JSON file written by --stats (or its \"camera\" object alone)");
    cmd->add_option("--marker", marker, "orientation marker (patient axes L/R, P/A, S/I) in the lower-left corner: on|off")->capture_default_str();
    cmd->add_option("--fov", fov, "vertical field of view in degrees")->capture_default_str();
    cmd->add_flag("--ortho", ortho, "orthographic projection");
    cmd->add_option("--size", size, "image size WxH (default 512x512, or the camera file's)");
    cmd->add_option("--background", background, "background r,g,b in [0,1]")->capture_default_str();
    cmd->add_option("--shading", shading, "gradient shading of the volume: on|off")->capture_default_str();
    cmd->add_option("--proxy", proxy, "slice geometry: planes (view-aligned) or shells (spherical around the eye, perspective)")
        ->capture_default_str();
    cmd->add_option("--blend", blend, "blend bricks towards coarser neighbours (Carmona et al.): on|off")->capture_default_str();
    cmd->add_option("--prefilter", prefilter,
                    "coarse levels (texels 4+ voxels apart) hold the data smoothed by their tent filter instead of point samples "
                    "(no aliasing of thin structures): on|off (a scene file keeps the choice it was built with)")
        ->capture_default_str();
    cmd->add_option("--cut", cut, "cutting plane px,py,pz,nx,ny,nz (point and normal, mm): removes the eye's side, shows the data on it");
    cmd->add_option("--cut-line", cutLine, "draw the isosurface's intersection with the cutting plane: on|off")->capture_default_str();
    cmd->add_option("--voi", voi, "volume of interest x0,y0,z0,x1,y1,z1 (mm): opacity scaled inside/outside the box (Levoy)");
    cmd->add_option("--voi-inside", voiInside, "opacity factor inside the volume of interest")->capture_default_str();
    cmd->add_option("--voi-outside", voiOutside, "opacity factor outside the volume of interest")->capture_default_str();
    cmd->add_option("--voi-ramp", voiRamp, "width of the smooth transition across the box's surface, mm")->capture_default_str();
    cmd->add_option("--step", step, "slice / sample spacing in voxels (default 0.5 for slices, 0.25 for raycast)");
    cmd->add_option("--lod-pixels", lodPixels, "stop refining where texels are at most this many pixels apart on screen (0 = off)")
        ->capture_default_str();
    cmd->add_option("--max-brick", maxBrick, "brick edge in texels (power of two)")->capture_default_str();
    cmd->add_option("--texel-bits", texelBits,
                    "brick precision: 8 (value and gradient in 8 bits, fastest) or 16 (twice the memory, ~10 % slower frames; "
                    "for transfer functions narrow against a brick's values, e.g. soft tissue)")
        ->capture_default_str();
  }
  TexelBits bits() const { return texelBits == 16 ? TexelBits::Sixteen : TexelBits::Eight; }
};

/// Everything a frame needs besides the selection: the scene, transfer function, camera, surface.
struct Frame {
  Frame() = default;
  Frame(const Frame&) = delete;  // brickError refers to this frame's scene and volume of interest
  Frame& operator=(const Frame&) = delete;

  Scene scene;
  double buildMs = 0, surfaceMs = 0, polygonsMs = 0;  // octrees built; the surface's polygons reconstructed
  TransferFunction tf;
  Camera patientCamera;  // as the user sees it: patient space (LPS mm)
  Camera camera;         // the renderers' (grid frame)
  std::optional<SurfaceOctree> builtSurface;
  const SurfaceOctree* so = nullptr;
  TriangleMesh mesh;
  size_t polygons = 0;
  glm::vec4 surfaceColor{1.0f};
  glm::vec3 background{0.0f};
  std::optional<CutPlane> cut;            // grid frame
  std::optional<VolumeOfInterest> voi;    // its box in patient axes, placed in the grid frame
  std::optional<glm::dvec3> focus;        // grid frame
  /// The bricks' image errors for this view and transfer function, made on the first budgeted
  /// selection and shared by the later ones (bench's sweep, progressive levels).
  mutable std::shared_ptr<BrickImageError> brickError;
};

/// Loads the scene and sets up the transfer function, camera and surface of @p o, converting the
/// user's patient coordinates (camera, cut, volume of interest, focus) into the grid frame.
void prepareFrame(const RenderOptions& o, std::ostream& out, std::ostream& err, Frame* f);

/// Selection parameters for a frame: ε, budget (MB), focus, the eye, the transfer function's opacity
/// and slope, frustum culling and blending.
SelectionParams selectionParams(const RenderOptions& o, const Frame& f, double epsilon, double budgetMb);

/// Renders one frame with o.renderer; slices need a current GlContext. The reference refines its
/// rays progressively with --progressive or --adaptive; @p onLevel receives each level's image.
Image renderFrame(const RenderOptions& o, const Frame& f, const Selection& sel, SlicesStats* ss, RaycastStats* rs,
                  BrickTextureCache* textures = nullptr, const std::function<void(int, const Image&, uint64_t)>& onLevel = {});

}  // namespace hyb::app
