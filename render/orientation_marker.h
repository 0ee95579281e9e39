// The orientation marker: a triad of the patient's axes in a corner of the image, each labelled
// at both ends (L/R, P/A, S/I), drawn with the camera's rotation so that a reader sees at once
// where the patient's left, anterior and superior lie in the picture.
#pragma once

#include <glm/glm.hpp>

#include <array>

#include "render/camera.h"
#include "render/image.h"

namespace hyb {

/// Where one end of one axis of the marker lands.
struct MarkerLabel {
  char letter;         ///< L R P A S I
  glm::dvec2 pixel;    ///< image position of the label's centre (x right, y down)
  double depth;        ///< towards the viewer (< 0) or away from it (> 0), in units of the axis length
};

/// The six labels of the marker for the patient-space camera @p patientCamera, the triad centred
/// in the image's lower-left corner.
std::array<MarkerLabel, 6> markerLabels(const Camera& patientCamera);

/// Draws the marker into @p image (opaque lines and letters, premultiplied), the far ends first.
void drawOrientationMarker(const Camera& patientCamera, Image* image);

}  // namespace hyb
