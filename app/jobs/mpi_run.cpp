// `tinbuild build --mpi` (header).
#include "app/jobs/mpi_run.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <sstream>
#include <thread>

#include "app/jobs/merge_job.h"
#include "app/jobs/part_job.h"
#include "app/jobs/run_outputs.h"
#include "formats/io/output_file.h"
#include "formats/io/output_transaction.h"
#include "formats/mesh/seam_file.h"
#include "libterrain/core/error.h"
#include "libterrain/finalizer/record_file_stream.h"
#include "libterrain/finalizer/regions.h"

#ifdef TINBUILD_HAVE_MPI
#include <dlfcn.h>
#include <unistd.h>

#include "app/jobs/mpi_api.h"
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

MpiScope::MpiScope(bool) {}
MpiScope::~MpiScope() = default;

HydrologyReport runMpiHydrology(HydrologyOptions, Diagnostics&) {
  throw UsageError(
      "--mpi: this tinbuild was built without MPI; install Open MPI (Debian: libopenmpi-dev openmpi-bin, "
      "share/install-deps.sh does) and rebuild, or run the hydrology in one process");
}

#else

bool mpiAvailable() {
  return true;
}

namespace {

// tinbuild-mpi.so (mpi_api.h), loaded on the first call: from $TINBUILD_MPI_MODULE when set, else beside
// the executable, else from ../lib/tinbuild beside it.  A module that cannot be loaded is a usage error
// naming the paths tried and the loader's reason.
const TinbuildMpiApi& mpi() {
  static const TinbuildMpiApi* api = [] {
    std::vector<std::string> tried;
    if (const char* env = std::getenv("TINBUILD_MPI_MODULE"); env && *env) {
      tried.emplace_back(env);
    } else {
      std::error_code ec;
      const fs::path exe = fs::read_symlink("/proc/self/exe", ec);
      const fs::path dir = ec ? fs::path(".") : exe.parent_path();
      tried.push_back((dir / "tinbuild-mpi.so").string());
      tried.push_back((dir / ".." / "lib" / "tinbuild" / "tinbuild-mpi.so").string());
    }
    std::string reasons;
    for (const std::string& path : tried) {
      // RTLD_GLOBAL: Open MPI's own plugins, which it loads in turn, resolve their symbols in libmpi.
      if (void* handle = ::dlopen(path.c_str(), RTLD_NOW | RTLD_GLOBAL)) {
        using Entry = const TinbuildMpiApi* (*)();
        auto entry = reinterpret_cast<Entry>(::dlsym(handle, "tinbuild_mpi_api"));
        const TinbuildMpiApi* table = entry ? entry() : nullptr;
        if (table && table->version == kTinbuildMpiApiVersion) return table;
        reasons += (reasons.empty() ? "" : "; ") + path + ": not a tinbuild MPI module of this version";
        continue;
      }
      const char* why = ::dlerror();
      reasons += (reasons.empty() ? "" : "; ") + std::string(why ? why : path + ": cannot be loaded");
    }
    throw UsageError("--mpi: cannot load tinbuild's MPI module (" + reasons +
                     "); it is built beside tinbuild when CMake finds MPI (set TINBUILD_MPI_MODULE to its path)");
  }();
  return *api;
}

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
  mpi().allreduceInPlace(&cancelled, 1, kTinbuildMpiInt, kTinbuildMpiMax);
  if (cancelled) throw CancelledError();
  int length = static_cast<int>(message.size());
  std::vector<int> lengths(static_cast<std::size_t>(size));
  mpi().allgather(&length, 1, lengths.data(), kTinbuildMpiInt);
  std::vector<int> offsets(static_cast<std::size_t>(size), 0);
  int total = 0;
  for (int i = 0; i < size; ++i) {
    offsets[static_cast<std::size_t>(i)] = total;
    total += lengths[static_cast<std::size_t>(i)];
  }
  if (total == 0) return;
  std::string all(static_cast<std::size_t>(total), '\0');
  mpi().allgatherv(message.data(), length, all.data(), lengths.data(), offsets.data(), kTinbuildMpiChar);
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

// An MPI run's steps read what the step before wrote, under its final name (other processes read it):
// the output transaction (if any) commits each step's files provisionally.  A run stopped later removes
// them again on every rank, so nothing of a stopped run stays under a final name; the merge's outputs
// appear all at once, at the end, and the part files become the run's with them.
void commitStep() {
  if (OutputTransaction* t = OutputTransaction::current()) t->commitProvisionally();
}

// A state file goes from a rank to rank 0 in chunks of 16 MiB (a few milliseconds each), so neither side
// holds a whole file in memory.  Before each chunk, and once after the last, the two ranks vote: a
// cancellation or a failure (a read, a write, a full disk) on either side stops both at the same point,
// so neither is left waiting on the other, and the collective step around the exchange then stops every
// rank.  A cancellation is thus honoured within a chunk.
constexpr std::uint64_t kChunk = std::uint64_t{1} << 24;
constexpr int kGoOn = 0, kStopCancelled = 1, kStopFailed = 2;

// Both ranks' states -> the worse one.
int pairVote(int peer, int tag, int mine) {
  int theirs = kGoOn;
  mpi().sendrecv(&mine, &theirs, 1, kTinbuildMpiInt, peer, tag);
  return std::max(mine, theirs);
}

void stopOnVote(int outcome, const std::string& error, int peer) {
  if (outcome == kStopFailed)
    throw Error(!error.empty() ? error : "the transfer failed on rank " + std::to_string(peer));
  if (outcome == kStopCancelled) throw CancelledError();
}

int stateOf(const std::string& error, const CancelFlag* cancel) {
  return !error.empty() ? kStopFailed : cancelRequested(cancel) ? kStopCancelled : kGoOn;
}

// Sends `path` (when it exists) to rank 0; returns the bytes sent.
std::uint64_t sendFile(const std::string& path, int tag, const CancelFlag* cancel) {
  std::ifstream in(path, std::ios::binary);
  std::error_code ec;
  const std::uint64_t size = in ? fs::file_size(path, ec) : 0;
  const std::uint64_t header[2] = {in && !ec ? 1u : 0u, size};
  mpi().send(header, 2, kTinbuildMpiUint64, 0, tag);
  if (!header[0]) return 0;
  std::vector<char> buffer(static_cast<std::size_t>(std::min(kChunk, size)));
  std::string error;
  for (std::uint64_t at = 0;;) {
    const std::uint64_t n = std::min(kChunk, size - at);
    if (n > 0 && error.empty() && !in.read(buffer.data(), static_cast<std::streamsize>(n)))
      error = path + ": cannot read the file to send it to rank 0";
    stopOnVote(pairVote(0, tag, stateOf(error, cancel)), error, 0);
    if (n == 0) return size;
    mpi().send(buffer.data(), static_cast<int>(n), kTinbuildMpiChar, 0, tag);
    at += n;
  }
}

// Rank 0: receives what `from` sends (sendFile) into `path`; returns the bytes received.
std::uint64_t receiveFile(const std::string& path, int from, int tag, const CancelFlag* cancel) {
  std::uint64_t header[2] = {0, 0};
  mpi().recv(header, 2, kTinbuildMpiUint64, from, tag);
  if (!header[0]) return 0;
  const std::uint64_t size = header[1];
  std::string error;
  std::unique_ptr<OutputFile> out;
  try {
    out = std::make_unique<OutputFile>(path, static_cast<std::size_t>(std::max<std::uint64_t>(16, std::min(kChunk, size))));
  } catch (const std::exception& e) {
    error = e.what();
  }
  std::vector<char> buffer(static_cast<std::size_t>(std::min(kChunk, size)));
  for (std::uint64_t at = 0;;) {
    const std::uint64_t n = std::min(kChunk, size - at);
    if (n == 0 && error.empty()) {  // the whole file: committed before the last vote, which reports it
      try {
        out->commit();
      } catch (const std::exception& e) {
        error = e.what();
      }
    }
    stopOnVote(pairVote(from, tag, stateOf(error, cancel)), error, from);
    if (n == 0) return size;
    mpi().recv(buffer.data(), static_cast<int>(n), kTinbuildMpiChar, from, tag);
    if (error.empty()) {
      try {
        out->write(buffer.data(), static_cast<std::size_t>(n));
      } catch (const std::exception& e) {
        error = e.what();
      }
    }
    at += n;
  }
}

// Rank 0's file at `path` (read there) to every rank, in chunks: its bytes, on every rank.
std::string broadcastFile(int rank, const std::string& path) {
  std::string bytes = rank == 0 ? readWhole(path) : std::string();
  std::uint64_t n = bytes.size();
  mpi().bcast(&n, 1, kTinbuildMpiUint64, 0);
  bytes.resize(n);
  for (std::uint64_t at = 0; at < n; at += kChunk)
    mpi().bcast(bytes.data() + at, static_cast<int>(std::min(kChunk, n - at)), kTinbuildMpiChar, 0);
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
    mpi().allreduceInPlace(mins, 3, kTinbuildMpiDouble, kTinbuildMpiMin);
    mpi().allreduceInPlace(maxs, 3, kTinbuildMpiDouble, kTinbuildMpiMax);
    c.bounds.minX = mins[0];
    c.bounds.minY = mins[1];
    c.bounds.minZ = mins[2];
    c.bounds.maxX = maxs[0];
    c.bounds.maxY = maxs[1];
    c.bounds.maxZ = maxs[2];
    if (!c.segMin.empty()) {
      mpi().allreduceInPlace(c.segMin.data(), static_cast<int>(c.segMin.size()), kTinbuildMpiDouble, kTinbuildMpiMin);
      mpi().allreduceInPlace(c.segMax.data(), static_cast<int>(c.segMax.size()), kTinbuildMpiDouble, kTinbuildMpiMax);
      bytes_ += (c.segMin.size() + c.segMax.size()) * 8;
    }
    FilterCounts& f = c.filter;
    std::vector<std::uint64_t> v{c.points};
    f.forEachCounter([&v](std::uint64_t& x) { v.push_back(x); });
    v.insert(v.end(), c.regions.begin(), c.regions.end());
    bytes_ += (v.size() + 6) * 8;
    mpi().allreduceInPlace(v.data(), static_cast<int>(v.size()), kTinbuildMpiUint64, kTinbuildMpiSum);
    std::size_t k = 0;
    c.points = v[k++];
    f.forEachCounter([&](std::uint64_t& x) { x = v[k++]; });
    for (std::uint64_t& x : c.regions) x = v[k++];
  }

