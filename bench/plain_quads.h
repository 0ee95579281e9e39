// The fragment-throughput baseline of hyb_bench: plain full-screen quads sampling a 3D texture.
#pragma once

#include <cstdint>

#include "volume/volume.h"

namespace hyb::bench {

/// Seconds llvmpipe takes to blend @p quads full-screen quads that sample a 3D texture of @p volume
/// into a float framebuffer of @p width x @p height, and the fragments it shaded. The texture is
/// R32F, or with @p brickFormat the bricks' default RGBA8 (value and gradient), to tell the cost of
/// the format from that of the shader. Requires a current GlContext.
double plainQuadSeconds(const Volume& volume, int width, int height, int quads, uint64_t* fragments, bool brickFormat = false);

}  // namespace hyb::bench
