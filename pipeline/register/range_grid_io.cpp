#include "pipeline/register/range_grid_io.h"

#include <cmath>
#include <fstream>
#include <limits>
#include <sstream>
#include <vector>

namespace d3d {

Status ParseRangeGridPly(const std::string& text, double scale, cv::Mat* out) {
  if (!out) return InvalidArgument("range grid: null output");
  try {
    std::istringstream in(text);
    std::string line;
    if (!std::getline(in, line) || line.rfind("ply", 0) != 0)
      return ParseError("range grid: not a PLY file");
    long cols = -1, rows = -1, nv = -1, ng = -1;
    int vprops = 0;
    bool in_vertex = false, ascii = false, header_done = false;
    while (std::getline(in, line)) {
      std::istringstream ls(line);
      std::string w;
      ls >> w;
      if (w == "format") {
        std::string f;
        ls >> f;
        ascii = f == "ascii";
      } else if (w == "obj_info") {
        std::string k;
        long v = 0;
        ls >> k >> v;
        if (k == "num_cols") cols = v;
        if (k == "num_rows") rows = v;
      } else if (w == "element") {
        std::string e;
        long n = -1;
        ls >> e >> n;
        in_vertex = e == "vertex";
        if (e == "vertex") nv = n;
        if (e == "range_grid") ng = n;
      } else if (w == "property" && in_vertex) {
        ++vprops;
      } else if (w == "end_header") {
        header_done = true;
        break;
      }
    }
    if (!header_done) return ParseError("range grid: no end_header");
    if (!ascii) return Unsupported("range grid: only ascii PLY is read");
    if (cols <= 0 || rows <= 0 || cols > 100000 || rows > 100000)
      return ParseError("range grid: missing or bad num_cols/num_rows");
    if (nv < 0 || ng != cols * rows)
      return ParseError("range grid: range_grid count != num_cols · num_rows");
    if (vprops < 3) return ParseError("range grid: vertex needs x y z");
    if (static_cast<double>(nv) > static_cast<double>(text.size()) / 2)
      return ParseError("range grid: vertex count larger than the file");
    std::vector<cv::Vec3f> v(static_cast<size_t>(nv));
    for (long i = 0; i < nv; ++i) {
      if (!std::getline(in, line))
        return ParseError("range grid: truncated vertex list at " + std::to_string(i));
      std::istringstream ls(line);
      double x, y, z;
      if (!(ls >> x >> y >> z)) return ParseError("range grid: bad vertex " + std::to_string(i));
      if (!std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z))
        return Corrupt("range grid: non-finite vertex " + std::to_string(i));
      v[static_cast<size_t>(i)] =
          cv::Vec3f(static_cast<float>(x * scale), static_cast<float>(y * scale),
                    static_cast<float>(z * scale));
    }
    cv::Mat P(static_cast<int>(rows), static_cast<int>(cols), CV_32FC3,
              cv::Scalar::all(std::numeric_limits<float>::quiet_NaN()));
    for (long g = 0; g < ng; ++g) {
      if (!std::getline(in, line))
        return ParseError("range grid: truncated grid at " + std::to_string(g));
      std::istringstream ls(line);
      long k = -1;
      if (!(ls >> k) || k < 0) return ParseError("range grid: bad grid entry " + std::to_string(g));
      if (k == 0) continue;
      long idx = -1;
      if (!(ls >> idx)) return ParseError("range grid: bad grid entry " + std::to_string(g));
      if (idx < 0 || idx >= nv)
        return Corrupt("range grid: index " + std::to_string(idx) + " out of range");
      P.at<cv::Vec3f>(static_cast<int>(g / cols), static_cast<int>(g % cols)) =
          v[static_cast<size_t>(idx)];
    }
    *out = P;
    return Status::Ok();
  } catch (const std::exception& e) {
    return Status(StatusCode::kInternal, std::string("range grid: ") + e.what());
  }
}

Status LoadRangeGridPly(const std::string& path, double scale, cv::Mat* out) {
  std::ifstream f(path, std::ios::binary);
  if (!f) return NotFound("range grid: cannot open '" + path + "'");
  std::ostringstream ss;
  ss << f.rdbuf();
  if (!f.good() && !f.eof()) return IoError("range grid: cannot read '" + path + "'");
  return ParseRangeGridPly(ss.str(), scale, out);
}

Status LoadRangeScanPoses(const std::string& conf_path,
                          std::map<std::string, Rigid3d>* world_from_scan) {
  std::ifstream f(conf_path);
  if (!f) return NotFound("cannot read '" + conf_path + "'");
  world_from_scan->clear();
  std::string line;
  while (std::getline(f, line)) {
    std::istringstream is(line);
    std::string w, name;
    double tx, ty, tz, qx, qy, qz, qw;
    if (!(is >> w) || w != "bmesh" || !(is >> name >> tx >> ty >> tz >> qx >> qy >> qz >> qw))
      continue;
    Rigid3d T = Rigid3d::Identity();
    T.linear() = Eigen::Quaterniond(qw, qx, qy, qz).normalized().toRotationMatrix().transpose();
    T.translation() = Eigen::Vector3d(tx, ty, tz) * 1000.0;  // m → mm
    (*world_from_scan)[name.substr(0, name.find('.'))] = T;
  }
  if (world_from_scan->empty()) return ParseError("no 'bmesh' line in '" + conf_path + "'");
  return Status::Ok();
}

}  // namespace d3d
