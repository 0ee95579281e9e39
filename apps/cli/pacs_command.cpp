#include "apps/cli/pacs_command.h"

#include <CLI/CLI.hpp>

#include <memory>
#include <ostream>
#include <string>

#include "volume/dicomweb.h"

namespace hyb::app {

namespace {

struct PacsOptions {
  std::string root, authFile;
  DicomWebQuery query;
  double timeout = 30.0;
  std::string validate() const {
    if (root.empty()) return "pacs needs the archive's DICOMweb root (expected: pacs http(s)://HOST:PORT/ROOT, e.g. http://127.0.0.1:8042/dicom-web)";
    if (!isDicomWebUrl(root)) return "pacs " + redactUrl(root) + ": not a DICOMweb root (expected http(s)://HOST:PORT/ROOT)";
    if (!(timeout >= 1.0 && timeout <= 3600.0)) return "--timeout must be seconds in [1, 3600]";
    return "";
  }
};

// The series grouped by patient and study, each with its address.
void printListing(const std::string& root, const std::vector<DicomWebSeries>& found, std::ostream& out) {
  size_t studies = 0;
  for (size_t k = 0; k < found.size(); ++k) studies += k == 0 || found[k].info.studyUid != found[k - 1].info.studyUid;
  out << "pacs     " << redactUrl(root) << ": " << found.size() << " series in " << studies
      << (studies == 1 ? " study" : " studies") << (found.empty() ? "" : "; give a series' address to info, build, render, export or view") << "\n";
  std::string patient = "\x01", study = "\x01";
  for (const DicomWebSeries& s : found) {
    const DicomSeriesInfo& i = s.info;
    const std::string who = (i.patientName.empty() ? "(no name)" : i.patientName) + (i.patientId.empty() ? "" : " (ID " + i.patientId + ")");
    if (who != patient) out << "patient  " << (patient = who) << "\n", study = "\x01";
    if (i.studyUid != study)
      out << "  study  " << (i.studyDate.empty() ? "(no date)" : i.studyDate) << (i.studyDescription.empty() ? "" : "  " + i.studyDescription) << "  ("
          << (study = i.studyUid) << ")\n";
    out << "    " << (i.modality.empty() ? "?" : i.modality) << (i.number.empty() ? "" : "  #" + i.number) << "  " << i.slices
        << (i.slices == 1 ? " instance" : " instances") << (i.date.empty() ? "" : "  " + i.date) << (i.description.empty() ? "" : "  " + i.description) << "\n"
        << "      " << redactUrl(s.url) << "\n";
  }
}

}  // namespace

PacsCommand addPacsCommand(CLI::App& app, std::ostream& out) {
  auto o = std::make_shared<PacsOptions>();
  CLI::App* cmd = app.add_subcommand("pacs", "list the patients, studies and series of a DICOMweb archive (QIDO-RS), with each series' address");
  cmd->add_option("root", o->root, "the archive's DICOMweb root, http(s)://HOST:PORT/ROOT (Orthanc: /dicom-web)");
  cmd->add_option("--patient", o->query.patient, "Patient Name to match (DICOM wildcards * and ?)");
  cmd->add_option("--study-date", o->query.studyDate, "Study Date: YYYYMMDD, or a range YYYYMMDD-YYYYMMDD (either end open)");
  cmd->add_option("--modality", o->query.modality, "modality of the series to list: CT, MR...");
  cmd->add_option("--pacs-auth-file", o->authFile,
                  "file whose first line is 'Bearer TOKEN' or 'USER:PASSWORD' (default: HYB_DICOMWEB_TOKEN or HYB_DICOMWEB_USER=USER:PASSWORD)");
  cmd->add_option("--timeout", o->timeout, "seconds without a byte from the archive before giving up")->capture_default_str();
  return {cmd, [o, &out] {
            if (const std::string e = o->validate(); !e.empty()) throw ValueError(e);
            DicomWebOptions options;
            options.authFile = o->authFile;
            options.stallSeconds = o->timeout;
            printListing(o->root, queryDicomWeb(o->root, o->query, options), out);
            return 0;
          }};
}

}  // namespace hyb::app
