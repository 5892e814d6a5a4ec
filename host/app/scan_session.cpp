#include "host/app/scan_session.h"

#include <malloc.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <fstream>
#include <stdexcept>

namespace d3d {
namespace {

// Resident set size now (MiB), from /proc/self/statm.
double RssMiB() {
  std::ifstream f("/proc/self/statm");
  long pages = 0, resident = 0;
  f >> pages >> resident;
  return static_cast<double>(resident) * static_cast<double>(sysconf(_SC_PAGESIZE)) /
         (1024.0 * 1024.0);
}

// Bytes malloc has handed out and not had back (all arenas: in use in the heaps, plus mmapped
// chunks), MiB. Beside the RSS it tells a growing program from an allocator keeping freed pages.
double HeapInUseMiB() {
  const struct mallinfo2 mi = mallinfo2();
  return static_cast<double>(mi.uordblks + mi.hblkhd) / (1024.0 * 1024.0);
}

double SteadyS() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

}  // namespace

void ScanSessionOptions::Check() const {
  if (!(duration_s >= 0))
    throw std::invalid_argument("ScanSessionOptions: duration_s must be >= 0");
  if (!(preview_fps > 0))
    throw std::invalid_argument("ScanSessionOptions: preview_fps must be > 0");
}

ScanSession::ScanSession(ScanApp* app, Viewer* viewer, const ScanSessionOptions& options,
                         ScanSessionRequests requests)
    : app_(app), viewer_(viewer), o_(options), requests_(requests) {
  o_.Check();
  if (app_ == nullptr || !requests_.stop || !requests_.save || !requests_.undo)
    throw std::invalid_argument(
        "ScanSession: an app and the stop, save and undo requests are needed");
}

ScanSession::~ScanSession() {
  if (saver_.joinable()) saver_.join();
}

void ScanSession::SetMessage(const std::string& message, double until_s) {
  std::lock_guard<std::mutex> lock(message_mu_);
  message_ = message;
  message_until_s_ = until_s;
}

void ScanSession::Undo(double now_s) {
  if (app_->RequestUndo()) return;
  SetMessage("undo is off (--no-refuse or --undo-views 0)", now_s + 3);
}

void ScanSession::StartSave(bool print) {
  if (saving_.exchange(true)) return;  // one save at a time
  if (saver_.joinable()) saver_.join();
  saver_ = std::thread([this, print] {
    const Status s = app_->SaveNow(o_.out_dir);
    const std::string saved = "saved " + o_.out_dir + "/scan.ply";
    if (print)
      std::fprintf(stderr, "\nd3d-scan: %s\n", s.ok() ? saved.c_str() : s.ToString().c_str());
    SetMessage(s.ok() ? saved : "save failed: " + s.ToString(), SteadyS() + 4);
    saving_.store(false);
  });
}

void ScanSession::SampleMemory() {
  rss_timeline_.push_back(RssMiB());
  memory_timeline_.push_back(app_->Memory());
  heap_timeline_.push_back(HeapInUseMiB());
}

void ScanSession::PrintStatusLine(double elapsed_s) const {
  const PreviewStatus st = app_->CurrentStatus();
  std::fprintf(stderr,
               "\rd3d-scan: %5.0f s  received %llu  processed %llu  fused %llu  dropped %llu  %.1f "
               "bursts/s  latency p95 %.0f ms  %s   ",
               elapsed_s, static_cast<unsigned long long>(st.bursts_received),
               static_cast<unsigned long long>(st.bursts_processed),
               static_cast<unsigned long long>(st.bursts_fused),
               static_cast<unsigned long long>(st.bursts_dropped), st.bursts_per_s,
               st.latency_ms_p95, st.override_cue ? PreviewCueText(st.cue_override) : "");
}

void ScanSession::Run() {
  app_->Start();
  const double t0 = SteadyS();
  double next_frame = t0, next_line = t0 + 1, last_fps_t = t0;
  int64_t fps_frames = 0;
  const double frame_dt = 1.0 / std::max(1.0, o_.preview_fps);
  while (!app_->finished()) {
    const double now = SteadyS();
    if (requests_.stop->load() || (o_.duration_s > 0 && now - t0 >= o_.duration_s)) break;
    if (requests_.undo->exchange(false)) Undo(now);
    if (app_->undos_done() != undos_seen_) {  // what the last undo did, on the status line
      undos_seen_ = app_->undos_done();
      const std::string m = app_->LastUndoMessage();
      if (!o_.quiet) std::fprintf(stderr, "\nd3d-scan: %s\n", m.c_str());
      SetMessage(m, now + 3);
    }
    if (requests_.save->exchange(false)) StartSave(true);
    if (viewer_ && now >= next_frame) {
      next_frame = std::max(next_frame + frame_dt, now);
      PreviewStatus st = app_->CurrentStatus();
      {
        std::lock_guard<std::mutex> lock(message_mu_);
        if (now < message_until_s_) st.message = message_;
      }
      if (!viewer_->Render(app_->LatestSnapshot(), st, fps_)) break;  // window closed
      ++frames_;
      ++fps_frames;
      if (now - last_fps_t >= 1.0) {
        fps_ = static_cast<double>(fps_frames) / (now - last_fps_t);
        fps_frames = 0;
        last_fps_t = now;
      }
      for (ViewerAction a : viewer_->TakeActions()) {
        if (a == ViewerAction::kQuit) {
          requests_.stop->store(true);
        } else if (a == ViewerAction::kPause) {
          app_->SetPaused(!app_->paused());
        } else if (a == ViewerAction::kUndo) {
          Undo(now);
        } else if (a == ViewerAction::kReset) {
          app_->Reset();
          SetMessage("model reset", now + 3);
        } else if (a == ViewerAction::kSave) {
          StartSave(false);
        }
      }
    }
    if (now >= next_line) {
      next_line += 1;
      SampleMemory();
      if (!o_.quiet) PrintStatusLine(now - t0);
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(viewer_ ? 2 : 20));
  }
  preview_s_ = SteadyS() - t0;
  app_->RequestStop();
  app_->Join();
  if (saver_.joinable()) saver_.join();
  if (!o_.quiet) std::fprintf(stderr, "\n");
}

void ScanSession::Report(nlohmann::json* report) const {
  nlohmann::json& r = *report;
  r["preview_fps"] = viewer_ && preview_s_ > 0 ? static_cast<double>(frames_) / preview_s_ : 0.0;
  // Of those frames, the ones drawn: the others showed the same picture (Viewer::Render).
  r["preview_draws_per_s"] =
      viewer_ && preview_s_ > 0 ? static_cast<double>(viewer_->frames_drawn()) / preview_s_ : 0.0;
  r["preview"] = viewer_ ? (viewer_->headless() ? "offscreen" : "window") : "none";
  r["rss_mib_per_s"] = rss_timeline_;
  nlohmann::json mem;  // one array per figure, aligned with rss_mib_per_s
  const auto column = [&](const char* name, auto field) {
    nlohmann::json a = nlohmann::json::array();
    for (const ScanMemory& m : memory_timeline_) a.push_back(field(m));
    mem[name] = std::move(a);
  };
  column("views", [](const ScanMemory& m) { return m.views; });
  column("model_samples", [](const ScanMemory& m) { return m.model_samples; });
  column("model_mib", [](const ScanMemory& m) { return m.model_mib; });
  column("undo_journal_mib", [](const ScanMemory& m) { return m.undo_journal_mib; });
  column("keyframes", [](const ScanMemory& m) { return m.keyframes; });
  column("keyframes_mib", [](const ScanMemory& m) { return m.keyframes_mib; });
  column("tsdf_mib", [](const ScanMemory& m) { return m.tsdf_mib; });
  column("views_kept_memory_mib", [](const ScanMemory& m) { return m.views_kept_memory_mib; });
  column("preview_points", [](const ScanMemory& m) { return m.preview_points; });
  mem["heap_in_use_mib"] = heap_timeline_;
  r["memory_per_s"] = std::move(mem);
}

cv::Mat ScanSession::FinalPicture() {
  cv::Mat picture;
  if (!viewer_) return picture;
  // The last snapshot (the whole model), the status as at the end.
  PreviewStatus st = app_->CurrentStatus();
  st.message = "scan finished";
  st.override_cue =
      st.override_cue && st.cue_override != PreviewCue::kProbeLost;  // the model's own state
  viewer_->Render(app_->LatestSnapshot(), st, fps_, &picture);
  return picture;
}

}  // namespace d3d
