#include "app/commands.h"

namespace tinbuild::app {

const std::vector<Command>& commands() {
  static const std::vector<Command> all = {infoCommand(),        buildCommand(),  finalizeCommand(),
                                           triangulateCommand(), verifyCommand(), demoCommand(),
                                           benchCommand()};
  return all;
}

}  // namespace tinbuild::app