 private:
  int rank_, size_;
  std::uint64_t bytes_ = 0;  // this rank's contributions to the sums
};

// The exchange of the plan's records.  When the plan kept every rank's slice as decoded records (costly
// inputs: LAZ, text, reprojection; SliceRecords), each rank sends the records of other parts' regions to
// those parts' ranks, and each part then reads its points from local files: every point is decoded once
// in the whole run (by the plan), where a part would otherwise decode its window of the inputs again.
//   - A part reads, in rank order, the records each rank sent it, and at its own rank's place its own
//     slice's records, all of them: its window filter drops the other parts' (counted there as other
//     parts' points, as when it reads the inputs).  A rank's own points are thus never copied: with tiles
//     delivered in flight order most of a slice is its own part's.
//   - The slices are consecutive runs of the survey's records, and a sender's records keep their order,
//     so a part reads its points in the survey's order.
//   - In rounds of up to 2^18 records (8 MiB) a rank, fewer with many ranks (a rank receives at most
//     1 GiB a round: MPI counts are ints); before each round the ranks vote, so that a failure (a read, a
//     write, a full disk) or a cancellation on any rank stops all of them at the same point.
std::uint64_t exchangeBatch(int size) {
  return std::clamp<std::uint64_t>((std::uint64_t{1} << 25) / static_cast<std::uint64_t>(size), 4096,
                                   std::uint64_t{1} << 18);
}

struct ExchangedRecords {
  std::unique_ptr<TempFile> own, received;  // this rank's slice; the other ranks' records for its part
  std::vector<std::unique_ptr<RecordFileStream>> pieces;
  std::vector<PointStream*> streams;  // what the part reads, in order
  std::uint64_t sentRecords = 0;              // to other ranks
  std::uint64_t receivedBytes = 0;            // from other ranks
};

