// The live vertices of a streaming mesh, by id: what every consumer that needs a vertex's data at its
// triangles keeps (the mesh tee's coordinates, the contour tracer's).
//
// A streaming mesh numbers its vertices 0, 1, 2, ... in the order it announces them, announces a vertex
// just before its first triangle and finalizes it after its last, so the live ids are mostly a sliding
// window of recent ids: on the demo's surveys 96% of the vertices are finalized within 4,096 ids of the
// newest one.  The table is therefore a ring indexed by id (slot id mod N), where inserting, finding and
// erasing a recent vertex touch one slot and compute no hash, plus a small hash table (linear probing,
// backward-shift deletion) for the stragglers: a vertex whose ring slot is wanted by a newer id moves
// there, as does a vertex inserted out of order.  When the stragglers outnumber an eighth of the ring
// and the ring has fewer slots than half the live vertices, the ring doubles and everything in reach of
// the larger window moves back to it.  So the ring ends at most about the peak live count, and the whole
// table holds no more than one hash table of the live set would (10^8-point build with a DEM: 3 MiB
// against the hash table's 4 MiB, 45-47 s against 52.8 s; a ring allowed twice the live count: 6 MiB,
// 46 s, and at 10^9 points about 9 MiB more than the hash table).
//
// Slot: a trivially copyable struct with a std::uint64_t member `id`; an unused slot has id kFreeId,
// which no stream can use.  Pointers returned by find() are valid until the next insert or erase.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

namespace tinbuild {

template <class Slot>
class LiveIdTable {
 public:
  static constexpr std::uint64_t kFreeId = ~std::uint64_t{0};

  LiveIdTable() { clear(); }

  void clear() {
    ring_.assign(kMinRing, free());
    ringMask_ = kMinRing - 1;
    ringSize_ = 0;
    hash_.assign(16, free());
    hashMask_ = 15;
    hashSize_ = 0;
    next_ = 0;
  }

  std::size_t size() const { return ringSize_ + hashSize_; }
  std::size_t capacityBytes() const { return (ring_.size() + hash_.size()) * sizeof(Slot); }

  // nullptr when the id is not live (kFreeId never is: it marks the free slots).
  const Slot* find(std::uint64_t id) const {
    const Slot& r = ring_[id & ringMask_];
    if (r.id == id) return id == kFreeId ? nullptr : &r;
    if (hashSize_ == 0 || id == kFreeId) return nullptr;
    return hashFind(id);
  }
  Slot* find(std::uint64_t id) {
    return const_cast<Slot*>(static_cast<const LiveIdTable&>(*this).find(id));
  }

  // false (and nothing changes) when the id is live already or is kFreeId.
  bool insert(const Slot& v) {
    if (v.id == kFreeId) return false;
    Slot& r = ring_[v.id & ringMask_];
    if (v.id >= next_) {
      next_ = v.id + 1;  // newer than every id seen: cannot be live already
    } else if (r.id == v.id || (hashSize_ != 0 && hashFind(v.id))) {
      return false;
    }
    file(r, v);
    if (hashSize_ * 8 > ring_.size() && ring_.size() * 2 < size()) growRing();
    return true;
  }

  // false when the id is not live.
  bool erase(std::uint64_t id) {
    if (id == kFreeId) return false;
    Slot& r = ring_[id & ringMask_];
    if (r.id == id) {
      r.id = kFreeId;
      --ringSize_;
      return true;
    }
    return hashSize_ != 0 && hashErase(id);
  }

 private:
  static constexpr std::size_t kMinRing = 1024;
  static Slot free() {
    Slot s{};
    s.id = kFreeId;
    return s;
  }
  static std::size_t home(std::uint64_t id, std::size_t mask) {
    return static_cast<std::size_t>((id * 0x9E3779B97F4A7C15ull) >> 20) & mask;
  }

  // Puts v in its ring slot r: a free slot takes it; a slot holding an older id gives that one to the
  // hash (a straggler) and takes v; a slot holding a newer id leaves v to the hash (v came out of order).
  void file(Slot& r, const Slot& v) {
    if (r.id == kFreeId) {
      r = v;
      ++ringSize_;
    } else if (r.id < v.id) {
      hashInsert(r);
      r = v;
    } else {
      hashInsert(v);
    }
  }

  const Slot* hashFind(std::uint64_t id) const {
    for (std::size_t i = home(id, hashMask_);; i = (i + 1) & hashMask_) {
      const Slot& s = hash_[i];
      if (s.id == id) return &s;
      if (s.id == kFreeId) return nullptr;
    }
  }
  void hashInsert(const Slot& v) {
    if ((hashSize_ + 1) * 4 > hash_.size() * 3) growHash();
    std::size_t i = home(v.id, hashMask_);
    while (hash_[i].id != kFreeId) i = (i + 1) & hashMask_;
    hash_[i] = v;
    ++hashSize_;
  }
  bool hashErase(std::uint64_t id) {
    std::size_t i = home(id, hashMask_);
    while (hash_[i].id != id) {
      if (hash_[i].id == kFreeId) return false;
      i = (i + 1) & hashMask_;
    }
    // Backward shift: pull later members of the probe run into the hole when their home slot does not
    // lie cyclically in (hole, j].
    std::size_t hole = i;
    for (std::size_t j = (i + 1) & hashMask_; hash_[j].id != kFreeId; j = (j + 1) & hashMask_) {
      const std::size_t h = home(hash_[j].id, hashMask_);
      const bool stay = hole <= j ? (hole < h && h <= j) : (hole < h || h <= j);
      if (!stay) {
        hash_[hole] = hash_[j];
        hole = j;
      }
    }
    hash_[hole].id = kFreeId;
    --hashSize_;
    return true;
  }
  void growHash() {
    std::vector<Slot> old;
    old.swap(hash_);
    hash_.assign(old.size() * 2, free());
    hashMask_ = hash_.size() - 1;
    hashSize_ = 0;
    for (const Slot& s : old)
      if (s.id != kFreeId) hashInsert(s);
  }
  // Doubles the ring and re-files every vertex: in the ring when its new slot is free or holds an
  // older id (which then goes to the hash), else in the hash.
  void growRing() {
    std::vector<Slot> oldRing, oldHash;
    oldRing.swap(ring_);
    oldHash.swap(hash_);
    ring_.assign(oldRing.size() * 2, free());
    ringMask_ = ring_.size() - 1;
    ringSize_ = 0;
    hash_.assign(16, free());
    hashMask_ = 15;
    hashSize_ = 0;
    for (const Slot& s : oldRing)
      if (s.id != kFreeId) file(ring_[s.id & ringMask_], s);
    for (const Slot& s : oldHash)
      if (s.id != kFreeId) file(ring_[s.id & ringMask_], s);
  }

  std::vector<Slot> ring_;
  std::size_t ringMask_ = 0, ringSize_ = 0;
  std::vector<Slot> hash_;  // the stragglers
  std::size_t hashMask_ = 0, hashSize_ = 0;
  std::uint64_t next_ = 0;  // one past the largest id ever inserted
};

}  // namespace tinbuild
