// A run's outputs as one transaction: all of them appear under their final names, or none does.
//
// Every writer writes under a temporary name beside its target (formats/io/output_file.h).  Without a
// transaction it renames that into place when it finishes (library callers, tests).  While a transaction
// is current, a writer's finishing rename goes to the transaction instead (commitRename): nothing is
// renamed until the whole run is done, and then commit() renames everything in one short, ordered step:
//   1. a journal listing every rename is written (and synced) beside each output the run locked;
//   2. the renames, in the order the writers finished (the report, staged last, comes last);
//   3. the post-commit steps (a DEM directory's staging folder removed; with --overwrite, the stale tiles
//      of an earlier run removed), then the journals.
// A transaction destroyed without commit() (an error, a cancellation, an exception unwinding) removes
// every temporary it staged: no output appears under its final name.  A run killed inside step 2 (SIGKILL,
// a power cut: nothing else can stop it there, it neither reads nor computes) leaves a journal; the next
// run that locks one of those outputs finds it and finishes the renames (rollForwardJournals), so the
// earlier run's result becomes whole, and the new run then replaces it or is refused as usual.
//
// Claims.  A transaction writes only what its run claimed (app/jobs/output_claim.h: the one place where a
// command's outputs are checked against its inputs, locked and refused when they exist): a staged rename
// whose final name is neither claimed nor inside a claimed directory is an internal error, and so is any
// finishing rename while the process requires transactions (the CLI: every command runs inside one) but
// none is current.  So a command that writes without going through the contract fails its first test.
// Folders the run created for its outputs (createParentDirectories) are removed again, when empty, if the
// transaction is rolled back.
//
// Threads: writers on any thread may stage; commit() and the destructor run on the thread that made the
// transaction.  One transaction is current per process at a time.
#pragma once

#include <cstdint>
#include <functional>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

#include "formats/io/run_lock.h"

namespace tinbuild {

class OutputTransaction {
 public:
  OutputTransaction();
  ~OutputTransaction();
  OutputTransaction(const OutputTransaction&) = delete;
  OutputTransaction& operator=(const OutputTransaction&) = delete;

  // The transaction writers stage into; nullptr when none.
  static OutputTransaction* current();

  // Records that `temp` becomes `final` at the commit.
  void stage(const std::string& temp, const std::string& final);
  // The run may write `path` (a file), or anything inside `dir`.
  void claim(const std::string& path);
  void claimDirectory(const std::string& dir);
  // Whether `final` was claimed (by name, or inside a claimed directory).
  bool claims(const std::string& final) const;
  // A folder createParentDirectories made for this run's outputs (removed on roll-back when empty).
  void createdDirectory(const std::string& dir);
  // The folders of this run a roll-back could not remove because something was still in them (another
  // process's files of the same run, under MPI), deepest first; the caller tries again once every process
  // has rolled back.  Taken: the list is then empty.
  std::vector<std::string> takeLeftoverDirectories();

  // A step to run after the renames (and never when the transaction is rolled back); `undo` (optional) runs
  // instead when it is rolled back.
  void afterCommit(std::function<void()> step, std::function<void()> undo = nullptr);
  // A step to run if the transaction is rolled back, whatever was committed provisionally before (an
  // afterCommit step is done, and its undo forgotten, at the next provisional commit); forgotten at commit().
  void onRollback(std::function<void()> undo);
  // Holds a lock of the run's until the transaction ends; journals go beside the locked paths.
  void adopt(RunLock lock, const std::vector<std::string>& lockedPaths);
  // The staged temporary of `final` ("" when none).
  std::string stagedTemp(const std::string& final) const;

  // Renames everything staged so far into place (see the header).  DataError naming the output when a
  // rename fails (the journal then stays, and the next run finishes the commit).  What is staged after a
  // commit is rolled back unless committed too.
  void commit();
  // The same renames, for a later step of the run to read the files under their names (an MPI run's part
  // files, which other processes read), but provisionally: if the transaction is then rolled back (an
  // error, a cancellation), these files are removed again, so a stopped run leaves none of them.  Only
  // commit() makes them the run's for good.  (A run killed outright leaves them: docs/usage.md.)
  void commitProvisionally();
  // The files committed provisionally so far are the run's for good: a later roll-back leaves them (an MPI
  // run's finished parts, which the same command run again reuses: app/jobs/part_job.h).
  void keepProvisional();
  // Rolls back now what the destructor would (staged temporaries, provisional files, undo steps) and
  // releases the run's locks; the transaction is then empty.  An MPI rank calls it before MPI_Finalize,
  // whose fence holds every rank until all have cleaned up: mpirun stops the whole job at the first rank
  // that exits non-zero, and would otherwise kill a slower rank in the middle of its cleanup.
  void rollback();
  std::size_t stagedCount() const;

 private:
  mutable std::mutex mutex_;
  void commitLocked();
  std::vector<std::pair<std::string, std::string>> renames_;  // (temp, final) in staging order
  std::vector<std::string> provisional_;                      // renamed by commitProvisionally()
  std::vector<std::pair<std::function<void()>, std::function<void()>>> after_;
  std::vector<std::function<void()>> onRollback_;
  std::vector<RunLock> locks_;
  std::vector<std::string> lockedPaths_;
  std::vector<std::string> claimedFiles_, claimedDirs_;  // absolute, normalized
  std::vector<std::string> createdDirs_;                 // in creation order (parents first)
  std::vector<std::string> leftoverDirs_;                // roll-back: not empty then (deepest first)
  OutputTransaction* previous_ = nullptr;
};

// A writer's finishing rename: staged in the current transaction, or done at once when there is none.
// DataError naming `final` when the rename fails; Error when `final` is not the run's (see Claims above).
void commitRename(const std::string& temp, const std::string& final);

// A test hook for the fault-injection tests: with TINBUILD_FAULT_SIGNAL=NAME in the environment the process
// sends itself SIGTERM the first time it reaches the point NAME -- "output" (its first temporary output file
// created: the work under way), "commit" (the commit's start, after the work) -- so that a signal at those
// moments is tested without depending on the machine's speed.
void faultPoint(const char* name);

// The CLI's promise that every command runs inside a transaction: from then on a finishing rename with no
// transaction current is an internal error (library callers, the tests, keep renaming at once).
void requireOutputTransactions();

// The size of an output by its final name: its staged temporary's while a transaction holds it.
std::uint64_t outputSize(const std::string& final);
// Whether an output exists by its final name, or is staged under it.
bool outputExists(const std::string& final);
// Where an output can be read now: its staged temporary while a transaction holds it, else its name (a
// merge reads back the manifest and the seam mesh it has just written, before they are committed).
std::string readablePath(const std::string& final);

// Finishes the commit of a run that died inside it, from the journal beside `path` (call while holding
// `path`'s lock).  Returns the number of renames it finished.
int rollForwardJournal(const std::string& path);

}  // namespace tinbuild
