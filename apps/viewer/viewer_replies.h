// What the viewer's server tells the page: one type per reply, each written in one place (the
// requests are parsed in viewer_protocol.h). Pure functions of their fields, tested in-process.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "apps/viewer/viewer_files.h"
#include "apps/viewer/viewer_protocol.h"
#include "apps/viewer/viewer_quality.h"
#include "render/scene_pool.h"
#include "volume/dicomweb.h"

namespace hyb::viewer {

/// A scene opened for the client: its summary, the six views, the transfer functions, the isosurfaces
/// ready, the data directory's volumes and the frame table's fields (the page's controls' ranges).
struct InfoReply {
  const SceneSummary& scene;
  std::vector<float> surfaces;          ///< isovalues whose surfaces are ready
  const std::vector<DataEntry>& volumes;
  bool fromDataDir = false;             ///< opened from the data directory: the page's menu shows it
  std::string pacs;                     ///< the PACS the page may search (its address redacted), or empty
  std::vector<std::string> meshes = {}; ///< the data directory's mesh files, which frames may draw
  std::string text() const;
};

/// The data directory's volumes (a client that opens none yet).
struct VolumesReply {
  const std::vector<DataEntry>& volumes;
  std::string pacs;  ///< the PACS the page may search (its address redacted), or empty
  std::vector<std::string> meshes = {};  ///< the data directory's mesh files, which frames may draw
  std::string text() const;
};

/// What a PACS search found: each series with what the page lists and its address, to open.
struct PacsReply {
  const std::vector<DicomWebSeries>& series;
  std::string text() const;
  /// What the page and the server's messages call @p s: patient, date, modality, description, instances.
  static std::string label(const DicomWebSeries& s);
};

/// A scene's load under way: its current task and the fraction done.
struct LoadingReply {
  std::string scene, task;
  double progress = 0.0;
  std::string text() const;
};

/// A scene that could not be opened: why, in words (an error message that names the scene).
struct OpenFailedReply {
  std::string scene, message;
  std::string text() const;
};

/// An isosurface being built for a scene, ready, or failed.
struct SurfaceReply {
  std::string scene;
  float iso = 0.0f;
  ScenePool::SurfaceState state = ScenePool::SurfaceState::Building;
  std::string task;       ///< while building
  double progress = 0.0;  ///< while building
  std::string text() const;
};

/// When a frame's request came from the page: its wait for the render thread, and its arrival's
/// wall clock (milliseconds since the epoch: the page compares them with its own clock).
struct Arrival {
  double waitMs = 0.0, epochMs = 0.0;
  uint64_t waitedRenders = 0;  ///< other clients' renders (frames or bands) drawn while it waited
};

/// What a frame shows of its scene's surfaces (ScenePool::Frame): the isovalue drawn, whether the
/// one asked for is ready, whether the builder is at work on it.
struct SurfaceShown {
  std::optional<float> iso;
  bool ready = true, building = false;
  explicit SurfaceShown(const ScenePool::Frame& f) : iso(f.iso), ready(f.surfaceReady), building(f.surfaceBuilding) {}
  /// The surface a frame of @p r draws: none when it asks for none.
  std::optional<float> drawn(const FrameRequest& r) const { return r.settings.iso ? iso : std::nullopt; }
};

/// A frame message's header: the request it answers, the ladder's level it was drawn at, the
/// surface shown, when the request came, and the frame's counts and times.
struct FrameHeader {
  const SceneSummary& scene;
  const FrameRequest& r;
  const QualityLevel& q;
  int level = 0;
  bool final = false;
  const SurfaceShown& surface;
  const std::optional<Arrival>& arrival;
  const FrameStats& st;
  double maxError = 0, renderMs = 0;
  int bands = 1;             ///< a final frame drawn band by band: how many
  double longestBandMs = 0;  ///< ... and the longest band's time
  bool sharper = false;  ///< the sharper step before a slow final frame (AdaptiveQuality::sharperStep)
  /// Sent as PNG: the final frame, and the sharper step (drawn as the final frame is but for its
  /// spacing, it differs from it by less than JPEG would change it).
  bool png() const { return final || sharper; }

  /// The header as the page reads it (type "frame"), of an image @p width x @p height encoded in
  /// @p encodeMs; the final frame's carries the `hybrid-octree render` command that makes it.
  std::string text(int width, int height, double encodeMs) const;
};

/// The `hybrid-octree render` command line that makes the frame @p r asks of the volume at @p path
/// (DICOM @p series), the transfer function's points in the file @p tfFile when they are not a preset.
std::string renderCommand(const std::string& path, const std::string& series, const FrameRequest& r, const std::string& tfFile);

/// The transfer function's points as a --tf file.
std::string tfText(const std::vector<TransferFunction::Point>& points);

}  // namespace hyb::viewer
