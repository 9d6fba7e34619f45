#include "app/command_frame.h"

#include "app/jobs/output_claim.h"
#include "app/pipeline_options.h"
#include "app/progress_display.h"
#include "libterrain/core/error.h"

namespace tinbuild::app {

CommandFrame::CommandFrame(const RunSettings& settings,
                           const std::vector<std::pair<std::string, std::string>>& inputs, bool reports) {
  installCancelHandlers();
  startWriting();
  if (settings.report.empty() || !reports) return;
  // The report is an output like any other: never an input (checked first, so that `--report INPUT` is
  // named as the input it is), locked, refused when it exists.  Its temporary is created now, so an
  // unwritable --report fails before any work.
  ClaimSet set;
  set.outputs = {OutputClaim("--report", settings.report)};
  set.inputs = inputs;
  set.overwrite = settings.overwrite;
  claimOutputs(set);
  report_ = std::make_unique<OutputFile>(settings.report);
}

void CommandFrame::commit(const std::string& report, int (*progress)(double, const char*, void*),
                          void* progressData, bool decided) {
  if (report_ && !report.empty()) {
    report_->write(report);
    report_->commit();  // (staged: renamed with the outputs, last)
  }
  // The last moment a cancellation stops the run: from here the commit is a few renames.  (An MPI run
  // decided this moment collectively, on every rank at once.)
  faultPoint("commit");
  if (!decided && progress && !progress(1.0, "committing outputs", progressData)) throw CancelledError();
  if (!decided && cancelRequested()) throw CancelledError();
  transaction_.commit();
}

}  // namespace tinbuild::app
