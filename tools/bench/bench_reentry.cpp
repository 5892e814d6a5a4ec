// d3d-bench-reentry: how often a re-entry is accepted at a wrong pose, on an adversarial set
// (issue 50: "views of tooth N started at tooth N ± 1 and at mirrored positions").
// A full-arch scan of the virtual probe runs through the offline chain (d3d-fuse's reconstruction
// and tracking with model anchoring, at --bin and --every). Then, every --stride-th view i that the
// scan placed in its model, a fresh tracker is brought to the scan's state at i (the scan's views
// 0 … i again) and trials branch off it: the probe is lifted (--gap views without points) and put
// back (two views: the first may become a re-entry candidate that the second confirms):
//   - "same place": where the scan went on (the control: it should re-enter there);
//   - "N teeth back / on": the scan's next poses moved along the arch by N tooth pitches (the arch
//     length / 14), seen from the same side, distance and angle;
//   - "mirrored": the scan's next poses mirrored across the arch's midline (the contralateral
//   tooth).
// After each trial the tracker takes its views back (Tracker::UndoFrom) for the next one. The track
// starts from the place it left, so the neighbouring and the mirrored tooth meet the re-entry
// search's own prior.
// Each trial view the tracker accepted into the main model is checked against the truth relative
// to the scan's view nearest it (the scan's own drift is no error here): off by more than 0.2 mm or
// 1° is a false accept (report.json's wrong_fusions: kWrongFusionMm at the view's footprint,
// kWrongFusionDeg), else right; a trial with no accepted view
// is refused. Prints a table by start (and the largest error of the right ones); --json one object.
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <nlohmann/json.hpp>

#include "common/options/option_registry.h"
#include "pipeline/chain/scan_chain.h"
#include "pipeline/eval/evaluate_scan.h"
#include "sim/session/sim_session.h"
#include "sim/trajectory/arch_moves.h"

using namespace d3d;

namespace {

struct Start {
  std::string name;
  double teeth = 0;     // along the arch, in tooth pitches
  bool mirror = false;  // across the midline
};

struct TrialView {
  size_t start = 0;  // index into the starts
  int trial = 0;     // trial number
  bool accepted = false;
  Rigid3d est = Rigid3d::Identity(), truth = Rigid3d::Identity();
};

struct Tally {
  int trials = 0, right = 0, refused = 0, wrong = 0;
  double worst_mm = 0, worst_deg = 0;  // of the false accepts
  double right_mm = 0, right_deg = 0;  // the largest error of the right ones
};

// Renders, reconstructs and registers bursts of the session at any pose; the clock runs on by one
// view period per view fed.
class Chain {
 public:
  Chain(SimSession& session, const ScanOptions& so, int every)
      : session_(session),
        recon_(session.calibration(), so.recon, so.bin),
        registrar_(recon_.calibration(), so.tracker, so.anchor, so.recon.normal_max_gap_mm),
        period_ns_(static_cast<int64_t>(every * 1e9 / 30)) {}

  // Burst `index` of the session rendered along move(trajectory) with noise of `sequence` into
  // *frames; *truth: the true pose at the burst's reference time.
  void Render(int64_t index, const std::function<Rigid3d(const Rigid3d&)>& move, uint64_t sequence,
              std::vector<cv::Mat>* frames, Rigid3d* truth) {
    const Trajectory& traj = session_.trajectory();
    const PoseAtTime pose = [&](int64_t t) { return move(traj.WorldFromProbe(t)); };
    const Burst b = session_.probe().RenderBurst(pose, session_.BurstStartNs(index), sequence,
                                                 session_.options().seed, false);
    frames->clear();
    for (const BurstFrame& f : b.frames) frames->push_back(f.image);
    *truth = pose(b.reference_ns);
  }
  TrackResult Feed(const std::vector<cv::Mat>& frames, uint64_t sequence) {
    if (!recon_.Reconstruct(frames, &view_).ok())
      throw std::runtime_error("reconstruction refused a rendered burst");
    return Register(sequence);
  }
  TrackResult FeedEmpty(uint64_t sequence) {  // the probe out of the mouth: no points
    view_.points_in_cam.setTo(cv::Scalar::all(std::nanf("")));
    view_.normals.setTo(cv::Scalar::all(std::nanf("")));
    view_.quality.setTo(0);
    view_.points = view_.pixels_edge_filled = 0;
    return Register(sequence);
  }
  ScanRegistrar& registrar() { return registrar_; }
  const PinholeBrownConrady& camera() const {
    return recon_.calibration().camera;
  }  // the views' (binned)

