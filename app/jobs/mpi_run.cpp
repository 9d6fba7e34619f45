// `tinbuild build --mpi` (header).
#include "app/jobs/mpi_run.h"

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "app/jobs/run_outputs.h"
#include "formats/io/output_file.h"
#include "formats/io/output_transaction.h"
#include "libterrain/core/error.h"

#ifdef TINBUILD_HAVE_MPI
#include <mpi.h>
#include <unistd.h>
#endif

namespace tinbuild {

int mpiRankFromEnvironment() {
  for (const char* name : {"OMPI_COMM_WORLD_RANK", "PMIX_RANK", "PMI_RANK", "MV2_COMM_WORLD_RANK", "SLURM_PROCID"})
    if (const char* v = std::getenv(name))
      if (*v) return std::atoi(v);
  return -1;
}

namespace fs = std::filesystem;

#ifndef TINBUILD_HAVE_MPI

bool mpiAvailable() {
  return false;
}

RunReport runMpiBuild(const PipelineOptions&, const std::vector<std::string>&, const std::string&, Diagnostics&) {
  throw UsageError(
      "--mpi: this tinbuild was built without MPI; install Open MPI (Debian: libopenmpi-dev openmpi-bin, "
      "share/install-deps.sh does) and rebuild, or use tinbuild plan / build --plan --part / merge");
}

#else

bool mpiAvailable() {
  return true;
}

namespace {

std::string readWhole(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

void writeWhole(const std::string& path, const std::string& bytes) {
  OutputFile f(path, std::max<std::size_t>(bytes.size(), 16));
  f.write(bytes);
  f.commit();
}

// Runs `step` on every rank; if it failed anywhere, every rank throws an Error naming each failure (the
// ranks' messages are gathered), so all of them stop together and exit non-zero.  A cancellation
// (SIGTERM or SIGINT, which mpirun forwards to every rank) anywhere is a cancellation everywhere: every
// rank throws CancelledError, so the run exits 3 as a single process does.
template <class Step>
void collective(int rank, int size, const std::string& what, Step step) {
  std::string message;
  int cancelled = 0;
  try {
    step();
  } catch (const CancelledError&) {
    cancelled = 1;
    message = "cancelled";
  } catch (const std::exception& e) {
    message = e.what();
    if (message.empty()) message = "failed";
  }
  MPI_Allreduce(MPI_IN_PLACE, &cancelled, 1, MPI_INT, MPI_MAX, MPI_COMM_WORLD);
  if (cancelled) throw CancelledError();
  int length = static_cast<int>(message.size());
  std::vector<int> lengths(static_cast<std::size_t>(size));
  MPI_Allgather(&length, 1, MPI_INT, lengths.data(), 1, MPI_INT, MPI_COMM_WORLD);
  std::vector<int> offsets(static_cast<std::size_t>(size), 0);
  int total = 0;
  for (int i = 0; i < size; ++i) {
    offsets[static_cast<std::size_t>(i)] = total;
    total += lengths[static_cast<std::size_t>(i)];
  }
  if (total == 0) return;
  std::string all(static_cast<std::size_t>(total), '\0');
  MPI_Allgatherv(message.data(), length, MPI_CHAR, all.data(), lengths.data(), offsets.data(), MPI_CHAR,
                 MPI_COMM_WORLD);
  std::string report;
  for (int i = 0; i < size; ++i) {
    if (lengths[static_cast<std::size_t>(i)] == 0) continue;
    if (!report.empty()) report += "; ";
    report += what + " " + std::to_string(i) + " (rank " + std::to_string(i) + ") failed: " +
              all.substr(static_cast<std::size_t>(offsets[static_cast<std::size_t>(i)]),
                         static_cast<std::size_t>(lengths[static_cast<std::size_t>(i)]));
  }
  (void)rank;
  throw Error(report);
}

// An MPI run's steps read what the step before wrote, under its final name: the output transaction (if
// any) commits each step's files.  A run stopped later keeps the part files and the plan state it
// committed (a re-run replaces them); the merge's outputs still appear all at once, at the end.
void commitStep() {
  if (OutputTransaction* t = OutputTransaction::current()) t->commit();
}

constexpr std::uint64_t kChunk = std::uint64_t{1} << 28;

void sendBytes(const std::string& bytes, int to, int tag) {
  const std::uint64_t n = bytes.size();
  MPI_Send(&n, 1, MPI_UINT64_T, to, tag, MPI_COMM_WORLD);
  for (std::uint64_t at = 0; at < n; at += kChunk)
    MPI_Send(bytes.data() + at, static_cast<int>(std::min(kChunk, n - at)), MPI_CHAR, to, tag, MPI_COMM_WORLD);
}

std::string receiveBytes(int from, int tag) {
  std::uint64_t n = 0;
  MPI_Recv(&n, 1, MPI_UINT64_T, from, tag, MPI_COMM_WORLD, MPI_STATUS_IGNORE);
  std::string bytes(n, '\0');
  for (std::uint64_t at = 0; at < n; at += kChunk)
    MPI_Recv(bytes.data() + at, static_cast<int>(std::min(kChunk, n - at)), MPI_CHAR, from, tag, MPI_COMM_WORLD,
             MPI_STATUS_IGNORE);
  return bytes;
}

// A private temporary directory for a rank's state (rank 0 keeps its state beside the outputs).
std::string makeLocalDir(int rank) {
  if (rank == 0) return "";
  const char* tmp = std::getenv("TMPDIR");
  std::string t = std::string(tmp && *tmp ? tmp : "/tmp") + "/tinbuild-mpi-XXXXXX";
  std::vector<char> buf(t.begin(), t.end());
  buf.push_back('\0');
  if (!::mkdtemp(buf.data())) throw Error(t + ": cannot create a temporary directory: " + std::strerror(errno));
  return buf.data();
}

// The sums of the plan's counts over the ranks.  A rank whose counting failed says so in counts.error;
// then every rank throws, naming each failure (no rank is left waiting in a collective call).
class MpiReducer : public PlanReducer {
 public:
  MpiReducer(int rank, int size) : rank_(rank), size_(size) {}
  int slice() const override { return rank_; }
  int slices() const override { return size_; }
  std::uint64_t bytes() const { return bytes_; }
  void reduce(PlanCounts& c) override {
    const std::string error = c.error;
    collective(rank_, size_, "plan on rank", [&] {
      if (!error.empty()) throw Error(error);
    });
    double mins[3] = {c.bounds.minX, c.bounds.minY, c.bounds.minZ}, maxs[3] = {c.bounds.maxX, c.bounds.maxY, c.bounds.maxZ};
    MPI_Allreduce(MPI_IN_PLACE, mins, 3, MPI_DOUBLE, MPI_MIN, MPI_COMM_WORLD);
    MPI_Allreduce(MPI_IN_PLACE, maxs, 3, MPI_DOUBLE, MPI_MAX, MPI_COMM_WORLD);
    c.bounds.minX = mins[0];
    c.bounds.minY = mins[1];
    c.bounds.minZ = mins[2];
    c.bounds.maxX = maxs[0];
    c.bounds.maxY = maxs[1];
    c.bounds.maxZ = maxs[2];
    if (!c.segMin.empty()) {
      MPI_Allreduce(MPI_IN_PLACE, c.segMin.data(), static_cast<int>(c.segMin.size()), MPI_DOUBLE, MPI_MIN, MPI_COMM_WORLD);
      MPI_Allreduce(MPI_IN_PLACE, c.segMax.data(), static_cast<int>(c.segMax.size()), MPI_DOUBLE, MPI_MAX, MPI_COMM_WORLD);
      bytes_ += (c.segMin.size() + c.segMax.size()) * 8;
    }
    FilterCounts& f = c.filter;
    std::vector<std::uint64_t> v{c.points};
    f.forEachCounter([&v](std::uint64_t& x) { v.push_back(x); });
    v.insert(v.end(), c.regions.begin(), c.regions.end());
    bytes_ += (v.size() + 6) * 8;
    MPI_Allreduce(MPI_IN_PLACE, v.data(), static_cast<int>(v.size()), MPI_UINT64_T, MPI_SUM, MPI_COMM_WORLD);
    std::size_t k = 0;
    c.points = v[k++];
    f.forEachCounter([&](std::uint64_t& x) { x = v[k++]; });
    for (std::uint64_t& x : c.regions) x = v[k++];
  }

 private:
  int rank_, size_;
  std::uint64_t bytes_ = 0;  // this rank's contributions to the sums
};

// Finalizes MPI on the way out, whatever happens.
struct MpiSession {
  int rank = 0, size = 1;
  bool owned = false;
  MpiSession() {
    int initialized = 0;
    MPI_Initialized(&initialized);
    if (!initialized) {
      MPI_Init(nullptr, nullptr);
      owned = true;
    }
    MPI_Comm_rank(MPI_COMM_WORLD, &rank);
    MPI_Comm_size(MPI_COMM_WORLD, &size);
  }
  ~MpiSession() {
    if (owned) MPI_Finalize();
  }
};

}  // namespace

RunReport runMpiBuild(const PipelineOptions& options, const std::vector<std::string>& buildArgs,
                      const std::string& command, Diagnostics& diag) {
  const auto t0 = std::chrono::steady_clock::now();
  MpiSession mpi;
  const int rank = mpi.rank, size = mpi.size;
  {
    const RunOutputs outputs = resolveOutputs(options);
    checkPlannedOutputs(outputs);
    checkOutputOwnership(options, outputs);
    refusePlannedOutputs(options, outputs, size);  // (every rank sees the same files: all refuse alike)
  }
  // Rank 0's plan and state sit beside the first output (the file system all ranks share); the other
  // ranks keep their state in a temporary directory of their own until they send it.
  const std::string anchor = !options.meshOutput.empty() ? options.meshOutput : options.dem.path;
  fs::path sharedBase = fs::path(anchor);
  if (sharedBase.has_filename() && sharedBase.filename() != ".") {
  } else {
    sharedBase = sharedBase.parent_path();
  }
  std::string base = sharedBase.string();
  while (base.size() > 1 && base.back() == '/') base.pop_back();
  const std::string rootPlanPath = base + ".mpi-plan.json";
  std::string localDir;
  Plan plan;
  plan.buildArgs = buildArgs;
  plan.command = command;
  RunReport planReport;
  std::uint64_t exchanged = 0;

  using Clock = std::chrono::steady_clock;
  auto since = [](Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); };
  // 1. The plan.  Every rank counts a slice of the survey and the counts are summed (MPI_Allreduce), so
  // the plan reads the survey once in all, not once on rank 0; a COPC survey is planned by rank 0's
  // finalizer (one process lays its grid on the octree) and broadcast.
  const auto tPlan = Clock::now();
  bool sliced = false;
  // Each rank opens the survey once to plan (its part, read through the part's window, opens it again:
  // a reader restricted to a window is another reader).
  Survey survey;
  collective(rank, size, "plan on rank", [&] {
    localDir = makeLocalDir(rank);
    survey = openSurvey(options, diag, /*needIntensity=*/false);
    sliced = planInSlices(survey);
  });
  if (sliced) {
    MpiReducer reducer(rank, size);
    PipelineOptions po = options;
    po.overwrite = true;
    plan.path = rank == 0 ? rootPlanPath : localDir + "/plan.json";
    planReport = runPlanInSlices(po, survey, size, plan, diag, reducer);  // (its errors reach every rank)
    exchanged += 2 * reducer.bytes();  // (halved with the rest below: counted as sent, not also received)
    collective(rank, size, "plan on rank", [&] {
      writePlan(plan, plan.path);
      commitStep();
    });
  } else {
    collective(rank, size, "plan on rank", [&] {
      if (rank != 0) return;
      PipelineOptions po = options;
      po.overwrite = true;
      plan.path = rootPlanPath;
      planReport = runPlan(po, survey, size, plan, diag);
      commitStep();
    });
    std::string planText = rank == 0 ? readWhole(rootPlanPath) : std::string();
    std::uint64_t planBytes = planText.size();
    MPI_Bcast(&planBytes, 1, MPI_UINT64_T, 0, MPI_COMM_WORLD);
    planText.resize(planBytes);
    MPI_Bcast(planText.data(), static_cast<int>(planBytes), MPI_CHAR, 0, MPI_COMM_WORLD);
    exchanged += planBytes * static_cast<std::uint64_t>(size - 1) * (rank == 0 ? 1 : 0) * 2;
    collective(rank, size, "plan copy on rank", [&] {
      if (rank == 0) {
        plan = readPlan(rootPlanPath);
        return;
      }
      const std::string path = localDir + "/plan.json";
      writeWhole(path, planText);
      commitStep();
      plan = readPlan(path);
    });
  }

