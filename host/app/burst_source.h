// Where the host's stage graph takes its bursts from (the ingest stage): the probe over DDS
// (host/receiver BurstReceiver) or a recording (common/recording, d3d-record's format).
//
// Threads: Next() runs on the graph's ingest thread only. The DDS listener thread is Cyclone's:
// BurstReceiver checks and copies samples into its own bounded queue and never waits for us; the
// ingest thread pops them, copies the pixels into the item's preallocated frames and gives the
// sample's buffers back (Recycle). Counters and probe_lost() are atomics, readable from any thread.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "calib/model/probe_calibration.h"
#include "common/core/status.h"
#include "common/recording/recording.h"
#include "host/receiver/receiver.h"
#include "protocol/messages.h"

namespace d3d {

// The burst part of one graph item, filled by a source.
struct IngestedBurst {
  uint64_t burst_seq = 0;
  int64_t capture_ns = 0;       // mid-burst capture time (probe clock, Unix epoch ns)
  int64_t receive_ns = 0;       // when the host got it (recording: when it was recorded)
  std::vector<cv::Mat> frames;  // H×W CV_8U (or CV_16U), reused between bursts
};

// Copies a burst message's pixels into `out` (reusing its frames). INVALID_ARGUMENT for a burst
// whose geometry does not fit (the receiver has checked it already).
[[nodiscard]] Status CopyBurst(const proto::BurstMsg& msg, int64_t receive_ns, IngestedBurst* out);

class BurstSource {
 public:
  enum class Result { kBurst, kNothing, kEnd };  // kNothing: no burst yet (call again)
  virtual ~BurstSource() = default;
  // Ingest thread: the next burst into *out. May wait a little (≤ ~50 ms) for one.
  virtual Result Next(IngestedBurst* out) = 0;
  uint64_t received() const {
    return received_.load(std::memory_order_relaxed);
  }  // bursts that reached the host
  uint64_t malformed() const {
    return malformed_.load(std::memory_order_relaxed);
  }  // dropped by the checks / undecodable
  uint64_t dropped() const {
    return dropped_.load(std::memory_order_relaxed);
  }  // dropped before the graph (receiver queue full)
  bool probe_lost() const { return probe_lost_.load(std::memory_order_relaxed); }
  uint64_t probe_returns() const { return probe_returns_.load(std::memory_order_relaxed); }
  uint64_t missing() const {
    return missing_.load(std::memory_order_relaxed);
  }  // sequence gaps: lost before the host
  // Set before the graph starts. A burst the source leaves out by design (a replay's selection,
  // RecordingSourceOptions::select_capture_ns) is handed to `sink` on the ingest thread, in capture
  // order: a live host's graph drops bursts too, and they still reach the gap bridge's ring.
  void set_skipped_sink(std::function<void(const IngestedBurst&)> sink) {
    skipped_sink_ = std::move(sink);
  }

 protected:
  std::function<void(const IngestedBurst&)> skipped_sink_;
  std::atomic<uint64_t> received_{0}, malformed_{0}, dropped_{0}, probe_returns_{0}, missing_{0};
  std::atomic<bool> probe_lost_{false};
};

struct RecordingSourceOptions {
  double rate = 0;  // 0: as fast as the graph takes them (lossless replay); > 0: paced by the
                    // recorded times × rate
  int64_t max_bursts = 0;  // > 0: end after this many bursts
  // Non-empty: only the bursts whose capture time (IngestedBurst::capture_ns, ns) lies within
  // select_tolerance_ns of one of these times are delivered, the rest are skipped (skipped(), not
  // counted in received()).
  // E.g. the times of a live run's poses.txt: the same views again, losslessly, to reproduce what
  // the live host's tracker saw. Any order; max_bursts counts delivered bursts.
  std::vector<int64_t> select_capture_ns;
  int64_t select_tolerance_ns = 1000000;  // 1 ms; bursts are ≥ 10 ms apart
  void Check() const;                     // throws std::invalid_argument
};

class RecordingBurstSource final : public BurstSource {
 public:
  // NOT_FOUND / PARSE_ERROR / CORRUPT / UNSUPPORTED as RecordingReader::OpenFile; INVALID_ARGUMENT
  // for a recording without a PhaseBurst channel or without a calibration (header or ProbeInfo).
  [[nodiscard]] static Status Open(const std::string& path, const RecordingSourceOptions& options,
                                   std::unique_ptr<RecordingBurstSource>* out);
  const ProbeCalibration& calibration() const { return calibration_; }
  const RecordingHeader& header() const { return reader_->header(); }
  const RecordingDiagnostics& diagnostics() const { return reader_->diagnostics(); }
  Result Next(IngestedBurst* out) override;
  // Bursts left out by select_capture_ns (well-formed, not delivered).
  uint64_t skipped() const { return skipped_.load(std::memory_order_relaxed); }
  // What a damaged recording lost of its bursts (from their burst_seq; missing() counts the jumps
  // within intact data, lost before the recorder). Read it once Next() has returned kEnd.
  const SequenceLossCounter& bursts_lost() const { return lost_; }

 private:
  bool Selected(int64_t capture_ns) const;
  RecordingSourceOptions o_;
  std::atomic<uint64_t> skipped_{0};
  std::unique_ptr<RecordingReader> reader_;
  SequenceLossCounter lost_{nullptr};
  bool lost_ended_ = false;
  ProbeCalibration calibration_;
  uint16_t burst_channel_ = 0;
  size_t chunk_ = 0, message_ = 0;
  int64_t delivered_ = 0;
  std::vector<RecordedMessage> messages_;
  proto::BurstMsg msg_;
  int64_t t0_file_ = -1, t0_wall_ = 0;
};

struct DdsSourceOptions {
  double probe_timeout_s = 1.0;  // no burst for this long after some: "probe lost"
  double idle_exit_s = 0;  // > 0: end the scan after this long without a burst (after the first)
  // > 0 (live): a burst that waited longer than this in the receiver's queue is dropped (counted in
  // dropped()) rather than ingested: at start-up the graph would otherwise begin with the bursts
  // that queued while it was being set up, seconds older than the next one it takes.
  double max_age_s = 0;
  void Check() const;
};

class DdsBurstSource final : public BurstSource {
 public:
  // `receiver` is started and borrowed (outlives the source).
  DdsBurstSource(BurstReceiver* receiver, const DdsSourceOptions& options);
  // Waits (up to timeout_s, or until *stop) for the probe's ProbeInfo and its calibration, calling
  // `while_waiting` (if set) between its looks, every 20 ms (e.g. a preview frame).
  // UNAVAILABLE without one (or when stopped first).
  [[nodiscard]] Status WaitForCalibration(double timeout_s, const std::atomic<bool>* stop,
                                          ProbeCalibration* calibration, proto::InfoMsg* info,
                                          const std::function<void()>& while_waiting = {});
  Result Next(IngestedBurst* out) override;

 private:
  BurstReceiver* rx_;
  DdsSourceOptions o_;
  ReceivedSample sample_;
  int64_t last_burst_ns_ = 0;  // steady clock
  uint64_t copy_failures_ = 0;
  uint64_t stale_ = 0;  // dropped for max_age_s
};

}  // namespace d3d
