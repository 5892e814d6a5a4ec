// The virtual probe's physical design: the optics, sensor and materials that the renderer needs
// beyond the calibration (apertures, focus, noise, reflectance). The calibration part is what a
// factory calibration would measure; it is written to calibration.json. Everything else is ground
// truth known only to the simulator.
//
// Default geometry (documented against published intraoral-scanner figures):
//   - Field of view ≈ 16 × 12 mm at the 50 mm working distance (camera 640 × 480, fx = fy = 2000
//   px,
//     25 µm per pixel on the tooth). Published IOS fields of view are about 14–20 mm wide (e.g.
//     Logozzo et al. 2014, "Recent advances in dental optics", Opt. Lasers Eng. 54: 203–221).
//   - The working distance is measured along the unfolded optical path from the camera's centre
//     (the tip mirror folds it inside the handpiece); the measurement volume / depth of field is
//     42–58 mm (16 mm ≥ the 15 mm asked; published IOS scan depths are 0–20 mm from the tip).
//   - Triangulation angle 12° (8–15° range of IOS fringe projectors): the projector sits
//     b = 50 · tan 12° = 10.63 mm along +x of the camera and aims at the working point.
//   - Projector: a DMD of 912 × 1140 micromirrors (DLP4500 class, modelled with square pixels),
//     fx = fy = 2100 px (23.8 µm per projector pixel at 50 mm, a 21.7 × 27 mm field that covers
//     the camera's across the whole measurement volume).
//   - Projector intensity response: uncorrected gamma 2.2 (calibration.projector_gamma).
//   - Apertures: camera entrance pupil 0.6 mm and projector 0.8 mm, the balance between defocus at
//     the depth-of-field limits and diffraction (λ = 450 nm blue LED): camera blur σ ≈ 0.63 px at
//     focus and ≈ 1.05 px at ±8 mm.
#pragma once

#include <cmath>

#include "calib/model/probe_calibration.h"
#include "common/mesh/mesh.h"

namespace d3d {

// Lens and illumination optics (ground truth, not in calibration.json).
struct ProbeOptics {
  double camera_focus_mm = 50.0;     // plane of best focus, camera z
  double camera_pupil_mm = 0.6;      // entrance pupil diameter D
  double projector_focus_mm = 50.0;  // plane of best focus, projector z
  double projector_pupil_mm = 0.8;
  double wavelength_nm = 450.0;  // blue LED illumination
  // Irradiance of a fully-on projector pixel on a surface facing the projector at
  // projector_focus_mm, in units of the sensor's full well per unit albedo during one exposure.
  double projector_irradiance = 1.15;
  double ambient_irradiance = 0.02;  // stray room/operatory light reaching the teeth, same units

  void Check() const;
  // Gaussian σ (pixels) of the blur of a point at distance z_mm (along the device's axis) for a
  // device with focal length f_px: defocus blur circle of diameter c = f_px·D·|z − z_f| / (z·z_f)
  // (thin lens, z_f ≫ f) as a uniform disk (σ = c/4), combined in quadrature with the Airy core
  // (σ ≈ 0.42 λ f_px / D).
  static double BlurSigmaPx(double f_px, double pupil_mm, double focus_mm, double wavelength_nm,
                            double z_mm);
};

// BlurSigmaPx of one device with the factors that do not depend on z computed once: the same
// operations in the same order (the same bits, BlurSigmaPx is this), for per-pixel use.
class DeviceBlur {
 public:
  DeviceBlur(double f_px, double pupil_mm, double focus_mm, double wavelength_nm)
      : f_pupil_(f_px * pupil_mm), focus_mm_(focus_mm), airy_squared_([&] {
          const double sigma_airy = 0.42 * wavelength_nm * 1e-6 * f_px / pupil_mm;
          return sigma_airy * sigma_airy;
        }()) {}
  double SigmaPx(double z_mm) const {
    const double defocus_diameter_px = f_pupil_ * std::abs(z_mm - focus_mm_) / (z_mm * focus_mm_);
    const double sigma_defocus = defocus_diameter_px / 4.0;
    return std::sqrt(sigma_defocus * sigma_defocus + airy_squared_);
  }

