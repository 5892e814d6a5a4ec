// d3d-sim: renders bursts of the virtual probe scanning a dental arch, with ground truth.
// Thin wiring of SimSession (sim/session) and the burst folder format (common/burst).
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "common/burst/burst_io.h"
#include "common/core/progress.h"
#include "common/mesh/mesh_io.h"
#include "common/options/option_registry.h"
#include "sim/calibration/calibration_session.h"
#include "sim/session/sim_session.h"

namespace fs = std::filesystem;
using namespace d3d;

namespace {

struct BurstStats {
  double surface_share = 0;  // pixels that see a surface
  double lit_share = 0;      // pixels lit by the projector
  double median_depth_mm = std::nan("");
};

BurstStats Stats(const FrameTruth& t) {
  BurstStats s;
  std::vector<float> depths;
  int lit = 0;
  for (int r = 0; r < t.visibility.rows; ++r)
    for (int c = 0; c < t.visibility.cols; ++c) {
      const uint8_t v = t.visibility.at<uint8_t>(r, c);
      if (v == 0) continue;
      depths.push_back(t.depth_mm.at<float>(r, c));
      lit += v == 2;
    }
  const double n = static_cast<double>(t.visibility.total());
  s.surface_share = static_cast<double>(depths.size()) / n;
  s.lit_share = lit / n;
  if (!depths.empty()) {
    std::nth_element(depths.begin(), depths.begin() + static_cast<long>(depths.size() / 2),
                     depths.end());
    s.median_depth_mm = depths[depths.size() / 2];
  }
  return s;
}

// A 2×2 picture of one burst: frame 0, the marker frame, true depth (jet over the measurement
// volume, black where no surface) and surfaces (tooth white, gingiva pink, unlit dark blue).
cv::Mat PreviewPicture(const Burst& burst, const ProbeCalibration& calib) {
  auto grey = [](const cv::Mat& m) {
    cv::Mat g, c;
    if (m.depth() == CV_8U)
      g = m;
    else
      m.convertTo(g, CV_8U, 255.0 / 65535.0);
    cv::cvtColor(g, c, cv::COLOR_GRAY2BGR);
    return c;
  };
  const size_t marker = static_cast<size_t>(std::max(0, calib.pattern.marker_frame));
  cv::Mat top, bottom, all;
  cv::hconcat(grey(burst.frames[0].image),
              grey(burst.frames[std::min(marker, burst.frames.size() - 1)].image), top);
  const FrameTruth& t = burst.reference_truth;
  if (t.depth_mm.empty()) {  // --truth none: the frames only
    cv::putText(top,
                "burst " + std::to_string(burst.sequence) + ": frame 0 | frame " +
                    std::to_string(marker) + " (marker)",
                cv::Point(10, top.rows - 12), cv::FONT_HERSHEY_SIMPLEX, 0.6,
                cv::Scalar(0, 255, 255), 1, cv::LINE_AA);
    return top;
  }
  cv::Mat depth8;
  t.depth_mm.convertTo(depth8, CV_8U, 255.0 / (calib.depth_max_mm - calib.depth_min_mm),
                       -255.0 * calib.depth_min_mm / (calib.depth_max_mm - calib.depth_min_mm));
  cv::Mat depth;
  cv::applyColorMap(depth8, depth, cv::COLORMAP_JET);
  depth.setTo(cv::Scalar(0, 0, 0), t.visibility == 0);
  cv::Mat labels(t.visibility.size(), CV_8UC3, cv::Scalar(0, 0, 0));
  labels.setTo(cv::Scalar(235, 235, 235), t.label == static_cast<int>(SurfaceLabel::kTooth));
  labels.setTo(cv::Scalar(150, 120, 230), t.label == static_cast<int>(SurfaceLabel::kGingiva));
  labels.setTo(cv::Scalar(90, 30, 10), t.visibility == 1);
  cv::hconcat(depth, labels, bottom);
  cv::vconcat(top, bottom, all);
  const std::string caption =
      "burst " + std::to_string(burst.sequence) + ": frame 0 | frame " + std::to_string(marker) +
      " (marker) | depth " + std::to_string(static_cast<int>(calib.depth_min_mm)) + "-" +
      std::to_string(static_cast<int>(calib.depth_max_mm)) + " mm | tooth/gingiva/unlit";
  cv::putText(all, caption, cv::Point(10, all.rows - 12), cv::FONT_HERSHEY_SIMPLEX, 0.6,
              cv::Scalar(0, 255, 255), 1, cv::LINE_AA);
  return all;
}

bool ParseCamera(const std::string& text, int* w, int* h) {
  return std::sscanf(text.c_str(), "%dx%d", w, h) == 2;
}

// Everything the command line sets.
struct ToolOptions {
  SimSessionOptions session;
  CalibrationSessionOptions calibration;
  bool calibration_session = false;  // render a calibration session instead of bursts
  std::string out_dir, camera = "640x480", patterns = "burst", truth = "ref";
  int64_t frames = 30, first = 0;
  bool no_noise = false, no_gamma = false, quiet = false, json = false;
};

void DeclareOptions(OptionRegistry* options, ToolOptions* o) {
  SimSessionOptions& opt = o->session;
  options->Add("--model", &opt.model,
               "'typodont' (built-in, default) or a mesh file: PLY/STL/OBJ in mm");
  options->Add(
      "--trajectory", &opt.trajectory,
      "a scan style: " + ScanStyleList() + " (default full-arch); quadrant; or a TUM file");
  options
      ->Add("--frames", &o->frames,
            "number of bursts to render (default 30; 0 = the whole trajectory)")
      .Range(0, 100'000'000);
  options->Add("--index", &o->first, "index of the first burst (default 0)").Range(0, 100'000'000);
  options->Add("--seed", &opt.seed, "seed of hand motion and sensor noise (default 1)");
  options->Add("--rate", &opt.burst_rate_hz, "bursts per second (default 30)");
  options->Add("--camera", &o->camera, "camera size: 640x480 (default) or 1280x1024");
  options->Add(
      "--patterns", &o->patterns,
      "burst (default: 4-step with marker) | phase:N:PERIOD[:x|y] | multifreq:N:P1,P2,..[:x|y] | "
      "gray:CELL[:x|y] | white | black");
  options->Add("--truth", &o->truth,
               "ground-truth maps to write: ref (default: at the burst's mid time) | first (and of "
               "frame 0) | "
               "all (and of every frame) | none");
  options->Add("--motion-blur", &opt.render.motion_blur_samples,
               "poses averaged over each exposure (default 1)");
  options->Add("--threads", &opt.render.threads, "render threads (default 0 = all cores)");
  options->Flag("--texture-frame", &opt.texture_frame,
                "bursts get a 5th, uniformly lit texture frame");
  options->Flag("--no-noise", &o->no_noise, "no shot or read noise (quantisation stays)");
  options->Flag("--no-gamma", &o->no_gamma, "linear projector (default: uncorrected gamma 2.2)");
  options->Flag("--quiet", &o->quiet, "no progress bar");
  options->Flag("--json", &o->json, "print a JSON summary as the last line");
  options->Add("--out", &o->out_dir, "output folder").Required();
  // Calibration sessions (sim/calibration): a printed target at N poses instead of a scan.
  options->Flag("--calibration-session", &o->calibration_session,
                "render a calibration session instead of bursts: a printed target at --poses poses "
                "under white light and "
                "phase-shift sets along both projector axes, with the true calibration (see "
                "sim/calibration)");
  options->Add("--target", &o->calibration.target,
               "calibration target: circles:COLSxROWS:SPACING_MM[:asymmetric]:d=DIAM_MM | "
               "chessboard:COLSxROWS:SQUARE_MM (default circles:9x7:1.2:d=0.6)");
  options->Add("--poses", &o->calibration.poses,
               "calibration session: number of target poses (default 15)");
}

// --calibration-session: renders the target session and reports it. Returns the exit code.
int RunCalibrationSession(const ToolOptions& o) {
  CalibrationSessionOptions cal = o.calibration;
  cal.seed = o.session.seed;
  cal.noise = !o.no_noise;
  cal.gamma = !o.no_gamma;
  cal.threads = o.session.render.threads;
  if (!ParseCamera(o.camera, &cal.camera_width, &cal.camera_height)) return 2;
  CalibrationSessionResult r;
  try {
    if (const Status s = RenderCalibrationSession(cal, o.out_dir, !o.quiet, &r); !s.ok()) {
      std::fprintf(stderr, "d3d-sim: %s\n", s.ToString().c_str());
      return s.code() == StatusCode::kInvalidArgument ? 2 : 1;
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "d3d-sim: %s\n", e.what());
    return 2;
  }
  const nlohmann::json summary{{"calibration_session", o.out_dir},
                               {"target", r.target.ToString()},
                               {"poses", r.views.size()},
                               {"seconds", r.seconds}};
  if (o.json)
    std::printf("%s\n", summary.dump().c_str());
  else
    std::printf("d3d-sim: calibration session of %zu poses of %s written to %s (%.1f s)\n",
                r.views.size(), r.target.ToString().c_str(), o.out_dir.c_str(), r.seconds);
  return 0;
}

// Checks the scan options and builds the session and its pattern set. Returns 0, or the exit
// code after printing why not.
int CreateSession(ToolOptions* o, std::unique_ptr<SimSession>* session, PatternSet* set) {
  SimSessionOptions& opt = o->session;
  if (!ParseCamera(o->camera, &opt.camera_width, &opt.camera_height)) {
    std::fprintf(stderr, "d3d-sim: --camera must look like 640x480, got '%s'\n", o->camera.c_str());
    return 2;
  }
  if (o->truth != "ref" && o->truth != "first" && o->truth != "all" && o->truth != "none") {
    std::fprintf(stderr, "d3d-sim: --truth must be ref, first, all or none\n");
    return 2;
  }
  opt.render.noise = !o->no_noise;
  opt.render.gamma = !o->no_gamma;
  try {
    const Status s = SimSession::Create(opt, session);
    if (!s.ok()) {
      std::fprintf(stderr, "d3d-sim: %s\n", s.ToString().c_str());
      return 1;
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "d3d-sim: %s\n", e.what());
    return 2;
  }
  cv::setNumThreads(opt.render.threads > 0 ? opt.render.threads : cv::getNumberOfCPUs());
  if (const Status s = ParsePatternSet(o->patterns, (*session)->calibration(), set); !s.ok()) {
    std::fprintf(stderr, "d3d-sim: %s\n", s.ToString().c_str());
    return 2;
  }
  return 0;
}

// Creates OUT/bursts and writes the session's calibration, trajectory and scene. Returns 0 or 1.
int WriteSessionFiles(const std::string& out_dir, const SimSession& session) {
  std::error_code ec;
  fs::create_directories(fs::path(out_dir) / "bursts", ec);
  if (ec) {
    std::fprintf(stderr, "d3d-sim: cannot create '%s': %s\n", out_dir.c_str(),
                 ec.message().c_str());
    return 1;
  }
  for (const Status& s :
       {session.calibration().Save((fs::path(out_dir) / "calibration.json").string()),
        session.trajectory().SaveTum((fs::path(out_dir) / "trajectory.tum").string()),
        SavePlyBinary((fs::path(out_dir) / "scene.ply").string(), session.scene())}) {
    if (!s.ok()) {
      std::fprintf(stderr, "d3d-sim: %s\n", s.ToString().c_str());
      return 1;
    }
  }
  return 0;
}

// Sums of the rendered bursts' figures, for the summary.
struct RenderTotals {
  double surface = 0, lit = 0;  // sums of the per-burst shares
  int64_t in_volume = 0;        // bursts whose median depth lies in the measurement volume
  double seconds = 0;
};

// Renders bursts first .. first+count-1 into OUT/bursts/NNNNNN and the middle one's preview.
// Returns 0 or 1.
int RenderBursts(const ToolOptions& o, SimSession* session, const PatternSet& set, int64_t count,
                 RenderTotals* totals) {
  std::vector<int> truth_frames;
  if (o.truth == "first") truth_frames = {0};
  if (o.truth == "all")
    for (int k = 0; k < static_cast<int>(set.frames.size()); ++k) truth_frames.push_back(k);
  ProgressBar bar("d3d-sim", count, !o.quiet);
  const auto& calib = session->calibration();
  const auto start = std::chrono::steady_clock::now();
  for (int64_t i = 0; i < count; ++i) {
    const int64_t index = o.first + i;
    const PoseAtTime pose = [&](int64_t t) { return session->trajectory().WorldFromProbe(t); };
    Burst burst =
        session->probe().RenderBurst(pose, session->BurstStartNs(index),
                                     static_cast<uint64_t>(index), o.session.seed, true, &set);
    const BurstStats st = Stats(burst.reference_truth);
    if (o.truth == "none") burst.reference_truth = FrameTruth{};
    totals->surface += st.surface_share;
    totals->lit += st.lit_share;
    totals->in_volume +=
        st.median_depth_mm >= calib.depth_min_mm && st.median_depth_mm <= calib.depth_max_mm;
    char name[32];
    std::snprintf(name, sizeof(name), "%06lld", static_cast<long long>(index));
    if (const Status s =
            WriteBurstDir((fs::path(o.out_dir) / "bursts" / name).string(), burst, truth_frames);
        !s.ok()) {
      std::fprintf(stderr, "\nd3d-sim: %s\n", s.ToString().c_str());
      return 1;
    }
    if (i == count / 2 && !cv::imwrite((fs::path(o.out_dir) / "preview.png").string(),
                                       PreviewPicture(burst, calib))) {
      std::fprintf(stderr, "\nd3d-sim: cannot write preview.png\n");
      return 1;
    }
    bar.Update(i + 1);
  }
  bar.Finish();
  totals->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return 0;
}

// Writes OUT/summary.json and prints the summary (JSON with --json, else one line).
void ReportScan(const ToolOptions& o, const SimSession& session, const PatternSet& set,
                int64_t count, int64_t available, const RenderTotals& totals) {
  const double n = static_cast<double>(std::max<int64_t>(count, 1));
  const nlohmann::json summary{
      {"model", o.session.model},
      {"trajectory", o.session.trajectory},
      {"seed", o.session.seed},
      {"patterns", set.id},
      {"bursts", count},
      {"first_index", o.first},
      {"trajectory_bursts", available},
      {"trajectory_s", static_cast<double>(session.trajectory().DurationNs()) * 1e-9},
      {"surface_pct", 100.0 * totals.surface / std::max<int64_t>(count, 1)},
      {"lit_pct", 100.0 * totals.lit / std::max<int64_t>(count, 1)},
      {"in_measurement_volume_pct", 100.0 * static_cast<double>(totals.in_volume) / n},
      {"ms_per_burst_with_io", 1000.0 * totals.seconds / n},
      {"out", o.out_dir}};
  std::ofstream(fs::path(o.out_dir) / "summary.json") << summary.dump(2) << "\n";
  if (o.json)
    std::printf("%s\n", summary.dump().c_str());
  else
    std::printf("d3d-sim: %lld bursts of %s written to %s (%.0f ms per burst)\n",
                static_cast<long long>(count), o.session.model.c_str(), o.out_dir.c_str(),
                1000.0 * totals.seconds / n);
}

}  // namespace

