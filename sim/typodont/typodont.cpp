// Procedural upper-arch typodont. See typodont.h for the frame.
//
// Anatomical values (millimetres, before `scale`)
// ------------------------------------------------
// Crown dimensions of the maxillary permanent teeth, after Ash & Nelson, "Wheeler's Dental Anatomy,
// Physiology and Occlusion" (8th/9th ed., table of tooth measurements), rounded as in our brief:
//
//   tooth         FDI  crown h  MD   MD cervix  BL   BL cervix  incl.  angul.  papilla
//   central       11    10.5   8.5    7.0      7.0    6.0      +20     +5      4.0
//   lateral       12     9.0   6.5    5.0      6.0    5.0      +17     +8      3.8
//   canine        13    10.0   7.5    5.5      8.0    7.0       +8     +9      3.5
//   1st premolar  14     8.5   7.0    5.0      9.0    8.0       +3     +3      3.0
//   2nd premolar  15     8.0   6.5    5.0      9.0    8.0       +2     +3      3.0
//   1st molar     16     7.5  10.0    8.0     11.0   10.0       -2     +5      2.8
//   2nd molar     17     7.0   9.0    7.0     11.0   10.0       -4     +5      2.5
//
//   incl.  = labial/buccal crown inclination of the long axis (deg; incisors ~15-25 deg in
//            cephalometric norms, U1 to the occlusal-plane normal), angul. = mesial crown tip (deg,
//            Andrews 1972, "The six keys to normal occlusion"), papilla = height of the interdental
//            papilla above the mid-tooth gingival margin (typically 3-5 mm anteriorly, less
//            posteriorly; cf. Tarnow et al. 1992 on the contact-point-to-crest distance).
//   Heights of contour: buccal/labial in the cervical third, palatal at the cervical third
//   (incisors: cingulum) or middle third (posteriors); contact areas in the incisal/occlusal third
//   (Wheeler). Molars: 4 cusps, mesiopalatal largest, distopalatal smallest (smaller still on 17),
//   oblique ridge MP-DB, rhomboid occlusal outline (acute MB and DP angles).
//   Cusp inclines 35-40 deg (slopes 0.72 molars, 0.85 premolars); fissures 0.4 mm deep, 0.47 mm
//   wide at half depth (Gaussian profile, sigma 0.2 mm) so that 0.15 mm facets resolve them.
//
// Arch form (occlusal arch curve through incisal edges and the central fossae): tangent angle
// phi(s) = 78.5 deg * (1 - exp(-(s / 17.25)^2)) along the arc length s from the midline, fitted so
// that inter-canine width (cusp tips) = 34 mm, inter-first-molar width (mesiobuccal cusp tips)
// = 52 mm and arch depth (labial of 11/21 to the distal of 17/27) = 45 mm, the values of our brief
// and of average adult maxillary arches (e.g. Bishara et al. 1997, "Arch width changes from 6 weeks
// to 45 years of age"). The curve is a smooth tangent-angle (clothoid-like) form: round anteriorly,
// nearly straight and diverging by ~11 deg per side posteriorly. Teeth are placed along it in FDI
// order, each `gap_mm` from its neighbour (exact point-to-triangle distance on the crown meshes).
//
// Gingiva: scalloped margin 1 mm occlusal of the cemento-enamel junction at mid-tooth, papillae
// rising between the teeth (table), free gingiva `gingiva_thickness_mm` wide around the crowns,
// root eminences on the buccal side (canine most prominent), a palatal slope toward the palate.
#include "sim/typodont/typodont.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <limits>
#include <map>
#include <random>
#include <unordered_map>
#include <utility>
#include <vector>

#include "common/core/status.h"
#include "common/mesh/closest_point.h"

namespace d3d {

void TypodontOptions::Check() const {
  D3D_CHECK_MSG(std::isfinite(scale) && scale >= 0.3 && scale <= 3.0,
                "typodont scale must be in [0.3, 3], got " << scale);
  D3D_CHECK_MSG(std::isfinite(gap_mm) && gap_mm >= 0.0 && gap_mm <= 2.0,
                "typodont gap_mm must be in [0, 2] mm, got " << gap_mm);
  D3D_CHECK_MSG(std::isfinite(crown_edge_mm) && crown_edge_mm >= 0.03 && crown_edge_mm <= 1.0,
                "typodont crown_edge_mm must be in [0.03, 1] mm, got " << crown_edge_mm);
  D3D_CHECK_MSG(std::isfinite(gingiva_edge_mm) && gingiva_edge_mm >= 0.05 && gingiva_edge_mm <= 3.0,
                "typodont gingiva_edge_mm must be in [0.05, 3] mm, got " << gingiva_edge_mm);
  D3D_CHECK_MSG(
      std::isfinite(gingiva_thickness_mm) && gingiva_thickness_mm >= 0.4 &&
          gingiva_thickness_mm <= 3.0,
      "typodont gingiva_thickness_mm must be in [0.4, 3] mm, got " << gingiva_thickness_mm);
  D3D_CHECK_MSG(
      std::isfinite(gingiva_top_y_mm) && gingiva_top_y_mm >= 12.0 && gingiva_top_y_mm <= 30.0,
      "typodont gingiva_top_y_mm must be in [12, 30] mm, got " << gingiva_top_y_mm);
  D3D_CHECK_MSG(std::isfinite(palate_width_mm) && palate_width_mm >= 0.5 && palate_width_mm <= 15.0,
                "typodont palate_width_mm must be in [0.5, 15] mm, got " << palate_width_mm);
  D3D_CHECK_MSG(std::isfinite(asymmetry) && asymmetry >= 0.0 && asymmetry <= 3.0,
                "typodont asymmetry must be in [0, 3], got " << asymmetry);
}

namespace {

using Eigen::Matrix3d;
using Eigen::Vector2d;
using Eigen::Vector3d;
using Eigen::Vector3i;

constexpr double kPi = 3.14159265358979323846;
constexpr double kInf = std::numeric_limits<double>::infinity();

double Rad(double deg) { return deg * kPi / 180.0; }
double Clamp01(double t) { return std::clamp(t, 0.0, 1.0); }
double Smoothstep(double t) {
  t = Clamp01(t);
  return t * t * (3.0 - 2.0 * t);
}
// Polynomial smooth minimum (Quilez): exact min when |a - b| >= k.
double SmoothMin(double a, double b, double k) {
  const double h = std::max(k - std::abs(a - b), 0.0) / k;
  return std::min(a, b) - h * h * k * 0.25;
}
double Sq(double x) { return x * x; }

// Portable uniform draw in (-1, 1) from mt19937 (std distributions differ between libraries).
double Symmetric(std::mt19937& rng) {
  return 2.0 * (static_cast<double>(rng()) + 0.5) / 4294967296.0 - 1.0;
}

double DistanceToSegment(const Vector2d& p, const Vector2d& a, const Vector2d& b) {
  const Vector2d ab = b - a;
  const double t = Clamp01((p - a).dot(ab) / std::max(ab.squaredNorm(), 1e-12));
  return (p - (a + t * ab)).norm();
}

// ---------------------------------------------------------------------------------------------
// Monotone piecewise-cubic (Fritsch-Carlson) profile with flat ends: half-widths versus height.

struct Knot {
  double t;      // height as a fraction of the crown height
  double value;  // mm
};

class Profile {
 public:
  Profile() = default;
  Profile(std::vector<Knot> knots, double t_scale, double v_scale) {
    for (const Knot& k : knots) {
      t_.push_back(k.t * t_scale);
      v_.push_back(k.value * v_scale);
    }
    const size_t n = t_.size();
    m_.assign(n, 0.0);
    for (size_t i = 1; i + 1 < n; ++i) {
      const double d0 = (v_[i] - v_[i - 1]) / (t_[i] - t_[i - 1]);
      const double d1 = (v_[i + 1] - v_[i]) / (t_[i + 1] - t_[i]);
      if (d0 * d1 > 0) m_[i] = 2.0 / (1.0 / d0 + 1.0 / d1);  // harmonic mean; 0 at extrema
    }
  }
  double operator()(double t) const {
    if (t <= t_.front()) return v_.front();
    if (t >= t_.back()) return v_.back();
    size_t i = 1;
    while (t > t_[i]) ++i;
    const double h = t_[i] - t_[i - 1];
    const double x = (t - t_[i - 1]) / h;
    const double x2 = x * x, x3 = x2 * x;
    return (2 * x3 - 3 * x2 + 1) * v_[i - 1] + (x3 - 2 * x2 + x) * h * m_[i - 1] +
           (-2 * x3 + 3 * x2) * v_[i] + (x3 - x2) * h * m_[i];
  }

