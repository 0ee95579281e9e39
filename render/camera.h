// Pinhole and orthographic cameras in world millimetres.
#pragma once

#include <glm/glm.hpp>

#include <cmath>

namespace hyb {

/// Limits of a camera a user gives: coordinates within ±kMaxCameraMm of the patient origin (1 km;
/// beyond it depths overflow the renderers' float and slab arithmetic) and a field of view in
/// [kMinFovDeg, kMaxFovDeg).
inline constexpr double kMaxCameraMm = 1e6, kMinFovDeg = 0.1, kMaxFovDeg = 179.0;
/// Largest image edge, pixels: the renderers' float framebuffer of 16384² would take 4 GiB, more
/// than llvmpipe allocates.
inline constexpr int kMaxRenderEdge = 8192;

/// Whether every coordinate of @p p is finite and within ±kMaxCameraMm.
inline bool withinCameraRange(const glm::dvec3& p) {
  return glm::all(glm::lessThanEqual(glm::abs(p), glm::dvec3(kMaxCameraMm)));  // false for NaN
}

/// A camera looking from eye to center; pixel (0, 0) is the top-left corner. The renderers take it
/// in the grid frame; the user gives it in the patient's (render/patient_view.h converts).
struct Camera {
  glm::dvec3 eye{0, 0, 1}, center{0}, up{0, 1, 0};
  double fovDeg = 30.0;      ///< vertical field of view (perspective)
  bool ortho = false;
  double orthoHeight = 1.0;  ///< world height of the view (orthographic), mm
  int width = 512, height = 512;
  /// The image's right is −(forward × up) instead of forward × up: a camera set up in the patient
  /// looking at a grid stored left-handed there (the grid frame is then a mirror image of the
  /// patient's, and so must the camera be).
  bool mirrored = false;

  /// The projection and the image a camera is made for.
  struct Lens {
    double fovDeg = 30.0;
    bool ortho = false;
    int width = 512, height = 512;
  };
  /// Where an orbit looks from (azimuth about +z from −y, elevation towards +z, degrees) and through what lens.
  struct Orbit {
    double azimuthDeg = 0.0, elevationDeg = 0.0;
    Lens lens;
  };
  /// Camera around the box [lo, hi] (mm) at a distance where the box's bounding sphere fills the view.
  static Camera orbit(const glm::dvec3& lo, const glm::dvec3& hi, const Orbit& o);

  glm::dvec3 forward() const { return glm::normalize(center - eye); }
  /// The unit direction of the image's x axis (to the right).
  glm::dvec3 right() const {
    const glm::dvec3 r = glm::normalize(glm::cross(forward(), up));
    return mirrored ? -r : r;
  }
  /// The unit direction of the image's y axis (up), orthogonal to forward.
  glm::dvec3 trueUp() const { return glm::cross(glm::normalize(glm::cross(forward(), up)), forward()); }
  /// Whether any part of the box [lo, hi] (mm) may be seen: false only when all eight corners lie
  /// outside one side of the view frustum (the near side being the eye plane; ortho: no near side).
  bool seesBox(const glm::dvec3& lo, const glm::dvec3& hi) const;
  /// The size (mm) of a pixel at the nearest point of the box [lo, hi] to the eye.
  double pixelMmAt(const glm::dvec3& lo, const glm::dvec3& hi) const {
    if (ortho) return orthoHeight / height;
    return 2.0 * glm::length(eye - glm::clamp(eye, lo, hi)) * std::tan(glm::radians(fovDeg) * 0.5) / height;
  }
  /// Ray through the point (px, py) in pixel units (pixel centres at +0.5).
  void ray(double px, double py, glm::dvec3* origin, glm::dvec3* dir) const;
};

}  // namespace hyb
