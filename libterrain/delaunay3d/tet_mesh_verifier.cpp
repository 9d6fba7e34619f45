#include "libterrain/delaunay3d/tet_mesh_verifier.h"

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <map>
#include <unordered_map>

#include "libterrain/core/mix_bits.h"
#include "libterrain/core/report_text.h"
#include "libterrain/delaunay3d/predicates3d.h"

namespace tinbuild {

namespace {

struct FaceKey {
  std::uint64_t a, b, c;
  bool operator==(const FaceKey&) const = default;
};
struct FaceHash {
  std::size_t operator()(const FaceKey& k) const { return mixBits(k.a * 3 + mixBits(k.b * 5 + mixBits(k.c))); }
};
struct OpenFace {
  Point3 tet[4];  // the first tetrahedron, positive
  int opposite;   // which of its vertices is not on the face
};

// The face opposite v[i], ordered so that v[i] lies on its positive side (as the tetrahedralizer's).
constexpr int kFace[4][3] = {{1, 3, 2}, {0, 2, 3}, {0, 3, 1}, {0, 1, 2}};

}  // namespace

void PointSetFingerprint3::add(double x, double y, double z) {
  ++count;
  hash += mixBits(std::bit_cast<std::uint64_t>(x) ^ mixBits(std::bit_cast<std::uint64_t>(y) ^ mixBits(std::bit_cast<std::uint64_t>(z))));
}

struct TetMeshVerifier::Impl {
  TetCheckReport r;
  std::unordered_map<std::uint64_t, Point3> live;
  std::uint64_t nextId = 0;
  std::unordered_map<FaceKey, OpenFace, FaceHash> open;
  std::map<std::string, std::size_t> problemIndex;
  ExactDeterminantSum volume;  // six times the tetrahedra's volume, exactly

