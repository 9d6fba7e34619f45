// The tinbuild executable: a launcher that takes SIGINT and SIGTERM before anything else runs, then loads
// the program (tinbuild-app.so beside it) and calls it.
//
// Why a launcher: the program links GDAL, PROJ, GeographicLib, SQLite, NetCDF and their ~110 libraries.
// The dynamic loader maps and relocates them and runs their static initializers before main(), which takes
// 30-40 ms here and more on a loaded machine; a SIGTERM in that window (a batch system stopping a job that
// has just started) took the default action, exit 143, instead of a cancellation's exit 3.  This file
// links only the C library: its handler is in place from the process's first instructions.  Nothing has
// been written until the program installs its own handler (app/progress_display.cpp), so a signal before
// then ends the process at once with exit 3.  The program's handler replaces this one atomically.
#include <dlfcn.h>
#include <limits.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

namespace {

void earlySignal(int) {
  static const char message[] = "tinbuild: cancelled\n";
  (void)!::write(STDERR_FILENO, message, sizeof message - 1);
  ::_exit(3);
}

}  // namespace

int main(int argc, char** argv) {
  struct sigaction sa;
  ::memset(&sa, 0, sizeof sa);
  sa.sa_handler = earlySignal;
  ::sigemptyset(&sa.sa_mask);
  ::sigaction(SIGINT, &sa, nullptr);
  ::sigaction(SIGTERM, &sa, nullptr);
  ::sigaction(SIGUSR2, &sa, nullptr);  // (a stop request too: what mpirun forwards, see progress_display.cpp)
  // A parent may have blocked them (the mask is inherited across exec): a stop request must still arrive.
  sigset_t stops;
  ::sigemptyset(&stops);
  ::sigaddset(&stops, SIGINT);
  ::sigaddset(&stops, SIGTERM);
  ::sigaddset(&stops, SIGUSR2);
  ::sigprocmask(SIG_UNBLOCK, &stops, nullptr);

  // The program beside this executable (TINBUILD_APP_MODULE names another, for tests of the launcher).
  char path[PATH_MAX];
  const char* module = ::getenv("TINBUILD_APP_MODULE");
  if (!module) {
    const ssize_t n = ::readlink("/proc/self/exe", path, sizeof path - 32);
    if (n <= 0) {
      ::fprintf(stderr, "tinbuild: error: cannot find the executable's folder (/proc/self/exe)\n");
      return 1;
    }
    path[n] = '\0';
    char* slash = ::strrchr(path, '/');
    ::strcpy(slash ? slash + 1 : path, "tinbuild-app.so");
    module = path;
  }
  void* program = ::dlopen(module, RTLD_NOW | RTLD_LOCAL);
  if (!program) {
    ::fprintf(stderr, "tinbuild: error: %s: cannot load the program: %s\n", module, ::dlerror());
    return 1;
  }
  using Main = int (*)(int, char**);
  const auto run = reinterpret_cast<Main>(::dlsym(program, "tinbuild_main"));
  if (!run) {
    ::fprintf(stderr, "tinbuild: error: %s: not tinbuild's program (no tinbuild_main)\n", module);
    return 1;
  }
  return run(argc, argv);
}
