#include "libterrain/mesh/mesh_tee.h"

#include <condition_variable>
#include <cstring>
#include <deque>
#include <exception>
#include <initializer_list>
#include <mutex>
#include <string>
#include <thread>

#include "libterrain/core/error.h"

namespace tinbuild {

void VertexTable::insert(const MeshVertex& v) {
  if (v.id == LiveIdTable<MeshVertex>::kFreeId)
    throw Error("streaming mesh: vertex id " + std::to_string(v.id) + " too large");
  if (!table_.insert(v)) throw Error("streaming mesh: vertex " + std::to_string(v.id) + " announced twice");
}

void VertexTable::notLive(std::uint64_t id) {
  throw Error("streaming mesh: triangle uses vertex " + std::to_string(id) + ", which is not live");
}

void VertexTable::erase(std::uint64_t id) {
  if (!table_.erase(id)) throw Error("streaming mesh: vertex " + std::to_string(id) + " finalized twice");
}

// ---------------------------------------------------------------------------------------------------
// MeshTee: events, the batch queue and the writer thread.

// Threaded mode queues the events as 64-bit words, each event one tagged first word (kind in the top
// two bits) and its operands: vertex = tag|id, x, y, z (bits); triangle = tag|a, b, c, or, when there
// are TriangleSinks, tag|a, xa, ya, za, b, xb, yb, zb, c, xc, yc, zc; finalization = tag|id; complete =
// tag|sink, first key, end key (in the batch's key list).  The caller's side resolves a triangle's ids
// in the one VertexTable (which its agents need anyway) and ships the coordinates: a second table on
// the writer's side cost as much memory again and a second round of cache misses per triangle (three
// random probes into a table of the mesh's width), about a quarter of the CPU of a build with a DEM.
namespace {
enum : std::uint64_t { kVertex = 0, kTriangle = 1, kFinalize = 2, kComplete = 3 };
constexpr int kTagShift = 62;
constexpr std::uint64_t kPayload = (std::uint64_t{1} << kTagShift) - 1;
constexpr std::size_t kBatchWords = 16384;  // 128 KB batches

inline std::uint64_t bitsOf(double v) {
  std::uint64_t b;
  std::memcpy(&b, &v, sizeof b);
  return b;
}
inline double doubleOf(std::uint64_t b) {
  double v;
  std::memcpy(&v, &b, sizeof v);
  return v;
}
}  // namespace

struct MeshTee::Batch {
  // A fixed buffer of kBatchWords + 12 words (one event past the threshold fits), `used` of them filled.
  std::unique_ptr<std::uint64_t[]> words = std::make_unique_for_overwrite<std::uint64_t[]>(kBatchWords + 12);
  std::size_t used = 0;
  std::vector<std::int64_t> keys;
};

class MeshTee::Writer {
 public:
  static constexpr std::size_t kMaxQueued = 8;
  explicit Writer(MeshTee& tee) : tee_(tee), thread_([this] { run(); }) {}
  ~Writer() {
    {
      std::lock_guard lock(mutex_);
      stop_ = true;
    }
    changed_.notify_all();
    thread_.join();
  }
  // Queues a full batch (blocks while the queue is full); rethrows an output's exception.
  void push(std::unique_ptr<Batch> batch) {
    std::unique_lock lock(mutex_);
    changed_.wait(lock, [&] { return queue_.size() < kMaxQueued || error_; });
    if (error_) std::rethrow_exception(error_);
    queue_.push_back(std::move(batch));
    changed_.notify_all();
  }
  // Waits until everything queued has been applied, stops the thread, rethrows an output's exception.
  void finish() {
    std::unique_lock lock(mutex_);
    changed_.wait(lock, [&] { return (queue_.empty() && !busy_) || error_; });
    if (error_) std::rethrow_exception(error_);
  }
  // A used batch for the producer to fill again (saves reallocating its buffers).
  std::unique_ptr<Batch> recycled() {
    std::lock_guard lock(mutex_);
    if (spare_.empty()) return std::make_unique<Batch>();
    auto b = std::move(spare_.back());
    spare_.pop_back();
    return b;
  }

