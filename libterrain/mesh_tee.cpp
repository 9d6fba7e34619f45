#include "libterrain/mesh_tee.h"

#include <string>

#include "libterrain/error.h"

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

void MeshTee::begin(const MeshInfo& info) {
  vertices_ = VertexTable();
  for (auto* s : meshSinks_) s->begin(info);
  for (auto* s : triangleSinks_) s->begin(info);
}

void MeshTee::vertex(std::uint64_t id, double x, double y, double z) {
  for (auto* s : meshSinks_) s->vertex(id, x, y, z);
  if (!triangleSinks_.empty()) {
    const MeshVertex v{id, x, y, z};
    vertices_.insert(v);
    for (auto* s : triangleSinks_) s->vertex(v);
  }
}

void MeshTee::triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) {
  for (auto* s : meshSinks_) s->triangle(a, b, c);
  if (!triangleSinks_.empty()) {
    const MeshVertex& va = vertices_.at(a);
    const MeshVertex& vb = vertices_.at(b);
    const MeshVertex& vc = vertices_.at(c);
    for (auto* s : triangleSinks_) s->triangle(va, vb, vc);
  }
}

void MeshTee::finalizeVertex(std::uint64_t id) {
  for (auto* s : meshSinks_) s->finalizeVertex(id);
  if (!triangleSinks_.empty()) vertices_.erase(id);
}

void MeshTee::checkpoint(const ActiveRegion& region) {
  for (auto* s : meshSinks_) s->checkpoint(region);
  for (auto* s : triangleSinks_) s->checkpoint(region);
}

void MeshTee::end() {
  for (auto* s : meshSinks_) s->end();
  for (auto* s : triangleSinks_) s->end();
}

}  // namespace tinbuild
