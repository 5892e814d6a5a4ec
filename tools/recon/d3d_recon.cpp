// d3d-recon: one burst → an organised point cloud (pipeline/recon), from a burst folder or from
// the virtual probe, with accuracy figures when the truth is known.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "common/burst/burst_io.h"
#include "common/mesh/mesh_io.h"
#include "common/mesh/point_cloud_io.h"
#include "common/options/option_registry.h"
#include "pipeline/recon/evaluate.h"
#include "pipeline/recon/reconstruct.h"
#include "pipeline/unwrap/quality_map.h"
#include "sim/session/sim_session.h"

namespace fs = std::filesystem;
using namespace d3d;

namespace {

// Wrapped-phase error (rad) against the truth on valid pixels: RMS.
double PhaseRmsRad(const PhaseMaps& phase, const FrameTruth& truth, const FringePatternSpec& spec) {
  double sum2 = 0;
  int64_t n = 0;
  for (int r = 0; r < phase.phi.rows; ++r)
    for (int c = 0; c < phase.phi.cols; ++c) {
      if (!phase.valid.at<uint8_t>(r, c) || truth.visibility.at<uint8_t>(r, c) != 2) continue;
      const double Phi =
          spec.AbsolutePhase(truth.projector_uv.at<cv::Vec2f>(r, c)[spec.axis == 'y' ? 1 : 0]);
      if (!std::isfinite(Phi)) continue;  // a binned block across a depth step
      const double e = std::remainder(phase.phi.at<float>(r, c) - Phi, 2 * M_PI);
      sum2 += e * e;
      ++n;
    }
  return n ? std::sqrt(sum2 / static_cast<double>(n)) : std::nan("");
}

cv::Mat Colourise(const cv::Mat& m, double lo, double hi) {
  return FalseColour(m, lo, hi, cv::COLORMAP_VIRIDIS);
}

// Why each pixel has no point, as colours (BGR): the first stage that dropped it.
//   black    no wrapped phase (dark, saturated, too little modulation B)
//   grey     quality 0: shadow, low modulation, saturated or isolated
//   blue     quality 0: albedo edge (modulation_edge_ratio)
//   orange   quality 0: phase noise or a discontinuity (max_laplace)
//   cyan     in no unwrapping region (a conflict, a backward step)
//   yellow   in a region too small to anchor
//   magenta  in a region neither marker nor depth anchored (ambiguous)
//   purple   in a region rejected: marker votes disagree, or ordering violations
//   pink     in an anchored region, but dropped by neck pruning or outside the measurement volume
//   red      an absolute phase, but no point (the triangulation's volume margin)
//   white    a point
//   sky blue a point in the albedo-edge cut, its phase filled from the anchored pixels beside it
cv::Mat DropReasonImage(const ReconstructedView& v) {
  const cv::Vec3b kBlack{0, 0, 0}, kGrey{128, 128, 128}, kBlue{255, 0, 0}, kOrange{0, 140, 255},
      kCyan{255, 255, 0}, kYellow{0, 255, 255}, kMagenta{255, 0, 255}, kPurple{128, 0, 128},
      kPink{203, 192, 255}, kRed{0, 0, 255}, kWhite{255, 255, 255}, kSky{255, 191, 0};
  cv::Mat out(v.points_in_cam.size(), CV_8UC3);
  for (int r = 0; r < out.rows; ++r)
    for (int c = 0; c < out.cols; ++c) {
      cv::Vec3b colour = kRed;
      const int rid = v.unwrap.region.at<int32_t>(r, c);
      if (std::isfinite(v.points_in_cam.at<cv::Vec3f>(r, c)[2])) {
        colour = v.quality_reason.at<uint8_t>(r, c) ==
                         static_cast<uint8_t>(QualityReason::kModulationEdge)
                     ? kSky
                     : kWhite;
      } else if (!v.phase.valid.at<uint8_t>(r, c)) {
        colour = kBlack;
      } else if (!(v.quality.at<float>(r, c) > 0)) {
        const auto reason = static_cast<QualityReason>(v.quality_reason.at<uint8_t>(r, c));
        colour = reason == QualityReason::kModulationEdge ? kBlue
                 : reason == QualityReason::kPhaseNoise   ? kOrange
                                                          : kGrey;
      } else if (rid < 0 || rid >= static_cast<int>(v.unwrap.regions.size())) {
        colour = kCyan;
      } else if (v.unwrap.order.at<int32_t>(r, c) < 0) {
        switch (v.unwrap.regions[static_cast<size_t>(rid)].anchor) {
          case RegionAnchor::kTooSmall:
            colour = kYellow;
            break;
          case RegionAnchor::kAmbiguous:
            colour = kMagenta;
            break;
          case RegionAnchor::kMarkerConflict:
          case RegionAnchor::kInconsistent:
            colour = kPurple;
            break;
          // Anchored: neck pruning, or outside the measurement volume (the unwrapper does not say
          // which).
          default:
            colour = kPink;
            break;
        }
      }
      out.at<cv::Vec3b>(r, c) = colour;
    }
  return out;
}

Status WriteMaps(const std::string& dir, const ReconstructedView& v, const cv::Mat& error_um) {
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) return IoError("cannot create '" + dir + "'");
  cv::Mat order_f;
  v.unwrap.order.convertTo(order_f, CV_32F);
  order_f.setTo(std::nanf(""), v.unwrap.order < 0);
  double kmin = 0, kmax = 1;
  cv::minMaxIdx(v.unwrap.order, nullptr, &kmax);
  // The unwrapper's regions (UnwrapResult::region) as 16-bit grey, index + 1 (0: in none): which
  // pixels one region joined, e.g. across a depth step that hides a whole fringe.
  cv::Mat region16;
  v.unwrap.region.convertTo(region16, CV_16U, 1.0, 1.0);
  const bool ok =
      cv::imwrite(dir + "/phase.png", Colourise(v.phase.phi, 0, 2 * M_PI)) &&
      cv::imwrite(dir + "/region.png", region16) &&
      cv::imwrite(dir + "/modulation.png", Colourise(v.phase.modulation, 0, 120)) &&
      cv::imwrite(dir + "/quality.png", Colourise(v.quality, 0, 1)) &&
      cv::imwrite(dir + "/order.png", Colourise(order_f, kmin, std::max(kmax, 1.0))) &&
      cv::imwrite(dir + "/marker.png", v.phase.marker) &&
      cv::imwrite(dir + "/texture.png", v.texture) &&
      cv::imwrite(dir + "/dropped.png", DropReasonImage(v)) &&
      (v.phase.kappa.empty() ||
       cv::imwrite(dir + "/kappa.png", Colourise(v.phase.kappa, 0, 1.5))) &&
      (error_um.empty() || (cv::imwrite(dir + "/error_um.png", ErrorHeatMap(error_um, 25.0)) &&
                            cv::imwrite(dir + "/error_um.tiff", error_um)));
  return ok ? Status::Ok() : IoError("cannot write maps in '" + dir + "'");
}

