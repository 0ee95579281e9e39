#include "render/scene_renderer.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <limits>
#include <unordered_set>
#include <utility>

#include "hybrid_octree/coarse_surface.h"
#include "hybrid_octree/surface_octree.h"
#include "render/patient_view.h"
#include "render/raycast_interactive.h"
#include "surface/mesh_ops.h"
#include "surface/mesh_simplify.h"
#include "volume/core/error.h"
#include "volume/core/parallel.h"

namespace hyb {

namespace {

using Clock = std::chrono::steady_clock;
double msSince(Clock::time_point t0) { return std::chrono::duration<double, std::milli>(Clock::now() - t0).count(); }

bool sameCamera(const Camera& a, const Camera& b) {
  return a.eye == b.eye && a.center == b.center && a.up == b.up && a.fovDeg == b.fovDeg && a.ortho == b.ortho &&
         a.orthoHeight == b.orthoHeight && a.width == b.width && a.height == b.height && a.mirrored == b.mirrored;
}
bool sameTf(const TransferFunction& a, const TransferFunction& b) {
  const auto &p = a.points(), &q = b.points();
  if (p.size() != q.size()) return false;
  for (size_t i = 0; i < p.size(); ++i)
    if (p[i].value != q[i].value || p[i].color != q[i].color || p[i].alpha != q[i].alpha) return false;
  return true;
}
bool sameCut(const std::optional<CutPlane>& a, const std::optional<CutPlane>& b) {
  return a.has_value() == b.has_value() && (!a || (a->point == b->point && a->normal == b->normal));
}
bool sameVoi(const std::optional<VolumeOfInterest>& a, const std::optional<VolumeOfInterest>& b) {
  return a.has_value() == b.has_value() &&
         (!a || (a->lo == b->lo && a->hi == b->hi && a->inside == b->inside && a->outside == b->outside && a->ramp == b->ramp &&
                 a->toBox == b->toBox && a->offset == b->offset));
}

}  // namespace

// An isosurface as the renderers take it: the Surface Octree (the scene's, or built), its polygons
// triangulated (grid mm), with gradient normals made on first use, and a BVH for the reference.

// The image errors of the last view, with the inputs they were measured for.
struct SceneRenderer::Errors {
  Camera camera;
  TransferFunction tf;
  std::optional<CutPlane> cut;
  std::optional<VolumeOfInterest> voi;
  std::unique_ptr<ViewErrors> errors;
};

SceneRenderer::SceneRenderer(Scene scene, const Options& options) : mScene(std::move(scene)), mOptions(options) {
  HYB_CHECK(mScene.volume.hasSamples() || mScene.knots);
  setCacheBound();  // (the brick textures it may keep count from the start)
}

SceneRenderer::~SceneRenderer() {
  if (mGl) mGl->makeCurrent();  // the textures and programs are deleted in their own context
}

void SceneRenderer::prepareTarget(int width, int height) {
  if (!mGl) return;
  mGl->makeCurrent();  // (another renderer's may be)
  mTargets.prepare(width, height, *mGl);
}

void SceneRenderer::ensureGl() {
  if (!mGl) mGl.emplace();
  mGl->makeCurrent();  // another renderer's context may have been made (or destroyed) since
  if (!mTextures) mTextures = std::make_unique<BrickTextureCache>(mOptions.textureLimitBytes);
}

const PreIntegrationTable& SceneRenderer::preintegration(const TransferFunction& tf, double minMm, double maxMm, FrameStats* st) {
  const bool kept = mPreintegration && sameTf(tf, mPreintegrationTf);
  if (!(kept && mPreintegration->covers(minMm, maxMm))) {
    // A frame that needs other layers keeps the ones made before too (a hair inside their
    // thicknesses, so that rounding adds no layer).
    if (kept) {
      minMm = std::min(minMm, PreIntegrationTable::layerMm(mPreintegration->firstLayer()) * (1.0 + 1e-9));
      maxMm = std::max(maxMm, PreIntegrationTable::layerMm(mPreintegration->firstLayer() + mPreintegration->layers() - 1) * (1.0 - 1e-9));
    }
    mPreintegration = std::make_unique<PreIntegrationTable>(preintegrationFor(tf, volume().minValue(), volume().maxValue(), minMm, maxMm));
    mPreintegrationTf = tf;
    st->preintegrationMs = mPreintegration->buildMs();
  }
  return *mPreintegration;
}

void SceneRenderer::dropTextures() {
  if (!mTextures) return;
  mGl->makeCurrent();
  mTextures->clear();
}

namespace {

// The distance, mm, of @p stepVoxels smallest voxel spacings of @p v (a renderer's sample spacing).
double stepMm(const Volume& v, double stepVoxels) { return stepVoxels * std::min({v.spacing().x, v.spacing().y, v.spacing().z}); }

// The error of simplified level @p k: 2^k of the smallest voxel edge.
double simplifiedErrorMm(const glm::dvec3& spacing, int k) { return double(1 << k) * std::min({spacing.x, spacing.y, spacing.z}); }

// Tells @p reserve what a surface being made will hold, and 0 once it is made or stopped.
class Reservation {
 public:
  Reservation(const std::function<void(uint64_t)>& reserve, uint64_t bytes) : mReserve(reserve) {
    if (mReserve) mReserve(bytes);
  }
  ~Reservation() {
    if (mReserve) mReserve(0);
  }
  Reservation(const Reservation&) = delete;
  Reservation& operator=(const Reservation&) = delete;

