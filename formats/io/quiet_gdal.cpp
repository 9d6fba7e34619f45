#include "formats/io/quiet_gdal.h"

#include <cpl_error.h>

#include <cerrno>

#include "formats/io/output_file.h"
#include "libterrain/core/error.h"

namespace tinbuild {

namespace {

thread_local int t_failureErrno = 0;

void keepDiskErrno(CPLErr level, CPLErrorNum, const char*) {
  const int e = errno;  // (first: nothing below may change it)
  if (level >= CE_Failure && t_failureErrno == 0 && !diskErrorReason(e).empty()) t_failureErrno = e;
}

}  // namespace

QuietGdal::QuietGdal() {
  CPLPushErrorHandler(keepDiskErrno);
  CPLErrorReset();
  t_failureErrno = 0;
}

QuietGdal::~QuietGdal() {
  CPLPopErrorHandler();
}

std::string gdalMessage() {
  const char* msg = CPLGetLastErrorMsg();
  return msg && *msg ? std::string(": ") + msg : std::string();
}

void gdalFailure(const std::string& path, const std::string& what) {
  const int e = t_failureErrno ? t_failureErrno : errno;
  throw DataError(path, what + gdalMessage() + diskErrorReason(e));
}

}  // namespace tinbuild
