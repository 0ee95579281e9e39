#include "render/selection_policy.h"

#include <cmath>

namespace hyb {

BrickImageError& ViewErrors::get() {
  if (!mErrors)
    mErrors = std::make_unique<BrickImageError>(mVolume, mOctree, mTf, mCamera,
                                                BrickErrorClipping{mCut ? mCut->keptSide(mCamera) : glm::dvec4(0, 0, 0, 1), mVoi, mKnots});
  return *mErrors;
}

SelectionParams viewSelectionParams(const Volume& volume, const ViewShown& shown, const SelectionChoice& choice, ViewErrors* errors) {
  const TransferFunction& tf = shown.tf;
  const Camera& camera = shown.camera;
  const CutPlane* cut = shown.cut;
  const VolumeOfInterest* voi = shown.voi;
  SelectionParams params;
  params.epsilon = float(choice.epsilon);
  params.spacing = volume.spacing();
  params.maxBrickEdge = choice.maxBrickEdge;
  params.focus = choice.focus;
  params.eye = camera.eye;
  params.texelBudget = choice.texelBudget;
  params.blend = choice.blend;
  const TransferFunction* f = &tf;
  const Camera* c = &camera;
  params.opacity = [f](float lo, float hi) { return f->maxAlpha(lo, hi); };
  params.distortion = [f](float lo, float hi, float error) { return f->distortion(lo, hi, error); };
  // LaMar's screen-space stop: the size of a pixel at a box's nearest point.
  params.lodPixels = choice.lodPixels;
  params.pixelSize = [c](const glm::dvec3& lo, const glm::dvec3& hi) { return c->pixelMmAt(lo, hi); };
  // Within a budget, texels go where they change this image most (measured per brick, on first use).
  if (errors) {
    params.brickError = [errors](uint32_t node, int p) { return errors->get()(node, p); };
    params.prefetchBrickErrors = [errors](const std::vector<std::pair<uint32_t, int>>& bricks) { errors->get().prefetch(bricks); };
  }
  // Frustum culling, nodes wholly on the removed side of the cutting plane, and nodes the volume
  // of interest scales to zero opacity.
  const glm::dvec4 kept = cut ? cut->keptSide(camera) : glm::dvec4(0, 0, 0, 1);
  params.inView = [c, kept, voi](const glm::dvec3& lo, const glm::dvec3& hi) {
    const glm::dvec3 far = glm::mix(lo, hi, glm::dvec3(glm::greaterThan(glm::dvec3(kept), glm::dvec3(0.0))));
    return glm::dot(glm::dvec3(kept), far) + kept.w >= 0.0 && c->seesBox(lo, hi) && !(voi && voi->hides(lo, hi));
  };
  return params;
}

}  // namespace hyb