 private:
  std::vector<double> t_, v_, m_;
};

// ---------------------------------------------------------------------------------------------
// Anatomy tables (see the header comment for sources).

enum class ToothKind { kIncisor, kCanine, kPremolar, kMolar };

struct CuspSpec {
  double u, v;  // tip, as fractions of the half-widths at the shoulder (u > 0 distal, v > 0 buccal)
  double drop;  // mm below the crown height
  double ru, rv;  // footprint stretch (1 = standard cone)
};
struct RidgeSpec {
  Vector2d a, b;  // ends, fractions of the half-widths
  double drop;    // mm below the crown height
};

struct ToothSpec {
  ToothKind kind = ToothKind::kIncisor;
  double height = 10;                                 // crown height, CEJ to tip
  double md = 8, bl = 7;                              // for the record and tests
  std::vector<Knot> mesial, distal, buccal, palatal;  // half-widths (t = w / height, mm)
  double shoulder = 0.9;                   // start of the occlusal cap, fraction of the height
  double cap_top = 1.0;                    // apex of the blank cap above the crown height (mm)
  double cap_power = 2.0;                  // flatness of the cap blank
  double exponent = 2.3;                   // superellipse exponent of the cross-sections
  double skew = 0.0;                       // rhomboid shear: u += skew * v
  double palatal_taper = 0.0;              // MD narrowing toward the palatal side (cingulum)
  double inclination = 0, angulation = 0;  // deg
  double tip_y = 0;                        // y of the crown tip (occlusal plane = 0)
  double papilla = 3;                      // mm
  double eminence = 0.5;                   // buccal root eminence (mm)
  double fossa_depth = 0;                  // palatal fossa (incisors, canine)
  std::vector<double> fossa_centers;       // fractions of the MD half-width
  double fossa_width = 0.5;
  std::vector<CuspSpec> cusps;
  std::vector<RidgeSpec> ridges;
  std::vector<std::vector<Vector2d>> grooves;  // polylines, fractions of the half-widths
  double cusp_slope = 0.62;
  double canine_slope_mesial = 0.62, canine_slope_distal = 0.85;
  double buccal_groove_u = 0;   // molars: buccal groove on the buccal face (fraction)
  double palatal_groove_u = 0;  // molars: palatal groove on the palatal face (fraction)
};

// position: 1 central incisor ... 7 second molar.
ToothSpec SpecFor(int position) {
  ToothSpec s;
  switch (position) {
    case 1:
      s.kind = ToothKind::kIncisor;
      s.height = 10.5, s.md = 8.5, s.bl = 7.0;
      s.mesial = {{-0.15, 3.3}, {0, 3.5}, {0.75, 4.25}, {0.93, 4.25}};
      s.distal = {{-0.15, 3.3}, {0, 3.5}, {0.68, 4.25}, {0.93, 3.85}};
      s.buccal = {{-0.15, 2.85}, {0, 3.0}, {0.2, 3.3}, {0.6, 2.45}, {0.93, 0.6}};
      s.palatal = {{-0.15, 2.85}, {0, 3.0}, {0.22, 3.7}, {0.5, 2.3}, {0.93, 0.5}};
      s.shoulder = 0.93, s.cap_top = 1.0, s.cap_power = 2.0, s.exponent = 2.3;
      s.inclination = 20, s.angulation = 5, s.tip_y = 0.0, s.papilla = 4.0, s.eminence = 0.3;
      s.fossa_depth = 0.55, s.fossa_centers = {0.0}, s.fossa_width = 0.55, s.palatal_taper = 0.3;
      break;
    case 2:
      s.kind = ToothKind::kIncisor;
      s.height = 9.0, s.md = 6.5, s.bl = 6.0;
      s.mesial = {{-0.15, 2.35}, {0, 2.5}, {0.75, 3.25}, {0.92, 3.2}};
      s.distal = {{-0.15, 2.35}, {0, 2.5}, {0.62, 3.25}, {0.92, 2.75}};
      s.buccal = {{-0.15, 2.4}, {0, 2.5}, {0.2, 2.8}, {0.6, 2.0}, {0.92, 0.55}};
      s.palatal = {{-0.15, 2.4}, {0, 2.5}, {0.22, 3.2}, {0.5, 1.95}, {0.92, 0.45}};
      s.shoulder = 0.92, s.cap_top = 1.0, s.cap_power = 2.0, s.exponent = 2.3;
      s.inclination = 17, s.angulation = 8, s.tip_y = 0.7, s.papilla = 3.8, s.eminence = 0.25;
      s.fossa_depth = 0.6, s.fossa_centers = {0.0}, s.fossa_width = 0.55, s.palatal_taper = 0.3;
      break;
    case 3:
      s.kind = ToothKind::kCanine;
      s.height = 10.0, s.md = 7.5, s.bl = 8.0;
      s.mesial = {{-0.15, 2.6}, {0, 2.75}, {0.6, 3.75}};
      s.distal = {{-0.15, 2.6}, {0, 2.75}, {0.6, 3.75}};
      s.buccal = {{-0.15, 3.35}, {0, 3.5}, {0.25, 4.1}, {0.6, 3.3}};
      s.palatal = {{-0.15, 3.35}, {0, 3.5}, {0.25, 3.9}, {0.6, 2.6}};
      s.shoulder = 0.6, s.cap_top = 0.6, s.cap_power = 2.0, s.exponent = 2.2;
      s.inclination = 8, s.angulation = 9, s.tip_y = 0.0, s.papilla = 3.5, s.eminence = 0.7;
      s.fossa_depth = 0.3, s.fossa_centers = {-0.42, 0.42}, s.fossa_width = 0.22,
      s.palatal_taper = 0.25;
      s.cusps = {{-0.05, 0.12, 0.0, 1.0, 1.0}};
      break;
    case 4:
    case 5: {
      const bool first = position == 4;
      s.kind = ToothKind::kPremolar;
      s.height = first ? 8.5 : 8.0, s.md = first ? 7.0 : 6.5, s.bl = 9.0;
      const double a = s.md / 2;
      s.mesial = {{-0.15, 2.35}, {0, 2.5}, {0.68, a}};
      s.distal = {{-0.15, 2.35}, {0, 2.5}, {0.68, a}};
      s.buccal = {{-0.15, 3.85}, {0, 4.0}, {0.3, 4.55}, {0.68, 4.05}};
      s.palatal = {{-0.15, 3.85}, {0, 4.0}, {0.45, 4.45}, {0.68, 4.0}};
      s.shoulder = 0.68, s.cap_top = 1.0, s.cap_power = 3.0, s.exponent = 2.4;
      s.inclination = first ? 3 : 2, s.angulation = 3, s.tip_y = first ? 0.2 : 0.3;
      s.papilla = 3.0, s.eminence = 0.3;
      s.cusps = {{first ? 0.06 : 0.0, 0.46, 0.0, 1.8, 1.0},
                 {-0.04, -0.46, first ? 0.8 : 0.3, 1.6, 1.0}};
      s.ridges = {{{-0.84, -0.45}, {-0.84, 0.45}, 1.7}, {{0.84, -0.45}, {0.84, 0.45}, 1.8}};
      s.grooves = {{{-0.64, 0.0}, {-0.2, 0.02}, {0.2, 0.02}, {0.64, 0.0}}};
      s.cusp_slope = 0.85, s.palatal_taper = 0.1;
      break;
    }
    default: {
      const bool first = position == 6;
      s.kind = ToothKind::kMolar;
      s.height = first ? 7.5 : 7.0, s.md = first ? 10.0 : 9.0, s.bl = 11.0;
      const double a = s.md / 2, ac = first ? 4.0 : 3.5;
      s.mesial = {{-0.15, ac - 0.15}, {0, ac}, {0.63, a}};
      s.distal = {{-0.15, ac - 0.15}, {0, ac}, {0.63, a}};
      s.buccal = {{-0.15, 4.85}, {0, 5.0}, {0.3, 5.4}, {0.63, 5.05}};
      s.palatal = {{-0.15, 4.85}, {0, 5.0}, {0.45, 5.6}, {0.63, 5.3}};
      s.shoulder = 0.63, s.cap_top = 1.0, s.cap_power = 3.0, s.exponent = 2.8, s.skew = -0.12;
      s.inclination = first ? -2 : -4, s.angulation = 5, s.tip_y = first ? 0.3 : 0.8;
      s.papilla = first ? 2.8 : 2.5, s.eminence = 0.25;
      s.cusps = {{-0.45, 0.50, 0.0, 1.0, 1.0},
                 {0.45, 0.52, 0.35, 0.95, 0.95},
                 {-0.22, -0.45, 0.15, 1.2, 1.2},
                 {0.55, -0.55, first ? 1.0 : 1.4, first ? 0.75 : 0.6, first ? 0.75 : 0.6}};
      s.ridges = {{{-0.22, -0.45}, {0.45, 0.52}, 1.3},           // oblique ridge MP-DB
                  {{-0.84, -0.55}, {-0.84, 0.55}, 1.5},          // mesial marginal ridge
                  {{0.84, -0.45}, {0.84, 0.55}, 1.7}};           // distal marginal ridge
      s.grooves = {{{-0.72, 0.0}, {-0.1, 0.05}},                 // central
                   {{-0.1, 0.05}, {0.02, 1.3}},                  // buccal
                   {{0.72, 0.1}, {0.32, -0.12}, {0.14, -1.3}}};  // distal / distopalatal
      s.cusp_slope = 0.72;
      s.buccal_groove_u = 0.02, s.palatal_groove_u = 0.14;
      break;
    }
  }
  return s;
}

// Seeded per-tooth deviations from the table.
struct Jitter {
  double rotation = 0, tip = 0, torque = 0;  // deg
  double dy = 0;                             // mm
  double md = 1, bl = 1, height = 1;         // factors
};

Jitter DrawJitter(std::mt19937& rng, double amount) {
  Jitter j;
  j.rotation = 2.0 * amount * Symmetric(rng);
  j.tip = 2.0 * amount * Symmetric(rng);
  j.torque = 2.0 * amount * Symmetric(rng);
  j.dy = 0.15 * amount * Symmetric(rng);
  j.md = 1.0 + 0.02 * amount * Symmetric(rng);
  j.bl = 1.0 + 0.02 * amount * Symmetric(rng);
  j.height = 1.0 + 0.02 * amount * Symmetric(rng);
  return j;
}

// ---------------------------------------------------------------------------------------------
// Occlusal arch curve in the xz plane, by arc length; negative s is the mirror (patient's right).

class ArchCurve {
 public:
  explicit ArchCurve(double scale) : scale_(scale) {
    const double length = 90.0 * scale;
    const int n = static_cast<int>(std::ceil(length / kStep)) + 2;
    x_.resize(n), z_.resize(n);
    double x = 0, z = 0;
    x_[0] = 0, z_[0] = 0;
    for (int i = 1; i < n; ++i) {  // midpoint rule: phi is smooth
      const double phi = Phi((i - 0.5) * kStep);
      x += std::cos(phi) * kStep;
      z -= std::sin(phi) * kStep;
      x_[i] = x, z_[i] = z;
    }
  }
  // Tangent angle of the left half (s >= 0), from +x toward -z.
  double Phi(double s) const {
    return kPhiMax * (1.0 - std::exp(-std::pow(s / (kS0 * scale_), kP)));
  }
  double SignedPhi(double s) const { return s >= 0 ? Phi(s) : -Phi(-s); }
  double Curvature(double s) const {
    const double a = std::abs(s) / (kS0 * scale_);
    if (a <= 0) return 0;
    return kPhiMax * kP / (kS0 * scale_) * std::pow(a, kP - 1) * std::exp(-std::pow(a, kP));
  }
  Vector2d Point(double s) const {  // (x, z)
    const double a = std::abs(s) / kStep;
    const int i = std::min(static_cast<int>(a), static_cast<int>(x_.size()) - 2);
    const double f = a - i;
    const double x = x_[i] + f * (x_[i + 1] - x_[i]);
    const double z = z_[i] + f * (z_[i + 1] - z_[i]);
    return {s >= 0 ? x : -x, z};
  }
  Vector2d Tangent(double s) const {
    const double p = SignedPhi(s);
    return {std::cos(p), -std::sin(p)};
  }
  Vector2d Normal(double s) const {  // buccal (outward)
    const double p = SignedPhi(s);
    return {std::sin(p), std::cos(p)};
  }
  // Closest point on the curve to (x, z), Newton from a guess: returns (s, n).
  Vector2d Project(const Vector2d& p, double s) const {
    for (int it = 0; it < 6; ++it) {
      const Vector2d d = p - Point(s);
      const double n = d.dot(Normal(s));
      const double step = d.dot(Tangent(s)) / std::max(0.2, 1.0 + Curvature(s) * n);
      s += step;
      if (std::abs(step) < 1e-7) break;
    }
    return {s, (p - Point(s)).dot(Normal(s))};
  }

