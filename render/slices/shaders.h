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
/// kind k ≥ 1: a surface triangle of colour k − 1 (the isosurface's, or a user mesh's) whose fragments are drawn where their depth (along forward, or the
/// distance to the eye for shells) lies in [slab.x, slab.y) (SlabPolygon: a triangle covering
/// several slabs comes once per slab). All are clipped by the cutting plane. Compiled after the
/// same #defines as kSliceFragment: llvmpipe sets up every varying of every triangle, so the face
/// normal is flat unless the surface has vertex normals (SMOOTH), and the slab goes only to the
/// SURFACE variants (bricks whose stream holds surface triangles).
inline constexpr const char* kStreamVertex = R"(
layout(location = 0) in vec3 position;
layout(location = 1) in vec3 normal;
layout(location = 2) in vec3 kindSlab;  // kind, slab near depth, slab far depth
uniform mat4 viewProj;
uniform vec4 cutPlane;  // kept where dot(cutPlane.xyz, x) + cutPlane.w >= 0
out vec3 vWorld;
#if SMOOTH
out vec3 vNormal;  // vertex normals, interpolated
#else
flat out vec3 vNormal;
#endif
flat out float vKind;
#if SURFACE
flat out vec2 vSlab;
#endif
void main() {
  vWorld = position;
  vNormal = normal;
  vKind = kindSlab.x;
#if SURFACE
  vSlab = kindSlab.yz;
#endif
#if CUT
  gl_ClipDistance[0] = dot(cutPlane.xyz, position) + cutPlane.w;
#endif
  gl_Position = viewProj * vec4(position, 1.0);
}
)";

/// What the slice and cutting-plane fragment shaders share: a brick's texture coordinates and its
/// normalised values' classification by the transfer function's lookup table. Follows the
/// #version line (and the slice shader's #defines); the shader's source follows it.
inline constexpr const char* kClassify = R"(
uniform sampler1D tfTex;
uniform float tfMin, tfScale, tfSize;
uniform vec3 fineScale, fineOffset;  // world mm -> the brick texture's coordinates
uniform float valueOffset, valueScale;  // value = valueOffset + valueScale * (2 u - 1)

// The value a brick's normalised value u stands for.
float valueOf(float u) { return valueOffset + valueScale * (2.0 * u - 1.0); }

// The lookup table's entry (nearest) for the normalised value u.
vec4 classify(float u) {
  return texelFetch(tfTex, int(clamp((valueOf(u) - tfMin) * tfScale + 0.5, 0.0, tfSize - 1.0)), 0);
}
)";

/// A brick's piece of the cutting plane (multiplanar reformat): the data's colour, opaque, from the
/// brick's values at 16 bits; transparent entries let the volume behind show. After kClassify.
inline constexpr const char* kCutFragment = R"(
in vec3 vWorld;
out vec4 fragColor;
uniform sampler3D cutTex;
void main() {
  vec4 c = classify(texture(cutTex, vWorld * fineScale + fineOffset).x);
  if (c.a <= 0.0) discard;
  fragColor = vec4(c.rgb, 1.0);
}
)";

/// One brick's slice: sample the brick texture, classify with the per-millimetre transfer
/// function, correct opacity for the segment the slice stands for, shade, premultiply. llvmpipe
/// runs both sides of every branch, uniform ones included, so each feature a frame does not use
/// is compiled out: the source follows "#version 450 core\n" and a #define of SHADING (headlight
/// shading by the brick's stored gradient), SURFACE (translucent triangles in the stream), CUT (a
/// cutting plane clips the stream), SHELLS (spherical-shell bricks may occur), VOI, ORTHO,
/// TEXEL16 (16-bit brick texels), SMOOTH (the surface's vertex normals interpolated), MESHES (user
/// meshes' triangles in the stream, coloured by their kind from a table), GEOMETRY (the number of
/// scan-converted geometry parts composited over each sample, 0 for none) and SEGMENTS
/// (each fragment's segment cut to the brick's box: bricks sliced coarser than the base spacing)
/// and PREINT (pre-integrated classification: the segment, always cut to the box, read from the
/// PreIntegrationTable at the values of its two ends), each 0 or 1.
inline constexpr const char* kSliceFragment = R"(
in vec3 vWorld;
#if SMOOTH
in vec3 vNormal;  // a surface triangle's vertex normals, interpolated
#else
flat in vec3 vNormal;  // a surface triangle's face normal
#endif
flat in float vKind;
#if SURFACE
flat in vec2 vSlab;
#endif
out vec4 fragColor;
uniform vec4 surfaceColor;  // straight rgb, alpha per crossing
#if MESHES
uniform vec4 surfaceColors[16];  // by kind − 1: the isosurface's, then each user mesh's
#endif
uniform sampler3D volumeTex;  // the brick's lattice: normalised value, gradient direction (RGBA8 or RGBA16)
uniform vec3 eye, forward;
uniform float sliceSpacing;  // mm between this brick's slice planes along forward (radii: shells)
uniform int shells;  // 1: this brick's proxies are spherical shells around the eye
uniform vec3 boxLo, boxHi;  // this brick's box, world mm (SEGMENTS)
uniform vec3 voiCentre, voiHalf, voiOffset;  // the box in its own axes; the grid origin there
uniform mat3 voiToBox;  // grid axes to the box's
uniform float voiInside, voiOutside, voiRamp;

