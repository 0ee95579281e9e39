// The paged knot store: bricks read back bit-exactly, damage refused by block, frames identical to
// the in-memory ones whatever the cache's bound.
#include "hybrid_octree/knot_store.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <array>
#include <cstring>
#include <random>

#include "hybrid_octree/coarse_surface.h"
#include "hybrid_octree/hybrid_io.h"
#include "render/slices/brick_textures.h"
#include "render/patient_view.h"
#include "render/scene_renderer.h"
#include "render_util.h"
#include "test_util.h"

namespace hyb {
namespace {

using ::testing::HasSubstr;

// A sphere of bone-like values in noisy soft tissue, @p dims spanning several store blocks, held as @p type.
Volume noisyHead(glm::ivec3 dims, ScalarType type) {
  std::mt19937 rng(7);
  std::uniform_int_distribution<int> noise(-20, 20);
  const glm::dvec3 c = glm::dvec3(dims - 1) * 0.5;
  const size_t n = size_t(dims.x) * size_t(dims.y) * size_t(dims.z);
  std::vector<int16_t> s(n);
  for (int k = 0, i = 0; k < dims.z; ++k)
    for (int y = 0; y < dims.y; ++y)
      for (int x = 0; x < dims.x; ++x, ++i) {
        const double r = glm::length((glm::dvec3(x, y, k) - c) / (c + 1.0));
        s[size_t(i)] = int16_t((r < 0.6 ? 90 : r < 0.75 ? 200 : 30) + noise(rng));
      }
  if (type == ScalarType::Int16) return Volume(dims, glm::dvec3(0.7, 0.8, 1.1), type, SampleArray(std::move(s)), "head");
  if (type == ScalarType::UInt8) {
    std::vector<uint8_t> u(n);
    for (size_t i = 0; i < n; ++i) u[i] = uint8_t(std::max(0, int(s[i])));
    return Volume(dims, glm::dvec3(0.7, 0.8, 1.1), type, SampleArray(std::move(u)), "head");
  }
  std::vector<float> f(n);
  for (size_t i = 0; i < n; ++i) f[i] = float(s[i]) * 0.37f;
  return Volume(dims, glm::dvec3(0.7, 0.8, 1.1), type, SampleArray(std::move(f)), "head");
}

// Soft tissue faint, the shell opaque: what the paged frames draw from noisyHead.
TransferFunction headTf() { return TransferFunction({{60.0f, {1, 1, 1}, 0.0f}, {120.0f, {1.0f, 0.6f, 0.4f}, 0.05f}, {220.0f, {1.0f, 1.0f, 0.9f}, 0.4f}}, "head"); }

// noisyHead (int16, spanning several store blocks) and its octree, saved as a scene file in a
// temporary directory.
struct SavedHead {
  test::TempDir dir;
  Volume v = noisyHead({70, 45, 37}, ScalarType::Int16);
  VolumeOctree t = VolumeOctree::build(v);
  std::string path = dir.file("h.hoct");
  SavedHead() { saveScene(path, v, t); }
};

bool sameBits(const std::vector<glm::vec4>& a, const std::vector<glm::vec4>& b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(glm::vec4)) == 0;
}

TEST(KnotStore, EveryBrickReadsBackAsTheBrickMadeInMemory) {
  test::TempDir dir;
  for (const ScalarType type : {ScalarType::Int16, ScalarType::UInt8, ScalarType::Float32})
    for (const bool prefilter : {true, false}) {
      SCOPED_TRACE(std::string(scalarName(type)) + (prefilter ? " prefiltered" : " point-subsampled"));
      const Volume v = noisyHead({70, 45, 37}, type);
      const VolumeOctree t = VolumeOctree::build(v, VolumeOctreeOptions{8, prefilter});
      saveScene(dir.file("h.hoct"), v, t);
      const Scene paged = loadScene(dir.file("h.hoct"), SceneLoadOptions{false, 0});
      ASSERT_TRUE(paged.knots);
      EXPECT_FALSE(paged.volume.hasSamples());
      EXPECT_EQ(paged.knots->samples(), v.samples());  // the samples, in their own type
      const VolumeKnots memory(v, t);
      // Every lattice of every node at every level, its coarse lattice, and its blended texels.
      size_t lattices = 0, expected = 0;
      for (uint32_t i = 0; i < t.nodes().size(); ++i) {
        const OctreeNode& n = t.nodes()[i];
        expected += size_t(t.maxLevel(n)) + 1;
        for (int p = 0; p <= t.maxLevel(n); ++p) {
          ASSERT_TRUE(sameBits(latticeKnots(*paged.knots, t.lattice(n, p)), latticeKnots(memory, t.lattice(n, p)))) << "node " << i << " p " << p;
          if (i > 0) {
            ASSERT_TRUE(sameBits(latticeKnots(*paged.knots, t.coarseLattice(n, p)), latticeKnots(memory, t.coarseLattice(n, p))));
            Brick b;
            b.node = i;
            b.p = p;
            b.coarseCorners = 0x5a;
            ASSERT_TRUE(sameBits(brickTexels(*paged.knots, paged.octree, b), brickTexels(memory, t, b)));
          }
          ++lattices;
        }
      }
      EXPECT_EQ(lattices, expected);
      // The store is smaller than the samples it holds, in their type, for every level.
      EXPECT_LT(paged.knots->compressedBytes(), v.voxelCount() * scalarSize(v.storedType()) * 2);
    }
}

// A source that counts its reads: the blocks a KnotSampler copies (KnotSource::sampleBlock's default).
struct CountingKnots final : KnotSource {
  const KnotSource& inner;
  mutable int reads = 0;
  explicit CountingKnots(const KnotSource& k) : inner(k) {}
  glm::ivec3 dims() const override { return inner.dims(); }
  glm::dvec3 spacing() const override { return inner.spacing(); }
  void read(int s, const glm::ivec3& lo, const glm::ivec3& count, float* values, glm::vec3* gradients) const override {
    ++reads;
    inner.read(s, lo, count, values, gradients);
  }
};

// The ray tracer's sampler gives Volume::sample's numbers bit for bit, and keeps every block of
// a beam its table can hold: a block is read once however the rays alternate between them (a
// direct-mapped table read two blocks sharing a slot again for every ray).
TEST(KnotSampler, SamplesAsTheVolumeAndReadsEachBlockOnceWhileItsSetHoldsIt) {
  const Volume v = noisyHead({130, 70, 40}, ScalarType::Int16);  // 5 × 3 × 2 blocks of 32
  const VolumeOctree t = VolumeOctree::build(v);
  const VolumeKnots knots(v, t);
  const CountingKnots counting(knots);
  KnotSampler sampler(counting, KnotSampler::kWays);  // one set: any four blocks
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  const glm::vec3 hi(v.dims() - 1);
  for (int i = 0; i < 2000; ++i) {
    const glm::vec3 p = glm::vec3(u(rng), u(rng), u(rng)) * hi;
    const float a = sampler.sample(p), b = v.sample(p);
    const glm::vec3 g = sampler.sampleGradient(p), h = v.sampleGradient(p);
    ASSERT_EQ(std::memcmp(&a, &b, sizeof a), 0) << i;
    ASSERT_EQ(std::memcmp(&g, &h, sizeof g), 0) << i;
  }
  // Four blocks, visited in turn by 100 "rays": read once each.
  KnotSampler beam(counting, KnotSampler::kWays);
  const std::array<glm::vec3, 4> blocks{glm::vec3(5, 5, 5), glm::vec3(40, 5, 5), glm::vec3(70, 40, 5), glm::vec3(100, 5, 35)};
  counting.reads = 0;
  for (int ray = 0; ray < 100; ++ray)
    for (const glm::vec3& p : blocks) EXPECT_EQ(beam.sample(p + 0.25f * float(ray % 4)), v.sample(p + 0.25f * float(ray % 4)));
  EXPECT_EQ(counting.reads, 4);
  // A fifth replaces the least recently used (the first); a beam of five blocks in a set of four
  // then reads each again, each replacing the next one it needs: what the table's size bounds.
  beam.sample(glm::vec3(5, 40, 35));
  EXPECT_EQ(counting.reads, 5);
  beam.sample(blocks[3]);
  EXPECT_EQ(counting.reads, 5);
  for (const glm::vec3& p : blocks) beam.sample(p);
  EXPECT_EQ(counting.reads, 8);  // the first three again; the last was used just before
}

TEST(KnotStore, ADamagedBlockIsRefusedByName) {
  test::TempDir dir;
  const Volume v = noisyHead({70, 45, 37}, ScalarType::Int16);
  saveScene(dir.file("h.hoct"), v, VolumeOctree::build(v));
  const std::vector<uint8_t> good = test::readBytes(dir.file("h.hoct"));
  uint64_t volumeBytes = 0, blockBytes = 0;
  std::memcpy(&volumeBytes, &good[16 + 4], 8);
  const size_t blocksAt = 16 + 16 + size_t(volumeBytes);  // KDAT's section header
  std::memcpy(&blockBytes, &good[blocksAt + 4], 8);
  ASSERT_EQ(std::string(good.begin() + ptrdiff_t(blocksAt), good.begin() + ptrdiff_t(blocksAt) + 4), "KDAT");
  // One flipped bit in the last (finest) block: the file opens paged, and the block is refused when read.
  std::vector<uint8_t> bad = good;
  bad[blocksAt + 16 + size_t(blockBytes) - 5] ^= 0x10;
  test::writeBytes(dir.file("bad.hoct"), bad);
  const Scene paged = loadScene(dir.file("bad.hoct"), SceneLoadOptions{false, 0});
  const glm::ivec3 d = v.dims();
  std::vector<float> values(size_t(d.x) * d.y * d.z);
  try {
    paged.knots->read(1, glm::ivec3(0), d, values.data(), nullptr);
    ADD_FAILURE() << "a corrupt block was read";
  } catch (const IoError& e) {
    EXPECT_THAT(e.what(), HasSubstr("bad.hoct: knot store block "));
    EXPECT_THAT(e.what(), HasSubstr(" of spacing 1 is corrupt (checksum mismatch)"));
  }
  // Loading the samples whole reads every block: refused the same way.
  EXPECT_THROW(
      {
        try {
          loadScene(dir.file("bad.hoct"));
        } catch (const IoError& e) {
          EXPECT_THAT(e.what(), HasSubstr("of spacing 1 is corrupt"));
          throw;
        }
      },
      IoError);
  // A file cut inside its blocks is refused before anything is read.
  test::writeBytes(dir.file("cut.hoct"), std::vector<uint8_t>(good.begin(), good.begin() + ptrdiff_t(blocksAt + 16 + blockBytes / 2)));
  try {
    loadScene(dir.file("cut.hoct"), SceneLoadOptions{false, 0});
    ADD_FAILURE() << "a truncated store was opened";
  } catch (const IoError& e) {
    EXPECT_THAT(e.what(), HasSubstr("truncated scene file (section 1 needs"));
  }
}

// --memory bounds a paged scene's octrees and its block cache together: the cache gets what the
// octrees leave, at least a quarter of the bound; no bound, no limit.
TEST(KnotStore, TheOctreesCountAgainstAPagedScenesMemory) {
  test::TempDir dir;
  const Volume v = noisyHead({70, 45, 37}, ScalarType::Int16);
  const VolumeOctree t = VolumeOctree::build(v);
  const SurfaceOctree surface = SurfaceOctree::build(v, t, 150.0f);
  saveScene(dir.file("h.hoct"), v, t, &surface);
  const Scene unbounded = loadScene(dir.file("h.hoct"), SceneLoadOptions{false, 0});
  EXPECT_EQ(unbounded.knots->cacheStats().limit, 0u);
  const uint64_t octrees = unbounded.octree.bytesUsed() + unbounded.surface->bytesUsed();
  ASSERT_GT(octrees, 10000u);
  EXPECT_EQ(loadScene(dir.file("h.hoct"), SceneLoadOptions{false, octrees + 300000}).knots->cacheStats().limit, 300000u);
  EXPECT_EQ(loadScene(dir.file("h.hoct"), SceneLoadOptions{false, octrees}).knots->cacheStats().limit, octrees / 4);
  EXPECT_EQ(sceneCacheBytes(1000, 900), 250u);
  EXPECT_EQ(sceneCacheBytes(1000, 100), 900u);
  EXPECT_EQ(sceneCacheBytes(0, 100), 0u);
}

TEST(KnotStore, PagedFramesEqualInMemoryFramesWithinATenthOfTheData) {
  test::gl();
  const SavedHead head;
  const auto& [dir, v, t, path] = head;
  const uint64_t tenth = v.voxelCount() * 2 / 10;
  SceneRenderer paged(loadScene(path, SceneLoadOptions{false, 0})), memory(loadScene(path));
  KnotStore& store = *paged.scene().knots;
  store.setCacheLimit(tenth);
  Look look;
  look.tf = headTf();
  const std::vector<glm::dvec3> visible = visiblePoints(v, t, look.tf);
  // Framed alike from the store's samples and from memory.
  EXPECT_EQ(visiblePoints(paged.volume(), paged.octree(), look.tf, std::nullopt, &store), visible);
  Quality coarse;
  coarse.epsilon = 40.0;  // coarse bricks, blended towards coarser neighbours
  Quality budget;
  budget.budgetMb = 0.02;  // ranked by measured image errors, read through the store
  const auto compare = [&](const std::vector<Quality>& qualities) {
    for (const double azimuth : {0.0, 70.0, 150.0, 250.0}) {
      SCOPED_TRACE(azimuth);
      View view;
      view.camera = fitCamera(visible, orbitDirection(azimuth, 20), {30, false, 40, 40}, 0.05);
      for (const Quality& q : qualities) {
        const RenderedFrame a = paged.render(view, look, q), b = memory.render(view, look, q);
        if (q.renderer == Renderer::Slices) {
          EXPECT_GT(a.stats.slices.bricks, 0u);
        }
        EXPECT_EQ(a.stats.slices.bricks, b.stats.slices.bricks);
        EXPECT_EQ(a.stats.rays.samples, b.stats.rays.samples);
        EXPECT_EQ(a.image.pixels, b.image.pixels);
        EXPECT_LE(store.cacheStats().bytesHeld, tenth + kMaxStoreBlockBytes);
      }
    }
  };
  // Volume frames read only the blocks their bricks need.
  compare({Quality{}, coarse});
  EXPECT_FALSE(paged.volume().hasSamples());
  // The image errors a budget ranks by read the store a node at a time, never the samples whole.
  compare({budget});
  EXPECT_FALSE(paged.volume().hasSamples());
  // The reference ray tracer reads the samples through the same cache, a cached block at a time in place, the
  // face of a cutting plane included.
  Quality reference;
  reference.renderer = Renderer::Raycast;
  reference.step = 0.7;
  compare({reference});
  look.cut = CutPlane{glm::dvec3(24.0, 17.0, 20.0), glm::dvec3(0.3, 1.0, 0.2)};
  compare({reference});
  look.cut.reset();
  EXPECT_FALSE(paged.volume().hasSamples());
  // A translucent surface is extracted and shaded a leaf and a few blocks at a time through the
  // same cache.
  look.iso = 150.0f;
  look.surfaceColor = glm::vec4(0.9f, 0.9f, 0.8f, 0.5f);
  compare({Quality{}});
  EXPECT_FALSE(paged.volume().hasSamples());
  // So is the surface clustered for a frame's level of detail (by cubes of 2 or 4 voxels here).
  Quality lod;
  lod.lodPixels = 3.0;
  compare({lod});
  EXPECT_GT(paged.render(View{fitCamera(visible, orbitDirection(0, 20), {30, false, 40, 40}, 0.05)}, look, lod).stats.surfaceSpacing, 1);
  for (const int s : {2, 4}) {
    const TriangleMesh a = clusteredSurface(store, t, s, 150.0f), b = clusteredSurface(VolumeKnots(v, t), t, s, 150.0f);
    ASSERT_GT(a.triangles.size(), 100u);
    EXPECT_EQ(a.triangles, b.triangles);
    EXPECT_EQ(a.vertices, b.vertices);
    EXPECT_EQ(a.normals, b.normals);
  }
  EXPECT_FALSE(paged.volume().hasSamples());
  const StoreCacheStats stats = store.cacheStats();
  EXPECT_GT(stats.hits, 0u);
  EXPECT_GT(stats.misses, 0u);
  EXPECT_GT(stats.evicted, 0u);
  EXPECT_EQ(stats.limit, tenth);
}

// A moving frame packs at most Quality::packTexels of its selection's bricks, nearest the eye
// first, and draws the others from coarser bricks, never a hole; the frames after pack the rest,
// so the cut reaches the exact one over a few frames, whether the samples are in memory or paged.
TEST(KnotStore, MovingFramesPackABoundedShareOfNewTexturesAndReachTheExactFrame) {
  test::gl();
  const SavedHead head;
  const auto& [dir, v, t, path] = head;
  Look look;
  look.tf = headTf();
  View view;
  view.camera = fitCamera(visiblePoints(v, t, look.tf), orbitDirection(30.0, 20), {30, false, 40, 40}, 0.05);
  for (const bool paged : {false, true}) {
    SceneRenderer r(loadScene(path, SceneLoadOptions{!paged, 0})), exact(loadScene(path));
    const RenderedFrame want = exact.render(view, look, Quality{});
    ASSERT_GT(want.stats.slices.bricks, 20u);
    const uint64_t brickTexels = want.selection.texels / want.stats.slices.bricks;
    Quality moving;
    moving.waitForBricks = false;
    moving.packTexels = 2 * brickTexels;
    int frames = 0;
    size_t coarser = std::numeric_limits<size_t>::max();
    for (; frames < 40; ++frames) {
      if (paged) r.scene().knots->waitForPrefetch();
      const RenderedFrame f = r.render(view, look, moving);
      // Never a hole: wherever the exact frame is half opaque, this one shows something.
      size_t holes = 0;
      for (size_t i = 0; i < want.image.pixels.size(); ++i) holes += want.image.pixels[i].a >= 0.5f && f.image.pixels[i].a < 0.1f;
      EXPECT_EQ(holes, 0u) << paged << " frame " << frames;
      EXPECT_LE(f.stats.bricksNotResident, coarser) << paged << " frame " << frames;
      coarser = f.stats.bricksNotResident;
      if (coarser == 0) {
        EXPECT_EQ(f.image.pixels, want.image.pixels) << paged;
        break;
      }
    }
    // The bound spread the packing over frames: about one per two of the view's bricks.
    EXPECT_GE(frames + 1, int(want.stats.slices.bricks / 4)) << paged;
    EXPECT_LT(frames, 40) << paged;
  }
}

TEST(KnotStore, AColdCacheDrawsCoarserBricksNeverAHoleWhileThePrefetchThreadLoadsTheRest) {
  test::gl();
  const SavedHead head;
  const auto& [dir, v, t, path] = head;
  SceneRenderer::Options options;
  options.readAnywayBytes = 8192;  // the levels of spacing 8 and more are read uncached
  SceneRenderer paged(loadScene(path, SceneLoadOptions{false, 0}), options), memory(loadScene(path));
  KnotStore& store = *paged.scene().knots;
  ASSERT_EQ(store.coarseSpacing(options.readAnywayBytes), 8);
  Look look;
  look.tf = headTf();
  const std::vector<glm::dvec3> visible = visiblePoints(v, t, look.tf);
  Quality now;
  now.waitForBricks = false;
  const glm::ivec3 cells = v.dims() - 1;
  View view;
  view.camera = fitCamera(visible, orbitDirection(0.0, 20), {30, false, 40, 40}, 0.05);
  const RenderedFrame want = memory.render(view, look, Quality{});
  const RenderedFrame first = paged.render(view, look, now);
  // Cold: coarser bricks where the knots are not cached, and still every cell drawn once.
  EXPECT_GT(first.stats.bricksNotResident, 0u);
  EXPECT_GT(first.selection.maxError, want.selection.maxError);
  uint64_t covered = 0;
  for (const Brick& b : first.selection.bricks) {
    glm::ivec3 lo, hi;
    t.voxelBox(t.nodes()[b.node], &lo, &hi);
    covered += uint64_t(hi.x - lo.x) * uint64_t(hi.y - lo.y) * uint64_t(hi.z - lo.z);
  }
  EXPECT_EQ(covered, uint64_t(cells.x) * uint64_t(cells.y) * uint64_t(cells.z));
  // Never a hole: wherever the exact frame is half opaque, the coarse one shows something. (Its
  // lattices 8 voxels apart blur the 5-voxel shell: 12.1 dB.)
  size_t holes = 0;
  for (size_t i = 0; i < want.image.pixels.size(); ++i) holes += want.image.pixels[i].a >= 0.5f && first.image.pixels[i].a < 0.1f;
  EXPECT_EQ(holes, 0u);
  EXPECT_GT(test::psnrOf(first.image, want.image), 10.0);
  // Once the prefetch thread has loaded the rest, the frame is the exact one.
  store.waitForPrefetch();
  EXPECT_EQ(store.prefetchPending(), 0u);
  const RenderedFrame then = paged.render(view, look, now);
  EXPECT_EQ(then.stats.bricksNotResident, 0u);
  EXPECT_EQ(then.image.pixels, want.image.pixels);
  // Another view of the same bricks finds them all.
  view.camera = fitCamera(visible, orbitDirection(150.0, 20), {30, false, 40, 40}, 0.05);
  const RenderedFrame other = paged.render(view, look, now);
  EXPECT_EQ(other.stats.bricksNotResident, 0u);
  EXPECT_EQ(other.image.pixels, memory.render(view, look, Quality{}).image.pixels);
  EXPECT_FALSE(paged.volume().hasSamples());
}

}  // namespace
}  // namespace hyb