 private:
  const std::function<void(uint64_t)>& mReserve;
};

}  // namespace

int simplifiedLevelCount(const glm::ivec3& dims, const glm::dvec3& spacing) {
  const glm::dvec3 extent = glm::dvec3(dims) * spacing;
  const double longestMm = std::max({extent.x, extent.y, extent.z});
  int k = kSimplifiedLevels - 1;  // the coarsest level
  while (k < 20 && simplifiedErrorMm(spacing, k) * kCoarsestLevelFraction < longestMm) ++k;
  return k + 1;
}

std::vector<TriangleMesh> SceneRenderer::simplifiedLevels(const Scene& scene, const TriangleMesh& smooth, const Progress* progress,
                                                         const std::function<void(uint64_t)>& reserve) {
  const Reservation reserved(reserve, kSimplifyBytesPerTriangle * uint64_t(smooth.triangles.size()));
  const glm::dvec3 spacing = scene.volume.spacing();
  std::vector<TriangleMesh> levels;
  const int count = simplifiedLevelCount(scene.volume.dims(), spacing);
  for (int k = 0; k < count; ++k) {
    // Level k from level k − 1 within what its error adds: errors add up to level k's.
    const double step = simplifiedErrorMm(spacing, k) - (k == 0 ? 0.0 : simplifiedErrorMm(spacing, k - 1));
    levels.push_back(simplifyWithinBlocks(k == 0 ? smooth : levels.back(), double(kSimplifiedBlockVoxels << k) * spacing, step, progress));
    setSceneNormals(scene, &levels.back());
  }
  return levels;
}

std::unique_ptr<PreparedSurface> SceneRenderer::prepareSurface(const Scene& scene, float iso, const Progress* progress, FrameStats* stats,
                                                              const std::function<void(uint64_t)>& reserve) {
  // The Surface Octree (the scene's when it matches), its polygons triangulated, shaded by the gradient;
  // a paged scene's samples are read through its cache a leaf at a time, never whole, so a
  // viewer's builder thread may read them while the scene's frames draw.
  auto s = std::make_unique<PreparedSurface>();
  s->iso = iso;
  s->exact = true;
  const bool fromScene = scene.surface && scene.surface->isovalue() == iso;
  auto t0 = Clock::now();
  if (!fromScene) {
    s->built = sceneSurface(scene, iso, progress);
    if (stats) {
      stats->surfaceBuilt = true;
      stats->surfaceBuildMs = msSince(t0);
    }
  }
  t0 = Clock::now();
  const SurfaceOctree& octree = fromScene ? *scene.surface : *s->built;
  const Reservation reserved(reserve, octree.reconstructBytes());
  const DiscreteMesh d = octree.reconstruct(0, progress);
  s->polygons = d.faceCount();
  auto smooth = std::make_shared<TriangleMesh>(fineMeshToTriangles(d, scene.volume.spacing()));
  setSceneNormals(scene, smooth.get());
  s->smooth = std::move(smooth);
  if (stats) stats->surfacePolygonsMs = msSince(t0);
  return s;
}

size_t PreparedSurface::bytesUsed() const {
  size_t n = (smooth ? smooth->bytesUsed() : 0) + facet.bytesUsed() + (built ? built->bytesUsed() : 0);
  for (const TriangleMesh& m : simplified) n += m.bytesUsed();
  for (const auto& [s, m] : coarse) n += m.bytesUsed();
  return n;
}

size_t SceneRenderer::surfaceBytes() const {
  size_t n = mRegions.bytes();
  for (const auto& s : mSurfaces) n += s->bytesUsed();
  return n;
}

void SceneRenderer::boundCache() {
  mKeptBytes = surfaceBytes();
  setCacheBound();
}

std::function<void(uint64_t)> SceneRenderer::surfaceReservation() {
  auto held = std::make_shared<uint64_t>(0);  // this reservation's part of mReservedBytes
  return [this, held](uint64_t bytes) {
    mReservedBytes += bytes;  // (added before the old part goes: the sum never wraps)
    releaseSurfaceBytes(std::exchange(*held, bytes));
  };
}

void SceneRenderer::holdSurfaceBytes(uint64_t bytes) {
  mReservedBytes += bytes;
  setCacheBound();
}

void SceneRenderer::releaseSurfaceBytes(uint64_t bytes) {
  HYB_CHECK(mReservedBytes >= bytes);
  mReservedBytes -= bytes;
  setCacheBound();
}

void SceneRenderer::setCacheBound() {
  if (!mScene.knots || mOptions.memoryBytes == 0) return;
  // Each caller stores its count before locking, so the last to set the bound sees both counts.
  uint64_t freed = 0;
  {
    const std::lock_guard lock(mBoundMutex);
    const uint64_t octrees = mScene.octree.bytesUsed() + (mScene.surface ? mScene.surface->bytesUsed() : 0);
    // The brick textures kept between frames count at their bound: llvmpipe holds them in this
    // process's memory, and the cache's bound does not then move with every frame.
    const uint64_t textures = mOptions.keepTextures ? mOptions.textureLimitBytes : 0;
    freed = mScene.knots->setCacheLimit(sceneCacheBytes(mOptions.memoryBytes, octrees + textures + mKeptBytes + mReservedBytes));
  }
  KnotStore::giveBackFreed(freed);  // (not under the lock: the other thread would wait for the trim)
}

PreparedSurface& SceneRenderer::keep(std::unique_ptr<PreparedSurface> surface) {
  // One entry an isovalue: what is kept of it stays, the clustered surfaces joined.
  const auto it = std::find_if(mSurfaces.begin(), mSurfaces.end(), [&](const auto& s) { return s->iso == surface->iso; });
  if (it != mSurfaces.end()) {
    if ((*it)->exact && !surface->exact) std::swap(surface, *it);
    surface->coarse.merge((*it)->coarse);
    if (surface->simplified.empty()) surface->simplified = std::move((*it)->simplified);
    mSurfaces.erase(it);
  }
  mSurfaces.push_front(std::move(surface));
  trimSurfaces();
  return *mSurfaces.front();
}

void SceneRenderer::pinSurfaces(std::vector<float> isos) {
  mPinned = std::move(isos);
  trimSurfaces();
}

// The pinned surfaces and two others are kept: a user flipping between two isovalues rebuilds neither.
void SceneRenderer::trimSurfaces() {
  int unpinned = 0;
  std::erase_if(mSurfaces, [&](const auto& s) { return std::find(mPinned.begin(), mPinned.end(), s->iso) == mPinned.end() && ++unpinned > 2; });
  boundCache();
}

void SceneRenderer::adoptSurface(std::unique_ptr<PreparedSurface> surface) { keep(std::move(surface)); }

PreparedSurface& SceneRenderer::entry(float iso) {
  const auto it = std::find_if(mSurfaces.begin(), mSurfaces.end(), [&](const auto& s) { return s->iso == iso; });
  if (it != mSurfaces.end()) {
    mSurfaces.splice(mSurfaces.begin(), mSurfaces, it);
    return *mSurfaces.front();
  }
  auto s = std::make_unique<PreparedSurface>();
  s->iso = iso;
  return keep(std::move(s));
}

PreparedSurface& SceneRenderer::surfaceEntry(float iso, FrameStats* stats) {
  PreparedSurface& s = entry(iso);
  return s.exact ? s : keep(prepareSurface(mScene, iso, mOptions.progress, stats, surfaceReservation()));
}

const TriangleMesh& SceneRenderer::coarseSurface(float iso, int s, FrameStats* stats) {
  HYB_CHECK(s >= 2);
  for (const auto& e : mSurfaces)
    if (e->iso == iso && e->coarse.count(s)) return entry(iso).coarse.at(s);  // (entry() makes it the most recent)
  // Made before its entry: a build that stops leaves no empty entry behind.
  const auto t0 = Clock::now();
  const Volume& v = mScene.volume;
  TriangleMesh mesh = v.hasSamples() ? clusteredSurface(VolumeKnots(v, mScene.octree), mScene.octree, s, iso, mOptions.progress)
                                     : clusteredSurface(*mScene.knots, mScene.octree, s, iso, mOptions.progress);
  if (stats) {
    stats->surfaceBuilt = true;
    stats->surfaceBuildMs = msSince(t0);
  }
  return entry(iso).coarse.emplace(s, std::move(mesh)).first->second;
}

const TriangleMesh& SceneRenderer::surface(float iso, SurfaceNormals normals) {
  const TriangleMesh& mesh = surfaceEntry(iso, nullptr).mesh(normals);
  boundCache();
  return mesh;
}

double SceneRenderer::nearestPixelMm(const Camera& gridCamera) const {
  return gridCamera.pixelMmAt(glm::dvec3(0.0), glm::dvec3(volume().dims() - 1) * volume().spacing());
}

int SceneRenderer::surfaceSpacing(const Camera& gridCamera, const Quality& quality) const {
  if (quality.renderer != Renderer::Slices || quality.lodPixels <= 0.0 || quality.simplifiedSurface) return 1;
  return clusterSpacingFor(quality.lodPixels * nearestPixelMm(gridCamera), volume().spacing(), octree().leafEdge());
}

int SceneRenderer::drawnSpacing(const Camera& gridCamera, const Quality& quality, float iso) const {
  const int s = surfaceSpacing(gridCamera, quality);
  if (quality.waitForSurface || quality.renderer != Renderer::Slices) return s;
  const auto it = std::find_if(mSurfaces.begin(), mSurfaces.end(), [&](const auto& e) { return e->iso == iso; });
  if (it == mSurfaces.end()) return 0;
  const PreparedSurface& e = **it;
  // A moving frame draws the preview while the builder simplifies the surface for it.
  if (s == 1 && e.exact && quality.simplifiedSurface && e.simplified.empty() && !e.coarse.empty()) return e.coarse.begin()->first;
  if ((s == 1 && e.exact) || e.coarse.count(s)) return s;
  if (e.exact) return 1;  // finer than asked: it only costs the triangles between pixel centres
  return e.coarse.empty() ? 0 : e.coarse.begin()->first;
}

FrameStats SceneRenderer::prepare(const View& view, const Look& look, const Quality& quality) {
  FrameStats st;
  if (!look.iso) return st;
  const Camera gridCamera = toGridCamera(view.camera, volume().frame());
  if (byRegions(gridCamera, quality, *look.iso)) return st;  // the frame reconstructs what it draws
  const int spacing = drawnSpacing(gridCamera, quality, *look.iso);
  if (spacing > 0) prepareAt(*look.iso, spacing, look.normals, &st);
  return st;
}

const TriangleMesh& SceneRenderer::prepareAt(float iso, int s, SurfaceNormals normals, FrameStats* st) {
  st->surfaceSpacing = s;
  if (s > 1) {
    const TriangleMesh& mesh = coarseSurface(iso, s, st);
    st->surfaceTriangles = mesh.triangles.size();
    return mesh;
  }
  PreparedSurface& e = surfaceEntry(iso, st);
  st->surfacePolygons = e.polygons;
  st->surfaceTriangles = e.mesh(normals).triangles.size();
  return e.mesh(normals);
}

size_t SceneRenderer::surfacePolygons(float iso) const {
  for (const auto& s : mSurfaces)
    if (s->iso == iso && s->exact) return s->polygons;
  return 0;
}

std::vector<float> SceneRenderer::surfaceIsos() const {
  std::vector<float> isos;
  for (const auto& s : mSurfaces) isos.push_back(s->iso);
  return isos;
}

bool SceneRenderer::hasAnySurface(float iso) const {
  return std::any_of(mSurfaces.begin(), mSurfaces.end(), [&](const auto& s) { return s->iso == iso && (s->exact || !s->coarse.empty()); });
}

std::shared_ptr<const TriangleMesh> SceneRenderer::unsimplified(float iso) const {
  for (const auto& s : mSurfaces)
    if (s->iso == iso && s->exact && s->simplified.empty()) return s->smooth;
  return nullptr;
}

bool SceneRenderer::hasSurface(float iso) const {
  return std::any_of(mSurfaces.begin(), mSurfaces.end(), [&](const auto& s) { return s->iso == iso && s->exact; });
}

ViewErrors& SceneRenderer::viewErrors(const Camera& gridCamera, const TransferFunction& tf, const std::optional<CutPlane>& cut,
                                      const std::optional<VolumeOfInterest>& voi, bool anyCamera) {
  if (mErrors && (anyCamera || sameCamera(mErrors->camera, gridCamera)) && sameTf(mErrors->tf, tf) && sameCut(mErrors->cut, cut) &&
      sameVoi(mErrors->voi, voi))
    return *mErrors->errors;
  mErrors = std::make_unique<Errors>(Errors{gridCamera, tf, cut, voi, nullptr});
  Errors& e = *mErrors;
  e.errors = std::make_unique<ViewErrors>(mScene.volume, mScene.octree, ViewShown{e.tf, e.camera, e.cut ? &*e.cut : nullptr, e.voi ? &*e.voi : nullptr},
                                          mScene.knots.get());
  return *e.errors;
}

size_t SceneRenderer::drawResident(const Camera& camera, uint64_t packTexels, Selection* selection) {
  KnotStore* store = mScene.knots.get();
  const VolumeOctree& octree = mScene.octree;
  const int readAnyway = store ? store->coarseSpacing(mOptions.readAnywayBytes) : 0;
  const BrickTextureCache* textures = mOptions.keepTextures ? mTextures.get() : nullptr;
  const glm::dvec3 spacing = mScene.volume.spacing();
  auto distance = [&](const Brick& b) {
    glm::ivec3 lo, hi;
    octree.voxelBox(octree.nodes()[b.node], &lo, &hi);
    return glm::length(glm::clamp(camera.eye, glm::dvec3(lo) * spacing, glm::dvec3(hi) * spacing) - camera.eye);
  };
  auto kept = [&](const Brick& b) { return textures && textures->contains(b); };
  auto knotsAtHand = [&](const Brick& b) {
    if (!store) return true;
    const std::vector<KnotBox> boxes = brickKnotBoxes(octree, b);
    return std::all_of(boxes.begin(), boxes.end(), [&](const KnotBox& k) { return k.s >= readAnyway || store->cached(k); });
  };
  // The selection's bricks this frame packs, nearest the eye first, within packTexels (the nearest
  // always: every frame makes progress); the others wait. The coarser bricks drawn instead of them
  // are not bounded (each has an eighth of the texels or fewer): were they, the root would end up
  // drawing the whole volume.
  auto key = [](const Brick& b) { return uint64_t(b.node) << 8 | uint64_t(b.p); };
  std::unordered_set<uint64_t> waiting;
  if (packTexels > 0) {
    std::vector<const Brick*> toPack;
    for (const Brick& b : selection->bricks)
      if (!b.hidden && !kept(b) && knotsAtHand(b)) toPack.push_back(&b);
    std::stable_sort(toPack.begin(), toPack.end(), [&](const Brick* a, const Brick* b) { return distance(*a) < distance(*b); });
    uint64_t packed = 0;
    for (const Brick* b : toPack) {
      if (packed > 0 && packed + b->texelCount() > packTexels)
        waiting.insert(key(*b));
      else
        packed += b->texelCount();
    }
  }
  auto resident = [&](const Brick& b) { return kept(b) || (!waiting.contains(key(b)) && knotsAtHand(b)); };
  std::vector<Brick> missing;
  *selection = residentSelection(octree, *selection, resident, &missing);
  if (store) {
    // Coarse lattices first (a frame soon after draws them if the fine ones are not in yet), then
    // the nearest to the eye.
    auto spacingOf = [&](const Brick& b) { return octree.edge(octree.nodes()[b.node]) >> b.p; };
    std::stable_sort(missing.begin(), missing.end(), [&](const Brick& a, const Brick& b) {
      return spacingOf(a) != spacingOf(b) ? spacingOf(a) > spacingOf(b) : distance(a) < distance(b);
    });
    std::vector<KnotBox> boxes;
    for (const Brick& b : missing)
      for (const KnotBox& k : brickKnotBoxes(octree, b)) boxes.push_back(k);
    store->prefetch(boxes);  // (also when empty: what an earlier view asked for is not needed now)
  }
  return missing.size();
}

SelectionParams SceneRenderer::selectionParams(const FrameGrid& g, const Look& look, const Quality& quality, FrameStats* st) {
  const Volume& v = mScene.volume;
  SelectionChoice choice;
  choice.epsilon = quality.epsilon;
  if (quality.focus) choice.focus = v.frame().toGrid(*quality.focus);
  choice.maxBrickEdge = quality.maxBrickEdge;
  choice.blend = quality.blend;
  choice.lodPixels = quality.lodPixels;
  ViewErrors& errors = viewErrors(g.camera, look.tf, g.cut, g.voi, quality.reuseViewErrors);
  auto paramsOf = [&](const SelectionChoice& c) {
    return viewSelectionParams(v, {look.tf, g.camera, g.cut ? &*g.cut : nullptr, g.voi ? &*g.voi : nullptr}, c, &errors);
  };
  if (quality.budgetPercent > 0.0) {
    // A percentage is of this view's full-resolution texels (every visible brick exact), at least one.
    SelectionChoice full = choice;
    full.epsilon = 0.0;
    st->fullTexels = selectNodes(mScene.octree, paramsOf(full)).texels;
    choice.texelBudget = std::max<uint64_t>(1, uint64_t(quality.budgetPercent / 100.0 * double(st->fullTexels)));
  } else if (quality.budgetMb > 0.0) {
    // A budget beyond 2^62 texels limits nothing (and would overflow the count): unlimited.
    const double texels = quality.budgetMb * 1024.0 * 1024.0 / double(bytesPerTexel(quality.texelBits));
    if (texels < 1.0) HYB_THROW(ValueError, "--budget ", quality.budgetMb, " MB is smaller than one texel");
    choice.texelBudget = texels < 0x1p62 ? uint64_t(texels) : 0;
  }
  st->budgetTexels = choice.texelBudget;
  SelectionParams params = paramsOf(choice);
  if (const GeometryChannel* geometry = frameGeometry(look, st)) {
    // A brick holding geometry is drawn, and at full resolution unless ε_u reaches the data's range.
    params.holdsChannel = [geometry](uint32_t node) { return geometry->holds(node); };
    params.channelError = std::max(v.maxValue() - v.minValue(), std::numeric_limits<float>::min());
  }
  return params;
}

Selection SceneRenderer::select(const View& view, const Look& look, const Quality& quality) {
  validateFrame(view, look, quality);
  FrameStats st;
  return selectNodes(mScene.octree, selectionParams(frameGrid(view, look, volume().frame()), look, quality, &st));
}

SceneRenderer::SortLast SceneRenderer::sortLast(const View& view, const Look& look, const Quality& quality, int parts) {
  Quality whole = quality;
  whole.region.reset();
  whole.selection.reset();
  if (quality.renderer == Renderer::Raycast) {  // bricks to balance the regions by, not to draw: no budget to measure
    whole.budgetMb = 0.0;
    whole.budgetPercent = 0.0;
  }
  SortLast out{select(view, look, whole), {}, {}};
  out.regions = splitSelection(mScene.octree, volume().spacing(), out.selection, parts);
  const Camera c = frameGrid(view, look, volume().frame()).camera;
  const glm::dvec3 forward = glm::normalize(c.center - c.eye);
  out.frontToBack = out.regions.frontToBack(c.ortho ? c.eye - forward * 1e9 * glm::length(volume().extentMm()) : c.eye);
  return out;
}

RenderedFrame SceneRenderer::render(const View& view, const Look& look, const Quality& quality, const LevelCallback& onLevel) {
  validateFrame(view, look, quality);
  if (quality.rows) {
    const glm::ivec2 rows = *quality.rows;
    if (!(rows.x >= 0 && rows.x < rows.y && rows.y <= view.camera.height))
      HYB_THROW(ValueError, "rows ", rows.x, "..", rows.y, " invalid (expected 0 <= first < last <= ", view.camera.height, ")");
    if (quality.progressive > 1 || quality.adaptive > 0) HYB_THROW(ValueError, "a band of rows cannot be rendered progressively");
  }
  if (quality.imageScale < 1.0) {
    // Rendered smaller, then magnified: each image of a progressive frame too.
    const int W = view.camera.width, H = view.camera.height;
    View small = view;
    small.camera.width = std::max(1, int(std::lround(W * quality.imageScale)));
    small.camera.height = std::max(1, int(std::lround(H * quality.imageScale)));
    Quality whole = quality;
    whole.imageScale = 1.0;
    LevelCallback magnified;
    if (onLevel) magnified = [&](int level, int levels, const Image& image, const FrameStats& st) { onLevel(level, levels, resampled(image, W, H), st); };
    RenderedFrame f = render(small, look, whole, magnified);
    const auto t0 = Clock::now();
    f.image = resampled(f.image, W, H);
    f.stats.renderMs += msSince(t0);
    return f;
  }
  if (quality.region && !look.meshes.empty()) HYB_THROW(ValueError, "--mesh: user meshes are not drawn by sort-last frames (MPI ranks)");
  RenderedFrame out;
  out.stats.renderer = quality.renderer;
  const FrameGrid g = frameGrid(view, look, volume().frame());
  const TriangleMesh* mesh = look.iso ? frameSurface(g, look, quality, &out.stats) : nullptr;
  if (mesh && quality.region) mesh = &regionSurface(*mesh, *quality.region);
  if (quality.renderer == Renderer::Raycast)
    renderRaycast(g, look, quality, mesh, onLevel, &out);
  else
    renderSlicesFrame(g, look, quality, mesh, onLevel, &out);
  return out;
}

const TriangleMesh& SceneRenderer::regionSurface(const TriangleMesh& mesh, const RegionBox& region) {
  RegionSurface& r = mRegionSurface;
  if (r.from != &mesh || r.triangles != mesh.triangles.size() || r.vertices != mesh.vertices.size() || !(r.box == region)) {
    r.mesh = cutMeshToRegion(mesh, region);
    for (auto& kept : mSurfaces)  // a ray tracer's BVH made for the mesh this one replaces
      for (int k = 0; k < 2; ++k)
        if (kept->bvhMesh[k] == &r.mesh) kept->bvhMesh[k] = nullptr;
    r.from = &mesh;
    r.triangles = mesh.triangles.size();
    r.vertices = mesh.vertices.size();
    r.box = region;
  }
  return r.mesh;
}

const GeometryChannel* SceneRenderer::frameGeometry(const Look& look, FrameStats* st) {
  if (look.meshes.empty() || look.meshMethod != MeshMethod::ScanConvert) return nullptr;
  KeptGeometry& k = mGeometry;
  bool same = k.channel && k.from.size() == look.meshes.size() && k.filter == look.meshFilter;
  for (size_t i = 0; same && i < k.from.size(); ++i) same = k.from[i] == look.meshes[i].mesh && k.colors[i] == look.meshes[i].color;
  if (!same) {
    if (mGl) mGl->makeCurrent();  // the textures of the channel replaced are deleted in their context
    k = KeptGeometry{};
    for (const UserMesh& m : look.meshes) {
      k.from.push_back(m.mesh);
      k.colors.push_back(m.color);
    }
    k.filter = look.meshFilter;
    k.channel = std::make_unique<GeometryChannel>(scanConvertGeometry(look.meshes, volume(), mScene.octree, look.meshFilter));
    st->geometryMs = k.channel->ms;
  }
  st->geometryBytes = k.channel->bytes();
  return k.channel.get();
}

const GridMeshes* SceneRenderer::frameMeshes(const Look& look, bool bvh, FrameStats* st) {
  if (look.meshes.empty() || look.meshMethod != MeshMethod::Polygons) return nullptr;
  KeptMeshes& k = mMeshes;
  bool same = k.from.size() == look.meshes.size();
  for (size_t i = 0; same && i < k.from.size(); ++i) same = k.from[i] == look.meshes[i].mesh && k.colors[i] == look.meshes[i].color;
  const auto t0 = Clock::now();
  if (!same) {
    k = KeptMeshes{};
    for (const UserMesh& m : look.meshes) {
      k.from.push_back(m.mesh);
      k.colors.push_back(m.color);
    }
    k.grid = gridMeshes(look.meshes, volume().frame(), mScene.octree, volume().spacing());
  }
  if (bvh && !k.bvh) {
    std::vector<const TriangleMesh*> parts;
    for (const TriangleMesh& m : k.grid.whole) parts.push_back(&m);
    k.bvh = std::make_unique<Bvh>(parts);
  }
  st->meshesMs = msSince(t0);
  for (const TriangleMesh& m : k.grid.whole) st->meshTriangles += m.triangles.size();
  return &k.grid;
}

bool SceneRenderer::byRegions(const Camera& gridCamera, const Quality& quality, float iso) const {
  if (!mScene.surface || mScene.surface->isovalue() != iso || mOptions.memoryBytes == 0) return false;
  if (quality.renderer != Renderer::Slices || !quality.waitForSurface || quality.simplifiedSurface || quality.region) return false;
  if (surfaceSpacing(gridCamera, quality) != 1 || surfacePolygons(iso) > 0) return false;
  return mScene.surface->reconstructBytes() > mOptions.memoryBytes / kWholeSurfaceMemoryDivisor;
}

namespace {

// What a frame draws of @p mesh (triangulated, polygonStarts set): the polygons one of whose
// triangles @p seen keeps, whole (@p wholePolygons: a translucent surface's are sorted by their
// centroids), or only the triangles it keeps (an opaque surface draws triangle by triangle).
TriangleMesh seenPart(const TriangleMesh& mesh, const std::function<bool(const glm::vec3&, const glm::vec3&, const glm::vec3&)>& seen,
                      bool wholePolygons) {
  TriangleMesh out;
  out.vertices = mesh.vertices;
  out.polygonStarts.push_back(0);
  for (size_t p = 0; p + 1 < mesh.polygonStarts.size(); ++p) {
    const uint32_t b = mesh.polygonStarts[p], e = mesh.polygonStarts[p + 1];
    const size_t first = out.triangles.size();
    for (uint32_t t = b; t < e; ++t) {
      const glm::uvec3 tr = mesh.triangles[t];
      if (!seen(mesh.vertices[tr.x], mesh.vertices[tr.y], mesh.vertices[tr.z])) continue;
      if (wholePolygons) {
        out.triangles.insert(out.triangles.end(), mesh.triangles.begin() + b, mesh.triangles.begin() + e);
        break;
      }
      out.triangles.push_back(tr);
    }
    if (out.triangles.size() > first) out.polygonStarts.push_back(uint32_t(out.triangles.size()));
  }
  removeUnreferencedVertices(&out);
  return out;
}

// Appends @p part to @p mesh (its polygons after @p mesh's).
void appendMesh(const TriangleMesh& part, TriangleMesh* mesh) {
  const uint32_t base = uint32_t(mesh->vertices.size()), first = uint32_t(mesh->triangles.size());
  mesh->vertices.insert(mesh->vertices.end(), part.vertices.begin(), part.vertices.end());
  mesh->normals.insert(mesh->normals.end(), part.normals.begin(), part.normals.end());
  for (const glm::uvec3& t : part.triangles) mesh->triangles.push_back(t + base);
  for (size_t p = 1; p < part.polygonStarts.size(); ++p) mesh->polygonStarts.push_back(first + part.polygonStarts[p]);
}

}  // namespace

const TriangleMesh& SceneRenderer::regionSurface(const FrameGrid& g, const Look& look, FrameStats* st) {
  const auto t0 = Clock::now();
  const SurfaceOctree& so = *mScene.surface;
  SurfaceRegions& r = mRegions;
  if (r.regions.empty() || r.iso != so.isovalue()) {
    r = SurfaceRegions{};
    r.iso = so.isovalue();
    r.regions = so.regions(mOptions.surfaceRegionNodes);
    r.kept.resize(r.regions.size());
  }
  r.frame = TriangleMesh{};
  r.frame.polygonStarts.push_back(0);
  boundCache();  // (the last frame's polygons are gone)
  // What the slice renderer draws of a triangle: a pixel centre it may cover, or its line on the
  // cutting plane (cut_plane_pass.cpp draws a segment where the corners' sides differ).
  const PixelCentres centres = framePixelCentres(volume(), g.camera);
  const std::optional<glm::dvec4> cut = g.cut && look.cutLine ? std::optional(g.cut->keptSide(g.camera)) : std::nullopt;
  auto seen = [&](const glm::vec3& a, const glm::vec3& b, const glm::vec3& c) {
    if (const PixelCentres::Cover cover = centres.cover(a, b, c, nullptr); !(cover.known && cover.centres == 0)) return true;
    if (!cut) return false;
    const double sa = glm::dot(glm::dvec3(*cut), glm::dvec3(a)) + cut->w, sb = glm::dot(glm::dvec3(*cut), glm::dvec3(b)) + cut->w,
                 sc = glm::dot(glm::dvec3(*cut), glm::dvec3(c)) + cut->w;
    return std::min({sa, sb, sc}) <= 0.0 && std::max({sa, sb, sc}) >= 0.0;
  };
  // A region whose box lies beside the image draws nothing: it is not reconstructed.
  const glm::dvec3 spacing = volume().spacing();
  auto offImage = [&](const SurfaceRegion& region) {
    return centres.besideImage(glm::dvec3(region.origin) * spacing, glm::dvec3(region.origin + region.edge) * spacing);
  };
  // Regions are kept (without normals) while they fit in an eighth of the bound: the next frame
  // reconstructs only the others.
  const uint64_t keptBound = mOptions.memoryBytes / 8;
  std::atomic<uint64_t> admitted{r.keptBytes};
  const bool gradient = look.normals == SurfaceNormals::Gradient, translucent = look.surfaceColor.a < 1.0f;
  size_t polygons = 0, triangles = 0;
  constexpr size_t kBatch = 16;  // regions made at once: their meshes are held until appended
  for (size_t b = 0; b < r.regions.size(); b += kBatch) {
    const size_t e = std::min(r.regions.size(), b + kBatch);
    std::vector<std::shared_ptr<const TriangleMesh>> kept(e - b);
    std::vector<TriangleMesh> parts(e - b);
    std::vector<std::array<size_t, 3>> sizes(e - b, {0, 0, 0});  // made or kept, its polygons and triangles
    ParallelFailure failure;
#pragma omp parallel for schedule(dynamic)
    for (size_t i = b; i < e; ++i)
      failure.run([&] {
        if (offImage(r.regions[i])) return;
        std::shared_ptr<const TriangleMesh> mesh =
            r.kept[i] ? r.kept[i] : std::make_shared<const TriangleMesh>(fineMeshToTriangles(so.reconstructIn(r.regions[i]), spacing));
        sizes[i - b] = {1, mesh->polygonStarts.size() - 1, mesh->triangles.size()};
        parts[i - b] = seenPart(*mesh, seen, translucent);
        if (gradient) setSceneNormals(mScene, &parts[i - b]);
        if (!r.kept[i] && admitted.fetch_add(mesh->bytesUsed()) + mesh->bytesUsed() <= keptBound)
          kept[i - b] = std::move(mesh);
        else if (!r.kept[i])
          admitted -= mesh->bytesUsed();
      });
    failure.rethrow();
    so.releasePages();
    for (size_t i = b; i < e; ++i) {
      if (sizes[i - b][0] == 0) continue;  // beside the image
      ++(r.kept[i] ? st->surfaceRegionsKept : st->surfaceRegionsMade);
      polygons += sizes[i - b][1];
      triangles += sizes[i - b][2];
      if (kept[i - b]) {
        r.keptBytes += kept[i - b]->bytesUsed();
        r.kept[i] = std::move(kept[i - b]);
      }
      appendMesh(parts[i - b], &r.frame);
    }
    boundCache();  // (the cache gives back what the polygons kept take)
  }
  st->surfacePolygons = polygons;
  st->surfaceTriangles = triangles;
  st->surfacePolygonsMs = msSince(t0);
  return r.frame;
}

const TriangleMesh* SceneRenderer::frameSurface(const FrameGrid& g, const Look& look, const Quality& quality, FrameStats* st) {
  if (byRegions(g.camera, quality, *look.iso)) return &regionSurface(g, look, st);
  if (!mRegions.frame.triangles.empty()) {  // a frame by regions before this one: its triangles go
    mRegions.frame = TriangleMesh{};
    boundCache();
  }
  // Kept from earlier frames, or built now; none when the frame does not wait and nothing is kept.
  const Camera& camera = g.camera;
  const int spacing = drawnSpacing(camera, quality, *look.iso);
  if (spacing == 0) return nullptr;
  const TriangleMesh& mesh = prepareAt(*look.iso, spacing, look.normals, st);
  boundCache();  // (a surface made for this frame)
  if (spacing > 1 || !(quality.simplifiedSurface && quality.renderer == Renderer::Slices)) return &mesh;
  PreparedSurface& s = surfaceEntry(*look.iso, nullptr);
  if (s.simplified.empty()) {
    if (!quality.waitForSurface) return &mesh;  // the builder makes them (drawnSpacing takes a preview kept meanwhile)
    s.simplified = simplifiedLevels(mScene, *s.smooth, mOptions.progress, surfaceReservation());
    boundCache();
  }
  // The coarsest level whose error is within the pixels asked where the volume is nearest.
  const double allowedMm = quality.surfaceErrorPixels * nearestPixelMm(camera);
  int k = 0;
  while (k + 1 < int(s.simplified.size()) && simplifiedErrorMm(volume().spacing(), k + 1) <= allowedMm) ++k;
  st->surfaceTriangles = s.simplified[size_t(k)].triangles.size();
  st->surfaceSimplified = true;
  return &s.simplified[size_t(k)];
}

void SceneRenderer::renderRaycast(const FrameGrid& g, const Look& look, const Quality& quality, const TriangleMesh* mesh,
                                  const LevelCallback& onLevel, RenderedFrame* out) {
  FrameStats& st = out->stats;
  const Bvh* bvh = nullptr;
  if (mesh) {
    PreparedSurface& s = *mSurfaces.front();  // this frame's
    // Made for the mesh drawn (an entry's meshes can be made again).
    const int k = look.normals == SurfaceNormals::Gradient ? 1 : 0;
    if (!s.bvh[k] || s.bvhMesh[k] != mesh) {
      const auto b0 = Clock::now();
      s.bvh[k] = std::make_unique<Bvh>(*mesh);
      s.bvhMesh[k] = mesh;
      st.bvhMs = msSince(b0);
    }
    bvh = s.bvh[k].get();
  }
  RaycastOptions ro = raycastOptions(g, look, quality, bvh);
  if (const GridMeshes* meshes = frameMeshes(look, true, &st)) {
    ro.meshes = mMeshes.bvh.get();
    ro.meshColors = meshes->colors;
  }
  ro.geometry = frameGeometry(look, &st);
  ro.knots = volume().hasSamples() ? nullptr : mScene.knots.get();  // a paged scene's samples through its cache
  if (quality.classification == Classification::PreIntegrated) {
    // Segments are a step long, shorter where a surface crossing or the volume's end cuts them.
    const double dt = stepMm(volume(), ro.stepVoxels);
    ro.preintegrated = &preintegration(look.tf, 0.25 * dt, dt, &st);
  }
  ro.progress = mOptions.progress;
  const auto t0 = Clock::now();
  if (onLevel)
    ro.onLevel = [&](int level, const Image& image, uint64_t rays) {
      if (level >= ro.refineLevels) return;
      FrameStats ls = st;
      ls.rays.rays = rays;
      ls.renderMs = msSince(t0);
      onLevel(level, ro.refineLevels, image, ls);
    };
  if (quality.interactiveRays && interactiveRaysServe(volume(), ro))
    out->image = raycastInteractive(volume(), mScene.octree, look.tf, g.camera, ro, {.stats = &st.rays});
  else
    out->image = raycast(volume(), mScene.octree, look.tf, g.camera, ro, &st.rays);
  st.renderMs = msSince(t0);
}

void SceneRenderer::renderSlicesFrame(const FrameGrid& g, const Look& look, const Quality& quality, const TriangleMesh* mesh,
                                      const LevelCallback& onLevel, RenderedFrame* out) {
  FrameStats& st = out->stats;
  // The selection: ε and the budget for this view.
  const auto s0 = Clock::now();
  const SelectionParams params = selectionParams(g, look, quality, &st);
  out->selection = quality.selection ? *quality.selection : selectNodes(mScene.octree, params);
  if (!quality.waitForBricks && (mScene.knots || quality.packTexels > 0)) st.bricksNotResident = drawResident(g.camera, quality.packTexels, &out->selection);
  st.selectMs = msSince(s0);

  ensureGl();
  SlicesOptions so = slicesOptions(g, look, quality, mesh, frameMeshes(look, false, &st));
  so.textures = mOptions.keepTextures ? mTextures.get() : nullptr;
  so.targets = &mTargets;
  so.knots = mScene.knots.get();
  so.geometry = frameGeometry(look, &st);
  if (quality.classification == Classification::PreIntegrated) {
    // From half the base spacing (segments cut at bricks' faces) to twice the coarsest levels'
    // spacing (32 base spacings) along oblique rays (SlicesOptions::preintegrated).
    const double delta = stepMm(volume(), so.stepVoxels);
    so.preintegrated = &preintegration(look.tf, 0.5 * delta, 128.0 * delta, &st);
  }
  // Progressive refinement (Levoy): coarse images first, each with an eighth of the next one's
  // texels (one level coarser), the last being the requested selection. Early images of a long
  // sequence bottom out at the coarsest selection the octree has (at least one texel is asked for).
  for (int k = 1; k < quality.progressive; ++k) {
    const int shift = 3 * (quality.progressive - k);
    SelectionParams coarser = params;
    coarser.texelBudget = std::max<uint64_t>(1, shift < 64 ? out->selection.texels >> shift : 0);
    FrameStats ls = st;
    const auto p0 = Clock::now();
    const Selection coarse = selectNodes(mScene.octree, coarser);
    const Image preview = renderSlices({volume(), mScene.octree, coarse}, look.tf, g.camera, so, &ls.slices);
    ls.renderMs = msSince(p0);
    if (onLevel) onLevel(k, quality.progressive, preview, ls);
  }
  so.progress = mOptions.progress;
  const auto r0 = Clock::now();
  out->image = renderSlices({volume(), mScene.octree, out->selection}, look.tf, g.camera, so, &st.slices);
  st.renderMs = msSince(r0);
  st.brickErrorsMeasured = mErrors->errors->measured();  // the view's, made by the selection
  st.textureBytesKept = mTextures->bytes();
}

}  // namespace hyb
