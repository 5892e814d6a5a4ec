// A running scan as the user sees it, on the tool's main thread (libcamera's `cam` splits CamApp
// and CameraSession the same way; ScanApp wires the stage graph, this drives it): draws the live
// preview at its frame-rate cap, takes the viewer's keys (quit, pause, undo, reset, save) and the
// tool's signals, saves the model mid-scan on a saver thread, prints the status line, and samples
// the process's memory once a second, until the scan ends, the window closes, the duration is up
// or a stop is requested; then stops the graph.
//
// Threads: Run, Report and FinalPicture on the tool's main thread; the saver thread runs
// ScanApp::SaveNow and sets the message line (under a mutex the render loop reads it with). The
// requests are atomics a signal handler may set.
#pragma once

#include <atomic>
#include <mutex>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <string>
#include <thread>
#include <vector>

#include "host/app/scan_app.h"
#include "viewer/viewer.h"

namespace d3d {

struct ScanSessionOptions {
  double duration_s = 0;    // stop after this many seconds (0 = until the scan ends or a stop)
  double preview_fps = 20;  // the preview's frame-rate cap (> 0)
  bool quiet = false;       // no status line on stderr
  std::string out_dir = "scan_out";  // where a save mid-scan writes scan.ply
  void Check() const;                // throws std::invalid_argument
};

// What the tool's signal handlers request (e.g. SIGINT stop, SIGUSR1 save, SIGUSR2 undo); each is
// taken (reset) by the session. Not owned.
struct ScanSessionRequests {
  std::atomic<bool>* stop = nullptr;
  std::atomic<bool>* save = nullptr;
  std::atomic<bool>* undo = nullptr;
};

class ScanSession {
 public:
  // `app` (started by Run) and `viewer` (null: no preview) are borrowed and must outlive the
  // session. Throws std::invalid_argument for bad options or a missing request.
  ScanSession(ScanApp* app, Viewer* viewer, const ScanSessionOptions& options,
              ScanSessionRequests requests);
  ~ScanSession();  // joins a save still running
  ScanSession(const ScanSession&) = delete;
  ScanSession& operator=(const ScanSession&) = delete;

  // Starts the app and runs the loop until the end, then stops the app (RequestStop, Join).
  void Run();
  // The session's figures for report.json: preview_fps, preview_draws_per_s, preview,
  // rss_mib_per_s (the resident set, MiB, once a second) and memory_per_s (ScanMemory's parts and
  // heap_in_use_mib at the same seconds).
  void Report(nlohmann::json* report) const;
  // The final preview picture (the whole model, "scan finished"), BGR; empty without a viewer.
  cv::Mat FinalPicture();

 private:
  void Undo(double now_s);
  void StartSave(bool print);  // on the saver thread; `print`: also say so on stderr
  void SetMessage(const std::string& message, double until_s);
  void Draw(double now_s);  // one preview frame and the viewer's keys
  void SampleMemory();
  void PrintStatusLine(double elapsed_s) const;

  ScanApp* app_;
  Viewer* viewer_;
  ScanSessionOptions o_;
  ScanSessionRequests requests_;
  std::mutex message_mu_;  // the saver thread sets the message line, the render loop reads it
  std::string message_;
  double message_until_s_ = 0;
  std::thread saver_;
  std::atomic<bool> saving_{false};
  uint64_t undos_seen_ = 0;
  double fps_ = 0, preview_s_ = 0;
  int64_t frames_ = 0;
  std::vector<double> rss_timeline_;  // MiB, once a second: memory must stay flat after warm-up
  std::vector<ScanMemory>
      memory_timeline_;                // what the scan's growing parts hold, at the same seconds
  std::vector<double> heap_timeline_;  // MiB malloc has handed out, at the same seconds
};

}  // namespace d3d
