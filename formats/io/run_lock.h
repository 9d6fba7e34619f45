// Outputs owned by one run at a time.
//
// Two runs writing the same outputs at once would leave a mixture of both (tiles of one survey in the
// other's DEM folder, a mesh from one and a report from the other), each exiting 0.  So a run takes a
// lock on every output it writes before any work and holds it to the end: the second run fails at once,
// naming the output and the holder (its process id, host, start time and command), and writes nothing.
//
// The lock of PATH is the file `.NAME.tinbuild-lock` beside it (NAME: PATH's file or folder name), held
// with flock(2), which the kernel releases when the process dies in any way (SIGKILL included), so a lock
// is never stale.  The file records the holder for the message.  It is removed when the run ends; a run
// that takes a lock checks that the file it locked is still the one at that name (a run that ended may
// have removed it meanwhile), and takes the new one otherwise.
//
// Holding the lock of PATH is what makes the temporaries beside PATH (PATH.tmp-...) of any other run dead:
// no live run can own them (removeStaleTemporaries).  Network file systems: flock works on NFS v4 and most
// cluster file systems (Lustre with -o flock, GPFS); on one mounted without locking, taking the lock fails
// with a message saying so.
#pragma once

#include <string>
#include <vector>

namespace tinbuild {

class RunLock {
 public:
  RunLock() = default;
  // Locks every path (empty ones, "-" and devices are skipped; parents are created); DataError naming the
  // path and the holder when another run holds one (the locks taken so far are released).
  explicit RunLock(const std::vector<std::string>& paths, const std::string& command = "");
  ~RunLock();
  RunLock(RunLock&& other) noexcept;
  RunLock& operator=(RunLock&& other) noexcept;
  RunLock(const RunLock&) = delete;
  RunLock& operator=(const RunLock&) = delete;

  // The lock file of PATH.
  static std::string lockPath(const std::string& path);

 private:
  void lockAll(const std::vector<std::string>& paths, const std::string& holder);
  void release() noexcept;
  struct Held {
    std::string lockFile;
    int fd = -1;
  };
  std::vector<Held> held_;
};

// Removes the temporaries that runs which died left beside PATH (PATH.tmp-*, files or folders).  Call it
// only while holding PATH's lock.  Returns how many it removed.
int removeStaleTemporaries(const std::string& path);

}  // namespace tinbuild