 private:
  static constexpr double kStep = 0.02;
  static constexpr double kPhiMax = 78.5 * kPi / 180.0;
  static constexpr double kS0 = 17.25;
  static constexpr double kP = 2.0;
  double scale_;
  std::vector<double> x_, z_;
};

// ---------------------------------------------------------------------------------------------
// One crown in its local frame: u distal, v buccal, w occlusal (crown direction), origin at the
// centre of the cervical line; the crown tip is at w = height.

struct LocalCrown {
  std::vector<Vector3d> vertices;
  std::vector<Vector3i> faces;
  std::vector<Vector3d> normals;  // area-weighted
  std::vector<Vector3d> cusp_tips;
  double height = 0;
  double half_md = 0;
};

struct HalfWidths {
  double mesial, distal, buccal, palatal;
};

class CrownShape {
 public:
  CrownShape(const ToothSpec& spec, const Jitter& jitter, double scale)
      : spec_(spec),
        height_(spec.height * scale * jitter.height),
        mesial_(spec.mesial, height_, scale * jitter.md),
        distal_(spec.distal, height_, scale * jitter.md),
        buccal_(spec.buccal, height_, scale * jitter.bl),
        palatal_(spec.palatal, height_, scale * jitter.bl),
        scale_(scale) {
    shoulder_ = spec.shoulder * height_;
    cap_top_ = height_ + spec.cap_top * scale;
    cap_widths_ = Widths(shoulder_);
    a_ref_ = 0.5 * (cap_widths_.mesial + cap_widths_.distal);
    for (const CuspSpec& c : spec.cusps) {
      const double v = c.v * (c.v >= 0 ? cap_widths_.buccal : cap_widths_.palatal);
      cusps_.push_back({c.u * a_ref_ + spec.skew * v, v, height_ - c.drop * scale, c.ru, c.rv});
    }
    for (const RidgeSpec& r : spec.ridges)
      ridges_.push_back({ToLocal(r.a), ToLocal(r.b), r.drop * scale});
    for (const auto& g : spec.grooves) {
      std::vector<Vector2d> pts;
      for (const Vector2d& p : g) pts.push_back(ToLocal(p));
      grooves_.push_back(pts);
    }
  }

  double height() const { return height_; }
  double shoulder() const { return shoulder_; }
  double a_ref() const { return a_ref_; }
  const std::vector<CuspSpec>& cusps() const { return cusps_; }

  HalfWidths Widths(double w) const { return {mesial_(w), distal_(w), buccal_(w), palatal_(w)}; }

  // Horizontal cross-section at height w, superellipse parameter phi (0 = distal, pi/2 = buccal).
  Vector2d Outline(double phi, const HalfWidths& hw, double w) const {
    const double c = std::cos(phi), s = std::sin(phi);
    const double e = 2.0 / spec_.exponent;
    const double pu = std::copysign(std::pow(std::abs(c), e), c);
    const double pv = std::copysign(std::pow(std::abs(s), e), s);
    const double taper = pv < 0 ? 1.0 - spec_.palatal_taper * pv * pv : 1.0;
    const double u = taper * pu * (pu >= 0 ? hw.distal : hw.mesial);
    double v = pv * (pv >= 0 ? hw.buccal : hw.palatal);
    v += SideDetail(u, pv, hw, w);
    return {u + spec_.skew * v, v};
  }

  // Blank cap: parameter beta in [0, pi/2] -> (rho, w).
  double CapRho(double beta) const {
    return std::pow(std::max(std::cos(beta), 0.0), 2.0 / spec_.cap_power);
  }
  double CapW(double beta) const { return shoulder_ + (cap_top_ - shoulder_) * std::sin(beta); }

  // Occlusal surface height w = F(u, v) (used where it lies below the blank cap).
  double Occlusal(double u, double v) const {
    switch (spec_.kind) {
      case ToothKind::kIncisor:
        return height_ - 0.012 * u * u / scale_;
      case ToothKind::kCanine: {
        const CuspSpec& c = cusps_.front();
        const double du = u - c.u, dv = v - c.v;
        const double ku = du < 0 ? spec_.canine_slope_mesial : spec_.canine_slope_distal;
        const double eps = 0.5 * scale_;
        return height_ + eps - std::sqrt(eps * eps + Sq(ku * du) + Sq(0.3 * dv));
      }
      default:
        return PosteriorOcclusal(u, v);
    }
  }

  // The occlusal field is kept above the shoulder (so the cap never folds below the side wall)
  // and blended under the blank cap, which rounds the crown over its height of contour.
  double Surface(double beta, double u, double v) const {
    const double floor = shoulder_ + 0.5 * scale_;
    const double occlusal = -SmoothMin(-Occlusal(u, v), -floor, 0.3 * scale_);
    return SmoothMin(CapW(beta), occlusal, 0.4 * scale_);
  }

 private:
  Vector2d ToLocal(const Vector2d& p) const {
    const double v = p.y() * (p.y() >= 0 ? cap_widths_.buccal : cap_widths_.palatal);
    return {p.x() * a_ref_ + spec_.skew * v, v};
  }

  // Features of the side walls as offsets along v: palatal fossa with marginal ridges (incisors,
  // canine), labial developmental depressions (incisors), buccal/palatal grooves (molars).
  double SideDetail(double u, double pv, const HalfWidths& hw, double w) const {
    const double t = w / height_;
    const double a = 0.5 * (hw.mesial + hw.distal);
    const double x = u / a;
    double dv = 0;
    if (pv < 0 && spec_.fossa_depth > 0) {
      double g = 0;
      for (double c : spec_.fossa_centers) g += std::exp(-Sq(Sq((x - c) / spec_.fossa_width)));
      const double band = Smoothstep((t - 0.3) / 0.15) * (1.0 - Smoothstep((t - 0.8) / 0.12));
      const double depth = std::min(spec_.fossa_depth * scale_, 0.6 * hw.palatal);
      dv += depth * g * band * pv * pv;
    }
    if (pv > 0 && spec_.kind == ToothKind::kIncisor) {
      const double g = std::exp(-Sq((x - 0.36) / 0.13)) + std::exp(-Sq((x + 0.36) / 0.13));
      const double band = Smoothstep((t - 0.4) / 0.2) * (1.0 - Smoothstep((t - 0.85) / 0.08));
      dv -= 0.12 * scale_ * g * band * pv * pv;
    }
    if (spec_.kind == ToothKind::kMolar) {
      const double band = Smoothstep((t - 0.4) / 0.3);
      if (pv > 0)
        dv -= 0.3 * scale_ * std::exp(-Sq((x - spec_.buccal_groove_u) / 0.07)) * band * Sq(Sq(pv));
      if (pv < 0)
        dv +=
            0.25 * scale_ * std::exp(-Sq((x - spec_.palatal_groove_u) / 0.08)) * band * Sq(Sq(pv));
    }
    return dv;
  }

