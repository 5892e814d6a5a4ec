// The host's receiving end of the probe protocol: subscribes to PhaseBurst, ProbeInfo and
// ProbeStatus, checks every sample, and hands accepted ones to the consumer through a bounded
// queue.
//
// Checks (a failing sample is dropped, counted by reason and logged, rate-limited):
//   all:        protocol major version (proto::ProtocolCompatible), serial filter
//   PhaseBurst: 1 ≤ width, height ≤ 8192; bit depth 1..16; 3..8 frames; every frame exactly
//               width × height × (1 or 2) bytes; frame timestamps and pattern indices increasing
//   ProbeInfo:  the calibration JSON parses (calib/model) and its camera size matches width ×
//   height ProbeStatus: state within the enum
// Sequence: per probe serial, a burst_seq above the next expected counts a gap (and the missing
// bursts); one below counts a duplicate/reordering and is dropped; 0 after others is a probe
// restart.
//
// Threads: the DDS listener thread (Cyclone's receive thread) takes samples, checks and copies them
// into recycled message buffers and pushes them to the queue; it never waits for the consumer: when
// the queue is full the sample is dropped (preview: the oldest queued burst instead) and counted.
// Pop()/Recycle()/counters()/LatestInfo() may be called from any thread.
#pragma once

#include <array>
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <mutex>
#include <string>
#include <variant>
#include <vector>

#include "calib/model/probe_calibration.h"
#include "common/core/status.h"
#include "protocol/d3d_protocol.h"
#include "protocol/dds_setup.h"
#include "protocol/messages.h"

namespace d3d {

enum class DropReason : int {
  kProtocolVersion = 0,
  kSerial,    // not the probe we listen to
  kGeometry,  // width/height/bit depth out of range
  kFrameCount,
  kFrameSize,
  kFrameOrder,   // timestamps or pattern indices not increasing
  kDuplicate,    // burst_seq at or below one already delivered
  kCalibration,  // ProbeInfo calibration does not parse or does not match the image size
  kBadEnum,
  kQueueFull,
  kCount
};
const char* DropReasonName(DropReason r);

struct ReceiverOptions {
  std::string serial;    // accept only this probe; "" = any
  bool preview = false;  // QoS: preview (freshest burst, best effort) or every burst (reliable)
  size_t queue_capacity = 32;  // samples waiting for the consumer
  // Where drop reasons are logged (first 5 of each reason, then every 100th); nullptr = silent.
  std::function<void(const std::string&)> log;
  void Check() const;  // throws std::invalid_argument
};

struct ReceivedSample {
  int64_t receive_ns = 0;  // when the listener took it (Unix epoch)
  std::variant<proto::BurstMsg, proto::InfoMsg, proto::StatusMsg> msg;
};

struct ReceiverCounters {
  uint64_t bursts_accepted = 0, infos_accepted = 0, statuses_accepted = 0;
  uint64_t sequence_gaps = 0;   // times a burst_seq jumped forward
  uint64_t bursts_missing = 0;  // bursts skipped by those jumps
  uint64_t probe_restarts = 0;
  std::array<uint64_t, static_cast<size_t>(DropReason::kCount)> dropped{};
  uint64_t dropped_total() const;
};

// The pure checks, also used by tests and d3d-replay --info. "" when fine, else the reason's
// detail.
DropReason CheckBurst(const d3d_proto_PhaseBurst& s, std::string* detail);  // kCount = accepted
DropReason CheckInfo(const proto::InfoMsg& m, ProbeCalibration* calibration, std::string* detail);

class BurstReceiver {
 public:
  explicit BurstReceiver(const ReceiverOptions& options);
  ~BurstReceiver();  // deletes the readers (listeners stop) before the queue goes away
  BurstReceiver(const BurstReceiver&) = delete;
  BurstReceiver& operator=(const BurstReceiver&) = delete;

  // Creates topics and readers with listeners on `participant` (borrowed; must outlive Stop()).
  [[nodiscard]] Status Start(proto::DdsParticipant* participant);
  void Stop();  // deletes the readers; queued samples stay poppable

  // The next sample in arrival order; false after timeout_ns without one.
  bool Pop(ReceivedSample* out, int64_t timeout_ns);
  // Gives a consumed sample's buffers back for reuse by the listener (optional; avoids
  // allocations).
  void Recycle(ReceivedSample&& sample);
  // The latest accepted ProbeInfo and its parsed calibration; false if none yet.
  bool LatestInfo(proto::InfoMsg* info, ProbeCalibration* calibration) const;
  ReceiverCounters counters() const;
  // Readers' DDS entities (tests, benchmarks): 0 before Start.
  dds_entity_t burst_reader() const { return burst_reader_; }

 private:
  static void OnBurst(dds_entity_t reader, void* self);
  static void OnInfo(dds_entity_t reader, void* self);
  static void OnStatus(dds_entity_t reader, void* self);
  void Drop(DropReason r, const std::string& detail);
  void Push(ReceivedSample&& s);

  ReceiverOptions options_;
  dds_entity_t burst_reader_ = 0, info_reader_ = 0, status_reader_ = 0;
  mutable std::mutex mu_;  // guards everything below
  std::condition_variable cv_;
  std::deque<ReceivedSample> queue_;
  std::vector<proto::BurstMsg> spare_bursts_;  // recycled buffers
  std::map<std::string, uint64_t> next_seq_;   // per serial
  ReceiverCounters counters_;
  bool have_info_ = false;
  proto::InfoMsg info_;
  ProbeCalibration calibration_;
};

}  // namespace d3d