int main(int argc, char** argv) {
  OptionRegistry options(
      "d3d-sim: the virtual intraoral probe. Renders 4-frame phase-shift bursts of a dental arch "
      "along a "
      "hand-held scan trajectory, with per-pixel ground truth, and writes them as a burst folder "
      "set:\n"
      "  OUT/calibration.json  the probe's calibration (the only thing downstream stages may use)\n"
      "  OUT/trajectory.tum    the true trajectory (TUM: t[s] tx ty tz[mm] qx qy qz qw)\n"
      "  OUT/scene.ply         the scene mesh (mm)\n"
      "  OUT/bursts/NNNNNN/    frame_K.png, burst.json (timestamps, poses), truth_ref/ and "
      "truth_K/ (*.npy|png)\n"
      "  OUT/preview.png       the middle burst: frames, true depth, surfaces (frames only with "
      "--truth none)\n"
      "  OUT/summary.json      what was rendered");
  ToolOptions o;
  DeclareOptions(&options, &o);
  if (int code = 0; !options.Parse(argc, argv, &code)) return code;
  if (o.calibration_session) return RunCalibrationSession(o);

  std::unique_ptr<SimSession> session;
  PatternSet set;
  if (const int code = CreateSession(&o, &session, &set); code != 0) return code;
  const int64_t available = session->NumBursts();
  if (o.first < 0 || o.first >= available) {
    std::fprintf(stderr, "d3d-sim: --index %lld outside the trajectory's %lld bursts\n",
                 static_cast<long long>(o.first), static_cast<long long>(available));
    return 2;
  }
  const int64_t count =
      o.frames <= 0 ? available - o.first : std::min(o.frames, available - o.first);
  if (const int code = WriteSessionFiles(o.out_dir, *session); code != 0) return code;
  RenderTotals totals;
  if (const int code = RenderBursts(o, session.get(), set, count, &totals); code != 0) return code;
  ReportScan(o, *session, set, count, available, totals);
  return 0;
}
