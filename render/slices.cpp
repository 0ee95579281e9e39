// Hybrid slice renderer: I. Boada, I. Navazo, "3D Texture-based Hybrid Visualizations", 2002, §4,
// in view-aligned form (slice polygons cut on the CPU, global slice planes; docs/renderer.md).
// This file is the frame, stage by stage; the stages' internals are files of their own in
// render/slices/: brick_textures (textures, blending, the cache), proxy_geometry (planes and
// shells), slab_polygons (the SlabPolygon lists), cut_plane_pass and the shaders.
#include "render/slices.h"

#include <malloc.h>

#include <glm/gtc/matrix_transform.hpp>
#include <glm/gtc/type_ptr.hpp>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <deque>
#include <exception>
#include <limits>
#include <optional>
#include <string>
#include <thread>
#include <utility>

#include "render/gl_objects.h"
#include "render/slices/cut_plane_pass.h"
#include "render/slices/proxy_geometry.h"
#include "render/slices/shaders.h"
#include "render/slices/slab_polygons.h"
#include "volume/core/error.h"
#include "volume/core/parallel.h"

namespace hyb {

namespace {

// Base slice spacings between a brick's slices when its texels are @p step voxels apart: full
// resolution keeps the base spacing (half a voxel by default: twice a texel), two voxels a texel
// take three (4/3 a texel), coarser levels twice their step (once a texel: the paper's slab width, §4.1;
// their knots hold the data smoothed by the lattice's tent). Every brick's planes lie on the base
// grid, and coarse fragments cut the stretch they stand for to the brick's box (SEGMENTS in
// the slice shader), so a level change shows no seam of sampling (docs/multires.md measures the
// choices).
int slicePeriod(int step) { return step == 1 ? 1 : step == 2 ? 3 : 2 * step; }

// The period of a level of @p step voxels a texel among planes @p stepVoxels apart: slicePeriod's
// at the default half voxel; at a wider spacing about the same distance in voxels rather than the
// same multiple of the spacing (which undersamples the texels: woodgrain and specks on the moving
// frames' coarse bricks), every plane where that distance is below the spacing.
int levelPeriod(int step, double stepVoxels) {
  const int period = slicePeriod(step);
  return std::clamp(int(0.5 * period / stepVoxels), 1, period);
}

// How far (in slice spacings) a brick's visible boxes grow for pre-integrated fragments: their
// segments reach a spacing either side of their slice, and further along an oblique ray.
constexpr double kPreintegratedGrowth = 2.0;

// The bricks (nodes with brickOf ≥ 0) in back-to-front octree order: the octant farthest from the
// eye first, then those one, two and three flips towards it (valid for perspective too).
std::vector<uint32_t> bricksBackToFront(const VolumeOctree& octree, const BrickIndex& brickOf, const glm::dvec3& eyeVoxel) {
  std::vector<uint32_t> order;
  std::vector<uint32_t> stack{0};
  while (!stack.empty()) {
    const uint32_t i = stack.back();
    stack.pop_back();
    if (brickOf[i] >= 0) {
      order.push_back(i);
      continue;
    }
    const OctreeNode& n = octree.nodes()[i];
    const glm::dvec3 mid = glm::dvec3(n.origin) + 0.5 * octree.edge(n);
    const int far = (eyeVoxel.x < mid.x) | (eyeVoxel.y < mid.y) << 1 | (eyeVoxel.z < mid.z) << 2;
    for (int k : {7, 6, 5, 3, 4, 2, 1, 0}) {  // pushed in reverse, popped far first
      const int slot = far ^ k;
      if (n.childMask & (1u << slot)) stack.push_back(childIndex(n, slot));
    }
  }
  return order;
}

// The camera's matrices, with near and far planes around the volume.
struct FrameCamera {
  glm::mat4 viewProj;
  glm::dvec3 forward;
  double diag;  // the volume's diagonal, mm
};
FrameCamera frameCamera(const Volume& volume, const Camera& camera, double baseDelta) {
  FrameCamera c;
  c.forward = camera.forward();
  const glm::dvec3 boxHi = volume.extentMm();
  double dmin = 1e300, dmax = -1e300;
  for (int k = 0; k < 8; ++k) {
    const glm::dvec3 p((k & 1) ? boxHi.x : 0, (k & 2) ? boxHi.y : 0, (k & 4) ? boxHi.z : 0);
    dmin = std::min(dmin, glm::dot(p - camera.eye, c.forward));
    dmax = std::max(dmax, glm::dot(p - camera.eye, c.forward));
  }
  c.diag = std::max(1e-3, glm::length(boxHi));
  // Slab indices (depth / spacing, depth along f or from the eye) are kept in 32 bits.
  if ((glm::length(camera.eye) + c.diag) / baseDelta >= double(1 << 30))
    HYB_THROW(ValueError, "slice spacing ", baseDelta, " mm is too small for a scene ", glm::length(camera.eye) + c.diag, " mm deep (at most 2^30 slabs)");
  const double zNear = camera.ortho ? dmin - 0.01 * c.diag : std::max(dmin - 0.01 * c.diag, 1e-4 * c.diag);
  const double zFar = dmax + 0.01 * c.diag;
  const double aspect = double(camera.width) / double(camera.height);
  // A mirrored camera flips the image's x axis (no face culling: winding does not matter).
  const glm::dmat4 view = glm::scale(glm::dmat4(1.0), glm::dvec3(camera.mirrored ? -1.0 : 1.0, 1.0, 1.0)) *
                          glm::lookAt(camera.eye, camera.center, camera.up);
  const glm::dmat4 proj = camera.ortho ? glm::ortho(-0.5 * camera.orthoHeight * aspect, 0.5 * camera.orthoHeight * aspect,
                                                    -0.5 * camera.orthoHeight, 0.5 * camera.orthoHeight, zNear, zFar)
                                       : glm::perspective(glm::radians(camera.fovDeg), aspect, zNear, zFar);
  c.viewProj = glm::mat4(proj * view);
  return c;
}

// Whether node @p n's box may cover a pixel of image rows [rows.x, rows.y) (from the top) of an
// image @p height pixels tall seen through @p viewProj: its corners' projection, two pixels wider,
// meets them, or a corner lies at or behind the eye's plane (then it may cover anything).
bool meetsRows(const VolumeOctree& octree, const OctreeNode& n, const glm::dvec3& spacing, const glm::mat4& viewProj, int height,
               const glm::ivec2& rows) {
  glm::ivec3 lo, hi;
  octree.voxelBox(n, &lo, &hi);
  const glm::dmat4 m(viewProj);
  double y0 = 1e300, y1 = -1e300;  // window rows from the top
  for (int c = 0; c < 8; ++c) {
    const glm::dvec4 clip = m * glm::dvec4(glm::dvec3(c & 1 ? hi.x : lo.x, c & 2 ? hi.y : lo.y, c & 4 ? hi.z : lo.z) * spacing, 1.0);
    if (clip.w <= 0.0) return true;
    const double y = (0.5 - 0.5 * clip.y / clip.w) * double(height);
    y0 = std::min(y0, y);
    y1 = std::max(y1, y);
  }
  return y1 + 2.0 >= double(rows.x) && y0 - 2.0 <= double(rows.y);
}

// The transfer function's lookup table (texture unit 1, read with texelFetch) and what it shows;
// the pre-integration table (unit 2, a 3D texture read trilinearly) when the frame uses it.
struct TransferTable {
  LutLayout layout;
  std::vector<glm::vec4> lut;
  gl::Texture texture, ownTable;
  VisibleValues visible;
  TransferTable(const Volume& volume, const TransferFunction& tf, const PreIntegrationTable* pre, BrickTextureCache* cache)
      : layout(volume.minValue(), volume.maxValue(), tf), lut(tableOf(layout, tf)), texture(gl::Texture::make()), visible(lut, layout) {
    glActiveTexture(GL_TEXTURE1);
    glBindTexture(GL_TEXTURE_1D, texture.id());
    glTexImage1D(GL_TEXTURE_1D, 0, GL_RGBA32F, LutLayout::kSize, 0, GL_RGBA, GL_FLOAT, lut.data());
    // A filter without mipmaps keeps the texture complete.
    glTexParameteri(GL_TEXTURE_1D, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
    glTexParameteri(GL_TEXTURE_1D, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
    if (!pre) return;
    auto make = [pre] {
      gl::Texture t = gl::Texture::make();
      glActiveTexture(GL_TEXTURE2);
      glBindTexture(GL_TEXTURE_3D, t.id());
      glTexImage3D(GL_TEXTURE_3D, 0, GL_RGBA32F, pre->bins(), pre->bins(), pre->layers(), 0, GL_RGBA, GL_FLOAT, pre->texels().data());
      glTexParameteri(GL_TEXTURE_3D, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
      glTexParameteri(GL_TEXTURE_3D, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
      for (const GLenum wrap : {GL_TEXTURE_WRAP_S, GL_TEXTURE_WRAP_T, GL_TEXTURE_WRAP_R}) glTexParameteri(GL_TEXTURE_3D, wrap, GL_CLAMP_TO_EDGE);
      return t;
    };
    const GLuint id = cache ? cache->tableTexture(pre->id(), make) : (ownTable = make()).id();
    glActiveTexture(GL_TEXTURE2);
    glBindTexture(GL_TEXTURE_3D, id);
  }
  static std::vector<glm::vec4> tableOf(const LutLayout& layout, const TransferFunction& tf) {
    std::vector<glm::vec4> lut(LutLayout::kSize);
    for (int i = 0; i < LutLayout::kSize; ++i) lut[size_t(i)] = tf.lookup(layout.value(i));
    return lut;
  }
};

// The first texture unit of the geometry parts' coverage (0: the brick, 1: the transfer function, 2:
// the pre-integration table).
constexpr int kGeometryUnit = 3;

// The geometry parts a slice frame samples.
int geometryParts(const SlicesOptions& options) {
  return options.geometry ? int(std::min(options.geometry->parts.size(), size_t(kMaxGeometryParts))) : 0;
}

// Binds the geometry parts' textures to units kGeometryUnit…, made at the channel's first slice
// frame (RGBA8, clamped to a border of no coverage and no normal as GeometryPart::at reads outside its crop).
void bindGeometry(const SlicesOptions& options) {
  const int parts = geometryParts(options);
  if (parts == 0) return;
  const GeometryChannel& g = *options.geometry;
  if (g.textures.size() != size_t(parts)) {
    g.textures.clear();
    glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
    for (int k = 0; k < parts; ++k) {
      const GeometryPart& part = g.parts[size_t(k)];
      gl::Texture t = gl::Texture::make();
      glActiveTexture(GLenum(GL_TEXTURE0 + kGeometryUnit + k));
      glBindTexture(GL_TEXTURE_3D, t.id());
      const glm::u8vec4 none(0, 128, 128, 128);
      const glm::ivec3 dims = part.texels.empty() ? glm::ivec3(1) : part.dims;
      glTexImage3D(GL_TEXTURE_3D, 0, GL_RGBA8, dims.x, dims.y, dims.z, 0, GL_RGBA, GL_UNSIGNED_BYTE, part.texels.empty() ? &none : part.texels.data());
      glTexParameteri(GL_TEXTURE_3D, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
      glTexParameteri(GL_TEXTURE_3D, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
      const float border[4] = {0.0f, 128.0f / 255.0f, 128.0f / 255.0f, 128.0f / 255.0f};
      glTexParameterfv(GL_TEXTURE_3D, GL_TEXTURE_BORDER_COLOR, border);
      for (const GLenum wrap : {GL_TEXTURE_WRAP_S, GL_TEXTURE_WRAP_T, GL_TEXTURE_WRAP_R}) glTexParameteri(GL_TEXTURE_3D, wrap, GL_CLAMP_TO_BORDER);
      g.textures.push_back(std::move(t));
    }
    glPixelStorei(GL_UNPACK_ALIGNMENT, 4);
  }
  for (int k = 0; k < parts; ++k) {
    glActiveTexture(GLenum(GL_TEXTURE0 + kGeometryUnit + k));
    glBindTexture(GL_TEXTURE_3D, g.textures[size_t(k)].id());
  }
  glActiveTexture(GL_TEXTURE0);
}

// The frame's programs: the slice program in variants, bricks sliced at the base spacing or coarser
// (SEGMENTS: each fragment's segment cut to the brick's box, a cost full resolution need not pay;
// docs/multires.md) and bricks whose stream holds translucent surface pieces or not (SURFACE:
// llvmpipe runs the surface's branch for every slice fragment too), and the cutting plane's. Kept with the brick
// textures across frames when there is a cache: llvmpipe compiles a new program's shaders again at
// its first draw.
struct SliceFrame;

class FramePrograms {
 public:
  struct Slice {
    GLuint id = 0;
    GLint fineScale, fineOffset, valueOffset, valueScale, sliceSpacing, shells, boxLo, boxHi;
  };
  /// The programs of frame @p f (defined after SliceFrame).
  explicit FramePrograms(const SliceFrame& f);

 private:
  void define() {
    const SlicesOptions& options = mOptions;
    const Camera& camera = mCamera;
    mDefines = "#version 450 core\n";
    for (const auto& [name, on] : {std::pair{"SHADING", options.shading}, {"CUT", bool(options.cut)},
                                   {"SHELLS", options.proxy == Proxy::Shells && !camera.ortho}, {"VOI", bool(options.voi)}, {"ORTHO", camera.ortho},
                                   {"TEXEL16", options.texelBits == TexelBits::Sixteen}, {"PREINT", bool(options.preintegrated)},
                                   {"MESHES", options.meshes && !options.meshes->empty()}})
      mDefines += std::string("#define ") + name + (on ? " 1\n" : " 0\n");
    mDefines += "#define GEOMETRY " + std::to_string(geometryParts(options)) + "\n";
  }

 public:

  // The slice program for bricks sliced at the base spacing or coarser (@p segments), whose stream
  // holds surface pieces (@p surface) or not.
  const Slice& slice(bool segments, bool surface) {
    Slice& p = mSlice[size_t(segments) + 2 * size_t(surface)];
    if (p.id) return p;
    const std::string head = mDefines + "#define SEGMENTS " + (segments ? "1\n" : "0\n") + "#define SURFACE " + (surface ? "1\n" : "0\n") +
                             "#define SMOOTH " + (surface && mSmooth ? "1\n" : "0\n");
    p.id = program(head, head + shaders::kStreamVertex, head + shaders::kClassify + shaders::kSliceFragment);
    auto uniform = [&](const char* name) { return glGetUniformLocation(p.id, name); };
    setShared(p.id);
    glUniform1i(uniform("volumeTex"), 0);
    const glm::dvec3& eye = mCamera.eye;
    glUniform3f(uniform("eye"), float(eye.x), float(eye.y), float(eye.z));
    glUniform3f(uniform("forward"), float(mFrame.forward.x), float(mFrame.forward.y), float(mFrame.forward.z));
    glUniform4fv(uniform("surfaceColor"), 1, glm::value_ptr(mOptions.surfaceColor));
    if (mOptions.meshes && !mOptions.meshes->empty()) {  // the table of colours: the isosurface's, then each mesh's
      std::vector<glm::vec4> colors{mOptions.surfaceColor};
      colors.insert(colors.end(), mOptions.meshes->colors.begin(), mOptions.meshes->colors.end());
      glUniform4fv(uniform("surfaceColors"), GLsizei(colors.size()), glm::value_ptr(colors.front()));
    }
    glUniform4fv(uniform("cutPlane"), 1, glm::value_ptr(mCutPlane));
    if (const VolumeOfInterest* voi = mOptions.voi) {
      const glm::vec3 centre(0.5 * (voi->lo + voi->hi)), half(0.5 * (voi->hi - voi->lo));
      glUniform3fv(uniform("voiCentre"), 1, glm::value_ptr(centre));
      glUniform3fv(uniform("voiHalf"), 1, glm::value_ptr(half));
      const glm::mat3 toBox(voi->toBox);
      const glm::vec3 offset(voi->offset);
      glUniformMatrix3fv(uniform("voiToBox"), 1, GL_FALSE, glm::value_ptr(toBox));
      glUniform3fv(uniform("voiOffset"), 1, glm::value_ptr(offset));
      glUniform1f(uniform("voiInside"), float(voi->inside));
      glUniform1f(uniform("voiOutside"), float(voi->outside));
      glUniform1f(uniform("voiRamp"), float(voi->ramp));
    }
    if (const PreIntegrationTable* pre = mOptions.preintegrated) {
      glUniform1i(uniform("preTex"), 2);
      glUniform1f(uniform("preMin"), pre->vmin());
      glUniform1f(uniform("preScale"), pre->scale());
      glUniform1f(uniform("preBins"), float(pre->bins()));
      glUniform1f(uniform("preFirst"), float(pre->firstLayer()));
      glUniform1f(uniform("preLayers"), float(pre->layers()));
    }
    if (const int parts = geometryParts(mOptions); parts > 0) {
      const GeometryChannel& g = *mOptions.geometry;
      std::vector<GLint> units;
      std::vector<glm::vec3> scale, offset;
      std::vector<glm::vec4> color;
      std::vector<float> tau;
      const glm::dvec3 spacing = mSpacing;
      for (int k = 0; k < parts; ++k) {
        const GeometryPart& part = g.parts[size_t(k)];
        const glm::dvec3 dims(glm::max(part.dims, glm::ivec3(1)));
        // uv = (x / spacing − lo + ½) / dims: texel j's centre on voxel lo + j, as GeometryPart::at reads.
        units.push_back(kGeometryUnit + k);
        scale.push_back(glm::vec3(1.0 / (spacing * dims)));
        offset.push_back(glm::vec3((0.5 - glm::dvec3(part.lo)) / dims));
        color.push_back(part.color);
        tau.push_back(float(part.thicknessMm));
      }
      glUniform1iv(uniform("geomTex"), parts, units.data());
      glUniform3fv(uniform("geomScale"), parts, glm::value_ptr(scale.front()));
      glUniform3fv(uniform("geomOffset"), parts, glm::value_ptr(offset.front()));
      glUniform4fv(uniform("geomColor"), parts, glm::value_ptr(color.front()));
      glUniform1fv(uniform("geomTau"), parts, tau.data());
    }
    p.fineScale = uniform("fineScale"), p.fineOffset = uniform("fineOffset"), p.valueOffset = uniform("valueOffset");
    p.valueScale = uniform("valueScale"), p.sliceSpacing = uniform("sliceSpacing"), p.shells = uniform("shells");
    p.boxLo = uniform("boxLo"), p.boxHi = uniform("boxHi");
    return p;
  }

  // The opaque surface's program.
  GLuint surface() { return program("surface", shaders::kWorldVertex, shaders::kSurfaceFragment); }

  // The cutting plane's program, its shared uniforms set.
  GLuint cut() {
    const GLuint id = program("cut", shaders::kWorldVertex, std::string("#version 450 core\n") + shaders::kClassify + shaders::kCutFragment);
    setShared(id);
    return id;
  }

 private:
  GLuint program(const std::string& key, const std::string& vertex, const std::string& fragment) {
    if (GLuint id = mOptions.textures ? mOptions.textures->program(key) : 0) return id;
    gl::Program p = gl::linkProgram(vertex, fragment);
    const GLuint id = p.id();
    if (mOptions.textures)
      mOptions.textures->insertProgram(key, std::move(p));
    else
      mOwn.push_back(std::move(p));
    return id;
  }
  // Uniforms of kClassify and the camera, the same in the slice and cutting-plane programs.
  void setShared(GLuint id) const {
    glUseProgram(id);
    glUniformMatrix4fv(glGetUniformLocation(id, "viewProj"), 1, GL_FALSE, glm::value_ptr(mFrame.viewProj));
    glUniform1i(glGetUniformLocation(id, "tfTex"), 1);
    glUniform1f(glGetUniformLocation(id, "tfMin"), mTable.layout.vmin);
    glUniform1f(glGetUniformLocation(id, "tfScale"), mTable.layout.scale);
    glUniform1f(glGetUniformLocation(id, "tfSize"), float(LutLayout::kSize));
  }

  const SlicesOptions& mOptions;
  const Camera& mCamera;
  const FrameCamera& mFrame;
  const TransferTable& mTable;
  glm::vec4 mCutPlane;
  glm::dvec3 mSpacing;  // the volume's voxel spacing (mm)
  bool mSmooth;  // the translucent surface has vertex normals
  std::string mDefines;
  std::array<Slice, 4> mSlice;
  std::vector<gl::Program> mOwn;  // without a cache: the frame's own
};

// The frame's target: float colour (premultiplied) and depth for opaque surfaces, cleared, a
// band's rows only (a scissor: a viewport shifted to the band changes llvmpipe's interpolation by
// float rounding); the vertex array and buffer the surface passes draw from, bound; depth tested.
struct SliceTarget {
  glm::ivec2 rows;  // the image rows drawn [rows.x, rows.y), from the top
  std::optional<gl::FloatTarget> own;  // (without a cache)
  gl::VertexArray vao;
  gl::Buffer vbo;
  SliceTarget(const Camera& camera, const SlicesOptions& options) : rows(options.rows.value_or(glm::ivec2(0, camera.height))) {
    HYB_CHECK(rows.x >= 0 && rows.x < rows.y && rows.y <= camera.height);
    if (options.targets)
      options.targets->get(camera.width, camera.height);
    else
      own.emplace(camera.width, camera.height);
    if (options.rows) {
      glEnable(GL_SCISSOR_TEST);
      glScissor(0, camera.height - rows.y, camera.width, rows.y - rows.x);
    } else {
      glDisable(GL_SCISSOR_TEST);
    }
    glDepthMask(GL_TRUE);  // a previous frame may have left depth writes off, which would skip the clear
    glDisable(GL_BLEND);
    glClearColor(0, 0, 0, 0);
    glClearDepth(1.0);
    glClear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);
    vao = gl::VertexArray::make();
    glBindVertexArray(vao.id());
    vbo = gl::Buffer::make();
    glBindBuffer(GL_ARRAY_BUFFER, vbo.id());
    glEnable(GL_DEPTH_TEST);
    glDepthFunc(GL_LESS);
  }
};

// What every stage of one slice frame reads, made once after its target: its inputs, its camera,
// the transfer function's table, the bricks' draw order and the surface's polygons by brick. Its
// pointers point into it, so it is neither copied nor moved.
struct SliceFrame {
  const Volume& volume;
  const VolumeOctree& octree;
  const Selection& selection;
  const TransferFunction& tf;
  const Camera& camera;
  const SlicesOptions& options;
  const glm::ivec2 rows;          // the image rows drawn, from the top
  const double baseDelta;         // the base slice spacing, mm
  const FrameCamera view;         // the camera's matrices and forward axis
  const glm::dvec4 cut;           // the cutting plane's kept side (everything without a plane)
  const bool withTriangles;       // a surface with triangles is drawn
  const bool translucent;         // and drawn translucent, between the slices
  const TransferTable table;
  const PixelCentres pixelCentres;
  const PixelCentres* centres;    // the triangles between pixel centres left out, or none
  const BrickIndex brickOf;
  const std::vector<uint32_t> order;              // the bricks' nodes, back to front
  const std::optional<SurfacePolygons> polygons;  // the surface's, with triangles
  const SurfacePolygons* surface;                 // the translucent surface's polygons (in SlabPolygon lists), or none
  const BrickPolygons polygonsOf;
  const std::optional<SurfacePolygons> meshes;    // the user meshes' pieces (in SlabPolygon lists), or none
  const BrickPolygons meshesOf;

  SliceFrame(const SelectedBricks& in, const TransferFunction& tfIn, const Camera& cameraIn, const SlicesOptions& optionsIn,
             const glm::ivec2& rowsIn)
      : volume(in.volume), octree(in.octree), selection(in.selection), tf(tfIn), camera(cameraIn), options(optionsIn), rows(rowsIn),
        baseDelta(options.stepVoxels * std::min({spacing().x, spacing().y, spacing().z})), view(frameCamera(volume, camera, baseDelta)),
        cut(options.cut ? options.cut->keptSide(camera) : glm::dvec4(0, 0, 0, 1)),
        withTriangles(options.surface && !options.surface->triangles.empty()), translucent(withTriangles && options.surfaceColor.a < 1.0f),
        table(volume, tf, options.preintegrated, options.textures), pixelCentres(view.viewProj, camera.width, camera.height),
        centres(options.leaveOutUnseen ? &pixelCentres : nullptr), brickOf(selection), order(bricksInView()),
        polygons(withTriangles ? std::optional<SurfacePolygons>(*options.surface) : std::nullopt), surface(translucent ? &*polygons : nullptr),
        polygonsOf(polygons ? polygonsByBrick(volume, octree, selection, *polygons, options.region)
                            : BrickPolygons{std::vector<uint32_t>(selection.bricks.size() + 1, 0), {}}),
        meshes(meshPolygons(options)),
        meshesOf(meshes ? polygonsByBrick(volume, octree, selection, *meshes, options.region)
                        : BrickPolygons{std::vector<uint32_t>(selection.bricks.size() + 1, 0), {}}) {
    if (options.textures) {
      options.textures->setBits(options.texelBits);
      options.textures->beginFrame();
    }
  }
  SliceFrame(const SliceFrame&) = delete;
  SliceFrame& operator=(const SliceFrame&) = delete;
  glm::dvec3 spacing() const { return volume.spacing(); }
  // Whether brick @p b holds polygons of the SlabPolygon lists.
  bool holdsPolygons(size_t b) const { return (surface && !polygonsOf.of(b).empty()) || !meshesOf.of(b).empty(); }

 private:
  // The user meshes' pieces as polygons coloured by their meshes (colour 0 is the isosurface's).
  static std::optional<SurfacePolygons> meshPolygons(const SlicesOptions& options) {
    if (!options.meshes || options.meshes->pieces.triangles.empty()) return std::nullopt;
    SurfacePolygons p(options.meshes->pieces);
    p.colors.reserve(options.meshes->pieceMesh.size());
    for (const uint16_t m : options.meshes->pieceMesh) p.colors.push_back(uint16_t(m + 1));
    return p;
  }

  // The bricks back to front, less those outside the band of rows or the region (the members
  // above order made).
  std::vector<uint32_t> bricksInView() const {
    const glm::dvec3 eyeVoxel = (camera.ortho ? camera.eye - view.forward * 1e9 * view.diag : camera.eye) / spacing();
    std::vector<uint32_t> inView = bricksBackToFront(octree, brickOf, eyeVoxel);
    HYB_CHECK(inView.size() == selection.bricks.size());
    if (options.rows)
      std::erase_if(inView, [&](uint32_t node) { return !meetsRows(octree, octree.nodes()[node], spacing(), view.viewProj, camera.height, rows); });
    if (options.region)
      std::erase_if(inView, [&](uint32_t node) {  // a brick lies inside one region: its centre's
        const OctreeNode& n = octree.nodes()[node];
        return !options.region->contains((glm::dvec3(n.origin) + 0.5 * double(octree.edge(n))) * spacing());
      });
    return inView;
  }
};

// What a worker reuses from one brick's stream to the next.
struct StreamScratch {
  SlabPolygonList list;
  std::vector<std::pair<glm::dvec3, glm::dvec3>> boxes;
  std::vector<float> one;
};

// What one brick draws: planned on the submitting thread (textures are GL work), its vertex stream
// built by a worker thread while this one submits the bricks before it to llvmpipe, whose vertex
// processing runs on the submitting thread: the two halves of the per-brick work overlap.
struct BrickDraw {
  uint32_t brick = 0, node = 0;  // index into selection.bricks, and its node
  bool visible = false, sliced = false, shell = false;
  bool crossed = false;  // the cutting plane crosses its box (then it is textured)
  bool geometry = false;  // its box holds scan-converted geometry: sliced whole, at the base spacing
  bool pending = false;  // its texels are packed into `packed`, uploaded when it is drawn
  GLuint texture = 0;
  glm::vec3 fineScale{0.0f}, fineOffset{0.0f};  // grid mm -> the texture's coordinates
  float valueOffset = 0.0f, valueScale = 1.0f;
  double delta = 0.0;  // this brick's slice spacing
  glm::dvec3 blo{0.0}, bhi{0.0}, slo{0.0}, shi{0.0};  // the brick's box and the box it slices
  ShellFrame frame{};
  const VisibleBlocks* blocks = nullptr;  // each slice or shell is cut from the box of the visible blocks it meets
  KnotLattice lattice{};
  CachedBrick* cached = nullptr;  // its cache entry, found before the frame's first draw; null: made by this frame
  PackedBrick packed;             // its texels, from its batch's packing to its texture's making
  glm::ivec3 texels{0};           // its texture's size
  std::vector<float> cutPolygon;  // its piece of the cutting plane, until planned
  // Built by the worker:
  std::vector<float> stream;  // kStreamFloats a vertex
  uint64_t slices = 0, surfaceTriangles = 0, unseenTriangles = 0, slabPolygonDraws = 0;
};

// The bricks' textures and slicing, back to front: textures from the cache or packed (on all cores:
// their texels are most of a first frame's work) and uploaded; the cutting plane's piece of each;
// the box each slices (the cells the transfer function can make visible: empty-space skipping
// inside the brick, found from the packed texels' ranges) and its slice spacing (slicePeriod).
//
// The draws are planned a batch at a time, a batch ahead of the drawing: packing every brick first
// held a whole frame's packed texels at once (1.83 GB for the phantom's 93,066 bricks), so at most
// two batches' are held now (the one drawn and the next), whatever the brick count. Bricks the
// cutting plane crosses are planned before any draw: the plane is drawn first, from their textures.
class BrickPlanner {
 public:
  explicit BrickPlanner(const SliceFrame& f)
      : mF(f), mInMemory(f.volume, f.octree), mKnots(f.options.knots ? *f.options.knots : mInMemory), mSpacing(f.spacing()),
        mBatch(std::max<size_t>(f.options.packBatch, 1)) {
    const VolumeOctree& octree = f.octree;
    const SlicesOptions& options = f.options;
    const Camera& camera = f.camera;
    // The frame's draws, and the crossed bricks to pack; no cache entry is marked as used here.
    // Hidden (transparent or culled) bricks cost no texels; their surface triangles are still drawn.
    std::vector<size_t> crossedToPack;
    mDraws.reserve(f.order.size());
    for (const uint32_t i : f.order) {
      const OctreeNode& n = octree.nodes()[i];
      BrickDraw d;
      d.brick = uint32_t(f.brickOf[i]);
      d.node = i;
      d.geometry = options.geometry && options.geometry->holds(i);
      const Brick& b = f.selection.bricks[d.brick];
      d.visible = !b.hidden && (f.tf.maxAlpha(n.minValue, n.maxValue) > 0.0f || d.geometry);
      if (!d.visible && !f.holdsPolygons(d.brick)) continue;
      glm::ivec3 lo, hi;
      octree.voxelBox(n, &lo, &hi);
      d.blo = d.slo = glm::dvec3(lo) * mSpacing;
      d.bhi = d.shi = glm::dvec3(hi) * mSpacing;
      d.shell = options.proxy == Proxy::Shells && !camera.ortho && shellFrame(d.blo, d.bhi, camera.eye, &d.frame);
      d.crossed = d.visible && options.cut && slicePolygon(d.blo, d.bhi, glm::dvec3(f.cut), -f.cut.w, &d.cutPolygon);
      if (d.crossed && !(options.textures && options.textures->contains(b))) crossedToPack.push_back(mDraws.size());
      mDraws.push_back(std::move(d));
    }
    // In draw order, as a frame that packed every brick first did (the cache's order of use is the
    // same): each textured brick's cache entry found (marked as used by this frame, so that no draw
    // evicts it before its own), and the crossed bricks planned, their textures made from batches
    // packed just before.
    size_t next = 0;
    for (size_t first = 0;; first += mBatch) {
      const size_t count = std::min(mBatch, crossedToPack.size() - first);
      pack(crossedToPack.data() + first, count);
      const size_t end = first + count < crossedToPack.size() ? crossedToPack[first + count] : mDraws.size();
      for (; next < end; ++next) {
        BrickDraw& d = mDraws[next];
        if (!d.visible) continue;
        d.cached = options.textures ? options.textures->find(f.selection.bricks[d.brick]) : nullptr;
        if (d.crossed) {
          plan(d);
        } else if (!d.cached) {
          d.pending = true;
          mToPack.push_back(next);
        }
      }
      if (end == mDraws.size()) break;
    }
    mUploaded = crossedToPack.size() + mToPack.size();
  }

  // The frame's draws, back to front; those before planned() are ready to draw.
  std::vector<BrickDraw>& draws() { return mDraws; }
  size_t planned() const { return mPlanned; }
  // The first draw of the last batch planned.
  size_t lastBatch() const { return mLastBatch; }
  // The cutting plane's pieces, in draw order.
  const std::vector<CutPiece>& cut() const { return mCut; }

  // Plans the next batch: packs the next packBatch bricks on all cores, then plans the draws up to
  // the first brick of the batch after (to the last draw when no brick is left to pack).
  void planNext() {
    const size_t count = std::min(mBatch, mToPack.size() - mPacked);
    pack(mToPack.data() + mPacked, count);
    mPacked += count;
    const size_t end = mPacked < mToPack.size() ? mToPack[mPacked] : mDraws.size();
    mLastBatch = mPlanned;
    for (; mPlanned < end; ++mPlanned)
      if (!mDraws[mPlanned].crossed) plan(mDraws[mPlanned]);
  }

  // Records that draw @p d's packed texels were made into its texture.
  void uploaded(BrickDraw& d) {
    d.packed = PackedBrick{};
    --mHeld;
  }

  // Writes the frame's figures to @p st.
  void addStats(SlicesStats* st) const {
    st->bricks = mBricks;
    st->uploadedBricks = mUploaded;
    st->blendedBricks = mBlended;
    st->texels = mTexels;
    st->shellBricks = mShellBricks;
    st->textureBytes = mTexels * bytesPerTexel(mF.options.texelBits) + mCutTexels * kBytesPerCutTexel;
    st->peakPackedBricks = mPeakHeld;
  }

 private:
  // Packs the texels of draws @p js[0, count) on all cores. Warm frames (nothing to pack) do not
  // open the parallel region: its threads would spin for a while after it (libgomp's default wait
  // policy), taking a core from llvmpipe's rasterizer.
  void pack(const size_t* js, size_t count) {
    if (count == 0) return;
    ParallelFailure failure;
#pragma omp parallel for schedule(dynamic) if (count > 1)
    for (size_t k = 0; k < count; ++k)
      failure.run([&] {
        BrickDraw& d = mDraws[js[k]];
        const Brick& b = mF.selection.bricks[d.brick];
        const std::vector<glm::vec4> texels = brickTexels(mKnots, mF.octree, b);
        d.packed = packBrick(texels, mF.options.texelBits);
        d.packed.brick.ranges = texelRanges(texels, mF.octree.lattice(mF.octree.nodes()[d.node], b.p).dims);
      });
    failure.rethrow();
    mHeld += count;
    mPeakHeld = std::max(mPeakHeld, mHeld);
  }

  // Plans draw @p d, its brick found in the cache or packed.
  void plan(BrickDraw& d) {
    const Brick& b = mF.selection.bricks[d.brick];
    const KnotLattice fine = mF.octree.lattice(mF.octree.nodes()[d.node], b.p);
    d.sliced = d.visible;
    if (d.visible) {
      // A crossed brick's texture is made now, others' when they are drawn.
      CachedBrick* cached = d.cached;
      CachedBrick made;
      if (!cached && d.crossed) {
        made = uploadBrick(std::move(d.packed), fine.dims, mF.options.texelBits);
        uploaded(d);
        if (mF.options.textures) cached = &mF.options.textures->insert(b, std::move(made));
      } else if (!cached) {
        d.texels = fine.dims;
      }
      CachedBrick& brick = cached ? *cached : d.pending ? d.packed.brick : made;
      CutPiece piece;
      if (d.crossed) {
        piece.polygon = std::move(d.cutPolygon);
        if (mF.options.texelBits == TexelBits::Sixteen) {
          piece.texture = brick.texture.id();  // its value is 16 bits already
        } else {
          if (!brick.cutTexture) {
            const uint64_t before = brick.bytes;
            uploadCutTexture(brickTexels(mKnots, mF.octree, b), fine.dims, &brick);
            if (cached) mF.options.textures->grew(b, brick.bytes - before);
          }
          piece.texture = brick.cutTexture.id();
          mCutTexels += fine.count();
        }
      }
      d.texture = brick.texture.id();
      d.valueOffset = brick.valueOffset;
      d.valueScale = brick.valueScale;
      mTexels += fine.count();
      ++mBricks;
      mBlended += b.coarseCorners != 0;
      if (mF.options.visibleBoxes && !d.geometry) {
        glm::dvec3 vlo(0.0), vhi(0.0);
        findVisibleBlocks(brick.ranges, mF.table.visible, &brick.visible);
        d.sliced = visibleBox(brick.visible, fine, &vlo, &vhi);
        d.slo = glm::max(d.blo, vlo * mSpacing);
        d.shi = glm::min(d.bhi, vhi * mSpacing);
        if (d.sliced) {
          d.blocks = cached || d.pending ? &brick.visible : &mFrameBlocks.emplace_back(std::move(made.visible));
          d.lattice = fine;
        }
      }
      // The texture coordinates are affine in grid mm: uv = x·scale + offset.
      const glm::dvec3 dims(fine.dims);
      d.fineScale = glm::vec3(1.0 / (mSpacing * double(fine.step) * dims));
      d.fineOffset = glm::vec3((0.5 - glm::dvec3(fine.origin) / double(fine.step)) / dims);
      piece.fineScale = d.fineScale, piece.fineOffset = d.fineOffset, piece.valueOffset = d.valueOffset, piece.valueScale = d.valueScale;
      if (!piece.polygon.empty()) mCut.push_back(std::move(piece));
      if (!cached && !d.pending) {
        mFrameTextures.push_back(std::move(made.texture));
        if (made.cutTexture) mFrameTextures.push_back(std::move(made.cutTexture));
      }
    }
    // Each level is sliced at its own rate (LaMar 1999), the shader correcting the opacity for it,
    // on a subset of the global planes. A brick holding surface polygons is too, its slabs between
    // its own slices as in the paper, where its level approximates the field; where the level is
    // exact the brick keeps the base spacing so that the surface is composited exactly, and so
    // does a brick holding the eye, so that the near plane cuts the volume finely.
    const bool holdsEye = !mF.camera.ortho && glm::all(glm::greaterThanEqual(mF.camera.eye, d.blo)) && glm::all(glm::lessThanEqual(mF.camera.eye, d.bhi));
    const bool exactWithSurface = (!mF.polygonsOf.of(d.brick).empty() || !mF.meshesOf.of(d.brick).empty()) && b.error == 0.0f && b.coarseCorners == 0;
    // At least four planes across the brick's box: a ray's stretch in the brick that meets none of
    // its planes is lost.
    const double across = std::min({d.bhi.x - d.blo.x, d.bhi.y - d.blo.y, d.bhi.z - d.blo.z});
    const int period = std::clamp(int(across / (4.0 * mF.baseDelta)), 1, levelPeriod(fine.step, mF.options.stepVoxels));
    d.delta = mF.baseDelta * (d.sliced && !holdsEye && !exactWithSurface && !d.geometry ? period : 1);
    if (mF.options.preintegrated && d.blocks) {  // its fragments read up to a spacing either side
      d.slo = glm::max(d.blo, d.slo - kPreintegratedGrowth * d.delta);
      d.shi = glm::min(d.bhi, d.shi + kPreintegratedGrowth * d.delta);
    }
    mShellBricks += d.shell && d.sliced;
  }

  const SliceFrame& mF;
  const VolumeKnots mInMemory;
  const KnotSource& mKnots;
  const glm::dvec3 mSpacing;
  const size_t mBatch;
  std::vector<BrickDraw> mDraws;
  std::vector<CutPiece> mCut;
  std::deque<VisibleBlocks> mFrameBlocks;   // visible blocks of bricks no cache keeps
  std::vector<gl::Texture> mFrameTextures;  // textures no cache keeps
  std::vector<size_t> mToPack;              // draws whose bricks are packed batch by batch
  size_t mPacked = 0, mPlanned = 0, mLastBatch = 0;
  size_t mHeld = 0, mPeakHeld = 0;  // draws holding packed texels, now and at most
  uint64_t mTexels = 0, mCutTexels = 0, mBricks = 0, mBlended = 0, mShellBricks = 0, mUploaded = 0;
};

// Brick @p d's vertex stream: its slices far to near, each slab's SlabPolygon list before the slice
// that closes the slab.
void buildStream(BrickDraw& d, const SliceFrame& f, StreamScratch& scratch) {
  const Camera& camera = f.camera;
  const FrameCamera& frame = f.view;
  const glm::dvec3 spacing = f.spacing();
  const SurfacePolygons* surface = f.surface;
  auto& [list, boxes, one] = scratch;
  const ProxyDepth depth{d.shell, frame.forward, camera.eye};
  // This brick owns the proxies with depth in [bmin, bmax).
  const auto [bmin, bmax] = depth.range(d.blo, d.bhi);
  long long kLo = (long long)std::floor(bmin / d.delta) - 1, kHi = (long long)std::ceil(bmax / d.delta);
  const bool meshes = f.meshes && !f.meshesOf.of(d.brick).empty();
  if (meshes) {  // the user meshes' pieces beside the translucent isosurface's polygons
    SlabSource sources[2];
    size_t n = 0;
    if (surface) sources[n++] = {surface, f.polygonsOf.of(d.brick)};
    sources[n++] = {&*f.meshes, f.meshesOf.of(d.brick)};
    list.build(std::span<const SlabSource>(sources, n), {depth, d.delta, d.sliced, f.options.cutToSlabs}, f.centres);
  } else if (surface) {
    list.build(*surface, f.polygonsOf.of(d.brick), {depth, d.delta, d.sliced, f.options.cutToSlabs}, f.centres);
  }
  if (surface || meshes) {
    if (d.sliced && !list.empty()) {
      kLo = std::min(kLo, list.firstSlab());
      kHi = std::max(kHi, list.lastSlab());
    }
    d.surfaceTriangles = list.triangles();
    d.unseenTriangles = list.unseen();
  }
  if (d.blocks) {
    boxes.resize(size_t(kHi - kLo + 1));
    // Blocks are merged while a group spans at most two pixels along every axis: a small frame
    // of a large study has many blocks to each pixel, and finer boxes would save few fragments.
    const double blockMm = 2.0 * d.lattice.step * std::max({spacing.x, spacing.y, spacing.z}), pixelMm = camera.pixelMmAt(d.blo, d.bhi);
    int merge = 1;
    while (merge < 64 && 2 * merge * blockMm <= 2.0 * pixelMm) merge *= 2;
    proxyBoxes(*d.blocks, d.lattice, spacing, depth, {d.delta, kLo, merge, f.options.preintegrated ? kPreintegratedGrowth * d.delta : 0.0}, &boxes);
  }
  for (long long k = kHi; k >= kLo; --k) {
    if ((surface || meshes) && f.options.slabOrder) list.emitDownTo(k, &d.stream);
    const double plane = double(k) * d.delta;
    one.clear();
    glm::dvec3 lo = d.slo, hi = d.shi;
    if (d.blocks) {
      lo = glm::max(lo, boxes[size_t(k - kLo)].first);
      hi = glm::min(hi, boxes[size_t(k - kLo)].second);
    }
    if (d.sliced && plane >= bmin && plane < bmax && glm::all(glm::lessThanEqual(lo, hi)) &&
        (d.shell ? plane > 0.0 && shellPolygon(lo, hi, d.frame, {camera.eye, plane, shellCells(d.frame, plane, d.delta)}, &one)
                 : slicePolygon(lo, hi, frame.forward, plane, &one))) {
      for (size_t v = 0; v < one.size(); v += 3) putVertex(&d.stream, glm::vec3(one[v], one[v + 1], one[v + 2]), glm::vec3(0.0f), 0.0f, -1e30f, 1e30f);
      ++d.slices;
    }
  }
  if (surface || meshes) {
    list.emitRest(&d.stream);
    d.slabPolygonDraws = list.draws();
  }
}

FramePrograms::FramePrograms(const SliceFrame& f)
    : mOptions(f.options), mCamera(f.camera), mFrame(f.view), mTable(f.table), mCutPlane(glm::vec4(f.cut)), mSpacing(f.spacing()),
      mSmooth(f.translucent && !f.options.surface->normals.empty()) {
  define();
}

// One slice frame, its stages as methods (as vtkFlyingEdges3D's passes are methods of one
// algorithm object): made, it holds the target, what every stage reads (SliceFrame) and the
// programs; renderSlices calls the stages in order, each drawing over what those before it drew.
class SlicesFrame {
 public:
  SlicesFrame(const SelectedBricks& in, const TransferFunction& tf, const Camera& camera, const SlicesOptions& options)
      : mTarget(camera, options), mF(in, tf, camera, options, mTarget.rows),
        mPrograms(mF) {
    if (options.cut) glEnable(GL_CLIP_DISTANCE0);
  }

  // The opaque surface first, writing depth; then depth writes off and blending on for the rest.
  void drawOpaqueSurface() {
    const bool opaque = mF.withTriangles && !mF.translucent;
    if (opaque) mStats.unseenTriangles = drawSurfaceTriangles();
    glEnableVertexAttribArray(0);
    glEnableVertexAttribArray(1);
    glEnableVertexAttribArray(2);
    glDepthMask(GL_FALSE);
    // Only the opaque surface and the cutting plane write depth; without them every fragment passes
    // (llvmpipe would still read and compare the depth of every one).
    if (!opaque && !mF.options.cut) glDisable(GL_DEPTH_TEST);
    glEnable(GL_BLEND);
    glBlendFunc(GL_ONE, GL_ONE_MINUS_SRC_ALPHA);  // premultiplied "over", back to front
  }

  // The bricks' draws planned in order, the textures of those the cutting plane crosses made; the
  // fragments are counted from here on.
  void planBricks() {
    mQuery = gl::Query::make();
    glBeginQuery(GL_FRAGMENT_SHADER_INVOCATIONS_ARB, mQuery.id());
    mPlanner.emplace(mF);
  }

  // The cutting plane, opaque and writing depth.
  void drawCutPlane() {
    if (mF.options.cut) mStats.cutPolygons = hyb::drawCutPlane(mPrograms.cut(), mPlanner->cut());
  }

  // The bricks' textures and slicing planned a batch ahead of the drawing (the next batch when
  // the drawing enters the last one planned); each brick's slices and SlabPolygon lists built by a
  // worker in draw order (it publishes how many are done) and drawn here. The worker builds only
  // planned draws, at most kLookahead bricks ahead of the drawing, so the streams held at once stay
  // a few bricks' worth however many bricks the frame has.
  void drawBricks() {
    constexpr size_t kLookahead = 32;
    BrickPlanner& planner = *mPlanner;
    std::vector<BrickDraw>& draws = planner.draws();
    planner.planNext();
    // The draws the worker may build, set here alone; kAbandon stops it.
    constexpr size_t kAbandon = std::numeric_limits<size_t>::max();
    std::atomic<size_t> built{0}, ready{0};
    std::exception_ptr failure;
    std::thread worker([&] {
      StreamScratch scratch;
      try {
        for (size_t j = 0; j < draws.size(); ++j) {
          size_t may = ready.load(std::memory_order_acquire);
          for (; may <= j; may = ready.load(std::memory_order_acquire)) ready.wait(may);
          if (may == kAbandon) return;
          buildStream(draws[j], mF, scratch);
          built.fetch_add(1, std::memory_order_release);
          built.notify_one();
        }
      } catch (...) {
        failure = std::current_exception();
        built.store(draws.size(), std::memory_order_release);
        built.notify_one();
      }
    });
    // The worker is joined whatever happens here (an exception leaving this scope, from the drawing
    // or the packing, would otherwise terminate the process through its std::thread); it is stopped
    // first.
    struct Join {
      std::thread& t;
      std::atomic<size_t>& ready;
      ~Join() {
        ready.store(kAbandon, std::memory_order_release);
        ready.notify_one();
        if (t.joinable()) t.join();
      }
    } join{worker, ready};
    ProgressTask progress(mF.options.progress, "slices", draws.size());
    for (size_t j = 0; j < draws.size(); ++j, progress.advance()) {
      if (j >= planner.lastBatch() && planner.planned() < draws.size()) planner.planNext();
      HYB_DCHECK(j < planner.planned());
      ready.store(std::min(planner.planned(), j + kLookahead + 1), std::memory_order_release);
      ready.notify_one();
      for (size_t seen = built.load(std::memory_order_acquire); seen <= j; seen = built.load(std::memory_order_acquire)) built.wait(seen);
      if (failure) break;
      drawBrick(draws[j]);
    }
    worker.join();
    if (failure) std::rethrow_exception(failure);
  }

  // The isosurface's outline on the cutting plane, on top.
  void drawCutLine() {
    const SlicesOptions& options = mF.options;
    if (options.cut && options.cutLine && options.surface)
      mStats.cutLineSegments = hyb::drawCutLine(*options.surface, mF.cut, mF.view.viewProj, options.surfaceColor);
  }

  // The band's pixels, and the frame's figures in @p stats (if given).
  Image readBack(SlicesStats* stats) {
    glEndQuery(GL_FRAGMENT_SHADER_INVOCATIONS_ARB);
    GLuint fragments = 0;  // libOSMesa exports only the 32-bit getter; frames stay below 2^32 fragments
    glGetQueryObjectuiv(mQuery.id(), GL_QUERY_RESULT, &fragments);
    mStats.fragments = fragments;
    mPlanner->addStats(&mStats);
    const int W = mF.camera.width, h = mF.rows.y - mF.rows.x;
    Image image(W, h);
    std::vector<float> rgba(size_t(W) * size_t(h) * 4);
    glReadPixels(0, mF.camera.height - mF.rows.y, W, h, GL_RGBA, GL_FLOAT, rgba.data());
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < W; ++x) {
        const float* p = &rgba[(size_t(h - 1 - y) * W + x) * 4];
        image.at(x, y) = glm::vec4(p[0], p[1], p[2], p[3]);
      }
    const GLenum err = glGetError();
    glDisable(GL_CLIP_DISTANCE0);
    glDisable(GL_SCISSOR_TEST);
    if (mF.options.textures) mF.options.textures->evict();
    if (err != GL_NO_ERROR) HYB_THROW(RuntimeError, "OpenGL error 0x", std::hex, err, " while rendering slices");
    if (stats) *stats = mStats;
    return image;
  }

 private:
  // Draws the opaque surface with depth writes (kSurfaceFragment), headlight-shaded (by its vertex
  // normals when it has them), clipped by the cutting plane, from the target's vertex buffer. The
  // triangles that cover no pixel centre are left out (a large study's surface at a small size:
  // nearly all of them); returns their count.
  uint64_t drawSurfaceTriangles() {
    const GLuint program = mPrograms.surface();
    const TriangleMesh& surface = *mF.options.surface;
    const Camera& camera = mF.camera;
    const PixelCentres* centres = mF.centres;
    const glm::vec3 color(mF.options.surfaceColor);
    const glm::vec4 cutPlane(mF.cut);
    glUseProgram(program);
    const glm::vec3 f(camera.forward());
    auto at = [&](const char* name) { return glGetUniformLocation(program, name); };
    glUniformMatrix4fv(at("viewProj"), 1, GL_FALSE, glm::value_ptr(mF.view.viewProj));
    glUniform3f(at("eye"), float(camera.eye.x), float(camera.eye.y), float(camera.eye.z));
    glUniform3fv(at("forward"), 1, glm::value_ptr(f));
    glUniform1i(at("ortho"), camera.ortho ? 1 : 0);
    glUniform3fv(at("color"), 1, glm::value_ptr(color));
    glUniform4fv(at("cutPlane"), 1, glm::value_ptr(cutPlane));
    // Drawn a run of triangles at a time, in order (the depth test keeps the same fragments): the
    // vertex stream, and llvmpipe's copy of it, never hold a large surface whole.
    constexpr size_t kRunFloats = size_t(6) << 20;
    std::vector<float> data;
    uint64_t unseen = 0;
    glEnableVertexAttribArray(0);
    glVertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, 6 * sizeof(float), nullptr);
    glEnableVertexAttribArray(1);
    glVertexAttribPointer(1, 3, GL_FLOAT, GL_FALSE, 6 * sizeof(float), reinterpret_cast<void*>(3 * sizeof(float)));
    auto draw = [&] {
      if (data.empty()) return;
      glBufferData(GL_ARRAY_BUFFER, GLsizeiptr(data.size() * sizeof(float)), data.data(), GL_STREAM_DRAW);
      glDrawArrays(GL_TRIANGLES, 0, GLsizei(data.size() / 6));
      data.clear();
    };
    for (const glm::uvec3& t : surface.triangles) {
      const glm::vec3 a = surface.vertices[t.x], b = surface.vertices[t.y], c = surface.vertices[t.z];
      if (const PixelCentres::Cover cover = centres ? centres->cover(a, b, c, nullptr) : PixelCentres::Cover{}; cover.known && cover.centres == 0) {
        ++unseen;
        continue;
      }
      const glm::vec3 face = glm::normalize(glm::cross(b - a, c - a));
      for (int k = 0; k < 3; ++k) {
        const glm::vec3 p = surface.vertices[t[k]], n = surface.normals.empty() ? face : surface.normals[t[k]];
        data.insert(data.end(), {p.x, p.y, p.z, n.x, n.y, n.z});
      }
      if (data.size() >= kRunFloats) draw();
    }
    draw();
    return unseen;
  }

  // Draws @p d: its figures counted, its texture made from its packed texels, its stream sent to
  // the slice program with its brick's uniforms.
  void drawBrick(BrickDraw& d) {
    const SlicesOptions& options = mF.options;
    mStats.slices += d.slices;
    mStats.surfaceTriangles += d.surfaceTriangles;
    mStats.unseenTriangles += d.unseenTriangles;
    mStats.slabPolygonDraws += d.slabPolygonDraws;
    // A packed brick's texture, made for its draw: kept by the cache if it has room (it evicts
    // earlier frames' bricks for it), else deleted when this draw ends.
    CachedBrick drawing;
    if (d.pending) {
      drawing = uploadBrick(std::move(d.packed), d.texels, options.texelBits);
      mPlanner->uploaded(d);
      d.texture = drawing.texture.id();
    }
    // The frees of a frame's textures and streams leave the heap fragmented, its pages resident
    // though unused: handed back every kTrimBytes drawn, a frame's memory follows what it holds.
    constexpr size_t kTrimBytes = size_t(128) << 20;
    mDrawnBytes += d.stream.size() * sizeof(float) + drawing.bytes;
    if (mDrawnBytes > kTrimBytes) {
      malloc_trim(0);
      mDrawnBytes = 0;
    }
    auto keep = [&] {
      if (drawing.texture && options.textures && options.textures->makeRoom(drawing.bytes))
        options.textures->insert(mF.selection.bricks[d.brick], std::move(drawing));
    };
    if (d.stream.empty()) {
      keep();
      return;
    }
    const FramePrograms::Slice& sp = mPrograms.slice(d.delta > mF.baseDelta, d.slabPolygonDraws > 0);
    if (sp.id != mBound) glUseProgram(mBound = sp.id);
    if (d.visible) {
      glActiveTexture(GL_TEXTURE0);
      glBindTexture(GL_TEXTURE_3D, d.texture);
      glUniform3fv(sp.fineScale, 1, glm::value_ptr(d.fineScale));
      glUniform3fv(sp.fineOffset, 1, glm::value_ptr(d.fineOffset));
      glUniform1f(sp.valueOffset, d.valueOffset);
      glUniform1f(sp.valueScale, d.valueScale);
      glUniform3f(sp.boxLo, float(d.blo.x), float(d.blo.y), float(d.blo.z));
      glUniform3f(sp.boxHi, float(d.bhi.x), float(d.bhi.y), float(d.bhi.z));
    }
    glUniform1f(sp.sliceSpacing, float(d.delta));
    glUniform1i(sp.shells, d.shell ? 1 : 0);
    // A buffer object per brick, deleted after its draw: re-specifying one would make llvmpipe wait
    // for the previous draws, while llvmpipe is done with a draw's vertices when the call returns.
    const gl::Buffer buffer = gl::Buffer::make();
    glBindBuffer(GL_ARRAY_BUFFER, buffer.id());
    glBufferData(GL_ARRAY_BUFFER, GLsizeiptr(d.stream.size() * sizeof(float)), d.stream.data(), GL_STREAM_DRAW);
    glVertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, kStreamFloats * sizeof(float), nullptr);
    glVertexAttribPointer(1, 3, GL_FLOAT, GL_FALSE, kStreamFloats * sizeof(float), reinterpret_cast<void*>(3 * sizeof(float)));
    glVertexAttribPointer(2, 3, GL_FLOAT, GL_FALSE, kStreamFloats * sizeof(float), reinterpret_cast<void*>(6 * sizeof(float)));
    glDrawArrays(GL_TRIANGLES, 0, GLsizei(d.stream.size() / kStreamFloats));
    std::vector<float>().swap(d.stream);
    keep();
  }

  const SliceTarget mTarget;
  const SliceFrame mF;
  FramePrograms mPrograms;
  SlicesStats mStats;
  gl::Query mQuery;                      // counts the fragments from the planning on
  std::optional<BrickPlanner> mPlanner;  // made by planBricks
  GLuint mBound = 0;                     // the slice program in use
  size_t mDrawnBytes = 0;                // of streams and new textures since the heap was last trimmed
};

}  // namespace

PixelCentres framePixelCentres(const Volume& volume, const Camera& camera) {
  // (the slice spacing only bounds the slab indices, which these centres do not use)
  return PixelCentres(frameCamera(volume, camera, std::numeric_limits<double>::max()).viewProj, camera.width, camera.height);
}

SlicesOptions slicesOptions(const FrameGrid& grid, const Look& look, const Quality& quality, const TriangleMesh* surface, const GridMeshes* meshes) {
  SlicesOptions so;
  so.meshes = meshes && !meshes->empty() ? meshes : nullptr;
  so.stepVoxels = quality.step.value_or(0.5);
  so.shading = look.shading;
  so.texelBits = quality.texelBits;
  so.proxy = quality.proxy;
  so.surface = surface;
  so.surfaceColor = look.surfaceColor;
  so.cut = grid.cut ? &*grid.cut : nullptr;
  so.cutLine = look.cutLine;
  so.voi = grid.voi ? &*grid.voi : nullptr;
  so.cutToSlabs = quality.cutToSlabs;
  so.region = quality.region ? &*quality.region : nullptr;
  so.rows = quality.rows;
  return so;
}

Image renderSlices(const SelectedBricks& bricks, const TransferFunction& tf, const Camera& camera, const SlicesOptions& options,
                   SlicesStats* stats) {
  SlicesFrame frame(bricks, tf, camera, options);  // the target, the table, the bricks in order, the programs
  bindGeometry(options);
  frame.drawOpaqueSurface();
  frame.planBricks();
  frame.drawCutPlane();
  frame.drawBricks();
  frame.drawCutLine();
  return frame.readBack(stats);
}

}  // namespace hyb
