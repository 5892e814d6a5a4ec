// The "libcamera" capture backend: a real sensor through libcamera (Debian's libcamera 0.0.3).
//
// State of this backend: Open() enumerates the cameras, acquires the selected one and configures a
// raw stream at the requested size; UNAVAILABLE with a clear message when libcamera lists no camera
// (all our development machines and CI). Frame capture (requests, buffer mapping, the strobe
// counter from the sensor's metadata) is NOT implemented: there is no camera to develop it against,
// so Capture() returns UNSUPPORTED rather than pretending.
#include <libcamera/camera.h>
#include <libcamera/camera_manager.h>
#include <libcamera/stream.h>

#include "firmware/probe/capture_backend.h"

namespace d3d {
namespace {

class LibcameraCaptureBackend final : public CaptureBackend {
 public:
  explicit LibcameraCaptureBackend(const CaptureOptions& o) : options_(o) {}
  ~LibcameraCaptureBackend() override { Close(); }

  Status Open() override {
    manager_ = std::make_unique<libcamera::CameraManager>();
    if (const int rc = manager_->start(); rc != 0)
      return Unavailable("libcamera: camera manager failed to start (" + std::to_string(rc) + ")");
    const auto cameras = manager_->cameras();
    if (cameras.empty()) return Unavailable("libcamera lists no cameras on this machine");
    camera_ = options_.camera_id.empty() ? cameras.front() : manager_->get(options_.camera_id);
    if (!camera_) return Unavailable("libcamera: no camera with id '" + options_.camera_id + "'");
    if (camera_->acquire() != 0)
      return Unavailable("libcamera: camera '" + camera_->id() + "' is in use");
    acquired_ = true;
    std::unique_ptr<libcamera::CameraConfiguration> config =
        camera_->generateConfiguration({libcamera::StreamRole::Raw});
    if (!config || config->empty())
      return Unavailable("libcamera: camera '" + camera_->id() + "' offers no raw stream");
    config->at(0).size = libcamera::Size(static_cast<unsigned>(options_.width),
                                         static_cast<unsigned>(options_.height));
    if (config->validate() == libcamera::CameraConfiguration::Invalid)
      return Unavailable("libcamera: raw stream configuration invalid");
    if (camera_->configure(config.get()) != 0) return Unavailable("libcamera: configure failed");
    info_.backend = "libcamera";
    info_.sensor_model = camera_->id();
    info_.width = static_cast<int>(config->at(0).size.width);
    info_.height = static_cast<int>(config->at(0).size.height);
    return Status::Ok();
  }
  const CaptureInfo& info() const override { return info_; }
  Status SetExposure(int64_t) override {
    return Unsupported("libcamera backend: exposure control not implemented");
  }
  Status Capture(int, uint64_t, int64_t, CapturedFrame*) override {
    return Unsupported(
        "libcamera backend: frame capture not implemented (no camera to develop against)");
  }
  void Close() override {
    if (camera_ && acquired_) camera_->release();
    acquired_ = false;
    camera_.reset();
    if (manager_) manager_->stop();
    manager_.reset();
  }

 private:
  CaptureOptions options_;
  CaptureInfo info_;
  std::unique_ptr<libcamera::CameraManager> manager_;
  std::shared_ptr<libcamera::Camera> camera_;
  bool acquired_ = false;
};

}  // namespace

std::unique_ptr<CaptureBackend> MakeLibcameraCaptureBackend(const CaptureOptions& options) {
  return std::make_unique<LibcameraCaptureBackend>(options);
}

}  // namespace d3d
