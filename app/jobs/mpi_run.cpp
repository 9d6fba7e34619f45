// `tinbuild build --mpi` (header).
#include "app/jobs/mpi_run.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <optional>
#include <sstream>
#include <thread>

#include "app/jobs/merge_job.h"
#include "app/jobs/part_job.h"
#include "app/jobs/run_outputs.h"
#include "formats/io/output_file.h"
#include "formats/io/output_transaction.h"
#include "formats/mesh/seam_file.h"
#include "formats/raster/dem_pieces.h"
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

// Every rank's string, on every rank (a few bytes to a few kilobytes each: error messages, tile names,
// figures).
std::vector<std::string> allgatherStrings(int size, const std::string& mine) {
  int length = static_cast<int>(mine.size());
  std::vector<int> lengths(static_cast<std::size_t>(size)), offsets(lengths);
  mpi().allgather(&length, 1, lengths.data(), kTinbuildMpiInt);
  std::int64_t total = 0;
  for (std::size_t i = 0; i < lengths.size(); ++i) {
    offsets[i] = static_cast<int>(total);
    total += lengths[i];
  }
  if (total > std::int64_t{2147483647}) throw Error("MPI: more than 2 GiB to gather from the ranks");
  if (total == 0) return std::vector<std::string>(static_cast<std::size_t>(size));  // (every rank knows it)
  std::string all(static_cast<std::size_t>(total), '\0');
  mpi().allgatherv(mine.data(), length, all.data(), lengths.data(), offsets.data(), kTinbuildMpiChar);
  std::vector<std::string> out;
  for (std::size_t i = 0; i < lengths.size(); ++i)
    out.push_back(all.substr(static_cast<std::size_t>(offsets[i]), static_cast<std::size_t>(lengths[i])));
  return out;
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
  const std::vector<std::string> messages = allgatherStrings(size, message);
  std::string report;
  for (int i = 0; i < size; ++i) {
    const std::string& m = messages[static_cast<std::size_t>(i)];
    if (m.empty()) continue;
    if (!report.empty()) report += "; ";
    report += what + " " + std::to_string(i) + " (rank " + std::to_string(i) + ") failed: " + m;
  }
  if (report.empty()) return;
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

// Broadcasts go in chunks of 16 MiB (MPI's counts are ints).  A vote's outcomes: go on, or stop (a
// cancellation, a failure) on every rank at the same point.
constexpr std::uint64_t kChunk = std::uint64_t{1} << 24;
constexpr int kGoOn = 0, kStopCancelled = 1, kStopFailed = 2;

int stateOf(const std::string& error, const CancelFlag* cancel) {
  return !error.empty() ? kStopFailed : cancelRequested(cancel) ? kStopCancelled : kGoOn;
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

// An exchange of records between every pair of ranks, in rounds of MPI_Alltoallv: `produce` hands each
// record to send(rank, encode), which appends it to that rank's buffer; `deliver` gets, each round, every
// sender's bytes in rank order (whole records: a record is never split between rounds).  A rank sends at
// most 32 MiB a round, at most 256 MiB / ranks (64 KiB at least) to one rank, so no rank receives much
// more than 256 MiB at once (up to 4096 ranks; MPI's counts are ints).  Each round ends in a vote (more
// to send, a failure, a cancellation), so a failure or a stop anywhere ends every rank's loop at the same
// round; the collective step after it then stops them all.  Returns the bytes this rank received from
// the others.
using SendRecord = std::function<void(int, const std::function<void(std::string&)>&)>;
std::uint64_t exchangeInRounds(int rank, int size, const std::string& what, const CancelFlag* cancel,
                               const std::function<void(const SendRecord&)>& produce,
                               const std::function<void(const char*, std::size_t)>& deliver) {
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
        for (std::size_t d = 0; d < n; ++d)  // (senders in rank order)
          deliver(receiveBuffer.data() + receiveOffsets[d], static_cast<std::size_t>(receiveCounts[d]));
      } catch (const std::exception& e) {
        error = e.what();
      }
    }
    if (cancelRequested(cancel)) stopped = true;
    int vote[2] = {done && error.empty() && !stopped ? 0 : 1, error.empty() && !stopped ? 0 : 1};
    mpi().allreduceInPlace(vote, 2, kTinbuildMpiInt, kTinbuildMpiMax);
    return vote[0] == 0 || vote[1] != 0;
  };
  const SendRecord send = [&](int to, const std::function<void(std::string&)>& encode) {
    std::string& o = out[static_cast<std::size_t>(to)];
    const std::size_t before = o.size();
    encode(o);
    pending += o.size() - before;
    if (pending >= perRound || o.size() >= perPeer)
      if (round(false)) throw Abort{};
  };
  bool finished = false;
  try {
    produce(send);
  } catch (const Abort&) {
    finished = true;  // (another rank failed or was stopped: the collective after this says so)
  } catch (const CancelledError&) {
    stopped = true;
  } catch (const std::exception& e) {
    error = e.what();
  }
  while (!finished) finished = round(true);
  collective(rank, size, what, [&] {
    if (!error.empty()) throw Error(error);
    if (stopped) throw CancelledError();
  });
  return received;
}

