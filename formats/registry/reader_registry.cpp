#include "formats/registry/reader_registry.h"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <cctype>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <vector>

#include "formats/io/stdin_source.h"
#include "formats/pointcloud/las_reader.h"
#include "formats/pointcloud/laz/chunk_codec.h"
#include "formats/pointcloud/xyz_reader.h"
#include "libterrain/core/diagnostics.h"
#include "libterrain/core/error.h"
#include "libterrain/core/report_text.h"
#include "libterrain/core/temp_file.h"

namespace tinbuild {

namespace {

// A reader that hands everything to another one (the decorators below change one thing each).
class ForwardingReader : public PointReader {
 public:
  explicit ForwardingReader(std::unique_ptr<PointReader> inner) : inner_(std::move(inner)) {}
  const SourceInfo& info() const override { return inner_->info(); }
  std::size_t read(PointRecord* out, std::size_t max) override { return inner_->read(out, max); }
  bool rewindable() const override { return inner_->rewindable(); }
  void rewind() override { inner_->rewind(); }
  bool cheapToReread() const override { return inner_->cheapToReread(); }
  bool seekable() const override { return inner_->seekable(); }
  void seek(std::uint64_t record, std::uint64_t count) override { inner_->seek(record, count); }
  void setDecodeThreads(int threads) override { inner_->setDecodeThreads(threads); }
  void willRead(std::uint64_t record, std::uint64_t count) override { inner_->willRead(record, count); }
  void suspend() override { inner_->suspend(); }
  bool describeBlocks(std::vector<Block>& blocks, BlockFrame& frame) const override {
    return inner_->describeBlocks(blocks, frame);
  }
  void restrictTo(const ClipRect& window) override { inner_->restrictTo(window); }
  std::uint64_t skippedOutside() const override { return inner_->skippedOutside(); }

 protected:
  std::unique_ptr<PointReader> inner_;
};

// Presents another reader with the CRS replaced (--a_srs), so readers need not know about overrides.
class CrsOverride : public ForwardingReader {
 public:
  CrsOverride(std::unique_ptr<PointReader> inner, CrsInfo crs)
      : ForwardingReader(std::move(inner)), info_(inner_->info()) {
    info_.crs = std::move(crs);
  }
  const SourceInfo& info() const override {
    // Counts become known during reading; mirror them.
    info_.pointCount = inner_->info().pointCount;
    info_.pointCountKnown = inner_->info().pointCountKnown;
    return info_;
  }

 private:
  mutable SourceInfo info_;
};

// LAZ on standard input: its chunk table lies at the end, so the compressed bytes (about a seventh of
// the LAS) are first copied to a temporary file beside the others ($TMPDIR, else /tmp), which is then
// read like any LAZ file (in parallel, seekable) and removed with the reader.  info().path says "-".
class StdinLazCopy : public ForwardingReader {
 public:
  StdinLazCopy(std::unique_ptr<PointReader> inner, std::string temp)
      : ForwardingReader(std::move(inner)), temp_(std::move(temp)), info_(inner_->info()) {
    info_.path = "-";
  }
  ~StdinLazCopy() override {
    inner_.reset();
    ::unlink(temp_.c_str());
  }
  const SourceInfo& info() const override { return info_; }

