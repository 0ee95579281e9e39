// Operations on triangle meshes after extraction: dropping vertices no triangle uses, shading
// normals from the volume's gradient, and placing a grid-frame mesh in the patient.
#pragma once

#include <algorithm>
#include <functional>
#include <limits>
#include <span>

#include "surface/mesh.h"
#include "volume/patient_frame.h"
#include "volume/volume.h"

namespace hyb {

/// Removes the vertices no triangle references (the Surface Octree's reconstruction leaves the
/// straight-through vertices it dropped from polygons), renumbering triangles and normals. Keeps
/// the order of the vertices that remain.
void removeUnreferencedVertices(TriangleMesh* mesh);

/// The distance below which float coordinates of magnitude up to @p scale mm (taken as at least 1)
/// no longer tell points apart once rounded: 16 ulps.
inline double floatResolutionMm(double scale) { return 16.0 * double(std::numeric_limits<float>::epsilon()) * std::max(scale, 1.0); }

/// Whether the triangle (a, b, c) (mm) is flat: its corner opposite the longest edge lies within
/// floatResolutionMm of that edge's line. Such a triangle shows no area, but llvmpipe rasterises
/// it once its float corners snap apart, with attributes interpolated through the reciprocal of
/// its area (NaN colours: black specks), so nothing drawn may hold one.
bool flatTriangle(const glm::dvec3& a, const glm::dvec3& b, const glm::dvec3& c);

/// Sets @p mesh's per-vertex normals (grid-frame mesh, mm) from @p volume's gradient: outward is
/// towards lower values (samples ≥ the isovalue are inside), so n = −∇f/|∇f|, with the gradient
/// Levoy's central differences interpolated trilinearly at the vertex (Volume::sampleGradient).
/// Where the gradient vanishes the area-weighted normal of the vertex's triangles is used. The
/// geometry is unchanged: smooth shading of the exact DiscMC surface.
void setGradientNormals(const Volume& volume, TriangleMesh* mesh);
/// The gradients (data units per mm) at voxel positions: gradients[i] at points[i]. Called from
/// several threads at once, on runs of neighbouring vertices.
using GradientsAt = std::function<void(std::span<const glm::vec3> points, glm::vec3* gradients)>;
/// The same with the gradient from @p gradients on a grid of @p spacing: a field that is not held
/// whole (a paged scene's, read through its cache).
void setGradientNormals(const glm::dvec3& spacing, const GradientsAt& gradients, TriangleMesh* mesh);

/// Maps a grid-frame mesh (mm) into the patient (LPS mm) with @p frame; a mirrored frame reverses
/// every triangle's winding so that outward stays outward.
void toPatientSpace(const PatientFrame& frame, TriangleMesh* mesh);

}  // namespace hyb