struct Figures {
  CloudErrors err;
  UnwrapStats unwrap;
  std::vector<RegionInfo> largest_regions;  // the unwrapper's largest regions, for diagnosis
  double phase_rms_rad = std::nan("");
  double ms = 0;
  int64_t points = 0;
  int64_t pixels_edge_filled = 0;  // of the points, those in the albedo-edge cut (EdgeFiller)
};

// Everything the command line sets.
struct ToolOptions {
  std::string images, sim_model, calibration_path, out_ply, maps_dir, camera = "640x480", pose_text;
  int64_t index = -1, count = 1;
  int bin = 1;
  uint32_t seed = 1;
  bool json = false, motion_compensation = false;
};

void DeclareOptions(OptionRegistry* options, ToolOptions* o) {
  options->Add("--images", &o->images, "burst folder (frame_K.png + burst.json)");
  options->Add("--sim", &o->sim_model, "render with the virtual probe: 'typodont' or a mesh file");
  options->Add("--index", &o->index,
               "--sim: burst index on the full-arch trajectory (default: the first pose)");
  options->Add("--pose", &o->pose_text,
               "--sim: render one burst with the probe held still at world_from_probe = 'tx ty tz "
               "qx qy qz qw'\n"
               "(mm, unit quaternion; the TUM order without the time)");
  options->Add("--camera", &o->camera, "--sim: camera size, 640x480 (default) or 1280x1024");
  options->Add("--count", &o->count,
               "--sim: evaluate N bursts spread evenly over the trajectory (default 1)");
  options->Add("--seed", &o->seed, "--sim: seed (default 1)");
  options->Add("--calibration", &o->calibration_path,
               "calibration.json (default: found beside the images)");
  options->Add("--out", &o->out_ply,
               "write the cloud as binary PLY (x y z nx ny nz intensity quality)");
  options->Add("--maps", &o->maps_dir,
               "write PNG maps: phase, modulation, quality, order, region (16-bit: the "
               "unwrapper's region index + 1, 0 in none), marker, texture, dropped (why a pixel "
               "has no point), kappa (harmonic attenuation), error (PNG, and TIFF in µm)");
  options->Flag("--motion-compensation", &o->motion_compensation,
                "compensate the hand's motion within the burst "
                "(PhaseOptions::motion_compensation), as d3d-fuse and\n"
                "d3d-scan reconstruct hand-held bursts");
  options->Add("--bin", &o->bin,
               "average the frames over NxN pixel blocks and reconstruct with the binned "
               "calibration, as d3d-scan\n"
               "does (default 1; the truth is binned alike: BinnedTruth)");
  options->Flag("--json", &o->json, "print one JSON object as the last line");
}