  double PosteriorOcclusal(double u, double v) const {
    const double eps = 0.4 * scale_, tau = 0.12 * scale_;
    std::array<double, 8> f{};
    size_t n = 0;
    const double slope = spec_.cusp_slope;
    for (const CuspSpec& c : cusps_) {
      const double du = (u - c.u) / c.ru, dv = (v - c.v) / c.rv;
      f[n++] = c.drop - slope * (std::sqrt(eps * eps + du * du + dv * dv) - eps);  // c.drop = tip w
    }
    const Vector2d p(u, v);
    for (const Ridge& r : ridges_) {
      const double d = DistanceToSegment(p, r.a, r.b);
      f[n++] = height_ - r.drop - 0.9 * (std::sqrt(eps * eps + d * d) - eps);
    }
    double m = -kInf;
    for (size_t i = 0; i < n; ++i) m = std::max(m, f[i]);
    double sum = 0;
    for (size_t i = 0; i < n; ++i) sum += std::exp((f[i] - m) / tau);
    double h = m + tau * std::log(sum);
    const double sigma = 0.2 * scale_, depth = 0.4 * scale_;
    for (const auto& g : grooves_) {
      double d = kInf;
      for (size_t i = 0; i + 1 < g.size(); ++i)
        d = std::min(d, DistanceToSegment(p, g[i], g[i + 1]));
      h -= depth * std::exp(-0.5 * Sq(d / sigma));
    }
    return h;
  }

  struct Ridge {
    Vector2d a, b;
    double drop;
  };

  ToothSpec spec_;
  double height_;
  Profile mesial_, distal_, buccal_, palatal_;
  double scale_;
  double shoulder_ = 0, cap_top_ = 0, a_ref_ = 0;
  HalfWidths cap_widths_{};
  std::vector<CuspSpec> cusps_;  // u, v in mm; drop holds the tip height w
  std::vector<Ridge> ridges_;
  std::vector<std::vector<Vector2d>> grooves_;
};

// Arc-length table of a closed ring of points: maps arc length to the superellipse parameter.
struct OutlineTable {
  std::vector<double> phi, arc;
  double length = 0;
  double PhiAt(double a) const {
    const auto it = std::upper_bound(arc.begin(), arc.end(), a);
    const size_t i = std::clamp<size_t>(static_cast<size_t>(it - arc.begin()), 1, arc.size() - 1);
    const double f = (a - arc[i - 1]) / std::max(arc[i] - arc[i - 1], 1e-15);
    return phi[i - 1] + f * (phi[i] - phi[i - 1]);
  }
};

template <typename F>
OutlineTable MakeOutlineTable(F&& outline) {
  constexpr int kSamples = 384;
  OutlineTable t;
  t.phi.resize(kSamples + 1), t.arc.resize(kSamples + 1);
  Vector3d prev = outline(0.0);
  t.phi[0] = 0, t.arc[0] = 0;
  for (int i = 1; i <= kSamples; ++i) {
    const double phi = 2.0 * kPi * i / kSamples;
    const Vector3d p = outline(phi);
    t.phi[i] = phi;
    t.arc[i] = t.arc[i - 1] + (p - prev).norm();
    prev = p;
  }
  t.length = t.arc.back();
  return t;
}

// Connects ring a (lower / outer) to ring b (upper / inner) by matching their parameters.
void Zip(const std::vector<double>& pa, int a0, const std::vector<double>& pb, int b0,
         std::vector<Vector3i>& faces) {
  const int na = static_cast<int>(pa.size()), nb = static_cast<int>(pb.size());
  auto param = [](const std::vector<double>& p, int i) {
    return i < static_cast<int>(p.size()) ? p[i] : 2.0 * kPi + p[0];
  };
  int i = 0, j = 0;
  while (i < na || j < nb) {
    const bool advance_a = j >= nb || (i < na && param(pa, i + 1) < param(pb, j + 1));
    if (advance_a) {
      faces.emplace_back(a0 + i % na, a0 + (i + 1) % na, b0 + j % nb);
      ++i;
    } else {
      faces.emplace_back(a0 + i % na, b0 + (j + 1) % nb, b0 + j % nb);
      ++j;
    }
  }
}

std::vector<Vector3d> AreaWeightedNormals(const std::vector<Vector3d>& v,
                                          const std::vector<Vector3i>& f) {
  std::vector<Vector3d> n(v.size(), Vector3d::Zero());
  for (const Vector3i& t : f) {
    const Vector3d c = (v[t[1]] - v[t[0]]).cross(v[t[2]] - v[t[0]]);
    for (int k = 0; k < 3; ++k) n[t[k]] += c;
  }
  for (Vector3d& x : n) {
    const double len = x.norm();
    x = len > 0 ? Vector3d(x / len) : Vector3d(0, -1, 0);
  }
  return n;
}

LocalCrown BuildCrown(const CrownShape& shape, double edge, double scale) {
  LocalCrown crown;
  crown.height = shape.height();
  crown.half_md = shape.a_ref();
  const double ring_spacing = 0.85 * edge;  // along rings
  std::vector<std::vector<double>> ring_params;
  std::vector<int> ring_first;

  // A ring of vertices evenly spaced (in 3-D) along `point(phi)`.
  auto add_ring = [&](auto&& point) {
    const OutlineTable table = MakeOutlineTable(point);
    const int n = std::max(3, static_cast<int>(std::ceil(table.length / ring_spacing)));
    std::vector<double> params(n);
    ring_first.push_back(static_cast<int>(crown.vertices.size()));
    for (int k = 0; k < n; ++k) {
      params[k] = table.PhiAt(table.length * k / n);
      crown.vertices.push_back(point(params[k]));
    }
    ring_params.push_back(std::move(params));
  };

  // Side wall: rings of constant height from below the cervical line up to the shoulder.
  const double w_bottom = -1.6 * scale;
  const int wall_rings =
      std::max(2, static_cast<int>(std::ceil((shape.shoulder() - w_bottom) / (0.9 * edge))) + 1);
  for (int r = 0; r < wall_rings; ++r) {
    const double w = w_bottom + (shape.shoulder() - w_bottom) * r / (wall_rings - 1);
    const HalfWidths hw = shape.Widths(w);
    add_ring([&](double phi) {
      const Vector2d p = shape.Outline(phi, hw, w);
      return Vector3d(p.x(), p.y(), w);
    });
  }

  // Occlusal cap: the shoulder outline scaled by rho(beta), height min(blank cap, occlusal field).
  const HalfWidths cap_hw = shape.Widths(shape.shoulder());
  auto cap_outline = [&](double phi) { return shape.Outline(phi, cap_hw, shape.shoulder()); };
  auto cap_point = [&](double phi, double beta) {
    const Vector2d p = shape.CapRho(beta) * cap_outline(phi);
    return Vector3d(p.x(), p.y(), shape.Surface(beta, p.x(), p.y()));
  };
  // Ring heights from the longest meridian increments over a few directions.
  constexpr int kBeta = 320, kDirections = 96;
  std::vector<double> arc(kBeta + 1, 0.0);
  {
    std::vector<Vector3d> prev(kDirections);
    for (int d = 0; d < kDirections; ++d) prev[d] = cap_point(2 * kPi * d / kDirections, 0.0);
    for (int i = 1; i <= kBeta; ++i) {
      const double beta = 0.5 * kPi * i / kBeta;
      double step = 0;
      for (int d = 0; d < kDirections; ++d) {
        const Vector3d p = cap_point(2 * kPi * d / kDirections, beta);
        step = std::max(step, (p - prev[d]).norm());
        prev[d] = p;
      }
      arc[i] = arc[i - 1] + step;
    }
  }
  const int cap_rings = std::max(2, static_cast<int>(std::ceil(arc.back() / (0.8 * edge))));
  for (int r = 1; r < cap_rings; ++r) {
    const double target = arc.back() * r / cap_rings;
    const size_t i =
        static_cast<size_t>(std::upper_bound(arc.begin(), arc.end(), target) - arc.begin());
    const size_t k = std::clamp<size_t>(i, 1, kBeta);
    const double f = (target - arc[k - 1]) / std::max(arc[k] - arc[k - 1], 1e-15);
    const double beta = 0.5 * kPi * (k - 1 + f) / kBeta;
    add_ring([&](double phi) { return cap_point(phi, beta); });
  }
  for (size_t r = 0; r + 1 < ring_params.size(); ++r) {
    Zip(ring_params[r], ring_first[r], ring_params[r + 1], ring_first[r + 1], crown.faces);
  }
  // Pole.
  const int pole = static_cast<int>(crown.vertices.size());
  crown.vertices.push_back(cap_point(0.0, 0.5 * kPi));
  const auto& last = ring_params.back();
  const int n_last = static_cast<int>(last.size());
  for (int k = 0; k < n_last; ++k) {
    crown.faces.emplace_back(ring_first.back() + k, ring_first.back() + (k + 1) % n_last, pole);
  }
  crown.normals = AreaWeightedNormals(crown.vertices, crown.faces);

  // Cusp tips: the highest vertex near each designed tip.
  const int cap_first = ring_first[wall_rings];
  for (const CuspSpec& c : shape.cusps()) {
    int best = -1;
    for (int i = cap_first; i < static_cast<int>(crown.vertices.size()); ++i) {
      const Vector3d& p = crown.vertices[i];
      if (Sq(p.x() - c.u) + Sq(p.y() - c.v) > Sq(1.2 * scale)) continue;
      if (best < 0 || p.z() > crown.vertices[best].z()) best = i;
    }
    if (best >= 0) crown.cusp_tips.push_back(crown.vertices[best]);
  }
  return crown;
}

// ---------------------------------------------------------------------------------------------
// Placement along the arch (left-side coordinates; the right side is mirrored afterwards).

struct Pose {
  Matrix3d rotation;     // columns: local u, v, w in global coordinates
  Vector3d translation;  // global = rotation * local + translation
  Vector3d Apply(const Vector3d& p) const { return rotation * p + translation; }
};

struct ToothPlacement {
  ToothSpec spec;
  Jitter jitter;
  double s = 0;
  double tip_y = 0;
  Pose pose;
};

Pose MakePose(const ArchCurve& arch, const ToothPlacement& t, double height) {
  const double phi = arch.Phi(t.s);
  const Vector3d tangent(std::cos(phi), 0, -std::sin(phi));
  const Vector3d normal(std::sin(phi), 0, std::cos(phi));
  const Vector3d occlusal(0, -1, 0);
  const double alpha = Rad(t.spec.inclination + t.jitter.torque);
  const double gamma = Rad(t.spec.angulation + t.jitter.tip);
  const double theta = Rad(t.jitter.rotation);
  // Labial crown inclination: the occlusal axis leans buccally.
  Vector3d w = std::cos(alpha) * occlusal + std::sin(alpha) * normal;
  Vector3d v = std::cos(alpha) * normal - std::sin(alpha) * occlusal;
  Vector3d u = tangent;
  // Mesial crown tip: the occlusal axis leans toward mesial (-u).
  const Vector3d w2 = std::cos(gamma) * w - std::sin(gamma) * u;
  u = std::cos(gamma) * u + std::sin(gamma) * w;
  w = w2;
  // Rotation about the long axis.
  const Vector3d u3 = std::cos(theta) * u + std::sin(theta) * v;
  v = -std::sin(theta) * u + std::cos(theta) * v;
  u = u3;
  Pose pose;
  pose.rotation.col(0) = u, pose.rotation.col(1) = v, pose.rotation.col(2) = w;
  const Vector2d c = arch.Point(t.s);
  const Vector3d anchor(c.x(), t.tip_y, c.y());
  pose.translation = anchor - pose.rotation * Vector3d(0, 0, height);
  return pose;
}

// One proximal side of a crown (above the cervical line) in global coordinates, with the faces
// around each vertex for exact point-to-triangle distances.
struct Proximal {
  std::vector<Vector3d> points;
  std::vector<Vector3i> faces;                 // indices into points
  std::vector<std::vector<int>> vertex_faces;  // faces around each point
};

Proximal ProximalSide(const LocalCrown& crown, const Pose& pose, bool distal) {
  Proximal p;
  const double limit = 0.25 * crown.half_md;
  std::vector<int> index(crown.vertices.size(), -1);
  for (size_t i = 0; i < crown.vertices.size(); ++i) {
    const Vector3d& v = crown.vertices[i];
    if (v.z() < 0.0) continue;
    if (distal ? v.x() < limit : v.x() > -limit) continue;
    index[i] = static_cast<int>(p.points.size());
    p.points.push_back(pose.Apply(v));
  }
  p.vertex_faces.resize(p.points.size());
  for (const Vector3i& f : crown.faces) {
    if (index[f[0]] < 0 || index[f[1]] < 0 || index[f[2]] < 0) continue;
    const int id = static_cast<int>(p.faces.size());
    p.faces.emplace_back(index[f[0]], index[f[1]], index[f[2]]);
    for (int k = 0; k < 3; ++k) p.vertex_faces[index[f[k]]].push_back(id);
  }
  return p;
}

// Spatial hash of points for nearest-neighbour queries within one cell.
class PointGrid {
 public:
  PointGrid(const std::vector<Vector3d>& points, double cell) : points_(points), cell_(cell) {
    for (size_t i = 0; i < points.size(); ++i)
      cells_[Key(Cell(points[i]))].push_back(static_cast<int>(i));
  }
  // Index of the nearest point within about one cell, or -1.
  int Nearest(const Vector3d& q) const {
    const Eigen::Vector3i c = Cell(q);
    int best = -1;
    double best_d = kInf;
    for (int dx = -1; dx <= 1; ++dx)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dz = -1; dz <= 1; ++dz) {
          const auto it = cells_.find(Key(c + Eigen::Vector3i(dx, dy, dz)));
          if (it == cells_.end()) continue;
          for (int i : it->second) {
            const double d = (points_[i] - q).squaredNorm();
            if (d < best_d) best_d = d, best = i;
          }
        }
    return best;
  }

