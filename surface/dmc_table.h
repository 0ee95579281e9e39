// The Discretized Marching Cubes case table (Montani, Scateni and Scopigno, "Discretized Marching
// Cubes", Visualization '94; docs/surface.md), derived in code at first use.
//
// Cell-local doubled coordinates: corner c sits at 2·(c&1, c>>1&1, c>>2&1); a corner is inside when
// its sample is ≥ the isovalue. Vertices are the midpoints of the 12 edges.
//
// Derivation, per configuration:
//  1. Loops. On each face the crossed edges are joined by segments; on an ambiguous face (inside
//     corners diagonal) the segments cut off the two outside corners, i.e. inside corners stay
//     connected (the rule of Bourke's table, seen from the other side). The rule reads only the
//     face's four corners, so two cells sharing a face always produce the same trace on it: the
//     table is crack-free by construction. Segments are directed so that loops run counter-clockwise
//     seen from outside the solid.
//  2. Triangulation. Among all triangulations of every loop, keep those whose triangles are
//     non-degenerate, have one of the 13 normals, do not lie in a cube face and add no diagonal
//     lying in a cube face; take the combination with the fewest distinct planes (ties: first in
//     enumeration order).
//  3. Polygons. Triangles on the same plane that share an edge are merged into polygons.
// caseTableStats() reports what the derivation found; the tests check it.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "surface/discrete_plane.h"

namespace hyb::dmc {

/// Corner @p c of a cell in doubled local coordinates.
inline glm::ivec3 cornerPosition(int c) { return 2 * glm::ivec3(c & 1, (c >> 1) & 1, (c >> 2) & 1); }

/// The two corners of edge @p e (edges 0–3 run along x, 4–7 along y, 8–11 along z).
std::array<int, 2> edgeCorners(int e);

/// Midpoint of edge @p e in doubled local coordinates (exactly one odd coordinate).
glm::ivec3 edgeMidpoint(int e);

/// One merged polygon of a configuration: edge-midpoint vertices, counter-clockwise from outside.
struct CasePolygon {
  uint8_t plane = 0;               ///< index into Case::planes
  std::vector<uint8_t> edges;      ///< vertex = edgeMidpoint(edges[i])
};

/// Everything the table holds for one configuration.
struct Case {
  std::vector<PlaneId> planes;                  ///< distinct planes, cell-local (at most 4)
  std::vector<std::array<uint8_t, 3>> triangles;  ///< vertex edges, counter-clockwise from outside
  std::vector<uint8_t> trianglePlane;           ///< index into planes, per triangle
  std::vector<CasePolygon> polygons;            ///< coplanar triangles merged
  std::vector<std::vector<uint8_t>> loops;      ///< the loops of step 1, as edge ids
  std::array<uint8_t, 2> fold{255, 255};       ///< edges of the face diagonal folded onto, if any

  bool hasFold() const { return fold[0] != 255; }
};

/// The 256 cases, indexed by the mask of inside corners (bit c for corner c).
const std::array<Case, 256>& caseTable();

/// For the 24 cases with a fold: the variant through the centre of the same face (5 planes). A cell
/// uses it when the cell below that face folds onto the same diagonal, which would make the two
/// folds coincide (four triangles on one edge); the variant shares only an endpoint with it.
/// Other entries are empty.
const std::array<Case, 256>& alternativeCaseTable();

/// What the derivation found.
struct CaseTableStats {
  int solved = 0;                   ///< configurations (of 254 non-trivial) with a valid triangulation
  std::array<int, 5> byPlaneCount{};  ///< configurations needing 0…4 distinct planes
  int maxLoopSize = 0;
  int maxPolygonsPerCell = 0;
};
CaseTableStats caseTableStats();

}  // namespace hyb::dmc
