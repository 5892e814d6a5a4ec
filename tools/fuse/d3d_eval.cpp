// d3d-eval: trueness, coverage and a deviation heat map of a scanned mesh against a reference;
// precision between repeated scans; absolute trajectory error against true poses.
#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "common/mesh/mesh_io.h"
#include "common/options/option_registry.h"
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
    if (!(is >> ts >> x >> y >> z >> qx >> qy >> qz >> qw))
      return ParseError(path + ":" + std::to_string(ln) + ": expected 8 numbers");
    const Eigen::Quaterniond q(qw, qx, qy, qz);
    if (std::abs(q.norm() - 1) > 1e-3)
      return ParseError(path + ":" + std::to_string(ln) + ": quaternion not unit");
    t->push_back(ts);
    poses->push_back(RigidFromQuaternion(q.normalized(), Eigen::Vector3d(x, y, z)));
  }
  return Status::Ok();
}

int Fail(const Status& s) {
  std::fprintf(stderr, "d3d-eval: %s\n", s.ToString().c_str());
  return 1;
}

struct Options {
  std::string scan_path, ref_path, heatmap, poses_path, truth_path;
  std::vector<std::string> precision;
  bool json = false, no_global = false;
  double max_distance = 1.0, range_um = 50;
};

void DeclareOptions(OptionRegistry* r, Options* o) {
  r->Add("--scan", &o->scan_path, "scanned mesh (PLY/STL/OBJ, mm)");
  r->Add("--reference", &o->ref_path, "reference mesh (PLY/STL/OBJ, mm)");
  r->Add("--heatmap", &o->heatmap, "write the deviation heat map (PNG)");
  r->Add("--heatmap-range", &o->range_um, "heat map colour range ± (um)");
  r->Add("--max-distance", &o->max_distance, "scan points farther than this (mm) are outliers");
  r->Add("--precision", &o->precision,
         "two or more scans of the same object: pairwise precision (RMS, p95 of |d| in um) over "
         "the surface both\n"
         "cover (reciprocal closest points; the one-sided figures are printed too)");
  r->Add("--poses", &o->poses_path,
         "estimated poses (TUM, mm); with --truth: ATE. Also the initial alignment");
  r->Add("--truth", &o->truth_path, "true poses (TUM, mm), matched by timestamp");
  r->Flag("--no-global", &o->no_global,
          "start ICP from identity instead of the global (principal axes) alignment");
  r->Flag("--json", &o->json, "print one JSON object");
}

// The absolute trajectory error of --poses against --truth (each estimated pose matched to the true
// one nearest in time, within 1 ms) into *j. *initial: the alignment it found, taken as the scan's
// initial alignment when *have_initial (3 or more matched poses).
Status AddTrajectoryError(const Options& o, nlohmann::json* j, Rigid3d* initial,
                          bool* have_initial) {
  std::vector<double> te, tt;
  std::vector<Rigid3d> pe, pt;
  if (const Status s = LoadTumPoses(o.poses_path, &te, &pe); !s.ok()) return s;
  if (const Status s = LoadTumPoses(o.truth_path, &tt, &pt); !s.ok()) return s;
  std::vector<Rigid3d> a, b;
  size_t k = 0;
  for (size_t i = 0; i < te.size(); ++i) {  // nearest truth by time (within 1 ms)
    while (k + 1 < tt.size() && std::abs(tt[k + 1] - te[i]) <= std::abs(tt[k] - te[i])) ++k;
    if (!tt.empty() && std::abs(tt[k] - te[i]) < 1e-3) {
      a.push_back(pe[i]);
      b.push_back(pt[k]);
    }
  }
  const AteReport ate = AbsoluteTrajectoryError(a, b, initial);
  *have_initial = a.size() >= 3;
  (*j)["ate_mm"] = ate.rmse_mm;
  (*j)["ate_deg"] = ate.mean_deg;
  (*j)["ate_max_mm"] = ate.max_mm;
  (*j)["ate_poses"] = ate.poses;
  return Status::Ok();
}

