// libFuzzer target for the files a merge reads: the seam file (formats/mesh/seam_file.h), the DEM piece
// file (formats/raster/dem_pieces.h), the part record, the plan and the mesh manifest
// (formats/io/plan_file.h).  The merge trusts none of them: whatever their bytes, reading them must either
// succeed or throw tinbuild::Error (a DataError naming the file), never crash, hang or trip a sanitizer.
//
// An input is a selector byte (which reader, modulo 5) and then the file's bytes.  The seed corpus
// (tests/fuzz/run-bounded.sh) is a real plan's state: a part's seam file, pieces, record, the plan and the
// manifest, each behind its selector.
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>

#include "formats/io/plan_file.h"
#include "formats/mesh/seam_file.h"
#include "formats/raster/dem_pieces.h"
#include "libterrain/core/error.h"
#include "libterrain/delaunay/seam_step.h"

namespace {

class NoOutput : public tinbuild::SeamOutput {
 public:
  void begin(const tinbuild::MeshInfo&) override {}
  void triangle(tinbuild::SeamRecord&, tinbuild::SeamRecord&, tinbuild::SeamRecord&) override {}
  void finalize(tinbuild::SeamRecord&) override {}
  void end() override {}
};

std::string writeTemp(const std::uint8_t* data, std::size_t size) {
  char name[] = "/tmp/fuzz-state-XXXXXX";
  const int fd = ::mkstemp(name);
  if (fd < 0) std::abort();
  std::size_t done = 0;
  while (done < size) {
    const ssize_t n = ::write(fd, data + done, size - done);
    if (n <= 0) std::abort();
    done += static_cast<std::size_t>(n);
  }
  ::close(fd);
  return name;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 1) return 0;
  const int which = data[0] % 5;
  const std::string path = writeTemp(data + 1, size - 1);
  try {
    switch (which) {
      case 0: {
        NoOutput out;
        tinbuild::SeamStep step(out, tinbuild::DelaunayOptions{});
        tinbuild::StreamInfo info;
        info.grid.depth = 4;
        info.grid.size = 1e6;
        step.begin(info);
        // The plan id and part are the file's own (when its header holds them), so every record behind a
        // well-formed header is reached.
        std::string id;
        std::uint32_t part = 0;
        const std::uint8_t* f = data + 1;
        const std::size_t n = size - 1;
        if (n >= 12) {
          std::uint32_t len = 0;
          std::memcpy(&len, f + 8, 4);
          if (len <= n - 12) {
            id.assign(reinterpret_cast<const char*>(f + 12), len);
            if (n >= 16 + len) std::memcpy(&part, f + 12 + len, 4);
          }
        }
        tinbuild::readSeamFile(path, id, part, step);
        step.end();
        break;
      }
      case 1: {
        tinbuild::DemPieceIndex index;
        index.add(path);
        tinbuild::DemTile tile;
        for (const auto& [ty, tx] : index.keys()) index.addPieces(tx, ty, tile, false, -9999.0f);
        break;
      }
      case 2:
        (void)tinbuild::readPartDone(path);
        break;
      case 3:
        (void)tinbuild::readPlan(path);
        break;
      case 4:
        (void)tinbuild::readMeshManifest(path);
        break;
    }
  } catch (const tinbuild::Error&) {
    // a clear error: what the merge does with a damaged file
  }
  std::remove(path.c_str());
  return 0;
}