// Levoy's volume of interest: the opacity factor, smooth across the box's surface.
float voiFactor(vec3 x) {
  vec3 q = abs(voiToBox * x + voiOffset - voiCentre) - voiHalf;
  float d = length(max(q, vec3(0.0))) + min(max(q.x, max(q.y, q.z)), 0.0);
  float t = voiRamp > 0.0 ? clamp(0.5 - d / voiRamp, 0.0, 1.0) : (d <= 0.0 ? 1.0 : 0.0);
  return mix(voiOutside, voiInside, t * t * (3.0 - 2.0 * t));
}

#if GEOMETRY
// The scan-converted geometry (render/geometry_channel.h): each part's texture (RGBA8, a crop of the
// grid: coverage, then its normal n as 128 + 127·n), its colour and its sheet's thickness τ (mm).
uniform sampler3D geomTex[GEOMETRY];
uniform vec3 geomScale[GEOMETRY], geomOffset[GEOMETRY];
uniform vec4 geomColor[GEOMETRY];
uniform float geomTau[GEOMETRY];

// compositeGeometry: the parts, each over those after it, over the data's premultiplied sample;
// with cosine = |n·dir| (1 where a part has no normal n), a part of coverage c over len mm has opacity
// 1 − (1 − a)^(c·cosine·len/τ) and its colour is shaded by the headlight, 0.25 + 0.75·cosine.
vec4 withGeometry(vec4 geom[GEOMETRY], float len, vec4 data, vec3 dir) {
  vec4 over = vec4(0.0);
  for (int k = 0; k < GEOMETRY; ++k) {
    if (geom[k].r > 0.0) {
      vec3 n = geom[k].gba - vec3(128.0 / 255.0);
      float nn = dot(n, n);
      float cosine = nn > 1e-12 ? abs(dot(n, dir)) * inversesqrt(nn) : 1.0;
      float a = 1.0 - pow(1.0 - geomColor[k].a, geom[k].r * cosine * len / geomTau[k]);
      over += vec4(geomColor[k].rgb * ((0.25 + 0.75 * cosine) * a), a) * (1.0 - over.a);
    }
  }
  return over + data * (1.0 - over.a);
}
#endif

#if PREINT
// The pre-integration table (PreIntegrationTable): colour C / α and optical depth per mm, the front
// value's bin along x, the back value's along y, layers of thickness 2^((k + preFirst) / 2) mm
// along z, read trilinearly.
uniform sampler3D preTex;
uniform float preMin, preScale, preBins, preFirst, preLayers;

// The premultiplied colour and opacity of a segment of len mm (> 0) from value vf to value vb,
// its optical depth scaled by depthScale.
vec4 preintegrated(float vf, float vb, float len, float depthScale) {
  vec2 uv = (clamp((vec2(vf, vb) - preMin) * preScale, 0.0, preBins - 1.0) + 0.5) / preBins;
  float k = clamp(2.0 * log2(len) - preFirst, 0.0, preLayers - 1.0);
  vec4 e = texture(preTex, vec3(uv, (k + 0.5) / preLayers));
  float alpha = 1.0 - exp2(-1.44269504 * len * depthScale * e.a);
  return vec4(e.rgb * alpha, alpha);
}
#endif

// The stretch [front, back] of the ray through x that this fragment stands for, in units of the
// slices' parameter (depth along forward, or radius), v being the ray's step per unit of it: half-way
// to the planes (shells) either side, and out to where the ray enters or leaves the brick for the
// first and last one in it, so that the brick integrates exactly its own stretch of every ray at
// any spacing (no seam where a neighbour's spacing differs, nothing lost or doubled at the
// volume's faces). r is the unnormalised ray, rr its squared length.
void segment(vec3 x, vec3 r, float rr, out vec3 v, out float front, out float back) {
#if ORTHO
  v = forward;
#else
  v = r / max(abs(dot(r, forward)), 1e-6 * sqrt(rr));
#if SHELLS
  if (shells == 1) v = r * inversesqrt(rr);
#endif
#endif
  vec3 inv = 1.0 / mix(v, vec3(1e-20), lessThan(abs(v), vec3(1e-20)));
  vec3 sa = (boxLo - x) * inv, sb = (boxHi - x) * inv;
  vec3 near = min(sa, sb), far = max(sa, sb);
  float enter = min(max(max(near.x, near.y), near.z), 0.0), leave = max(min(min(far.x, far.y), far.z), 0.0);
  // A neighbour's plane counts as in the brick unless its face is nearer than the plane by more
  // than a thousandth of the spacing (a plane on a face belongs to the brick behind it).
  float h = 0.5 * sliceSpacing;
  front = enter > -0.999 * sliceSpacing ? enter : -h;
  back = leave < 1.001 * sliceSpacing ? leave : h;
}

