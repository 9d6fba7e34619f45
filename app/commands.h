// The subcommands of the tinbuild executable.  Each parses its arguments into an options struct and
// calls one library entry point; main() maps exceptions to exit codes.
#pragma once

#include <string>
#include <vector>

#include "app/cli.h"

namespace tinbuild::app {

struct Command {
  std::string name;
  std::string synopsis;
  std::string summary;      // one line for `tinbuild help`
  std::string description;  // paragraph for `tinbuild help COMMAND`
  std::vector<cli::OptionSpec> options;
  int (*run)(const cli::ParsedArgs& args);
};

const std::vector<Command>& commands();

Command infoCommand();
Command demoCommand();
Command benchCommand();
Command finalizeCommand();
Command triangulateCommand();
Command buildCommand();
Command planCommand();
Command mergeCommand();
Command verifyCommand();
Command tetrahedralizeCommand();
Command hydrologyCommand();

}  // namespace tinbuild::app
namespace tinbuild {
struct PipelineOptions;
struct HydrologyOptions;
}
namespace tinbuild::app {
// `tinbuild verify` on a tetrahedral mesh (app/cmd_tetrahedralize.cpp): exit code 0 when it holds.
int verifyTetMesh(const std::string& mesh, const std::vector<std::string>& points, const PipelineOptions& o,
                  bool json);
// `tinbuild finalize --3d` (app/cmd_tetrahedralize.cpp): the 3D finalized stream.
int runFinalize3dCommand(const cli::ParsedArgs& args);
// `tinbuild hydrology` and `build --hydrology` (app/cmd_hydrology.cpp): the run in a frame of its own.
struct RunSettings;
int runHydrologyJob(HydrologyOptions o, const RunSettings& rs);

}  // namespace tinbuild::app
