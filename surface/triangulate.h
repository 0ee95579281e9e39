// Exact triangulation of planar polygons with integer vertices.
#pragma once

#include <glm/glm.hpp>

#include <array>
#include <cstdint>
#include <vector>

namespace hyb {

/// Triangulates the simple planar polygon @p loop (indices into @p points, counter-clockwise seen
/// against @p normal) by ear clipping with exact integer orientation tests. Collinear vertices
/// (T-junctions) are kept and never produce zero-area triangles. Appends to @p out, with the same
/// orientation as the polygon. Returns false (appending nothing) when the polygon is degenerate or
/// not simple enough for ear clipping.
bool triangulatePolygon(const std::vector<glm::ivec3>& points, const uint32_t* loop, size_t n, const glm::ivec3& normal,
                        std::vector<std::array<uint32_t, 3>>* out);

}  // namespace hyb