  commitStep();  // (the plan's files, for the next step to read)
  survey = Survey();  // (its readers are done with)
  const double planSeconds = since(tPlan);
  // 2. Every rank its part.
  const auto tPart = Clock::now();
  RunReport partReport;
  collective(rank, size, "part", [&] {
    PipelineOptions po = options;
    po.plan = &plan;
    po.part = rank;
    po.commandLine = plan.command;
    partReport = runBuild(po, diag);
    commitStep();  // the part's files, which the exchange and the merge read
  });

  double partSeconds = since(tPart);
  // 3. Seam files, DEM pieces and part records to rank 0.
  const char* kinds[] = {"seam", "dem", "json"};
  collective(rank, size, "exchange from rank", [&] {
    for (int from = 1; from < size; ++from)
      for (int k = 0; k < 3; ++k) {
        const int tag = 100 + k;
        if (rank == from) {
          const std::string path = plan.partFile(rank, kinds[k]);
          std::error_code ec;
          const bool present = fs::exists(path, ec);
          std::string bytes = present ? readWhole(path) : std::string();
          const std::uint64_t flag = present ? 1 : 0;
          MPI_Send(&flag, 1, MPI_UINT64_T, 0, tag, MPI_COMM_WORLD);
          if (present) sendBytes(bytes, 0, tag);
          exchanged += bytes.size();
        } else if (rank == 0) {
          std::uint64_t flag = 0;
          MPI_Recv(&flag, 1, MPI_UINT64_T, from, tag, MPI_COMM_WORLD, MPI_STATUS_IGNORE);
          if (!flag) continue;
          const std::string bytes = receiveBytes(from, tag);
          writeWhole(plan.partFile(from, kinds[k]), bytes);
          exchanged += bytes.size();
        }
      }
  });
  collective(rank, size, "commit on rank", [&] { commitStep(); });  // rank 0: the files it received
  if (!localDir.empty()) {
    std::error_code ec;
    fs::remove_all(localDir, ec);
  }

