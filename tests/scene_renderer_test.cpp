// The scene renderer: one object kept alive across frames, redoing only what a change needs.
#include "render/scene_renderer.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <condition_variable>
#include <cstdlib>
#include <mutex>
#include <thread>
#include <tuple>

#include "hybrid_octree/coarse_surface.h"
#include "hybrid_octree/hybrid_io.h"
#include "render/patient_view.h"
#include "render/scene_pool.h"
#include "surface/mesh_simplify.h"
#include "render_util.h"
#include "test_util.h"

namespace hyb {
namespace {

using ::testing::HasSubstr;

using test::sphereScene;

TransferFunction warm() { return TransferFunction({{0.0f, {1, 1, 1}, 0.0f}, {2.0f, {1.0f, 0.6f, 0.3f}, 0.3f}, {15.0f, {0.3f, 0.6f, 1.0f}, 0.05f}}, "warm"); }
// The same support (values above 0) over another domain: another lookup table.
TransferFunction cool() { return TransferFunction({{0.0f, {1, 1, 1}, 0.0f}, {3.0f, {0.2f, 0.5f, 1.0f}, 0.2f}, {20.0f, {0.9f, 0.9f, 0.9f}, 0.1f}}, "cool"); }

// The translucent surface of value 0 under warm(): a sphere's, for the tests of surface detail.
Look surfaceAtZero() {
  Look look;
  look.tf = warm();
  look.iso = 0.0f;
  look.surfaceColor = glm::vec4(0.9f, 0.9f, 0.9f, 0.5f);
  return look;
}

// Orthographic from the front of a 97³ grid, 120 mm high: a pixel is 120 mm over the rows, at any depth.
View frontOfGrid97() {
  View view;
  view.camera.eye = glm::dvec3(48.0, -200.0, 48.0);
  view.camera.center = glm::dvec3(48.0);
  view.camera.up = glm::dvec3(0, 0, 1);
  view.camera.ortho = true;
  view.camera.orthoHeight = 120.0;
  return view;
}

// The surface of @p iso with its simplified levels, as a viewer's frames draw it.
std::unique_ptr<PreparedSurface> withLevels(const Scene& scene, float iso) {
  std::unique_ptr<PreparedSurface> s = SceneRenderer::prepareSurface(scene, iso);
  s->simplified = SceneRenderer::simplifiedLevels(scene, *s->smooth);
  return s;
}

View viewFrom(double azimuth, const Volume& v, int pixels = 48, double margin = 0.05) {
  View view;
  view.camera = fitCamera(visiblePoints(v, VolumeOctree::build(v), warm()), orbitDirection(azimuth, 15), {30, false, pixels, pixels}, margin);
  return view;
}

TEST(SceneRenderer, ASurfaceMadeOnAnotherThreadIsAdoptedAndDrawnAsIfBuiltHere) {
  test::gl();
  SceneRenderer r(sphereScene()), sync(sphereScene());
  Look look;
  look.tf = warm();
  const View view = viewFrom(20, r.volume());
  EXPECT_FALSE(r.hasSurface(5.0f));
  // Built beside frames of the same renderer, which read the same scene.
  std::unique_ptr<PreparedSurface> made;
  std::thread builder([&] { made = SceneRenderer::prepareSurface(r.scene(), 5.0f); });
  for (int i = 0; i < 3; ++i) r.render(view, look, Quality{});
  builder.join();
  ASSERT_TRUE(made);
  EXPECT_GT(made->polygons, 0u);
  EXPECT_TRUE(made->facet.triangles.empty());  // made when a frame first asks for it
  EXPECT_EQ(made->mesh(SurfaceNormals::Facet).triangles, made->smooth->triangles);
  EXPECT_TRUE(made->facet.normals.empty());
  r.adoptSurface(std::move(made));
  EXPECT_TRUE(r.hasSurface(5.0f));
  look.iso = 5.0f;
  look.surfaceColor = glm::vec4(0.9f, 0.8f, 0.7f, 0.5f);
  const RenderedFrame adopted = r.render(view, look, Quality{});
  EXPECT_FALSE(adopted.stats.surfaceBuilt);  // nothing built for this frame
  const RenderedFrame built = sync.render(view, look, Quality{});
  EXPECT_TRUE(built.stats.surfaceBuilt);
  EXPECT_EQ(adopted.stats.surfaceTriangles, built.stats.surfaceTriangles);
  EXPECT_EQ(adopted.image.pixels, built.image.pixels);
}

// A paged scene's --memory counts the surfaces and brick textures its renderer keeps: the cache's
// bound is what the octree and they leave (sceneCacheBytes), its blocks given back at once when a
// surface comes, and it grows again when a surface goes; below the octree and surfaces it keeps a
// quarter.
TEST(SceneRenderer, TheSurfacesAndTexturesKeptCountAgainstAPagedScenesMemory) {
  test::gl();
  test::TempDir dir;
  saveScene(dir.file("s.hoct"), sphereScene().volume, sphereScene().octree);
  for (const uint64_t memory : {uint64_t(8) << 20, uint64_t(64) << 10}) {
    SCOPED_TRACE(memory);
    SceneRenderer::Options options;
    options.memoryBytes = memory;
    SceneRenderer r(loadScene(dir.file("s.hoct"), SceneLoadOptions{false, memory}), options);
    const KnotStore& store = *r.scene().knots;
    const uint64_t octree = r.octree().bytesUsed();
    EXPECT_EQ(store.cacheStats().limit, sceneCacheBytes(memory, octree));
    EXPECT_EQ(r.surfaceBytes(), 0u);
    Look look;
    look.tf = warm();
    look.iso = 5.0f;
    look.surfaceColor = glm::vec4(0.9f, 0.8f, 0.7f, 0.5f);
    r.render(viewFrom(20, sphereScene().volume), look, Quality{});  // reads blocks, then makes the surface
    const TriangleMesh& smooth = r.surface(5.0f, SurfaceNormals::Gradient);
    const size_t one = r.surfaceBytes();
    EXPECT_GE(one, sizeof(glm::vec3) * 2 * smooth.vertices.size() + sizeof(glm::uvec3) * smooth.triangles.size());
    EXPECT_EQ(store.cacheStats().limit, sceneCacheBytes(memory, octree + one));
    EXPECT_LE(store.cacheStats().bytesHeld, store.cacheStats().limit);
    r.surface(5.0f, SurfaceNormals::Facet);  // its copy without normals counts too
    EXPECT_GT(r.surfaceBytes(), one);
    EXPECT_EQ(store.cacheStats().limit, sceneCacheBytes(memory, octree + r.surfaceBytes()));
    // Two more isovalues: the first goes (two unpinned surfaces are kept), the bound follows.
    r.surface(4.0f, SurfaceNormals::Gradient);
    const size_t two = r.surfaceBytes();
    r.surface(6.0f, SurfaceNormals::Gradient);
    EXPECT_EQ(r.surfaceIsos().size(), 2u);
    EXPECT_LT(r.surfaceBytes(), two + one);
    EXPECT_EQ(store.cacheStats().limit, sceneCacheBytes(memory, octree + r.surfaceBytes()));
    if (memory < octree + r.surfaceBytes()) {
      EXPECT_EQ(store.cacheStats().limit, memory / 4);
    }
    // A surface being made on another thread counts while it is made, two at once apart (the
    // first done does not take the other's count), and a surface handed over until adopted.
    const auto first = r.surfaceReservation();
    const auto second = r.surfaceReservation();
    first(1 << 20);
    second(3 << 20);
    EXPECT_EQ(store.cacheStats().limit, sceneCacheBytes(memory, octree + r.surfaceBytes() + (4 << 20)));
    first(2 << 20);
    first(0);
    EXPECT_EQ(store.cacheStats().limit, sceneCacheBytes(memory, octree + r.surfaceBytes() + (3 << 20)));
    r.holdSurfaceBytes(5 << 20);
    second(0);
    EXPECT_EQ(store.cacheStats().limit, sceneCacheBytes(memory, octree + r.surfaceBytes() + (5 << 20)));
    r.releaseSurfaceBytes(5 << 20);
    EXPECT_EQ(store.cacheStats().limit, sceneCacheBytes(memory, octree + r.surfaceBytes()));
  }
  // The brick textures a renderer keeps between frames count at their bound (a viewer's
  // --texture-mb), from its start; a renderer that keeps none counts none.
  for (const bool keep : {true, false}) {
    const uint64_t memory = uint64_t(8) << 20;
    SceneRenderer::Options options;
    options.memoryBytes = memory;
    options.textureLimitBytes = uint64_t(3) << 20;
    options.keepTextures = keep;
    SceneRenderer r(loadScene(dir.file("s.hoct"), SceneLoadOptions{false, memory}), options);
    const uint64_t counted = r.octree().bytesUsed() + (keep ? options.textureLimitBytes : 0);
    EXPECT_EQ(r.scene().knots->cacheStats().limit, sceneCacheBytes(memory, counted)) << keep;
    r.surface(5.0f, SurfaceNormals::Gradient);
    EXPECT_EQ(r.scene().knots->cacheStats().limit, sceneCacheBytes(memory, counted + r.surfaceBytes())) << keep;
  }
  // What the reconstruction and the levels will hold is told before they start, and 0 after, even
  // when they stop.
  const Scene scene = sphereScene();
  std::vector<uint64_t> heard;
  const auto made = SceneRenderer::prepareSurface(scene, 5.0f, nullptr, nullptr, [&](uint64_t bytes) { heard.push_back(bytes); });
  ASSERT_TRUE(made->built);
  EXPECT_THAT(heard, ::testing::ElementsAre(made->built->reconstructBytes(), 0u));
  EXPECT_GT(made->built->reconstructBytes(), 0u);
  heard.clear();
  SceneRenderer::simplifiedLevels(scene, *made->smooth, nullptr, [&](uint64_t bytes) { heard.push_back(bytes); });
  EXPECT_THAT(heard, ::testing::ElementsAre(kSimplifyBytesPerTriangle * made->smooth->triangles.size(), 0u));
  heard.clear();
  const Progress stop([](const std::string& task, double) {
    if (task == "surface polygons") throw std::runtime_error("stopped");
  });
  EXPECT_THROW(SceneRenderer::prepareSurface(scene, 5.0f, &stop, nullptr, [&](uint64_t bytes) { heard.push_back(bytes); }), std::runtime_error);
  ASSERT_EQ(heard.size(), 2u);
  EXPECT_GT(heard[0], 0u);
  EXPECT_EQ(heard[1], 0u);
}

// A viewer keeps a scene file paged: a surface made on its builder thread reads the samples a leaf
// at a time through the scene's cache, never whole, and gives the surface of the scene in memory,
// normals and simplified levels bit for bit; what the viewer shows of it first (the summary:
// histogram, framed views) is what the scene in memory gives.
TEST(SceneRenderer, APagedSceneBuildsItsSurfacesThroughItsCacheAndStaysPaged) {
  test::gl();
  test::TempDir dir;
  saveScene(dir.file("s.hoct"), sphereScene().volume, sphereScene().octree);
  SceneRenderer paged(loadScene(dir.file("s.hoct"), SceneLoadOptions{false, 1 << 20})), memory(loadScene(dir.file("s.hoct")));
  ASSERT_FALSE(paged.volume().hasSamples());
  const SceneSummary a = summarizeScene(paged.scene(), "k", "p", "", "n"), b = summarizeScene(memory.scene(), "k", "p", "", "n");
  EXPECT_EQ(a.histogram.counts, b.histogram.counts);
  EXPECT_EQ(a.histogram.p01, b.histogram.p01);
  EXPECT_EQ(a.histogram.p50, b.histogram.p50);
  EXPECT_EQ(a.histogram.p99, b.histogram.p99);
  EXPECT_EQ(a.histogram.mean, b.histogram.mean);
  for (int v = 0; v < 6; ++v) EXPECT_EQ(a.views[size_t(v)].eye, b.views[size_t(v)].eye) << v;
  // Beyond its sample limit, the histogram of the samples at even positions, exactly.
  const Volume& whole = memory.volume();
  const glm::ivec3 n = whole.dims(), k = knotCounts(n, 2);
  std::vector<float> even;
  for (int z = 0; z < k.z; ++z)
    for (int y = 0; y < k.y; ++y)
      for (int x = 0; x < k.x; ++x) even.push_back(whole.at(knotPosition(x, 2, n.x), knotPosition(y, 2, n.y), knotPosition(z, 2, n.z)));
  const Histogram expected = computeHistogram(even.size(), whole.minValue(), whole.maxValue(), 128,
                                              [&](const auto& use) { use(even.data(), even.size()); });
  const Histogram sub = summarizeScene(paged.scene(), "k", "p", "", "n", whole.voxelCount() - 1).histogram;
  EXPECT_EQ(sub.counts, expected.counts);
  EXPECT_EQ(sub.p50, expected.p50);
  EXPECT_NE(sub.counts, a.histogram.counts);
  Look look;
  look.tf = warm();
  const View view = viewFrom(20, memory.volume());
  std::unique_ptr<PreparedSurface> made;
  std::thread builder([&] { made = withLevels(paged.scene(), 5.0f); });
  for (int i = 0; i < 2; ++i) paged.render(view, look, Quality{});
  builder.join();
  EXPECT_FALSE(paged.volume().hasSamples());
  std::unique_ptr<PreparedSurface> inMemory = withLevels(memory.scene(), 5.0f);
  ASSERT_TRUE(made->built && inMemory->built);
  EXPECT_GT(made->built->nodes().size(), 0u);
  EXPECT_EQ(made->built->nodes(), inMemory->built->nodes());
  EXPECT_EQ(made->smooth->vertices, inMemory->smooth->vertices);
  EXPECT_EQ(made->smooth->normals, inMemory->smooth->normals);
  ASSERT_EQ(made->simplified.size(), inMemory->simplified.size());
  for (size_t l = 0; l < made->simplified.size(); ++l) EXPECT_EQ(made->simplified[l].normals, inMemory->simplified[l].normals) << l;
  EXPECT_LE(paged.scene().knots->cacheStats().bytesHeld, paged.scene().knots->cacheStats().limit + kMaxStoreBlockBytes);
  paged.adoptSurface(std::move(made));
  memory.adoptSurface(std::move(inMemory));
  look.iso = 5.0f;
  look.surfaceColor = glm::vec4(0.9f, 0.8f, 0.7f, 0.5f);
  const RenderedFrame p = paged.render(view, look, Quality{}), m = memory.render(view, look, Quality{});
  EXPECT_GT(p.stats.surfaceTriangles, 0u);
  EXPECT_EQ(p.stats.surfaceTriangles, m.stats.surfaceTriangles);
  EXPECT_EQ(p.image.pixels, m.image.pixels);
  EXPECT_FALSE(paged.volume().hasSamples());
}

// A scene whose Surface Octree's reconstruction exceeds its memory draws its surface region by
// region, keeping only the polygons the frame draws: the image is the whole surface's, opaque or
// translucent, smooth or by facets, with a cutting plane and its line, from near and far; a
// region beside the image is not reconstructed, and regions that fit their bound are kept.
TEST(SceneRenderer, ASurfaceBeyondTheMemoryIsDrawnRegionByRegionAsTheWholeWould) {
  test::gl();
  test::TempDir dir;
  const Scene s = sphereScene({48, 44, 40}, 17.0);
  const SurfaceOctree so = SurfaceOctree::build(s.volume, s.octree, 0.0f);
  saveScene(dir.file("s.hoct"), s.volume, s.octree, &so);
  SceneRenderer::Options small, unbounded;
  small.memoryBytes = so.reconstructBytes();  // the whole reconstruction takes more than half of it
  small.surfaceRegionNodes = 64;
  unbounded.memoryBytes = 0;
  SceneRenderer regions(loadScene(dir.file("s.hoct"), SceneLoadOptions{false, small.memoryBytes}), small);
  SceneRenderer whole(loadScene(dir.file("s.hoct"), SceneLoadOptions{false, 0}), unbounded);
  ASSERT_TRUE(regions.scene().surface->mapped());
  const size_t count = so.regions(small.surfaceRegionNodes).size();
  ASSERT_GT(count, 8u);
  Look look;
  look.tf = warm();
  look.iso = 0.0f;
  auto expectSame = [&](const View& view, const Look& l, const char* what) {
    const RenderedFrame a = regions.render(view, l, Quality{}), b = whole.render(view, l, Quality{});
    EXPECT_GT(a.stats.surfaceRegionsMade + a.stats.surfaceRegionsKept, 0u) << what;
    EXPECT_EQ(b.stats.surfaceRegionsMade + b.stats.surfaceRegionsKept, 0u) << what;
    EXPECT_EQ(a.image.pixels, b.image.pixels) << what;
    EXPECT_TRUE(std::any_of(a.image.pixels.begin(), a.image.pixels.end(), [](const glm::vec4& p) { return p.a > 0.0f; })) << what;
    return a.stats;
  };
  const View view = viewFrom(20, s.volume, 64);
  const FrameStats first = expectSame(view, look, "opaque");
  EXPECT_EQ(first.surfaceRegionsMade + first.surfaceRegionsKept, count);
  EXPECT_EQ(first.surfacePolygons, whole.surfacePolygons(0.0f));
  EXPECT_EQ(first.surfaceTriangles, whole.surface(0.0f, SurfaceNormals::Gradient).triangles.size());
  look.surfaceColor = glm::vec4(0.9f, 0.8f, 0.7f, 0.5f);
  expectSame(view, look, "translucent");
  look.normals = SurfaceNormals::Facet;
  expectSame(view, look, "facets");
  look.normals = SurfaceNormals::Gradient;
  look.cut = CutPlane{s.volume.frame().toPatient(glm::dvec3(24.0, 22.0, 20.0) * s.volume.spacing()), glm::dvec3(0.3, 1.0, 0.2)};
  expectSame(view, look, "cut");
  look.cut.reset();
  View near = view;
  near.camera.eye = near.camera.center + (near.camera.eye - near.camera.center) * 0.3;
  const FrameStats zoomed = expectSame(near, look, "near");
  EXPECT_LT(zoomed.surfaceRegionsMade + zoomed.surfaceRegionsKept, count);  // the regions beside the image are skipped
  // With room, the regions are kept: the next frame reconstructs none.
  SceneRenderer::Options roomy = small;
  roomy.memoryBytes = 2 * so.reconstructBytes() - 1;
  SceneRenderer keeping(loadScene(dir.file("s.hoct"), SceneLoadOptions{false, roomy.memoryBytes}), roomy);
  const RenderedFrame k1 = keeping.render(view, look, Quality{}), k2 = keeping.render(view, look, Quality{});
  EXPECT_EQ(k1.stats.surfaceRegionsMade, count);
  EXPECT_EQ(k2.stats.surfaceRegionsMade, 0u);
  EXPECT_EQ(k2.stats.surfaceRegionsKept, count);
  EXPECT_EQ(k2.image.pixels, k1.image.pixels);
  EXPECT_GT(keeping.surfaceBytes(), 0u);
}

TEST(SceneRenderer, ChangesRedoOnlyWhatDependsOnThem) {
  test::gl();
  SceneRenderer r(sphereScene());
  Look look;
  look.tf = warm();
  Quality q;
  const View front = viewFrom(0, r.volume()), side = viewFrom(70, r.volume());
  const RenderedFrame first = r.render(front, look, q);
  EXPECT_GT(first.stats.slices.uploadedBricks, 0u);
  EXPECT_EQ(first.stats.slices.uploadedBricks, first.stats.slices.bricks);
  // The same view again: nothing uploaded, the same image.
  const RenderedFrame again = r.render(front, look, q);
  EXPECT_EQ(again.stats.slices.uploadedBricks, 0u);
  EXPECT_EQ(again.image.pixels, first.image.pixels);
  // A new camera keeps the bricks: the full-resolution bricks it shares are not uploaded again.
  const RenderedFrame turned = r.render(side, look, q);
  EXPECT_LT(turned.stats.slices.uploadedBricks, turned.stats.slices.bricks / 2);
  // A new transfer function keeps the textures (their ranges are values) and shows what a fresh
  // renderer shows.
  Look other = look;
  other.tf = cool();
  const RenderedFrame recoloured = r.render(front, other, q);
  EXPECT_EQ(recoloured.stats.slices.uploadedBricks, 0u);
  SceneRenderer fresh(sphereScene());
  EXPECT_EQ(recoloured.image.pixels, fresh.render(front, other, q).image.pixels);
  // A new isovalue builds its surface once; the textures stay.
  Look withSurface = look;
  withSurface.iso = 4.0f;
  withSurface.surfaceColor = glm::vec4(0.9f, 0.9f, 0.9f, 0.5f);
  const RenderedFrame surfaced = r.render(front, withSurface, q);
  EXPECT_TRUE(surfaced.stats.surfaceBuilt);
  EXPECT_GT(surfaced.stats.surfaceTriangles, 0u);
  EXPECT_EQ(surfaced.stats.slices.uploadedBricks, 0u);
  EXPECT_FALSE(r.render(side, withSurface, q).stats.surfaceBuilt);
  // The reference sees the same scene through the same object.
  Quality reference;
  reference.renderer = Renderer::Raycast;
  const Image ref = r.render(front, withSurface, reference).image;
  if (const char* d = std::getenv("HYB_DEBUG_IMAGES")) {
    writePng(std::string(d) + "/ref.png", ref, glm::vec3(0));
    writePng(std::string(d) + "/slices.png", surfaced.image, glm::vec3(0));
    Look facet = withSurface;
    facet.normals = SurfaceNormals::Facet;
    writePng(std::string(d) + "/ref_facet.png", r.render(front, facet, reference).image, glm::vec3(0));
    writePng(std::string(d) + "/slices_facet.png", r.render(front, facet, q).image, glm::vec3(0));
  }
  EXPECT_GE(test::psnrOf(ref, surfaced.image), 35.0);
}

// The viewer's frames before the final one: the surface simplified within blocks and placed uncut draws fewer
// triangles and pieces, and stays close to the exact frame and to the reference.
TEST(SceneRenderer, TheSimplifiedUncutSurfaceStaysCloseToTheExactOne) {
  test::gl();
  SceneRenderer r(sphereScene());
  Look look;
  look.tf = warm();
  look.iso = 4.0f;
  look.surfaceColor = glm::vec4(0.9f, 0.9f, 0.9f, 0.5f);
  const View view = viewFrom(30, r.volume(), 96, 0.3);  // the tolerances below hold with this room around the sphere
  Quality exact;
  exact.step = 1.0;
  exact.maxBrickEdge = kSimplifiedBlockVoxels;
  Quality moving = exact;
  moving.simplifiedSurface = true;
  moving.cutToSlabs = false;
  const RenderedFrame e = r.render(view, look, exact), m = r.render(view, look, moving);
  EXPECT_LT(3 * m.stats.slices.surfaceTriangles, e.stats.slices.surfaceTriangles);
  EXPECT_EQ(m.stats.slices.slabPolygonDraws, m.stats.slices.surfaceTriangles);  // one piece a triangle
  EXPECT_GT(e.stats.slices.slabPolygonDraws, e.stats.slices.surfaceTriangles);
  Quality reference;
  reference.renderer = Renderer::Raycast;
  const Image ref = r.render(view, look, reference).image;
  EXPECT_GE(test::psnrOf(ref, e.image), 48.0);
  EXPECT_GE(test::psnrOf(ref, m.image), 42.0);  // 44.3 dB: the simplified sphere is 86 triangles
  EXPECT_GE(test::psnrOf(e.image, m.image), 42.0);
}

// The simplified surface's levels: each coarser, within its error of the sphere (the vertices stay
// on the input surface; a triangle's centroid falls inside the sphere by at most its error), and a
// frame draws the coarsest level whose error fits its pixels (orthographic: a pixel is the view's
// height over its rows, whatever the depth), level 0 when no error is allowed.
TEST(SceneRenderer, SmallFramesDrawCoarserLevelsOfTheSimplifiedSurface) {
  test::gl();
  SceneRenderer r(sphereScene({97, 97, 97}, 40.0));
  std::unique_ptr<PreparedSurface> made = withLevels(r.scene(), 0.0f);
  ASSERT_EQ(made->simplified.size(), size_t(kSimplifiedLevels));
  std::vector<size_t> counts;
  for (int k = 0; k < kSimplifiedLevels; ++k) {
    const TriangleMesh& m = made->simplified[size_t(k)];
    counts.push_back(m.triangles.size());
    EXPECT_LT(counts.back(), k == 0 ? made->smooth->triangles.size() : counts[size_t(k) - 1]) << k;
    EXPECT_EQ(m.normals.size(), m.vertices.size()) << k;
    double sag = 0.0;
    for (const glm::uvec3& t : m.triangles) {
      const glm::dvec3 c = (glm::dvec3(m.vertices[t.x]) + glm::dvec3(m.vertices[t.y]) + glm::dvec3(m.vertices[t.z])) / 3.0;
      sag = std::max(sag, 40.0 - glm::length(c - glm::dvec3(48.0)));
    }
    EXPECT_LE(sag, double(1 << k) + 0.1) << k;  // the 0.1: level 0's input lies within a tenth of a voxel
  }
  r.adoptSurface(std::move(made));
  Look look = surfaceAtZero();
  View view = frontOfGrid97();
  Quality q;
  q.simplifiedSurface = true;
  q.cutToSlabs = false;
  q.maxBrickEdge = kSimplifiedBlockVoxels;
  // Pixels of 1, 3 and 8 voxels: levels 0, 1 and 3 at one pixel's error; level 2 at 3 voxels when
  // the error may be two pixels.
  for (const auto& [pixels, errorPixels, level] : {std::tuple{120, 1.0, 0}, {40, 1.0, 1}, {15, 1.0, 3}, {40, 2.0, 2}, {15, 0.0, 0}}) {
    view.camera.width = view.camera.height = pixels;
    q.surfaceErrorPixels = errorPixels;
    EXPECT_EQ(r.render(view, look, q).stats.slices.surfaceTriangles, counts[size_t(level)]) << pixels << " pixels, " << errorPixels;
  }
  // In perspective, a pixel where the volume is nearest (200 mm from the eye, a 30° field): 0.89 mm
  // at 120 rows (level 0), 3.6 mm at 30 rows (level 1).
  view.camera.ortho = false;
  view.camera.fovDeg = 30.0;
  q.surfaceErrorPixels = 1.0;
  for (const auto& [pixels, level] : {std::pair{120, 0}, {30, 1}}) {
    view.camera.width = view.camera.height = pixels;
    EXPECT_EQ(r.render(view, look, q).stats.slices.surfaceTriangles, counts[size_t(level)]) << pixels << " pixels, perspective";
  }
}

// A larger volume gets coarser levels, up to two pixels of a 128-pixel view of it: the cranium's
// four, the clinical study's five (its slices 0.37 mm apart, the errors' unit), the phantom's six. A capsule of radius 20 along a volume
// 520 voxels long gets a fifth level, of 16 voxels' error, coarser than the fourth and within it.
TEST(SceneRenderer, ALargerVolumeGetsCoarserSimplifiedLevels) {
  const glm::dvec3 iso(1.0);
  EXPECT_EQ(simplifiedLevelCount({1, 1, 1}, iso), 4);
  EXPECT_EQ(simplifiedLevelCount({256, 256, 108}, {0.957, 0.957, 1.5}), 4);  // the cranium
  EXPECT_EQ(simplifiedLevelCount({512, 512, 432}, iso), 4);
  EXPECT_EQ(simplifiedLevelCount({512, 512, 432}, {0.4776, 0.4776, 0.3724}), 5);
  EXPECT_EQ(simplifiedLevelCount({2048, 2048, 1024}, glm::dvec3(0.25)), 6);
  EXPECT_EQ(simplifiedLevelCount({64, 513, 64}, iso), 5);
  EXPECT_EQ(simplifiedLevelCount({2048, 2048, 1024}, iso), 6);
  // Errors are in the smallest spacing, the extent in mm: 400 slices of 2 mm are 800 mm.
  EXPECT_EQ(simplifiedLevelCount({256, 256, 400}, {1.0, 1.0, 2.0}), 5);
  const glm::dvec3 a(30.0, 23.5, 23.5), b(489.0, 23.5, 23.5);
  auto axisDistance = [&](const glm::dvec3& p) { return glm::length(p - glm::mix(a, b, glm::clamp((p.x - a.x) / (b.x - a.x), 0.0, 1.0))); };
  Scene scene;
  scene.volume = test::makeVolume({520, 48, 48}, [&](int i, int j, int k) { return 20.0 - axisDistance(glm::dvec3(i, j, k)); });
  scene.octree = VolumeOctree::build(scene.volume);
  std::unique_ptr<PreparedSurface> made = withLevels(scene, 0.0f);
  ASSERT_EQ(made->simplified.size(), size_t(5));
  for (size_t k = 1; k < made->simplified.size(); ++k) {
    const TriangleMesh& m = made->simplified[k];
    EXPECT_LT(m.triangles.size(), made->simplified[k - 1].triangles.size()) << k;
    double sag = 0.0;
    for (const glm::uvec3& t : m.triangles)
      sag = std::max(sag, 20.0 - axisDistance((glm::dvec3(m.vertices[t.x]) + glm::dvec3(m.vertices[t.y]) + glm::dvec3(m.vertices[t.z])) / 3.0));
    EXPECT_LE(sag, double(1 << k) + 0.1) << k;
  }
}

// A frame asking for a screen-space level of detail draws the surface clustered by the largest
// cubes its pixels allow where the volume is nearest (orthographic: a pixel is the view's height
// over its rows), never builds the full-resolution one, and keeps each clustered surface for the
// next frame; at one voxel, or without the level of detail, it draws the Surface Octree's.
TEST(SceneRenderer, FramesWithALevelOfDetailDrawTheSurfaceClusteredByTheirPixels) {
  test::gl();
  SceneRenderer r(sphereScene({97, 97, 97}, 40.0));  // leaves of 8 voxels: cubes of 8 at most
  Look look = surfaceAtZero();
  View view = frontOfGrid97();
  Quality q;
  q.lodPixels = 1.0;
  // Pixels of 24, 8, 3, 1.5 and 1 voxels: cubes of 8 (the leaf edge), 8, 2, 1 and 1; no
  // full-resolution surface made before a frame needs it.
  for (const auto& [pixels, cubes] : {std::pair{5, 8}, {15, 8}, {40, 2}, {80, 1}, {120, 1}}) {
    view.camera.width = view.camera.height = pixels;
    EXPECT_EQ(r.hasSurface(0.0f), pixels > 80) << pixels << " pixels";
    const FrameStats st = r.render(view, look, q).stats;
    EXPECT_EQ(st.surfaceSpacing, cubes) << pixels << " pixels";
    const size_t triangles = cubes > 1 ? clusteredSurface(VolumeKnots(r.volume(), r.octree()), r.octree(), cubes, 0.0f).triangles.size()
                                       : r.surface(0.0f, SurfaceNormals::Gradient).triangles.size();
    EXPECT_EQ(st.surfaceTriangles, triangles) << pixels << " pixels";
  }
  // Kept: the next frame of the same cubes builds nothing.
  view.camera.width = view.camera.height = 40;
  EXPECT_FALSE(r.render(view, look, q).stats.surfaceBuilt);
  // Close to the full-resolution surface's frame at the same selection, translucent, in perspective.
  view.camera.ortho = false;
  view.camera.fovDeg = 30.0;
  view.camera.width = view.camera.height = 64;
  Quality coarse = q;
  coarse.lodPixels = 1.5;  // 1.68 mm pixels where the volume is nearest (200 mm away): cubes of 2
  Quality exact = coarse;
  exact.lodPixels = 0.0;
  exact.epsilon = 1e9f;  // the same bricks as the coarse frame's: the coarsest (the sphere's field is smooth)
  coarse.epsilon = 1e9f;
  const RenderedFrame c = r.render(view, look, coarse), e = r.render(view, look, exact);
  EXPECT_EQ(c.stats.surfaceSpacing, 2);
  EXPECT_EQ(e.stats.surfaceSpacing, 1);
  EXPECT_EQ(c.selection.texels, e.selection.texels);
  EXPECT_LT(2 * c.stats.surfaceTriangles, e.stats.surfaceTriangles);
  // 33.3 dB: silhouettes and shading moved by less than a pixel (the frames are 25.4 and 24.8 dB
  // from the reference, whose volume is finer than these coarsest bricks).
  EXPECT_GE(test::psnrOf(e.image, c.image), 32.0);
  // The viewer's moving frames keep their simplified levels; the reference its exact surface.
  Quality moving = q;
  moving.simplifiedSurface = true;
  EXPECT_EQ(r.render(view, look, moving).stats.surfaceSpacing, 1);
  Quality reference = coarse;
  reference.renderer = Renderer::Raycast;
  EXPECT_EQ(r.render(view, look, reference).stats.surfaceSpacing, 1);
}

// A viewer's frames do not wait for their surface (Quality::waitForSurface false): before the
// full-resolution surface is adopted they draw the clustered preview a builder made, whatever they
// ask, and build nothing; after, the full-resolution one (finer than a level of detail asks costs
// only the triangles between pixel centres), the preview still kept, and in moving frames until
// the simplified levels come; a later preview leaves it.
TEST(SceneRenderer, FramesThatDoNotWaitDrawTheKeptSurfaceNearestTheirOwn) {
  test::gl();
  SceneRenderer r(sphereScene({65, 65, 65}, 25.0));
  auto preview = [&] {
    auto p = std::make_unique<PreparedSurface>();
    p->iso = 0.0f;
    p->coarse.emplace(8, clusteredSurface(VolumeKnots(r.volume(), r.octree()), r.octree(), 8, 0.0f));
    return p;
  };
  const size_t previewTriangles = preview()->coarse.at(8).triangles.size();
  r.adoptSurface(preview());
  EXPECT_TRUE(r.hasAnySurface(0.0f));
  EXPECT_FALSE(r.hasSurface(0.0f));
  Look look;
  look.tf = warm();
  look.iso = 0.0f;
  const View view = viewFrom(30, r.volume(), 64);
  Quality moving;
  moving.simplifiedSurface = true;
  moving.waitForSurface = false;
  Quality final;
  final.lodPixels = 0.5;
  final.waitForSurface = false;
  for (const Quality& q : {moving, final}) {
    const FrameStats st = r.render(view, look, q).stats;
    EXPECT_EQ(st.surfaceSpacing, 8);
    EXPECT_EQ(st.surfaceTriangles, previewTriangles);
    EXPECT_FALSE(st.surfaceBuilt);
  }
  EXPECT_FALSE(r.hasSurface(0.0f));
  // The full-resolution surface first, its simplified levels after, as the pool's builder hands
  // them over: meanwhile the moving frames draw the preview and make no level.
  std::unique_ptr<PreparedSurface> exact = SceneRenderer::prepareSurface(r.scene(), 0.0f);
  auto levels = std::make_unique<PreparedSurface>();
  levels->iso = 0.0f;
  levels->simplified = SceneRenderer::simplifiedLevels(r.scene(), *exact->smooth);
  r.adoptSurface(std::move(exact));
  ASSERT_TRUE(r.hasSurface(0.0f));
  const size_t full = r.surface(0.0f, SurfaceNormals::Gradient).triangles.size();
  const FrameStats before = r.render(view, look, moving).stats;
  EXPECT_EQ(before.surfaceSpacing, 8);
  EXPECT_EQ(before.surfaceTriangles, previewTriangles);
  EXPECT_FALSE(before.surfaceSimplified);
  EXPECT_NE(r.unsimplified(0.0f), nullptr);
  EXPECT_EQ(r.render(view, look, final).stats.surfaceSpacing, 1);
  r.adoptSurface(std::move(levels));
  EXPECT_EQ(r.unsimplified(0.0f), nullptr);
  const FrameStats after = r.render(view, look, moving).stats;
  EXPECT_EQ(after.surfaceSpacing, 1);
  EXPECT_LT(after.surfaceTriangles, full);  // a simplified level
  EXPECT_TRUE(after.surfaceSimplified);
  EXPECT_EQ(r.render(view, look, final).stats.surfaceTriangles, full);
  Quality coarse = final;
  coarse.lodPixels = 1e6;  // cubes of 8 asked: kept
  EXPECT_EQ(r.render(view, look, coarse).stats.surfaceTriangles, previewTriangles);
  coarse.lodPixels = 2.5 / view.camera.pixelMmAt(glm::dvec3(0.0), glm::dvec3(64.0));  // cubes of 2 asked, not kept: the full-resolution surface
  const FrameStats st = r.render(view, look, coarse).stats;
  EXPECT_EQ(st.surfaceSpacing, 1);
  EXPECT_EQ(st.surfaceTriangles, full);
  r.adoptSurface(preview());
  EXPECT_TRUE(r.hasSurface(0.0f));
  // A frame that waits makes what it asks for.
  coarse.waitForSurface = true;
  const FrameStats made = r.render(view, look, coarse).stats;
  EXPECT_EQ(made.surfaceSpacing, 2);
  EXPECT_TRUE(made.surfaceBuilt);
}

// A scene above the pool's preview size, paged or in memory, gets from the builder thread a
// clustered surface (previewSpacing), then the full-resolution one; the renderer keeps both, and a
// frame that does not wait draws the preview where its pixels allow cubes that large, building nothing.
// About a pixel of a 96-pixel frame of the whole volume, along its longest voxel edge.
TEST(ScenePool, PreviewCubesAreAboutAPixelOfTheSmallestMovingFrame) {
  EXPECT_EQ(previewSpacing({512, 512, 432}, {0.4776, 0.4776, 0.3724}, 8), 4);  // the clinical study: 2.55 mm pixels
  EXPECT_EQ(previewSpacing({2048, 2048, 1024}, {0.25, 0.25, 0.25}, 8), 8);     // the phantom: the leaf edge
  EXPECT_EQ(previewSpacing({2048, 2048, 1024}, {0.25, 0.25, 0.25}, 4), 4);
  EXPECT_EQ(previewSpacing({384, 384, 384}, {1.0, 1.0, 1.0}, 8), 4);           // 4 mm pixels: cubes of 4 fit exactly
  EXPECT_EQ(previewSpacing({383, 383, 383}, {1.0, 1.0, 1.0}, 8), 2);
  EXPECT_EQ(previewSpacing({40, 36, 32}, {1.0, 1.0, 1.0}, 8), 2);              // never finer than 2: cheaper than the full surface
}

TEST(SceneRenderer, ThePoolsBuilderHandsOverAClusteredPreviewFirst) {
  test::gl();
  test::TempDir dir;
  saveScene(dir.file("s.hoct"), sphereScene().volume, sphereScene().octree);
  for (const bool paged : {true, false}) {
    SCOPED_TRACE(paged ? "paged" : "in memory");
    std::mutex mutex;
    std::condition_variable changed;
    bool opened = false, ready = false;
    int buildingSix = 0;
    ScenePool::Events events;
    events.loading = [](uint64_t, const std::string&, const std::string&, double) {};
    events.opened = [&](uint64_t, const std::string&, const SceneSummary* summary, const std::string&) { opened = summary != nullptr; changed.notify_all(); };
    events.surface = [&](uint64_t, const std::string&, float iso, ScenePool::SurfaceState state, const std::string&, double) {
      ready = ready || state == ScenePool::SurfaceState::Ready;
      buildingSix += iso == 6.0f && state == ScenePool::SurfaceState::Building;
    };
    events.wake = [&] { changed.notify_all(); };
    ScenePool::Options options;
    options.loader = [paged](const std::string& path, const std::string&, const Progress*) {
      return paged ? loadScene(path, SceneLoadOptions{false, 1 << 20}) : sphereScene();
    };
    options.previewSamples = 0;
    {
      ScenePool pool(mutex, options, events);
      std::unique_lock<std::mutex> lock(mutex);
      pool.open(1, "k", dir.file("s.hoct"), "", "s");
      changed.wait(lock, [&] { return opened; });
      ScenePool::Frame f = pool.forFrame(1, 5.0f);
      ASSERT_TRUE(f.renderer);
      EXPECT_FALSE(f.surfaceReady);
      EXPECT_TRUE(f.surfaceBuilding);
      while (!ready) {
        changed.wait_for(lock, std::chrono::milliseconds(50));
        pool.collect(lock);
      }
      f = pool.forFrame(1, 5.0f);
      EXPECT_TRUE(f.surfaceReady);
      ASSERT_EQ(f.iso, std::optional<float>(5.0f));
      Look look;
      look.tf = warm();
      look.iso = 5.0f;
      const int preview = previewSpacing(f.renderer->volume().dims(), f.renderer->volume().spacing(), f.renderer->octree().leafEdge());
      EXPECT_EQ(preview, 2);  // (40 mm across: below a voxel a pixel at 96 pixels)
      // Frames asking coarser and coarser cubes: the one asking the preview's draws it, the others the
      // full-resolution surface (finer than asked, never a cube size not kept).
      bool drewPreview = false;
      for (double pixels = 1.0; pixels <= 64.0; pixels *= 2.0) {
        Quality coarse;
        coarse.lodPixels = pixels;
        coarse.waitForSurface = false;
        const FrameStats st = f.renderer->render(viewFrom(20, sphereScene().volume), look, coarse).stats;  // (framed from the samples in memory)
        EXPECT_TRUE(st.surfaceSpacing == 1 || st.surfaceSpacing == preview) << pixels << " pixels";
        EXPECT_FALSE(st.surfaceBuilt) << pixels << " pixels";
        EXPECT_GT(st.surfaceTriangles, 0u);
        drewPreview = drewPreview || st.surfaceSpacing == preview;
      }
      EXPECT_TRUE(drewPreview);
      // Then the simplified levels of the moving frames.
      auto levelsCome = [&](float iso) {
        for (int i = 0; i < 600 && f.renderer->unsimplified(iso); ++i) {
          changed.wait_for(lock, std::chrono::milliseconds(50));
          pool.collect(lock);
        }
        return f.renderer->unsimplified(iso) == nullptr;
      };
      EXPECT_TRUE(levelsCome(5.0f));
      EXPECT_FALSE(pool.forFrame(1, 5.0f).surfaceBuilding);
      // A full-resolution surface kept without its levels (its build stopped before them) is ready at
      // once; the builder makes only the levels, telling no viewer it builds.
      f.renderer->adoptSurface(SceneRenderer::prepareSurface(f.renderer->scene(), 6.0f));
      f = pool.forFrame(1, 6.0f);
      EXPECT_TRUE(f.surfaceReady);
      EXPECT_TRUE(f.surfaceBuilding);
      EXPECT_TRUE(levelsCome(6.0f));
      EXPECT_EQ(buildingSix, 0);
      lock.unlock();
    }
  }
}

// A frame rendered band by band (a viewer's large final frame, between whose bands other clients'
// frames are drawn) is the whole frame, bit for bit: both renderers, the translucent surface cut
// into slabs, perspective and orthographic, with a cutting plane; a band that misses part of the
// volume skips its bricks.
TEST(SceneRenderer, AFrameInBandsIsTheWholeFrame) {
  test::gl();
  SceneRenderer r(sphereScene());
  Look look;
  look.tf = warm();
  look.iso = 4.0f;
  look.surfaceColor = glm::vec4(0.9f, 0.8f, 0.7f, 0.5f);
  for (const bool ortho : {false, true})
    for (const bool cut : {false, true})
      for (const Renderer renderer : {Renderer::Slices, Renderer::Raycast}) {
        View view = viewFrom(40, r.volume(), 61);
        view.camera.height = 53;
        view.camera.ortho = ortho;
        view.camera.orthoHeight = 40.0;
        Look l = look;
        if (cut) l.cut = CutPlane{glm::dvec3(19.5, 17.5, 15.5), glm::dvec3(0.3, 1.0, 0.2)};
        Quality whole;
        whole.renderer = renderer;
        const RenderedFrame all = r.render(view, l, whole);
        Image merged(61, 53);
        size_t fewest = SIZE_MAX;  // bricks of the band that meets fewest
        for (int y = 0; y < 53; y += 10) {
          Quality band = whole;
          band.rows = glm::ivec2(y, std::min(y + 10, 53));
          const RenderedFrame part = r.render(view, l, band);
          ASSERT_EQ(part.image.width, 61);
          ASSERT_EQ(part.image.height, band.rows->y - band.rows->x) << "the band's rows only";
          for (int row = band.rows->x; row < band.rows->y; ++row)
            for (int x = 0; x < 61; ++x) merged.at(x, row) = part.image.at(x, row - band.rows->x);
          fewest = std::min(fewest, part.stats.slices.bricks);
        }
        EXPECT_EQ(merged.pixels, all.image.pixels) << "ortho " << ortho << " cut " << cut << " renderer " << int(renderer);
        if (renderer == Renderer::Slices) {
          EXPECT_LT(fewest, all.stats.slices.bricks) << "a band draws the bricks it meets";
        }
      }
  View view = viewFrom(40, r.volume());
  Quality bad;
  bad.rows = glm::ivec2(10, 10);
  EXPECT_THROW(r.render(view, look, bad), ValueError);
  bad.rows = glm::ivec2(0, 49);
  EXPECT_THROW(r.render(view, look, bad), ValueError);
  bad.rows = glm::ivec2(0, 8);
  bad.progressive = 2;
  EXPECT_THROW(r.render(view, look, bad), ValueError);
}

// A large frame's target made ahead on another thread, in a context sharing the renderer's, draws
// the frame the renderer's own would; asked before the renderer has a context, or for a size kept
// already, nothing is made.
TEST(SceneRenderer, ATargetMadeAheadOnAnotherThreadDrawsTheSameFrame) {
  test::gl();
  SceneRenderer ahead(sphereScene()), here(sphereScene());
  Look look;
  look.tf = warm();
  look.iso = 4.0f;
  look.surfaceColor = glm::vec4(0.9f, 0.8f, 0.7f, 0.5f);
  ahead.prepareTarget(61, 53);  // no context yet: nothing to share
  View small = viewFrom(40, ahead.volume(), 20);
  ahead.render(small, look, Quality{});
  EXPECT_EQ(ahead.targetsMadeAhead(), 0u);
  View view = viewFrom(40, ahead.volume(), 61);
  view.camera.height = 53;
  ahead.prepareTarget(61, 53);
  const RenderedFrame a = ahead.render(view, look, Quality{});
  EXPECT_EQ(ahead.targetsMadeAhead(), 1u);
  const RenderedFrame b = here.render(view, look, Quality{});
  ASSERT_EQ(a.image.pixels.size(), size_t(61 * 53));
  EXPECT_EQ(a.image.pixels, b.image.pixels);
  EXPECT_GT(std::count_if(a.image.pixels.begin(), a.image.pixels.end(), [](const glm::vec4& p) { return p.a > 0.1f; }), 500) << "the sphere is drawn";
  ahead.prepareTarget(61, 53);  // kept: not made again
  EXPECT_EQ(ahead.render(view, look, Quality{}).image.pixels, b.image.pixels);
  EXPECT_EQ(ahead.targetsMadeAhead(), 1u);
}

TEST(SceneRenderer, TextureMemoryStaysWithinItsLimitAcrossFrames) {
  test::gl();
  Look look;
  look.tf = warm();
  Quality coarse;  // budgets, so that each frame picks its own levels and bricks
  coarse.budgetPercent = 40;
  SceneRenderer unlimited(sphereScene());
  const View front = viewFrom(0, unlimited.volume());
  const RenderedFrame full = unlimited.render(front, look, coarse);
  const uint64_t limit = unlimited.textureBytes() / 2;
  SceneRenderer limited(sphereScene(), SceneRenderer::Options{limit, nullptr});
  for (const double percent : {100.0, 25.0, 60.0, 12.5, 40.0}) {
    const View view = viewFrom(percent, limited.volume());
    Quality q = coarse;
    q.budgetPercent = percent;
    const RenderedFrame f = limited.render(view, look, q);
    unlimited.render(view, look, q);
    // A frame draws all its bricks; afterwards the least recently used go until the limit holds.
    EXPECT_LE(limited.textureBytes(), std::max(limit, f.stats.slices.textureBytes)) << percent;
  }
  EXPECT_LT(limited.textureBytes(), unlimited.textureBytes());  // the unlimited one kept every view's bricks
  // The limit changes which bricks stay, never the image.
  EXPECT_EQ(limited.render(front, look, coarse).image.pixels, full.image.pixels);
}

// A frame at a fraction of its size is the small frame magnified, for both renderers, and the
// fraction is checked.
TEST(SceneRenderer, AFrameAtAFractionOfItsSizeIsTheSmallFrameMagnified) {
  test::gl();
  SceneRenderer r(sphereScene());
  const Look look = surfaceAtZero();
  View view = viewFrom(30, r.volume(), 48);
  View small = view;
  small.camera.width = small.camera.height = 24;
  for (const Renderer renderer : {Renderer::Slices, Renderer::Raycast}) {
    Quality q;
    q.renderer = renderer;
    q.step = 1.0;
    const Image smallImage = r.render(small, look, q).image;
    q.imageScale = 0.5;
    const Image scaled = r.render(view, look, q).image;
    ASSERT_EQ(scaled.width, 48);
    const Image want = resampled(smallImage, 48, 48);
    for (size_t i = 0; i < want.pixels.size(); ++i) ASSERT_EQ(scaled.pixels[i], want.pixels[i]) << i;
  }
  for (const double bad : {0.0, 1.5, std::nan("")}) {
    Quality q;
    q.imageScale = bad;
    try {
      r.render(view, look, q);
      ADD_FAILURE() << "image scale " << bad << " was accepted";
    } catch (const ValueError& e) {
      EXPECT_THAT(e.what(), HasSubstr("--image-scale"));
    }
  }
  Quality band;
  band.imageScale = 0.5;
  band.rows = glm::ivec2(0, 10);
  EXPECT_THROW(r.render(view, look, band), ValueError);
}

// Each renderer reads the frame's look and quality in one place: every quality it honours reaches
// its options, the grid frame's cut and volume of interest by address.
TEST(SceneRenderer, EachRendererMakesItsOptionsFromTheFramesLookAndQuality) {
  FrameGrid grid;
  grid.cut = CutPlane{glm::dvec3(1, 2, 3), glm::dvec3(0, 0, 1)};
  grid.voi = VolumeOfInterest{};
  Look look = surfaceAtZero();
  look.shading = false;
  look.cutLine = false;
  Quality q;
  const SlicesOptions s0 = slicesOptions(grid, look, q, nullptr);
  EXPECT_EQ(s0.stepVoxels, 0.5);
  EXPECT_EQ(raycastOptions(grid, look, q, nullptr).stepVoxels, 0.25);
  EXPECT_EQ(raycastOptions(grid, look, q, nullptr).refineLevels, 1);
  q.step = 1.7;
  q.texelBits = TexelBits::Sixteen;
  q.proxy = Proxy::Shells;
  q.cutToSlabs = false;
  q.region = RegionBox{};
  q.rows = glm::ivec2(3, 9);
  const TriangleMesh mesh;
  const SlicesOptions s = slicesOptions(grid, look, q, &mesh);
  EXPECT_EQ(s.stepVoxels, 1.7);
  EXPECT_FALSE(s.shading);
  EXPECT_FALSE(s.cutLine);
  EXPECT_EQ(s.texelBits, TexelBits::Sixteen);
  EXPECT_EQ(s.proxy, Proxy::Shells);
  EXPECT_FALSE(s.cutToSlabs);
  EXPECT_EQ(s.surface, &mesh);
  EXPECT_EQ(s.surfaceColor, look.surfaceColor);
  EXPECT_EQ(s.cut, &*grid.cut);
  EXPECT_EQ(s.voi, &*grid.voi);
  EXPECT_EQ(s.region, &*q.region);
  EXPECT_EQ(s.rows, q.rows);
  EXPECT_EQ(s.textures, nullptr);  // the engine's to give
  q.adaptive = 4.0;
  const RaycastOptions r = raycastOptions(grid, look, q, nullptr);
  EXPECT_EQ(r.stepVoxels, 1.7);
  EXPECT_FALSE(r.shading);
  EXPECT_EQ(r.surfaceColor, look.surfaceColor);
  EXPECT_EQ(r.cut, &*grid.cut);
  EXPECT_EQ(r.voi, &*grid.voi);
  EXPECT_EQ(r.region, &*q.region);
  EXPECT_EQ(r.rows, q.rows);
  EXPECT_EQ(r.refineLevels, 4);  // an adaptive tolerance alone refines in four levels
  EXPECT_FLOAT_EQ(r.refineTolerance, 4.0f / 255.0f);
  q.progressive = 3;
  EXPECT_EQ(raycastOptions(grid, look, q, nullptr).refineLevels, 3);
}

TEST(SceneRenderer, ProgressiveFramesAndValidation) {
  test::gl();
  SceneRenderer r(sphereScene());
  Look look;
  look.tf = warm();
  Quality q;
  q.progressive = 3;
  std::vector<uint64_t> texels;
  const RenderedFrame last = r.render(viewFrom(30, r.volume()), look, q, [&](int level, int levels, const Image&, const FrameStats& st) {
    EXPECT_EQ(levels, 3);
    EXPECT_EQ(level, int(texels.size()) + 1);
    texels.push_back(st.slices.texels);
  });
  ASSERT_EQ(texels.size(), 2u);
  EXPECT_LE(texels[0], texels[1]);
  EXPECT_LE(texels[1], last.stats.slices.texels);
  Quality bad;
  bad.step = 9.0;
  try {
    r.render(viewFrom(30, r.volume()), look, bad);
    ADD_FAILURE() << "a step of 9 voxels was accepted";
  } catch (const ValueError& e) {
    EXPECT_THAT(e.what(), HasSubstr("--step"));
  }
  Look dark = look;
  dark.surfaceColor.a = 2.0f;
  EXPECT_THROW(r.render(viewFrom(30, r.volume()), dark, Quality{}), ValueError);
  View tiny = viewFrom(30, r.volume());
  tiny.camera.width = 0;
  EXPECT_THROW(r.render(tiny, look, Quality{}), ValueError);
}

}  // namespace
}  // namespace hyb
