#include "app/commands.h"

namespace tinbuild::app {

const std::vector<Command>& commands() {
  static const std::vector<Command> all = {infoCommand(),        buildCommand(),          finalizeCommand(),
                                           triangulateCommand(), tetrahedralizeCommand(), verifyCommand(),
                                           planCommand(),        mergeCommand(),          hydrologyCommand(),
                                           demoCommand(),        benchCommand()};
  return all;
}

}  // namespace tinbuild::app
