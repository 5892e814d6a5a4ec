// Whole positional reads and writes on a file descriptor: pread/pwrite repeated over interrupted
// (EINTR) and short transfers until all n bytes are done. Shared by the recording reader, the
// flash model and the view archive's spill file, which each word their own errors.
#pragma once

#include <cstddef>
#include <cstdint>

namespace d3d {

// Reads n bytes at `offset` into buf. Returns the bytes read: n, or fewer when the file ended
// (errno then 0) or a read failed (errno set by pread).
size_t PreadFull(int fd, void* buf, size_t n, uint64_t offset);
// Writes n bytes from buf at `offset`. Returns the bytes written: n, or fewer when a write failed
// (errno set by pwrite) or wrote nothing (errno then 0).
size_t PwriteFull(int fd, const void* buf, size_t n, uint64_t offset);

}  // namespace d3d
