// Patient space: where a volume's grid lies in the patient (DICOM PS3.3 C.7.6.2.1.1, ITK's image
// geometry). One convention inside the program: LPS, as DICOM and ITK use it (x towards the
// patient's left, y towards posterior, z towards superior), in millimetres. Readers convert their
// file's convention (NIfTI's and Slicer's RAS, say) into it; everything a user types or reads is in it.
//
// The grid frame is the renderers' and the octree's: voxel (i, j, k) at (i·sx, j·sy, k·sz) mm. A
// patient point is p = origin + direction · g for the grid point g, the direction's columns being
// the unit directions of the i, j and k axes. The direction is orthonormal, so the map is rigid
// (a rotation, or a rotation with a reflection where the grid is stored left-handed).
#pragma once

#include <glm/glm.hpp>

#include <string>

namespace hyb {

/// The index-to-patient transform of a volume, without its spacing (Volume keeps that).
struct PatientFrame {
  glm::dmat3 direction{1.0};  ///< columns: unit LPS directions of the i, j and k axes (orthonormal)
  glm::dvec3 origin{0.0};     ///< LPS position of voxel (0, 0, 0)'s centre, mm
  /// The file carries no orientation: direction and origin are its reader's convention (the grid's
  /// axes taken as LPS, or NIfTI's method 1), not where the patient lies.
  bool assumed = false;

  /// Patient (LPS mm) position of grid point @p grid (mm, voxel (i,j,k) at (i·sx, j·sy, k·sz)).
  glm::dvec3 toPatient(const glm::dvec3& grid) const { return origin + direction * grid; }
  /// Grid point (mm) of patient position @p patient.
  glm::dvec3 toGrid(const glm::dvec3& patient) const { return glm::transpose(direction) * (patient - origin); }
  /// A patient direction (or normal) in grid axes.
  glm::dvec3 vectorToGrid(const glm::dvec3& v) const { return glm::transpose(direction) * v; }
  /// A grid direction in patient axes.
  glm::dvec3 vectorToPatient(const glm::dvec3& v) const { return direction * v; }
  /// Whether the grid is stored left-handed in the patient (det direction = −1): a camera set up in
  /// the patient sees the grid mirrored.
  bool mirrored() const { return glm::determinant(direction) < 0.0; }
  /// Whether every axis runs along a patient axis (a permutation with flips, no rotation).
  bool axisAligned() const;
  bool operator==(const PatientFrame& o) const { return direction == o.direction && origin == o.origin; }
};

/// The three-letter code naming where each grid axis points, e.g. "LPS" (i towards the left, j
/// towards posterior, k towards superior: the identity) or "RAS"; "oblique (nearest XYZ)" when an
/// axis is more than 10⁻⁴ off a patient axis. The letters name the direction each index increases
/// towards, as DICOM's Patient Orientation and nibabel do; ITK's legacy SpatialOrientation names
/// (ITK_COORDINATE_ORIENTATION_RAI) and MetaImage's AnatomicalOrientation name the opposite ends.
std::string orientationCode(const glm::dmat3& direction);

/// The direction matrix of a code of three letters from {L,R,P,A,S,I}, one of each pair, naming
/// where each axis points (LPS: identity). False when @p code is not one.
bool directionFromCode(const std::string& code, glm::dmat3* direction);

/// A frame from a direction matrix read from a file: each column is normalised and the matrix is
/// made exactly orthonormal (headers print cosines to a few digits) when it is within 10⁻³ of it.
/// @throw ValueError naming @p what when a column is zero or not finite, or the axes are not
/// orthogonal (a sheared grid, such as a gantry tilt), with the angle between the worst pair.
PatientFrame makePatientFrame(const glm::dmat3& direction, const glm::dvec3& origin, const std::string& what);

/// Converts between RAS (NIfTI, Slicer) and LPS coordinates: negates x and y (its own inverse).
inline glm::dvec3 rasToLps(const glm::dvec3& v) { return {-v.x, -v.y, v.z}; }

}  // namespace hyb