// The bursts to reconstruct, with their calibration and, when the truth is known, the scene.
struct Inputs {
  std::vector<Burst> bursts;
  ProbeCalibration calib;
  TriangleMesh scene;
  bool have_truth = false;
};

// --images: the burst folder, the calibration beside it (or --calibration) and, when the folder has
// truth maps, the scene.ply beside the calibration. Returns 0, or the exit code after printing why.
int LoadBurstFolder(ToolOptions* o, Inputs* in) {
  Burst b;
  if (const Status s = ReadBurstDir(o->images, true, &b); !s.ok()) {
    std::fprintf(stderr, "d3d-recon: %s\n", s.ToString().c_str());
    return 1;
  }
  if (o->calibration_path.empty()) {
    for (fs::path d = fs::absolute(o->images); !d.empty() && d != d.root_path();
         d = d.parent_path()) {
      if (fs::exists(d / "calibration.json")) {
        o->calibration_path = (d / "calibration.json").string();
        break;
      }
    }
  }
  if (const Status s = ProbeCalibration::Load(o->calibration_path, &in->calib); !s.ok()) {
    std::fprintf(stderr, "d3d-recon: %s\n", s.ToString().c_str());
    return 1;
  }
  const fs::path scene_path = fs::path(o->calibration_path).parent_path() / "scene.ply";
  in->have_truth = b.reference_truth.has_maps() && fs::exists(scene_path) &&
                   LoadMesh(scene_path.string(), &in->scene).ok();
  in->bursts.push_back(std::move(b));
  return 0;
}

// --sim: renders the bursts with the virtual probe: one at --pose (then --count is 0), or --count
// bursts from --index on, or spread evenly over the trajectory. Returns 0, or the exit code after
// printing why.
int RenderSimBursts(ToolOptions* o, Inputs* in) {
  SimSessionOptions so;
  so.model = o->sim_model;
  so.seed = o->seed;
  if (std::sscanf(o->camera.c_str(), "%dx%d", &so.camera_width, &so.camera_height) != 2) {
    std::fprintf(stderr, "d3d-recon: --camera must look like 640x480, got '%s'\n",
                 o->camera.c_str());
    return 2;
  }
  std::unique_ptr<SimSession> session;
  if (const Status s = SimSession::Create(so, &session); !s.ok()) {
    std::fprintf(stderr, "d3d-recon: %s\n", s.ToString().c_str());
    return 1;
  }
  in->calib = session->calibration();
  in->scene = session->scene();
  in->have_truth = true;
  const int64_t n = session->NumBursts();
  if (!o->pose_text.empty()) {
    double v[7];
    if (std::sscanf(o->pose_text.c_str(), "%lf %lf %lf %lf %lf %lf %lf", &v[0], &v[1], &v[2], &v[3],
                    &v[4], &v[5], &v[6]) != 7 ||
        std::abs(Eigen::Vector4d(v[3], v[4], v[5], v[6]).norm() - 1.0) > 1e-3) {
      std::fprintf(
          stderr,
          "d3d-recon: --pose must be 'tx ty tz qx qy qz qw' with a unit quaternion, got '%s'\n",
          o->pose_text.c_str());
      return 2;
    }
    const Rigid3d world_from_probe = RigidFromQuaternion(
        Eigen::Quaterniond(v[6], v[3], v[4], v[5]).normalized(), Eigen::Vector3d(v[0], v[1], v[2]));
    in->bursts.push_back(session->probe().RenderBurst(
        [world_from_probe](int64_t) { return world_from_probe; }, 0, 0, o->seed, true));
    o->count = 0;
  }
  for (int64_t i = 0; i < o->count; ++i) {
    const int64_t k =
        o->index >= 0 ? o->index + i : (o->count == 1 ? 0 : i * (n - 1) / (o->count - 1));
    if (k >= n) break;
    in->bursts.push_back(session->RenderBurst(k, true));
  }
  return 0;
}