 private:
  std::string temp_;
  SourceInfo info_;
};

// Copies standard input to a new temporary file; returns its path.
std::string copyStdinToTemporary() {
  std::string templ = defaultTempDir() + "/tinbuild-stdin-XXXXXX.laz";
  std::vector<char> name(templ.begin(), templ.end());
  name.push_back('\0');
  const int fd = ::mkstemps(name.data(), 4);
  if (fd < 0)
    throw DataError("-", "cannot create a temporary file for LAZ from standard input in " + templ + ": " +
                             std::strerror(errno));
  const std::string path = name.data();
  try {
    std::vector<std::uint8_t> buffer(std::size_t{1} << 20);
    for (std::size_t n; (n = readStdin(buffer.data(), buffer.size())) > 0;) {
      for (std::size_t done = 0; done < n;) {
        const ssize_t w = ::write(fd, buffer.data() + done, n - done);
        if (w < 0 && errno == EINTR) continue;
        if (w < 0) throw DataError(path, std::string("cannot write standard input's copy: ") + std::strerror(errno));
        done += static_cast<std::size_t>(w);
      }
    }
  } catch (...) {
    ::close(fd);
    ::unlink(path.c_str());
    throw;
  }
  ::close(fd);
  return path;
}

// LAS 1.4's header is 375 bytes; a COPC file's first VLR follows it at once: user id "copc", record 1.
bool recognisesCopc(const std::uint8_t* head, std::size_t size) {
  constexpr std::size_t kVlr = 375;
  if (!looksLikeLas(head, size) || size < kVlr + 20) return false;
  static const char kUser[16] = {'c', 'o', 'p', 'c'};
  return std::memcmp(head + kVlr + 2, kUser, 16) == 0 && head[kVlr + 18] == 1 && head[kVlr + 19] == 0;
}
bool recognisesLaz(const std::uint8_t* head, std::size_t size) {
  return looksLikeLas(head, size) && size > 104 && (head[104] & 0xC0) != 0;
}
bool recognisesAnything(const std::uint8_t*, std::size_t) {
  return true;
}

std::unique_ptr<LasReader> lasReader(const std::string& path, const ReaderOptions& options,
                                     Diagnostics& diag) {
  auto las = std::make_unique<LasReader>(path, diag);
  las->setDecodeThreads(options.decodeThreads);
  las->setDropCache(options.dropCache);
  las->setLazBoundsCheck(options.lazBoundsCheck);
  return las;
}
std::unique_ptr<PointReader> openLas(const std::string& path, const ReaderOptions& options,
                                     Diagnostics& diag) {
  return lasReader(path, options, diag);
}
// LAZ and COPC are read by the LAS reader, which decodes their chunks (formats/pointcloud/laz).
std::unique_ptr<PointReader> openLaz(const std::string& path, const ReaderOptions& options,
                                     Diagnostics& diag) {
  if (path == "-") {  // (see StdinLazCopy)
    const std::string temp = copyStdinToTemporary();
    try {
      return std::make_unique<StdinLazCopy>(openLaz(temp, options, diag), temp);
    } catch (...) {
      ::unlink(temp.c_str());
      throw;
    }
  }
  auto las = lasReader(path, options, diag);
  std::uint32_t layers = laz::kLayerXY | laz::kLayerZ | laz::kLayerClass | laz::kLayerFlags;
  if (options.intensity) layers |= laz::kLayerIntensity;
  las->setLazLayers(layers);
  return las;
}
std::unique_ptr<PointReader> openXyz(const std::string& path, const ReaderOptions& options,
                                     Diagnostics& diag) {
  return std::make_unique<XyzReader>(path, options, diag);
}

// Reads up to kSniffBytes from the start of PATH (stdin: pushed back for the reader).
std::size_t sniff(const std::string& path, std::uint8_t* head) {
  std::size_t got = 0;
  if (path == "-") {
    while (got < kSniffBytes) {
      const std::size_t r = readStdin(head + got, kSniffBytes - got);
      if (r == 0) break;
      got += r;
    }
    unreadStdin(head, got);
    return got;
  }
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) throw DataError(path, std::string("cannot open: ") + std::strerror(errno));
  while (got < kSniffBytes) {
    ssize_t r;
    do r = ::read(fd, head + got, kSniffBytes - got);
    while (r < 0 && errno == EINTR);
    if (r < 0) {
      const int e = errno;
      ::close(fd);
      throw DataError(path, std::string("cannot read: ") + std::strerror(e));
    }
    if (r == 0) break;
    got += static_cast<std::size_t>(r);
  }
  ::close(fd);
  return got;
}

}  // namespace

const std::vector<ReaderRow>& readerTable() {
  static const std::vector<ReaderRow> table = {
      {"COPC", "laz", recognisesCopc, openLaz},  // (name.copc.laz)
      {"LAZ", "laz", recognisesLaz, openLaz},
      {"LAS", "las", looksLikeLas, openLas},
      {"XYZ", "xyz", recognisesAnything, openXyz},
  };
  return table;
}

