// The frame every command that writes files runs in: one output transaction for the whole command, the
// report claimed like any output, and the commit at the very end.
//
//   CommandFrame frame(settings, inputs);  // the transaction; --report claimed against the inputs
//   ... the job: claimOutputs()/claimRun() for its outputs, then the work ...
//   frame.commit(reportJson, progress);    // the report staged, the last cancellation check, the renames
//
// The CLI promises (requireOutputTransactions, in main) that every finishing rename happens inside such a
// frame and only for claimed files (app/jobs/output_claim.h), so a command that forgot the contract fails
// at its first run instead of writing around it.  A frame left without commit() (an error, a cancellation)
// rolls everything back: no file appears under its final name, and folders it created are removed.
#pragma once

#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "formats/io/output_file.h"
#include "formats/io/output_transaction.h"

namespace tinbuild::app {

struct RunSettings;

class CommandFrame {
 public:
  // `inputs`: (what names it, path) of every file the command reads; `reports`: false on the ranks of an
  // MPI run but the first (rank 0 reports for the run).
  CommandFrame(const RunSettings& settings, const std::vector<std::pair<std::string, std::string>>& inputs,
               bool reports = true);
  CommandFrame(const CommandFrame&) = delete;
  CommandFrame& operator=(const CommandFrame&) = delete;

  // Writes the report (when one was asked for and `report` is not empty), checks once more for a
  // cancellation (unless the run was `decided` collectively), then commits.  CancelledError when stopped.
  void commit(const std::string& report, int (*progress)(double, const char*, void*), void* progressData,
              bool decided = false);

 private:
  OutputTransaction transaction_;
  std::unique_ptr<OutputFile> report_;
};

}  // namespace tinbuild::app