 private:
  TrackResult Register(uint64_t sequence) {
    clock_ns_ += period_ns_;
    TrackResult r = registrar_.Register(view_, sequence, clock_ns_);
    registrar_.Commit();
    return r;
  }
  SimSession& session_;
  ScanReconstructor recon_;
  ScanRegistrar registrar_;
  ReconstructedView view_;
  int64_t period_ns_, clock_ns_ = 0;
};

struct Scan {
  std::vector<Rigid3d> est, truth;  // the scan's views in the main model
  std::vector<Eigen::Vector3d>
      footprint;  // ViewFootprint of the view camera: where errors are judged
};

// The pose error of a trial view (est, truth) relative to the scan's view nearest it (by true
// position): (E_j⁻¹ E)⁻¹ (T_j⁻¹ T), mm at the view's footprint and degrees. Relative to a neighbour
// the scan placed, its drift is no error here, and no alignment's own error enters.
void ErrorAgainstNearest(const Scan& scan, const Rigid3d& est, const Rigid3d& truth, double* mm,
                         double* deg) {
  size_t j = 0;
  double best = std::numeric_limits<double>::infinity();
  for (size_t i = 0; i < scan.truth.size(); ++i) {
    const double d = (scan.truth[i].translation() - truth.translation()).squaredNorm();
    if (d < best) best = d, j = i;
  }
  const Rigid3d e = scan.est[j].inverse() * est, t = scan.truth[j].inverse() * truth;
  *mm = FootprintDistanceMm(e, t, scan.footprint);
  *deg = RotationAngleRad(e, t) * 180 / M_PI;
}

std::vector<Tally> Evaluate(const std::vector<TrialView>& views, size_t starts, const Scan& scan) {
  std::vector<Tally> tally(starts);
  std::map<std::pair<size_t, int>, int> outcome;  // (start, trial) → 0 refused, 1 right, 2 wrong
  for (const TrialView& v : views) {
    int& o = outcome[{v.start, v.trial}];
    if (!v.accepted) continue;
    double mm, deg;
    ErrorAgainstNearest(scan, v.est, v.truth, &mm, &deg);
    if (mm > kWrongFusionMm || deg > kWrongFusionDeg) {
      o = 2;
      tally[v.start].worst_mm = std::max(tally[v.start].worst_mm, mm);
      tally[v.start].worst_deg = std::max(tally[v.start].worst_deg, deg);
    } else {
      o = std::max(o, 1);
      tally[v.start].right_mm = std::max(tally[v.start].right_mm, mm);
      tally[v.start].right_deg = std::max(tally[v.start].right_deg, deg);
    }
  }
  for (const auto& [key, o] : outcome) {
    Tally& t = tally[key.first];
    ++t.trials;
    t.refused += o == 0;
    t.right += o == 1;
    t.wrong += o == 2;
  }
  return tally;
}

void Print(const std::vector<Start>& starts, const std::vector<Tally>& tally, nlohmann::json* j,
           bool json) {
  int all = 0, wrong = 0;
  if (!json)
    std::printf("%-14s %7s %7s %8s %7s %12s %9s %9s %14s\n", "start", "trials", "right", "refused",
                "wrong", "false acc %", "worst mm", "worst deg", "right max mm/°");
  for (size_t s = 0; s < starts.size(); ++s) {
    const Tally& t = tally[s];
    const double rate = t.trials ? 100.0 * t.wrong / t.trials : 0;
    all += t.trials;
    wrong += t.wrong;
    (*j)["starts"][starts[s].name] = {
        {"trials", t.trials},       {"right", t.right},           {"refused", t.refused},
        {"wrong", t.wrong},         {"false_accept_pct", rate},   {"worst_mm", t.worst_mm},
        {"worst_deg", t.worst_deg}, {"right_max_mm", t.right_mm}, {"right_max_deg", t.right_deg}};
    if (!json)
      std::printf("%-14s %7d %7d %8d %7d %12.2f %9.3f %9.2f %8.3f/%5.2f\n", starts[s].name.c_str(),
                  t.trials, t.right, t.refused, t.wrong, rate, t.worst_mm, t.worst_deg, t.right_mm,
                  t.right_deg);
  }
  (*j)["trials"] = all;
  (*j)["false_accepts"] = wrong;
  if (json)
    std::printf("%s\n", j->dump(2).c_str());
  else
    std::printf("all: %d trials, %d false accepts (%.2f %%)\n", all, wrong,
                all ? 100.0 * wrong / all : 0);
}

struct Options {
  std::string model = "typodont";
  unsigned seed = 1;
  int bin = 2, every = 2, stride = 20, gap = 15;
  bool json = false;
};

void DeclareOptions(OptionRegistry* r, Options* o) {
  r->Add("--sim", &o->model, "typodont or an arch mesh (PLY/STL/OBJ, mm)");
  r->Add("--seed", &o->seed, "the full-arch scan's seed");
  r->Add("--bin", &o->bin, "pixel binning, as d3d-fuse --bin").Range(1, 4);
  r->Add("--every", &o->every, "every N-th burst, as d3d-fuse --every").Range(1, 8);
  r->Add("--stride", &o->stride, "scan views between trials").Range(5, 100000);
  r->Add("--gap", &o->gap, "views without points in a lift").Range(3, 1000);
  r->Flag("--json", &o->json, "print one JSON object instead of the table");
}

// d3d-fuse's scan options at --bin and --every, with room to take the trials back.
ScanOptions ReentryScanOptions(int bin, int every) {
  ScanOptions so;
  so.tracker = TrackerOptionsForStep(so.tracker, every);
  so.tracker.odometry.map.undo_inserts = 64;  // the trials are taken back
  so = ScanOptionsForBin(so, bin);
  so.Check();
  return so;
}

// The full-arch scan: every --every-th burst, its frames kept for the replays.
struct ScanRun {
  std::vector<int64_t> bursts;
  std::vector<std::vector<cv::Mat>> frames;
  std::vector<Rigid3d> truth;
  std::vector<TrackResult> tracked;
  Scan scan;  // the views it placed in its main model
};

// Runs the scan through a fresh chain. Throws when it placed too few views to judge the trials.
ScanRun RunScan(SimSession& session, const ScanOptions& so, int every) {
  ScanRun run;
  for (int64_t i = 0; i < session.NumBursts(); i += every) run.bursts.push_back(i);
  const size_t n = run.bursts.size();
  run.frames.resize(n);
  run.truth.resize(n);
  run.tracked.resize(n);
  {
    Chain chain(session, so, every);
    run.scan.footprint = ViewFootprint(chain.camera(), EvaluateOptions{}.footprint_depth_mm);
    const auto identity = [](const Rigid3d& p) { return p; };
    for (size_t i = 0; i < n; ++i) {
      chain.Render(run.bursts[i], identity, static_cast<uint64_t>(run.bursts[i]), &run.frames[i],
                   &run.truth[i]);
      run.tracked[i] = chain.Feed(run.frames[i], static_cast<uint64_t>(run.bursts[i]));
      std::fprintf(stderr, "\rscan: view %zu of %zu", i + 1, n);
    }
  }
  for (size_t i = 0; i < n; ++i)
    if (run.tracked[i].accepted && run.tracked[i].in_main) {
      run.scan.est.push_back(run.tracked[i].world_from_cam);
      run.scan.truth.push_back(run.truth[i]);
    }
  std::fprintf(stderr, "\nscan: %zu of %zu views in the model\n", run.scan.est.size(), n);
  if (run.scan.est.size() < 50)
    throw std::runtime_error("the scan placed too few views to judge the trials");
  return run;
}

// The trials (the file comment): from every --stride-th view the scan placed, a lift and a put-back
// at each start, taken back after. Returns every put-back view.
std::vector<TrialView> RunTrials(SimSession& session, const ArchFrame& arch, const ScanOptions& so,
                                 const Options& o, const ScanRun& run,
                                 const std::vector<Start>& starts) {
  const double pitch = arch.length_mm / 14;
  std::vector<TrialView> trials;
  uint64_t sequence = 1u << 24;  // the trials' noise, apart from the scan's
  int trial = 0;
  for (size_t i = 30; i + 2 < run.bursts.size(); i += static_cast<size_t>(o.stride)) {
    if (!run.tracked[i].accepted || !run.tracked[i].in_main) continue;
    const double arc = ArcPositionSeenMm(arch, run.truth[i]);
    if (!std::isfinite(arc)) continue;
    Chain chain(session, so, o.every);
    for (size_t k = 0; k <= i; ++k) chain.Feed(run.frames[k], static_cast<uint64_t>(run.bursts[k]));
    for (size_t s = 0; s < starts.size(); ++s) {
      const Start& st = starts[s];
      const double to = st.mirror ? 2 * arch.midline_arc_mm - arc : arc + st.teeth * pitch;
      if (to < 0 || to > arch.length_mm || (st.mirror && std::abs(to - arc) < 1.5 * pitch))
        continue;
      const Rigid3d along = ArchMove(arch, arc, st.teeth * pitch);
      const auto move = [&](const Rigid3d& p) {
        return st.mirror ? MirrorAcrossMidline(arch, arc, p) : along * p;
      };
      const int64_t first = chain.registrar().tracker().views();
      for (int g = 0; g < o.gap; ++g) chain.FeedEmpty(sequence++);
      for (size_t k = i + 1; k <= i + 2; ++k) {
        TrialView v{s, trial};
        std::vector<cv::Mat> put_back;
        chain.Render(run.bursts[k], move, sequence, &put_back, &v.truth);
        const TrackResult t = chain.Feed(put_back, sequence++);
        v.accepted = t.accepted && t.in_main;
        v.est = t.world_from_cam;
        trials.push_back(v);
      }
      const Tracker::UndoResult u = chain.registrar().tracker().UndoFrom(first);
      if (!u.ok) throw std::runtime_error("the trial's views cannot be taken back: " + u.reason);
    }
    ++trial;
    std::fprintf(stderr, "\rtrials: after view %zu of %zu, %d places", i, run.bursts.size(), trial);
  }
  std::fprintf(stderr, "\n");
  return trials;
}

}  // namespace

