#include "hybrid_octree/surface_octree.h"

#include <gtest/gtest.h>

#include <random>

#include "surface/cgal_geometry.h"
#include "surface/dmc.h"
#include "surface/dmc_table.h"
#include "test_util.h"
#include "volume/plane_source.h"
#include "volume/volume_io.h"

namespace hyb {
namespace {

double area(const TriangleMesh& m) {
  double a = 0;
  for (const glm::uvec3& t : m.triangles) {
    const glm::dvec3 p = m.vertices[t.x], q = m.vertices[t.y], r = m.vertices[t.z];
    a += 0.5 * glm::length(glm::cross(q - p, r - p));
  }
  return a;
}

struct Compared {
  TriangleMesh dmc, octree;
  SurfaceOctree so;
};

Compared compare(const Volume& v, float iso, SurfaceOctreeOptions options = {}) {
  const VolumeOctree t = VolumeOctree::build(v);
  Compared c;
  c.dmc = toTriangleMesh(extractDiscMC(v, iso), v.spacing());
  c.so = SurfaceOctree::build(v, t, iso, options);
  c.octree = fineMeshToTriangles(c.so.reconstruct(), v.spacing());
  return c;
}

// Face f of @p m as its plane and its loop's points (fine coordinates).
std::pair<PlaneId, std::vector<glm::ivec3>> faceOf(const DiscreteMesh& m, size_t f) {
  std::vector<glm::ivec3> loop;
  for (uint32_t k = m.offsets[f]; k < m.offsets[f + 1]; ++k) loop.push_back(m.vertices[m.indices[k]]);
  return {m.planes[f], loop};
}

// Reconstructed region by region (regions of at most @p maxNodes nodes), the surface is the whole
// reconstruction's, face for face in its order, each region's vertices those its faces use; returns
// the regions whose nodes reconstructed alone (without their neighbours) would give other faces.
size_t expectRegionsMakeTheWhole(const SurfaceOctree& so, size_t maxNodes) {
  const DiscreteMesh whole = so.reconstruct();
  const std::vector<SurfaceRegion> regions = so.regions(maxNodes);
  EXPECT_GT(regions.size(), 1u);
  size_t f = 0, differAlone = 0;
  uint32_t next = 0;
  for (const SurfaceRegion& r : regions) {
    EXPECT_EQ(r.first, next);
    next = r.last;
    EXPECT_TRUE(r.last - r.first <= maxNodes || r.edge == so.mergeEdge());
    const DiscreteMesh m = so.reconstructIn(r);
    std::vector<bool> used(m.vertices.size(), false);
    for (uint32_t v : m.indices) used[v] = true;
    EXPECT_EQ(std::count(used.begin(), used.end(), false), 0);
    for (size_t g = 0; g < m.faceCount(); ++g, ++f) {
      if (f >= whole.faceCount()) {
        ADD_FAILURE() << "region faces beyond the whole's " << whole.faceCount();
        return differAlone;
      }
      if (faceOf(m, g) != faceOf(whole, f)) {
        ADD_FAILURE() << "face " << f << " (region at " << r.origin.x << "," << r.origin.y << "," << r.origin.z << " edge " << r.edge
                      << ") differs from the whole reconstruction's";
        return differAlone;
      }
    }
    // The same nodes without their neighbours: what the neighbours add shows here.
    std::vector<SurfaceNode> own(so.nodes().begin() + r.first, so.nodes().begin() + r.last);
    const DiscreteMesh alone = SurfaceOctree::fromParts(so.dims(), so.isovalue(), 0, so.mergeEdge(), own, "region").reconstruct();
    bool same = alone.faceCount() == m.faceCount();
    for (size_t g = 0; same && g < m.faceCount(); ++g) same = faceOf(alone, g) == faceOf(m, g);
    differAlone += !same;
  }
  EXPECT_EQ(next, so.nodeCount());
  EXPECT_EQ(f, whole.faceCount());
  return differAlone;
}


TEST(SurfaceOctree, LeafCodesReproduceEveryConfiguration) {
  // Each configuration alone: the reconstructed leaf equals the DiscMC cell (same area, and every
  // region's truth value agrees with the corner classes where a corner is strictly inside a region).
  for (int m = 1; m < 255; ++m) {
    std::vector<float> s(8);
    for (int c = 0; c < 8; ++c) s[size_t(c)] = float((m >> c) & 1);
    const Volume v({2, 2, 2}, glm::dvec3(1.0), ScalarType::UInt8, s, "cell");
    SurfaceOctreeOptions leavesOnly;
    leavesOnly.maxEdge = 1;
    const Compared c = compare(v, 0.5f, leavesOnly);
    ASSERT_EQ(c.so.nodes().size(), size_t(1));
    EXPECT_NEAR(area(c.octree), area(c.dmc), 1e-12) << "config " << m;
    const SurfaceNode& leaf = leafCode(m, false);
    EXPECT_LE(leaf.planeCount, 4);
    for (int corner = 0; corner < 8; ++corner) {
      const glm::i64vec3 p = glm::i64vec3(dmc::cornerPosition(corner)) * int64_t(12);
      bool onPlane = false;
      for (int j = 0; j < leaf.planeCount; ++j)
        onPlane |= idot(orientationNormal(leaf.planes[size_t(j)].orientation), dmc::cornerPosition(corner)) == leaf.planes[size_t(j)].d;
      if (!onPlane) {
        EXPECT_EQ(nodeContains(leaf, p, 1), bool((m >> corner) & 1)) << "config " << m << " corner " << corner;
      }
    }
  }
}

TEST(SurfaceOctree, MergedSphereAndTorusAreLosslessClosedAndManifold) {
  std::vector<std::pair<std::string, Volume>> shapes;
  for (double r : {4.7, 9.3, 14.3}) shapes.push_back({"sphere " + std::to_string(r), test::sphereVolume(glm::ivec3(int(2 * r) + 5), r)});
  shapes.push_back({"torus", test::makeVolume({31, 31, 13}, [](int i, int j, int k) {
                      const glm::dvec3 q = glm::dvec3(i, j, k) - glm::dvec3(15, 15, 6);
                      return 4.2 - glm::length(glm::dvec2(glm::length(glm::dvec2(q.x, q.y)) - 9.5, q.z));
                    })});
  for (const auto& [name, v] : shapes) {
    const Compared c = compare(v, 0.0f);
    ASSERT_GT(c.dmc.triangles.size(), size_t(0)) << name;
    EXPECT_LT(c.so.nodes().size(), c.so.cellCount()) << name << ": nothing merged";
    const double a = area(c.dmc), b = area(c.octree);
    EXPECT_NEAR(b, a, 1e-9 * a) << name;  // the same surface
    const MeshCheck check = checkMesh(c.octree);
    EXPECT_TRUE(check.manifold) << name;
    EXPECT_TRUE(check.closed) << name;
    EXPECT_FALSE(check.selfIntersecting) << name;
    EXPECT_TRUE(check.outward) << name;
    EXPECT_NEAR(check.volume, checkMesh(c.dmc).volume, 1e-9 * check.volume) << name;
    EXPECT_LE(hausdorffDistance(c.dmc, c.octree, 0.05).upper, 0.05) << name;  // Hausdorff 0 within the bound
    EXPECT_LT(c.octree.triangles.size(), c.dmc.triangles.size()) << name;
    for (const SurfaceNode& n : c.so.nodes()) EXPECT_LE(n.planeCount, kMaxNodePlanes + (n.edge == 1 ? 1 : 0));
  }
}

TEST(SurfaceOctree, SphereCountsAgainstMarchingCubes) {
  // Exact counts (the merge is deterministic), within the target of at most half MC's triangles.
  const Volume v = test::sphereVolume(glm::ivec3(33), 14.3);
  const Compared c = compare(v, 0.0f);
  const size_t mc = extractMarchingCubes(v, 0.0f).triangles.size();
  EXPECT_EQ(mc, size_t(7688));
  EXPECT_EQ(c.dmc.triangles.size(), size_t(7688));
  EXPECT_EQ(c.so.cellCount(), size_t(3848));
  EXPECT_EQ(c.so.nodes().size(), size_t(752));
  EXPECT_EQ(c.octree.triangles.size(), size_t(3416));  // polygons merged within each volume leaf
  const TriangleMesh whole = fineMeshToTriangles(c.so.reconstruct(kMaxDim), v.spacing());
  EXPECT_EQ(whole.triangles.size(), size_t(3356));     // merged across leaves too (export)
  EXPECT_LE(double(c.octree.triangles.size()), 0.5 * double(mc));
  EXPECT_NEAR(area(whole), area(c.dmc), 1e-9 * area(c.dmc));
  EXPECT_TRUE(checkMesh(whole).closed);
}

TEST(SurfaceOctree, MergeLimitsAndPlaneBudgetAreRespected) {
  const Volume v = test::sphereVolume(glm::ivec3(25), 10.2);
  for (int maxEdge : {1, 2, 4}) {
    SurfaceOctreeOptions o;
    o.maxEdge = maxEdge;
    const Compared c = compare(v, 0.0f, o);
    for (const SurfaceNode& n : c.so.nodes()) EXPECT_LE(n.edge, maxEdge);
    EXPECT_NEAR(area(c.octree), area(c.dmc), 1e-9 * area(c.dmc));
  }
  SurfaceOctreeOptions k1;
  k1.maxPlanes = 1;
  const Compared c = compare(v, 0.0f, k1);
  for (const SurfaceNode& n : c.so.nodes()) {
    if (n.edge > 1) {
      EXPECT_EQ(n.planeCount, 1);
    }
  }
  EXPECT_TRUE(checkMesh(c.octree).closed);
  SurfaceOctreeOptions bad;
  bad.maxPlanes = 5;
  EXPECT_THROW(SurfaceOctree::build(v, VolumeOctree::build(v), 0.0f, bad), ValueError);
  bad = SurfaceOctreeOptions();
  bad.maxEdge = 3;
  EXPECT_THROW(SurfaceOctree::build(v, VolumeOctree::build(v), 0.0f, bad), ValueError);

  // The build merges leaf by leaf (cells bucketed by Morton code up to 16³ a leaf, sorted above):
  // leaves of 32 cells and a merge limit of 8 give exactly the nodes of leaves of 8.
  VolumeOctreeOptions wide;
  wide.leafEdge = 32;
  SurfaceOctreeOptions eight;
  eight.maxEdge = 8;
  const SurfaceOctree a = SurfaceOctree::build(v, VolumeOctree::build(v, wide), 0.0f, eight);
  const SurfaceOctree b = SurfaceOctree::build(v, VolumeOctree::build(v), 0.0f);
  ASSERT_EQ(a.nodes().size(), b.nodes().size());
  for (size_t i = 0; i < a.nodes().size(); ++i) {
    EXPECT_EQ(a.nodes()[i].origin, b.nodes()[i].origin);
    EXPECT_EQ(a.nodes()[i].edge, b.nodes()[i].edge);
    EXPECT_EQ(a.nodes()[i].inside, b.nodes()[i].inside);
    EXPECT_EQ(a.nodes()[i].occurs, b.nodes()[i].occurs);
  }
  // Merging up to 32 cells (regions of boxes over 8 cells are analysed uncached): a tilted plane
  // merges into nodes of 32 cells and keeps exactly the DiscMC surface.
  const glm::ivec3 dims(33);
  std::vector<float> samples;
  for (int k = 0; k < dims.z; ++k)
    for (int j = 0; j < dims.y; ++j)
      for (int i = 0; i < dims.x; ++i) samples.push_back(float(i + j) - 31.5f + 0.01f * float(k % 2));
  const Volume plane(dims, glm::dvec3(1.0), ScalarType::Float32, samples, "plane");
  const SurfaceOctree big = SurfaceOctree::build(plane, VolumeOctree::build(plane, wide), 0.0f);
  const SurfaceOctree small = SurfaceOctree::build(plane, VolumeOctree::build(plane), 0.0f);
  EXPECT_EQ(big.mergeEdge(), 32);
  EXPECT_TRUE(std::any_of(big.nodes().begin(), big.nodes().end(), [](const SurfaceNode& n) { return n.edge == 32; }));
  EXPECT_LT(big.nodes().size(), small.nodes().size());
  const TriangleMesh bigMesh = fineMeshToTriangles(big.reconstruct(), plane.spacing());
  const TriangleMesh dmc = toTriangleMesh(extractDiscMC(plane, 0.0f), plane.spacing());
  EXPECT_NEAR(area(bigMesh), area(dmc), 1e-9 * area(dmc));
}

// A streamed build reads its planes once more, a slab of leaves at a time: the nodes of the build
// from the volume in memory, for slabs that do not divide the grid and leaves of several sizes.
TEST(SurfaceOctree, AStreamedBuildReadsThePlanesASlabOfLeavesAtATime) {
  std::mt19937 rng(7);
  const Volume v = test::makeVolume({37, 29, 45}, [&](int i, int j, int k) {
    return float(16.0 - glm::length(glm::dvec3(i - 18, j - 14, k - 22)) + double(rng() % 5));
  });
  for (int leaf : {2, 4, 16}) {
    const VolumeOctree t = VolumeOctree::build(v, VolumeOctreeOptions{leaf, true, nullptr});
    const SurfaceOctree whole = SurfaceOctree::build(v, t, 9.5f);
    const std::unique_ptr<PlaneSource> planes = planesOf(v);
    const SurfaceOctree streamed = SurfaceOctree::build(*planes, t, 9.5f);
    EXPECT_GT(whole.nodes().size(), 500u) << leaf;
    EXPECT_EQ(streamed.nodes(), whole.nodes()) << leaf;
    EXPECT_EQ(streamed.cellCount(), whole.cellCount()) << leaf;
    EXPECT_EQ(streamed.mergeEdge(), whole.mergeEdge()) << leaf;
  }
}

// A streamed build whose nodes wait in a temporary file holds the octree built in memory, node for
// node: exact counts on a plane (x = 10.5 crosses 19 × 16 cells, merged into one node, a rectangle,
// per leaf of 8³ cells it meets, 3 × 2) and on a noisy sphere, and the same reconstructed mesh. The file is
// never seen in its directory.
TEST(SurfaceOctree, ASpooledStreamedBuildHoldsTheOctreeBuiltInMemory) {
  test::TempDir dir;
  const Volume plane = test::makeVolume({33, 20, 17}, [](int i, int, int) { return float(i) - 10.5f; });
  std::mt19937 rng(11);
  const Volume sphere = test::makeVolume({37, 29, 45}, [&](int i, int j, int k) {
    return float(16.0 - glm::length(glm::dvec3(i - 18, j - 14, k - 22)) + double(rng() % 5));
  });
  for (const Volume* v : {&plane, &sphere}) {
    SCOPED_TRACE(v == &plane ? "plane" : "sphere");
    const float iso = v == &plane ? 0.0f : 9.5f;
    const VolumeOctree t = VolumeOctree::build(*v, VolumeOctreeOptions{8, true, nullptr});
    const SurfaceOctree whole = SurfaceOctree::build(*v, t, iso);
    const std::unique_ptr<PlaneSource> planes = planesOf(*v);
    const SpooledSurfaceOctree spooled = SpooledSurfaceOctree::build(*planes, t, iso, dir.path().string());
    EXPECT_TRUE(test::namesIn(dir).empty());
    uint64_t planeIds = 0;
    for (const SurfaceNode& n : whole.nodes()) planeIds += n.planeCount;
    if (v == &plane) {
      EXPECT_EQ(whole.cellCount(), size_t(19 * 16));
      EXPECT_EQ(whole.nodes().size(), size_t(6));
      EXPECT_EQ(planeIds, 6u);
    } else {
      EXPECT_GT(whole.nodes().size(), 500u);
    }
    EXPECT_EQ(spooled.nodeCount(), whole.nodes().size());
    EXPECT_EQ(spooled.planeIds(), planeIds);
    EXPECT_EQ(spooled.cellCount(), whole.cellCount());
    EXPECT_EQ(spooled.mergeEdge(), whole.mergeEdge());
    EXPECT_EQ(spooled.isovalue(), iso);
    const SurfaceOctree loaded = spooled.load();
    EXPECT_EQ(loaded.nodes(), whole.nodes());
    const TriangleMesh a = fineMeshToTriangles(loaded.reconstruct(), v->spacing()), b = fineMeshToTriangles(whole.reconstruct(), v->spacing());
    if (v == &plane) {
      EXPECT_EQ(b.triangles.size(), size_t(6 * 2));  // a rectangle a node
    }
    EXPECT_EQ(a.triangles.size(), b.triangles.size());
    EXPECT_TRUE(a.vertices == b.vertices);
    EXPECT_TRUE(a.triangles == b.triangles);
    // The encoded nodes are the in-memory octree's, in its order.
    std::vector<uint8_t> fromSpool, fromMemory;
    spooled.encodeNodes([&](std::span<const uint8_t> bytes) { fromSpool.insert(fromSpool.end(), bytes.begin(), bytes.end()); });
    whole.encodeNodes([&](std::span<const uint8_t> bytes) { fromMemory.insert(fromMemory.end(), bytes.begin(), bytes.end()); });
    EXPECT_EQ(fromSpool.size(), whole.nodes().size() * kSurfaceNodeBytes);
    EXPECT_TRUE(fromSpool == fromMemory);
  }
  // A directory the temporary file cannot be made in is named.
  const std::unique_ptr<PlaneSource> planes = planesOf(plane);
  try {
    SpooledSurfaceOctree::build(*planes, VolumeOctree::build(plane), 0.0f, dir.file("missing"));
    ADD_FAILURE() << "spooled into a missing directory";
  } catch (const IoError& e) {
    EXPECT_NE(std::string(e.what()).find(dir.file("missing") + ": cannot create a temporary file for the surface octree"), std::string::npos) << e.what();
  }
}

TEST(SurfaceOctree, DegenerateInputs) {
  const Volume sphere = test::sphereVolume(glm::ivec3(9), 3.0);
  const VolumeOctree t = VolumeOctree::build(sphere);
  EXPECT_TRUE(SurfaceOctree::build(sphere, t, sphere.maxValue() + 1).nodes().empty());
  EXPECT_TRUE(SurfaceOctree::build(sphere, t, sphere.minValue()).nodes().empty());
  EXPECT_EQ(SurfaceOctree::build(sphere, t, sphere.maxValue() + 1).reconstruct().faceCount(), size_t(0));
  // Surfaces cut by the volume's box stay open exactly where DiscMC's are.
  const Volume cut = test::sphereVolume(glm::ivec3(12, 12, 5), 4.5);
  const Compared c = compare(cut, 0.0f);
  EXPECT_NEAR(area(c.octree), area(c.dmc), 1e-9 * area(c.dmc));
  const MeshCheck a = checkMesh(c.octree), b = checkMesh(c.dmc);
  EXPECT_TRUE(a.manifold);
  EXPECT_FALSE(a.selfIntersecting);
  EXPECT_GT(a.boundaryEdges, size_t(0));
  EXPECT_GT(b.boundaryEdges, size_t(0));
  // Noisy data: random binary blocks, including the fold variants.
  std::mt19937 rng(3);
  for (int trial = 0; trial < 40; ++trial) {
    const Volume noise = test::makeVolume({6, 5, 5}, [&](int, int, int) { return float(rng() & 1); });
    const Compared n = compare(noise, 0.5f);
    EXPECT_NEAR(area(n.octree), area(n.dmc), 1e-9 * std::max(1.0, area(n.dmc))) << trial;
    EXPECT_TRUE(checkMesh(n.octree).manifold) << trial;
  }
}

TEST(SurfaceOctree, VolumeNodeRangesPartitionTheNodes) {
  const Volume v = test::sphereVolume(glm::ivec3(40, 37, 30), 13.1);
  const VolumeOctree t = VolumeOctree::build(v);
  const SurfaceOctree so = SurfaceOctree::build(v, t, 0.0f);
  // Every surface node lies in exactly one volume leaf, found by range without search at draw time.
  size_t covered = 0;
  for (const OctreeNode& n : t.nodes()) {
    const auto [b, e] = so.rangeIn(glm::ivec3(n.origin), t.edge(n));
    for (uint32_t i = b; i < e; ++i) {
      const SurfaceNode& s = so.nodes()[i];
      EXPECT_TRUE(glm::all(glm::greaterThanEqual(glm::ivec3(s.origin), glm::ivec3(n.origin))));
      EXPECT_TRUE(glm::all(glm::lessThanEqual(glm::ivec3(s.origin) + int(s.edge), glm::ivec3(n.origin) + t.edge(n))));
    }
    if (n.isLeaf()) covered += e - b;
  }
  EXPECT_EQ(covered, so.nodes().size());
  const auto root = so.rangeIn(glm::ivec3(0), 1 << t.depth());
  EXPECT_EQ(root.second - root.first, so.nodes().size());
}

TEST(SurfaceOctreeCranium, LosslessOnBoneAndSkin) {
  const Volume v = readVolume(kDefaultVolumePath);
  const VolumeOctree t = VolumeOctree::build(v);
  for (float iso : {400.0f, -500.0f}) {
    const SurfaceOctree so = SurfaceOctree::build(v, t, iso);
    const TriangleMesh octree = fineMeshToTriangles(so.reconstruct(), v.spacing());
    const TriangleMesh dmc = toTriangleMesh(extractDiscMC(v, iso, isoBlocks(t, iso)), v.spacing());
    EXPECT_NEAR(area(octree), area(dmc), 1e-9 * area(dmc)) << iso;
    EXPECT_LT(double(octree.triangles.size()), 0.55 * double(dmc.triangles.size())) << iso;
    const MeshCheck c = checkMesh(octree);
    EXPECT_TRUE(c.manifold) << iso;
    EXPECT_FALSE(c.selfIntersecting) << iso;
  }
}

// A region's polygons (reconstructIn) are exactly the whole reconstruction's polygons of its nodes:
// the T-junctions its neighbours' vertices make on its faces, its merges and the vertices a
// neighbour shares (kept, not dropped as straight) included; regions as small as a leaf.
TEST(SurfaceOctree, RegionsReconstructTheWholeSurfaceFaceForFace) {
  const Volume v = test::sphereVolume(glm::ivec3(40, 37, 30), 13.1);
  const VolumeOctree t = VolumeOctree::build(v);
  const SurfaceOctree so = SurfaceOctree::build(v, t, 0.0f);
  // (No surface plane passes through a node's face: its axis planes lie between samples, at odd
  // doubled coordinates, the faces at even ones. A neighbour's merge then keeps the vertices it
  // shares with a region.)
  size_t axisPlanes = 0;
  for (const SurfaceNode& n : so.nodes())
    for (int j = 0; j < n.planeCount; ++j) {
      const glm::ivec3 normal = orientationNormal(n.planes[size_t(j)].orientation);
      if (std::abs(normal.x) + std::abs(normal.y) + std::abs(normal.z) != 1) continue;
      ++axisPlanes;
      EXPECT_EQ(std::abs(n.planes[size_t(j)].d) % 2, 1);
    }
  EXPECT_GT(axisPlanes, 0u);
  EXPECT_GT(expectRegionsMakeTheWhole(so, 1), 0u);
  EXPECT_GT(expectRegionsMakeTheWhole(so, 200), 0u);
  // One region holding every node is the whole.
  const std::vector<SurfaceRegion> all = so.regions(so.nodeCount());
  ASSERT_EQ(all.size(), 1u);
  EXPECT_EQ(all[0].last - all[0].first, so.nodeCount());
  const DiscreteMesh one = so.reconstructIn(all[0]), whole = so.reconstruct();
  ASSERT_EQ(one.faceCount(), whole.faceCount());
  for (size_t f = 0; f < one.faceCount(); ++f) EXPECT_EQ(faceOf(one, f), faceOf(whole, f)) << f;
}

TEST(SurfaceOctreeCranium, RegionsReconstructTheWholeSurfaceFaceForFace) {
  const Volume v = readVolume(kDefaultVolumePath);
  const VolumeOctree t = VolumeOctree::build(v);
  for (float iso : {400.0f, -500.0f}) {
    const SurfaceOctree so = SurfaceOctree::build(v, t, iso);
    EXPECT_GT(expectRegionsMakeTheWhole(so, 4096), 0u) << iso;
  }
}

}  // namespace
}  // namespace hyb
