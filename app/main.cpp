// tinbuild: streaming LIDAR to TIN and DEM.  main() dispatches to a subcommand and maps exceptions to
// exit codes: 0 success, 1 data or runtime error, 2 usage error, 3 cancelled.
#include <malloc.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <iostream>
#include <new>

#include "app/commands.h"
#include "app/progress_display.h"
#include "app/version.h"
#include "formats/io/output_transaction.h"
#include "libterrain/core/error.h"

namespace {

void printOverview() {
  std::cout
      << "tinbuild " << TINBUILD_VERSION
      << ": streaming LIDAR (LAS/XYZ) to TIN and DEM\n\nusage: tinbuild COMMAND [ARGS...]\n\ncommands:\n";
  for (const auto& c : tinbuild::app::commands()) {
    std::string left = "  " + c.name;
    std::cout << left << std::string(left.size() < 14 ? 14 - left.size() : 1, ' ') << c.summary << "\n";
  }
  std::cout << "  help          this overview, or `tinbuild help COMMAND` for one command\n"
               "\nRun `tinbuild COMMAND --help` for a command's options.  Exit codes: 0 success, 1 data or\n"
               "runtime error, 2 usage error, 3 cancelled.\n";
}

const tinbuild::app::Command* findCommand(const std::string& name) {
  for (const auto& c : tinbuild::app::commands())
    if (c.name == name) return &c;
  return nullptr;
}

}  // namespace

static int runCommand(int argc, char** argv) {
  // First of all: a SIGTERM from a batch system that arrives while the process starts (GDAL and PROJ load)
  // is a cancellation like any other (exit 3), not the default action's death.
  tinbuild::app::installCancelHandlers();
  // Every command writes inside its CommandFrame (app/command_frame.h) and only what it claimed: a file
  // committed any other way is an internal error, not a silent clobber.
  tinbuild::requireOutputTransactions();
  std::vector<std::string> args(argv + 1, argv + argc);
  try {
    if (args.empty()) {
      printOverview();
      return 2;
    }
    const std::string name = args[0];
    if (name == "--version" || name == "version") {
      std::cout << "tinbuild " << TINBUILD_VERSION << "\n";
      return 0;
    }
    if (name == "help" || name == "--help" || name == "-h") {
      if (args.size() > 1) {
        const auto* c = findCommand(args[1]);
        if (!c) throw tinbuild::UsageError("no such command '" + args[1] + "'");
        std::cout << tinbuild::cli::formatHelp(c->synopsis, c->description, c->options);
      } else {
        printOverview();
      }
      return 0;
    }
    const auto* c = findCommand(name);
    if (!c) throw tinbuild::UsageError("unknown command '" + name + "' (run `tinbuild help`)");
    std::vector<std::string> rest(args.begin() + 1, args.end());
    for (const auto& a : rest) {
      if (a == "--help" || a == "-h") {
        std::cout << tinbuild::cli::formatHelp(c->synopsis, c->description, c->options);
        return 0;
      }
    }
    auto parsed = tinbuild::cli::parseArgs(rest, c->options, c->name);
    parsed.commandLine = "tinbuild";
    for (const auto& a : args) parsed.commandLine += " " + a;
    return c->run(parsed);
  } catch (const tinbuild::UsageError& e) {
    std::cerr << "tinbuild: error: " << e.what() << "\n";
    return 2;
  } catch (const tinbuild::CancelledError&) {
    std::cerr << "tinbuild: cancelled\n";
    return 3;
  } catch (const tinbuild::Error& e) {
    std::cerr << "tinbuild: error: " << e.what() << "\n";
    return 1;
  } catch (const std::bad_alloc&) {
    std::cerr << "tinbuild: error: out of memory\n";
    return 1;
  } catch (const std::exception& e) {
    std::cerr << "tinbuild: error: " << e.what() << "\n";
    return 1;
  }
}

// Called by the launcher (app/launcher.cpp), which has taken SIGINT and SIGTERM already.
extern "C" __attribute__((visibility("default"))) int tinbuild_main(int argc, char** argv) {
  // Buffers of 128 KiB and more (chunks, queues, triangulator arrays, DEM blocks) come and go with the
  // stream's front.  glibc raises its mmap threshold each time such a buffer is freed, after which they
  // come from the heap and their pages stay with the process when freed: on a 10^8-point build that
  // was a fifth of the peak memory.  A fixed threshold keeps them mapped apart and given back on free.
  mallopt(M_MMAP_THRESHOLD, 128 * 1024);
  const int code = runCommand(argc, argv);
  // A run that failed or was cancelled has removed its temporaries and released its locks on the way
  // out (the stack unwound); the libraries' exit handlers are skipped, because one of them may crash
  // over the failure (HDF5 closes a NetCDF file again after a failed write), and a clear error must
  // stay a clear error with its exit code.
  if (code != 0) {
    std::cout.flush();
    std::cerr.flush();
    std::fflush(nullptr);
    std::_Exit(code);
  }
  return code;
}
