// Every job of app/jobs, for callers that run several (the CLI, the tests, the benchmarks).  Each job has
// a room of its own:
//   job_options.h   what a job is asked to do (PipelineOptions)
//   survey.h        the inputs, opened once per job, and the finalizer's options derived from them
//   run_outputs.h   the outputs, resolved once, with one writer context
//   build_job.h     finalize, triangulate, build (one process)
//   part_job.h      one part of a plan: the build wrapped
//   plan_job.h      planning a survey for parts
//   merge_job.h     merging the parts
//   tin_parts.h     a TIN in parts read, joined or described as one
//   verify_job.h    verify
//   run_report.h    what a job did, as a summary and as JSON
#pragma once

#include "app/jobs/build_job.h"
#include "app/jobs/job_options.h"
#include "app/jobs/merge_job.h"
#include "app/jobs/part_job.h"
#include "app/jobs/plan_job.h"
#include "app/jobs/run_outputs.h"
#include "app/jobs/run_report.h"
#include "app/jobs/survey.h"
#include "app/jobs/tin_parts.h"
#include "app/jobs/verify_job.h"
