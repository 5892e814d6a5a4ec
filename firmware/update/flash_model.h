// A NOR-flash model for the probe's firmware storage: erase in blocks (all bytes → 0xFF), program
// in pages (only erased bytes), read anything. Backed by a file (the simulated probe's flash
// survives a killed process, like flash survives a power cut) or by memory (tests, fuzzers).
//
// Geometry and timing defaults follow a 128 Mbit SPI NOR part (Winbond W25Q128JV datasheet, §9.6
// AC electrical characteristics: 64 KiB block erase tBE2 150 ms typical, 256-byte page program tPP
// 0.4 ms typical). The timing is only modelled (it drives bwPollTimeout on a real link and the
// time estimate); the file-backed model runs as fast as the disk.
//
// Power-cut injection: after N operations (block erases + page programs) the next operation is
// torn — half of the page is programmed, or half of the block erased — and every later operation
// fails with kUnavailable, as if the supply had dropped mid-operation.
//
// Thread safety: none; one owner thread (the update agent's) calls every method.
#pragma once

#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "common/core/status.h"

namespace d3d::fw {

struct FlashGeometry {
  uint32_t erase_block_bytes = 64 * 1024;
  uint32_t page_bytes = 256;
  uint64_t size_bytes = 0;        // a multiple of erase_block_bytes
  double block_erase_ms = 150.0;  // typical time of one block erase
  double page_program_ms = 0.4;   // typical time of one page program
  // Throws std::invalid_argument unless page | erase block | size and all are positive.
  void Check() const;
};

struct FlashStats {
  int64_t block_erases = 0;
  int64_t page_programs = 0;
  double ModelledBusyMs(const FlashGeometry& g) const {
    return static_cast<double>(block_erases) * g.block_erase_ms +
           static_cast<double>(page_programs) * g.page_program_ms;
  }
};

class Flash {
 public:
  // Opens (or creates, fully erased) a file-backed flash of exactly geometry.size_bytes bytes.
  // Errors: kIoError if the file cannot be created/opened, kInvalidArgument if its size differs.
  static Status OpenFile(const std::string& path, const FlashGeometry& geometry,
                         std::unique_ptr<Flash>* out);
  // A fully erased flash in memory.
  static std::unique_ptr<Flash> InMemory(const FlashGeometry& geometry);
  ~Flash();
  Flash(const Flash&) = delete;
  Flash& operator=(const Flash&) = delete;

  const FlashGeometry& geometry() const { return geometry_; }
  const FlashStats& stats() const { return stats_; }

  // Reads out.size() bytes at addr. kInvalidArgument when out of range.
  Status Read(uint64_t addr, std::span<uint8_t> out) const;
  // Erases the block starting at addr (block-aligned). kInvalidArgument when misaligned/out of
  // range.
  Status EraseBlock(uint64_t addr);
  // Programs data at addr (page-aligned; the last page may be partial). Every byte written must be
  // erased (0xFF) first: kCorrupt "not erased" otherwise (DFU errCHECK_ERASED).
  Status Program(uint64_t addr, std::span<const uint8_t> data);

  // Power-cut injection: -1 (default) never; otherwise operation number `ops` (0-based) is torn.
  void CutPowerAfterOps(int64_t ops) { cut_after_ops_ = ops; }
  bool power_cut() const { return dead_; }
  // Power comes back (in-memory tests; a file-backed probe restarts as a new process instead).
  void PowerCycle() {
    dead_ = false;
    cut_after_ops_ = -1;
  }
  int64_t ops() const { return ops_; }

 private:
  explicit Flash(const FlashGeometry& g) : geometry_(g) {}
  Status RawRead(uint64_t addr, std::span<uint8_t> out) const;
  Status RawWrite(uint64_t addr, std::span<const uint8_t> data);
  // True when this operation is the torn one (and marks the flash dead).
  bool TearNow();

  FlashGeometry geometry_;
  int fd_ = -1;               // file-backed when >= 0
  std::vector<uint8_t> mem_;  // memory-backed otherwise
  FlashStats stats_;
  int64_t ops_ = 0;
  int64_t cut_after_ops_ = -1;
  bool dead_ = false;
};

}  // namespace d3d::fw