// Do all ranks hold their slice's records, and can each take what the others send it?  (A vote: all or
// none exchange.)  matrix[s * size + d]: the records slice s holds in part d's regions.
bool canExchange(int rank, int size, const Plan& plan, const SliceRecords& mine, const FinalizerOptions& fo,
                 std::vector<std::uint64_t>& matrix, std::unique_ptr<TempFile>& file) {
  const std::size_t n = static_cast<std::size_t>(size), me = static_cast<std::size_t>(rank);
  int ok = mine.file && plan.parts.size() == n && mine.regions.size() == (std::size_t{1} << (2 * plan.regionLevel));
  std::vector<std::uint64_t> row(n, 0);
  if (ok)
    for (std::size_t k = 0; k < n; ++k)
      for (std::size_t m = plan.parts[k].first; m < plan.parts[k].end && m < mine.regions.size(); ++m)
        row[k] += mine.regions[m];
  matrix.assign(n * n, 0);
  mpi().allgather(row.data(), size, matrix.data(), kTinbuildMpiUint64);
  std::uint64_t incoming = 0;
  for (std::size_t s = 0; s < n; ++s)
    if (s != me) incoming += matrix[s * n + me];
  if (ok) {
    try {
      file = std::make_unique<TempFile>(fo.tempDir, "part-records");
      if (file->freeBytes() < fo.spoolReserve + incoming * sizeof(PointRecord)) ok = 0;
    } catch (const std::exception&) {
      ok = 0;
    }
  }
  mpi().allreduceInPlace(&ok, 1, kTinbuildMpiInt, kTinbuildMpiMin);
  if (!ok) file.reset();
  return ok != 0;
}

ExchangedRecords exchangeRecords(int rank, int size, const Plan& plan, SliceRecords& mine,
                                 const std::vector<std::uint64_t>& matrix, std::unique_ptr<TempFile> file,
                                 const CancelFlag* cancel) {
  const std::size_t n = static_cast<std::size_t>(size), me = static_cast<std::size_t>(rank);
  // Where each other rank's records go in this rank's file: the senders in rank order.
  std::vector<std::uint64_t> base(n + 1, 0), done(n, 0);
  for (std::size_t s = 0; s < n; ++s) base[s + 1] = base[s] + (s == me ? 0 : matrix[s * n + me]);
  // The part of each region.
  const RegionGrid regions{plan.grid, plan.regionLevel};
  std::vector<std::uint32_t> partOf(mine.regions.size(), 0);
  for (std::size_t k = 0; k < n; ++k)
    for (std::size_t m = plan.parts[k].first; m < plan.parts[k].end && m < partOf.size(); ++m)
      partOf[m] = static_cast<std::uint32_t>(k);
  const std::uint64_t perRound = exchangeBatch(size);
  int rounds = static_cast<int>((mine.records + perRound - 1) / perRound);
  mpi().allreduceInPlace(&rounds, 1, kTinbuildMpiInt, kTinbuildMpiMax);
  ExchangedRecords out;
  std::vector<PointRecord> batch, sendBuffer, receiveBuffer;
  std::vector<std::uint32_t> dest;
  std::vector<int> sendCounts(n), sendOffsets(n), receiveCounts(n), receiveOffsets(n), fill(n);
  std::string error;
  bool stopped = false;  // by a vote: the failing rank names its failure
  std::uint64_t at = 0;
  constexpr int kRecord = static_cast<int>(sizeof(PointRecord));
  for (int round = 0; round < rounds; ++round) {
    std::fill(sendCounts.begin(), sendCounts.end(), 0);
    try {
      const std::uint64_t k = std::min(perRound, mine.records - at);
      batch.resize(static_cast<std::size_t>(k));
      if (k > 0) mine.file->readAt(at * sizeof(PointRecord), batch.data(), batch.size() * sizeof(PointRecord));
      at += k;
      dest.resize(batch.size());
      for (std::size_t i = 0; i < batch.size(); ++i) {
        dest[i] = partOf[regions.ofPoint(batch[i].x, batch[i].y)];
        if (dest[i] != me) sendCounts[dest[i]] += kRecord;  // (its own part's stay in its file)
      }
      sendOffsets[0] = 0;
      for (std::size_t d = 1; d < n; ++d) sendOffsets[d] = sendOffsets[d - 1] + sendCounts[d - 1];
      sendBuffer.resize(static_cast<std::size_t>(sendOffsets[n - 1] + sendCounts[n - 1]) / sizeof(PointRecord));
      fill = sendOffsets;
      for (std::size_t i = 0; i < batch.size(); ++i) {
        if (dest[i] == me) continue;
        sendBuffer[static_cast<std::size_t>(fill[dest[i]] / kRecord)] = batch[i];
        fill[dest[i]] += kRecord;
      }
    } catch (const std::exception& e) {
      error = e.what();
    }
    // The vote: every rank goes on, or every rank stops here.
    int state = stateOf(error, cancel);
    mpi().allreduceInPlace(&state, 1, kTinbuildMpiInt, kTinbuildMpiMax);
    if (state != kGoOn) {
      stopped = true;
      break;
    }
    mpi().alltoall(sendCounts.data(), 1, receiveCounts.data(), kTinbuildMpiInt);
    std::size_t total = 0;
    for (std::size_t s = 0; s < n; ++s) {
      receiveOffsets[s] = static_cast<int>(total);
      total += static_cast<std::size_t>(receiveCounts[s]);
    }
    receiveBuffer.resize(total / sizeof(PointRecord));
    mpi().alltoallv(sendBuffer.data(), sendCounts.data(), sendOffsets.data(), receiveBuffer.data(),
                    receiveCounts.data(), receiveOffsets.data(), kTinbuildMpiChar);
    for (std::size_t d = 0; d < n; ++d) out.sentRecords += static_cast<std::uint64_t>(sendCounts[d] / kRecord);
    for (std::size_t s = 0; s < n; ++s)
      if (s != static_cast<std::size_t>(rank))
        out.receivedBytes += static_cast<std::uint64_t>(receiveCounts[s]);
    try {
      for (std::size_t s = 0; s < n; ++s) {
        const std::uint64_t k = static_cast<std::uint64_t>(receiveCounts[s] / kRecord);
        if (k == 0) continue;
        if (done[s] + k > base[s + 1] - base[s])
          throw Error("the exchange of records: rank " + std::to_string(s) + " sent more records than it counted");
        file->writeAt((base[s] + done[s]) * sizeof(PointRecord),
                      receiveBuffer.data() + static_cast<std::size_t>(receiveOffsets[s] / kRecord),
                      static_cast<std::size_t>(k * sizeof(PointRecord)));
        done[s] += k;
      }
    } catch (const std::exception& e) {
      error = e.what();
    }
  }
  for (std::size_t s = 0; s < n && error.empty() && !stopped; ++s)
    if (done[s] != base[s + 1] - base[s])
      error = "the exchange of records: rank " + std::to_string(s) + " sent " + std::to_string(done[s]) +
              " records of the " + std::to_string(base[s + 1] - base[s]) + " it counted for this part";
  collective(rank, size, "exchange of records on rank", [&] {
    if (!error.empty()) throw Error(error);
    if (cancelRequested(cancel)) throw CancelledError();
  });
  // The part's stream: the senders in rank order, this rank's own slice at its place.
  out.own = std::move(mine.file);
  out.received = std::move(file);
  for (std::size_t s = 0; s < n; ++s) {
    if (s == me)
      out.pieces.push_back(std::make_unique<RecordFileStream>(*out.own, 0, mine.records));
    else if (base[s + 1] > base[s])
      out.pieces.push_back(std::make_unique<RecordFileStream>(*out.received, base[s], base[s + 1] - base[s]));
    else
      continue;
    out.streams.push_back(out.pieces.back().get());
  }
  return out;
}