// One level's exchange of the seam.  `sources`: the seam files this rank holds (path, part or block
// index); `level`: the blocks' (-1: the top step, rank 0's); `inputs`: this rank's blocks of that level,
// their input files.  Returns the bytes this rank received.
std::uint64_t exchangeSeam(int rank, int size, const Plan& plan, int level,
                           const std::vector<std::pair<std::string, std::uint32_t> >& sources,
                           std::map<std::uint64_t, std::unique_ptr<SeamFileWriter> >& inputs,
                           const CancelFlag* cancel) {
  auto sinkOf = [&](std::uint32_t block) -> SeamSink& {
    const auto it = inputs.find(block);
    if (it == inputs.end())
      throw Error("the seam exchange: rank " + std::to_string(rank) + " got a record of block " +
                  std::to_string(block) + " of level " + std::to_string(level) + ", which it does not own");
    return *it->second;
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
  return exchangeInRounds(
      rank, size, "seam exchange on rank", cancel,
      [&](const SendRecord& send) {
        router.put = [&](std::uint64_t block,
                         const std::function<void(std::string&, std::uint32_t)>& encode) {
          send(level < 0 ? 0 : seamBlockOwner(plan, level, block),
               [&](std::string& o) { encode(o, static_cast<std::uint32_t>(block)); });
        };
        for (const auto& [path, index] : sources) readSeamFile(path, plan.id, index, router, cancel);
      },
      [&](const char* data, std::size_t bytes) { replaySeamRecords(data, bytes, sinkOf); });
}

// The seam step of an MPI run across its ranks: every level of blocks between the regions and the top,
// each block on its owner (seamBlockOwner), then what the level-1 blocks leave to rank 0, which runs the
// top step.  Returns this rank's figures and files, and on rank 0 the MergedBlocks' seam sums.
struct SeamAcrossRanks {
  MergedBlocks merged;          // (rank 0)
  std::uint64_t settled = 0;    // by this rank's blocks
  std::uint64_t blocks = 0;     // run by this rank
  std::uint64_t received = 0;   // bytes of seam records this rank received
  std::uint64_t peakBytes = 0;  // this rank's largest block step
  std::string demPieces;        // this rank's seam DEM pieces ("" without a DEM)
  std::vector<std::string> demTiles;  // the tiles its seam triangles filled alone
  bool bankChecked = false;
  BankCheckFigures bank;  // the hydro-flattening check of its seam pixels
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
    // Each rank checks the files its own part left (the merge on rank 0 checks the rest of every part).
    const PartDone done = readPartDone(plan.partFile(rank, "json"));
    checkPartFiles(done, plan);
    if (planned.dem) r.demPieces = localDir + "/seam-pieces.demp";
    if (planned.mesh) {  // (its block mesh locked for the run, as a part's mesh: what a killed run left goes)
      ClaimSet own;
      own.outputs = {OutputClaim(optionName(OutputOption::Mesh), seamBlockMeshPath(options.meshOutput, rank))
                         .rewritten()};
      claimOutputs(own);
    }
    runner = std::make_unique<SeamBlockRunner>(
        options, plan, done, planned.mesh ? seamBlockMeshPath(options.meshOutput, rank) : std::string(),
        r.demPieces);
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
  // The top: what is left, to rank 0, which settles it.
  std::map<std::uint64_t, std::unique_ptr<SeamFileWriter> > top;
  const std::string topPath = plan.stateDir() + "/seam-top.seam";
  collective(rank, size, "seam blocks on rank", [&] {
    if (rank == 0) top[0] = std::make_unique<SeamFileWriter>(topPath, plan.id, kTopSeamFile);
  });
  r.received += exchangeSeam(rank, size, plan, -1, sources, top, cancel);
  collective(rank, size, "seam blocks on rank", [&] {
    removeFiles(ownFiles);
    if (rank == 0) {
      top[0]->commit();
      commitStep();
      runner->runTop(topPath);
      ownFiles.push_back(topPath);
    }
    runner->finish();
    removeFiles(ownFiles);
    commitStep();  // (the rank's block mesh, for rank 0's manifest; its DEM tiles and pieces)
  });
  r.settled = runner->settled;
  r.blocks = runner->blocks;
  r.peakBytes = runner->peakBytes;
  r.demTiles = runner->demTiles;
  r.bankChecked = runner->bankChecked;
  r.bank = runner->bank;
  std::uint64_t sums[3] = {runner->settled, runner->triangles, runner->newVertices}, all[3] = {0, 0, 0};
  mpi().reduce(sums, all, 3, kTinbuildMpiUint64, kTinbuildMpiSum, 0);
  if (rank == 0) {
    r.merged.seamVertices = all[0];
    r.merged.triangles = all[1];
    r.merged.newVertices = all[2];
    if (planned.mesh)
      for (int i = 0; i < size; ++i) r.merged.meshes.push_back(seamBlockMeshPath(options.meshOutput, i));
  }
  return r;
}

// The hydro-flattening check's figures as bytes (to gather them) and back.
template <class T>
void putBytes(std::string& out, const T& v) {
  out.append(reinterpret_cast<const char*>(&v), sizeof v);
}
template <class T>
T getBytes(const std::string& in, std::size_t& at) {
  T v{};
  if (at + sizeof v > in.size()) throw Error("MPI: the gathered check figures are cut short");
  std::memcpy(&v, in.data() + at, sizeof v);
  at += sizeof v;
  return v;
}
std::string encodeBank(const BankCheckFigures& f) {
  std::string out;
  putBytes(out, f.samples);
  putBytes(out, f.violations);
  putBytes(out, f.worst);
  putBytes(out, f.worstDerived);
  for (const std::string* s : {&f.worstAt, &f.worstDerivedAt}) {
    putBytes(out, static_cast<std::uint64_t>(s->size()));
    out += *s;
  }
  for (const std::vector<std::uint64_t>* v : {&f.bodySamples, &f.bodyViolations}) {
    putBytes(out, static_cast<std::uint64_t>(v->size()));
    for (std::uint64_t x : *v) putBytes(out, x);
  }
  return out;
}
BankCheckFigures decodeBank(const std::string& in) {
  BankCheckFigures f;
  std::size_t at = 0;
  f.samples = getBytes<std::uint64_t>(in, at);
  f.violations = getBytes<std::uint64_t>(in, at);
  f.worst = getBytes<double>(in, at);
  f.worstDerived = getBytes<double>(in, at);
  for (std::string* s : {&f.worstAt, &f.worstDerivedAt}) {
    const auto n = getBytes<std::uint64_t>(in, at);
    if (at + n > in.size()) throw Error("MPI: the gathered check figures are cut short");
    s->assign(in, at, n);
    at += n;
  }
  for (std::vector<std::uint64_t>* v : {&f.bodySamples, &f.bodyViolations}) {
    const auto n = getBytes<std::uint64_t>(in, at);
    for (std::uint64_t k = 0; k < n; ++k) v->push_back(getBytes<std::uint64_t>(in, at));
  }
  return f;
}

// The DEM tiles left in pieces (by the parts and by the seam's block steps), each merged and written by
// its owner rank (demTileOwner's rule): every rank indexes its piece files, the ranks learn every tile's
// piece count, each piece goes to its tile's owner (exchangeInRounds), and each owner writes its tiles
// (no mosaic: rank 0 writes the mosaics last, over every tile).
struct DemOwned {
  std::uint64_t pieces = 0;        // pieces this rank merged
  std::uint64_t pieceBytes = 0;    // bytes of the pieces it held (its part's and its seam's)
  std::uint64_t received = 0;      // bytes of pieces it received from the others
  std::vector<std::string> tiles;  // the tiles it wrote
};

DemOwned mergeDemTilesAcrossRanks(int rank, int size, const Plan& plan, const PipelineOptions& options,
                                  const std::vector<std::string>& pieceFiles, const std::string& privateDir) {
  DemOwned r;
  const CancelFlag* cancel = options.finalizer.cancel;
  const std::string localDir = privateDir.empty() ? plan.stateDir() : privateDir;
  DemPieceIndex mine;
  std::vector<std::int64_t> keys;  // (ty, tx, pieces) of the tiles this rank holds pieces of
  collective(rank, size, "DEM pieces on rank", [&] {
    for (const std::string& f : pieceFiles) {
      std::error_code ec;
      if (f.empty() || !fs::exists(f, ec)) continue;
      mine.add(f);
      r.pieceBytes += fs::file_size(f, ec);
    }
    for (const auto& [tx, ty] : mine.keys())
      keys.insert(keys.end(), {ty, tx, static_cast<std::int64_t>(mine.piecesOf(tx, ty))});
  });
  std::map<std::pair<std::int64_t, std::int64_t>, std::int64_t> count;  // (ty, tx) -> pieces, every rank's
  {
    const std::string bytes(reinterpret_cast<const char*>(keys.data()), keys.size() * sizeof(std::int64_t));
    for (const std::string& from : allgatherStrings(size, bytes))
      for (std::size_t at = 0; at + 3 * sizeof(std::int64_t) <= from.size(); at += 3 * sizeof(std::int64_t)) {
        std::int64_t k[3];
        std::memcpy(k, from.data() + at, sizeof k);
        count[{k[0], k[1]}] += k[2];
      }
  }
  std::vector<std::uint64_t> pieces;
  for (const auto& [key, n] : count) pieces.push_back(static_cast<std::uint64_t>(n));
  const std::vector<int> owners = demTileOwners(pieces, size);
  std::map<std::pair<std::int64_t, std::int64_t>, int> ownerOf;
  {
    std::size_t k = 0;
    for (const auto& [key, n] : count) ownerOf[key] = owners[k++];
  }
  const std::string ownedPath = localDir + "/owned-pieces.demp";
  std::unique_ptr<DemPieceWriter> owned;
  collective(rank, size, "DEM pieces on rank", [&] { owned = std::make_unique<DemPieceWriter>(ownedPath); });
  r.received = exchangeInRounds(
      rank, size, "DEM piece exchange on rank", cancel,
      [&](const SendRecord& send) {
        std::string piece;
        mine.forEachPiece(
            [&](const DemTile& t) {
              piece.clear();
              appendDemPiece(piece, t);
              send(ownerOf.at({t.ty, t.tx}), [&](std::string& o) {
                putBytes(o, static_cast<std::uint64_t>(piece.size()));
                o += piece;
              });
            },
            cancel);
      },
      [&](const char* data, std::size_t bytes) {
        for (std::size_t at = 0; at < bytes;) {
          std::uint64_t n = 0;
          if (at + sizeof n > bytes) throw Error("the DEM piece exchange: a record cut short");
          std::memcpy(&n, data + at, sizeof n);
          at += sizeof n;
          if (at + n > bytes) throw Error("the DEM piece exchange: a record cut short");
          owned->writeEncoded(data + at, static_cast<std::size_t>(n));
          at += static_cast<std::size_t>(n);
        }
      });
  collective(rank, size, "DEM tiles on rank", [&] {
    owned->commit();
    owned.reset();
    commitStep();  // (the file under its name, to be read)
    DemPieceIndex index;
    index.add(ownedPath);
    r.pieces = index.pieces();
    const PartDone part = readPartDone(plan.partFile(rank, "json"));
    RunOutputs outputs = rankOutputs(options, part);
    outputs.context.demMerge = &index;
    outputs.context.demMosaic = false;
    std::unique_ptr<OpenedOutput> dem = outputs.dem.row->open(outputs.dem.path, outputs.context);
    MeshInfo info;
    info.bounds = plan.bounds;
    info.crsWkt = part.crs.wkt;
    dem->triangleSink()->begin(info);  // (no triangle: every tile from its pieces)
    dem->triangleSink()->end();
    r.tiles = dem->results().demTiles;
    std::error_code ec;
    fs::remove(ownedPath, ec);
    commitStep();
  });
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

// Test hooks (tests/app/parts_test.cpp): TINBUILD_FAULT_MPI_RANK=R and TINBUILD_FAULT_MPI_STEP=part make rank
// R's part fail (an error, before it reads a point); =seam kill rank R (SIGKILL) as the seam step begins,
// as a lost node would, after every part finished.
static void faultHook(int rank, const char* step) {
  const char* r = std::getenv("TINBUILD_FAULT_MPI_RANK");
  const char* s = std::getenv("TINBUILD_FAULT_MPI_STEP");
  if (!r || !s || std::atoi(r) != rank || std::string(s) != step) return;
  if (std::string(step) == "seam") ::raise(SIGKILL);
  throw Error(std::string("a fault the tests injected (TINBUILD_FAULT_MPI_STEP=") + step + ")");
}

// An earlier run that failed or was stopped after some of its parts finished left its plan and their
// state (keepPartOnFailure, app/jobs/part_job.h): the same command run again -- the same arguments, the
// inputs unchanged, as many ranks -- resumes it.  Another run's state is refused, naming it, unless
// --overwrite (then this run starts afresh and replaces it).  Every rank reads the same files, so all
// decide alike.
static bool resumable(const std::string& rootPlanPath, const std::vector<std::string>& buildArgs, int size,
                      bool overwrite) {
  std::error_code ec;
  if (!fs::exists(rootPlanPath, ec)) return false;
  std::string why;
  try {
    const Plan p = readPlan(rootPlanPath);
    if (p.buildArgs != buildArgs)
      why = "it was made by other build options";
    else if (p.parts.size() != static_cast<std::size_t>(size))
      why = "it was made by a run of " + std::to_string(p.parts.size()) + " ranks";
    else {
      checkPlanInputs(p);  // (DataError when an input changed since)
      return true;
    }
  } catch (const std::exception& e) {
    why = e.what();
  }
  if (overwrite) return false;
  throw DataError(rootPlanPath,
                  "an earlier --mpi run's state, which this run cannot resume (" + why +
                      "): run that command again to finish it, or pass --overwrite to start afresh");
}

static RunReport runMpiSteps(const MpiSession& session, const PipelineOptions& options,
                             const std::vector<std::string>& buildArgs, const std::string& command,
                             Diagnostics& diag, bool& ownsState);

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
  int rank = -1;
  bool ownsState = false;  // (past its claims: the plan's state is this run's)
  {
    MpiSession session(options.finalizer.cancel);
    rank = session.rank;
    try {
      return runMpiSteps(session, options, buildArgs, command, diag, ownsState);
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
  // Past the fence every rank has removed its files (and moved its finished part's aside): the folders this
  // rank made that still held another rank's files then are empty now.  The plan stays only with a
  // finished part to resume.
  if (rank == 0 && ownsState) {
    Plan root;
    root.path = mpiPlanPath(options);
    std::error_code ec;
    int kept = 0;
    for (const auto& e : fs::directory_iterator(root.stateDir(), ec)) {
      const std::string name = e.path().filename().string();
      kept += name.rfind("part-", 0) == 0 && e.path().extension() == ".json";
    }
    if (kept == 0) {
      fs::remove_all(root.stateDir(), ec);
      fs::remove(root.path, ec);
    } else {
      std::fprintf(
          stderr,
          "tinbuild: %d finished part%s kept in %s: run the same command again to resume, redoing only "
          "the rest\n",
          kept, kept == 1 ? " is" : "s are", root.stateDir().c_str());
    }
  }
  for (const std::string& dir : leftover) ::rmdir(dir.c_str());
  for (const std::string& dir : runFolders) ::rmdir(dir.c_str());  // (only when empty)
  std::rethrow_exception(failure);
}

static RunReport runMpiSteps(const MpiSession& session, const PipelineOptions& options,
                             const std::vector<std::string>& buildArgs, const std::string& command,
                             Diagnostics& diag, bool& ownsState) {
  const auto t0 = std::chrono::steady_clock::now();
  const int rank = session.rank, size = session.size;
  const RunOutputs planned = resolveOutputs(options);
  checkPlannedOutputs(planned);
  // Rank 0's plan and state sit beside the first output (the file system all ranks share); the other
  // ranks keep their state in a temporary directory of their own until they send it.
  const std::string rootPlanPath = mpiPlanPath(options);
  bool resume = false;
  Plan root;  // (its path only: the state folder's)
  root.path = rootPlanPath;
  {
    // Every rank sees the same files, so all refuse alike.  Rank 0's plan and its state folder are the
    // run's too (removed at its end).
    ClaimSet state;
    if (rank == 0)
      state.outputs = {OutputClaim("(the MPI run's plan)", rootPlanPath).unlocked().rewritten(),
                       OutputClaim("(the MPI run's state)", root.stateDir()).folder().unlocked().rewritten()};
    // The same command run again after a failure resumes the earlier run: what it left (its finished parts'
    // files, and what a run killed outright left under final names) is this run's to reuse or rewrite.
    resume = resumable(rootPlanPath, buildArgs, size, options.overwrite);
    std::vector<OutputClaim> claims = plannedClaims(planned, size);
    if (resume)
      for (OutputClaim& c : claims) c.rewritten();
    claimRun(options, claims, state);
    ownsState = true;
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
    // (A rank's private folder: its copy of the plan while it plans, its files of the seam and the DEM.)
    ClaimSet own;
    own.outputs = {
        OutputClaim("(rank " + std::to_string(rank) + "'s state)", localDir).folder().unlocked().rewritten()};
    claimOutputs(own);
    if (resume) {
      // The staging folders a run killed outright left in the DEM directory (no rank of this run has
      // begun to write in it yet).
      std::error_code ec;
      if (rank == 0 && planned.dem)
        for (const auto& e : fs::directory_iterator(options.dem.path, ec))
          if (e.path().filename().string().rfind(".tinbuild-", 0) == 0) fs::remove_all(e.path(), ec);
      return;
    }
    if (rank == 0) {  // (another run's state, which --overwrite replaces)
      std::error_code ec;
      fs::remove_all(root.stateDir(), ec);
    }
    survey = openSurvey(options, diag, /*needIntensity=*/false);
    sliced = planInSlices(survey) && !options.constraints.any();  // (constraints: rank 0 plans, as for COPC)
  });
  SliceRecords sliceRecords;
  if (resume) {
    collective(rank, size, "plan on rank", [&] { plan = readPlan(rootPlanPath); });
  } else if (sliced) {
    MpiReducer reducer(rank, size);
    PipelineOptions po = options;
    po.overwrite = true;
    po.seamBlocks = true;
    plan.path = rank == 0 ? rootPlanPath : localDir + "/plan.json";
    planReport = runPlanInSlices(po, survey, size, plan, diag, reducer, &sliceRecords);  // (errors reach every rank)
    exchanged += 2 * reducer.bytes();  // (halved with the rest below: counted as sent, not also received)
    collective(rank, size, "plan on rank", [&] {
      if (rank == 0) writePlan(plan, plan.path);
      commitStep();
    });
    // (Rank 0's, as written: its id is the one every part records.)
    collective(rank, size, "plan copy on rank", [&] {
      if (rank != 0) plan = readPlan(rootPlanPath);
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
  }
  // Every rank's part keeps its state in the plan's state folder, on the file system the ranks share (the
  // constraints the plan prepared are there too): a part finished by a run that then fails stays there
  // for the same command run again (keepPartOnFailure).
  plan.path = rootPlanPath;
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
  std::uint64_t reused = 0;
  collective(rank, size, "part", [&] {
    // A run resumed: the part an earlier run finished, whole, is not run again.
    if (resume) {
      if (const std::optional<PartDone> done = finishedPart(plan, rank)) {
        reused = 1;
        partReport.part = rank;
        partReport.inputs = options.inputs;
        if (!done->mesh.empty()) {
          partReport.outputs.push_back(done->mesh);
          // Its mesh file is locked for the run, as the part locks it (a run killed outright left its lock).
          ClaimSet own;
          own.outputs = {OutputClaim(optionName(OutputOption::Mesh), done->mesh).rewritten()};
          claimOutputs(own);
        }
      }
    }
    if (!reused) {
      faultHook(rank, "part");
      PipelineOptions po = options;
      po.plan = &plan;
      po.part = rank;
      po.commandLine = plan.command;
      po.partRecords = records.streams;
      partReport = runPart(po, diag);
    }
    commitStep();  // the part's files, which the seam, the DEM and the merge read
    keepPartOnFailure(plan, rank);
  });

  double partSeconds = since(tPart);
  // 3. The seam, block by block across the ranks (the top on rank 0); then each DEM tile left in pieces
  // merged by its owner rank; then the parts' records to rank 0.
  const auto tSeam = Clock::now();
  faultHook(rank, "seam");
  SeamAcrossRanks seam = settleSeamAcrossRanks(rank, size, plan, options, planned, localDir);
  exchanged += seam.received * 2;  // (halved with the rest below)
  std::uint64_t receivedBytes = seam.received + records.receivedBytes;
  const double seamSeconds = since(tSeam);
  const auto tDem = Clock::now();
  DemOwned dem;
  if (planned.dem) {
    dem = mergeDemTilesAcrossRanks(rank, size, plan, options, {plan.partFile(rank, "dem"), seam.demPieces},
                                   localDir);
    exchanged += dem.received * 2;
    receivedBytes += dem.received;
    // Rank 0's mosaics name every tile; its report adds every rank's hydro-flattening check.
    std::string names;
    for (const auto* list : {&seam.demTiles, &dem.tiles})
      for (const std::string& t : *list) names += t + '\n';
    const std::vector<std::string> tiles = allgatherStrings(size, names);
    const std::vector<std::string> banks =
        allgatherStrings(size, seam.bankChecked ? encodeBank(seam.bank) : "");
    std::uint64_t sums[2] = {dem.pieces, dem.pieceBytes}, all[2] = {0, 0};
    mpi().reduce(sums, all, 2, kTinbuildMpiUint64, kTinbuildMpiSum, 0);
    if (rank == 0) {
      for (const std::string& list : tiles) {
        std::istringstream in(list);
        for (std::string t; std::getline(in, t);) seam.merged.demTiles.push_back(t);
      }
      for (const std::string& b : banks) {
        if (b.empty()) continue;
        const BankCheckFigures f = decodeBank(b);
        if (!seam.merged.bankChecked)
          seam.merged.bank = f;
        else
          seam.merged.bank.add(f);
        seam.merged.bankChecked = true;
      }
      seam.merged.demPieces = all[0];
      seam.merged.pieceBytes = all[1];
    }
  }
  const double demSeconds = since(tDem);
  if (!localDir.empty()) {
    std::error_code ec;
    fs::remove_all(localDir, ec);
    localDir.clear();
  }

  // 4. The merge on rank 0: the manifest of the TIN in parts, the GeoPackage TIN and the contours, the DEM's
  // mosaics.
  const auto tMerge = Clock::now();
  RunReport merged;
  collective(rank, size, "merge on rank", [&] {
    if (rank != 0) return;
    PipelineOptions mo = options;
    mo.commandLine = plan.command;  // the parts' tiles record the plan's command: so do the merge's
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
  std::uint64_t mine[4] = {seam.settled, seam.blocks, dem.pieces, receivedBytes};
  std::vector<std::uint64_t> figures(4 * static_cast<std::size_t>(size));
  mpi().gather(mine, 4, figures.data(), kTinbuildMpiUint64, 0);
  std::uint64_t reusedAll = 0;
  mpi().reduce(&reused, &reusedAll, 1, kTinbuildMpiUint64, kTinbuildMpiSum, 0);
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
  merged.demSeconds = demSeconds;
  merged.partsReused = reusedAll;
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
