// Undo requests and what each did, shared by the host's stages. Any thread requests; the ingest
// stage sends the requests down the graph with the bursts; the register stage applies them
// (Record); the preview and fuse stages then cut the views of the undos they have not applied yet
// (Cut). Threads: every member is safe from any thread (atomics, and a mutex for the log).
#pragma once

#include <atomic>
#include <cstdint>
#include <mutex>
#include <string>
#include <vector>

#include "pipeline/chain/scan_chain.h"

namespace d3d {

class UndoLog {
 public:
  // `enabled`: undo is on (the tracker keeps an undo journal and the views' frames are kept).
  explicit UndoLog(bool enabled) : enabled_(enabled) {}

  // Any thread: one more request; false (and nothing) when undo is off.
  bool Request();
  bool enabled() const { return enabled_; }
  uint64_t requests() const { return requests_.load(); }

  // Register thread: what applying one request did. Appends the first view it took back to the
  // log (when it took any), sets the message and the counters. Returns u.ok.
  bool Record(const ScanRegistrar::UndoResult& u);
  // The smallest first view of undos [from_gen, to_gen) of the log (what a stage that applied
  // from_gen must cut); INT64_MAX when none.
  int64_t Cut(uint64_t from_gen, uint64_t to_gen) const;
  // What the latest undo did ("undid 2.0 s: 57 views", or why nothing).
  std::string LastMessage() const;
  uint64_t done() const { return done_.load(); }  // applied or refused
  uint64_t refused() const { return refused_.load(); }
  uint64_t views_undone() const { return views_undone_.load(); }

 private:
  const bool enabled_;
  std::atomic<uint64_t> requests_{0}, done_{0}, views_undone_{0}, refused_{0};
  mutable std::mutex mu_;
  std::vector<int64_t> log_;  // per undo applied: its first view taken back
  std::string message_;
};

}  // namespace d3d