// ---- The seam across ranks (docs/design.md, "The seam across ranks").  Level by level, every rank sends
// each seam record it holds (its part's, then what its blocks left) to the rank owning the record's
// block one level up, which appends it to that block's input file; then each rank runs its blocks.

// One level's exchange.  `sources`: the seam files this rank holds (path, part or block index); `level`:
// the blocks' (-1: the top step, rank 0's); `inputs`: this rank's blocks of that level, their input files.
// In rounds: a rank sends at most 32 MiB a round, at most 256 MiB / ranks (64 KiB at least) to one rank,
// so no rank receives much more than 256 MiB at once (up to 4096 ranks; MPI's counts are ints).  Each round
// ends in a vote (more to send, a failure, a cancellation), so a failure or a stop anywhere ends every rank's
// loop at the same round; the collective step after it then stops them all.  Returns the bytes this rank
// received.
std::uint64_t exchangeSeam(int rank, int size, const Plan& plan, int level,
                           const std::vector<std::pair<std::string, std::uint32_t> >& sources,
                           std::map<std::uint64_t, std::unique_ptr<SeamFileWriter> >& inputs,
                           const CancelFlag* cancel) {
  struct Abort {};
  const std::size_t n = static_cast<std::size_t>(size);
  const std::size_t perPeer = std::max<std::size_t>(std::size_t{1} << 16, (std::size_t{256} << 20) / n);
  const std::size_t perRound = std::size_t{32} << 20;
  std::vector<std::string> out(n);
  std::size_t pending = 0;
  std::string error;
  bool stopped = false;
  std::uint64_t received = 0;
  std::vector<int> sendCounts(n), receiveCounts(n), sendOffsets(n), receiveOffsets(n);
  std::string sendBuffer, receiveBuffer;
  auto sinkOf = [&](std::uint32_t block) -> SeamSink& {
    const auto it = inputs.find(block);
    if (it == inputs.end())
      throw Error("the seam exchange: rank " + std::to_string(rank) + " got a record of block " +
                  std::to_string(block) + " of level " + std::to_string(level) + ", which it does not own");
    return *it->second;
  };
  // One round; true when every rank is done (or one failed: then `error` or `stopped` may be another's).
  auto round = [&](bool done) {
    int total = 0;
    for (std::size_t d = 0; d < n; ++d) {
      sendCounts[d] = static_cast<int>(out[d].size());
      sendOffsets[d] = total;
      total += sendCounts[d];
    }
    sendBuffer.clear();
    for (const std::string& b : out) sendBuffer += b;
    mpi().alltoall(sendCounts.data(), 1, receiveCounts.data(), kTinbuildMpiInt);
    std::int64_t all = 0;
    for (std::size_t d = 0; d < n; ++d) {
      receiveOffsets[d] = static_cast<int>(all);
      all += receiveCounts[d];
    }
    receiveBuffer.resize(static_cast<std::size_t>(all));
    mpi().alltoallv(sendBuffer.data(), sendCounts.data(), sendOffsets.data(), receiveBuffer.data(),
                    receiveCounts.data(), receiveOffsets.data(), kTinbuildMpiChar);
    for (std::string& b : out) b.clear();
    pending = 0;
    received += static_cast<std::uint64_t>(all - receiveCounts[static_cast<std::size_t>(rank)]);
    if (error.empty() && !stopped) {
      try {
        for (std::size_t d = 0; d < n; ++d)  // (senders in rank order: each region's own order is kept)
          replaySeamRecords(receiveBuffer.data() + receiveOffsets[d],
                            static_cast<std::size_t>(receiveCounts[d]), sinkOf);
      } catch (const std::exception& e) {
        error = e.what();
      }
    }
    if (cancelRequested(cancel)) stopped = true;
    int vote[2] = {done && error.empty() && !stopped ? 0 : 1, error.empty() && !stopped ? 0 : 1};
    mpi().allreduceInPlace(vote, 2, kTinbuildMpiInt, kTinbuildMpiMax);
    return vote[0] == 0 || vote[1] != 0;
  };
  struct Router : SeamSink {
    std::function<void(std::uint64_t, const std::function<void(std::string&, std::uint32_t)>&)> put;
    const GridSpec* grid = nullptr;
    int level = 0;
    void seamVertex(std::uint64_t id, double x, double y, double z, bool all, const Wedge* w,
                    std::size_t count) override {
      const std::uint64_t b = level < 0 ? 0 : seamBlockOfVertex(*grid, level, x, y);
      put(b, [&](std::string& o, std::uint32_t block) {
        appendSeamVertex(o, block, id, x, y, z, all, w, count);
      });
    }
    void seamTag(const CellTag& c) override {
      if (level >= 0 && c.level < level) throw Error("the seam exchange: a seam tag above its block");
      const std::uint64_t b = level < 0 ? 0 : seamBlockOfTag(level, c);
      put(b, [&](std::string& o, std::uint32_t block) { appendSeamTag(o, block, c); });
    }
  } router;
  router.grid = &plan.grid;
  router.level = level;
  router.put = [&](std::uint64_t block, const std::function<void(std::string&, std::uint32_t)>& encode) {
    const int owner = level < 0 ? 0 : seamBlockOwner(plan, level, block);
    std::string& o = out[static_cast<std::size_t>(owner)];
    const std::size_t before = o.size();
    encode(o, static_cast<std::uint32_t>(block));
    pending += o.size() - before;
    if (pending >= perRound || o.size() >= perPeer)
      if (round(false)) throw Abort{};
  };
  bool finished = false;
  try {
    for (const auto& [path, index] : sources) readSeamFile(path, plan.id, index, router, cancel);
  } catch (const Abort&) {
    finished = true;  // (another rank failed or was stopped: the collective after this says so)
  } catch (const CancelledError&) {
    stopped = true;
  } catch (const std::exception& e) {
    error = e.what();
  }
  while (!finished) finished = round(true);
  collective(rank, size, "seam exchange on rank", [&] {
    if (!error.empty()) throw Error(error);
    if (stopped) throw CancelledError();
  });
  return received;
}

