// The few MPI calls `build --mpi` makes, as a table of plain functions (a C ABI).  The table lives in a
// module of its own, tinbuild-mpi.so (mpi_module.cpp), the only code linked to MPI: tinbuild loads it
// (dlopen) when a run asks for MPI, so that every other run starts without Open MPI's libraries (about
// 1.3 MiB of resident pages and their relocations on each start).  Only the types and operations
// tinbuild uses are in it.
#pragma once

#include <cstdint>

extern "C" {

enum TinbuildMpiType { kTinbuildMpiInt = 0, kTinbuildMpiDouble = 1, kTinbuildMpiUint64 = 2, kTinbuildMpiChar = 3 };
enum TinbuildMpiOp { kTinbuildMpiMin = 0, kTinbuildMpiMax = 1, kTinbuildMpiSum = 2 };

// Every call works on MPI_COMM_WORLD; `type` is a TinbuildMpiType, `op` a TinbuildMpiOp.  A failing MPI
// call ends the job (MPI's default error handler), as a direct call would.
struct TinbuildMpiApi {
  int version;  // kTinbuildMpiApiVersion
  // MPI_Init unless it was already initialised; *owned says whether finalize() must end it.
  void (*init)(int* rank, int* size, int* owned);
  void (*finalize)();
  void (*allreduceInPlace)(void* buffer, int count, int type, int op);
  void (*allgather)(const void* send, int count, void* receive, int type);
  void (*allgatherv)(const void* send, int count, void* receive, const int* counts, const int* offsets, int type);
  void (*sendrecv)(const void* send, void* receive, int count, int type, int peer, int tag);
  void (*send)(const void* buffer, int count, int type, int to, int tag);
  void (*recv)(void* buffer, int count, int type, int from, int tag);
  void (*bcast)(void* buffer, int count, int type, int root);
  void (*gather)(const void* send, int count, void* receive, int type, int root);
  void (*reduce)(const void* send, void* receive, int count, int type, int op, int root);
  // Every rank sends `count` items to every rank (send[i * count ..] to rank i).
  void (*alltoall)(const void* send, int count, void* receive, int type);
  // Every rank sends sendCounts[i] items from send + sendOffsets[i] to rank i, and receives
  // receiveCounts[i] items from rank i at receive + receiveOffsets[i] (counts and offsets in items).
  void (*alltoallv)(const void* send, const int* sendCounts, const int* sendOffsets, void* receive,
                    const int* receiveCounts, const int* receiveOffsets, int type);
  // The stop channel: a stop request travels to every rank beside the run's collectives, so a signal to
  // any one rank stops all of them within a poll, wherever they are in their work.  It needs
  // MPI_THREAD_MULTIPLE (init asks for it): stopOpen() on every rank at once returns 0 when the library
  // does not give it (then a signal reaches the others at the next collective step).  stopPoll(request),
  // from one thread (the watcher), sends a stop to every rank once `request` is non-zero and returns
  // non-zero once a stop has arrived from any rank.  stopClose() on every rank at once, after the last
  // poll, receives every stop that was sent before it frees the channel.
  int (*stopOpen)();
  int (*stopPoll)(int request);
  void (*stopClose)();
};

constexpr int kTinbuildMpiApiVersion = 3;

// The module's one exported symbol.
const TinbuildMpiApi* tinbuild_mpi_api();
}
