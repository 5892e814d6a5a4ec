#include "sim/render/probe_design.h"

#include <cmath>

namespace d3d {

void ProbeOptics::Check() const {
  D3D_CHECK_MSG(camera_focus_mm > 0 && projector_focus_mm > 0, "focus distances must be positive");
  D3D_CHECK_MSG(camera_pupil_mm > 0 && projector_pupil_mm > 0, "pupil diameters must be positive");
  D3D_CHECK_MSG(wavelength_nm > 200 && wavelength_nm < 2000,
                "wavelength " << wavelength_nm << " nm out of range");
  D3D_CHECK_MSG(projector_irradiance > 0 && ambient_irradiance >= 0,
                "irradiances must be non-negative");
}

double ProbeOptics::BlurSigmaPx(double f_px, double pupil_mm, double focus_mm, double wavelength_nm,
                                double z_mm) {
  return DeviceBlur(f_px, pupil_mm, focus_mm, wavelength_nm).SigmaPx(z_mm);
}

void SensorModel::Check() const {
  D3D_CHECK_MSG(full_well_e > 0, "full well must be positive");
  D3D_CHECK_MSG(read_noise_e >= 0, "read noise must be non-negative");
  D3D_CHECK_MSG(bits >= 8 && bits <= 16, "ADC bits must be in [8, 16], got " << bits);
  D3D_CHECK_MSG(exposure_ns > 0, "exposure must be positive");
}

void Material::Check() const {
  D3D_CHECK_MSG(albedo > 0 && albedo <= 1, "albedo must be in (0, 1]");
  D3D_CHECK_MSG(subsurface_fraction >= 0 && subsurface_fraction <= 1,
                "sub-surface share must be in [0, 1]");
  D3D_CHECK_MSG(subsurface_sigma_mm >= 0, "sub-surface sigma must be ≥ 0");
  D3D_CHECK_MSG(specular_r0 >= 0 && specular_r0 < 1 && specular_exponent >= 1,
                "bad specular parameters");
  D3D_CHECK_MSG(mottle_amplitude >= 0 && mottle_amplitude < 0.5 && stain_amplitude >= 0 &&
                    stain_amplitude < 0.5,
                "texture amplitudes must be in [0, 0.5)");
  D3D_CHECK_MSG(mottle_scale_mm > 0 && stain_scale_mm > 0, "texture scales must be positive");
}

Material DefaultMaterial(SurfaceLabel label) {
  Material m;
  if (label == SurfaceLabel::kTooth) {
    m.albedo = 0.70;
    m.subsurface_fraction = 0.30;
    m.subsurface_sigma_mm = 0.12;
    m.specular_r0 = 0.056;
    m.specular_exponent = 300.0;
    m.mottle_amplitude = 0.04;
    m.mottle_scale_mm = 0.3;
    m.stain_amplitude = 0.12;
    m.stain_scale_mm = 2.0;
  } else {
    m.albedo = 0.35;
    m.subsurface_fraction = 0.55;
    m.subsurface_sigma_mm = 0.35;
    m.specular_r0 = 0.02;
    m.specular_exponent = 60.0;
    m.mottle_amplitude = 0.05;
    m.mottle_scale_mm = 0.5;
    m.stain_amplitude = 0.08;
    m.stain_scale_mm = 1.5;
  }
  return m;
}

void ProbeDesign::Check() const {
  calibration.Check();
  optics.Check();
  sensor.Check();
  enamel.Check();
  gingiva.Check();
}

ProbeDesign MakeDefaultProbeDesign(int camera_width, int camera_height) {
  const bool vga = camera_width == 640 && camera_height == 480;
  const bool sxga = camera_width == 1280 && camera_height == 1024;
  D3D_CHECK_MSG(vga || sxga, "the default probe has a 640x480 or 1280x1024 camera, not "
                                 << camera_width << "x" << camera_height);
  const double scale = sxga ? 2.0 : 1.0;
  ProbeDesign d;
  ProbeCalibration& c = d.calibration;
  c.source = "virtual-probe";
  // Slightly off-centre principal point and mild barrel distortion, as a real small lens has.
  c.camera = {camera_width,
              camera_height,
              2000.0 * scale,
              2000.0 * scale,
              (camera_width - 1) / 2.0 + 3.2 * scale,
              (camera_height - 1) / 2.0 - 2.6 * scale,
              -0.045,
              0.12,
              2.0e-4,
              -1.5e-4,
              0.0};
  c.projector = {912,  1140,  2100.0,  2100.0, 455.5 + 1.8, 569.5 - 3.1,
                 0.03, -0.05, -1.0e-4, 0.8e-4, 0.0};
  const double angle = 12.0 * M_PI / 180.0;
  const double working_distance = 50.0;
  c.cam_from_proj = Rigid3d::Identity();
  c.cam_from_proj.linear() = Eigen::AngleAxisd(-angle, Eigen::Vector3d::UnitY()).toRotationMatrix();
  c.cam_from_proj.translation() = Eigen::Vector3d(working_distance * std::tan(angle), 0.0, 0.0);
  c.depth_min_mm = 42.0;
  c.depth_max_mm = 58.0;
  c.projector_gamma = 2.2;
  c.pattern = FringePatternSpec{};
  d.optics.camera_focus_mm = working_distance;
  d.optics.projector_focus_mm = working_distance / std::cos(angle);
  d.Check();
  return d;
}

}  // namespace d3d
