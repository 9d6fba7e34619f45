// tinbuild-mpi.so: the MPI calls of `build --mpi` (mpi_api.h) over the MPI library.  Loaded by
// mpi_run.cpp only when a run asks for MPI.
#include "app/jobs/mpi_api.h"

#include <mpi.h>

#include <vector>

namespace {

MPI_Datatype typeOf(int type) {
  switch (type) {
    case kTinbuildMpiInt: return MPI_INT;
    case kTinbuildMpiDouble: return MPI_DOUBLE;
    case kTinbuildMpiUint64: return MPI_UINT64_T;
    default: return MPI_CHAR;
  }
}

MPI_Op opOf(int op) {
  return op == kTinbuildMpiMin ? MPI_MIN : op == kTinbuildMpiMax ? MPI_MAX : MPI_SUM;
}

void init(int* rank, int* size, int* owned) {
  int initialized = 0;
  MPI_Initialized(&initialized);
  *owned = 0;
  if (!initialized) {
    int provided = 0;  // (MPI_THREAD_MULTIPLE for the stop channel's watcher; less only disables it)
    MPI_Init_thread(nullptr, nullptr, MPI_THREAD_MULTIPLE, &provided);
    *owned = 1;
  }
  MPI_Comm_rank(MPI_COMM_WORLD, rank);
  MPI_Comm_size(MPI_COMM_WORLD, size);
}

void finalize() {
  MPI_Finalize();
}

void allreduceInPlace(void* buffer, int count, int type, int op) {
  MPI_Allreduce(MPI_IN_PLACE, buffer, count, typeOf(type), opOf(op), MPI_COMM_WORLD);
}

void allgather(const void* send, int count, void* receive, int type) {
  MPI_Allgather(send, count, typeOf(type), receive, count, typeOf(type), MPI_COMM_WORLD);
}

void allgatherv(const void* send, int count, void* receive, const int* counts, const int* offsets, int type) {
  MPI_Allgatherv(send, count, typeOf(type), receive, counts, offsets, typeOf(type), MPI_COMM_WORLD);
}

void sendrecv(const void* send, void* receive, int count, int type, int peer, int tag) {
  MPI_Sendrecv(send, count, typeOf(type), peer, tag, receive, count, typeOf(type), peer, tag, MPI_COMM_WORLD,
               MPI_STATUS_IGNORE);
}

void send(const void* buffer, int count, int type, int to, int tag) {
  MPI_Send(buffer, count, typeOf(type), to, tag, MPI_COMM_WORLD);
}

void recv(void* buffer, int count, int type, int from, int tag) {
  MPI_Recv(buffer, count, typeOf(type), from, tag, MPI_COMM_WORLD, MPI_STATUS_IGNORE);
}

void bcast(void* buffer, int count, int type, int root) {
  MPI_Bcast(buffer, count, typeOf(type), root, MPI_COMM_WORLD);
}

void gather(const void* send, int count, void* receive, int type, int root) {
  MPI_Gather(send, count, typeOf(type), receive, count, typeOf(type), root, MPI_COMM_WORLD);
}

void reduce(const void* send, void* receive, int count, int type, int op, int root) {
  MPI_Reduce(send, receive, count, typeOf(type), opOf(op), root, MPI_COMM_WORLD);
}

void alltoall(const void* send, int count, void* receive, int type) {
  MPI_Alltoall(send, count, typeOf(type), receive, count, typeOf(type), MPI_COMM_WORLD);
}

void alltoallv(const void* send, const int* sendCounts, const int* sendOffsets, void* receive,
               const int* receiveCounts, const int* receiveOffsets, int type) {
  MPI_Alltoallv(send, sendCounts, sendOffsets, typeOf(type), receive, receiveCounts, receiveOffsets, typeOf(type),
                MPI_COMM_WORLD);
}

// The stop channel (mpi_api.h): its own communicator, one receive posted from any rank, one send to each
// other rank at the first request.
constexpr int kStopTag = 1;
MPI_Comm gStop = MPI_COMM_NULL;
MPI_Request gStopReceive = MPI_REQUEST_NULL;
int gStopValue = 0, gStopOne = 1;
bool gStopReceived = false, gStopSent = false;
std::vector<MPI_Request> gStopSends;

int stopOpen() {
  int level = 0;
  MPI_Query_thread(&level);
  if (level < MPI_THREAD_MULTIPLE) return 0;
  MPI_Comm_dup(MPI_COMM_WORLD, &gStop);
  gStopReceived = gStopSent = false;
  MPI_Irecv(&gStopValue, 1, MPI_INT, MPI_ANY_SOURCE, kStopTag, gStop, &gStopReceive);
  return 1;
}

int stopPoll(int request) {
  if (gStop == MPI_COMM_NULL) return 0;
  if (request && !gStopSent) {
    int rank = 0, size = 1;
    MPI_Comm_rank(gStop, &rank);
    MPI_Comm_size(gStop, &size);
    for (int r = 0; r < size; ++r) {
      if (r == rank) continue;
      gStopSends.push_back(MPI_REQUEST_NULL);
      MPI_Isend(&gStopOne, 1, MPI_INT, r, kStopTag, gStop, &gStopSends.back());
    }
    gStopSent = true;
  }
  if (!gStopReceived) {
    int arrived = 0;
    MPI_Test(&gStopReceive, &arrived, MPI_STATUS_IGNORE);
    gStopReceived = arrived != 0;
  }
  return gStopReceived ? 1 : 0;
}

void stopClose() {
  if (gStop == MPI_COMM_NULL) return;
  int rank = 0, size = 1;
  MPI_Comm_rank(gStop, &rank);
  MPI_Comm_size(gStop, &size);
  // Every rank learns how many stops were sent to it, and takes them all: none is left in flight.
  std::vector<int> sent(static_cast<std::size_t>(size), gStopSent ? 1 : 0),
      from(static_cast<std::size_t>(size), 0);
  sent[static_cast<std::size_t>(rank)] = 0;
  MPI_Alltoall(sent.data(), 1, MPI_INT, from.data(), 1, MPI_INT, gStop);
  int expected = 0;
  for (const int f : from) expected += f;
  if (gStopReceived) {
    --expected;
  } else if (expected > 0) {
    MPI_Wait(&gStopReceive, MPI_STATUS_IGNORE);
    --expected;
  } else {
    MPI_Cancel(&gStopReceive);
    MPI_Wait(&gStopReceive, MPI_STATUS_IGNORE);
  }
  for (int value = 0; expected > 0; --expected)
    MPI_Recv(&value, 1, MPI_INT, MPI_ANY_SOURCE, kStopTag, gStop, MPI_STATUS_IGNORE);
  if (!gStopSends.empty())
    MPI_Waitall(static_cast<int>(gStopSends.size()), gStopSends.data(), MPI_STATUSES_IGNORE);
  gStopSends.clear();
  MPI_Comm_free(&gStop);
  gStop = MPI_COMM_NULL;
}

const TinbuildMpiApi kApi = {kTinbuildMpiApiVersion,
                             init,
                             finalize,
                             allreduceInPlace,
                             allgather,
                             allgatherv,
                             sendrecv,
                             send,
                             recv,
                             bcast,
                             gather,
                             reduce,
                             alltoall,
                             alltoallv,
                             stopOpen,
                             stopPoll,
                             stopClose};

}  // namespace

extern "C" __attribute__((visibility("default"))) const TinbuildMpiApi* tinbuild_mpi_api() {
  return &kApi;
}
