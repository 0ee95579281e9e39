// `hybrid-octree pacs ROOT`: the patients, studies and series a DICOMweb archive holds (QIDO-RS),
// each series with the address that info, build, render, export and view read.
#pragma once

#include <functional>
#include <iosfwd>

namespace CLI {
class App;
}

namespace hyb::app {

/// The `pacs` subcommand added to @p app; run() lists what it found on @p out (call it when
/// cmd->parsed()). Returns 0; throws IoError / ValueError with one line for the archive's faults.
struct PacsCommand {
  CLI::App* cmd = nullptr;
  std::function<int()> run;
};
PacsCommand addPacsCommand(CLI::App& app, std::ostream& out);

}  // namespace hyb::app
