// The "sim" capture backend: the virtual probe (sim/session) as a camera.
//
// Rendering is far slower than the probe's burst rate (~3.5 bursts/s per core at 640 × 480), so the
// backend renders a cycle of `sim_cycle` consecutive bursts of the scan path at start-up (Open) and
// then, at capture time, returns frame k of burst (n mod cycle) for the n-th burst, stamped with
// the real capture time. The bytes published are exactly the rendered images; only the timestamps
// are live. With max_bursts ≤ sim_cycle every burst is distinct.
//
// Fault injection (sim_fault_rate p, seeded by `seed`): each frame, with probability p, is one of
// (a) preceded by a frame the sensor lost (camera_frame_seq jumps), (b) torn: exposed across the
// pattern switch (timestamp off by half a frame interval), (c) latched with the previous trigger's
// counter (out of order). frame_sync must drop those bursts.
#include <chrono>
#include <mutex>
#include <random>
#include <thread>

#include "firmware/probe/capture_backend.h"
#include "sim/session/sim_session.h"

namespace d3d {
namespace {

class SimCaptureBackend final : public CaptureBackend {
 public:
  explicit SimCaptureBackend(const CaptureOptions& o)
      : options_(o), rng_(o.seed * 2654435761u + 17u) {}

  Status Open() override {
    SimSessionOptions so;
    so.model = options_.sim_model;
    so.trajectory = options_.trajectory;
    so.seed = options_.seed;
    so.burst_rate_hz = options_.rate_hz;
    so.camera_width = options_.width;
    so.camera_height = options_.height;
    so.render.threads = options_.render_threads;
    std::unique_ptr<SimSession> session;
    D3D_RETURN_IF_ERROR(SimSession::Create(so, &session));
    int64_t n = std::min<int64_t>(options_.sim_cycle, session->NumBursts());
    if (options_.max_bursts > 0) n = std::min<int64_t>(n, options_.max_bursts);
    if (n < 1)
      return InvalidArgument("sim: the trajectory holds no burst at " +
                             std::to_string(options_.rate_hz) + " Hz");
    cycle_.resize(static_cast<size_t>(n));
    for (int64_t b = 0; b < n; ++b) {
      const Burst burst = session->RenderBurst(b, /*with_truth=*/false);
      for (const BurstFrame& f : burst.frames) {
        const cv::Mat img = f.image.isContinuous() ? f.image : f.image.clone();
        cycle_[b].push_back(std::make_shared<const std::vector<uint8_t>>(
            img.data, img.data + img.total() * img.elemSize()));
      }
    }
    const ProbeDesign& d = session->probe().design();
    info_.backend = "sim";
    info_.sensor_model =
        "virtual-probe " + std::to_string(options_.width) + "x" + std::to_string(options_.height);
    info_.width = options_.width;
    info_.height = options_.height;
    info_.bit_depth = d.sensor.bits;
    info_.exposure_ns = d.sensor.exposure_ns;
    info_.frame_interval_ns = so.render.frame_interval_ns;
    info_.calibration = session->calibration();
    info_.patterns_per_burst = static_cast<int>(cycle_[0].size());
    return Status::Ok();
  }

  const CaptureInfo& info() const override { return info_; }

  Status SetExposure(int64_t exposure_ns) override {
    if (exposure_ns <= 0 || exposure_ns >= info_.frame_interval_ns)
      return InvalidArgument("exposure must be in (0, frame interval " +
                             std::to_string(info_.frame_interval_ns) + " ns)");
    std::lock_guard<std::mutex> lock(mu_);
    info_.exposure_ns =
        exposure_ns;  // metadata only: the cycle was rendered at the design exposure
    return Status::Ok();
  }

  Status Capture(int pattern_index, uint64_t trigger_seq, int64_t t_ns,
                 CapturedFrame* out) override {
    if (pattern_index < 0 || pattern_index >= info_.patterns_per_burst)
      return InvalidArgument("sim: no pattern " + std::to_string(pattern_index));
    if (pattern_index == 0 && captured_ > 0) ++burst_;
    ++captured_;
    int64_t exposure_ns;
    {
      std::lock_guard<std::mutex> lock(mu_);
      exposure_ns = info_.exposure_ns;
    }
    // The exposure ends at t + exposure/2: wait for it (system clock, like the timestamps).
    std::this_thread::sleep_until(
        std::chrono::system_clock::time_point(std::chrono::nanoseconds(t_ns + exposure_ns / 2)));
    out->pattern_index = pattern_index;
    out->trigger_seq = trigger_seq;
    out->camera_frame_seq = ++camera_seq_;
    out->timestamp_ns = t_ns;
    out->pixels = cycle_[burst_ % cycle_.size()][static_cast<size_t>(pattern_index)];
    if (options_.sim_fault_rate > 0 && uniform_(rng_) < options_.sim_fault_rate) {
      switch (rng_() % 3) {
        case 0:
          out->camera_frame_seq = ++camera_seq_;
          break;  // one frame lost before
        case 1:
          out->timestamp_ns += info_.frame_interval_ns / 2;
          break;  // torn
        default:
          out->trigger_seq = trigger_seq > 0 ? trigger_seq - 1 : 0;
          break;  // wrong trigger
      }
    }
    return Status::Ok();
  }

 private:
  CaptureOptions options_;
  CaptureInfo info_;
  mutable std::mutex mu_;  // guards info_.exposure_ns (command thread vs capture thread)
  std::vector<std::vector<std::shared_ptr<const std::vector<uint8_t>>>> cycle_;
  uint64_t captured_ = 0, burst_ = 0, camera_seq_ = 0;
  std::mt19937 rng_;
  std::uniform_real_distribution<double> uniform_{0.0, 1.0};
};

}  // namespace

std::unique_ptr<CaptureBackend> MakeSimCaptureBackend(const CaptureOptions& options) {
  return std::make_unique<SimCaptureBackend>(options);
}

}  // namespace d3d
