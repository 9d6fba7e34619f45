// The output contract: the one place where a command's outputs become its own.
//
// Every command that writes a file says here, once and before any work, what it writes and what it reads:
// claimOutputs() then
//   1. checks ownership: every output (and every file it names) is distinct from the others, from the
//      paths claimed elsewhere in the run (the report), and from every input -- by name, through a symbolic
//      link (paths are compared resolved) and by device and inode (a hard link); no output and no input lies
//      inside an output directory (a DEM tile directory, the demo's folder);
//   2. locks the outputs for the run (formats/io/run_lock.h: a second run on them fails at once, naming the
//      holder), finishes the commit of a run that died inside one (its journal) and removes the
//      temporaries dead runs left beside them;
//   3. refuses an output that exists, without --overwrite;
//   4. registers the claims with the current output transaction (formats/io/output_transaction.h), which
//      refuses to commit any file that was not claimed -- so a command that writes around this contract
//      fails at its first run, and the CLI runs every command inside a transaction (app/command_run.h).
// The order matters: ownership first, so that `--report INPUT` is "is an input of this run", never
// "exists; pass --overwrite" (which would invite the user to destroy the input).
#pragma once

#include <string>
#include <utility>
#include <vector>

#include "formats/io/run_lock.h"

namespace tinbuild {

struct OutputClaim {
  std::string option;              // how the user named it, for messages: "--mesh", "-o", "--report"
  std::string path;                // as typed
  std::vector<std::string> files;  // more final names written for it: a sidecar .prj, TetGen's .node
  bool directory = false;  // a folder the run writes inside (a DEM tile directory, the demo's folder):
                           // refused when it holds anything, or when one of `files` exists
  bool lock = true;        // held for the run (a plan's parts share one DEM directory: not locked)
  bool refuse = true;      // an existing one is refused without --overwrite (a part's own state: not)

  OutputClaim() = default;
  OutputClaim(std::string opt, std::string p, std::vector<std::string> more = {})
      : option(std::move(opt)), path(std::move(p)), files(std::move(more)) {}
  OutputClaim& folder() { return directory = true, *this; }
  OutputClaim& unlocked() { return lock = false, *this; }
  OutputClaim& rewritten() { return refuse = false, *this; }  // the run's own state, replaced when run again
};

struct ClaimSet {
  std::vector<OutputClaim> outputs;
  // (what names it, path): read by the run, never written, never inside an output directory.
  std::vector<std::pair<std::string, std::string>> inputs;
  // (option, path): written by the run but claimed elsewhere (the report, by the CLI): only kept distinct.
  std::vector<std::pair<std::string, std::string>> others;
  bool overwrite = false;
  std::string commandLine;  // recorded in the lock files, for the message a second run gets
};

// Claims the set (see the header).  UsageError for an output onto an input or onto another output,
// DataError naming the file for an existing output or one held by another run.  While an output
// transaction is current it holds the lock (the returned one is empty); otherwise the caller holds it.
RunLock claimOutputs(const ClaimSet& set);

// "-" (a standard stream) and devices are never claimed, locked or refused.
bool claimable(const std::string& path);

}  // namespace tinbuild