 private:
  void run() {
    for (;;) {
      std::unique_ptr<Batch> batch;
      {
        std::unique_lock lock(mutex_);
        changed_.wait(lock, [&] { return stop_ || !queue_.empty(); });
        if (stop_ || error_) return;
        batch = std::move(queue_.front());
        queue_.pop_front();
        busy_ = true;
      }
      changed_.notify_all();
      std::exception_ptr error;
      try {
        tee_.apply(*batch);
      } catch (...) {
        error = std::current_exception();
      }
      batch->used = 0;
      batch->keys.clear();
      {
        std::lock_guard lock(mutex_);
        busy_ = false;
        if (error) error_ = error;
        if (spare_.size() < kMaxQueued) spare_.push_back(std::move(batch));  // never freed: a 128 KB batch is an mmap
      }
      changed_.notify_all();
      if (error) return;
    }
  }

  MeshTee& tee_;
  std::mutex mutex_;
  std::condition_variable changed_;
  std::deque<std::unique_ptr<Batch>> queue_;
  std::vector<std::unique_ptr<Batch>> spare_;
  bool stop_ = false, busy_ = false;
  std::exception_ptr error_;
  std::thread thread_;  // last: started once everything above exists
};

MeshTee::MeshTee() = default;
MeshTee::~MeshTee() = default;  // a writer still running (the run failed) is stopped, its queue dropped

// The consumer side: runs on the writer thread (threaded) or right away (not threaded).  Without a writer
// thread it also keeps the table of live vertices and runs the agents.
void MeshTee::applyVertex(const MeshVertex& v) {
  for (auto* s : meshSinks_) s->vertex(v.id, v.x, v.y, v.z);
  if (triangleSinks_.empty()) return;
  for (auto* s : triangleSinks_) s->vertex(v);
  if (agentsInApply_)
    for (auto* a : agents_) a->vertex(v);
}

void MeshTee::applyTriangle(std::uint64_t ia, std::uint64_t ib, std::uint64_t ic) {
  for (auto* s : meshSinks_) s->triangle(ia, ib, ic);
}

void MeshTee::applyTriangle(const MeshVertex& a, const MeshVertex& b, const MeshVertex& c) {
  for (auto* s : meshSinks_) s->triangle(a.id, b.id, c.id);
  for (auto* s : triangleSinks_) s->triangle(a, b, c);
  if (agentsInApply_)
    for (auto* ag : agents_) ag->triangle(a, b, c);
}

void MeshTee::applyFinalize(std::uint64_t id) {
  for (auto* s : meshSinks_) s->finalizeVertex(id);
}

void MeshTee::apply(const Batch& batch) {
  const std::uint64_t* w = batch.words.get();
  const std::uint64_t* const end = w + batch.used;
  while (w < end) {
    const std::uint64_t head = *w;
    const std::uint64_t payload = head & kPayload;
    switch (head >> kTagShift) {
      case kVertex:
        applyVertex(MeshVertex{payload, doubleOf(w[1]), doubleOf(w[2]), doubleOf(w[3])});
        w += 4;
        break;
      case kTriangle:
        if (triangleSinks_.empty()) {
          applyTriangle(payload, w[1], w[2]);
          w += 3;
        } else {
          applyTriangle(MeshVertex{payload, doubleOf(w[1]), doubleOf(w[2]), doubleOf(w[3])},
                        MeshVertex{w[4], doubleOf(w[5]), doubleOf(w[6]), doubleOf(w[7])},
                        MeshVertex{w[8], doubleOf(w[9]), doubleOf(w[10]), doubleOf(w[11])});
          w += 12;
        }
        break;
      case kFinalize:
        applyFinalize(payload);
        w += 1;
        break;
      default:  // kComplete
        triangleSinks_[payload]->areasComplete(batch.keys.data() + w[1], static_cast<std::size_t>(w[2] - w[1]));
        w += 3;
        break;
    }
  }
}

// Appends one event's words to the batch being filled and hands the batch on when it is full.
void MeshTee::put(std::uint64_t tag, std::uint64_t first, std::initializer_list<std::uint64_t> rest) {
  if (first > kPayload) throw Error("mesh tee: vertex id " + std::to_string(first) + " too large");
  std::uint64_t* w = batch_->words.get() + batch_->used;
  *w++ = (tag << kTagShift) | first;
  for (const std::uint64_t v : rest) *w++ = v;
  batch_->used = static_cast<std::size_t>(w - batch_->words.get());
  if (batch_->used >= kBatchWords) {
    writer_->push(std::move(batch_));
    batch_ = writer_->recycled();
  }
}

void MeshTee::begin(const MeshInfo& info) {
  writer_.reset();
  batch_.reset();
  vertices_ = VertexTable();
  agents_.clear();
  agentSink_.clear();
  for (auto* s : meshSinks_) s->begin(info);
  for (std::size_t i = 0; i < triangleSinks_.size(); ++i) {
    triangleSinks_[i]->begin(info);
    if (auto* a = triangleSinks_[i]->agent()) {
      a->begin(info);
      agents_.push_back(a);
      agentSink_.push_back(static_cast<std::uint32_t>(i));
    }
  }
  const bool threaded = threaded_ && !empty();
  agentsInApply_ = !threaded;
  if (threaded) {
    writer_ = std::make_unique<Writer>(*this);
    batch_ = writer_->recycled();
  }
}

void MeshTee::vertex(std::uint64_t id, double x, double y, double z) {
  const MeshVertex v{id, x, y, z};
  if (!triangleSinks_.empty()) vertices_.insert(v);
  if (!writer_) return applyVertex(v);  // no copy, no queue
  for (auto* a : agents_) a->vertex(v);
  put(kVertex, id, {bitsOf(x), bitsOf(y), bitsOf(z)});
}

void MeshTee::triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) {
  if (triangleSinks_.empty()) {
    if (!writer_) return applyTriangle(a, b, c);
    return put(kTriangle, a, {b, c});
  }
  const MeshVertex& va = vertices_.at(a);
  const MeshVertex& vb = vertices_.at(b);
  const MeshVertex& vc = vertices_.at(c);
  if (!writer_) return applyTriangle(va, vb, vc);
  for (auto* ag : agents_) ag->triangle(va, vb, vc);
  put(kTriangle, a,
      {bitsOf(va.x), bitsOf(va.y), bitsOf(va.z), b, bitsOf(vb.x), bitsOf(vb.y), bitsOf(vb.z), c, bitsOf(vc.x),
       bitsOf(vc.y), bitsOf(vc.z)});
}