 private:
  Eigen::Vector3i Cell(const Vector3d& p) const {
    return {static_cast<int>(std::floor(p.x() / cell_)),
            static_cast<int>(std::floor(p.y() / cell_)),
            static_cast<int>(std::floor(p.z() / cell_))};
  }
  static int64_t Key(const Eigen::Vector3i& c) {
    return (static_cast<int64_t>(c.x() + 4096) << 26) ^ (static_cast<int64_t>(c.y() + 4096) << 13) ^
           static_cast<int64_t>(c.z() + 4096);
  }
  const std::vector<Vector3d>& points_;
  double cell_;
  std::unordered_map<int64_t, std::vector<int>> cells_;
};

// Smallest distance from the vertices of `b` to the triangles of `a` (around the nearest vertex).
double OneWayDistance(const Proximal& a, const PointGrid& grid_a, const Proximal& b) {
  double best = kInf;
  for (const Vector3d& q : b.points) {
    const int i = grid_a.Nearest(q);
    if (i < 0) continue;
    if ((q - a.points[i]).norm() > best + 0.5) continue;
    for (int f : a.vertex_faces[i]) {
      const Vector3i& t = a.faces[f];
      best = std::min(
          best, (q - ClosestOnTriangle(q, a.points[t[0]], a.points[t[1]], a.points[t[2]])).norm());
    }
  }
  return best;
}

// Surface distance between two proximal sides (vertex-to-triangle both ways).
double Separation(const Proximal& a, const PointGrid& grid_a, const Proximal& b) {
  const PointGrid grid_b(b.points, 0.8);
  return std::min(OneWayDistance(a, grid_a, b), OneWayDistance(b, grid_b, a));
}

// Places the seven teeth of one side along the arch, mesial to distal, each `gap` from the last.
void PlaceSide(const ArchCurve& arch, const std::vector<LocalCrown>& crowns, double gap,
               std::vector<ToothPlacement>& teeth) {
  constexpr double kCell = 0.8;
  double s = 0.5 * crowns[0].half_md + 0.5 * gap;
  for (size_t k = 0; k < teeth.size(); ++k) {
    ToothPlacement& t = teeth[k];
    const LocalCrown& crown = crowns[k];
    if (k == 0) {
      t.s = crown.half_md + 0.5 * gap;
      for (int it = 0; it < 40; ++it) {  // mesial face to the midline plane x = 0
        t.pose = MakePose(arch, t, crown.height);
        double min_x = kInf;
        for (const Vector3d& v : crown.vertices)
          if (v.z() >= 0) min_x = std::min(min_x, t.pose.Apply(v).x());
        const double step = (0.5 * gap - min_x) / std::cos(arch.Phi(t.s));
        t.s += step;
        if (std::abs(step) < 1e-5) break;
      }
      t.pose = MakePose(arch, t, crown.height);
      s = t.s;
      continue;
    }
    const ToothPlacement& prev = teeth[k - 1];
    const Proximal a = ProximalSide(crowns[k - 1], prev.pose, /*distal=*/true);
    const PointGrid grid(a.points, kCell);
    t.s = s + crowns[k - 1].half_md + crown.half_md + gap + 0.3;
    for (int it = 0; it < 60; ++it) {
      t.pose = MakePose(arch, t, crown.height);
      const double sep = Separation(a, grid, ProximalSide(crown, t.pose, /*distal=*/false));
      if (!std::isfinite(sep)) {
        t.s -= 0.5 * kCell;
        continue;
      }
      const double step = 0.95 * (sep - gap);
      t.s -= step;
      if (std::abs(step) < 1e-4) break;
    }
    t.pose = MakePose(arch, t, crown.height);
    s = t.s;
  }
}

// ---------------------------------------------------------------------------------------------
// Gingiva.

struct GumTooth {
  double s_lo, s_hi;   // arch extent of the crown
  double y_mid;        // margin height at mid-tooth
  double papilla;      // mm
  double inclination;  // deg
  double eminence;     // mm
  double Center() const { return 0.5 * (s_lo + s_hi); }
  double Half() const { return 0.5 * (s_hi - s_lo); }
};

class GumShape {
 public:
  GumShape(std::vector<GumTooth> teeth, double scale) : teeth_(std::move(teeth)), scale_(scale) {
    std::sort(teeth_.begin(), teeth_.end(),
              [](const GumTooth& a, const GumTooth& b) { return a.s_lo < b.s_lo; });
    const size_t n = teeth_.size();
    pap_lo_.resize(n), pap_hi_.resize(n);
    for (size_t i = 0; i < n; ++i) {
      const double own = teeth_[i].y_mid - teeth_[i].papilla;
      const double end = teeth_[i].y_mid - 1.2 * scale;
      pap_lo_[i] = i == 0 ? end : 0.5 * (own + teeth_[i - 1].y_mid - teeth_[i - 1].papilla);
      pap_hi_[i] = i + 1 == n ? end : 0.5 * (own + teeth_[i + 1].y_mid - teeth_[i + 1].papilla);
    }
  }
  double s_min() const { return teeth_.front().s_lo; }
  double s_max() const { return teeth_.back().s_hi; }

