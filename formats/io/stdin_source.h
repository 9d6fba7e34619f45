// Reading standard input with a little push-back.
//
// openPointReader must look at the first bytes of "-" to choose a reader (LAS starts with "LASF"), but a
// pipe cannot be rewound; the bytes it peeked are pushed back here and every reader reads stdin through
// readStdin(), which serves the pushed-back bytes first.
#pragma once

#include <cstddef>
#include <cstdint>

namespace tinbuild {

// Reads up to `size` bytes from stdin (pushed-back bytes first).  Returns 0 at end of input; retries on
// EINTR; throws DataError("-", ...) on a read error.
std::size_t readStdin(void* buffer, std::size_t size);

// Makes the next readStdin() calls return these bytes before anything else.
void unreadStdin(const std::uint8_t* data, std::size_t size);

}  // namespace tinbuild
