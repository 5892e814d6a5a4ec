#include "protocol/messages.h"

namespace d3d::proto {

size_t BurstMsg::PixelBytes() const {
  size_t n = 0;
  for (const FrameMsg& f : frames) n += f.pixels.size();
  return n;
}

const char* ProbeStateName(ProbeStateKind s) {
  switch (s) {
    case ProbeStateKind::kIdle:
      return "idle";
    case ProbeStateKind::kStreaming:
      return "streaming";
    case ProbeStateKind::kError:
      return "error";
    case ProbeStateKind::kRecovering:
      return "recovering";
  }
  return "unknown";
}

void ToDds(const BurstMsg& m, d3d_proto_PhaseBurst* out,
           std::vector<d3d_proto_ImageFrame>* frame_storage) {
  D3D_CHECK_MSG(m.frames.size() <= 8,
                "a PhaseBurst holds at most 8 frames, got " << m.frames.size());
  *out = {};
  CopyBounded(out->serial, m.serial);
  out->protocol_version = m.protocol_version;
  out->burst_seq = m.burst_seq;
  out->exposure_ns = m.exposure_ns;
  out->frame_interval_ns = m.frame_interval_ns;
  CopyBounded(out->pattern_set, m.pattern_set);
  out->width = m.width;
  out->height = m.height;
  out->bit_depth = m.bit_depth;
  frame_storage->assign(m.frames.size(), d3d_proto_ImageFrame{});
  for (size_t i = 0; i < m.frames.size(); ++i) {
    const FrameMsg& f = m.frames[i];
    d3d_proto_ImageFrame& d = (*frame_storage)[i];
    CopyBounded(d.pattern, f.pattern);
    d.pattern_index = f.pattern_index;
    d.timestamp_ns = f.timestamp_ns;
    d.camera_frame_seq = f.camera_frame_seq;
    d.pixels._length = d.pixels._maximum = static_cast<uint32_t>(f.pixels.size());
    d.pixels._buffer = const_cast<uint8_t*>(f.pixels.data());  // read only by dds_write
    d.pixels._release = false;
  }
  out->frames._length = out->frames._maximum = static_cast<uint32_t>(frame_storage->size());
  out->frames._buffer = frame_storage->data();
  out->frames._release = false;
}

void ToDds(const InfoMsg& m, d3d_proto_ProbeInfo* out) {
  *out = {};
  CopyBounded(out->serial, m.serial);
  out->protocol_version = m.protocol_version;
  CopyBounded(out->firmware_version, m.firmware_version);
  CopyBounded(out->sensor_model, m.sensor_model);
  CopyBounded(out->projector_model, m.projector_model);
  CopyBounded(out->capture_backend, m.capture_backend);
  out->width = m.width;
  out->height = m.height;
  out->bit_depth = m.bit_depth;
  out->calibration_json = const_cast<char*>(m.calibration_json.c_str());
}

void ToDds(const StatusMsg& m, d3d_proto_ProbeStatus* out) {
  *out = {};
  CopyBounded(out->serial, m.serial);
  out->protocol_version = m.protocol_version;
  out->timestamp_ns = m.timestamp_ns;
  out->state = static_cast<d3d_proto_ProbeStateKind>(m.state);
  out->temperature_c = m.temperature_c;
  out->bursts_published = m.bursts_published;
  out->bursts_dropped_sync = m.bursts_dropped_sync;
  out->frames_dropped_camera = m.frames_dropped_camera;
  out->publish_failures = m.publish_failures;
  out->last_command_id = m.last_command_id;
  CopyBounded(out->last_error, m.last_error);
}

void FromDds(const d3d_proto_PhaseBurst& s, BurstMsg* out) {
  out->serial = FromBounded(s.serial);
  out->protocol_version = s.protocol_version;
  out->burst_seq = s.burst_seq;
  out->exposure_ns = s.exposure_ns;
  out->frame_interval_ns = s.frame_interval_ns;
  out->pattern_set = FromBounded(s.pattern_set);
  out->width = s.width;
  out->height = s.height;
  out->bit_depth = s.bit_depth;
  out->frames.resize(s.frames._length);
  for (uint32_t i = 0; i < s.frames._length; ++i) {
    const d3d_proto_ImageFrame& f = s.frames._buffer[i];
    FrameMsg& d = out->frames[i];
    d.pattern = FromBounded(f.pattern);
    d.pattern_index = f.pattern_index;
    d.timestamp_ns = f.timestamp_ns;
    d.camera_frame_seq = f.camera_frame_seq;
    d.pixels.assign(f.pixels._buffer, f.pixels._buffer + f.pixels._length);
  }
}

void FromDds(const d3d_proto_ProbeInfo& s, InfoMsg* out) {
  out->serial = FromBounded(s.serial);
  out->protocol_version = s.protocol_version;
  out->firmware_version = FromBounded(s.firmware_version);
  out->sensor_model = FromBounded(s.sensor_model);
  out->projector_model = FromBounded(s.projector_model);
  out->capture_backend = FromBounded(s.capture_backend);
  out->width = s.width;
  out->height = s.height;
  out->bit_depth = s.bit_depth;
  out->calibration_json = s.calibration_json != nullptr ? s.calibration_json : "";
}

void FromDds(const d3d_proto_ProbeStatus& s, StatusMsg* out) {
  out->serial = FromBounded(s.serial);
  out->protocol_version = s.protocol_version;
  out->timestamp_ns = s.timestamp_ns;
  out->state = static_cast<ProbeStateKind>(s.state);
  out->temperature_c = s.temperature_c;
  out->bursts_published = s.bursts_published;
  out->bursts_dropped_sync = s.bursts_dropped_sync;
  out->frames_dropped_camera = s.frames_dropped_camera;
  out->publish_failures = s.publish_failures;
  out->last_command_id = s.last_command_id;
  out->last_error = FromBounded(s.last_error);
}

}  // namespace d3d::proto
