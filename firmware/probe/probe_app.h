// The probe's acquisition process: capture loop (projector trigger → camera frame → frame sync),
// DDS publishing of PhaseBurst / ProbeInfo / ProbeStatus (1 Hz and on every state change) and
// ProbeCommand handling with ProbeCommandAck. d3d-probe is a thin wrapper around this class.
//
// Threads and ownership:
//   - Run()'s caller: the capture loop. Owns the backend's and the frame sync's state; frames are
//     immutable shared buffers (CapturedFrame::pixels) handed to the publish queue.
//   - publish thread: takes assembled bursts from a bounded queue (publish_queue), writes them with
//     the frames' buffers referenced, not copied, by the DDS sample; a full queue drops the burst
//     (counted as a publish failure) instead of stalling the capture loop.
//   - status thread: ProbeStatus once per second and at each state transition.
//   - command thread: waits on the ProbeCommand reader (waitset), applies commands, acks each.
//   The projector driver is shared by the capture loop and the command thread under projector_mu_.
//
// Hooks for the firmware-update agent (issue 8): state() gives a ProbeStateQuery (IsStreaming());
// SetFirmwareVersion() changes the version reported in ProbeInfo and re-publishes it.
#pragma once

#include <atomic>
#include <condition_variable>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "firmware/probe/capture_backend.h"
#include "firmware/probe/frame_sync.h"
#include "firmware/probe/probe_state.h"
#include "firmware/probe/projector_driver.h"
#include "protocol/dds_setup.h"

namespace d3d {

struct ProbeAppOptions {
  std::string serial = "SIM-0001";          // ≤ 32 characters
  std::string firmware_version = "0.0.0";   // reported in ProbeInfo
  double rate_hz = 30.0;                    // bursts per second
  int64_t max_bursts = 0;                   // > 0: stop after this many bursts (then wait for acks)
  bool start_streaming = true;              // false: start idle, wait for CMD_START_STREAMING
  int publish_queue = 8;                    // bursts waiting for the publish thread
  int64_t ack_timeout_ns = 15'000'000'000;  // at the end: how long reliable readers may take
  int64_t status_period_ns = 1'000'000'000;  // ProbeStatus period (1 Hz)
  int max_recoveries = 3;                    // error → recovering attempts before giving up
  int wait_readers = 0;  // Run(): first wait for this many PhaseBurst readers ...
  int64_t wait_readers_timeout_ns = 60'000'000'000;  // ... at most this long (then UNAVAILABLE)
  // Called on the publish thread after each successful PhaseBurst write (tests, manifests).
  std::function<void(uint64_t burst_seq, const std::vector<CapturedFrame>& frames)> on_published;
  void Check() const;  // throws std::invalid_argument
};

struct ProbeCounters {
  std::atomic<uint64_t> bursts_published{0};
  std::atomic<uint64_t> publish_failures{0};
  std::atomic<uint64_t> capture_overruns{0};  // bursts that started late (the loop fell behind)
  std::atomic<uint64_t> commands{0};
  std::atomic<uint64_t> last_command_id{0};
};

class ProbeApp {
 public:
  // Takes the opened backend and the projector; `participant` is borrowed and must outlive the app.
  ProbeApp(const ProbeAppOptions& options, std::unique_ptr<CaptureBackend> backend,
           std::unique_ptr<ProjectorDriver> projector, proto::DdsParticipant* participant);
  ~ProbeApp();

  // Creates the DDS entities, configures the projector, publishes ProbeInfo, starts the threads.
  [[nodiscard]] Status Start();
  // The capture loop; returns when max_bursts were captured and acknowledged (OK; UNAVAILABLE if
  // readers did not acknowledge in time), when RequestStop() was called (OK), or when the probe
  // could not recover from errors (the last error).
  [[nodiscard]] Status Run();
  void RequestStop() { stop_ = true; }  // thread-safe, async-signal-safe (atomic store)

  const ProbeStateQuery& state() const { return state_; }
  const ProbeCounters& counters() const { return counters_; }
  const FrameSyncCounters& sync_counters() const { return sync_.counters(); }
  void SetFirmwareVersion(const std::string& version);
  [[nodiscard]] Status PublishInfo();
  // While `reason` is non-empty, CMD_START_STREAMING and SetStreaming(true) are refused with
  // UNAVAILABLE naming it (the update agent sets it for the DFU session). Thread-safe.
  void SetStreamingInhibit(const std::string& reason);
  // Starts (idle → streaming) or stops (streaming → idle) streaming, as the DDS commands do.
  // Thread-safe; UNAVAILABLE while inhibited, INVALID_ARGUMENT for an illegal transition.
  [[nodiscard]] Status SetStreaming(bool on);

 private:
  struct PendingBurst {
    std::vector<CapturedFrame> frames;
    int64_t exposure_ns;
  };
  Status CaptureOneBurst(int64_t t0_ns, uint64_t* trigger_seq);
  void PublishLoop();
  void StatusLoop();
  void CommandLoop();
  void PublishStatus();
  bool Recover(const Status& cause);
  std::string HandleCommand(int kind, double value, bool* accepted);

  ProbeAppOptions options_;
  std::unique_ptr<CaptureBackend> backend_;
  std::unique_ptr<ProjectorDriver> projector_;
  std::mutex projector_mu_;
  proto::DdsParticipant* participant_;
  ProbeStateMachine state_;
  FrameSync sync_;
  ProbeCounters counters_;
  std::atomic<bool> stop_{false};
  std::atomic<bool> threads_stop_{false};
  std::mutex info_mu_;
  std::string firmware_version_;   // guarded by info_mu_
  std::string streaming_inhibit_;  // guarded by info_mu_

  dds_entity_t burst_writer_ = 0, info_writer_ = 0, status_writer_ = 0, ack_writer_ = 0,
               command_reader_ = 0;

  std::mutex queue_mu_;
  std::condition_variable queue_cv_;
  std::deque<PendingBurst> queue_;
  bool publishing_ = false;      // the publish thread holds a burst (guarded by queue_mu_)
  uint64_t next_burst_seq_ = 0;  // publish thread only

  std::mutex status_mu_;
  std::condition_variable status_cv_;
  bool status_now_ = false;

  std::vector<std::thread> threads_;
};

}  // namespace d3d
