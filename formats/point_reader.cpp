#include "formats/point_reader.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "formats/las_reader.h"
#include "formats/stdin_source.h"
#include "formats/xyz_reader.h"
#include "libterrain/diagnostics.h"
#include "libterrain/error.h"

namespace tinbuild {

namespace {

// Presents another reader with the CRS replaced (--a_srs), so readers need not know about overrides.
class CrsOverride : public PointReader {
 public:
  CrsOverride(std::unique_ptr<PointReader> inner, CrsInfo crs)
      : inner_(std::move(inner)), info_(inner_->info()) {
    info_.crs = std::move(crs);
  }
  const SourceInfo& info() const override {
    // Counts become known during reading; mirror them.
    info_.pointCount = inner_->info().pointCount;
    info_.pointCountKnown = inner_->info().pointCountKnown;
    return info_;
  }
  std::size_t read(PointRecord* out, std::size_t max) override { return inner_->read(out, max); }
  bool rewindable() const override { return inner_->rewindable(); }
  bool cheapToReread() const override { return inner_->cheapToReread(); }
  void rewind() override { inner_->rewind(); }

 private:
  std::unique_ptr<PointReader> inner_;
  mutable SourceInfo info_;
};

bool hasLazExtension(const std::string& path) {
  if (path.size() < 4) return false;
  std::string ext = path.substr(path.size() - 4);
  for (auto& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return ext == ".laz";
}

}  // namespace

std::unique_ptr<PointReader> openPointReader(const std::string& path, const ReaderOptions& options,
                                             Diagnostics& diag) {
  std::uint8_t head[4] = {};
  std::size_t got = 0;
  if (path == "-") {
    while (got < 4) {
      const std::size_t r = readStdin(head + got, 4 - got);
      if (r == 0) break;
      got += r;
    }
    unreadStdin(head, got);
  } else {
    const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0) throw DataError(path, std::string("cannot open: ") + std::strerror(errno));
    ssize_t r;
    do r = ::read(fd, head, 4);
    while (r < 0 && errno == EINTR);
    ::close(fd);
    if (r < 0) throw DataError(path, std::string("cannot read: ") + std::strerror(errno));
    got = static_cast<std::size_t>(r);
  }
  std::unique_ptr<PointReader> reader;
  if (looksLikeLas(head, got)) {
    auto las = std::make_unique<LasReader>(path, diag);
    las->setDecodeThreads(options.decodeThreads);
    las->setDropCache(options.dropCache);
    reader = std::move(las);
  } else if (hasLazExtension(path)) {
    throw DataError(path, "LAZ is not supported yet: decompress with laszip/pdal first");
  } else {
    reader = std::make_unique<XyzReader>(path, options, diag);
  }
  if (!options.assignSrs.empty()) {
    CrsInfo crs = crsFromUser(options.assignSrs);
    crs.source = "user (--a_srs)";
    if (!reader->info().crs.empty() && !sameCrs(reader->info().crs, crs))
      diag.warn(
          "crs.overridden", path,
          "the file's CRS \"" + reader->info().crs.name + "\" is replaced by --a_srs \"" + crs.name + "\"");
    reader = std::make_unique<CrsOverride>(std::move(reader), std::move(crs));
  }
  return reader;
}

}  // namespace tinbuild
