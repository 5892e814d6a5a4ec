#include "firmware/update/flash_model.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>

#include "common/core/fd_io.h"

namespace d3d::fw {

void FlashGeometry::Check() const {
  D3D_CHECK_MSG(page_bytes > 0 && erase_block_bytes > 0 && size_bytes > 0,
                "flash geometry must be positive");
  D3D_CHECK_MSG(erase_block_bytes % page_bytes == 0,
                "erase block " << erase_block_bytes << " not a multiple of page " << page_bytes);
  D3D_CHECK_MSG(size_bytes % erase_block_bytes == 0,
                "flash size " << size_bytes << " not a multiple of the erase block");
  D3D_CHECK_MSG(block_erase_ms >= 0 && page_program_ms >= 0, "flash timings must be non-negative");
}

Status Flash::OpenFile(const std::string& path, const FlashGeometry& g,
                       std::unique_ptr<Flash>* out) {
  g.Check();
  const int fd = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (fd < 0) return IoError("flash: cannot open " + path + ": " + std::strerror(errno));
  struct stat st {};
  if (::fstat(fd, &st) != 0) {
    ::close(fd);
    return IoError("flash: cannot stat " + path);
  }
  std::unique_ptr<Flash> f(new Flash(g));
  f->fd_ = fd;
  if (st.st_size == 0) {
    // A new part: every byte erased.
    std::vector<uint8_t> ff(g.erase_block_bytes, 0xFF);
    for (uint64_t a = 0; a < g.size_bytes; a += g.erase_block_bytes)
      D3D_RETURN_IF_ERROR(f->RawWrite(a, ff));
  } else if (static_cast<uint64_t>(st.st_size) != g.size_bytes) {
    return InvalidArgument("flash: " + path + " holds " + std::to_string(st.st_size) +
                           " bytes, the geometry says " + std::to_string(g.size_bytes));
  }
  *out = std::move(f);
  return Status::Ok();
}

std::unique_ptr<Flash> Flash::InMemory(const FlashGeometry& g) {
  g.Check();
  std::unique_ptr<Flash> f(new Flash(g));
  f->mem_.assign(g.size_bytes, 0xFF);
  return f;
}

Flash::~Flash() {
  if (fd_ >= 0) ::close(fd_);
}

Status Flash::RawRead(uint64_t addr, std::span<uint8_t> out) const {
  if (fd_ < 0) {
    std::memcpy(out.data(), mem_.data() + addr, out.size());
    return Status::Ok();
  }
  const size_t done = PreadFull(fd_, out.data(), out.size(), addr);
  if (done < out.size()) return IoError("flash: read failed at " + std::to_string(addr + done));
  return Status::Ok();
}

Status Flash::RawWrite(uint64_t addr, std::span<const uint8_t> data) {
  if (fd_ < 0) {
    std::memcpy(mem_.data() + addr, data.data(), data.size());
    return Status::Ok();
  }
  const size_t done = PwriteFull(fd_, data.data(), data.size(), addr);
  if (done < data.size()) return IoError("flash: write failed at " + std::to_string(addr + done));
  return Status::Ok();
}

bool Flash::TearNow() {
  const bool tear = cut_after_ops_ >= 0 && ops_ == cut_after_ops_;
  ++ops_;
  if (tear) dead_ = true;
  return tear;
}

Status Flash::Read(uint64_t addr, std::span<uint8_t> out) const {
  if (dead_) return Unavailable("flash: power cut");
  if (addr > geometry_.size_bytes || out.size() > geometry_.size_bytes - addr) {
    return InvalidArgument("flash: read of " + std::to_string(out.size()) + " bytes at " +
                           std::to_string(addr) + " is out of range");
  }
  return RawRead(addr, out);
}

Status Flash::EraseBlock(uint64_t addr) {
  if (dead_) return Unavailable("flash: power cut");
  if (addr % geometry_.erase_block_bytes != 0 || addr >= geometry_.size_bytes) {
    return InvalidArgument("flash: erase at " + std::to_string(addr) +
                           " is misaligned or out of range");
  }
  std::vector<uint8_t> ff(geometry_.erase_block_bytes, 0xFF);
  if (TearNow()) {
    (void)RawWrite(addr, std::span<const uint8_t>(ff).first(ff.size() / 2));
    return Unavailable("flash: power cut during erase");
  }
  ++stats_.block_erases;
  return RawWrite(addr, ff);
}

Status Flash::Program(uint64_t addr, std::span<const uint8_t> data) {
  if (dead_) return Unavailable("flash: power cut");
  const uint32_t page = geometry_.page_bytes;
  if (addr % page != 0 || addr > geometry_.size_bytes ||
      data.size() > geometry_.size_bytes - addr) {
    return InvalidArgument("flash: program of " + std::to_string(data.size()) + " bytes at " +
                           std::to_string(addr) + " is misaligned or out of range");
  }
  std::vector<uint8_t> current(data.size());
  D3D_RETURN_IF_ERROR(RawRead(addr, current));
  if (!std::all_of(current.begin(), current.end(), [](uint8_t b) { return b == 0xFF; })) {
    return Corrupt("flash: program at " + std::to_string(addr) + " over bytes that are not erased");
  }
  for (size_t off = 0; off < data.size(); off += page) {
    const size_t n = std::min<size_t>(page, data.size() - off);
    if (TearNow()) {
      (void)RawWrite(addr + off, data.subspan(off, n / 2));
      return Unavailable("flash: power cut during page program");
    }
    ++stats_.page_programs;
    D3D_RETURN_IF_ERROR(RawWrite(addr + off, data.subspan(off, n)));
  }
  return Status::Ok();
}

}  // namespace d3d::fw
