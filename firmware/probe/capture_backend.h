// Camera capture backends of the probe and their registry.
//
// A backend delivers one frame per projector trigger: Capture(pattern_index, trigger_seq, t_ns)
// returns the frame whose exposure is centred on t_ns, tagged with the trigger counter the camera
// latched (its strobe input) and the camera's own frame counter; the pairing and the checks are in
// frame_sync.h. Backends: "sim" (the virtual probe, sim) and "libcamera" (a real sensor).
//
// Threads: one capture thread calls Open/Capture/Close; SetExposure may be called from the command
// thread (backends make it thread-safe).
#pragma once

#include <cstdint>
#include <functional>
#include <limits>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "calib/model/probe_calibration.h"
#include "common/core/status.h"

namespace d3d {

struct CapturedFrame {
  int pattern_index = 0;
  uint64_t trigger_seq = 0;       // latched from the projector trigger line
  uint64_t camera_frame_seq = 0;  // the sensor's frame counter (+1 per frame it exposed)
  int64_t timestamp_ns = 0;       // middle of the exposure, Unix epoch
  // H×W bytes (8 bit) or 2·H×W (16 bit LE). Immutable once captured; shared so that the publisher
  // sends it without a copy.
  std::shared_ptr<const std::vector<uint8_t>> pixels;
};

struct CaptureInfo {
  std::string backend;  // registry name
  std::string sensor_model;
  int width = 0, height = 0, bit_depth = 8;
  int64_t exposure_ns = 0;
  int64_t frame_interval_ns = 0;  // between the frames of a burst
  ProbeCalibration calibration;   // the probe's factory calibration
  int patterns_per_burst = 4;
};

struct CaptureOptions {
  // sim backend
  std::string sim_model = "typodont";  // "typodont" or a mesh file
  std::string trajectory = "full-arch";
  uint32_t seed = 1;
  double rate_hz = 30.0;  // burst rate (also the trajectory clock of the sim)
  int width = 640, height = 480;
  int sim_cycle = 30;           // distinct bursts pre-rendered at start-up, then repeated
  int max_bursts = 0;           // > 0: never pre-render more than this
  double sim_fault_rate = 0.0;  // per frame: drop it (camera gap) or tear its timestamp
  int render_threads = 0;       // 0 = all cores
  // libcamera backend
  std::string camera_id;  // "" = first camera
  void Check() const;     // throws std::invalid_argument
};

class CaptureBackend {
 public:
  virtual ~CaptureBackend() = default;
  // UNAVAILABLE when the device is absent (e.g. libcamera lists no camera), with a message saying
  // so.
  [[nodiscard]] virtual Status Open() = 0;
  virtual const CaptureInfo& info() const = 0;
  [[nodiscard]] virtual Status SetExposure(int64_t exposure_ns) = 0;
  // Blocks until the exposure centred on t_ns has ended, then fills *out. UNAVAILABLE if the camera
  // stopped delivering. A frame the sensor dropped is not returned: the next call returns the next
  // frame (its camera_frame_seq jumps), which frame_sync detects.
  [[nodiscard]] virtual Status Capture(int pattern_index, uint64_t trigger_seq, int64_t t_ns,
                                       CapturedFrame* out) = 0;
  virtual float temperature_c() const { return std::numeric_limits<float>::quiet_NaN(); }
  virtual void Close() {}
};

// Name → factory. Explicitly filled (RegisterBuiltinCaptureBackends), no static registration.
class CaptureBackendRegistry {
 public:
  using Factory = std::function<std::unique_ptr<CaptureBackend>(const CaptureOptions&)>;
  void Register(const std::string& name, Factory factory, bool real_camera);
  std::vector<std::string> Names() const;
  // name "auto": the first real-camera backend whose Open() succeeds; UNAVAILABLE listing what each
  // said otherwise. A known name: that backend, opened. INVALID_ARGUMENT for an unknown name.
  [[nodiscard]] Status CreateAndOpen(const std::string& name, const CaptureOptions& options,
                                     std::unique_ptr<CaptureBackend>* out) const;

 private:
  struct Entry {
    Factory factory;
    bool real_camera;
  };
  std::map<std::string, Entry> entries_;
  std::vector<std::string> order_;
};

// Registers "sim" and "libcamera".
void RegisterBuiltinCaptureBackends(CaptureBackendRegistry* registry);

std::unique_ptr<CaptureBackend> MakeSimCaptureBackend(const CaptureOptions& options);
std::unique_ptr<CaptureBackend> MakeLibcameraCaptureBackend(const CaptureOptions& options);

}  // namespace d3d
