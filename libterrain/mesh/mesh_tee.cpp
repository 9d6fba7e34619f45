#include "libterrain/mesh/mesh_tee.h"

#include <condition_variable>
#include <cstring>
#include <deque>
#include <exception>
#include <mutex>
#include <string>
#include <thread>

#include "libterrain/core/error.h"

namespace tinbuild {

namespace {
// Ids are dense and mostly sequential; a multiplicative mix keeps clusters of ids apart anyway when the
// live set is a few ranges far apart.
inline std::size_t slotOf(std::uint64_t id, std::size_t mask) {
  return static_cast<std::size_t>((id * 0x9E3779B97F4A7C15ull) >> 20) & mask;
}
}  // namespace

VertexTable::VertexTable() : slots_(1024), mask_(1023) {}

void VertexTable::grow() {
  std::vector<Slot> old;
  old.swap(slots_);
  slots_.assign(old.size() * 2, Slot{});
  mask_ = slots_.size() - 1;
  size_ = 0;
  for (const Slot& s : old)
    if (s.used) insert(s.v);
}

void VertexTable::insert(const MeshVertex& v) {
  if ((size_ + 1) * 4 > slots_.size() * 3) grow();
  std::size_t i = slotOf(v.id, mask_);
  while (slots_[i].used) {
    if (slots_[i].v.id == v.id)
      throw Error("streaming mesh: vertex " + std::to_string(v.id) + " announced twice");
    i = (i + 1) & mask_;
  }
  slots_[i].v = v;
  slots_[i].used = true;
  ++size_;
}

const MeshVertex& VertexTable::at(std::uint64_t id) const {
  std::size_t i = slotOf(id, mask_);
  while (slots_[i].used) {
    if (slots_[i].v.id == id) return slots_[i].v;
    i = (i + 1) & mask_;
  }
  throw Error("streaming mesh: triangle uses vertex " + std::to_string(id) + ", which is not live");
}

void VertexTable::erase(std::uint64_t id) {
  std::size_t i = slotOf(id, mask_);
  while (slots_[i].used && slots_[i].v.id != id) i = (i + 1) & mask_;
  if (!slots_[i].used) throw Error("streaming mesh: vertex " + std::to_string(id) + " finalized twice");
  // Backward-shift deletion: pull later members of the probe run into the hole when their home slot
  // does not lie cyclically in (hole, j].
  std::size_t hole = i, j = i;
  for (;;) {
    j = (j + 1) & mask_;
    if (!slots_[j].used) break;
    const std::size_t home = slotOf(slots_[j].v.id, mask_);
    const bool between = hole <= j ? (hole < home && home <= j) : (hole < home || home <= j);
    if (!between) {
      slots_[hole] = slots_[j];
      hole = j;
    }
  }
  slots_[hole].used = false;
  --size_;
}

// ---------------------------------------------------------------------------------------------------
// MeshTee: events, the batch queue and the writer thread.

// 40 bytes: the ids, or a vertex's id and coordinates bit for bit.  Triangles travel as ids; the writer
// side resolves them in its own VertexTable, so the triangulator's thread copies as little as possible.
struct MeshTee::Event {
  enum Kind : std::uint32_t { kVertex, kTriangle, kFinalize, kComplete };
  Kind kind = kVertex;
  std::uint32_t sink = 0;   // kComplete: the triangle sink the keys are for
  std::uint64_t w[4] = {};  // kVertex: id, x, y, z (bits); kTriangle: a, b, c; kFinalize: id;
                            // kComplete: keys [w[0], w[1]) of the batch's key list
};

namespace {
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
  std::vector<Event> events;
  std::vector<std::int64_t> keys;
};

class MeshTee::Writer {
 public:
  static constexpr std::size_t kBatchEvents = 4096, kMaxQueued = 8;
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
  // A used batch for the producer to fill again (saves reallocating the vectors).
  std::unique_ptr<Batch> recycled() {
    std::lock_guard lock(mutex_);
    if (spare_.empty()) {
      auto b = std::make_unique<Batch>();
      b->events.reserve(kBatchEvents);
      return b;
    }
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
        for (const Event& e : batch->events) tee_.apply(e, batch->keys);
      } catch (...) {
        error = std::current_exception();
      }
      batch->events.clear();
      batch->keys.clear();
      {
        std::lock_guard lock(mutex_);
        busy_ = false;
        if (error) error_ = error;
        if (spare_.size() < 2) spare_.push_back(std::move(batch));
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

MeshTee::MeshTee() : batch_(std::make_unique<Batch>()) {}
MeshTee::~MeshTee() = default;  // a writer still running (the run failed) is stopped, its queue dropped

// The consumer side: runs on the writer thread (threaded) or right away (not threaded).  It keeps its
// own table of live vertices for the TriangleSinks; without a writer thread it also runs the agents.
void MeshTee::applyVertex(const MeshVertex& v) {
  for (auto* s : meshSinks_) s->vertex(v.id, v.x, v.y, v.z);
  if (triangleSinks_.empty()) return;
  vertices_.insert(v);
  for (auto* s : triangleSinks_) s->vertex(v);
  if (agentsInApply_)
    for (auto* a : agents_) a->vertex(v);
}

void MeshTee::applyTriangle(std::uint64_t ia, std::uint64_t ib, std::uint64_t ic) {
  for (auto* s : meshSinks_) s->triangle(ia, ib, ic);
  if (triangleSinks_.empty()) return;
  const MeshVertex& a = vertices_.at(ia);
  const MeshVertex& b = vertices_.at(ib);
  const MeshVertex& c = vertices_.at(ic);
  for (auto* s : triangleSinks_) s->triangle(a, b, c);
  if (agentsInApply_)
    for (auto* ag : agents_) ag->triangle(a, b, c);
}

void MeshTee::applyFinalize(std::uint64_t id) {
  for (auto* s : meshSinks_) s->finalizeVertex(id);
  if (!triangleSinks_.empty()) vertices_.erase(id);
}

void MeshTee::apply(const Event& e, const std::vector<std::int64_t>& keys) {
  switch (e.kind) {
    case Event::kVertex:
      applyVertex(MeshVertex{e.w[0], doubleOf(e.w[1]), doubleOf(e.w[2]), doubleOf(e.w[3])});
      break;
    case Event::kTriangle:
      applyTriangle(e.w[0], e.w[1], e.w[2]);
      break;
    case Event::kFinalize:
      applyFinalize(e.w[0]);
      break;
    case Event::kComplete:
      triangleSinks_[e.sink]->areasComplete(keys.data() + e.w[0], static_cast<std::size_t>(e.w[1] - e.w[0]));
      break;
  }
}

void MeshTee::emit(const Event& e) {
  if (!writer_) {
    apply(e, batch_->keys);
    return;
  }
  batch_->events.push_back(e);
  if (batch_->events.size() >= Writer::kBatchEvents) {
    writer_->push(std::move(batch_));
    batch_ = writer_->recycled();
  }
}

void MeshTee::begin(const MeshInfo& info) {
  writer_.reset();
  batch_ = std::make_unique<Batch>();
  vertices_ = VertexTable();
  agentVertices_ = VertexTable();
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
  if (threaded) writer_ = std::make_unique<Writer>(*this);
}

void MeshTee::vertex(std::uint64_t id, double x, double y, double z) {
  if (!writer_) return applyVertex(MeshVertex{id, x, y, z});  // no copy, no queue
  if (!agents_.empty()) {
    const MeshVertex v{id, x, y, z};
    agentVertices_.insert(v);
    for (auto* a : agents_) a->vertex(v);
  }
  Event e;
  e.kind = Event::kVertex;
  e.w[0] = id;
  e.w[1] = bitsOf(x);
  e.w[2] = bitsOf(y);
  e.w[3] = bitsOf(z);
  emit(e);
}

void MeshTee::triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) {
  if (!writer_) return applyTriangle(a, b, c);
  if (!agents_.empty()) {
    const MeshVertex& va = agentVertices_.at(a);
    const MeshVertex& vb = agentVertices_.at(b);
    const MeshVertex& vc = agentVertices_.at(c);
    for (auto* ag : agents_) ag->triangle(va, vb, vc);
  }
  Event e;
  e.kind = Event::kTriangle;
  e.w[0] = a;
  e.w[1] = b;
  e.w[2] = c;
  emit(e);
}

void MeshTee::finalizeVertex(std::uint64_t id) {
  if (!writer_) return applyFinalize(id);
  if (!agents_.empty()) agentVertices_.erase(id);
  Event e;
  e.kind = Event::kFinalize;
  e.w[0] = id;
  emit(e);
}

void MeshTee::checkpoint(const ActiveRegion& region) {
  for (std::size_t k = 0; k < agents_.size(); ++k) {
    keys_.clear();
    agents_[k]->checkpoint(region, keys_);
    if (keys_.empty()) continue;
    Event e;
    e.kind = Event::kComplete;
    e.sink = agentSink_[k];
    e.w[0] = batch_->keys.size();
    batch_->keys.insert(batch_->keys.end(), keys_.begin(), keys_.end());
    e.w[1] = batch_->keys.size();
    emit(e);
    if (!writer_) batch_->keys.clear();
  }
}

void MeshTee::end() {
  if (writer_) {
    if (!batch_->events.empty()) writer_->push(std::move(batch_));
    batch_ = std::make_unique<Batch>();
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
