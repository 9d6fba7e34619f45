// GDAL's errors, kept quiet and put into ours.
//
// GDAL prints its errors on stderr by default.  While a QuietGdal lives (on this thread), they are not
// printed: the caller throws a DataError naming the file instead, with GDAL's last message (gdalMessage)
// and, when the failing call met the disk, the system's reason (gdalFailure: "Error writing TIFF header"
// is a full disk or a failing one; GDAL's message does not say which, and later calls overwrite errno,
// so the handler keeps the errno of the moment GDAL reported the failure).
#pragma once

#include <string>

namespace tinbuild {

class QuietGdal {
 public:
  QuietGdal();
  ~QuietGdal();
  QuietGdal(const QuietGdal&) = delete;
  QuietGdal& operator=(const QuietGdal&) = delete;
};

// ": GDAL's last message", or "" when it has none.
std::string gdalMessage();

// Throws DataError(path, what + GDAL's message + " (the system's reason)" when a disk error caused it).
[[noreturn]] void gdalFailure(const std::string& path, const std::string& what);

}  // namespace tinbuild
