#include "calib/features/target.h"

#include <cmath>
#include <cstdio>
#include <limits>
#include <sstream>

namespace d3d {
namespace {

std::vector<std::string> Split(const std::string& text, char sep) {
  std::vector<std::string> parts;
  std::string cur;
  for (char ch : text) {
    if (ch == sep) {
      parts.push_back(cur);
      cur.clear();
    } else {
      cur.push_back(ch);
    }
  }
  parts.push_back(cur);
  return parts;
}

bool ParseDouble(const std::string& s, double* v) {
  if (s.empty()) return false;
  char* end = nullptr;
  *v = std::strtod(s.c_str(), &end);
  return end && *end == '\0' && std::isfinite(*v);
}

}  // namespace

void CalibrationTarget::Check() const {
  const int min_cols = kind == TargetKind::kAsymmetricCircleGrid ? 2 : 3;
  D3D_CHECK_MSG(cols >= min_cols && rows >= 3,
                "target needs at least " << min_cols << "x3 features, got " << cols << "x" << rows);
  D3D_CHECK_MSG(std::isfinite(spacing_mm) && spacing_mm > 0,
                "target spacing must be positive, got " << spacing_mm);
  D3D_CHECK_MSG(circle_diameter_mm >= 0 && circle_diameter_mm < NearestFeatureDistanceMm(),
                "circle diameter " << circle_diameter_mm << " mm does not fit between circles "
                                   << NearestFeatureDistanceMm() << " mm apart");
  D3D_CHECK_MSG(IsCircles() || circle_diameter_mm == 0, "a chessboard has no circle diameter");
}

std::vector<Eigen::Vector3d> CalibrationTarget::FeaturePoints() const {
  std::vector<Eigen::Vector3d> p;
  p.reserve(static_cast<size_t>(NumFeatures()));
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) {
      const double x =
          kind == TargetKind::kAsymmetricCircleGrid ? (2 * c + r % 2) * spacing_mm : c * spacing_mm;
      p.emplace_back(x, r * spacing_mm, 0.0);
    }
  return p;
}

double CalibrationTarget::NearestFeatureDistanceMm() const {
  return kind == TargetKind::kAsymmetricCircleGrid ? std::sqrt(2.0) * spacing_mm : spacing_mm;
}

std::pair<Eigen::Vector2d, Eigen::Vector2d> CalibrationTarget::FeatureBounds() const {
  Eigen::Vector2d lo = Eigen::Vector2d::Constant(std::numeric_limits<double>::max()), hi = -lo;
  for (const auto& p : FeaturePoints()) {
    lo = lo.cwiseMin(p.head<2>());
    hi = hi.cwiseMax(p.head<2>());
  }
  return {lo, hi};
}

std::string CalibrationTarget::ToString() const {
  std::ostringstream os;
  os << (IsCircles() ? "circles:" : "chessboard:") << cols << "x" << rows << ":" << spacing_mm;
  if (kind == TargetKind::kAsymmetricCircleGrid) os << ":asymmetric";
  if (circle_diameter_mm > 0) os << ":d=" << circle_diameter_mm;
  return os.str();
}

Status ParseTarget(const std::string& text, CalibrationTarget* out) {
  const auto parts = Split(text, ':');
  const std::string usage = "target '" + text +
                            "': expected chessboard:COLSxROWS:SQUARE_MM or "
                            "circles:COLSxROWS:SPACING_MM[:asymmetric][:d=DIAM_MM]";
  if (parts.size() < 3) return InvalidArgument(usage);
  CalibrationTarget t;
  if (parts[0] == "chessboard") {
    t.kind = TargetKind::kChessboard;
    if (parts.size() != 3) return InvalidArgument(usage + " (a chessboard takes no options)");
  } else if (parts[0] == "circles") {
    t.kind = TargetKind::kCircleGrid;
  } else {
    return InvalidArgument(usage + " (unknown kind '" + parts[0] + "')");
  }
  int cols = 0, rows = 0;
  char tail = 0;
  if (std::sscanf(parts[1].c_str(), "%dx%d%c", &cols, &rows, &tail) != 2) {
    return InvalidArgument(usage + " (size '" + parts[1] + "' is not COLSxROWS)");
  }
  t.cols = cols;
  t.rows = rows;
  if (!ParseDouble(parts[2], &t.spacing_mm))
    return InvalidArgument(usage + " (spacing '" + parts[2] + "' is not a number)");
  for (size_t i = 3; i < parts.size(); ++i) {
    if (parts[i] == "asymmetric") {
      t.kind = TargetKind::kAsymmetricCircleGrid;
    } else if (parts[i].rfind("d=", 0) == 0) {
      if (!ParseDouble(parts[i].substr(2), &t.circle_diameter_mm))
        return InvalidArgument(usage + " (bad diameter)");
    } else {
      return InvalidArgument(usage + " (unknown option '" + parts[i] + "')");
    }
  }
  try {
    t.Check();
  } catch (const std::invalid_argument& e) {
    return InvalidArgument("target '" + text + "': " + e.what());
  }
  *out = t;
  return Status::Ok();
}

}  // namespace d3d
