// A stack of image planes (a DICOM series, a NIfTI image whose sform is sheared) put on the
// regular orthogonal grid the octrees and renderers need. Planes that are evenly spaced along
// their normal and lie on one line along it are the grid as they are. Otherwise (a gantry tilt
// moves each plane across the image plane; helical or multi-block acquisitions space them
// unevenly) every plane of an orthogonal grid is interpolated from the two source planes around
// it, each sampled where the output voxels lie in it, as dcm2niix's tilt correction and 3D
// Slicer's acquisition-geometry regularization do: anatomy lands where the positions put it.
#pragma once

#include <glm/glm.hpp>

#include <memory>
#include <string>
#include <vector>

#include "volume/patient_frame.h"
#include "volume/plane_source.h"

namespace hyb {

/// Planes sharing one size, pixel spacing and orientation, each at its own position.
struct PlaneStack {
  glm::dmat3 axes{1.0};            ///< columns: the rows' direction (i), the columns' (j) and their normal (k); orthonormal
  glm::dvec2 pixelSpacing{1.0};    ///< mm between columns (along i), between rows (along j)
  glm::ivec2 size{0};              ///< columns, rows
  std::vector<glm::dvec3> origins; ///< LPS mm of each plane's first pixel, in increasing depth along the normal
  std::vector<std::string> names;  ///< each plane's file (and frame), for messages
  double singleSpacing = 1.0;      ///< the spacing along the normal of a stack of one plane (its thickness)
};

/// The regular orthogonal grid a stack is drawn on, and how each of its planes is made.
struct StackGrid {
  glm::ivec3 dims{0};
  glm::dvec3 spacing{1.0};
  PatientFrame frame;
  bool resampled = false;  ///< false: the stack's planes are the grid's, as they are
  /// Output plane k from source planes a and b: (1 − t)·a + t·b, each sampled at the output's pixel
  /// (i, j) shifted by its shift (pixels) within its own plane.
  struct Plane {
    int a = 0, b = 0;
    double t = 0.0;
    glm::dvec2 shiftA{0.0}, shiftB{0.0};
  };
  std::vector<Plane> planes;
  std::vector<std::string> warnings;  ///< what was resampled, and why
};

/// The grid of @p stack. When its planes are evenly spaced along the normal (steps within 1 % and
/// 1 µm of their mean) and every position lies on the line through the first along the normal
/// (within 10 µm and 10⁻³ of the distance), the stack is the grid. Otherwise the grid keeps the
/// planes' axes and pixel lattice, grows across the image plane to hold every plane (the shift
/// of the last over the first), and is spaced along the normal by the smallest step that occurs
/// at least twice (within 1 %), else by the median step; a warning names the tilt angle (with
/// @p tiltNote, what the file says of it) or the range of steps.
/// @throw IoError naming @p what and the two planes around a missing one: a step more than 1.75
///        times the steps beside it (a missing slice is never interpolated across); or two planes
///        at one depth.
StackGrid stackGrid(const PlaneStack& stack, const std::string& what, const std::string& tiltNote = "");

/// @p source's planes (in the stack's order: its description's planes are the stack's) drawn on
/// @p grid, interpolated linearly between planes and bilinearly within them, integer samples
/// rounded to the nearest; what lies outside every source plane takes the smallest value of the
/// first source plane. Reads @p source once, forward, holding two of its planes: memory does not
/// follow the volume. @p source itself when the grid is the stack's.
std::unique_ptr<PlaneSource> resampledPlanes(std::unique_ptr<PlaneSource> source, StackGrid grid);

namespace detail {
/// Every plane of @p source read into one volume (its description with the samples).
Volume readAllPlanes(PlaneSource& source);
/// The planes of a volume read whole, which the source keeps alive.
std::unique_ptr<PlaneSource> planesOwning(std::shared_ptr<const Volume> volume, const std::string& name);
}  // namespace detail

}  // namespace hyb
