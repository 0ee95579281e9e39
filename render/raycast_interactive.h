// The ray tracer of moving frames: the reference's rays (render/raycast.h: segments of the same
// length, split at the same surface crossings, empty space skipped by the same octree nodes) in
// float arithmetic, the transfer function read from a table, one empty-space query per octree node
// entered rather than per segment, crossings found as the ray reaches them, rays stopped once
// nearly opaque and sample offsets interleaved across each 2² square of pixels. Its images are
// within a stated PSNR of the reference's at the same camera and spacing
// (tests/raycast_interactive_test.cpp), for half the time (docs/renderer.md).
#pragma once

#include <vector>

#include "render/raycast.h"

namespace hyb {

/// Whether raycastInteractive draws a frame of @p options: one without a cutting plane, volume of
/// interest, user meshes or geometry channel, pre-integration, sort-last region or refinement, of
/// the volume (not surfaces only), on a grid at least two samples along each axis. Other frames go to
/// raycast().
bool interactiveRaysServe(const Volume& volume, const RaycastOptions& options);

/// Alpha at which a moving frame's ray stops: 0.99 leaves at most 1 % of a pixel's colour out
/// where the reference (0.999) goes on; the reference's own rays on the cranium take a seventh
/// fewer samples stopping there (docs/renderer.md, Alternatives: early ray termination).
inline constexpr float kInteractiveOpaqueAlpha = 0.99f;

/// What raycastInteractive reports beside its image, each where not null: @p stats counted as
/// raycast's are; @p depth each pixel's distance (mm from the eye, rows from the top) at which its
/// opacity reaches ½, infinity where it never does (where a reprojection would move it).
struct InteractiveOutputs {
  RaycastStats* stats = nullptr;
  std::vector<float>* depth = nullptr;
};

/// Renders what raycast() renders for @p options (which interactiveRaysServe must accept), on all
/// cores: the transfer function read at the nearest of LutLayout's 4096 entries, the segments'
/// opacity corrected by a table for their common length (exactly for shorter ones), the shading
/// gradient Levoy's as in raycast(), rays stopped at kInteractiveOpaqueAlpha.
Image raycastInteractive(const Volume& volume, const VolumeOctree& octree, const TransferFunction& tf, const Camera& camera,
                         const RaycastOptions& options, InteractiveOutputs out = {});

}  // namespace hyb