  void problem(const std::string& kind, const std::string& first) {
    auto [it, fresh] = problemIndex.try_emplace(kind, r.problems.size());
    if (fresh) r.problems.push_back({kind, first, 0});
    ++r.problems[it->second].count;
  }
};

TetMeshVerifier::TetMeshVerifier() : impl_(std::make_unique<Impl>()) {}
TetMeshVerifier::~TetMeshVerifier() = default;

void TetMeshVerifier::begin(const TetMeshInfo&) {
  impl_ = std::make_unique<Impl>();
}

void TetMeshVerifier::vertex(std::uint64_t id, double x, double y, double z) {
  Impl& m = *impl_;
  if (id != m.nextId) m.problem("vertex ids out of order", std::to_string(id));
  m.nextId = id + 1;
  m.live[id] = {x, y, z};
  ++m.r.vertices;
  m.r.fingerprint.add(x, y, z);
  m.r.maxLiveVertices = std::max<std::uint64_t>(m.r.maxLiveVertices, m.live.size());
}

void TetMeshVerifier::tetrahedron(std::uint64_t a, std::uint64_t b, std::uint64_t c, std::uint64_t d) {
  Impl& m = *impl_;
  ++m.r.tetrahedra;
  const std::uint64_t id[4] = {a, b, c, d};
  Point3 p[4];
  for (int i = 0; i < 4; ++i) {
    auto it = m.live.find(id[i]);
    if (it == m.live.end()) {
      m.problem("tetrahedron uses a vertex that is not live", std::to_string(id[i]));
      return;
    }
    p[i] = it->second;
  }
  if (!(orient3d(p[0], p[1], p[2], p[3]) > 0)) {
    m.problem("tetrahedron not positively oriented", std::to_string(m.r.tetrahedra - 1));
    return;
  }
  m.volume.add(p[0], p[1], p[2], p[3]);
  for (int i = 0; i < 4; ++i) {
    std::uint64_t f[3] = {id[kFace[i][0]], id[kFace[i][1]], id[kFace[i][2]]};
    std::sort(f, f + 3);
    const FaceKey key{f[0], f[1], f[2]};
    auto it = m.open.find(key);
    if (it == m.open.end()) {
      OpenFace o;
      std::copy(p, p + 4, o.tet);
      o.opposite = i;
      m.open.emplace(key, o);
      m.r.maxOpenFaces = std::max<std::uint64_t>(m.r.maxOpenFaces, m.open.size());
      continue;
    }
    const OpenFace& o = it->second;
    ++m.r.interiorFaces;
    // The two tetrahedra lie on opposite sides of the face (else they overlap), and each opposite vertex
    // lies outside the other's circumsphere.
    const Point3& q = o.tet[o.opposite];
    const int* fi = kFace[i];
    if (!(orient3d(p[fi[0]], p[fi[1]], p[fi[2]], q) < 0))
      m.problem("tetrahedra overlap across a face", std::to_string(m.r.tetrahedra - 1));
    else if (inspherePerturbed(p[0], p[1], p[2], p[3], q) > 0 ||
             inspherePerturbed(o.tet[0], o.tet[1], o.tet[2], o.tet[3], p[i]) > 0)
      m.problem("face not locally Delaunay", std::to_string(m.r.tetrahedra - 1));
    m.open.erase(it);
  }
}

void TetMeshVerifier::finalizeVertex(std::uint64_t id) {
  Impl& m = *impl_;
  if (m.live.erase(id) == 0) m.problem("finalization of a vertex that is not live", std::to_string(id));
}

void TetMeshVerifier::end() {
  Impl& m = *impl_;
  if (!m.live.empty()) m.problem("vertices never finalized", std::to_string(m.live.begin()->first));
  // Hull: the faces used once, oriented outward (the inside tetrahedron's opposite vertex on the negative
  // side).  Closed (two faces at every edge), convex (neither face of an edge sees the other's third vertex
  // on its outer side), and enclosing the tetrahedra's volume.
  struct HullFace {
    Point3 p[3];
    std::uint64_t id[3];
  };
  std::vector<HullFace> hull;
  for (const auto& [key, o] : m.open) {
    HullFace h;
    const int* f = kFace[o.opposite];
    // kFace has the opposite vertex on the positive side: reverse for the outward orientation.
    h.p[0] = o.tet[f[0]], h.p[1] = o.tet[f[2]], h.p[2] = o.tet[f[1]];
    h.id[0] = key.a, h.id[1] = key.b, h.id[2] = key.c;  // (sorted; used as edge keys only)
    hull.push_back(h);
  }
  m.r.hullFaces = hull.size();
  Point3 o{0, 0, 0};
  if (!hull.empty()) o = hull[0].p[0];
  ExactDeterminantSum hv;  // six times the hull's volume, as a fan of tetrahedra from o, exactly
  std::map<std::pair<std::uint64_t, std::uint64_t>, std::vector<std::size_t>> edges;
  for (std::size_t i = 0; i < hull.size(); ++i) {
    hv.add(o, hull[i].p[0], hull[i].p[1], hull[i].p[2]);
    const std::uint64_t* id = hull[i].id;
    edges[{id[0], id[1]}].push_back(i);
    edges[{id[1], id[2]}].push_back(i);
    edges[{id[0], id[2]}].push_back(i);
  }
  for (const auto& [e, fs] : edges) {
    if (fs.size() != 2) {
      m.problem("hull is not a closed surface", std::to_string(e.first) + "-" + std::to_string(e.second));
      continue;
    }
    const HullFace &f = hull[fs[0]], &g = hull[fs[1]];
    for (int k = 0; k < 3; ++k) {
      if (g.id[k] == e.first || g.id[k] == e.second) continue;
      // g's third vertex must not lie strictly outside f (outside: the positive side of f's outward order).
      if (orient3d(f.p[0], f.p[1], f.p[2], g.p[k]) > 0)
        m.problem("hull is not convex", std::to_string(e.first) + "-" + std::to_string(e.second));
    }
  }
  m.r.volume = m.volume.value() / 6;
  m.r.hullVolume = hv.value() / 6;
  // Exact: the two sums are compared as expansions, with no tolerance (near-coplanar clouds have volumes
  // that a relative tolerance cannot tell from their rounding).
  if (m.volume.compare(hv) != 0)
    m.problem("hull volume differs from the tetrahedra's", formatDouble("%.17g", m.r.hullVolume) + " vs " +
                                                               formatDouble("%.17g", m.r.volume) +
                                                               " (exactly compared)");
}

const TetCheckReport& TetMeshVerifier::report() const {
  return impl_->r;
}

}  // namespace tinbuild