// Trueness and coverage of --scan against --reference into *j, from `initial` when given (else the
// global alignment unless --no-global); writes the heat map when asked.
Status AddTrueness(const Options& o, Rigid3d initial, bool have_initial, nlohmann::json* j) {
  TriangleMesh scan, ref;
  if (const Status s = LoadMesh(o.scan_path, &scan); !s.ok()) return s;
  if (const Status s = LoadMesh(o.ref_path, &ref); !s.ok()) return s;
  if (ref.face_labels.empty()) LabelFacesFromColors(&ref);
  const MeshClosestPoint cp(ref);
  if (!have_initial && !o.no_global) initial = GlobalAlign(scan, cp);
  EvaluateOptions eo;
  eo.max_distance_mm = o.max_distance;
  const TruenessReport t = EvaluateTrueness(scan, cp, initial, eo);
  AddTruenessFields(t, j);
  const Eigen::Quaterniond q(t.reference_from_scan.linear());
  (*j)["best_fit"] = {
      {"t_mm",
       {t.reference_from_scan.translation().x(), t.reference_from_scan.translation().y(),
        t.reference_from_scan.translation().z()}},
      {"q_xyzw", {q.x(), q.y(), q.z(), q.w()}}};
  (*j)["trueness_max_um"] = t.max_um;
  (*j)["points"] = t.points;
  (*j)["outlier_pct"] = t.outlier_pct;
  if (!o.heatmap.empty()) {
    TriangleMesh in_ref = scan;
    for (auto& v : in_ref.vertices) v = t.reference_from_scan * v;
    if (!cv::imwrite(o.heatmap, DeviationHeatMap(in_ref, t.signed_um, o.range_um)))
      return IoError("cannot write '" + o.heatmap + "'");
  }
  return Status::Ok();
}

// Pairwise precision between the --precision scans (every pair) and its mean RMS into *j.
Status AddPrecision(const Options& o, nlohmann::json* j) {
  std::vector<TriangleMesh> scans(o.precision.size());
  for (size_t i = 0; i < o.precision.size(); ++i)
    if (const Status s = LoadMesh(o.precision[i], &scans[i]); !s.ok()) return s;
  double sum = 0;
  int pairs = 0;
  nlohmann::json pj = nlohmann::json::array();
  for (size_t a = 0; a < scans.size(); ++a)
    for (size_t b = a + 1; b < scans.size(); ++b) {
      const MeshClosestPoint cp(scans[a]);
      const Rigid3d init = o.no_global ? Rigid3d::Identity() : GlobalAlign(scans[b], cp);
      const PrecisionReport p = EvaluatePrecision(scans[a], scans[b], init);
      pj.push_back({{"a", o.precision[a]},
                    {"b", o.precision[b]},
                    {"rms_um", p.rms_um},
                    {"p95_um", p.p95_um},
                    {"points", p.points},
                    {"not_reciprocal_pct", p.not_reciprocal_pct},
                    {"one_sided_rms_um", p.one_sided_rms_um},
                    {"one_sided_p95_um", p.one_sided_p95_um}});
      sum += p.rms_um;
      ++pairs;
    }
  (*j)["precision_pairs"] = pj;
  (*j)["precision_rms_um"] = sum / pairs;
  return Status::Ok();
}

}  // namespace

int main(int argc, char** argv) {
  OptionRegistry options(
      "d3d-eval: accuracy of a scan (mm) against a reference mesh: best-fit ICP, signed deviations "
      "(trueness:\n"
      "RMS, mean, mean |d|, p95 in um), coverage of the reference teeth within 0.2 mm, a heat map; "
      "precision\n"
      "between repeated scans (--precision); absolute trajectory error (--poses with --truth, TUM "
      "files, mm).");
  Options o;
  DeclareOptions(&options, &o);
  if (int code = 0; !options.Parse(argc, argv, &code)) return code;
  try {
    nlohmann::json j;
    Rigid3d initial = Rigid3d::Identity();
    bool have_initial = false;
    if (!o.poses_path.empty() && !o.truth_path.empty())
      if (const Status s = AddTrajectoryError(o, &j, &initial, &have_initial); !s.ok())
        return Fail(s);
    if (!o.scan_path.empty() && !o.ref_path.empty())
      if (const Status s = AddTrueness(o, initial, have_initial, &j); !s.ok()) return Fail(s);
    if (o.precision.size() >= 2)
      if (const Status s = AddPrecision(o, &j); !s.ok()) return Fail(s);
    if (j.empty()) {
      std::fprintf(stderr,
                   "d3d-eval: nothing to do: give --scan and --reference, --precision A B ..., or "
                   "--poses and --truth\n");
      return 2;
    }
    std::printf("%s\n", o.json ? j.dump().c_str() : j.dump(2).c_str());
  } catch (const std::exception& e) {
    std::fprintf(stderr, "d3d-eval: %s\n", e.what());
    return 2;
  }
  return 0;
}