// The figures of one reconstructed view; with the truth, its accuracy (error_um: per pixel).
Figures Evaluate(const ReconstructedView& view, const Burst& b, const Inputs& in, int bin,
                 cv::Mat* error_um) {
  Figures f;
  f.ms = view.ms_total;
  f.points = view.points;
  f.pixels_edge_filled = view.pixels_edge_filled;
  f.unwrap = view.unwrap.stats;
  f.largest_regions.resize(std::min<size_t>(view.unwrap.regions.size(), 6));
  std::partial_sort_copy(
      view.unwrap.regions.begin(), view.unwrap.regions.end(), f.largest_regions.begin(),
      f.largest_regions.end(),
      [](const RegionInfo& a, const RegionInfo& b) { return a.pixels > b.pixels; });
  if (in.have_truth) {
    const FrameTruth truth = bin > 1 ? BinnedTruth(b.reference_truth, bin) : b.reference_truth;
    f.err = EvaluateCloud(view.points_in_cam, view.unwrap.Phi, truth, in.scene, in.calib.pattern,
                          error_um);
    f.phase_rms_rad = PhaseRmsRad(view.phase, truth, in.calib.pattern);
  }
  return f;
}

// --out and --maps of the first burst. Returns 0, or 1 after printing why.
int WriteFirstView(const ToolOptions& o, const ReconstructedView& view, const cv::Mat& error_um) {
  if (!o.out_ply.empty()) {
    if (const Status s = SavePointCloudPly(o.out_ply, view.points_in_cam, view.normals,
                                           view.texture, view.quality);
        !s.ok()) {
      std::fprintf(stderr, "d3d-recon: %s\n", s.ToString().c_str());
      return 1;
    }
  }
  if (!o.maps_dir.empty()) {
    if (const Status s = WriteMaps(o.maps_dir, view, error_um); !s.ok()) {
      std::fprintf(stderr, "d3d-recon: %s\n", s.ToString().c_str());
      return 1;
    }
  }
  return 0;
}

// Reconstructs every burst (binned with --bin) and evaluates it; the first one's cloud and maps
// are written, and with several bursts one line per burst goes to stderr. Returns 0, or the exit
// code after printing why.
int ReconstructAll(const ToolOptions& o, Inputs* in, std::vector<Figures>* figures) {
  ReconstructOptions recon_options;
  recon_options.phase.motion_compensation = o.motion_compensation;
  if (o.bin < 1) {
    std::fprintf(stderr, "d3d-recon: --bin must be >= 1\n");
    return 2;
  }
  if (o.bin > 1) in->calib = BinnedCalibration(in->calib, o.bin);
  Reconstructor recon(in->calib, recon_options);
  ReconstructedView view;
  for (const Burst& b : in->bursts) {
    std::vector<cv::Mat> frames;
    for (int k = 0; k < in->calib.pattern.steps && k < static_cast<int>(b.frames.size()); ++k) {
      frames.push_back(b.frames[static_cast<size_t>(k)].image);
      if (o.bin > 1)
        if (const Status s =
                BinFrame(b.frames[static_cast<size_t>(k)].image, o.bin, &frames.back());
            !s.ok()) {
          std::fprintf(stderr, "d3d-recon: %s\n", s.ToString().c_str());
          return 1;
        }
    }
    if (const Status s = recon.Reconstruct(frames, &view); !s.ok()) {
      std::fprintf(stderr, "d3d-recon: burst %llu: %s\n",
                   static_cast<unsigned long long>(b.sequence), s.ToString().c_str());
      return 1;
    }
    cv::Mat error_um;
    const Figures f = Evaluate(view, b, *in, o.bin, &error_um);
    figures->push_back(f);
    if (&b == &in->bursts.front())
      if (const int code = WriteFirstView(o, view, error_um); code != 0) return code;
    if (o.count > 1) {
      std::fprintf(stderr,
                   "burst %6llu: %7lld points, tooth valid %5.1f %%, rms %6.1f um, p95 %6.1f um, "
                   "order errors %.4f %%, %.1f ms\n",
                   static_cast<unsigned long long>(b.sequence), static_cast<long long>(f.points),
                   f.err.tooth_valid_pct, f.err.rms_um, f.err.p95_um, f.err.order_error_pct, f.ms);
    }
  }
  return 0;
}

