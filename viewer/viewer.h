// The live preview window (GLFW + OpenGL) or its offscreen twin (EGL, Mesa's surfaceless
// platform: no display needed), drawing a PreviewSnapshot: the fused model as shaded points, the
// current view highlighted (orange when fused, red when refused), a scan segment apart from the
// model in the NEW SEGMENT blue beside it, the probe frustum in the
// tracking colour, and a status panel (state, bursts, bursts/s, latency, coverage, fps, keys):
// a strip at the top (and the keys line at the bottom of a window), its counters redrawn at most
// 4 times a second, a change of state or message at once (PanelRefresh, preview.h).
//
// Input (window only): left drag orbits, wheel zooms, keys: space = pause, r = reset the model,
// u = undo the last seconds, s = save, q / Esc = quit, f = fit the view to the model again. Actions
// are queued and taken by the caller with TakeActions(); the viewer never waits for the pipeline.
//
// Thread: everything here runs on the one render thread that created the viewer (GLFW requires
// the main thread for the window). Rendering cost grows with the points drawn: llvmpipe draws
// ~100k points at ~20 fps on this machine, so the host decimates the model (one point per cell).
#pragma once

#include <cstdint>
#include <memory>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "common/core/status.h"
#include "viewer/preview.h"

namespace d3d {

struct ViewerOptions {
  int width = 960, height = 720;  // px
  bool headless = false;          // offscreen (EGL surfaceless) instead of a window
  std::string title = "d3d-scan";
  float point_size_px = 3.0f;
  void Check() const;  // throws std::invalid_argument
};

enum class ViewerAction { kPause, kReset, kUndo, kSave, kQuit };

class Viewer {
 public:
  // UNAVAILABLE when no window can be opened (no display: use headless) or no EGL/GL is found,
  // with the reason.
  [[nodiscard]] static Status Create(const ViewerOptions& options, std::unique_ptr<Viewer>* out);
  ~Viewer();

  // Draws one frame of `snapshot` (nullptr: nothing yet) with `status`, shows it (window) and
  // processes input; with `capture`, the frame is also read back into it (H×W CV_8UC3 BGR, top row
  // first: --screenshot). A frame that would show the same picture as the last one drawn (the same
  // snapshot, camera and panel; the window not exposed) is not drawn again: the one shown is
  // current. Returns false once the window was closed.
  bool Render(const PreviewSnapshot* snapshot, const PreviewStatus& status, double fps,
              cv::Mat* capture = nullptr);
  // Frames Render actually drew (the others were still current).
  int64_t frames_drawn() const;
  std::vector<ViewerAction> TakeActions();
  bool headless() const;

 private:
  struct Impl;
  explicit Viewer(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace d3d