  // 4. The merge on rank 0.
  const auto tMerge = Clock::now();
  RunReport merged;
  collective(rank, size, "merge on rank", [&] {
    if (rank != 0) return;
    PipelineOptions mo = options;
    mo.commandLine = plan.command;  // the parts' tiles record the plan's command: so do the merge's
    merged = runMerge(mo, plan, diag);
  });
  const double mergeSeconds = since(tMerge);
  std::vector<double> partTimes(static_cast<std::size_t>(size));
  MPI_Gather(&partSeconds, 1, MPI_DOUBLE, partTimes.data(), 1, MPI_DOUBLE, 0, MPI_COMM_WORLD);
  std::uint64_t peak = peakRssBytes();
  std::vector<std::uint64_t> peaks(static_cast<std::size_t>(size));
  MPI_Gather(&peak, 1, MPI_UINT64_T, peaks.data(), 1, MPI_UINT64_T, 0, MPI_COMM_WORLD);
  std::uint64_t exchangedAll = 0;
  MPI_Reduce(&exchanged, &exchangedAll, 1, MPI_UINT64_T, MPI_SUM, 0, MPI_COMM_WORLD);
  if (rank != 0) {
    partReport.command = "build --mpi";
    partReport.secondaryRank = true;
    return partReport;
  }
  std::error_code ec;
  fs::remove_all(plan.stateDir(), ec);
  fs::remove(rootPlanPath, ec);
  merged.command = "build --mpi";
  merged.inputs = options.inputs;
  merged.finalizer = planReport.finalizer;
  merged.haveFinalizer = planReport.haveFinalizer;
  merged.rankPeakRss = peaks;
  merged.rankPartSeconds = partTimes;
  merged.planSeconds = planSeconds;
  merged.mergeSeconds = mergeSeconds;
  merged.exchangedBytes = exchangedAll / 2;  // each byte was counted by its sender and its receiver
  merged.planPath.clear();
  // Rank 0's own part's outputs, then the merge's.
  std::vector<std::string> outputs = partReport.outputs;
  outputs.insert(outputs.end(), merged.outputs.begin(), merged.outputs.end());
  merged.outputs = outputs;
  merged.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return merged;
}

#endif

}  // namespace tinbuild
