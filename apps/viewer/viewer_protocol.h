// The viewer's messages: what the page asks for over its WebSocket, parsed into typed requests and
// validated field by field (unknown fields, wrong types, non-finite or out-of-range numbers and
// oversized arrays are refused with a message naming the field), and what the server sends back.
// Pure functions: no sockets, no rendering, so that every rule is tested in-process.
#pragma once

#include <glm/glm.hpp>

#include <cstdint>
#include <optional>
#include <string>
#include <variant>
#include <vector>

#include "render/frame_settings.h"

namespace hyb::viewer {

/// Limits of what a client may ask for.
inline constexpr size_t kMaxMessageBytes = 64 * 1024;
inline constexpr int kMaxImageEdge = 2048, kMinImageEdge = 16;
inline constexpr size_t kMaxPathBytes = 4096;
/// Text messages waiting for a client that does not read them (its frames are bounded apart: only
/// the newest waits); beyond this the server closes that client.
inline constexpr size_t kMaxQueuedTextBytes = 1 << 20;

/// A frame to render: the page's whole state, so the server keeps no per-field history and a lost
/// message loses nothing. Besides seq, scene and interacting, a frame message holds the frame
/// table's viewer fields (render/frame_settings.h) under their names, as --stats' camera and the
/// command line's flags spell them: eye, center, up and size required, preset or tf_points.
struct FrameRequest {
  uint64_t seq = 0;         ///< echoed in the frame that answers it
  /// The scene the page shows (its info's "scene"): a request for another is stale and dropped;
  /// empty: the one the client shows.
  std::string scene;
  bool interacting = false;  ///< the user is dragging: hold the frame rate; false: refine to the final frame
  FrameSettings settings;    ///< the camera and the look, patient millimetres (LPS)

  /// The image size asked for.
  glm::ivec2 size() const { return *settings.size; }
  /// The isosurface asked for, or none.
  std::optional<float> iso() const { return settings.iso ? std::optional(float(*settings.iso)) : std::nullopt; }
};

/// Open a volume of the data directory (its path relative to that directory) and, for a DICOM
/// directory, one series; or a series of the server's PACS by its DICOMweb address (url).
struct OpenRequest {
  std::string path;
  std::string series;
  std::string url;  ///< ROOT/studies/UID/series/UID under the server's --pacs root; then no path
};

/// Search the server's PACS (QIDO-RS); empty fields match everything.
struct PacsSearchRequest {
  std::string patient;    ///< Patient Name, DICOM wildcards (* ?)
  std::string studyDate;  ///< YYYYMMDD or a range YYYYMMDD-YYYYMMDD
  std::string modality;
};

using Request = std::variant<FrameRequest, OpenRequest, PacsSearchRequest>;

/// Parses one text message. @throw ValueError with a message naming the field and what was expected.
Request parseRequest(const std::string& text);

/// A server → client text message {"type":"error","message":...}, and with the request's seq when known.
std::string errorMessage(const std::string& message, std::optional<uint64_t> seq = std::nullopt);

/// A binary frame message: a 4-byte little-endian length, that many bytes of JSON header, the image.
std::string frameMessage(const std::string& headerJson, const std::vector<uint8_t>& image);

/// Splits a binary frame message into header and image; false when it is not one.
bool splitFrameMessage(const std::string& message, std::string* headerJson, std::string* image);

}  // namespace hyb::viewer