void MeshTee::finalizeVertex(std::uint64_t id) {
  if (!triangleSinks_.empty()) vertices_.erase(id);
  if (!writer_) return applyFinalize(id);
  put(kFinalize, id, {});
}

void MeshTee::checkpoint(const ActiveRegion& region) {
  for (std::size_t k = 0; k < agents_.size(); ++k) {
    keys_.clear();
    agents_[k]->checkpoint(region, keys_);
    if (keys_.empty()) continue;
    if (!writer_) {
      triangleSinks_[agentSink_[k]]->areasComplete(keys_.data(), keys_.size());
      continue;
    }
    const std::uint64_t from = batch_->keys.size();
    batch_->keys.insert(batch_->keys.end(), keys_.begin(), keys_.end());
    put(kComplete, agentSink_[k], {from, static_cast<std::uint64_t>(batch_->keys.size())});
  }
}

void MeshTee::end() {
  if (writer_) {
    if (batch_->used > 0) writer_->push(std::move(batch_));
    batch_.reset();
    writer_->finish();
    writer_.reset();
  }
  // The outputs that take longest to finish (spatial index, last tiles, VRTs) go first; a cancellation
  // asked for meanwhile is honoured before the mesh files are renamed.
  if (progress_ && !progress_(1.0, "finishing outputs", progressData_)) throw CancelledError();
  for (auto* s : triangleSinks_) s->end();
  if (progress_ && !progress_(1.0, "finishing outputs", progressData_)) throw CancelledError();
  for (auto* s : meshSinks_) s->end();
}

}  // namespace tinbuild
