// d3d-scan: the host application, the main job. Subscribes to the probe over DDS (or replays a
// recording losslessly with --replay), runs the stage graph ingest → reconstruct → register →
// preview → fuse (host/app; the session loop: host/app/scan_session.h), shows the live preview
// (viewer/: a GLFW window, or offscreen with
// --headless), and at the end writes DIR/scan.ply, DIR/scan.stl, DIR/poses.txt, DIR/report.json and
// DIR/preview.png (and DIR/heatmap.png with a reference). A replay of a damaged recording scans
// every intact burst and saves the scan, then says on stderr what the file lost and exits 3.
//
// Thread pools are capped here (the tool owns the process): OpenCV and oneTBB to --threads, Mesa's
// llvmpipe to 1 rendering thread (LP_NUM_THREADS, unless set), so the graph's threads own the
// cores.
#include <tbb/global_control.h>

#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgcodecs.hpp>

#include "tools/d3d/report_head.h"
#include "tools/scan/scan_input.h"

namespace fs = std::filesystem;
using namespace d3d;

namespace {
std::atomic<bool> g_stop{false}, g_save{false}, g_undo{false};
void OnSignal(int) { g_stop.store(true); }
void OnSave(int) { g_save.store(true); }
void OnUndo(int) { g_undo.store(true); }
}  // namespace

int main(int argc, char** argv) {
  OptionRegistry options(
      "d3d-scan: the host application: live scan from the probe over DDS (or --replay FILE), live "
      "preview,\n"
      "and the fused model with its report. Writes DIR/scan.ply, scan.stl, poses.txt, report.json, "
      "preview.png.");
  ScanToolArgs args;
  ScanFlags flags;
  ScanAppOptions app_options;
  DeclareScanToolArgs(&options, &args, &app_options);
  DeclareScanFlags(&options, &flags, &app_options.scan);
  if (int code = 0; !options.Parse(argc, argv, &code)) return code;
  if (int code = ResolveScanToolArgs(&args); code != 0) return code;
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  std::signal(SIGUSR1, OnSave);  // save the model now (as the 's' key)
  std::signal(SIGUSR2, OnUndo);  // undo the last seconds (as the 'u' key)
  cv::setNumThreads(args.threads);
  tbb::global_control tbb_cap(tbb::global_control::max_allowed_parallelism,
                              static_cast<size_t>(args.threads));
  setenv("LP_NUM_THREADS", "1", 0);
  const std::string& out_dir = args.session.out_dir;
  try {
    // The preview first: the window is there (showing "waiting for probe") while the host waits for
    // the probe, and its set-up is not part of the ~0.4 s in which the probe's first bursts queue.
    std::unique_ptr<Viewer> viewer = OpenViewer(args);
    ScanInput input;
    if (int code = OpenScanInput(args, app_options, viewer.get(), &g_stop, &input); code != 0)
      return code;
    if (const Status s = MakeScanAppOptions(args, flags, &app_options); !s.ok()) {
      std::fprintf(stderr, "d3d-scan: %s\n", s.ToString().c_str());
      return 2;
    }
    ScanApp app(input.calibration, app_options, input.source);
    if (!app.views_spill_error().empty())
      std::fprintf(stderr, "d3d-scan: the kept frames stay in memory: %s\n",
                   app.views_spill_error().c_str());
    std::fprintf(stderr, "d3d-scan: %s graph, %s preview; out %s\n", EdgePolicyName(args.policy),
                 viewer ? (viewer->headless() ? "offscreen" : "window") : "no", out_dir.c_str());
    ScanSession session(&app, viewer.get(), args.session, {&g_stop, &g_save, &g_undo});
    session.Run();
    if (input.receiver) input.receiver->Stop();

    EvaluationTruth truth;
    if (const Status s = LoadEvaluationTruth(args, input.calibration, &truth); !s.ok()) {
      std::fprintf(stderr, "d3d-scan: reference: %s\n", s.ToString().c_str());
      return 2;
    }
    ScanResult result;  // with --refuse, the app's kept views fused again
    const Status finished = app.Finish(truth.truth, ScanViewProvider(), &result);
    ReportHead head = ToolReportHead("d3d-scan");
    head.probe_serial = input.probe_serial;
    if (truth.truth.reference != nullptr) head.reference = args.reference;
    AddReportHead(head, &result.report);
    session.Report(&result.report);
    ReportInput(args, flags, input, &result.report);
    if (!finished.ok()) {
      std::fprintf(stderr, "d3d-scan: %s\n", finished.ToString().c_str());
      std::error_code ec;
      fs::create_directories(out_dir, ec);
      std::ofstream(fs::path(out_dir) / "report.json") << result.report.dump(2) << "\n";
      return 1;
    }
    if (const Status s = WriteScanOutputs(out_dir, result); !s.ok()) {
      std::fprintf(stderr, "d3d-scan: %s\n", s.ToString().c_str());
      return 1;
    }
    if (const cv::Mat picture = session.FinalPicture(); !picture.empty()) {
      cv::imwrite((fs::path(out_dir) / "preview.png").string(), picture);
      if (!args.screenshot.empty()) cv::imwrite(args.screenshot, picture);
    }
    nlohmann::json brief = result.report;
    if (!args.json) brief.erase("events");
    std::printf("%s\n", args.json ? brief.dump().c_str() : brief.dump(2).c_str());
    const RecordingBurstSource* rec = input.recording.get();
    if (rec && rec->diagnostics().damaged()) {  // the scan is saved; the input was not whole
      for (const std::string& p : rec->diagnostics().problems)
        std::fprintf(stderr, "d3d-scan: %s: damaged: %s\n", args.replay.c_str(), p.c_str());
      std::fprintf(stderr,
                   "d3d-scan: warning: %s is damaged; the scan used every intact chunk and is "
                   "saved in %s; lost: %s; bursts "
                   "lost: %s (exit 3)\n",
                   args.replay.c_str(), out_dir.c_str(), rec->diagnostics().LossSummary().c_str(),
                   rec->bursts_lost().Describe().c_str());
      return 3;
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "d3d-scan: %s\n", e.what());
    return 2;
  }
  return 0;
}
