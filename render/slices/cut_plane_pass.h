// The cutting plane's pass (a multiplanar reformat in 3D; LaMar et al. 2000): the plane's piece in
// every textured brick it crosses, drawn first, opaque and writing depth, from the brick's values
// at 16 bits through the transfer function (what is kept of the volume lies behind it, so slices
// fail the depth test where it is opaque), and at the end the isosurface's intersection with the
// plane as lines on top.
#pragma once

#include <glm/glm.hpp>

#include <vector>

#include "render/gl_objects.h"
#include "surface/mesh.h"

namespace hyb {

/// One brick's piece of the cutting plane.
struct CutPiece {
  std::vector<float> polygon;  ///< triangles, xyz a vertex (grid mm)
  GLuint texture = 0;          ///< the brick's 16-bit values
  glm::vec3 fineScale{0.0f}, fineOffset{0.0f};  ///< grid mm -> the texture's coordinates
  float valueOffset = 0.0f, valueScale = 1.0f;  ///< value = offset + scale · (2·texel − 1)
};

/// Draws @p pieces with @p program (kCutFragment, its camera and lookup-table uniforms set) into the
/// bound target, writing depth. Returns the pieces drawn.
uint64_t drawCutPlane(GLuint program, const std::vector<CutPiece>& pieces);

/// Draws the intersection of @p surface with the plane @p cut (n·x + w = 0) as lines of @p color on
/// top: the plane is the nearest thing wherever it is drawn. Returns the segments drawn.
uint64_t drawCutLine(const TriangleMesh& surface, const glm::dvec4& cut, const glm::mat4& viewProj, const glm::vec4& color);

}  // namespace hyb
