#include "firmware/probe/probe_app.h"

#include <chrono>
#include <cmath>
#include <cstdio>

#include "protocol/d3d_protocol.h"
#include "protocol/messages.h"
#include "protocol/protocol.h"

namespace d3d {
namespace {

int64_t NowNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

proto::ProbeStateKind ToProto(ProbeState s) {
  switch (s) {
    case ProbeState::kIdle:
      return proto::ProbeStateKind::kIdle;
    case ProbeState::kStreaming:
      return proto::ProbeStateKind::kStreaming;
    case ProbeState::kError:
      return proto::ProbeStateKind::kError;
    case ProbeState::kRecovering:
      return proto::ProbeStateKind::kRecovering;
  }
  return proto::ProbeStateKind::kError;
}

}  // namespace

void ProbeAppOptions::Check() const {
  D3D_CHECK_MSG(!serial.empty() && serial.size() <= 32, "serial must have 1..32 characters");
  D3D_CHECK_MSG(rate_hz > 0 && rate_hz <= 1000, "rate must be in (0, 1000] Hz, got " << rate_hz);
  D3D_CHECK_MSG(max_bursts >= 0, "max_bursts must be ≥ 0");
  D3D_CHECK_MSG(publish_queue >= 1, "publish_queue must be ≥ 1");
  D3D_CHECK_MSG(status_period_ns > 0 && ack_timeout_ns >= 0, "periods must be positive");
}

ProbeApp::ProbeApp(const ProbeAppOptions& options, std::unique_ptr<CaptureBackend> backend,
                   std::unique_ptr<ProjectorDriver> projector, proto::DdsParticipant* participant)
    : options_(options),
      backend_(std::move(backend)),
      projector_(std::move(projector)),
      participant_(participant),
      sync_(FrameSyncOptions{backend_->info().patterns_per_burst, 500'000}),
      firmware_version_(options.firmware_version) {
  options.Check();
  D3D_CHECK_MSG(
      backend_->info().frame_interval_ns * backend_->info().patterns_per_burst <
          static_cast<int64_t>(1e9 / options.rate_hz),
      "a burst (" << backend_->info().patterns_per_burst << " frames) does not fit in 1/rate");
  state_.AddObserver([this](ProbeState, ProbeState, const std::string&) {
    std::lock_guard<std::mutex> lock(status_mu_);
    status_now_ = true;
    status_cv_.notify_all();
  });
}

ProbeApp::~ProbeApp() {
  threads_stop_ = true;
  queue_cv_.notify_all();
  status_cv_.notify_all();
  for (auto& t : threads_)
    if (t.joinable()) t.join();
  backend_->Close();
}

Status ProbeApp::Start() {
  const dds_entity_t pp = participant_->participant();
  Status s;
  const dds_entity_t t_burst =
      participant_->Topic(&d3d_proto_PhaseBurst_desc, proto::kTopicPhaseBurst, &s);
  D3D_RETURN_IF_ERROR(s);
  const dds_entity_t t_info =
      participant_->Topic(&d3d_proto_ProbeInfo_desc, proto::kTopicProbeInfo, &s);
  D3D_RETURN_IF_ERROR(s);
  const dds_entity_t t_status =
      participant_->Topic(&d3d_proto_ProbeStatus_desc, proto::kTopicProbeStatus, &s);
  D3D_RETURN_IF_ERROR(s);
  const dds_entity_t t_cmd =
      participant_->Topic(&d3d_proto_ProbeCommand_desc, proto::kTopicProbeCommand, &s);
  D3D_RETURN_IF_ERROR(s);
  const dds_entity_t t_ack =
      participant_->Topic(&d3d_proto_ProbeCommandAck_desc, proto::kTopicProbeCommandAck, &s);
  D3D_RETURN_IF_ERROR(s);
  using Q = std::unique_ptr<dds_qos_t, proto::QosDeleter>;
  burst_writer_ = dds_create_writer(
      pp, t_burst, Q(proto::MakeQos(proto::QosProfile::kBurstWriter)).get(), nullptr);
  info_writer_ = dds_create_writer(
      pp, t_info, Q(proto::MakeQos(proto::QosProfile::kInfoWriter)).get(), nullptr);
  status_writer_ = dds_create_writer(
      pp, t_status, Q(proto::MakeQos(proto::QosProfile::kStatusWriter)).get(), nullptr);
  ack_writer_ = dds_create_writer(
      pp, t_ack, Q(proto::MakeQos(proto::QosProfile::kCommandWriter)).get(), nullptr);
  command_reader_ = dds_create_reader(
      pp, t_cmd, Q(proto::MakeQos(proto::QosProfile::kCommandReader)).get(), nullptr);
  for (dds_entity_t e : {burst_writer_, info_writer_, status_writer_, ack_writer_, command_reader_})
    if (e < 0) return proto::DdsError("probe: creating DDS endpoints", e);
  {
    std::lock_guard<std::mutex> lock(projector_mu_);
    D3D_RETURN_IF_ERROR(projector_->Configure(backend_->info().calibration.pattern,
                                              backend_->info().patterns_per_burst));
  }
  D3D_RETURN_IF_ERROR(PublishInfo());
  threads_.emplace_back([this] { PublishLoop(); });
  threads_.emplace_back([this] { StatusLoop(); });
  threads_.emplace_back([this] { CommandLoop(); });
  if (options_.start_streaming)
    D3D_RETURN_IF_ERROR(state_.Transition(ProbeState::kStreaming, "start-up"));
  return Status::Ok();
}

void ProbeApp::SetFirmwareVersion(const std::string& version) {
  std::lock_guard<std::mutex> lock(info_mu_);
  firmware_version_ = version;
}

void ProbeApp::SetStreamingInhibit(const std::string& reason) {
  std::lock_guard<std::mutex> lock(info_mu_);
  streaming_inhibit_ = reason;
}

Status ProbeApp::SetStreaming(bool on) {
  if (on) {
    std::lock_guard<std::mutex> lock(info_mu_);
    if (!streaming_inhibit_.empty()) return Unavailable("streaming refused: " + streaming_inhibit_);
  }
  return state_.Transition(on ? ProbeState::kStreaming : ProbeState::kIdle, "command");
}

Status ProbeApp::PublishInfo() {
  const CaptureInfo& ci = backend_->info();
  proto::InfoMsg m;
  m.serial = options_.serial;
  m.protocol_version = proto::kProtocolVersion;
  {
    std::lock_guard<std::mutex> lock(info_mu_);
    m.firmware_version = firmware_version_;
  }
  m.sensor_model = ci.sensor_model;
  {
    std::lock_guard<std::mutex> lock(projector_mu_);
    m.projector_model = projector_->model();
  }
  m.capture_backend = ci.backend;
  m.width = static_cast<uint32_t>(ci.width);
  m.height = static_cast<uint32_t>(ci.height);
  m.bit_depth = static_cast<uint8_t>(ci.bit_depth);
  m.calibration_json = ci.calibration.ToJson();
  d3d_proto_ProbeInfo sample;
  proto::ToDds(m, &sample);
  const dds_return_t rc = dds_write(info_writer_, &sample);
  return rc < 0 ? proto::DdsError("probe: writing ProbeInfo", rc) : Status::Ok();
}

Status ProbeApp::CaptureOneBurst(int64_t t0_ns, uint64_t* trigger_seq) {
  const CaptureInfo& ci = backend_->info();
  for (int p = 0; p < ci.patterns_per_burst; ++p) {
    const int64_t t = t0_ns + p * ci.frame_interval_ns;
    ++*trigger_seq;
    {
      std::lock_guard<std::mutex> lock(projector_mu_);
      D3D_RETURN_IF_ERROR(projector_->Trigger(p, *trigger_seq, t));
    }
    sync_.OnTrigger(p, *trigger_seq, t);
    CapturedFrame frame;
    D3D_RETURN_IF_ERROR(backend_->Capture(p, *trigger_seq, t, &frame));
    std::vector<CapturedFrame> burst;
    if (sync_.OnFrame(frame, &burst)) {
      PendingBurst pb{std::move(burst), ci.exposure_ns};
      std::lock_guard<std::mutex> lock(queue_mu_);
      if (static_cast<int>(queue_.size()) >= options_.publish_queue) {
        ++counters_.publish_failures;  // the publisher fell behind: drop rather than stall capture
      } else {
        queue_.push_back(std::move(pb));
        queue_cv_.notify_one();
      }
    }
  }
  return Status::Ok();
}

bool ProbeApp::Recover(const Status& cause) {
  (void)state_.Transition(ProbeState::kError, cause.message());
  std::fprintf(stderr, "d3d-probe: error: %s\n", cause.ToString().c_str());
  for (int attempt = 1; attempt <= options_.max_recoveries && !stop_; ++attempt) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    if (!state_.Transition(ProbeState::kRecovering, "attempt " + std::to_string(attempt)).ok())
      return false;
    Status s;
    {
      std::lock_guard<std::mutex> lock(projector_mu_);
      s = projector_->Configure(backend_->info().calibration.pattern,
                                backend_->info().patterns_per_burst);
    }
    if (s.ok()) {
      (void)state_.Transition(ProbeState::kIdle, "recovered");
      return state_.Transition(ProbeState::kStreaming, "resume after recovery").ok();
    }
    (void)state_.Transition(ProbeState::kError, s.message());
  }
  return false;
}

Status ProbeApp::Run() {
  const int64_t period_ns = static_cast<int64_t>(std::llround(1e9 / options_.rate_hz));
  uint64_t trigger_seq = 0;
  for (int64_t waited = 0; options_.wait_readers > 0 && !stop_; waited += 10'000'000) {
    dds_publication_matched_status_t m{};
    dds_get_publication_matched_status(burst_writer_, &m);
    if (static_cast<int>(m.current_count) >= options_.wait_readers) break;
    if (waited >= options_.wait_readers_timeout_ns)
      return Unavailable("no PhaseBurst reader appeared within the wait timeout");
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  int64_t next = NowNs() + 20'000'000;
  Status last_error;
  while (!stop_) {
    if (options_.max_bursts > 0 &&
        static_cast<int64_t>(sync_.counters().bursts_complete.load()) >= options_.max_bursts)
      break;
    if (!state_.IsStreaming()) {
      if (state_.state() == ProbeState::kError)
        return Status(StatusCode::kUnavailable, "probe stayed in error: " + state_.last_error());
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
      next = NowNs() + 20'000'000;
      continue;
    }
    const Status s = CaptureOneBurst(next, &trigger_seq);
    if (!s.ok()) {
      last_error = s;
      if (!Recover(s)) return s;
      next = NowNs() + 20'000'000;
      continue;
    }
    next += period_ns;
    const int64_t now = NowNs();
    if (next < now) {  // fell behind (e.g. the host is slow and the machine busy): skip, count
      ++counters_.capture_overruns;
      next = now + 1'000'000;
    }
  }
  // Drain the publish queue, then let reliable readers acknowledge everything.
  {
    std::unique_lock<std::mutex> lock(queue_mu_);
    queue_cv_.wait(lock, [&] { return (queue_.empty() && !publishing_) || threads_stop_; });
  }
  PublishStatus();
  if (options_.max_bursts > 0 && !stop_) {
    const dds_return_t rc = dds_wait_for_acks(burst_writer_, options_.ack_timeout_ns);
    (void)dds_wait_for_acks(status_writer_, DDS_SECS(2));
    if (rc != DDS_RETCODE_OK)
      return Unavailable("readers did not acknowledge all bursts within the ack timeout");
  }
  return Status::Ok();
}

void ProbeApp::PublishLoop() {
  std::vector<d3d_proto_ImageFrame> frames;
  const CaptureInfo ci = backend_->info();
  const std::string pattern_set = ci.calibration.pattern.name;
  for (;;) {
    PendingBurst pb;
    {
      std::unique_lock<std::mutex> lock(queue_mu_);
      queue_cv_.wait(lock, [&] { return !queue_.empty() || threads_stop_; });
      if (queue_.empty()) return;
      pb = std::move(queue_.front());
      queue_.pop_front();
      publishing_ = true;
    }
    d3d_proto_PhaseBurst s{};
    proto::CopyBounded(s.serial, options_.serial);
    s.protocol_version = proto::kProtocolVersion;
    s.burst_seq = next_burst_seq_++;
    s.exposure_ns = pb.exposure_ns;
    s.frame_interval_ns = ci.frame_interval_ns;
    proto::CopyBounded(s.pattern_set, pattern_set);
    s.width = static_cast<uint32_t>(ci.width);
    s.height = static_cast<uint32_t>(ci.height);
    s.bit_depth = static_cast<uint8_t>(ci.bit_depth);
    frames.assign(pb.frames.size(), d3d_proto_ImageFrame{});
    for (size_t i = 0; i < pb.frames.size(); ++i) {
      const CapturedFrame& f = pb.frames[i];
      d3d_proto_ImageFrame& d = frames[i];
      const int k = f.pattern_index;
      proto::CopyBounded(d.pattern, pattern_set + "/" + std::to_string(k));
      d.pattern_index = static_cast<uint16_t>(k);
      d.timestamp_ns = f.timestamp_ns;
      d.camera_frame_seq = f.camera_frame_seq;
      d.pixels._buffer = const_cast<uint8_t*>(f.pixels->data());  // read-only use by dds_write
      d.pixels._length = d.pixels._maximum = static_cast<uint32_t>(f.pixels->size());
    }
    s.frames._buffer = frames.data();
    s.frames._length = s.frames._maximum = static_cast<uint32_t>(frames.size());
    const dds_return_t rc = dds_write(burst_writer_, &s);
    if (rc < 0) {
      ++counters_.publish_failures;
    } else {
      ++counters_.bursts_published;
      if (options_.on_published) options_.on_published(s.burst_seq, pb.frames);
    }
    std::lock_guard<std::mutex> lock(queue_mu_);
    publishing_ = false;
    queue_cv_.notify_all();
  }
}

void ProbeApp::PublishStatus() {
  proto::StatusMsg m;
  m.serial = options_.serial;
  m.protocol_version = proto::kProtocolVersion;
  m.timestamp_ns = NowNs();
  m.state = ToProto(state_.state());
  m.temperature_c = backend_->temperature_c();
  m.bursts_published = counters_.bursts_published;
  m.bursts_dropped_sync = sync_.counters().dropped_total();
  m.frames_dropped_camera = sync_.counters().frames_lost;
  m.publish_failures = counters_.publish_failures;
  m.last_command_id = counters_.last_command_id;
  m.last_error = state_.last_error();
  d3d_proto_ProbeStatus s;
  proto::ToDds(m, &s);
  if (dds_write(status_writer_, &s) < 0) ++counters_.publish_failures;
}

void ProbeApp::StatusLoop() {
  std::unique_lock<std::mutex> lock(status_mu_);
  while (!threads_stop_) {
    status_cv_.wait_for(lock, std::chrono::nanoseconds(options_.status_period_ns),
                        [&] { return status_now_ || threads_stop_.load(); });
    if (threads_stop_) return;
    status_now_ = false;
    lock.unlock();
    PublishStatus();
    lock.lock();
  }
}

std::string ProbeApp::HandleCommand(int kind, double value, bool* accepted) {
  *accepted = false;
  Status s;
  switch (kind) {
    case d3d_proto_CMD_START_STREAMING:
    case d3d_proto_CMD_STOP_STREAMING:
      s = SetStreaming(kind == d3d_proto_CMD_START_STREAMING);
      break;
    case d3d_proto_CMD_SET_EXPOSURE:
      s = backend_->SetExposure(static_cast<int64_t>(std::llround(value)));
      break;
    case d3d_proto_CMD_SET_BRIGHTNESS: {
      std::lock_guard<std::mutex> lock(projector_mu_);
      s = projector_->SetBrightness(value);
      break;
    }
    case d3d_proto_CMD_SET_PATTERN_PERIOD:
      // The calibration (and the sim's pre-rendered bursts) are for one pattern set; a new period
      // needs a pattern-set upload and re-calibration of the phase origin, not built yet.
      s = Unsupported(
          "pattern period change not supported by this firmware (pattern set fixed by the "
          "calibration)");
      break;
    default:
      s = InvalidArgument("unknown command kind " + std::to_string(kind));
  }
  *accepted = s.ok();
  return s.ok() ? "ok" : s.ToString();
}

void ProbeApp::CommandLoop() {
  const dds_entity_t ws = dds_create_waitset(participant_->participant());
  const dds_entity_t rc = dds_create_readcondition(command_reader_, DDS_ANY_STATE);
  dds_waitset_attach(ws, rc, 0);
  while (!threads_stop_) {
    (void)dds_waitset_wait(ws, nullptr, 0, DDS_MSECS(100));
    void* samples[8] = {};
    dds_sample_info_t infos[8];
    const int n = dds_take(command_reader_, samples, infos, 8, 8);
    for (int i = 0; i < n; ++i) {
      if (!infos[i].valid_data) continue;
      const auto* c = static_cast<const d3d_proto_ProbeCommand*>(samples[i]);
      const std::string target = proto::FromBounded(c->serial);
      if (!target.empty() && target != options_.serial) continue;
      d3d_proto_ProbeCommandAck ack{};
      proto::CopyBounded(ack.serial, options_.serial);
      ack.protocol_version = proto::kProtocolVersion;
      ack.command_id = c->command_id;
      bool accepted = false;
      const std::string msg = proto::ProtocolCompatible(c->protocol_version)
                                  ? HandleCommand(static_cast<int>(c->kind), c->value, &accepted)
                                  : "refused: protocol version " +
                                        std::to_string(c->protocol_version) + " incompatible";
      ack.accepted = accepted;
      proto::CopyBounded(ack.message, msg);
      ++counters_.commands;
      counters_.last_command_id = c->command_id;
      (void)dds_write(ack_writer_, &ack);
    }
    if (n > 0) dds_return_loan(command_reader_, samples, n);
  }
  dds_delete(ws);
}

}  // namespace d3d
