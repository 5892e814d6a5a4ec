#include "host/app/burst_source.h"

#include <algorithm>
#include <chrono>
#include <cstring>
#include <stdexcept>
#include <thread>

#include "protocol/codec.h"
#include "protocol/protocol.h"

namespace d3d {
namespace {
int64_t SteadyNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}
int64_t UnixNs() {  // the clock of ReceivedSample::receive_ns
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}
}  // namespace

Status CopyBurst(const proto::BurstMsg& msg, int64_t receive_ns, IngestedBurst* out) {
  if (msg.frames.empty() || msg.width == 0 || msg.height == 0)
    return InvalidArgument("burst without frames");
  const int type = msg.bit_depth > 8 ? CV_16U : CV_8U;
  const size_t bytes = msg.BytesPerFrame();
  out->frames.resize(msg.frames.size());
  for (size_t i = 0; i < msg.frames.size(); ++i) {
    if (msg.frames[i].pixels.size() != bytes)
      return InvalidArgument("frame " + std::to_string(i) + " has the wrong size");
    out->frames[i].create(static_cast<int>(msg.height), static_cast<int>(msg.width), type);
    std::memcpy(out->frames[i].data, msg.frames[i].pixels.data(), bytes);
  }
  out->burst_seq = msg.burst_seq;
  out->capture_ns = (msg.frames.front().timestamp_ns + msg.frames.back().timestamp_ns) / 2;
  out->receive_ns = receive_ns;
  return Status::Ok();
}

void RecordingSourceOptions::Check() const {
  if (!(rate >= 0) || max_bursts < 0)
    throw std::invalid_argument("RecordingSourceOptions: rate and max_bursts must be >= 0");
  if (select_tolerance_ns < 0)
    throw std::invalid_argument("RecordingSourceOptions: select_tolerance_ns must be >= 0");
}

bool RecordingBurstSource::Selected(int64_t capture_ns) const {
  const std::vector<int64_t>& t = o_.select_capture_ns;  // sorted by Open
  if (t.empty()) return true;
  const auto it = std::lower_bound(t.begin(), t.end(), capture_ns - o_.select_tolerance_ns);
  return it != t.end() && *it <= capture_ns + o_.select_tolerance_ns;
}

Status RecordingBurstSource::Open(const std::string& path, const RecordingSourceOptions& options,
                                  std::unique_ptr<RecordingBurstSource>* out) {
  options.Check();
  auto s = std::unique_ptr<RecordingBurstSource>(new RecordingBurstSource());
  s->o_ = options;
  std::sort(s->o_.select_capture_ns.begin(), s->o_.select_capture_ns.end());
  D3D_RETURN_IF_ERROR(RecordingReader::OpenFile(path, &s->reader_));
  s->lost_ = SequenceLossCounter(s->reader_.get());
  const RecordingChannel* cb = s->reader_->header().FindTopic(proto::kTopicPhaseBurst);
  if (cb == nullptr)
    return InvalidArgument(path + ": no " + std::string(proto::kTopicPhaseBurst) + " channel");
  s->burst_channel_ = cb->id;
  std::string calib_json = s->reader_->header().calibration_json;
  if (calib_json.empty()) {  // the ProbeInfo samples inside, if any
    const RecordingChannel* ci = s->reader_->header().FindTopic(proto::kTopicProbeInfo);
    if (ci != nullptr)
      s->reader_->ForEach([&](const RecordedMessage& m) {
        proto::InfoMsg info;
        if (m.channel == ci->id && proto::Decode(m.data, &info).ok() &&
            !info.calibration_json.empty()) {
          calib_json = info.calibration_json;
          return false;
        }
        return true;
      });
  }
  if (calib_json.empty())
    return InvalidArgument(path + ": the recording carries no calibration (no ProbeInfo)");
  D3D_RETURN_IF_ERROR(ProbeCalibration::FromJson(calib_json, &s->calibration_));
  *out = std::move(s);
  return Status::Ok();
}

