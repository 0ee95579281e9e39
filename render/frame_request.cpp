#include "render/frame_request.h"

#include <cmath>
#include <limits>

#include "render/patient_view.h"
#include "volume/core/error.h"

namespace hyb {

std::string View::validate() const {
  const Camera& c = camera;
  auto finite = [](const glm::dvec3& v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); };
  if (!finite(c.eye) || !finite(c.center) || !finite(c.up)) return "camera eye, center and up must be finite (patient mm)";
  if (glm::length(c.eye - c.center) == 0) return "camera eye and center must differ (the view direction runs from the eye to the center)";
  if (glm::length(glm::cross(c.center - c.eye, c.up)) == 0) return "camera up must be non-zero and not parallel to the view direction (eye to center)";
  if (c.width < 1 || c.height < 1 || c.width > kMaxRenderEdge || c.height > kMaxRenderEdge)
    return detail::concat("--size ", c.width, "x", c.height, " invalid (expected 1..", kMaxRenderEdge, " pixels each)");
  if (!(c.fovDeg >= kMinFovDeg && c.fovDeg < kMaxFovDeg)) return "the field of view (--fov, narrowed by --zoom) must be in [0.1, 179) degrees";
  if (!(std::isfinite(c.orthoHeight) && c.orthoHeight > 0)) return "camera orthographic height must be a finite positive size (mm)";
  return "";
}

std::string Look::validate() const {
  for (int k = 0; k < 4; ++k)
    if (!(surfaceColor[k] >= 0.0f && surfaceColor[k] <= 1.0f)) return "--surface-color components must be in [0, 1]";
  if (iso && !std::isfinite(*iso)) return "--iso must be a finite number";
  if (cut) {
    const glm::dvec3 p = cut->point, n = cut->normal;
    if (!(std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z) && std::isfinite(n.x) && std::isfinite(n.y) && std::isfinite(n.z)) ||
        glm::length(n) == 0.0)
      return "--cut needs a finite point and a finite non-zero normal (patient mm)";
  }
  if (voi) {
    if (!glm::all(glm::lessThan(voi->lo, voi->hi))) return "--voi box must have x0 < x1, y0 < y1, z0 < z1";
    if (!(std::isfinite(voi->inside) && voi->inside >= 0)) return "--voi-inside must be a finite factor >= 0";
    if (!(std::isfinite(voi->outside) && voi->outside >= 0)) return "--voi-outside must be a finite factor >= 0";
    if (!(std::isfinite(voi->ramp) && voi->ramp >= 0)) return "--voi-ramp must be a finite width >= 0 mm";
  }
  if (!(meshFilter == 0.0 || (meshFilter >= 1.0 && meshFilter <= 4.0))) return "--mesh-filter must be none or a box of 1 to 4 voxel cells";
  if (meshes.size() > size_t(kMaxUserMeshes)) return detail::concat("--mesh: ", meshes.size(), " meshes (expected at most ", kMaxUserMeshes, ")");
  for (const UserMesh& m : meshes) {
    if (!m.mesh) return "--mesh " + m.name + ": no mesh";
    for (int k = 0; k < 4; ++k)
      if (!(m.color[k] >= 0.0f && m.color[k] <= 1.0f)) return "--mesh " + m.name + ": colour components must be in [0, 1]";
  }
  return "";
}

std::string Quality::validate() const {
  if (!(epsilon >= 0 && epsilon <= double(std::numeric_limits<float>::max()))) return "--epsilon must be a finite value >= 0 within the float range (data units)";
  if (!(std::isfinite(budgetMb) && budgetMb >= 0)) return "--budget must be megabytes >= 0";
  if (!(std::isfinite(budgetPercent) && budgetPercent >= 0 && budgetPercent <= 100)) return "--budget percentage must be in (0, 100]";
  if (step && !(*step > 0.01 && *step <= 4)) return "--step must be in (0.01, 4] voxels";
  if (progressive < 1 || progressive > 8) return "--progressive must be in 1..8 images";
  if (!(std::isfinite(adaptive) && adaptive >= 0 && adaptive <= 255)) return "--adaptive must be a colour difference in [0, 255] (units of 1/255)";
  if (adaptive > 0 && renderer != Renderer::Raycast) return "--adaptive needs --renderer raycast (Levoy's adaptive refinement of the reference's rays)";
  if (focus && !(std::isfinite(focus->x) && std::isfinite(focus->y) && std::isfinite(focus->z))) return "--focus must be three finite coordinates";
  if (!(std::isfinite(surfaceErrorPixels) && surfaceErrorPixels >= 0)) return "surface error must be a finite number of pixels >= 0";
  if (!(imageScale > 0.0 && imageScale <= 1.0)) return "--image-scale must be in (0, 1] (a fraction of the image's size)";
  if (imageScale < 1.0 && rows) return "--image-scale cannot render a band of rows";
  if (region && (progressive > 1 || adaptive > 0)) return "a region of a sort-last frame cannot be rendered progressively (--progressive, --adaptive)";
  SelectionParams limits;  // the selection's own checks: the brick edge and the screen-space stop
  limits.maxBrickEdge = maxBrickEdge;
  limits.lodPixels = lodPixels;
  return limits.validate();
}

void validateFrame(const View& view, const Look& look, const Quality& quality) {
  for (const std::string& problem : {view.validate(), look.validate(), quality.validate()})
    if (!problem.empty()) throw ValueError(problem);
}

FrameGrid frameGrid(const View& view, const Look& look, const PatientFrame& frame) {
  FrameGrid g{toGridCamera(view.camera, frame), std::nullopt, look.voi};
  if (look.cut) g.cut = CutPlane{frame.toGrid(look.cut->point), frame.vectorToGrid(look.cut->normal)};
  if (g.voi) {
    g.voi->toBox = frame.direction;
    g.voi->offset = frame.origin;
  }
  return g;
}

}  // namespace hyb
