#include "formats/io/quiet_gdal.h"

#include <cpl_error.h>

#include <cerrno>
#include <cstring>

#include "libterrain/core/error.h"

namespace tinbuild {

namespace {

thread_local int t_failureErrno = 0;

bool isDiskErrno(int e) {
  return e == EIO || e == ENOSPC || e == EFBIG || e == EDQUOT || e == EROFS;
}

void keepDiskErrno(CPLErr level, CPLErrorNum, const char*) {
  if (level >= CE_Failure && isDiskErrno(errno) && t_failureErrno == 0) t_failureErrno = errno;
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
  std::string text = what + gdalMessage();
  if (isDiskErrno(e)) text += std::string(" (") + std::strerror(e) + ")";
  throw DataError(path, text);
}

}  // namespace tinbuild
