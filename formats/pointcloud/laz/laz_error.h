// LazError: the one exception type of the LAZ codec.
//
// Every malformed input the codec can detect (bad VLR, unknown item version, truncated or damaged chunk,
// inconsistent chunk table) is reported by throwing LazError with a message that names what is wrong.
// The codec works on byte ranges and knows nothing of files, so the caller adds the file name, chunk index
// and byte offset when it rethrows or reports. The codec never aborts and never reads out of bounds.
#pragma once

#include <stdexcept>

namespace tinbuild::laz {

class LazError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

}  // namespace tinbuild::laz