// The unit ray direction through this fragment.
vec3 rayDirection() {
#if ORTHO
  return forward;
#else
  return normalize(vWorld - eye);
#endif
}

void main() {
#if SURFACE
  if (vKind > 0.5) {  // translucent surface, headlight-shaded, premultiplied
    // This slab's part of the triangle (planes between slabs would cost llvmpipe's clipper more).
#if SHELLS
    float slabDepth = shells == 1 ? length(vWorld - eye) : dot(forward, vWorld);
#else
    float slabDepth = dot(forward, vWorld);
#endif
    if (!(slabDepth >= vSlab.x && slabDepth < vSlab.y)) discard;  // (NaN too)
    // Vertex normals on either side of a thin plate can cancel inside a triangle: unshaded there.
    float nn = dot(vNormal, vNormal);
    float shade = nn > 0.0 ? 0.25 + 0.75 * abs(dot(vNormal, rayDirection())) * inversesqrt(nn) : 1.0;
#if MESHES
    vec4 color = surfaceColors[clamp(int(vKind + 0.5) - 1, 0, 15)];
#else
    vec4 color = surfaceColor;
#endif
    fragColor = vec4(color.rgb * shade * color.a, color.a);
    return;
  }
#endif
  vec3 x = vWorld;
#if GEOMETRY
  // The parts' coverage and normal here: a sample the data leaves transparent is kept where one covers it.
  vec4 geom[GEOMETRY];
  bool covered = false;
  for (int k = 0; k < GEOMETRY; ++k) {
    geom[k] = texture(geomTex[k], x * geomScale[k] + geomOffset[k]);
    covered = covered || geom[k].r > 0.0;
  }
#define EMPTY(a) ((a) <= 0.0 && !covered)
#else
#define EMPTY(a) ((a) <= 0.0)
#endif
  // The ray r through this fragment, unnormalised, and its squared length.
#if ORTHO
  vec3 r = forward;
  float rr = 1.0;
#else
  vec3 r = vWorld - eye;
  float rr = dot(r, r);
#endif
#if PREINT
  vec3 v;
  float front, back;
  segment(x, r, rr, v, front, back);
  float len = (back - front) * length(v);
  if (!(len > 0.0)) discard;
  // The field at the segment's two ends; their gradients' mean shades it.
  vec4 texelFront = texture(volumeTex, (x + v * front) * fineScale + fineOffset);
  vec4 texelBack = texture(volumeTex, (x + v * back) * fineScale + fineOffset);
  vec4 texel = 0.5 * (texelFront + texelBack);
  float depthScale = 1.0;
#if VOI
  depthScale = voiFactor(x);
#endif
  vec4 c = preintegrated(valueOf(texelFront.x), valueOf(texelBack.x), len, depthScale);
  if (EMPTY(c.a)) discard;
  vec3 color = c.rgb;  // premultiplied
  float alpha = c.a;
#else
  // The brick's field and gradient at x (blending towards coarser bricks is baked into its texels).
  vec4 texel = texture(volumeTex, x * fineScale + fineOffset);
  vec4 c = classify(texel.x);
  if (EMPTY(c.a)) discard;
#if SEGMENTS
  vec3 v;
  float front, back;
  segment(x, r, rr, v, front, back);
  float len = (back - front) * length(v);
#else
  float len = sliceSpacing;
#if !ORTHO
#if SHELLS
  if (shells == 0)
#endif
    len *= sqrt(rr) / max(abs(dot(r, forward)), 1e-6 * sqrt(rr));
#endif
#endif
#if VOI
  c.a = min(c.a * voiFactor(x), 1.0);
  if (EMPTY(c.a)) discard;
#endif
  float alpha = c.a >= 1.0 ? 1.0 : 1.0 - pow(1.0 - c.a, len);
  vec3 color = c.rgb * alpha;
#endif
  float shade = 1.0;
#if SHADING
  {
#if TEXEL16
    vec3 g = texel.yzw - vec3(32768.0 / 65535.0);  // the middle code encodes 0
#else
    vec3 g = texel.yzw - vec3(128.0 / 255.0);
#endif
    float gg = dot(g, g);
    if (gg > 1e-12) shade = 0.25 + 0.75 * abs(dot(g, r)) * inversesqrt(gg * rr);
  }
#endif
#if GEOMETRY
  fragColor = withGeometry(geom, len, vec4(color * shade, alpha), rayDirection());
#else
  fragColor = vec4(color * shade, alpha);
#endif
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
  float nn = dot(vNormal, vNormal);  // vertex normals may cancel inside a triangle: unshaded there
  fragColor = vec4(color * (nn > 0.0 ? 0.25 + 0.75 * abs(dot(vNormal, dir)) * inversesqrt(nn) : 1.0), 1.0);
}
)";

}  // namespace hyb::shaders
