// d3d-scan's own options (the scan options every scanning tool takes are scan_flags.h's), and
// where its bursts and its truth come from: a recording replayed (--replay) or the probe on DDS;
// the scene and the true poses of the virtual probe (--reference, --sim-trajectory). Part of the
// d3d-scan executable, not a library.
#pragma once

#include <atomic>
#include <cstdint>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "common/options/option_registry.h"
#include "host/app/scan_app.h"
#include "host/app/scan_session.h"
#include "pipeline/chain/scan_flags.h"
#include "sim/session/sim_scene.h"
#include "tools/dds/tool_dds.h"
#include "viewer/viewer.h"

namespace d3d {

struct ScanToolArgs {
  std::string replay;      // a recording to replay instead of DDS
  double replay_rate = 0;  // 0 = as fast as the graph takes bursts, else the recorded timing × this
  int64_t max_bursts = 0;    // --replay: the first N bursts only (0 = all)
  std::string replay_views;  // --replay: only the bursts this TUM file lists
  uint64_t rx_queue = 0;     // live: the receiver's queue (0: by policy)
  std::string policy_text;   // live | lossless (empty: live on DDS, lossless with --replay)
  double step = 0;          // bursts between processed views for the tracker's gates (0: by policy)
  int threads = 0;          // OpenCV / oneTBB threads (0: by policy)
  int icp_threads = 0;      // the tracker's ICP threads (0 = threads)
  std::string spill_views;  // --refuse: where the kept frames spill ('memory': nowhere)
  std::string reference;    // evaluate against this scene
  std::string sim_trajectory;  // the virtual probe's scan path (true poses)
  uint32_t sim_seed = 1;
  double sim_rate = 30;  // the probe's burst rate (Hz)
  int domain = 0;
  std::string serial;  // listen to this probe only
  double probe_timeout_s = 1.0, idle_exit_s = 0, wait_probe_s = 120;
  bool headless = false, no_preview = false, json = false;
  std::string screenshot;
  int width = 960;             // preview width (px; height 3/4 of it)
  ScanSessionOptions session;  // --duration, --preview-fps, --quiet, --out

  // Set by ResolveScanToolArgs from the flags above.
  EdgePolicy policy = EdgePolicy::kLive;
  bool live_views = true;  // views come as unevenly as live: the live tracker's gates
};

// Declares d3d-scan's own options on `registry`, bound to `args` and to the fields of `*app`.
void DeclareScanToolArgs(OptionRegistry* registry, ScanToolArgs* args, ScanAppOptions* app);
// After parsing: the edge policy, the step and the thread counts by policy. 0, or 2 after printing
// what is wrong.
int ResolveScanToolArgs(ScanToolArgs* args);
// The app's options: the scan flags applied (ApplyScanFlags at the resolved step) and the live
// host's own (threads, view period, kept views and their spill folder, the live volume, binning of
// the highlighted view).
[[nodiscard]] Status MakeScanAppOptions(const ScanToolArgs& args, const ScanFlags& flags,
                                        ScanAppOptions* app);

// The preview window, or offscreen (--headless, or when no window opens); null with --no-preview
// or when neither works (said on stderr).
std::unique_ptr<Viewer> OpenViewer(const ScanToolArgs& args);

// Where the bursts come from. The members own the source's parts; `source` points at one of them.
struct ScanInput {
  std::unique_ptr<RecordingBurstSource> recording;
  proto::DdsParticipant participant;
  std::unique_ptr<BurstReceiver> receiver;
  std::unique_ptr<DdsBurstSource> dds;
  BurstSource* source = nullptr;
  ProbeCalibration calibration;
  std::string probe_serial;  // the probe's (its ProbeInfo, or the recording's header)
};
// Opens the recording, or joins DDS and waits for a probe's calibration (the preview, when there
// is one, shows "waiting" meanwhile; closing it sets *stop). 0, or the exit code after printing
// the error: 2 for a bad recording or views file, 3 when DDS or the probe fail.
int OpenScanInput(const ScanToolArgs& args, const ScanAppOptions& app, Viewer* viewer,
                  std::atomic<bool>* stop, ScanInput* in);
// The input's figures for report.json: the input, and a replayed recording's damage and skips.
void ReportInput(const ScanToolArgs& args, const ScanFlags& flags, const ScanInput& in,
                 nlohmann::json* report);

// The truth the scan is evaluated against: the scene (--reference) and, with --sim-trajectory,
// the virtual probe's true poses (its scene and trajectory, without the renderer). `truth` points
// into the other members: do not move.
struct EvaluationTruth {
  SimScene world;  // with --sim-trajectory or --reference typodont
  TriangleMesh scene;
  ScanTruth truth;
};
[[nodiscard]] Status LoadEvaluationTruth(const ScanToolArgs& args,
                                         const ProbeCalibration& calibration, EvaluationTruth* out);

}  // namespace d3d