int main(int argc, char** argv) {
  OptionRegistry options(
      "d3d-bench-reentry: the false-accept rate of re-entries after a lift, put back one and two "
      "teeth off\n"
      "and mirrored across the midline (the method: this tool's source).");
  Options o;
  DeclareOptions(&options, &o);
  if (int code = 0; !options.Parse(argc, argv, &code)) return code;
  try {
    SimSessionOptions sso;
    sso.model = o.model;
    sso.seed = o.seed;
    std::unique_ptr<SimSession> session;
    if (const Status s = SimSession::Create(sso, &session); !s.ok())
      throw std::runtime_error(s.ToString());
    const ArchFrame arch = AnalyzeArch(session->scene());
    if (!arch.ok())
      throw std::runtime_error(o.model + " is not taken for an arch: " + arch.status.ToString());
    const ScanOptions so = ReentryScanOptions(o.bin, o.every);
    const std::vector<Start> starts = {{"same place", 0, false}, {"1 tooth back", -1, false},
                                       {"1 tooth on", 1, false}, {"2 teeth back", -2, false},
                                       {"2 teeth on", 2, false}, {"mirrored", 0, true}};
    const ScanRun run = RunScan(*session, so, o.every);
    const std::vector<TrialView> trials = RunTrials(*session, arch, so, o, run, starts);
    nlohmann::json j{{"model", o.model},   {"seed", o.seed},
                     {"bin", o.bin},       {"every", o.every},
                     {"gap_views", o.gap}, {"tooth_pitch_mm", arch.length_mm / 14}};
    Print(starts, Evaluate(trials, starts.size(), run.scan), &j, o.json);
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "d3d-bench-reentry: %s\n", e.what());
    return 1;
  }
}
