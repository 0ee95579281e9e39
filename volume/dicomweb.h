// DICOM series in a PACS, over DICOMweb (PS3.18): QIDO-RS lists patients, studies and series;
// WADO-RS retrieves a series as multipart/related; type="application/dicom", each instance written
// as it arrives into a private temporary folder that the folder reader (dicom_io.cpp) then reads:
// one reader, two transports. HTTP goes through libcurl (TLS, timeouts, redirects, authentication).
// Credentials come from the environment or a file, never from the address, and no message holds
// them: an address is redacted wherever it is quoted.
#pragma once

#include <atomic>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "volume/core/progress.h"
#include "volume/volume.h"
#include "volume/volume_io.h"

namespace hyb {

class PlaneSource;

/// How to reach a DICOMweb server.
struct DicomWebOptions {
  /// A file holding the credentials on its first line: "Bearer TOKEN" or "USER:PASSWORD" (HTTP basic);
  /// empty: the environment's HYB_DICOMWEB_TOKEN (bearer) or HYB_DICOMWEB_USER ("USER:PASSWORD"), if any.
  std::string authFile;
  double connectSeconds = 10.0;  ///< to open the connection
  double stallSeconds = 30.0;    ///< a transfer receiving nothing for this long has timed out
  /// Set from any thread to stop a transfer: it then throws RuntimeError("... cancelled").
  const std::atomic<bool>* cancel = nullptr;
};

/// The options readVolume() and openPlanes() use for a DICOMweb address: the environment's
/// credentials, or those of the file setDicomWebAuthFile() named.
DicomWebOptions dicomWebDefaults();
/// Names the credentials file of dicomWebDefaults() (the command line's --pacs-auth-file); empty: the environment.
void setDicomWebAuthFile(const std::string& path);

/// Whether @p path is an http:// or https:// address (then readVolume() reads it over DICOMweb).
bool isDicomWebUrl(const std::string& path);
/// @p url with any user information ("user:password@") replaced by "***@": for every message and log.
std::string redactUrl(const std::string& url);

/// What QIDO-RS is asked for; empty fields match everything.
struct DicomWebQuery {
  std::string patient;    ///< Patient Name, DICOM wildcards (* ?) allowed
  std::string studyDate;  ///< Study Date: YYYYMMDD, or a range YYYYMMDD-YYYYMMDD (either end may be open)
  std::string modality;   ///< Modalities in Study / Modality: CT, MR...
};

/// One series found: what the folder listing gives (no size: QIDO-RS does not tell it) and its address.
struct DicomWebSeries {
  DicomSeriesInfo info;  ///< slices: Number of Series Related Instances
  std::string url;       ///< ROOT/studies/UID/series/UID, ready for readVolume()
};

/// The series of the studies matching @p query at the DICOMweb root @p root (e.g.
/// http://host:8042/dicom-web), grouped by study in the order the server lists the studies.
/// @throw IoError naming the redacted address and what went wrong (connection refused, HTTP 401,
///        403, 404, 5xx, a timeout, a body that is not DICOM JSON); ValueError for a malformed
///        address or query.
std::vector<DicomWebSeries> queryDicomWeb(const std::string& root, const DicomWebQuery& query, const DicomWebOptions& options = dicomWebDefaults());

/// The Series Instance UID of @p seriesUrl and the SOP Instance UIDs of its instances as the
/// archive lists them now (QIDO-RS), sorted: what a cache of scenes built from the series is
/// keyed by, so that a series whose instances changed is built again.
/// @throw as queryDicomWeb(); ValueError for an address that is not a series'.
std::pair<std::string, std::vector<std::string>> dicomWebInstances(const std::string& seriesUrl, const DicomWebOptions& options = dicomWebDefaults());

/// What a retrieval brought.
struct DicomWebFetch {
  size_t instances = 0;
  uint64_t bytes = 0;  ///< of the instances
};

/// Retrieves the series at @p seriesUrl (ROOT/studies/UID/series/UID) with WADO-RS into the
/// existing folder @p dir, each instance written to its own file (named by its SOP Instance UID)
/// as its part of the multipart body arrives, checked to be DICOM as soon as it is whole.
/// @p progress hears of the bytes received ("DICOMweb series"; of the Content-Length when the
/// server gives one).
/// @throw IoError naming the redacted address: HTTP errors as queryDicomWeb(), a body that is not
///        multipart/related of application/dicom, a part that is not DICOM, a body cut short;
///        RuntimeError when cancelled.
DicomWebFetch fetchDicomWebSeries(const std::string& seriesUrl, const std::string& dir, const DicomWebOptions& options = dicomWebDefaults(),
                                  const Progress* progress = nullptr);

/// The series at @p seriesUrl read as readDicomSeries() reads a folder holding its instances:
/// retrieved into a private temporary folder (removed before returning), then read; messages name
/// an instance by its address, ROOT/studies/UID/series/UID/instances/UID.
/// @throw as fetchDicomWebSeries() and readDicomSeries().
Volume readDicomWebSeries(const std::string& seriesUrl, const Progress* progress = nullptr, const DicomWebOptions& options = dicomWebDefaults());

/// How large a series' preview is (readDicomWebPreview()).
struct DicomWebPreview {
  int planes = 64;  ///< instances retrieved, at most
  int edge = 256;   ///< samples a side in the image plane, at most
};

/// A coarse look at the series at @p seriesUrl in a fraction of the time its retrieval takes: its
/// instances listed with their positions (QIDO-RS), about @p size.planes of them evenly spaced
/// along the stack retrieved one by one (WADO-RS) and read as readDicomSeries() reads a folder of
/// them, then averaged in blocks to at most @p size.edge samples a side (boxAveraged). Its patient
/// box is the series' within a stride along the stack. Empty when a preview would not be much
/// quicker than the series (at most twice size.planes instances of the stack) or cannot be made
/// this way (multi-frame instances, instances without a position or orientation). A localizer
/// (another orientation) is left out as the folder reader leaves it out.
/// @throw as fetchDicomWebSeries() and readDicomSeries().
std::optional<Volume> readDicomWebPreview(const std::string& seriesUrl, const DicomWebPreview& size = {}, const Progress* progress = nullptr,
                                          const DicomWebOptions& options = dicomWebDefaults());

namespace detail {

/// A WADO-RS answer's body of type @p contentType split into its instances' files in @p dir, as a
/// retrieval writes them, the body given @p chunk bytes at a time (as the network hands it over):
/// what a hostile archive's answer meets (the fuzz target `dicomweb_answer`).
/// @throw IoError as fetchDicomWebSeries() for a body that is not multipart DICOM.
DicomWebFetch splitMultipart(const std::string& contentType, std::string_view body, const std::string& dir, size_t chunk);

/// The streamed planes of the series at @p seriesUrl, as dicomPlanes() gives a folder's: the
/// series is retrieved into a private temporary folder that lives as long as the planes.
std::unique_ptr<PlaneSource> dicomWebPlanes(const std::string& seriesUrl, const Progress* progress = nullptr,
                                            const DicomWebOptions& options = dicomWebDefaults());

}  // namespace detail

}  // namespace hyb
