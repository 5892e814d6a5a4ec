#include "common/burst/burst_io.h"

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <sstream>

#include "common/core/npy_io.h"

namespace d3d {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
constexpr int kVersion = 1;

json PoseToJson(const Rigid3d& T) {
  const Eigen::Quaterniond q(T.rotation());
  const Eigen::Vector3d t = T.translation();
  return json::array({t.x(), t.y(), t.z(), q.x(), q.y(), q.z(), q.w()});
}

Rigid3d PoseFromJson(const json& j) {
  if (!j.is_array() || j.size() != 7)
    throw std::runtime_error("world_from_probe must be [tx,ty,tz,qx,qy,qz,qw]");
  const Eigen::Quaterniond q(j[6].get<double>(), j[3].get<double>(), j[4].get<double>(),
                             j[5].get<double>());
  return RigidFromQuaternion(
      q, Eigen::Vector3d(j[0].get<double>(), j[1].get<double>(), j[2].get<double>()));
}

Status WriteMat(const fs::path& path, const cv::Mat& m) {
  NpyType type;
  switch (m.depth()) {
    case CV_32F:
      type = NpyType::kFloat32;
      break;
    case CV_32S:
      type = NpyType::kInt32;
      break;
    case CV_8U:
      type = NpyType::kUint8;
      break;
    default:
      return InvalidArgument("truth map of unsupported depth");
  }
  std::vector<int64_t> shape{m.rows, m.cols};
  if (m.channels() > 1) shape.push_back(m.channels());
  const cv::Mat c = m.isContinuous() ? m : m.clone();
  return WriteNpy(path.string(), type, shape, c.data);
}

Status ReadMat(const fs::path& path, int cv_type, int rows, int cols, cv::Mat* out) {
  NpyArray a;
  D3D_RETURN_IF_ERROR(ReadNpy(path.string(), &a));
  const int channels = CV_MAT_CN(cv_type);
  const bool shape_ok = a.shape.size() == (channels > 1 ? 3u : 2u) && a.shape[0] == rows &&
                        a.shape[1] == cols && (channels == 1 || a.shape[2] == channels);
  if (!shape_ok) return InvalidArgument(path.string() + ": shape does not match the frames");
  out->create(rows, cols, cv_type);
  if (a.bytes.size() != out->total() * out->elemSize())
    return InvalidArgument(path.string() + ": wrong element type");
  std::memcpy(out->data, a.bytes.data(), a.bytes.size());
  return Status::Ok();
}

Status WriteTruth(const fs::path& dir, const FrameTruth& t) {
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) return IoError("cannot create '" + dir.string() + "': " + ec.message());
  D3D_RETURN_IF_ERROR(WriteMat(dir / "depth_mm.npy", t.depth_mm));
  D3D_RETURN_IF_ERROR(WriteMat(dir / "points_in_cam.npy", t.points_in_cam));
  D3D_RETURN_IF_ERROR(WriteMat(dir / "projector_uv.npy", t.projector_uv));
  D3D_RETURN_IF_ERROR(WriteMat(dir / "face_index.npy", t.face_index));
  if (!cv::imwrite((dir / "visibility.png").string(), t.visibility) ||
      !cv::imwrite((dir / "label.png").string(), t.label)) {
    return IoError("cannot write truth PNGs in '" + dir.string() + "'");
  }
  return Status::Ok();
}

Status ReadTruth(const fs::path& dir, int rows, int cols, FrameTruth* t) {
  D3D_RETURN_IF_ERROR(ReadMat(dir / "depth_mm.npy", CV_32F, rows, cols, &t->depth_mm));
  D3D_RETURN_IF_ERROR(ReadMat(dir / "points_in_cam.npy", CV_32FC3, rows, cols, &t->points_in_cam));
  D3D_RETURN_IF_ERROR(ReadMat(dir / "projector_uv.npy", CV_32FC2, rows, cols, &t->projector_uv));
  D3D_RETURN_IF_ERROR(ReadMat(dir / "face_index.npy", CV_32S, rows, cols, &t->face_index));
  t->visibility = cv::imread((dir / "visibility.png").string(), cv::IMREAD_UNCHANGED);
  t->label = cv::imread((dir / "label.png").string(), cv::IMREAD_UNCHANGED);
  if (t->visibility.empty() || t->label.empty())
    return NotFound("truth PNGs missing in '" + dir.string() + "'");
  return Status::Ok();
}

}  // namespace