// The unwrapper's statistics and largest regions of a single burst, for diagnosis.
nlohmann::json UnwrapJson(const Figures& f) {
  const UnwrapStats& u = f.unwrap;
  nlohmann::json j = {
      {"regions_total", u.regions_total},     {"regions_marker", u.regions_marker},
      {"regions_depth", u.regions_depth},     {"regions_rejected", u.regions_rejected},
      {"regions_small", u.regions_small},     {"pixels_usable", u.pixels_usable},
      {"pixels_valid", u.pixels_valid},       {"pixels_discontinuity", u.pixels_discontinuity},
      {"pixels_conflict", u.pixels_conflict}, {"pixels_small", u.pixels_small},
      {"pixels_rejected", u.pixels_rejected}, {"pixels_outside", u.pixels_outside},
      {"pixels_neck", u.pixels_neck},         {"pixels_edge_filled", f.pixels_edge_filled}};
  for (const RegionInfo& r : f.largest_regions)
    j["largest_regions"].push_back({{"pixels", r.pixels},
                                    {"anchor", RegionAnchorName(r.anchor)},
                                    {"offset", r.offset},
                                    {"marker_hits", r.marker_hits},
                                    {"marker_predicted", r.marker_predicted},
                                    {"marker_rival_hits", r.marker_rival_hits},
                                    {"bounded_pixels", r.bounded_pixels},
                                    {"admitting_pixels", r.admitting_pixels},
                                    {"violations", r.violations}});
  return j;
}

// Aggregate: per-frame figures averaged (RMS as the RMS over all points), worst frame too.
nlohmann::json Aggregate(const std::vector<Figures>& figures, bool have_truth) {
  nlohmann::json j;
  double sum2 = 0, p95_sum = 0, valid_sum = 0, ms_sum = 0, phase_sum = 0, worst_rms = 0;
  int64_t points = 0, evaluated = 0, order_err = 0, order_checked = 0;
  for (const Figures& f : figures) {
    sum2 += f.err.rms_um * f.err.rms_um * static_cast<double>(f.err.points);
    evaluated += f.err.points;
    p95_sum += f.err.p95_um;
    valid_sum += f.err.tooth_valid_pct;
    ms_sum += f.ms;
    phase_sum += std::isfinite(f.phase_rms_rad) ? f.phase_rms_rad : 0;
    points += f.points;
    order_err += f.err.order_errors;
    order_checked += f.err.order_checked;
    worst_rms = std::max(worst_rms, f.err.rms_um);
  }
  const double n = static_cast<double>(figures.size());
  j["bursts"] = figures.size();
  j["points"] = static_cast<double>(points) / n;
  j["ms"] = ms_sum / n;
  if (have_truth) {
    j["valid_pct"] = valid_sum / n;
    j["rms_um"] = evaluated ? std::sqrt(sum2 / static_cast<double>(evaluated)) : 0.0;
    j["worst_frame_rms_um"] = worst_rms;
    j["p95_um"] = p95_sum / n;
    j["fringe_order_error_pct"] =
        order_checked ? 100.0 * static_cast<double>(order_err) / static_cast<double>(order_checked)
                      : 0.0;
    j["phase_rms_rad"] = phase_sum / n;
  }
  if (figures.size() == 1) j["unwrap"] = UnwrapJson(figures.front());
  return j;
}

}  // namespace

int main(int argc, char** argv) {
  OptionRegistry options(
      "d3d-recon: reconstructs one phase-shift burst into an organised point cloud (camera frame, "
      "mm).\n"
      "Input: a burst folder (--images, as written by d3d-sim or d3d-record export; "
      "calibration.json in "
      "it or\n"
      "in a parent folder) or the virtual probe (--sim). With truth, prints accuracy figures.");
  ToolOptions o;
  DeclareOptions(&options, &o);
  if (int code = 0; !options.Parse(argc, argv, &code)) return code;
  if (o.images.empty() == o.sim_model.empty()) {
    std::fprintf(stderr, "d3d-recon: give exactly one of --images DIR or --sim MODEL\n");
    return 2;
  }
  try {
    Inputs in;
    if (const int code = !o.images.empty() ? LoadBurstFolder(&o, &in) : RenderSimBursts(&o, &in);
        code != 0)
      return code;
    std::vector<Figures> figures;
    if (const int code = ReconstructAll(o, &in, &figures); code != 0) return code;
    const nlohmann::json j = Aggregate(figures, in.have_truth);
    if (o.json)
      std::printf("%s\n", j.dump().c_str());
    else
      std::printf("%s\n", j.dump(2).c_str());
  } catch (const std::exception& e) {
    std::fprintf(stderr, "d3d-recon: %s\n", e.what());
    return 2;
  }
  return 0;
}
