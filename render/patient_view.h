// Cameras in patient space (LPS mm): the anatomical views in the radiological conventions, orbits
// relative to them, framing what the transfer function makes visible, and the conversion to the
// grid frame the renderers work in (volume/patient_frame.h).
#pragma once

#include <glm/glm.hpp>

#include <optional>
#include <string>
#include <vector>

#include "hybrid_octree/knot_source.h"
#include "hybrid_octree/volume_octree.h"
#include "render/camera.h"
#include "render/transfer_function.h"
#include "volume/patient_frame.h"
#include "volume/volume.h"

namespace hyb {

/// The six anatomical views. Anterior: the viewer faces the patient, superior up, so the
/// patient's left is on the image's right (as in a radiograph); posterior: from behind, left on
/// the left; left and right: from that side, superior up; superior (from above) and inferior (from
/// the feet, as axial images are read): anterior up.
enum class AnatomicalView { Anterior, Posterior, Left, Right, Superior, Inferior };

/// Parses "anterior" ... "inferior"; false for anything else.
bool parseAnatomicalView(const std::string& name, AnatomicalView* view);
/// The names parseAnatomicalView accepts, separated by '|'.
const char* anatomicalViewNames();

/// A view direction in patient space: the unit direction from the scene's centre to the eye, and
/// the image's up direction.
struct ViewDirection {
  glm::dvec3 toEye{0, -1, 0};
  glm::dvec3 up{0, 0, 1};
};
/// The direction of @p view.
ViewDirection viewDirection(AnatomicalView view);
/// An orbit relative to the anterior view: azimuth about the superior axis towards the patient's
/// left (90: the left view, 180: posterior, 270: right), elevation towards superior (degrees).
/// Superior is up; near the poles (|elevation| > 89°) up turns to stay continuous.
ViewDirection orbitDirection(double azimuthDeg, double elevationDeg);

/// A patient-space camera looking along −direction.toEye that frames @p points (patient mm)
/// in the image with @p margin of its half-extent free on the tighter side (perspective: the
/// distance at which every point lies inside the frustum, centred on their projection).
Camera fitCamera(const std::vector<glm::dvec3>& points, const ViewDirection& direction, const Camera::Lens& lens, double margin = 0.05);

/// Magnifies @p camera's image @p zoom times about its centre (a narrower field of view, or a
/// smaller orthographic height): the eye does not move.
void zoomCamera(Camera* camera, double zoom);

/// What the transfer function can make visible, in patient mm: the corners of the cells (8
/// samples) whose value range it gives an opacity or, with an isovalue, that the surface crosses,
/// enough of them to carry their convex hull (its vertices within each plane of samples). The
/// same anatomy stored in another order gives the same hull, hence the same fitCamera. Empty when
/// nothing is visible. The samples are read from @p knots where given (a paged scene), else from
/// @p volume; only those of the leaves whose range can be visible are read.
std::vector<glm::dvec3> visiblePoints(const Volume& volume, const VolumeOctree& octree, const TransferFunction& tf,
                                      std::optional<float> iso = std::nullopt, const KnotSource* knots = nullptr);

/// The grid-frame camera that sees what @p patientCamera sees in the patient.
Camera toGridCamera(const Camera& patientCamera, const PatientFrame& frame);

}  // namespace hyb
