#include "app/commands.h"

namespace tinbuild::app {

const std::vector<Command>& commands() {
  static const std::vector<Command> all = {infoCommand(), demoCommand(), benchCommand(), finalizeCommand()};
  return all;
}

}  // namespace tinbuild::app
