#include "common/core/fd_io.h"

#include <unistd.h>

#include <cerrno>

namespace d3d {

size_t PreadFull(int fd, void* buf, size_t n, uint64_t offset) {
  char* p = static_cast<char*>(buf);
  size_t done = 0;
  while (done < n) {
    const ssize_t r = ::pread(fd, p + done, n - done, static_cast<off_t>(offset + done));
    if (r < 0 && errno == EINTR) continue;
    if (r == 0) errno = 0;  // the file ended
    if (r <= 0) break;
    done += static_cast<size_t>(r);
  }
  return done;
}

size_t PwriteFull(int fd, const void* buf, size_t n, uint64_t offset) {
  const char* p = static_cast<const char*>(buf);
  size_t done = 0;
  while (done < n) {
    const ssize_t w = ::pwrite(fd, p + done, n - done, static_cast<off_t>(offset + done));
    if (w < 0 && errno == EINTR) continue;
    if (w == 0) errno = 0;
    if (w <= 0) break;
    done += static_cast<size_t>(w);
  }
  return done;
}

}  // namespace d3d