// Where rank 0 keeps rank `from`'s seam triangles for the DEM.
std::string seamTriangleFile(const Plan& plan, int from) {
  char name[40];
  std::snprintf(name, sizeof name, "/seam-triangles-%04d.bin", from);
  return plan.stateDir() + name;
}

// The seam step of an MPI run across its ranks: every level of blocks between the regions and the top,
// each block on its owner (seamBlockOwner), then what the level-1 blocks leave to rank 0, whose merge runs
// the top step.  Returns rank 0's MergedBlocks (sums over the ranks; the files by rank).
struct SeamAcrossRanks {
  MergedBlocks merged;          // (rank 0)
  std::uint64_t settled = 0;    // by this rank's blocks
  std::uint64_t blocks = 0;     // run by this rank
  std::uint64_t received = 0;   // bytes of seam records this rank received
  std::uint64_t peakBytes = 0;  // this rank's largest block step
  std::string demTriangles;     // this rank's seam triangle file ("" without a DEM)
};

SeamAcrossRanks settleSeamAcrossRanks(int rank, int size, const Plan& plan, const PipelineOptions& options,
                                      const RunOutputs& planned, const std::string& privateDir) {
  SeamAcrossRanks r;
  const std::string localDir =
      privateDir.empty() ? plan.stateDir() : privateDir;  // (rank 0: the plan's state)
  const CancelFlag* cancel = options.finalizer.cancel;
  std::vector<std::pair<std::string, std::uint32_t> > sources = {
      {plan.partFile(rank, "seam"), static_cast<std::uint32_t>(rank)}};
  std::vector<std::string> ownFiles;  // (the block files this rank made, removed as soon as read)
  std::unique_ptr<SeamBlockRunner> runner;
  collective(rank, size, "seam blocks on rank", [&] {
    const PartDone done = readPartDone(plan.partFile(rank, "json"));
    // (Rank 0's file is where the merge reads them all; the others' are sent there.)
    if (planned.dem)
      r.demTriangles = rank == 0 ? seamTriangleFile(plan, 0) : localDir + "/seam-triangles.bin";
    runner = std::make_unique<SeamBlockRunner>(
        options, plan, done.crs, planned.mesh ? seamBlockMeshPath(options.meshOutput, rank) : std::string(),
        r.demTriangles);
  });
  auto removeFiles = [](std::vector<std::string>& files) {
    std::error_code ec;
    for (const std::string& f : files) fs::remove(f, ec);
    files.clear();
  };
  for (int level = plan.regionLevel - 1; level >= 1; --level) {
    std::map<std::uint64_t, std::unique_ptr<SeamFileWriter> > inputs;
    std::vector<std::string> inputPaths;
    const std::uint64_t count = std::uint64_t{1} << (2 * level);
    collective(rank, size, "seam blocks on rank", [&] {
      for (std::uint64_t b = 0; b < count; ++b) {
        if (seamBlockOwner(plan, level, b) != rank) continue;
        const std::string path =
            localDir + "/in-" + std::to_string(level) + "-" + std::to_string(b) + ".seam";
        inputs[b] = std::make_unique<SeamFileWriter>(path, plan.id, static_cast<std::uint32_t>(b));
        inputPaths.push_back(path);
      }
    });
    r.received += exchangeSeam(rank, size, plan, level, sources, inputs, cancel);
    std::vector<std::pair<std::string, std::uint32_t> > next;
    collective(rank, size, "seam blocks on rank", [&] {
      for (auto& [b, writer] : inputs) writer->commit();
      inputs.clear();
      commitStep();           // (each file under its name, to be read)
      removeFiles(ownFiles);  // (the sources just sent; never the part's seam file)
      std::size_t i = 0;
      for (std::uint64_t b = 0; b < count; ++b) {
        if (seamBlockOwner(plan, level, b) != rank) continue;
        const std::string output =
            localDir + "/out-" + std::to_string(level) + "-" + std::to_string(b) + ".seam";
        runner->run(level, b, inputPaths[i++], output);
        next.emplace_back(output, static_cast<std::uint32_t>(b));
        ownFiles.push_back(output);
      }
      removeFiles(inputPaths);
      commitStep();
    });
    sources = std::move(next);
  }
  // The top: what is left, to rank 0.
  std::map<std::uint64_t, std::unique_ptr<SeamFileWriter> > top;
  const std::string topPath = plan.stateDir() + "/seam-top.seam";
  collective(rank, size, "seam blocks on rank", [&] {
    runner->finish();
    commitStep();  // (the rank's block mesh, for rank 0's manifest)
    if (rank == 0) top[0] = std::make_unique<SeamFileWriter>(topPath, plan.id, kTopSeamFile);
  });
  r.received += exchangeSeam(rank, size, plan, -1, sources, top, cancel);
  collective(rank, size, "seam blocks on rank", [&] {
    if (rank == 0) top[0]->commit();
    removeFiles(ownFiles);
    commitStep();
  });
  r.settled = runner->settled;
  r.blocks = runner->blocks;
  r.peakBytes = runner->peakBytes;
  std::uint64_t sums[3] = {runner->settled, runner->triangles, runner->newVertices}, all[3] = {0, 0, 0};
  mpi().reduce(sums, all, 3, kTinbuildMpiUint64, kTinbuildMpiSum, 0);
  if (rank == 0) {
    r.merged.top = topPath;
    r.merged.seamVertices = all[0];
    r.merged.triangles = all[1];
    r.merged.newVertices = all[2];
    if (planned.mesh)
      for (int i = 0; i < size; ++i) r.merged.meshes.push_back(seamBlockMeshPath(options.meshOutput, i));
  }
  return r;
}