namespace {

// Every row's extensions, sorted, once each.
std::vector<std::string> surveyExtensions() {
  std::vector<std::string> out;
  for (const ReaderRow& row : readerTable()) {
    const std::string list = row.extensions;
    for (std::size_t at = 0; at <= list.size();) {
      const std::size_t bar = std::min(list.find('|', at), list.size());
      const std::string e = list.substr(at, bar - at);
      if (!e.empty() && std::find(out.begin(), out.end(), e) == out.end()) out.push_back(e);
      at = bar + 1;
    }
  }
  std::sort(out.begin(), out.end());
  return out;
}

}  // namespace

bool isSurveyFileName(const std::string& name) {
  const auto dot = name.rfind('.');
  if (dot == std::string::npos) return false;
  std::string ext = name.substr(dot + 1);
  for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  static const std::vector<std::string> known = surveyExtensions();
  return std::find(known.begin(), known.end(), ext) != known.end();
}

std::string surveyExtensionsText() {
  std::vector<std::string> e = surveyExtensions();
  for (std::string& x : e) x = "." + x;
  return orList(e);
}

namespace {

// What is left for the XYZ reader must be text: an empty input, or binary data (a raster, an archive, a
// point cloud in a format tinbuild does not read) is named as such, not parsed as garbage columns.
void refuseNonText(const std::string& path, const std::uint8_t* head, std::size_t size) {
  if (size == 0) throw DataError(path, (path == "-" ? "standard input is empty" : "the file is empty (0 bytes)") +
                                           std::string(": there are no points to read"));
  std::size_t control = 0;
  bool nul = false;
  for (std::size_t i = 0; i < size; ++i) {
    const std::uint8_t c = head[i];
    nul = nul || c == 0;
    control += (c < 0x20 && c != '\t' && c != '\n' && c != '\r' && c != '\f') || c == 0x7f;
  }
  if (!nul && control * 20 <= size) return;  // text (UTF-8 and Latin-1 bytes above 0x7f are fine)
  struct Magic {
    const char* bytes;
    std::size_t n;
    const char* what;
  };
  static const Magic kMagic[] = {{"\x89PNG", 4, "a PNG image"},       {"II*\0", 4, "a TIFF image"},
                                 {"MM\0*", 4, "a TIFF image"},        {"PK\x03\x04", 4, "a ZIP archive"},
                                 {"\x1f\x8b", 2, "a gzip file"},      {"%PDF", 4, "a PDF document"},
                                 {"ASTM-E57", 8, "an E57 point cloud"}, {"\xff\xd8\xff", 3, "a JPEG image"},
                                 {"7z\xbc\xaf", 4, "a 7-Zip archive"},  {"BZh", 3, "a bzip2 file"}};
  std::string what = "binary data";
  for (const Magic& m : kMagic)
    if (size >= m.n && std::memcmp(head, m.bytes, m.n) == 0) what = m.what;
  char hex[3 * 8 + 1] = {};
  for (std::size_t i = 0; i < std::min<std::size_t>(size, 8); ++i) std::snprintf(hex + 3 * i, 4, "%02x ", head[i]);
  throw DataError(path, "it holds " + what + " (first bytes " + std::string(hex, std::min<std::size_t>(size, 8) * 3 - 1) +
                            "), not a point cloud tinbuild reads: LAS, LAZ, COPC or XYZ text");
}

}  // namespace

const ReaderRow& recogniseInput(const std::uint8_t* head, std::size_t size) {
  for (const ReaderRow& row : readerTable())
    if (row.recognises(head, size)) return row;
  return readerTable().back();
}

std::unique_ptr<PointReader> openPointReader(const std::string& path, const ReaderOptions& options,
                                             Diagnostics& diag) {
  std::uint8_t head[kSniffBytes] = {};
  const std::size_t got = sniff(path, head);
  const ReaderRow& row = recogniseInput(head, got);
  if (&row == &readerTable().back()) refuseNonText(path, head, got);  // (XYZ takes whatever is left)
  std::unique_ptr<PointReader> reader = row.open(path, options, diag);
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