BurstSource::Result RecordingBurstSource::Next(IngestedBurst* out) {
  if (o_.max_bursts > 0 && delivered_ >= o_.max_bursts) return Result::kEnd;
  for (;;) {
    if (message_ >= messages_.size()) {
      if (chunk_ >= reader_->chunks().size()) {
        if (!lost_ended_) lost_.End();
        lost_ended_ = true;
        return Result::kEnd;
      }
      messages_.clear();
      message_ = 0;
      const bool ok =
          reader_->ReadChunk(chunk_, &messages_).ok();  // damaged: recorded in diagnostics()
      lost_.Chunk(chunk_++, ok);
      if (!ok) continue;
    }
    const RecordedMessage& m = messages_[message_++];
    if (m.channel != burst_channel_) continue;
    if (!proto::Decode(m.data, &msg_).ok()) {
      received_.fetch_add(1, std::memory_order_relaxed);
      malformed_.fetch_add(1, std::memory_order_relaxed);
      continue;
    }
    std::string detail;
    d3d_proto_PhaseBurst dds{};
    std::vector<d3d_proto_ImageFrame> storage;
    proto::ToDds(msg_, &dds, &storage);
    if (CheckBurst(dds, &detail) != DropReason::kCount ||
        !CopyBurst(msg_, m.log_time_ns, out).ok()) {
      received_.fetch_add(1, std::memory_order_relaxed);
      malformed_.fetch_add(1, std::memory_order_relaxed);
      continue;
    }
    lost_.Message(msg_.burst_seq,
                  m.data.size());  // a malformed burst's number is not to be trusted
    missing_.store(lost_.missing_upstream(), std::memory_order_relaxed);
    if (!Selected(out->capture_ns)) {  // not one of the chosen views: as if the graph dropped it
      skipped_.fetch_add(1, std::memory_order_relaxed);
      if (skipped_sink_) skipped_sink_(*out);
      continue;
    }
    received_.fetch_add(1, std::memory_order_relaxed);
    ++delivered_;
    if (o_.rate > 0) {
      if (t0_file_ < 0) {
        t0_file_ = m.log_time_ns;
        t0_wall_ = SteadyNs();
      }
      const int64_t due =
          t0_wall_ + static_cast<int64_t>(static_cast<double>(m.log_time_ns - t0_file_) / o_.rate);
      const int64_t wait = due - SteadyNs();
      if (wait > 0) std::this_thread::sleep_for(std::chrono::nanoseconds(wait));
      out->receive_ns = std::chrono::duration_cast<std::chrono::nanoseconds>(
                            std::chrono::system_clock::now().time_since_epoch())
                            .count();
    }
    return Result::kBurst;
  }
}

void DdsSourceOptions::Check() const {
  if (!(probe_timeout_s > 0) || !(idle_exit_s >= 0) || !(max_age_s >= 0))
    throw std::invalid_argument(
        "DdsSourceOptions: probe_timeout_s > 0, idle_exit_s >= 0, max_age_s >= 0");
}

DdsBurstSource::DdsBurstSource(BurstReceiver* receiver, const DdsSourceOptions& options)
    : rx_(receiver), o_(options) {
  o_.Check();
}

Status DdsBurstSource::WaitForCalibration(double timeout_s, const std::atomic<bool>* stop,
                                          ProbeCalibration* calibration, proto::InfoMsg* info,
                                          const std::function<void()>& while_waiting) {
  const int64_t end = SteadyNs() + static_cast<int64_t>(timeout_s * 1e9);
  while (SteadyNs() < end) {
    if (rx_->LatestInfo(info, calibration)) return Status::Ok();
    if (stop != nullptr && stop->load()) return Unavailable("stopped before a probe appeared");
    if (while_waiting) while_waiting();
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  return Unavailable("no ProbeInfo (calibration) from a probe within " + std::to_string(timeout_s) +
                     " s");
}

BurstSource::Result DdsBurstSource::Next(IngestedBurst* out) {
  for (;;) {
    const ReceiverCounters c = rx_->counters();
    const uint64_t queue_full = c.dropped[static_cast<size_t>(DropReason::kQueueFull)];
    const uint64_t malformed =
        c.dropped_total() - queue_full - c.dropped[static_cast<size_t>(DropReason::kSerial)];
    malformed_.store(malformed + copy_failures_, std::memory_order_relaxed);
    dropped_.store(
        queue_full + stale_,
        std::memory_order_relaxed);  // accepted by the checks, then no room in the queue or too old
    received_.store(c.bursts_accepted + malformed, std::memory_order_relaxed);
    missing_.store(c.bursts_missing, std::memory_order_relaxed);
    if (!rx_->Pop(&sample_, 50'000'000)) {
      const int64_t now = SteadyNs();
      if (last_burst_ns_ > 0 &&
          now - last_burst_ns_ > static_cast<int64_t>(o_.probe_timeout_s * 1e9))
        probe_lost_.store(true);
      if (last_burst_ns_ > 0 && o_.idle_exit_s > 0 &&
          now - last_burst_ns_ > static_cast<int64_t>(o_.idle_exit_s * 1e9))
        return Result::kEnd;
      return Result::kNothing;
    }
    if (const auto* b = std::get_if<proto::BurstMsg>(&sample_.msg)) {
      if (o_.max_age_s > 0 &&
          UnixNs() - sample_.receive_ns > static_cast<int64_t>(o_.max_age_s * 1e9)) {
        rx_->Recycle(std::move(sample_));
        ++stale_;                     // counted in dropped_ at the top of the loop
        last_burst_ns_ = SteadyNs();  // the probe is there
        continue;
      }
      const Status s = CopyBurst(*b, sample_.receive_ns, out);
      rx_->Recycle(std::move(sample_));
      if (!s.ok()) {
        ++copy_failures_;
        continue;
      }
      if (probe_lost_.exchange(false)) probe_returns_.fetch_add(1, std::memory_order_relaxed);
      last_burst_ns_ = SteadyNs();
      return Result::kBurst;
    }
    rx_->Recycle(
        std::move(sample_));  // ProbeInfo / ProbeStatus: the receiver keeps the latest info
  }
}

}  // namespace d3d