 private:
  double f_pupil_, focus_mm_, airy_squared_;
};

// Image sensor (ground truth). Signal in units of the full well, then electrons, then DN.
struct SensorModel {
  double full_well_e = 10000.0;   // electrons at saturation (small-pixel global-shutter CMOS)
  double read_noise_e = 4.0;      // rms electrons
  int bits = 8;                   // ADC depth; DN = round(e · (2^bits − 1) / full_well)
  int64_t exposure_ns = 1000000;  // 1 ms exposure, centred on each frame's timestamp
  void Check() const;
};

// Optical material of a surface label. Diffuse reflectance ρ is for the blue (450 nm) light of the
// probe on a monochrome sensor.
struct Material {
  double albedo = 0.7;               // diffuse reflectance ρ
  double subsurface_fraction = 0.0;  // share s of the diffuse light that re-emerges after
                                     // sub-surface transport (blurred pattern)
  double subsurface_sigma_mm = 0.0;  // Gaussian σ of that transport on the surface
  double specular_r0 = 0.0;          // Fresnel reflectance at normal incidence (wet surface)
  double specular_exponent = 1.0;    // normalised Blinn–Phong exponent m: f = R0 (m+8)/8 (n·h)^m
  double mottle_amplitude = 0.0;     // relative albedo variation, fine (0.2–0.3 mm) scale
  double mottle_scale_mm = 0.3;
  double stain_amplitude = 0.0;  // relative albedo loss in stain patches (1–3 mm)
  double stain_scale_mm = 2.0;
  void Check() const;
};

// Default materials and their sources:
//  enamel: ρ = 0.70 (diffuse reflectance of human enamel in the blue–green, 0.6–0.8; Spitzer &
//    ten Bosch 1975, Calcif. Tissue Res. 17:129); sub-surface share 0.30 with σ = 0.12 mm: enamel
//    scatters weakly and forward (μs ≈ 15–105 cm⁻¹, g ≈ 0.96; Fried et al. 1995, Appl. Opt.
//    34:1278), so part of the light re-emerges within a few hundred µm; the values reproduce the
//    ≈ 30 % loss of fringe modulation that uncoated teeth show against powdered ones (our choice
//    within the range reported, e.g. Logozzo 2014). Wet enamel: R0 = ((1.62−1)/(1.62+1))² = 0.056
//    (refractive index 1.62), glossy lobe m = 300: glints saturate, as on a real wet tooth.
//    Texture: mottling ±4 % at 0.3 mm, stain patches −12 % at 2 mm (mild on purpose; baked at
//    the vertices of a mesh subdivided to ≤ 0.3 mm median edges, see scene_prep.h).
//  gingiva: ρ = 0.35 (oral mucosa reflects far less blue than enamel: haemoglobin absorption;
//    our choice within 0.2–0.4), sub-surface share 0.55 with σ = 0.35 mm (soft tissue μs' ≈
//    1–2 mm⁻¹, e.g. Jacques 2013, Phys. Med. Biol. 58:R37), saliva film R0 = 0.02 (n = 1.33),
//    m = 60; stippling ±5 % at 0.5 mm, vascular ±8 % at 1.5 mm.
Material DefaultMaterial(SurfaceLabel label);

struct ProbeDesign {
  ProbeCalibration calibration;  // the true calibration (written as calibration.json)
  ProbeOptics optics;
  SensorModel sensor;
  Material enamel = DefaultMaterial(SurfaceLabel::kTooth);
  Material gingiva = DefaultMaterial(SurfaceLabel::kGingiva);
  const Material& MaterialOf(SurfaceLabel label) const {
    return label == SurfaceLabel::kGingiva ? gingiva
                                           : enamel;  // unlabelled surfaces render as enamel
  }
  void Check() const;
};

// The default probe described above, with a camera of 640 × 480 (or 1280 × 1024: same field of
// view, fx doubled). Throws std::invalid_argument for other sizes.
ProbeDesign MakeDefaultProbeDesign(int camera_width = 640, int camera_height = 480);

}  // namespace d3d