  // Crest() tabulated every `step` over [s0, s1] for the many crown-vertex look-ups.
  void Tabulate(double s0, double s1, double step) {
    table_s0_ = s0, table_step_ = step;
    const size_t n = static_cast<size_t>(std::ceil((s1 - s0) / step)) + 2;
    table_.resize(n);
    for (size_t i = 0; i < n; ++i) table_[i] = Crest(s0 + step * i);
  }
  double CrestFast(double s) const {
    const double x =
        std::clamp((s - table_s0_) / table_step_, 0.0, static_cast<double>(table_.size() - 2));
    const size_t i = static_cast<size_t>(x);
    return table_[i] + (x - i) * (table_[i + 1] - table_[i]);
  }

  // Height of the gingival crest (margin, papillae, tuberosities) along the arch.
  double Crest(double s) const {
    constexpr double kQ = 2.0;
    const double tau = 0.22 * scale_;
    std::array<double, 18> f{};
    size_t n = 0;
    for (size_t i = 0; i < teeth_.size(); ++i) {
      const GumTooth& t = teeth_[i];
      const double x = (s - t.Center()) / t.Half();
      const double side = x < 0 ? pap_lo_[i] : pap_hi_[i];
      f[n++] = t.y_mid - (t.y_mid - side) * std::pow(std::abs(x), kQ);
    }
    const double ramp = 5.0 * scale_, rise = 2.5 * scale_;
    if (s < teeth_.front().Center())
      f[n++] = pap_lo_.front() + rise * Smoothstep((teeth_.front().s_lo - s) / ramp);
    if (s > teeth_.back().Center())
      f[n++] = pap_hi_.back() + rise * Smoothstep((s - teeth_.back().s_hi) / ramp);
    double m = -kInf;
    for (size_t i = 0; i < n; ++i) m = std::max(m, f[i]);
    double sum = 0;
    for (size_t i = 0; i < n; ++i) sum += std::exp((f[i] - m) / tau);
    return m + tau * std::log(sum);
  }
  // Smooth mid-tooth margin level (for the palatal top edge).
  double Level(double s) const {
    return Blend(s, [](const GumTooth& t) { return t.y_mid; });
  }
  double Inclination(double s) const {
    return Blend(s, [](const GumTooth& t) { return t.inclination; });
  }
  double Eminence(double s) const {
    double e = 0;
    for (const GumTooth& t : teeth_) {
      const double x = (s - t.Center()) / t.Half();
      if (std::abs(x) < 1) e += t.eminence * Sq(std::cos(0.5 * kPi * x));
    }
    return e;
  }

 private:
  template <typename F>
  double Blend(double s, F&& value) const {
    double num = 0, den = 0;
    for (const GumTooth& t : teeth_) {
      const double w = std::exp(-Sq((s - t.Center()) / t.Half())) + 1e-12;
      num += w * value(t), den += w;
    }
    return num / den;
  }
  std::vector<GumTooth> teeth_;
  std::vector<double> pap_lo_, pap_hi_;
  double scale_;
  std::vector<double> table_;
  double table_s0_ = 0, table_step_ = 1;
};

// Buccal/palatal extent of the crowns where they pierce the crest, binned along the arch.
class WallLimits {
 public:
  WallLimits(double s_min, double s_max, double bin) : s_min_(s_min), bin_(bin) {
    const size_t n = static_cast<size_t>(std::ceil((s_max - s_min) / bin)) + 1;
    hi_.assign(n, -kInf), lo_.assign(n, kInf);
  }
  void Add(double s, double n) {
    const size_t i = Index(s);
    hi_[i] = std::max(hi_[i], n), lo_[i] = std::min(lo_[i], n);
  }
  // Fills empty bins, dilates by `radius` and smooths by `sigma` so the walls clear every crown;
  // a second, much smoother copy (`sigma_top`) shapes the gingiva away from the margin.
  void Finish(double radius, double sigma, double sigma_top) {
    Fill(hi_), Fill(lo_);
    hi_ = Smooth(Dilate(hi_, radius, +1), sigma, &hi_, +1);
    lo_ = Smooth(Dilate(lo_, radius, -1), sigma, &lo_, -1);
    hi_top_ = Smooth(hi_, sigma_top, nullptr, +1);
    lo_top_ = Smooth(lo_, sigma_top, nullptr, -1);
  }
  double Hi(double s) const { return Interp(hi_, s); }
  double Lo(double s) const { return Interp(lo_, s); }
  double HiTop(double s) const { return Interp(hi_top_, s); }
  double LoTop(double s) const { return Interp(lo_top_, s); }

 private:
  size_t Index(double s) const {
    const double f = std::floor((s - s_min_) / bin_);
    return static_cast<size_t>(std::clamp(f, 0.0, static_cast<double>(hi_.size() - 1)));
  }
  double Interp(const std::vector<double>& a, double s) const {
    const double x = std::clamp((s - s_min_) / bin_ - 0.5, 0.0, static_cast<double>(a.size() - 1));
    const size_t i = std::min(static_cast<size_t>(x), a.size() - 2);
    const double f = x - i;
    return a[i] + f * (a[i + 1] - a[i]);
  }
  static void Fill(std::vector<double>& a) {
    const size_t n = a.size();
    std::vector<double> out = a;
    for (size_t i = 0; i < n; ++i) {
      if (std::isfinite(a[i])) continue;
      for (size_t d = 1; d < n; ++d) {  // nearest defined bin
        if (i >= d && std::isfinite(a[i - d])) {
          out[i] = a[i - d];
          break;
        }
        if (i + d < n && std::isfinite(a[i + d])) {
          out[i] = a[i + d];
          break;
        }
      }
      if (!std::isfinite(out[i])) out[i] = 0;
    }
    a = out;
  }
  std::vector<double> Dilate(const std::vector<double>& a, double radius, int sign) const {
    const int r = static_cast<int>(std::ceil(radius / bin_));
    const int n = static_cast<int>(a.size());
    std::vector<double> out(a.size());
    for (int i = 0; i < n; ++i) {
      double m = a[i];
      for (int d = -r; d <= r; ++d) {
        const int j = std::clamp(i + d, 0, n - 1);
        m = sign > 0 ? std::max(m, a[j]) : std::min(m, a[j]);
      }
      out[i] = m;
    }
    return out;
  }
  // Gaussian smoothing; with `floor`, never inside it (sign: +1 keep >=, -1 keep <=).
  std::vector<double> Smooth(const std::vector<double>& a, double sigma,
                             const std::vector<double>* floor, int sign) const {
    const int r = static_cast<int>(std::ceil(3 * sigma / bin_));
    const int n = static_cast<int>(a.size());
    std::vector<double> out(a.size());
    for (int i = 0; i < n; ++i) {
      double num = 0, den = 0;
      for (int d = -r; d <= r; ++d) {
        const double w = std::exp(-0.5 * Sq(d * bin_ / sigma));
        num += w * a[std::clamp(i + d, 0, n - 1)], den += w;
      }
      out[i] = num / den;
      if (floor) out[i] = sign > 0 ? std::max(out[i], (*floor)[i]) : std::min(out[i], (*floor)[i]);
    }
    return out;
  }
  double s_min_, bin_;
  std::vector<double> hi_, lo_, hi_top_, lo_top_;
};

struct GumParams {
  double edge, thickness, corner, top_y, palate_width, scale;
};

// Height of the gingiva's occlusal surface over (s, n) between the walls: the flat crest and the
// rounded fillets up to the buccal and palatal walls (+inf outside). Crowns are cut above it.
double GumSurfaceY(double crest, double n_b, double n_p, double corner, double n) {
  if (n >= n_b || n <= n_p) return kInf;
  double y = crest;
  if (n > n_b - corner) y += corner * Sq(1.0 - std::sqrt((n_b - n) / corner));
  if (n < n_p + corner) y += corner * Sq(1.0 - std::sqrt((n - n_p) / corner));
  return y;
}

// One cross-section of the gingiva at arch position s, in (n, y), palatal top -> buccal top.
class GumProfile {
 public:
  GumProfile(const GumShape& shape, const WallLimits& walls, const GumParams& p, double s) : p_(p) {
    crest_ = shape.Crest(s);
    n_b_ = walls.Hi(s) + p.thickness;
    n_p_ = walls.Lo(s) - p.thickness;
    n_b_top_ = walls.HiTop(s) + p.thickness;
    n_p_top_ = std::min(walls.LoTop(s) - p.thickness - p.palate_width, n_p_ - 0.5 * p.scale);
    lean_ = 0.8 * std::tan(Rad(shape.Inclination(s)));
    eminence_ = shape.Eminence(s);
    top_ = std::max(p.top_y, crest_ + 2.0 * p.scale);
    palate_top_ = std::max(shape.Level(s) + 6.5 * p.scale, crest_ + 2.0 * p.scale);
  }
  Vector2d Buccal(double t) const {  // wall from crest + corner to the top, t in [0, 1]
    const double y = crest_ + p_.corner + t * (top_ - crest_ - p_.corner);
    return {BuccalN(y), y};
  }
  Vector2d Palatal(
      double t) const {  // quarter ellipse from the palatal top (t=0) down to the fillet
    const double a = 0.5 * kPi * (1.0 - t);
    const double y0 = crest_ + p_.corner;
    return {n_p_ - (n_p_ - n_p_top_) * (1.0 - std::cos(a)), y0 + (palate_top_ - y0) * std::sin(a)};
  }
  Vector2d Crest(double t) const {
    return {n_p_ + p_.corner + t * (n_b_ - n_p_ - 2 * p_.corner), crest_};
  }
  Vector2d BuccalCorner(double t) const {  // crest end -> wall start, quadratic Bezier
    return Bezier({n_b_ - p_.corner, crest_}, {n_b_, crest_}, Buccal(0.0), t);
  }
  Vector2d PalatalCorner(double t) const {
    return Bezier(Palatal(1.0), {n_p_, crest_}, {n_p_ + p_.corner, crest_}, t);
  }

