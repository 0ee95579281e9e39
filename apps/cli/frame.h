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
#include "render/frame_settings.h"
#include "render/image.h"
#include "render/patient_view.h"
#include "render/scene_renderer.h"
#include "render/transfer_function.h"
#include "volume/core/file_util.h"
#include "volume/core/number_text.h"
#include "volume/core/progress.h"
#include "volume/plane_source.h"
#include "volume/volume_io.h"

namespace hyb::app {

using Clock = std::chrono::steady_clock;
/// Milliseconds since @p t0.
inline double msSince(Clock::time_point t0) { return std::chrono::duration<double, std::milli>(Clock::now() - t0).count(); }

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

/// Render flags (DESIGN 2), shared by render and bench: the input, the frame's settings (one
/// flag a field of render/frame_settings.h's table), and what the command does with the frame.
struct RenderOptions {
  VolumeInput input;
  std::string output, stats;
  FrameSettings settings;
  bool prefilter = true;
  std::optional<double> memoryMb;  // --memory: a scene's block cache (default: an eighth of physical memory)
  int repeat = 1;  // render: frames of the same view; brick textures are kept, the fastest counts

  /// Checks what the flags say together; empty when valid, else a message naming the flag.
  std::string validate() const;
  /// The flags shared by render and bench: every field of the table the command line takes.
  void add(CLI::App* cmd);
};

/// A render job: the scene's renderer and the frame the flags set up.
struct RenderJob : FrameSetup {
  std::unique_ptr<SceneRenderer> renderer;
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

/// One line on the surface of a frame that built or reconstructed it (empty when it was kept).
std::string surfaceLine(const FrameStats& stats, float iso, bool fromScene);

}  // namespace hyb::app