// The run's MPI: initialised once and finalized on the way out, whatever happens, and a watcher thread on
// every rank that carries a stop to all of them (mpi_api.h, the stop channel).  A SIGTERM to one rank (a
// node's job step stopped, a Ctrl-C in one terminal) sets that rank's cancel flag; its watcher sends a stop
// to every rank, whose watchers set their own flags within a poll (20 ms), and every rank unwinds from
// wherever its work is to the next collective step, which then stops them all together: exit 3 everywhere,
// within a second, nothing left.
struct MpiSession {
  int rank = 0, size = 1;
  bool owned = false, channel = false;
  std::atomic<bool> stopping{false};
  std::thread watcher;
  explicit MpiSession(const CancelFlag* cancel) {
    int own = 0;
    mpi().init(&rank, &size, &own);
    owned = own != 0;
    channel = mpi().stopOpen() != 0;
    if (channel && cancel)
      watcher = std::thread([this, cancel] {
        while (!stopping.load()) {
          // (The flag is the process's one cancel flag, which a signal handler sets: setting it here is
          // what a signal to this rank would have done.)
          if (mpi().stopPoll(cancelRequested(cancel) ? 1 : 0)) const_cast<CancelFlag*>(cancel)->request();
          std::this_thread::sleep_for(std::chrono::milliseconds(20));
        }
      });
  }
  ~MpiSession() {
    stopping.store(true);
    if (watcher.joinable()) watcher.join();
    if (channel) mpi().stopClose();
    if (owned) mpi().finalize();
  }
};

// The hydrology's transport (libterrain/hydrology/peers.h) over MPI.  Each exchange is two collectives:
// every rank's length (negative: the rank failed, its reason follows), then the bytes.
class MpiPeers final : public hydrology::Peers {
 public:
  MpiPeers(int rank, int size) : rank_(rank), size_(size) {}
  int rank() const override { return rank_; }
  int size() const override { return size_; }
  std::vector<std::vector<std::uint8_t> > allgather(const std::vector<std::uint8_t>& mine) override {
    return exchange(static_cast<std::int64_t>(mine.size()), mine);
  }
  void fail(const std::string& reason) override {
    if (failed_) return;  // (it learned of a failure at an exchange: every rank knows already)
    try {
      exchange(-1 - static_cast<std::int64_t>(reason.size()),
               std::vector<std::uint8_t>(reason.begin(), reason.end()));
    } catch (const hydrology::PeerFailed&) {
    }
  }
  // After a failure: whether every failed rank was stopped (SIGTERM, SIGINT) rather than in error.
  bool cancelled() const { return cancelled_; }

 private:
  std::vector<std::vector<std::uint8_t> > exchange(std::int64_t length,
                                                   const std::vector<std::uint8_t>& bytes) {
    std::vector<std::uint64_t> lengths(static_cast<std::size_t>(size_));
    auto mine = static_cast<std::uint64_t>(length);
    mpi().allgather(&mine, 1, lengths.data(), kTinbuildMpiUint64);
    bool failure = false;
    std::vector<int> counts(static_cast<std::size_t>(size_)), offsets(counts);
    std::int64_t total = 0;
    for (int i = 0; i < size_; ++i) {
      auto n = static_cast<std::int64_t>(lengths[static_cast<std::size_t>(i)]);
      if (n < 0) {
        failure = true;
        n = -1 - n;
      }
      counts[static_cast<std::size_t>(i)] = static_cast<int>(n);
      offsets[static_cast<std::size_t>(i)] = static_cast<int>(total);
      total += n;
    }
    if (total > std::int64_t{2147483647})
      throw Error("hydrology --mpi: one exchange of perimeters would exceed 2 GiB (" + std::to_string(total) +
                  " bytes); use smaller tiles (--tile-size) or more ranks");
    std::vector<std::uint8_t> all(static_cast<std::size_t>(total));
    mpi().allgatherv(bytes.data(), static_cast<int>(bytes.size()), all.data(), counts.data(), offsets.data(),
                     kTinbuildMpiChar);
    if (failure) {
      failed_ = true;
      cancelled_ = true;
      std::string report;
      for (int i = 0; i < size_; ++i) {
        if (static_cast<std::int64_t>(lengths[static_cast<std::size_t>(i)]) >= 0) continue;
        const std::string why(
            all.begin() + offsets[static_cast<std::size_t>(i)],
            all.begin() + offsets[static_cast<std::size_t>(i)] + counts[static_cast<std::size_t>(i)]);
        if (why != "cancelled") cancelled_ = false;
        if (!report.empty()) report += "; ";
        report += "rank " + std::to_string(i) + " failed: " + why;
      }
      throw hydrology::PeerFailed(report);
    }
    std::vector<std::vector<std::uint8_t> > out(static_cast<std::size_t>(size_));
    for (int i = 0; i < size_; ++i)
      out[static_cast<std::size_t>(i)].assign(
          all.begin() + offsets[static_cast<std::size_t>(i)],
          all.begin() + offsets[static_cast<std::size_t>(i)] + counts[static_cast<std::size_t>(i)]);
    return out;
  }
  int rank_, size_;
  bool failed_ = false, cancelled_ = false;
};

}  // namespace

MpiScope::MpiScope(bool wanted) {
  if (!wanted) return;
  int rank = 0, size = 1, own = 0;
  mpi().init(&rank, &size, &own);
  owned_ = own != 0;
}

MpiScope::~MpiScope() {
  if (owned_) mpi().finalize();
}

HydrologyReport runMpiHydrology(HydrologyOptions options, Diagnostics& diag) {
  MpiSession session(options.cancel);
  MpiPeers peers(session.rank, session.size);
  options.peers = &peers;
  try {
    return runHydrology(options, diag);
  } catch (const hydrology::PeerFailed& e) {
    // Another rank failed (this one's outputs are already rolled back by the unwinding).
    if (OutputTransaction* t = OutputTransaction::current()) t->rollback();
    if (peers.cancelled()) throw CancelledError();
    throw Error(e.what());
  } catch (...) {
    if (OutputTransaction* t = OutputTransaction::current()) t->rollback();
    throw;
  }
}

// Rank 0's plan: beside the first output (the mesh, else the DEM), FIRST.mpi-plan.json.
static std::string mpiPlanPath(const PipelineOptions& options) {
  const std::string anchor = !options.meshOutput.empty() ? options.meshOutput : options.dem.path;
  fs::path sharedBase = fs::path(anchor);
  if (!sharedBase.has_filename() || sharedBase.filename() == ".") sharedBase = sharedBase.parent_path();
  std::string base = sharedBase.string();
  while (base.size() > 1 && base.back() == '/') base.pop_back();
  return base + ".mpi-plan.json";
}

static RunReport runMpiSteps(const MpiSession& session, const PipelineOptions& options,
                      const std::vector<std::string>& buildArgs, const std::string& command, Diagnostics& diag);