 private:
  double BuccalN(double y) const {
    const double rise = y - crest_;
    const double base =
        n_b_ + (n_b_top_ - n_b_) * Smoothstep((rise - 1.0 * p_.scale) / (3.0 * p_.scale));
    return base - lean_ * rise + eminence_ * Smoothstep(rise / (3.0 * p_.scale));
  }
  static Vector2d Bezier(const Vector2d& a, const Vector2d& c, const Vector2d& b, double t) {
    return (1 - t) * (1 - t) * a + 2 * t * (1 - t) * c + t * t * b;
  }
  GumParams p_;
  double crest_, n_b_, n_p_, n_b_top_, n_p_top_, lean_, eminence_, top_, palate_top_;
};

template <typename F>
double CurveLength(F&& f) {
  double len = 0;
  Vector2d prev = f(0.0);
  for (int i = 1; i <= 32; ++i) {
    const Vector2d p = f(i / 32.0);
    len += (p - prev).norm();
    prev = p;
  }
  return len;
}

// Sweeps the gingiva profile along the arch (an open sheet: top, palate edge and ends are open).
TriangleMesh BuildGingiva(const ArchCurve& arch, const GumShape& shape, const WallLimits& walls,
                          const GumParams& p) {
  // Candidate stations every 0.05 mm along the arch (the gingiva runs 5 mm past the last teeth).
  const double s_lo = shape.s_min() - 5.0 * p.scale, s_hi = shape.s_max() + 5.0 * p.scale;
  const int n_candidates = static_cast<int>(std::ceil((s_hi - s_lo) / (0.05 * p.scale))) + 1;
  std::vector<double> candidates(n_candidates);
  std::vector<GumProfile> profiles;
  profiles.reserve(n_candidates);
  std::array<double, 5> longest{};
  for (int j = 0; j < n_candidates; ++j) {
    candidates[j] = s_lo + (s_hi - s_lo) * j / (n_candidates - 1);
    profiles.emplace_back(shape, walls, p, candidates[j]);
    const GumProfile& g = profiles.back();
    const std::array<double, 5> len = {CurveLength([&](double t) { return g.Palatal(t); }),
                                       CurveLength([&](double t) { return g.PalatalCorner(t); }),
                                       CurveLength([&](double t) { return g.Crest(t); }),
                                       CurveLength([&](double t) { return g.BuccalCorner(t); }),
                                       CurveLength([&](double t) { return g.Buccal(t); })};
    for (int k = 0; k < 5; ++k) longest[k] = std::max(longest[k], len[k]);
  }
  // Profile point counts per piece from the longest piece over all stations.
  std::array<int, 5> count{};
  for (int k = 0; k < 5; ++k)
    count[k] = std::max(2, static_cast<int>(std::ceil(longest[k] / p.edge)));
  const int per = count[0] + count[1] + count[2] + count[3] + count[4] + 1;
  auto profile_points = [&](int j) {
    const GumProfile& g = profiles[j];
    const Vector2d c = arch.Point(candidates[j]);
    const Vector2d nrm = arch.Normal(candidates[j]);
    std::vector<Vector3d> pts;
    pts.reserve(per);
    auto emit = [&](const Vector2d& q) {
      pts.emplace_back(c.x() + q.x() * nrm.x(), q.y(), c.y() + q.x() * nrm.y());
    };
    for (int i = 0; i < count[0]; ++i) emit(g.Palatal(static_cast<double>(i) / count[0]));
    for (int i = 0; i < count[1]; ++i) emit(g.PalatalCorner(static_cast<double>(i) / count[1]));
    for (int i = 0; i < count[2]; ++i) emit(g.Crest(static_cast<double>(i) / count[2]));
    for (int i = 0; i < count[3]; ++i) emit(g.BuccalCorner(static_cast<double>(i) / count[3]));
    for (int i = 0; i <= count[4]; ++i) emit(g.Buccal(static_cast<double>(i) / count[4]));
    return pts;
  };
  // Stations: the farthest candidate whose points all stay within the target of the last station.
  const double target = p.edge / 1.25;
  TriangleMesh gum;
  std::vector<Vector3d> last = profile_points(0);
  gum.vertices.insert(gum.vertices.end(), last.begin(), last.end());
  std::vector<Vector3d> accepted;
  for (int j = 1; j < n_candidates; ++j) {
    std::vector<Vector3d> pts = profile_points(j);
    double move = 0;
    for (int i = 0; i < per; ++i) move = std::max(move, (pts[i] - last[i]).norm());
    if (move > target && !accepted.empty()) {  // previous candidate is the next station
      gum.vertices.insert(gum.vertices.end(), accepted.begin(), accepted.end());
      last = accepted;
    }
    accepted = std::move(pts);
    if (j + 1 == n_candidates)
      gum.vertices.insert(gum.vertices.end(), accepted.begin(), accepted.end());
  }
  const int n_stations = static_cast<int>(gum.vertices.size()) / per;
  for (int j = 0; j + 1 < n_stations; ++j) {
    const int a = j * per, b = a + per;
    for (int k = 0; k + 1 < per; ++k) {
      gum.faces.emplace_back(a + k, b + k, a + k + 1);
      gum.faces.emplace_back(b + k, b + k + 1, a + k + 1);
    }
  }
  return gum;
}

// ---------------------------------------------------------------------------------------------

struct PlacedCrown {
  int fdi;
  int side;  // +1 left (2x), -1 right (1x)
  const ToothPlacement* placement;
  const LocalCrown* local;
  std::vector<Vector3d> vertices;  // global
  std::vector<Vector3i> faces;
  std::vector<double> arch_s;  // per vertex
};

}  // namespace

