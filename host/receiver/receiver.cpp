#include "host/receiver/receiver.h"

#include <chrono>

#include "protocol/protocol.h"

namespace d3d {
namespace {

int64_t NowNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

// Takes `reader`'s samples of type Sample until it has none left, kBatch at a time: per batch,
// on_batch() once, then on_sample(sample) for each sample with valid data, then the loan is
// returned.
template <typename Sample, int kBatch, typename OnBatch, typename OnSample>
void TakeAll(dds_entity_t reader, OnBatch&& on_batch, OnSample&& on_sample) {
  void* samples[kBatch] = {};
  dds_sample_info_t infos[kBatch];
  for (;;) {
    const int n = dds_take(reader, samples, infos, kBatch, kBatch);
    if (n <= 0) return;
    on_batch();
    for (int i = 0; i < n; ++i) {
      if (!infos[i].valid_data) continue;
      on_sample(*static_cast<const Sample*>(samples[i]));
    }
    dds_return_loan(reader, samples, n);
  }
}

template <typename Sample, int kBatch, typename OnSample>
void TakeAll(dds_entity_t reader, OnSample&& on_sample) {
  TakeAll<Sample, kBatch>(
      reader, [] {}, on_sample);
}

}  // namespace

const char* DropReasonName(DropReason r) {
  switch (r) {
    case DropReason::kProtocolVersion:
      return "protocol_version";
    case DropReason::kSerial:
      return "serial";
    case DropReason::kGeometry:
      return "geometry";
    case DropReason::kFrameCount:
      return "frame_count";
    case DropReason::kFrameSize:
      return "frame_size";
    case DropReason::kFrameOrder:
      return "frame_order";
    case DropReason::kDuplicate:
      return "duplicate";
    case DropReason::kCalibration:
      return "calibration";
    case DropReason::kBadEnum:
      return "bad_enum";
    case DropReason::kQueueFull:
      return "queue_full";
    case DropReason::kCount:
      break;
  }
  return "unknown";
}

uint64_t ReceiverCounters::dropped_total() const {
  uint64_t n = 0;
  for (uint64_t d : dropped) n += d;
  return n;
}

void ReceiverOptions::Check() const {
  D3D_CHECK_MSG(queue_capacity >= 1, "queue_capacity must be ≥ 1");
  D3D_CHECK_MSG(serial.size() <= 32, "serial must have ≤ 32 characters");
}

DropReason CheckBurst(const d3d_proto_PhaseBurst& s, std::string* detail) {
  if (!proto::ProtocolCompatible(s.protocol_version)) {
    *detail = "protocol version " + std::to_string(s.protocol_version) + ", expected major " +
              std::to_string(proto::ProtocolMajor(proto::kProtocolVersion));
    return DropReason::kProtocolVersion;
  }
  if (s.width < 1 || s.height < 1 || s.width > 8192 || s.height > 8192 || s.bit_depth < 1 ||
      s.bit_depth > 16) {
    *detail = std::to_string(s.width) + "x" + std::to_string(s.height) + " at " +
              std::to_string(s.bit_depth) + " bit";
    return DropReason::kGeometry;
  }
  if (s.frames._length < 3 || s.frames._length > 8) {
    *detail = std::to_string(s.frames._length) + " frames";
    return DropReason::kFrameCount;
  }
  const uint64_t bytes = uint64_t{s.width} * s.height * (s.bit_depth > 8 ? 2 : 1);
  for (uint32_t i = 0; i < s.frames._length; ++i) {
    const d3d_proto_ImageFrame& f = s.frames._buffer[i];
    if (f.pixels._length != bytes) {
      *detail = "frame " + std::to_string(i) + " has " + std::to_string(f.pixels._length) +
                " bytes, expected " + std::to_string(bytes);
      return DropReason::kFrameSize;
    }
    if (i > 0 && (f.timestamp_ns <= s.frames._buffer[i - 1].timestamp_ns ||
                  f.pattern_index <= s.frames._buffer[i - 1].pattern_index)) {
      *detail = "frame " + std::to_string(i) + " not after frame " + std::to_string(i - 1);
      return DropReason::kFrameOrder;
    }
  }
  return DropReason::kCount;
}

DropReason CheckInfo(const proto::InfoMsg& m, ProbeCalibration* calibration, std::string* detail) {
  if (!proto::ProtocolCompatible(m.protocol_version)) {
    *detail = "protocol version " + std::to_string(m.protocol_version);
    return DropReason::kProtocolVersion;
  }
  const Status s = ProbeCalibration::FromJson(m.calibration_json, calibration);
  if (!s.ok()) {
    *detail = s.ToString();
    return DropReason::kCalibration;
  }
  if (calibration->camera.width != static_cast<int>(m.width) ||
      calibration->camera.height != static_cast<int>(m.height)) {
    *detail = "calibration is for a " + std::to_string(calibration->camera.width) + "x" +
              std::to_string(calibration->camera.height) + " camera";
    return DropReason::kCalibration;
  }
  return DropReason::kCount;
}

BurstReceiver::BurstReceiver(const ReceiverOptions& options) : options_(options) {
  options.Check();
}

BurstReceiver::~BurstReceiver() { Stop(); }

void BurstReceiver::Stop() {
  for (dds_entity_t* r : {&burst_reader_, &info_reader_, &status_reader_}) {
    if (*r > 0) dds_delete(*r);  // waits for a running listener to return
    *r = 0;
  }
}

Status BurstReceiver::Start(proto::DdsParticipant* participant) {
  Status s;
  const dds_entity_t tb =
      participant->Topic(&d3d_proto_PhaseBurst_desc, proto::kTopicPhaseBurst, &s);
  D3D_RETURN_IF_ERROR(s);
  const dds_entity_t ti = participant->Topic(&d3d_proto_ProbeInfo_desc, proto::kTopicProbeInfo, &s);
  D3D_RETURN_IF_ERROR(s);
  const dds_entity_t ts =
      participant->Topic(&d3d_proto_ProbeStatus_desc, proto::kTopicProbeStatus, &s);
  D3D_RETURN_IF_ERROR(s);
  using Q = std::unique_ptr<dds_qos_t, proto::QosDeleter>;
  auto reader = [&](dds_entity_t topic, proto::QosProfile profile, dds_on_data_available_fn fn,
                    dds_entity_t* out) {
    dds_listener_t* l = dds_create_listener(this);
    dds_lset_data_available(l, fn);
    *out =
        dds_create_reader(participant->participant(), topic, Q(proto::MakeQos(profile)).get(), l);
    dds_delete_listener(l);
    return *out < 0 ? proto::DdsError("receiver: dds_create_reader", *out) : Status::Ok();
  };
  D3D_RETURN_IF_ERROR(
      reader(ti, proto::QosProfile::kInfoReader, &BurstReceiver::OnInfo, &info_reader_));
  D3D_RETURN_IF_ERROR(
      reader(ts, proto::QosProfile::kStatusReader, &BurstReceiver::OnStatus, &status_reader_));
  D3D_RETURN_IF_ERROR(reader(tb,
                             options_.preview ? proto::QosProfile::kBurstPreviewReader
                                              : proto::QosProfile::kBurstRecordReader,
                             &BurstReceiver::OnBurst, &burst_reader_));
  return Status::Ok();
}

void BurstReceiver::Drop(DropReason r, const std::string& detail) {
  uint64_t n;
  {
    std::lock_guard<std::mutex> lock(mu_);
    n = ++counters_.dropped[static_cast<size_t>(r)];
  }
  if (options_.log && (n <= 5 || n % 100 == 0)) {
    std::string m("receiver: dropped sample (");
    m.append(DropReasonName(r)).append(" #").append(std::to_string(n)).append("): ").append(detail);
    options_.log(m);
  }
}

void BurstReceiver::Push(ReceivedSample&& s) {
  std::unique_lock<std::mutex> lock(mu_);
  if (queue_.size() >= options_.queue_capacity) {
    ++counters_.dropped[static_cast<size_t>(DropReason::kQueueFull)];
    if (!options_.preview) return;  // keep what is queued; this one is lost (counted)
    queue_.pop_front();             // preview: the freshest wins
  }
  queue_.push_back(std::move(s));
  cv_.notify_one();
}

void BurstReceiver::OnBurst(dds_entity_t reader, void* arg) {
  auto* self = static_cast<BurstReceiver*>(arg);
  int64_t now = 0;  // when the batch was taken
  TakeAll<d3d_proto_PhaseBurst, 8>(
      reader, [&now] { now = NowNs(); },
      [&](const d3d_proto_PhaseBurst& s) {
        std::string detail;
        const std::string serial = proto::FromBounded(s.serial);
        if (!self->options_.serial.empty() && serial != self->options_.serial) {
          self->Drop(DropReason::kSerial, serial);
          return;
        }
        const DropReason r = CheckBurst(s, &detail);
        if (r != DropReason::kCount) {
          self->Drop(r, "burst " + std::to_string(s.burst_seq) + " from " + serial + ": " + detail);
          return;
        }
        ReceivedSample out;
        out.receive_ns = now;
        proto::BurstMsg msg;
        {
          std::lock_guard<std::mutex> lock(self->mu_);
          auto it = self->next_seq_.find(serial);
          if (it != self->next_seq_.end()) {
            if (s.burst_seq == 0 && it->second > 0) {
              ++self->counters_.probe_restarts;
            } else if (s.burst_seq < it->second) {
              detail = "burst " + std::to_string(s.burst_seq) + " after " +
                       std::to_string(it->second - 1);
            } else if (s.burst_seq > it->second) {
              ++self->counters_.sequence_gaps;
              self->counters_.bursts_missing += s.burst_seq - it->second;
            }
          }
          if (detail.empty()) {
            self->next_seq_[serial] = s.burst_seq + 1;
            ++self->counters_.bursts_accepted;
            if (!self->spare_bursts_.empty()) {
              msg = std::move(self->spare_bursts_.back());
              self->spare_bursts_.pop_back();
            }
          }
        }
        if (!detail.empty()) {
          self->Drop(DropReason::kDuplicate, detail);
          return;
        }
        proto::FromDds(s, &msg);  // copies into the recycled buffers' capacity
        out.msg = std::move(msg);
        self->Push(std::move(out));
      });
}

void BurstReceiver::OnInfo(dds_entity_t reader, void* arg) {
  auto* self = static_cast<BurstReceiver*>(arg);
  TakeAll<d3d_proto_ProbeInfo, 4>(reader, [&](const d3d_proto_ProbeInfo& s) {
    proto::InfoMsg m;
    proto::FromDds(s, &m);
    if (!self->options_.serial.empty() && m.serial != self->options_.serial) {
      self->Drop(DropReason::kSerial, m.serial);
      return;
    }
    ProbeCalibration cal;
    std::string detail;
    const DropReason r = CheckInfo(m, &cal, &detail);
    if (r != DropReason::kCount) {
      self->Drop(r, "ProbeInfo from " + m.serial + ": " + detail);
      return;
    }
    {
      std::lock_guard<std::mutex> lock(self->mu_);
      self->info_ = m;
      self->calibration_ = cal;
      self->have_info_ = true;
      ++self->counters_.infos_accepted;
    }
    self->Push(ReceivedSample{NowNs(), std::move(m)});
  });
}

void BurstReceiver::OnStatus(dds_entity_t reader, void* arg) {
  auto* self = static_cast<BurstReceiver*>(arg);
  TakeAll<d3d_proto_ProbeStatus, 8>(reader, [&](const d3d_proto_ProbeStatus& s) {
    const std::string serial = proto::FromBounded(s.serial);
    if (!self->options_.serial.empty() && serial != self->options_.serial) {
      self->Drop(DropReason::kSerial, serial);
      return;
    }
    if (!proto::ProtocolCompatible(s.protocol_version)) {
      self->Drop(DropReason::kProtocolVersion,
                 "ProbeStatus version " + std::to_string(s.protocol_version));
      return;
    }
    if (static_cast<int>(s.state) < 0 || static_cast<int>(s.state) > 3) {
      self->Drop(DropReason::kBadEnum,
                 "ProbeStatus state " + std::to_string(static_cast<int>(s.state)));
      return;
    }
    proto::StatusMsg m;
    proto::FromDds(s, &m);
    {
      std::lock_guard<std::mutex> lock(self->mu_);
      ++self->counters_.statuses_accepted;
    }
    self->Push(ReceivedSample{NowNs(), std::move(m)});
  });
}

bool BurstReceiver::Pop(ReceivedSample* out, int64_t timeout_ns) {
  std::unique_lock<std::mutex> lock(mu_);
  if (!cv_.wait_for(lock, std::chrono::nanoseconds(timeout_ns), [&] { return !queue_.empty(); }))
    return false;
  *out = std::move(queue_.front());
  queue_.pop_front();
  return true;
}

void BurstReceiver::Recycle(ReceivedSample&& sample) {
  if (auto* b = std::get_if<proto::BurstMsg>(&sample.msg)) {
    std::lock_guard<std::mutex> lock(mu_);
    if (spare_bursts_.size() < options_.queue_capacity) spare_bursts_.push_back(std::move(*b));
  }
}

bool BurstReceiver::LatestInfo(proto::InfoMsg* info, ProbeCalibration* calibration) const {
  std::lock_guard<std::mutex> lock(mu_);
  if (!have_info_) return false;
  if (info) *info = info_;
  if (calibration) *calibration = calibration_;
  return true;
}

ReceiverCounters BurstReceiver::counters() const {
  std::lock_guard<std::mutex> lock(mu_);
  return counters_;
}

}  // namespace d3d
