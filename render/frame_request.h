// What a frame is asked for: where it is seen from (View), what it shows (Look) and how well it is
// made (Quality), in patient space, and the same in the grid frame the renderers work in
// (FrameGrid). The engine (render/scene_renderer.h) takes these; each renderer makes its own
// options from them beside its code (slicesOptions, raycastOptions), so a quality a renderer
// honours is read in one place.
#pragma once

#include <glm/glm.hpp>

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "hybrid_octree/selection.h"
#include "render/camera.h"
#include "render/cut_plane.h"
#include "render/preintegration.h"
#include "render/regions.h"
#include "render/transfer_function.h"
#include "render/voi.h"
#include "surface/mesh.h"
#include "volume/patient_frame.h"

namespace hyb {

/// Proxy geometry that samples the bricks (LaMar 1999).
enum class Proxy {
  Planes,  ///< view-aligned planes f·x = kΔ, globally aligned
  Shells,  ///< spherical shells |x − eye| = kΔ around the eye (perspective; bricks the eye is too close
           ///< to, and orthographic views, use planes)
};

/// Precision of the brick textures' value and gradient: 8 bits (RGBA8, which llvmpipe filters in
/// fixed point) or 16 bits (RGBA16: twice the bytes, slower frames, for transfer functions whose
/// features are narrow against a brick's range of values, e.g. soft tissue next to air and bone).
enum class TexelBits { Eight = 8, Sixteen = 16 };
/// Bytes of one brick texel: value and three gradient components.
inline constexpr uint64_t bytesPerTexel(TexelBits bits) { return bits == TexelBits::Sixteen ? 8 : 4; }

/// The renderer of a frame: the hybrid slice renderer, or the reference ray tracer (ground truth).
enum class Renderer { Slices, Raycast };
/// How the isosurface is shaded: by the volume's gradient at its vertices, or by each polygon's plane.
enum class SurfaceNormals { Gradient, Facet };

/// The isosurface's colour unless one is asked for: bone white, opaque.
inline const glm::vec4 kDefaultSurfaceColor{0.95f, 0.92f, 0.85f, 1.0f};

/// Where a frame is seen from: the camera in patient space (LPS mm), with the image's size.
struct View {
  Camera camera;

  /// Empty when valid, else a message saying what of the camera is impossible.
  std::string validate() const;
};

/// One of Levoy's analytic primitives (--primitive), in patient space (LPS mm).
struct UserPrimitive {
  enum class Kind { Plane, Sphere, Polygon };
  Kind kind = Kind::Plane;
  std::vector<glm::dvec3> points;  ///< a plane's point, a sphere's centre, a polygon's corners (in order)
  glm::dvec3 normal{0.0};          ///< a plane's (not zero)
  double radius = 0.0;             ///< a sphere's (> 0)
  double thickness = 0.0;          ///< a plane's sheet (mm) when scan-converted; 0: the smallest voxel spacing
};

/// How a frame draws its user meshes and primitives (docs/user-geometry.md).
enum class MeshMethod {
  Polygons,     ///< exactly, in the SlabPolygon lists (the slices) and crossed by the rays (the reference)
  ScanConvert,  ///< Levoy's: filtered and scan-converted into a coverage channel on the volume's grid
};

/// A mesh of the user's own (an implant, a segmentation, a plan) drawn inside the volume with its
/// own colour: its triangles in patient space (LPS mm), shared by the frames that show it.
struct UserMesh {
  std::string name;                          ///< the file it came from (or "meshes[k]"), for messages
  std::shared_ptr<const TriangleMesh> mesh;  ///< finite vertices, indices in range (checkUserMesh)
  glm::vec4 color{0.4f, 0.7f, 1.0f, 0.5f};   ///< straight RGBA; a < 1 is translucent (per crossing)
  /// The analytic primitive @c mesh tessellates (scan-converted as itself), or none (a mesh).
  std::shared_ptr<const UserPrimitive> primitive;
};
/// At most this many user meshes a frame (the slice shader's table of colours holds them and the
/// isosurface's).
inline constexpr int kMaxUserMeshes = 15;

/// What a frame shows. Cut, volume of interest and meshes in patient space (LPS mm).
struct Look {
  TransferFunction tf;
  std::optional<float> iso;                      ///< the isosurface's value, or none
  glm::vec4 surfaceColor = kDefaultSurfaceColor;  ///< straight RGBA; a < 1 is translucent
  SurfaceNormals normals = SurfaceNormals::Gradient;
  bool shading = true;                            ///< gradient shading of the volume
  std::optional<CutPlane> cut;
  bool cutLine = true;                            ///< the surface's outline on the cutting plane
  std::optional<VolumeOfInterest> voi;            ///< its box along the patient's axes
  /// Meshes drawn exactly in both renderers, in the SlabPolygon lists beside the isosurface (the
  /// slices) and crossed by the rays (the reference); none: the frame is drawn as without them.
  std::vector<UserMesh> meshes;
  MeshMethod meshMethod = MeshMethod::Polygons;
  /// The scan-convert method's kernel: the side of a box in voxel cells (1: each voxel's own cell,
  /// the partial-volume fraction; wider is softer), or 0 for none (the voxel centre point-sampled:
  /// binary, aliased).
  double meshFilter = 1.0;