TriangleMesh MakeTypodont(const TypodontOptions& options, TypodontInfo* info) {
  options.Check();
  const double scale = options.scale;
  const ArchCurve arch(scale);
  std::mt19937 rng(options.seed);

  // Teeth of each side: specs, seeded jitter, local crowns, placement (left-side coordinates).
  std::array<std::vector<ToothPlacement>, 2> sides;  // [0] right (1x), [1] left (2x)
  std::array<std::vector<LocalCrown>, 2> crowns;
  for (int side = 0; side < 2; ++side) {
    for (int pos = 1; pos <= 7; ++pos) {
      ToothPlacement t;
      t.spec = SpecFor(pos);
      t.jitter = DrawJitter(rng, options.asymmetry);
      t.tip_y = t.spec.tip_y * scale + t.jitter.dy;
      const CrownShape shape(t.spec, t.jitter, scale);
      crowns[side].push_back(BuildCrown(shape, options.crown_edge_mm, scale));
      sides[side].push_back(t);
    }
    PlaceSide(arch, crowns[side], options.gap_mm, sides[side]);
  }

  // Global crowns (right side mirrored), ordered 17..11, 21..27.
  std::vector<PlacedCrown> placed;
  for (int side = 0; side < 2; ++side) {
    for (int k = 0; k < 7; ++k) {
      const int pos = side == 0 ? 7 - k : k + 1;
      const int idx = pos - 1;
      PlacedCrown c;
      c.fdi = (side == 0 ? 10 : 20) + pos;
      c.side = side == 0 ? -1 : 1;
      c.placement = &sides[side][idx];
      c.local = &crowns[side][idx];
      c.vertices.reserve(c.local->vertices.size());
      for (const Vector3d& v : c.local->vertices) {
        Vector3d g = c.placement->pose.Apply(v);
        if (c.side < 0) g.x() = -g.x();
        c.vertices.push_back(g);
      }
      c.faces = c.local->faces;
      if (c.side < 0)
        for (Vector3i& f : c.faces) std::swap(f[1], f[2]);
      c.arch_s.resize(c.vertices.size());
      for (size_t i = 0; i < c.vertices.size(); ++i) {
        const double guess = c.side * (c.placement->s + c.local->vertices[i].x());
        c.arch_s[i] = arch.Project({c.vertices[i].x(), c.vertices[i].z()}, guess).x();
      }
      placed.push_back(std::move(c));
    }
  }

  // Gingival crest from the crowns' arch extents and margin heights.
  std::vector<GumTooth> gum_teeth;
  for (const PlacedCrown& c : placed) {
    GumTooth g{kInf, -kInf, 0, 0, 0, 0};
    for (size_t i = 0; i < c.vertices.size(); ++i) {
      if (c.local->vertices[i].z() < 0.3 * c.local->height) continue;
      g.s_lo = std::min(g.s_lo, c.arch_s[i]);
      g.s_hi = std::max(g.s_hi, c.arch_s[i]);
    }
    g.y_mid = c.placement->pose.Apply(Vector3d(0, 0, 1.0 * scale)).y();
    g.papilla = c.placement->spec.papilla * scale;
    g.inclination = c.placement->spec.inclination;
    g.eminence = c.placement->spec.eminence * scale;
    gum_teeth.push_back(g);
  }
  GumShape gum_shape(gum_teeth, scale);
  gum_shape.Tabulate(gum_shape.s_min() - 6.0 * scale, gum_shape.s_max() + 6.0 * scale,
                     0.02 * scale);

  // Walls of the gingiva: clear the crowns where they pierce the crest.
  WallLimits walls(gum_shape.s_min() - 6.0 * scale, gum_shape.s_max() + 6.0 * scale, 0.2 * scale);
  std::vector<std::vector<Vector2d>> arch_sn(placed.size());
  for (size_t ci = 0; ci < placed.size(); ++ci) {
    const PlacedCrown& c = placed[ci];
    arch_sn[ci].resize(c.vertices.size());
    for (size_t i = 0; i < c.vertices.size(); ++i) {
      const Vector2d sn = arch.Project({c.vertices[i].x(), c.vertices[i].z()}, c.arch_s[i]);
      arch_sn[ci][i] = sn;
      if (std::abs(c.vertices[i].y() - gum_shape.CrestFast(sn.x())) < 0.6 * scale)
        walls.Add(sn.x(), sn.y());
    }
  }
  walls.Finish(0.8 * scale, 0.6 * scale, 2.5 * scale);
  const GumParams gum_params{options.gingiva_edge_mm,
                             options.gingiva_thickness_mm,
                             0.75 * options.gingiva_thickness_mm,
                             options.gingiva_top_y_mm * scale,
                             options.palate_width_mm * scale,
                             scale};

  // Cut each crown exactly where it enters the gingiva: a crown triangle wholly under the gum
  // surface goes, one crossing it is clipped along the crossing (edge points interpolated linearly
  // in the height above the surface, shared by both faces of the edge). Nothing of a crown stays
  // inside the gum: a lab scan of a typodont has no such surface, and it would count as tooth
  // surface no probe can reach (it was 4.5 % of the tooth area with a 0.2 mm overlap). The gingiva
  // runs on under the crowns (its crest spans the walls), so the cut edge leaves no hole.
  TriangleMesh mesh;
  for (size_t ci = 0; ci < placed.size(); ++ci) {
    const PlacedCrown& c = placed[ci];
    // Height of each vertex apical of the gum surface (> 0: inside the gingiva).
    std::vector<double> depth(c.vertices.size());
    for (size_t i = 0; i < c.vertices.size(); ++i) {
      const double s = arch_sn[ci][i].x(), n = arch_sn[ci][i].y();
      const double gum_y = GumSurfaceY(gum_shape.CrestFast(s), walls.Hi(s) + gum_params.thickness,
                                       walls.Lo(s) - gum_params.thickness, gum_params.corner, n);
      depth[i] = std::isfinite(gum_y) ? c.vertices[i].y() - gum_y : -1.0;
    }
    std::vector<int> remap(c.vertices.size(), -1);
    std::map<std::pair<int, int>, int>
        crossing;                   // crown edge -> mesh vertex where it meets the gum
    constexpr double kSnap = 0.05;  // share of an edge under which a crossing snaps to its kept end
    auto keep = [&](int i) {
      if (remap[i] < 0) {
        remap[i] = static_cast<int>(mesh.vertices.size());
        mesh.vertices.push_back(c.vertices[i]);
      }
      return remap[i];
    };
    auto cross = [&](int a, int b) {
      const auto key = std::minmax(a, b);
      auto it = crossing.find(key);
      if (it != crossing.end()) return it->second;
      const double t = depth[key.first] / (depth[key.first] - depth[key.second]);
      const int inside = depth[key.first] <= 0 ? key.first : key.second;
      int v;
      if ((inside == key.first ? t : 1.0 - t) < kSnap) {
        v = keep(inside);  // the crossing all but meets the kept corner: no sliver
      } else {
        v = static_cast<int>(mesh.vertices.size());
        mesh.vertices.push_back(c.vertices[key.first] +
                                t * (c.vertices[key.second] - c.vertices[key.first]));
      }
      crossing.emplace(key, v);
      return v;
    };
    auto add = [&](int a, int b, int d) {
      mesh.faces.emplace_back(a, b, d);
      mesh.face_labels.push_back(SurfaceLabel::kTooth);
      mesh.face_tooth_ids.push_back(static_cast<uint8_t>(c.fdi));
    };
    for (const Vector3i& f : c.faces) {
      // Sutherland-Hodgman against depth <= 0: the polygon kept has 3 or 4 corners (or none).
      std::array<int, 4> poly{};
      int corners = 0;
      for (int k = 0; k < 3; ++k) {
        const int a = f[k], b = f[(k + 1) % 3];
        const bool a_in = depth[a] <= 0, b_in = depth[b] <= 0;
        if (a_in) poly[corners++] = keep(a);
        if (a_in != b_in) poly[corners++] = cross(a, b);
      }
      int distinct = 0;  // drop corners a snapped crossing merged with the next
      for (int k = 0; k < corners; ++k)
        if (poly[k] != poly[(k + 1) % corners]) poly[distinct++] = poly[k];
      if (distinct >= 3) add(poly[0], poly[1], poly[2]);
      if (distinct == 4) add(poly[0], poly[2], poly[3]);
    }
  }

  const TriangleMesh gum = BuildGingiva(arch, gum_shape, walls, gum_params);
  const int gum_base = static_cast<int>(mesh.vertices.size());
  mesh.vertices.insert(mesh.vertices.end(), gum.vertices.begin(), gum.vertices.end());
  for (const Vector3i& f : gum.faces) {
    mesh.faces.push_back(f + Vector3i::Constant(gum_base));
    mesh.face_labels.push_back(SurfaceLabel::kGingiva);
    mesh.face_tooth_ids.push_back(0);
  }

  // Centre z between the labial of the central incisors and the distal of the second molars.
  double z_front = -kInf, z_back = kInf;
  for (size_t f = 0; f < mesh.faces.size(); ++f) {  // visible crown surface only
    const int pos = mesh.face_tooth_ids[f] % 10;
    for (int k = 0; k < 3 && (pos == 1 || pos == 7); ++k) {
      const double z = mesh.vertices[mesh.faces[f][k]].z();
      if (pos == 1) z_front = std::max(z_front, z);
      if (pos == 7) z_back = std::min(z_back, z);
    }
  }
  const Vector3d shift(0, 0, -0.5 * (z_front + z_back));
  for (Vector3d& v : mesh.vertices) v += shift;
  mesh.vertex_normals = AreaWeightedNormals(mesh.vertices, mesh.faces);

  if (info) {
    info->teeth.clear();
    for (const PlacedCrown& c : placed) {
      TypodontTooth t;
      t.fdi = c.fdi;
      t.arch_s = c.side * c.placement->s;
      const Pose& pose = c.placement->pose;
      auto to_global = [&](const Vector3d& local) {
        Vector3d g = pose.Apply(local);
        if (c.side < 0) g.x() = -g.x();
        return Vector3d(g + shift);
      };
      t.cej_center = to_global(Vector3d::Zero());
      t.tip = to_global(Vector3d(0, 0, c.local->height));
      t.axes = pose.rotation;
      if (c.side < 0) t.axes.row(0) *= -1.0;
      for (const Vector3d& tip : c.local->cusp_tips) t.cusp_tips.push_back(to_global(tip));
      info->teeth.push_back(std::move(t));
    }
    info->arch_curve.clear();
    const double s_end = std::max(std::abs(gum_shape.s_min()), std::abs(gum_shape.s_max()));
    for (double s = -std::floor(s_end); s <= std::floor(s_end) + 1e-9; s += 1.0) {
      const Vector2d p = arch.Point(s);
      info->arch_curve.emplace_back(p.x(), 0.0, p.y() + shift.z());
    }
  }
  return mesh;
}

}  // namespace d3d
