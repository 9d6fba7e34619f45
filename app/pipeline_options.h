// The options of the pipeline commands (build, plan, finalize, triangulate, merge, verify), each declared
// once in app/pipeline_options.cpp with its binding and checks, and the build's rules between options.
// `tinbuild demo` parses its build from words with the same table.
#pragma once

#include <bitset>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "app/cli.h"
#include "app/jobs/pipeline.h"
#include "app/option_table.h"

namespace tinbuild::app {

// How to run a job: the values of the run-only options, which the outputs never record.
struct RunSettings {
  std::string report;                           // --report FILE.json
  std::string progress;                         // --progress MODE ("" = auto)
  bool quiet = false;                           // -q
  int threads = 0;                              // --threads (0: the machine's cores)
  bool overwrite = false;                       // --overwrite
  std::string output;                           // -o (finalize, triangulate, plan, merge)
  bool mpi = false;                             // build --mpi
  std::string plan;                             // build --plan PLAN.json
  int part = -1;                                // build --part I
  int parts = 0;                                // plan --parts N
  std::optional<std::uint64_t> segmentRecords;  // plan --segment-records N
  std::vector<std::string> points;              // verify --points INPUT (each)
  bool json = false;                            // verify --json
  std::optional<std::string> tempDir;           // --temp-dir DIR (a part of a plan takes its own)
  std::string hydrology;                        // build --hydrology DIR
  std::string streamArea;                       // build --stream-area A
  std::optional<double> stage;                  // build --stage H
};

// What a pipeline command's options bind to.
struct PipelineArgs {
  PipelineOptions options;
  RunSettings run;
  std::optional<std::bitset<256>> contourClasses;  // --contour-class: checked against the TIN's classes
};

using PipelineTable = cli::OptionTable<PipelineArgs>;

const PipelineTable& buildTable();
const PipelineTable& planTable();
const PipelineTable& finalizeTable();
const PipelineTable& tetrahedralizeTable();  // finalize's inputs, a mesh output, --region-level, --slabs (3D)
const PipelineTable& triangulateTable();
const PipelineTable& mergeTable();
const PipelineTable& verifyTable();

// "-" (stdout) on a terminal: a UsageError naming the command.
void refuseBinaryToTerminal(const std::string& output, const char* command);

// A build's (or plan's) arguments, parsed with `table`: the inputs expanded, every option bound and
// checked, then the rules between options.
PipelineArgs parseBuildArgs(const cli::ParsedArgs& args, const PipelineTable& table = buildTable());

// The build as its outputs record it: "tinbuild build", the inputs as typed, then the options that shape
// the outputs in the table's order -- not -q, --threads, --report and the like, which change how it runs,
// not what it makes.  So one process, the parts of a plan and the ranks of an MPI run that make the same
// DEM record the same command, and their files are the same bytes.
std::string recordedCommand(const cli::ParsedArgs& args, const PipelineTable& table = buildTable());

// A plan's build: the inputs as expanded (every part reads the same files), then the recorded options.
std::vector<std::string> planBuildArgs(const cli::ParsedArgs& args, const PipelineOptions& o,
                                       const PipelineTable& table);

// A plan's build options, parsed as `build` parses them.
PipelineOptions planOptions(const Plan& plan);

// A build given as the words a user would type after `tinbuild build`, parsed by the build's table; its
// recorded command is those words in their order, without the run-only ones (the demo's build).
PipelineArgs parseBuildWords(const std::vector<std::string>& words);

}  // namespace tinbuild::app
