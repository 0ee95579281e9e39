// GLSL sources of the slice renderer, as raw strings.
#pragma once

namespace hyb::shaders {

/// Slices and surfaces: world-space positions in, transformed by viewProj.
inline constexpr const char* kWorldVertex = R"(#version 450 core
layout(location = 0) in vec3 position;
layout(location = 1) in vec3 normal;
uniform mat4 viewProj;
uniform vec4 cutPlane;  // kept where dot(cutPlane.xyz, x) + cutPlane.w >= 0
out vec3 vWorld;
out vec3 vNormal;
void main() {
  vWorld = position;
  vNormal = normal;
  gl_ClipDistance[0] = dot(cutPlane.xyz, position) + cutPlane.w;
  gl_Position = viewProj * vec4(position, 1.0);
}
)";

/// One brick's stream of slices and translucent surface triangles in draw order. kind 0: a slice;
/// kind 1: a surface triangle clipped to its slab [slab.x, slab.y] of view depth (SlabPolygon);
/// kind 2: the brick's piece of the cutting plane. All but the plane are clipped by it.
inline constexpr const char* kStreamVertex = R"(#version 450 core
layout(location = 0) in vec3 position;
layout(location = 1) in vec3 normal;
layout(location = 2) in vec3 kindSlab;  // kind, slab near depth, slab far depth
uniform mat4 viewProj;
uniform vec3 forward;
uniform vec4 cutPlane;  // kept where dot(cutPlane.xyz, x) + cutPlane.w >= 0
uniform int shells;     // 1: slabs are spherical shells around the eye, clipped per fragment
out vec3 vWorld;
out vec3 vNormal;
flat out float vKind;
flat out vec2 vSlab;
void main() {
  vWorld = position;
  vNormal = normal;
  vKind = kindSlab.x;
  vSlab = kindSlab.yz;
  float depth = dot(forward, position);
  gl_ClipDistance[0] = shells == 1 ? 1.0 : depth - kindSlab.y;
  gl_ClipDistance[1] = shells == 1 ? 1.0 : kindSlab.z - depth;
  gl_ClipDistance[2] = kindSlab.x > 1.5 ? 1.0 : dot(cutPlane.xyz, position) + cutPlane.w;
  gl_Position = viewProj * vec4(position, 1.0);
}
)";

/// One brick's slice: sample the brick texture, classify with the per-millimetre transfer
/// function, correct opacity for the segment the slice stands for, shade, premultiply. Compiled
/// after "#version 450 core\n#define SHADING 0|1\n": llvmpipe runs both sides of a uniform branch,
/// so an unshaded frame gets a program without the six gradient fetches.
inline constexpr const char* kSliceFragment = R"(
in vec3 vWorld;
in vec3 vNormal;
flat in float vKind;
flat in vec2 vSlab;
out vec4 fragColor;
uniform vec4 surfaceColor;  // straight rgb, alpha per crossing
uniform sampler3D volumeTex;  // the brick's lattice
uniform sampler1D tfTex;
uniform vec3 fineScale, fineOffset;  // world mm -> the brick texture's coordinates
uniform vec3 gradientStep;           // half a texel, mm
uniform float tfMin, tfScale, tfSize;
uniform vec3 eye, forward;
uniform int ortho;
uniform float sliceSpacing;  // mm between this brick's slice planes along forward
uniform int shells;  // 1: the proxies are spherical shells around the eye
uniform int voi;  // 1: scale opacity by the volume of interest
uniform vec3 voiCentre, voiHalf;
uniform float voiInside, voiOutside, voiRamp;

// Levoy's volume of interest: the opacity factor, smooth across the box's surface.
float voiFactor(vec3 x) {
  vec3 q = abs(x - voiCentre) - voiHalf;
  float d = length(max(q, vec3(0.0))) + min(max(q.x, max(q.y, q.z)), 0.0);
  float t = voiRamp > 0.0 ? clamp(0.5 - d / voiRamp, 0.0, 1.0) : (d <= 0.0 ? 1.0 : 0.0);
  return mix(voiOutside, voiInside, t * t * (3.0 - 2.0 * t));
}

// The brick's field at world position x (blending towards coarser bricks is baked into its texels).
float sampleAt(vec3 x) { return texture(volumeTex, x * fineScale + fineOffset).r; }

void main() {
  if (vKind > 0.5 && vKind < 1.5) {  // translucent surface, headlight-shaded, premultiplied
    if (shells == 1) {  // the slab between two shells: a sphere cannot be a clip plane
      float r = length(vWorld - eye);
      if (r < vSlab.x || r >= vSlab.y) discard;
    }
    vec3 d = ortho == 1 ? forward : normalize(vWorld - eye);
    float shade = 0.25 + 0.75 * abs(dot(normalize(vNormal), d));
    fragColor = vec4(surfaceColor.rgb * shade * surfaceColor.a, surfaceColor.a);
    return;
  }
  vec3 x = vWorld;
  float v = sampleAt(x);
  vec4 c = texture(tfTex, ((v - tfMin) * tfScale + 0.5) / tfSize);
  if (c.a <= 0.0) discard;
  if (vKind > 1.5) {  // the cutting plane: the data's colour, opaque
    fragColor = vec4(c.rgb, 1.0);
    return;
  }
  vec3 dir = ortho == 1 ? forward : normalize(vWorld - eye);
  float len = shells == 1 ? sliceSpacing : sliceSpacing / max(abs(dot(dir, forward)), 1e-6);
  if (voi == 1) {
    c.a = min(c.a * voiFactor(x), 1.0);
    if (c.a <= 0.0) discard;
  }
  float alpha = c.a >= 1.0 ? 1.0 : 1.0 - pow(1.0 - c.a, len);
  float shade = 1.0;
#if SHADING
  {
    vec3 h = gradientStep;
    vec3 g = vec3(sampleAt(x + vec3(h.x, 0, 0)) - sampleAt(x - vec3(h.x, 0, 0)),
                  sampleAt(x + vec3(0, h.y, 0)) - sampleAt(x - vec3(0, h.y, 0)),
                  sampleAt(x + vec3(0, 0, h.z)) - sampleAt(x - vec3(0, 0, h.z))) / (2.0 * h);
    float m = length(g);
    if (m > 1e-6) shade = 0.25 + 0.75 * abs(dot(g / m, dir));
  }
#endif
  fragColor = vec4(c.rgb * shade * alpha, alpha);
}
)";

/// Opaque surface: headlight shading, alpha 1.
inline constexpr const char* kSurfaceFragment = R"(#version 450 core
in vec3 vWorld;
in vec3 vNormal;
out vec4 fragColor;
uniform vec3 eye, forward;
uniform int ortho;
uniform vec3 color;
void main() {
  vec3 dir = ortho == 1 ? forward : normalize(vWorld - eye);
  fragColor = vec4(color * (0.25 + 0.75 * abs(dot(normalize(vNormal), dir))), 1.0);
}
)";

}  // namespace hyb::shaders
