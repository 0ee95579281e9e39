// Operations on triangle meshes after extraction: dropping vertices no triangle uses, shading
// normals from the volume's gradient, and placing a grid-frame mesh in the patient.
#pragma once

#include "surface/mesh.h"
#include "volume/patient_frame.h"
#include "volume/volume.h"

namespace hyb {

/// Removes the vertices no triangle references (the Surface Octree's reconstruction leaves the
/// straight-through vertices it dropped from polygons), renumbering triangles, polygon loops and
/// normals. Keeps the order of the vertices that remain.
void removeUnreferencedVertices(TriangleMesh* mesh);

/// Sets @p mesh's per-vertex normals (grid-frame mesh, mm) from @p volume's gradient: outward is
/// towards lower values (samples ≥ the isovalue are inside), so n = −∇f/|∇f|, with the gradient
/// Levoy's central differences interpolated trilinearly at the vertex (Volume::sampleGradient).
/// Where the gradient vanishes the area-weighted normal of the vertex's triangles is used. The
/// geometry is unchanged: smooth shading of the exact DiscMC surface.
void setGradientNormals(const Volume& volume, TriangleMesh* mesh);

/// Maps a grid-frame mesh (mm) into the patient (LPS mm) with @p frame; a mirrored frame reverses
/// every triangle's winding so that outward stays outward.
void toPatientSpace(const PatientFrame& frame, TriangleMesh* mesh);

}  // namespace hyb