RunReport runMpiBuild(const PipelineOptions& options, const std::vector<std::string>& buildArgs,
                      const std::string& command, Diagnostics& diag) {
  std::exception_ptr failure;
  std::vector<std::string> leftover;
  // The folders a failed run must not leave behind, if it makes them: the plan's state, the DEM's folder.
  // Each rank removes its own files; a folder still holding another rank's files then stays, so they are
  // tried again once every rank is done (below).  (Checked before MPI starts, so before any rank makes them.)
  std::vector<std::string> runFolders;
  {
    Plan root;
    root.path = mpiPlanPath(options);
    std::error_code ec;
    for (const std::string& dir : {root.stateDir(), options.dem.path})
      if (!dir.empty() && !fs::exists(dir, ec)) runFolders.push_back(dir);
  }
  {
    MpiSession session(options.finalizer.cancel);
    try {
      return runMpiSteps(session, options, buildArgs, command, diag);
    } catch (...) {
      // A stopped or failed run cleans up on every rank before MPI_Finalize (~MpiSession), whose fence
      // keeps the ranks together until all are done: mpirun stops the job at the first rank that exits
      // non-zero, which would kill a rank still removing its files.
      if (OutputTransaction* t = OutputTransaction::current()) {
        t->rollback();
        leftover = t->takeLeftoverDirectories();
      }
      failure = std::current_exception();
    }
  }
  // Past the fence every rank has removed its files: the folders this rank made that still held another
  // rank's files then are empty now.
  for (const std::string& dir : leftover) ::rmdir(dir.c_str());
  for (const std::string& dir : runFolders) ::rmdir(dir.c_str());  // (only when empty)
  std::rethrow_exception(failure);
}

