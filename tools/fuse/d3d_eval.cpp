// d3d-eval: trueness, coverage and a deviation heat map of a scanned mesh against a reference;
// precision between repeated scans; absolute trajectory error against true poses.
#include <CLI/CLI.hpp>
#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <sstream>

#include "common/mesh/mesh_io.h"
#include "pipeline/eval/evaluate_scan.h"
#include "pipeline/eval/report_json.h"

using namespace d3d;

namespace {

Status LoadTumPoses(const std::string& path, std::vector<double>* t, std::vector<Rigid3d>* poses) {
  std::ifstream f(path);
  if (!f) return NotFound("cannot open '" + path + "'");
  std::string line;
  int ln = 0;
  while (std::getline(f, line)) {
    ++ln;
    if (line.empty() || line[0] == '#') continue;
    std::istringstream is(line);
    double ts, x, y, z, qx, qy, qz, qw;
    if (!(is >> ts >> x >> y >> z >> qx >> qy >> qz >> qw)) return ParseError(path + ":" + std::to_string(ln) + ": expected 8 numbers");
    const Eigen::Quaterniond q(qw, qx, qy, qz);
    if (std::abs(q.norm() - 1) > 1e-3) return ParseError(path + ":" + std::to_string(ln) + ": quaternion not unit");
    t->push_back(ts);
    poses->push_back(RigidFromQuaternion(q.normalized(), Eigen::Vector3d(x, y, z)));
  }
  return Status::Ok();
}

int Fail(const Status& s) {
  std::fprintf(stderr, "d3d-eval: %s\n", s.ToString().c_str());
  return 1;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"d3d-eval: accuracy of a scan (mm) against a reference mesh: best-fit ICP, signed deviations (trueness:\n"
               "RMS, mean, mean |d|, p95 in um), coverage of the reference teeth within 0.2 mm, a heat map; precision\n"
               "between repeated scans (--precision); absolute trajectory error (--poses with --truth, TUM files, mm)."};
  std::string scan_path, ref_path, heatmap, poses_path, truth_path;
  std::vector<std::string> precision;
  bool json = false, no_global = false;
  double max_distance = 1.0, range_um = 50;
  app.add_option("--scan", scan_path, "scanned mesh (PLY/STL/OBJ, mm)");
  app.add_option("--reference", ref_path, "reference mesh (PLY/STL/OBJ, mm)");
  app.add_option("--heatmap", heatmap, "write the deviation heat map (PNG)");
  app.add_option("--heatmap-range", range_um, "heat map colour range ± (um)")->capture_default_str();
  app.add_option("--max-distance", max_distance, "scan points farther than this (mm) are outliers")->capture_default_str();
  app.add_option("--precision", precision,
                 "two or more scans of the same object: pairwise precision (RMS, p95 of |d| in um) over the surface both\n"
                 "cover (reciprocal closest points; the one-sided figures are printed too)");
  app.add_option("--poses", poses_path, "estimated poses (TUM, mm); with --truth: ATE. Also the initial alignment");
  app.add_option("--truth", truth_path, "true poses (TUM, mm), matched by timestamp");
  app.add_flag("--no-global", no_global, "start ICP from identity instead of the global (principal axes) alignment");
  app.add_flag("--json", json, "print one JSON object");
  CLI11_PARSE(app, argc, argv);
  try {
    nlohmann::json j;
    Rigid3d initial = Rigid3d::Identity();
    bool have_initial = false;
    if (!poses_path.empty() && !truth_path.empty()) {
      std::vector<double> te, tt;
      std::vector<Rigid3d> pe, pt;
      if (const Status s = LoadTumPoses(poses_path, &te, &pe); !s.ok()) return Fail(s);
      if (const Status s = LoadTumPoses(truth_path, &tt, &pt); !s.ok()) return Fail(s);
      std::vector<Rigid3d> a, b;
      size_t k = 0;
      for (size_t i = 0; i < te.size(); ++i) {  // nearest truth by time (within 1 ms)
        while (k + 1 < tt.size() && std::abs(tt[k + 1] - te[i]) <= std::abs(tt[k] - te[i])) ++k;
        if (!tt.empty() && std::abs(tt[k] - te[i]) < 1e-3) {
          a.push_back(pe[i]);
          b.push_back(pt[k]);
        }
      }
      const AteReport ate = AbsoluteTrajectoryError(a, b, &initial);
      have_initial = a.size() >= 3;
      j["ate_mm"] = ate.rmse_mm;
      j["ate_deg"] = ate.mean_deg;
      j["ate_max_mm"] = ate.max_mm;
      j["ate_poses"] = ate.poses;
    }
    if (!scan_path.empty() && !ref_path.empty()) {
      TriangleMesh scan, ref;
      if (const Status s = LoadMesh(scan_path, &scan); !s.ok()) return Fail(s);
      if (const Status s = LoadMesh(ref_path, &ref); !s.ok()) return Fail(s);
      if (ref.face_labels.empty()) LabelFacesFromColors(&ref);
      const MeshClosestPoint cp(ref);
      if (!have_initial && !no_global) initial = GlobalAlign(scan, cp);
      EvaluateOptions o;
      o.max_distance_mm = max_distance;
      const TruenessReport t = EvaluateTrueness(scan, cp, initial, o);
      j["best_fit_rmse_um"] = t.alignment_rmse_mm * 1000;
      const Eigen::Quaterniond q(t.reference_from_scan.linear());
      j["best_fit"] = {{"t_mm", {t.reference_from_scan.translation().x(), t.reference_from_scan.translation().y(), t.reference_from_scan.translation().z()}},
                       {"q_xyzw", {q.x(), q.y(), q.z(), q.w()}}};
      j["trueness_rms_um"] = t.rms_um;
      j["trueness_mean_um"] = t.mean_um;
      j["trueness_mean_abs_um"] = t.mean_abs_um;
      j["trueness_p95_um"] = t.p95_um;
      j["trueness_max_um"] = t.max_um;
      j["points"] = t.points;
      j["outlier_pct"] = t.outlier_pct;
      AddCoverageFields(t, &j);
      if (t.teeth_points > 0) {
        j["trueness_teeth_rms_um"] = t.teeth_rms_um;
        j["trueness_teeth_mean_um"] = t.teeth_mean_um;
        j["trueness_teeth_p95_um"] = t.teeth_p95_um;
        j["trueness_teeth_points"] = t.teeth_points;
      }
      if (!heatmap.empty()) {
        TriangleMesh in_ref = scan;
        for (auto& v : in_ref.vertices) v = t.reference_from_scan * v;
        if (!cv::imwrite(heatmap, DeviationHeatMap(in_ref, t.signed_um, range_um))) return Fail(IoError("cannot write '" + heatmap + "'"));
      }
    }
    if (precision.size() >= 2) {
      std::vector<TriangleMesh> scans(precision.size());
      for (size_t i = 0; i < precision.size(); ++i)
        if (const Status s = LoadMesh(precision[i], &scans[i]); !s.ok()) return Fail(s);
      double sum = 0;
      int pairs = 0;
      nlohmann::json pj = nlohmann::json::array();
      for (size_t a = 0; a < scans.size(); ++a)
        for (size_t b = a + 1; b < scans.size(); ++b) {
          const MeshClosestPoint cp(scans[a]);
          const Rigid3d init = no_global ? Rigid3d::Identity() : GlobalAlign(scans[b], cp);
          const PrecisionReport p = EvaluatePrecision(scans[a], scans[b], init);
          pj.push_back({{"a", precision[a]},
                        {"b", precision[b]},
                        {"rms_um", p.rms_um},
                        {"p95_um", p.p95_um},
                        {"points", p.points},
                        {"not_reciprocal_pct", p.not_reciprocal_pct},
                        {"one_sided_rms_um", p.one_sided_rms_um},
                        {"one_sided_p95_um", p.one_sided_p95_um}});
          sum += p.rms_um;
          ++pairs;
        }
      j["precision_pairs"] = pj;
      j["precision_rms_um"] = sum / pairs;
    }
    if (j.empty()) {
      std::fprintf(stderr, "d3d-eval: nothing to do: give --scan and --reference, --precision A B ..., or --poses and --truth\n");
      return 2;
    }
    std::printf("%s\n", json ? j.dump().c_str() : j.dump(2).c_str());
  } catch (const std::exception& e) {
    std::fprintf(stderr, "d3d-eval: %s\n", e.what());
    return 2;
  }
  return 0;
}
