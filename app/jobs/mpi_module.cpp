// tinbuild-mpi.so: the MPI calls of `build --mpi` (mpi_api.h) over the MPI library.  Loaded by
// mpi_run.cpp only when a run asks for MPI.
#include "app/jobs/mpi_api.h"

#include <mpi.h>

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
    MPI_Init(nullptr, nullptr);
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

const TinbuildMpiApi kApi = {kTinbuildMpiApiVersion, init, finalize, allreduceInPlace, allgather, allgatherv,
                             sendrecv, send, recv, bcast, gather, reduce, alltoall, alltoallv};

}  // namespace

extern "C" __attribute__((visibility("default"))) const TinbuildMpiApi* tinbuild_mpi_api() {
  return &kApi;
}