static RunReport runMpiSteps(const MpiSession& session, const PipelineOptions& options,
                      const std::vector<std::string>& buildArgs, const std::string& command, Diagnostics& diag) {
  const auto t0 = std::chrono::steady_clock::now();
  const int rank = session.rank, size = session.size;
  const RunOutputs planned = resolveOutputs(options);
  checkPlannedOutputs(planned);
  // Rank 0's plan and state sit beside the first output (the file system all ranks share); the other
  // ranks keep their state in a temporary directory of their own until they send it.
  const std::string rootPlanPath = mpiPlanPath(options);
  {
    // Every rank sees the same files, so all refuse alike.  Rank 0's plan and its state folder are the
    // run's too (removed at its end).
    ClaimSet state;
    Plan root;
    root.path = rootPlanPath;
    if (rank == 0)
      state.outputs = {OutputClaim("(the MPI run's plan)", rootPlanPath).unlocked().rewritten(),
                       OutputClaim("(the MPI run's state)", root.stateDir()).folder().unlocked().rewritten()};
    claimRun(options, plannedClaims(planned, size), state);
  }
  std::string localDir;
  // A rank's private directory goes on every way out: a failed or stopped run's too (before, each failed
  // MPI run left one in $TMPDIR on every rank but the first).
  struct RemoveOnExit {
    const std::string& dir;
    ~RemoveOnExit() {
      std::error_code ec;
      if (!dir.empty()) fs::remove_all(dir, ec);
    }
  } removeLocalDir{localDir};
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
    // (A rank's private folder: its copy of the plan, its part's state until sent.)
    ClaimSet own;
    own.outputs = {
        OutputClaim("(rank " + std::to_string(rank) + "'s state)", localDir).folder().unlocked().rewritten()};
    claimOutputs(own);
    survey = openSurvey(options, diag, /*needIntensity=*/false);
    sliced = planInSlices(survey) && !options.constraints.any();  // (constraints: rank 0 plans, as for COPC)
  });
  SliceRecords sliceRecords;
  if (sliced) {
    MpiReducer reducer(rank, size);
    PipelineOptions po = options;
    po.overwrite = true;
    po.seamBlocks = true;
    plan.path = rank == 0 ? rootPlanPath : localDir + "/plan.json";
    planReport = runPlanInSlices(po, survey, size, plan, diag, reducer, &sliceRecords);  // (errors reach every rank)
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
      po.seamBlocks = true;
      plan.path = rootPlanPath;
      planReport = runPlan(po, survey, size, plan, diag);
      commitStep();
    });
    const std::string planText = broadcastFile(rank, rootPlanPath);
    exchanged += planText.size() * static_cast<std::uint64_t>(size - 1) * (rank == 0 ? 1 : 0) * 2;
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
    // The constraints the plan prepared (constraints.bin beside it) go to every rank too.
    if (options.constraints.any()) {
      const std::string bytes = broadcastFile(rank, plan.constraintsFile());
      exchanged += bytes.size() * static_cast<std::uint64_t>(size - 1) * (rank == 0 ? 1 : 0) * 2;
      collective(rank, size, "plan copy on rank", [&] {
        if (rank == 0) return;
        std::filesystem::create_directories(plan.stateDir());
        writeWhole(plan.constraintsFile(), bytes);
        commitStep();
      });
    }
  }

  commitStep();  // (the plan's files, for the next step to read)
  survey = Survey();  // (its readers are done with)
  const double planSeconds = since(tPlan);
  // The plan's records to the ranks of their parts (when every rank kept its slice's).
  const auto tExchange = Clock::now();
  ExchangedRecords records;
  {
    std::vector<std::uint64_t> matrix;
    std::unique_ptr<TempFile> file;
    if (sliced && canExchange(rank, size, plan, sliceRecords, options.finalizer, matrix, file)) {
      records = exchangeRecords(rank, size, plan, sliceRecords, matrix, std::move(file), options.finalizer.cancel);
      exchanged += 2 * records.sentRecords * sizeof(PointRecord);  // (halved with the rest below)
    }
    sliceRecords = SliceRecords();
  }
  const double exchangeSeconds = since(tExchange);
  // 2. Every rank its part.
  const auto tPart = Clock::now();
  RunReport partReport;
  collective(rank, size, "part", [&] {
    PipelineOptions po = options;
    po.plan = &plan;
    po.part = rank;
    po.commandLine = plan.command;
    po.partRecords = records.streams;
    partReport = runPart(po, diag);
    commitStep();  // the part's files, which the exchange and the merge read
  });

  double partSeconds = since(tPart);
  // 3. The seam, block by block across the ranks; then the DEM pieces, the seam triangles for the DEM and
  // the part records to rank 0.
  const auto tSeam = Clock::now();
  SeamAcrossRanks seam = settleSeamAcrossRanks(rank, size, plan, options, planned, localDir);
  exchanged += seam.received * 2;  // (halved with the rest below)
  std::uint64_t receivedBytes = seam.received + records.receivedBytes;
  const double seamSeconds = since(tSeam);
  const CancelFlag* cancel = options.finalizer.cancel;
  auto triangleFile = [&plan](int from) { return seamTriangleFile(plan, from); };
  // One sender at a time, rank 1 first.  Before each sender all ranks vote, so that a failure or a stop
  // (which ends a transfer on both of its sides at the same chunk: sendFile) ends the loop on every rank
  // at the same sender; a rank that left it early would leave the next sender waiting for rank 0.
  std::string sendError;
  bool sendStopped = false;
  for (int from = 1; from < size; ++from) {
    int state = sendError.empty() && !sendStopped && !cancelRequested(cancel) ? 0 : 1;
    mpi().allreduceInPlace(&state, 1, kTinbuildMpiInt, kTinbuildMpiMax);
    if (state != 0) break;
    if (rank != from && rank != 0) continue;
    try {
      if (!seam.demTriangles.empty()) {
        if (rank == from)
          exchanged += sendFile(seam.demTriangles, 103, cancel);
        else
          receivedBytes += receiveFile(triangleFile(from), from, 103, cancel);  // (added below)
      }
      const char* kinds[] = {"dem", "json"};
      for (int k = 0; k < 2; ++k) {
        const int tag = 101 + k;
        if (rank == from)
          exchanged += sendFile(plan.partFile(rank, kinds[k]), tag, cancel);
        else
          receivedBytes += receiveFile(plan.partFile(from, kinds[k]), from, tag, cancel);
      }
    } catch (const CancelledError&) {
      sendStopped = true;
    } catch (const std::exception& e) {
      sendError = e.what();
    }
  }
  collective(rank, size, "exchange from rank", [&] {
    if (!sendError.empty()) throw Error(sendError);
    if (sendStopped || cancelRequested(cancel)) throw CancelledError();
  });
  exchanged += receivedBytes - seam.received - records.receivedBytes;  // (the files, counted as received)
  collective(rank, size, "commit on rank", [&] { commitStep(); });  // rank 0: the files it received
  if (!localDir.empty()) {
    std::error_code ec;
    fs::remove_all(localDir, ec);
    localDir.clear();
  }

  // 4. The merge on rank 0: the top of the seam, the DEM tiles left in pieces, the mosaics.
  const auto tMerge = Clock::now();
  RunReport merged;
  collective(rank, size, "merge on rank", [&] {
    if (rank != 0) return;
    PipelineOptions mo = options;
    mo.commandLine = plan.command;  // the parts' tiles record the plan's command: so do the merge's
    if (planned.dem)
      for (int i = 0; i < size; ++i) seam.merged.demTriangles.push_back(triangleFile(i));
    merged = runMerge(mo, plan, diag, &seam.merged);
  });
  const double mergeSeconds = since(tMerge);
  std::vector<double> partTimes(static_cast<std::size_t>(size));
  mpi().gather(&partSeconds, 1, partTimes.data(), kTinbuildMpiDouble, 0);
  std::uint64_t peak = peakRssBytes();
  std::vector<std::uint64_t> peaks(static_cast<std::size_t>(size));
  mpi().gather(&peak, 1, peaks.data(), kTinbuildMpiUint64, 0);
  std::uint64_t exchangedAll = 0;
  mpi().reduce(&exchanged, &exchangedAll, 1, kTinbuildMpiUint64, kTinbuildMpiSum, 0);
  // Every rank's figures (mpi.ranks): seam vertices settled, block steps, DEM pieces joined, bytes received.
  std::uint64_t mine[4] = {seam.settled + (rank == 0 ? merged.seamVertices - seam.merged.seamVertices : 0),
                           seam.blocks, rank == 0 ? merged.demPieces : 0, receivedBytes};
  std::vector<std::uint64_t> figures(4 * static_cast<std::size_t>(size));
  mpi().gather(mine, 4, figures.data(), kTinbuildMpiUint64, 0);
  std::uint64_t recordsSent = records.sentRecords, recordsAll = 0;
  mpi().reduce(&recordsSent, &recordsAll, 1, kTinbuildMpiUint64, kTinbuildMpiSum, 0);
  // 5. The decision: one last vote.  A cancellation that has reached any rank by now stops all of them
  // (exit 3, nothing of the merge committed).  After the vote the run is decided: rank 0 commits and
  // every rank exits 0, whatever signal arrives later (as a single process past its commit).  Without
  // it, a late SIGTERM could stop one rank with exit 3 while rank 0 committed a whole result.
  int stop = cancelRequested(options.finalizer.cancel) ? 1 : 0;
  mpi().allreduceInPlace(&stop, 1, kTinbuildMpiInt, kTinbuildMpiMax);
  if (stop) throw CancelledError();
  if (rank != 0) {
    partReport.command = "build --mpi";
    partReport.secondaryRank = true;
    partReport.decided = true;
    return partReport;
  }
  std::error_code ec;
  fs::remove_all(plan.stateDir(), ec);
  fs::remove(rootPlanPath, ec);
  merged.command = "build --mpi";
  merged.inputs = options.inputs;
  merged.finalizer = planReport.finalizer;
  merged.filter = planReport.filter;
  merged.haveFinalizer = planReport.haveFinalizer;
  merged.rankPeakRss = peaks;
  merged.rankPartSeconds = partTimes;
  merged.planSeconds = planSeconds;
  merged.exchangeSeconds = exchangeSeconds;
  merged.mergeSeconds = mergeSeconds;
  merged.seamSeconds = seamSeconds;
  for (int i = 0; i < size; ++i) {
    const std::uint64_t* f = &figures[4 * static_cast<std::size_t>(i)];
    merged.ranks.push_back(RunReport::RankFigures{f[0], f[1], f[2], f[3]});
  }
  merged.exchangedBytes = exchangedAll / 2;  // each byte was counted by its sender and its receiver
  merged.exchangedRecords = recordsAll;
  merged.planPath.clear();
  // Rank 0's own part's outputs, then the merge's.
  std::vector<std::string> outputs = partReport.outputs;
  outputs.insert(outputs.end(), merged.outputs.begin(), merged.outputs.end());
  merged.outputs = outputs;
  merged.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  merged.decided = true;
  return merged;
}

#endif

}  // namespace tinbuild