  /// Empty when valid, else a message naming the offending flag (--surface-color, --cut, --voi...).
  std::string validate() const;
};

/// How well a frame is made.
struct Quality {
  Renderer renderer = Renderer::Slices;
  double epsilon = 0.0;             ///< ε_u, data units
  double budgetMb = 0.0;            ///< texture budget, MB (0 = unlimited) ...
  double budgetPercent = 0.0;       ///< ... or a percentage of this view's full-resolution texels (0 = none)
  std::optional<double> step;       ///< sample spacing in voxels (default: 0.5 slices, 0.25 reference)
  Proxy proxy = Proxy::Planes;
  bool blend = true;
  /// Budgets rank bricks by the image errors measured for the last view even when the camera has
  /// moved since (same look): while a viewer's camera moves, measuring every view costs more than
  /// its frame, and the ranking changes little from one view to the next.
  bool reuseViewErrors = false;
  /// Draws the isosurface simplified (PreparedSurface::simplified, shaded smoothly whatever
  /// Look::normals asks): the coarsest level whose error is at most surfaceErrorPixels pixels where
  /// the volume comes nearest the eye, so a small frame of a large study draws as many triangles as
  /// its pixels show. Level 0 (a voxel's error, about a fifth of the triangles on CT bone) is in brick order
  /// exactly when the bricks are at least kSimplifiedBlockVoxels wide; a coarser level's triangle
  /// crossing a brick's face is composited with the brick holding its centroid.
  bool simplifiedSurface = false;
  double surfaceErrorPixels = 1.0;
  /// Cuts translucent polygons to the slabs between slices (SlicesOptions::cutToSlabs); false
  /// places each whole in its centroid's slab.
  bool cutToSlabs = true;
  TexelBits texelBits = TexelBits::Eight;
  /// Post-classified samples, or segments pre-integrated between their ends' values (both
  /// renderers; the table is made when the transfer function changes: FrameStats::preintegrationMs).
  Classification classification = Classification::Post;
  int maxBrickEdge = 16;
  /// LaMar's screen-space stop (SelectionParams::lodPixels; 0 = off). A slice frame's surface
  /// follows it too, unless simplifiedSurface: where the volume comes nearest the eye, the largest
  /// cubes at most this many pixels wide (clusterSpacingFor, at most the octree's leaf edge)
  /// cluster its vertices (clusteredSurface; the Surface Octree's surface when they are one voxel)
  /// (FrameStats::surfaceSpacing).
  double lodPixels = 0.0;
  std::optional<glm::dvec3> focus;  ///< region of interest, patient mm
  /// Images of one frame, coarse to fine (Levoy's progressive refinement): slices render 1/8 of
  /// the next image's texels each; the reference traces rays 2^(levels − 1) pixels apart first.
  int progressive = 1;
  double adaptive = 0.0;            ///< reference: refine where colours differ by more than this (1/255 units)
  /// Renders only the image rows [rows.x, rows.y) (from the top), exactly as the whole frame has
  /// them; the image is those rows only (its row 0 is rows.x). Not with progressive or adaptive refinement.
  std::optional<glm::ivec2> rows;
  /// A paged scene's slice frames: true reads every block the selection needs (the exact frame);
  /// false draws each brick whose knots are not cached from a coarser resident level
  /// (residentSelection: never a hole) while the store's prefetch thread loads them, and the
  /// frame says it is not final (FrameStats::bricksNotResident).
  bool waitForBricks = true;
  /// With waitForBricks false: texels the frame may pack for textures the cache does not keep (0:
  /// no bound). Bricks beyond it are drawn coarser, from kept textures where they can be, and
  /// packed by the frames after (Carmona et al.: the cut moves towards the new one frame by frame,
  /// so a moving frame that meets many new bricks costs about what the one before did).
  uint64_t packTexels = 0;
  /// The selection select() made for this very frame (a sort-last frame's, shared by its ranks),
  /// drawn instead of selecting again; none: the frame selects.
  std::shared_ptr<const Selection> selection;
  /// Renders at this fraction of the image's width and height and magnifies the result bilinearly
  /// (render/image.h resampled), as VTK's image sample distance 1/imageScale does: where a pixel
  /// is smaller than a voxel's footprint the frame costs a fraction of its fragments, and the
  /// magnification smooths the slices' aliasing. 1: every pixel rendered.
  double imageScale = 1.0;
  /// A sort-last frame's region (grid frame mm, render/regions.h), or none: the frame draws only
  /// what lies in it (slices: its bricks; the reference: its segments; both: the surface cut to
  /// it), on the whole frame's sample planes, so that the regions' images composited front to back
  /// (Regions::frontToBack) make the whole frame's image. Not with progressive or adaptive refinement.
  std::optional<RegionBox> region;
  /// Slice frames whose surface is not made yet: true makes it (the exact frame); false draws the
  /// kept surface of that isovalue nearest it (the full-resolution one when kept, else the finest
  /// clustered one) without making anything, as a viewer's frames do while its builder thread
  /// makes the surface (FrameStats::surfaceSpacing says which was drawn).
  bool waitForSurface = true;
  /// Ray-traced frames drawn by the moving frames' tracer (render/raycast_interactive.h: float
  /// arithmetic, a table for the transfer function, rays stopped at α ≥ 0.99) where it serves the
  /// frame; false: the reference's.
  bool interactiveRays = false;

  /// Empty when valid, else a message naming the offending flag (--epsilon, --step, --budget...).
  std::string validate() const;
};

/// @throw ValueError naming the first impossible parameter of a frame.
void validateFrame(const View& view, const Look& look, const Quality& quality);

/// A frame's camera, cutting plane and volume of interest in the grid frame of a volume whose
/// patient frame is @p frame (docs/patient-space.md): what the renderers take.
struct FrameGrid {
  Camera camera;
  std::optional<CutPlane> cut;
  std::optional<VolumeOfInterest> voi;
};
FrameGrid frameGrid(const View& view, const Look& look, const PatientFrame& frame);

}  // namespace hyb