Status WriteBurstDir(const std::string& dir, const Burst& burst,
                     const std::vector<int>& truth_frames) {
  if (burst.frames.empty()) return InvalidArgument("burst has no frames");
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) return IoError("cannot create '" + dir + "': " + ec.message());
  json frames = json::array();
  json truth_list = json::array();
  for (size_t i = 0; i < burst.frames.size(); ++i) {
    const BurstFrame& f = burst.frames[i];
    const std::string file = "frame_" + std::to_string(i) + ".png";
    if (!cv::imwrite((fs::path(dir) / file).string(), f.image))
      return IoError("cannot write " + dir + "/" + file);
    json frame{{"file", file}, {"pattern", f.pattern}, {"timestamp_ns", f.timestamp_ns}};
    if (burst.poses_known) frame["world_from_probe"] = PoseToJson(f.truth.world_from_probe);
    frames.push_back(std::move(frame));
  }
  for (int k : truth_frames) {
    if (k < 0 || k >= static_cast<int>(burst.frames.size()) ||
        !burst.frames[static_cast<size_t>(k)].truth.has_maps())
      continue;
    D3D_RETURN_IF_ERROR(WriteTruth(fs::path(dir) / ("truth_" + std::to_string(k)),
                                   burst.frames[static_cast<size_t>(k)].truth));
    truth_list.push_back(k);
  }
  json j{{"format", "d3dscan.burst"},
         {"version", kVersion},
         {"sequence", burst.sequence},
         {"frames", frames},
         {"truth_frames", truth_list}};
  if (burst.reference_truth.has_maps()) {
    D3D_RETURN_IF_ERROR(WriteTruth(fs::path(dir) / "truth_ref", burst.reference_truth));
    j["reference"] = {{"timestamp_ns", burst.reference_ns},
                      {"world_from_probe", PoseToJson(burst.reference_truth.world_from_probe)}};
  }
  std::ofstream out(fs::path(dir) / "burst.json", std::ios::trunc);
  out << j.dump(2) << "\n";
  if (!out) return IoError("cannot write " + dir + "/burst.json");
  return Status::Ok();
}

Status ReadBurstDir(const std::string& dir, bool read_truth, Burst* out) {
  std::ifstream in(fs::path(dir) / "burst.json");
  if (!in) return NotFound("no burst.json in '" + dir + "'");
  Burst burst;
  std::vector<int> truth_frames;
  try {
    std::stringstream ss;
    ss << in.rdbuf();
    const json j = json::parse(ss.str());
    if (j.value("format", "") != "d3dscan.burst")
      return ParseError(dir + "/burst.json is not a d3dscan.burst document");
    if (j.at("version").get<int>() > kVersion)
      return Unsupported(dir + "/burst.json has a newer format version");
    burst.sequence = j.at("sequence").get<uint64_t>();
    for (const auto& f : j.at("frames")) {
      BurstFrame frame;
      frame.pattern = f.at("pattern").get<std::string>();
      frame.timestamp_ns = f.at("timestamp_ns").get<int64_t>();
      if (read_truth && f.contains("world_from_probe"))
        frame.truth.world_from_probe = PoseFromJson(f.at("world_from_probe"));
      if (!f.contains("world_from_probe")) burst.poses_known = false;
      const std::string file = f.at("file").get<std::string>();
      if (file.find('/') != std::string::npos || file.find("..") != std::string::npos) {
        return ParseError(dir + "/burst.json names a frame outside its folder: '" + file + "'");
      }
      const std::string path = (fs::path(dir) / file).string();
      if (!fs::exists(path)) return NotFound("frame file '" + path + "' is missing");
      frame.image = cv::imread(path, cv::IMREAD_UNCHANGED);
      if (frame.image.empty()) return ParseError("cannot decode '" + path + "'");
      if (frame.image.channels() != 1) return InvalidArgument("'" + path + "' is not a grey image");
      burst.frames.push_back(std::move(frame));
    }
    if (j.contains("truth_frames")) truth_frames = j.at("truth_frames").get<std::vector<int>>();
    if (j.contains("reference")) {
      burst.reference_ns = j.at("reference").at("timestamp_ns").get<int64_t>();
      if (read_truth)
        burst.reference_truth.world_from_probe =
            PoseFromJson(j.at("reference").at("world_from_probe"));
    }
  } catch (const std::exception& e) {
    return ParseError(dir + "/burst.json: " + e.what());
  }
  if (burst.frames.empty()) return InvalidArgument(dir + ": burst has no frames");
  const cv::Mat& first = burst.frames[0].image;
  for (const auto& f : burst.frames) {
    if (f.image.size() != first.size() || f.image.type() != first.type()) {
      return InvalidArgument(dir + ": frames differ in size or type (" +
                             std::to_string(f.image.cols) + "x" + std::to_string(f.image.rows) +
                             " vs " + std::to_string(first.cols) + "x" +
                             std::to_string(first.rows) + ")");
    }
  }
  if (read_truth) {
    if (fs::exists(fs::path(dir) / "truth_ref")) {
      D3D_RETURN_IF_ERROR(
          ReadTruth(fs::path(dir) / "truth_ref", first.rows, first.cols, &burst.reference_truth));
    }
    for (int k : truth_frames) {
      if (k < 0 || k >= static_cast<int>(burst.frames.size()))
        return ParseError(dir + ": truth frame index out of range");
      D3D_RETURN_IF_ERROR(ReadTruth(fs::path(dir) / ("truth_" + std::to_string(k)), first.rows,
                                    first.cols, &burst.frames[static_cast<size_t>(k)].truth));
    }
  }
  *out = std::move(burst);
  return Status::Ok();
}

}  // namespace d3d
