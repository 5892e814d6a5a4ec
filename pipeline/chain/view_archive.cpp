#include "pipeline/chain/view_archive.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <cstring>

#include "common/core/fd_io.h"

namespace d3d {

ViewArchive::~ViewArchive() {
  if (fd_ >= 0) ::close(fd_);
}

Status ViewArchive::SpillTo(const std::string& dir) {
  if (fd_ >= 0) return InvalidArgument("view archive: already spills to a file");
  int fd = -1;
#ifdef O_TMPFILE
  fd = ::open(dir.c_str(), O_TMPFILE | O_RDWR | O_CLOEXEC, S_IRUSR | S_IWUSR);
#endif
  if (fd < 0) {  // no O_TMPFILE here (or on this file system): a named file, unlinked at once
    std::string path = dir + "/.d3d-views-XXXXXX";
    fd = ::mkstemp(path.data());
    if (fd >= 0) ::unlink(path.c_str());
  }
  if (fd < 0)
    return IoError("view archive: cannot make a spill file in '" + dir +
                   "': " + std::strerror(errno));
  fd_ = fd;
  file_end_ = 0;
  return Status::Ok();
}

Status ViewArchive::Add(uint64_t burst_seq, std::string_view blob) {
  if (!entries_.empty() && burst_seq <= entries_.back().burst_seq) sorted_ = false;
  bytes_ += static_cast<int64_t>(blob.size());
  if (fd_ >= 0) {
    const size_t done = PwriteFull(fd_, blob.data(), blob.size(), static_cast<uint64_t>(file_end_));
    if (done == blob.size()) {
      entries_.push_back({burst_seq, file_end_, blob.size(), {}});
      file_end_ += static_cast<int64_t>(blob.size());
      spilled_bytes_ += static_cast<int64_t>(blob.size());
      return Status::Ok();
    }
    const std::string why = done > 0 || errno == 0 ? "a short write" : std::strerror(errno);
    entries_.push_back({burst_seq, -1, blob.size(), std::string(blob)});
    return IoError("view archive: burst " + std::to_string(burst_seq) +
                   " kept in memory: the spill file's write failed (" + why + ")");
  }
  entries_.push_back({burst_seq, -1, blob.size(), std::string(blob)});
  return Status::Ok();
}

Status ViewArchive::Get(uint64_t burst_seq, std::vector<cv::Mat>* frames) const {
  const Entry* e = nullptr;
  if (sorted_) {
    const auto it = std::lower_bound(entries_.begin(), entries_.end(), burst_seq,
                                     [](const Entry& a, uint64_t s) { return a.burst_seq < s; });
    if (it != entries_.end() && it->burst_seq == burst_seq) e = &*it;
  } else {
    for (auto it = entries_.rbegin(); it != entries_.rend() && e == nullptr; ++it)
      if (it->burst_seq == burst_seq) e = &*it;
  }
  if (e == nullptr)
    return NotFound("view archive: burst " + std::to_string(burst_seq) + " was not kept");
  if (e->offset < 0) return UnpackFrames(e->blob, frames);
  read_.resize(e->size);
  if (PreadFull(fd_, read_.data(), e->size, static_cast<uint64_t>(e->offset)) < e->size)
    return IoError("view archive: burst " + std::to_string(burst_seq) +
                   ": the spill file cannot be read back (" +
                   (errno == 0 ? std::string("it ends early") : std::string(std::strerror(errno))) +
                   ")");
  return UnpackFrames(read_, frames);
}

bool ViewArchive::Remove(uint64_t burst_seq) {
  // Undone views are the newest: search from the back.
  for (auto it = entries_.rbegin(); it != entries_.rend(); ++it) {
    if (it->burst_seq != burst_seq) continue;
    bytes_ -= static_cast<int64_t>(it->size);
    if (it->offset >= 0) {
      spilled_bytes_ -= static_cast<int64_t>(it->size);
      if (it->offset + static_cast<int64_t>(it->size) == file_end_)
        file_end_ = it->offset;  // the newest: its space is reused
    }
    entries_.erase(std::next(it).base());
    return true;
  }
  return false;
}

void ViewArchive::Clear() {
  entries_.clear();
  sorted_ = true;
  bytes_ = 0;
  spilled_bytes_ = 0;
  if (fd_ >= 0 && ::ftruncate(fd_, 0) == 0)
    file_end_ = 0;  // else the next blobs go after the old ones
}

}  // namespace d3d
