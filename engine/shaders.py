"""GLSL of the raster half: G-buffer, shadow maps, deferred lighting, resolve and composite.

Every shader is built from a ``GPUShaderCreateInfo`` (Blender 5.0 removed the
source-string constructor) and created once per process by
``engine/gpu_resources.py``.

The lighting and composite shaders implement the surface response of
``phrt_addon/scene/shading.py`` (Lambert + GGX/Smith/Schlick, the uniform-environment
ambient and exact dielectric Fresnel) and the shadow-map lookup of
``phrt_addon/raster/shadowmap.py`` line for line, so the GPU image of a G-buffer equals
the numpy reference (``phrt_addon/raster/reference_raster.py``); ``tests/integration/
test_gpu_frame.py`` checks the two agree within 1e-3 relative on lit pixels.

G-buffer layout (one texture set per layer, opaque and transparent):
- ``position``  RGBA32F: camera-relative position (float32 keeps precision at any
  world coordinate), w = material index + 1 (0 = nothing drawn);
- ``normal``    RGBA32F: shading normal (front-facing), w = roughness;
- ``albedo``    RGBA8:   sqrt of the base colour with its texture applied (8 bits are
  enough for shading inputs once the darks get more codes), a = metallic;
- ``element``   R32UI:   element index + 1 (0 = not part of an element), 32 bits.
"""
from __future__ import annotations

import re

from ..phrt_addon.scene import rules

# Materials are stored in a float texture, MATERIAL_TABLE_WIDTH per row pair:
# row 2k: (transmission, ior, alpha, 0); row 2k+1: (emission rgb, 0).
MATERIAL_TABLE_WIDTH = 1024
# Cube-map shadow atlases hold the six faces in a 3 x 2 grid of tiles.
ATLAS_COLUMNS = 3
# Lights added by one lighting pass (each brings a shadow map and a traced-visibility sampler:
# 3 G-buffer + 1 material + 2 x 6 = the 16 samplers every GL implementation has).  More per pass
# reads the G-buffer and blends fewer times (arcade, 5 lights in 2 passes of 4+1 -> 1 of 5:
# 65 -> 56 CPU-ms on llvmpipe).
LIGHTS_PER_PASS = 6
LIGHT_KIND_CODES = {"SUN": 0, "POINT": 1, "SPOT": 2, "AREA": 3}

GBUFFER_VERT = """
void main() {
  vec4 world = model * vec4(pos, 1.0);
  v_position = world.xyz;
  v_normal = transpose(inverse(mat3(model))) * nor;
  v_uv = uv;
  gl_Position = frame.view_proj * world;
}
"""

GBUFFER_FRAG = rules.GLSL_SAMPLE_TEXTURE + """
void main() {
  vec3 n = normalize(v_normal);
  if (!gl_FrontFacing) { n = -n; }
  vec4 albedo = base_color;
  /* Sampled exactly as the tracer samples (rules.sample_texture: bilinear, wrapping).  A
     variant per case, not a branch: llvmpipe runs a branch's body for every fragment, and the
     sampling was 15% of arcade's G-buffer pass where most materials have no texture. */
#if WITH_TEXTURE
  albedo *= phrt_sample_texture(base_tex, v_uv);
#endif
  albedo = clamp(albedo, 0.0, 1.0);
  out_position = vec4(v_position, float(ids.x + 1));
  out_normal = vec4(n, params.x);
  /* 8 bits per channel of sqrt(albedo): a game G-buffer's precision, where it matters (darks). */
  out_albedo = vec4(sqrt(albedo.rgb), clamp(params.y, 0.0, 1.0));
  out_element = uint(ids.y + 1);
}
"""

SHADOW_VERT = """
void main() {
  vec4 world = model * vec4(pos, 1.0);
  v_axis_depth = -dot(world.xyz, frame.axis.xyz);
  gl_Position = frame.view_proj * world;
}
"""

SHADOW_FRAG = """
void main() {
  out_depth = v_axis_depth;
}
"""

FULLSCREEN_VERT = """
void main() {
  gl_Position = vec4(pos, 0.0, 1.0);
}
"""

# Functions shared by the lighting and composite passes: shading.py in GLSL.
COMMON_LIB = """
#define PHRT_INV_PI 0.3183098861837907
#define PHRT_MIN_ROUGHNESS 0.04
#define PHRT_LUMINANCE vec3(0.2126, 0.7152, 0.0722)

struct Surface {
  bool covered;
  vec3 position;
  vec3 normal;
  vec3 view;
  vec3 albedo;
  float metallic;
  float roughness;
  float transmission;
  float ior;
  float alpha_blend;
  vec3 emission;
  vec3 f0;
  float diffuse_weight;
  vec3 diffuse_color;
  float alpha;
  float n_dot_v;
};

vec4 material_row(int index, int row) {
  ivec2 texel = ivec2(index % MATERIAL_TABLE_WIDTH, (index / MATERIAL_TABLE_WIDTH) * 2 + row);
  return texelFetch(material_table, texel, 0);
}

float f0_dielectric(float ior) {
  float r = (ior - 1.0) / (ior + 1.0);
  return r * r;
}

Surface read_surface(vec4 position_material, vec4 normal_roughness, vec4 albedo_metallic) {
  Surface s;
  s.covered = position_material.w > 0.5;
  s.position = position_material.xyz;
  vec3 view_dir = camera.forward_ortho.w > 0.5 ? camera.forward_ortho.xyz
                                               : s.position / max(length(s.position), 1e-30);
  vec3 n = normal_roughness.xyz / max(length(normal_roughness.xyz), 1e-30);
  /* A normal facing away from the viewer (interpolation at silhouettes) is flipped. */
  if (dot(n, view_dir) > 0.0) { n = -n; }
  s.normal = n;
  s.view = -view_dir;
  s.albedo = albedo_metallic.rgb * albedo_metallic.rgb;  /* stored as sqrt in 8 bits */
  s.metallic = albedo_metallic.a;
  s.roughness = normal_roughness.w;
  int material = max(int(position_material.w + 0.5) - 1, 0);
  vec4 optical = material_row(material, 0);
  s.transmission = optical.x;
  s.ior = optical.y;
  s.alpha_blend = optical.z;
  s.emission = material_row(material, 1).rgb;
  s.f0 = mix(vec3(f0_dielectric(s.ior)), s.albedo, s.metallic);
  s.diffuse_weight = (1.0 - s.metallic) * (1.0 - s.transmission);
  s.diffuse_color = s.albedo * (s.diffuse_weight * PHRT_INV_PI);
  float r = max(s.roughness, PHRT_MIN_ROUGHNESS);
  s.alpha = r * r;
  s.n_dot_v = clamp(dot(s.normal, s.view), 1e-4, 1.0);
  return s;
}

/* Reflectance at grazing incidence: 1, fading to 0 for a surface with almost no specular
   reflection (F0 below 2%: an IOR-1 surface reflects nothing, not a bright rim). */
float specular_f90(vec3 f0) {
  return clamp(50.0 * (f0.r + f0.g + f0.b) / 3.0, 0.0, 1.0);
}

vec3 fresnel_schlick(vec3 f0, float cos_theta) {
  float m = 1.0 - clamp(cos_theta, 0.0, 1.0);
  return f0 + (specular_f90(f0) - f0) * (m * m * m * m * m);
}

float fresnel_dielectric(float cos_incident, float eta) {
  float cos_i = clamp(abs(cos_incident), 0.0, 1.0);
  float sin2_t = (1.0 - cos_i * cos_i) / (eta * eta);
  if (sin2_t > 1.0) { return 1.0; }
  if (abs(eta - 1.0) < 1e-12) { return 0.0; }  /* no interface: nothing is reflected */
  float cos_t = sqrt(clamp(1.0 - sin2_t, 0.0, 1.0));
  float rs = (cos_i - eta * cos_t) / max(cos_i + eta * cos_t, 1e-30);
  float rp = (eta * cos_i - cos_t) / max(eta * cos_i + cos_t, 1e-30);
  return 0.5 * (rs * rs + rp * rp);
}

vec3 brdf_cosine(Surface s, vec3 l) {
  float cosine = dot(s.normal, l);
  float n_dot_l = clamp(cosine, 0.0, 1.0);
  vec3 h = s.view + l;
  h /= max(length(h), 1e-12);
  float n_dot_h = clamp(dot(s.normal, h), 0.0, 1.0);
  float v_dot_h = clamp(dot(s.view, h), 0.0, 1.0);
  float a2 = s.alpha * s.alpha;
  float denom = n_dot_h * n_dot_h * (a2 - 1.0) + 1.0;
  float k = s.alpha * 0.5;
  float specular = a2 / max(3.14159265358979 * denom * denom, 1e-30)
                   / max(n_dot_l * (1.0 - k) + k, 1e-30) / (s.n_dot_v * (1.0 - k) + k) * 0.25;
  vec3 f = fresnel_schlick(s.f0, v_dot_h);
  /* Below the horizon (or not a number): no light, chosen without a branch. */
  return cosine > 0.0 ? (s.diffuse_color * (1.0 - f) + f * specular) * n_dot_l : vec3(0.0);
}

/* The layer's colour: emission, the accumulated lights, ambient diffuse and the reflection
   (the uniform environment, or the traced radiance where a ray was traced). */
vec3 shade_layer(Surface s, vec3 light_sum, vec4 traced_reflection, out float transmissive, out float fresnel_t) {
  vec3 world = camera.world.rgb;
  float m = 1.0 - clamp(s.n_dot_v, 0.0, 1.0);
  float ceiling = min(max(1.0 - s.roughness, max(s.f0.r, max(s.f0.g, s.f0.b))), specular_f90(s.f0));
  vec3 env_fresnel = s.f0 + (max(vec3(ceiling), s.f0) - s.f0) * (m * m * m * m * m);
  vec3 color = s.emission + light_sum + s.albedo * s.diffuse_weight * (1.0 - env_fresnel) * world;
  transmissive = s.transmission * (1.0 - s.metallic);
  fresnel_t = fresnel_dielectric(clamp(dot(s.normal, s.view), 0.0, 1.0), s.ior);
  vec3 reflect_weight = env_fresnel * (1.0 - transmissive) + transmissive * fresnel_t;
  vec3 reflected = traced_reflection.a > 0.5 ? traced_reflection.rgb : world;
  return color + reflect_weight * reflected;
}

vec3 finite_radiance(vec3 c) {
  bvec3 bad = isnan(c);
  c = vec3(bad.x ? 0.0 : c.x, bad.y ? 0.0 : c.y, bad.z ? 0.0 : c.z);
  return clamp(c, 0.0, 1e6);
}
"""

LIGHTING_FRAG = """
/* llvmpipe runs both sides of every branch for every pixel, with mask bookkeeping on top:
   the per-pixel code below chooses with selects rather than branches and early returns. */
/* A point relative to a cube map's centre in the view of the face that sees it: (right, up,
   forward) coordinates, the face's view being a signed permutation of the axes
   (shadowmap.cube_face_view, tested against the faces' matrices): selects, no indexing.
   ``tile``: that face's (column, row) in the atlas (faces +x -x +y -y +z -z in order). */
vec3 cube_face_view(vec3 p, out vec2 tile) {
  vec3 a = abs(p);
  bool x_major = a.x >= a.y && a.x >= a.z;
  bool y_major = !x_major && a.y >= a.z;
  float along = x_major ? p.x : (y_major ? p.y : p.z);
  bool negative = along < 0.0;
  float s = negative ? -1.0 : 1.0;
  float face = (x_major ? 0.0 : (y_major ? 2.0 : 4.0)) + (negative ? 1.0 : 0.0);
  float columns = float(ATLAS_COLUMNS);
  tile = vec2(face - columns * floor(face / columns), floor(face / columns));
  return x_major ? vec3(-s * p.y, p.z, s * p.x) : (y_major ? vec3(s * p.x, p.z, s * p.y) : vec3(-s * p.x, p.y, s * p.z));
}

/* Lit fraction of a camera-relative point: shadowmap.py's lookup (normal offset, 2x2 PCF
   on linear light-space depth, one gather).  ``cube`` (a constant of the variant): a cube
   map, whose face is chosen from the offset point.  Only view 0's matrix is read (a uniform
   index): llvmpipe fetches a matrix indexed by a per-pixel face lane by lane. */
float shadow_lit(int i, bool cube, sampler2D shadow_map, vec3 position, vec3 normal) {
  int faces = int(lights.light[i].shadow_offset.w + 0.5);
  mat4 view0 = lights.light[i].face_view_proj[0];
  vec3 axis0 = lights.light[i].face_axis[0].xyz;
  vec3 rel = position + lights.light[i].shadow_offset.xyz;
  float texel_angle = lights.light[i].shadow_params.x;
  float near = lights.light[i].shadow_params.y;
  bool ortho = lights.light[i].shadow_params.z > 0.5;
  int size = int(lights.light[i].shadow_params.w + 0.5);
  /* Depth along the view axis: a cube face's axis is the point's major axis. */
  vec3 a = abs(rel);
  float axis_depth = cube ? max(a.x, max(a.y, a.z)) : -dot(rel, axis0);
  float texel = ortho ? texel_angle : texel_angle * max(axis_depth, near);
  vec3 p = rel + normal * (NORMAL_OFFSET_TEXELS * texel);
  /* A cube face's clip coordinates from view 0's projection terms (every face has the same). */
  vec2 face_tile;
  vec3 face_view = cube_face_view(p, face_tile);
  vec4 clip = cube ? vec4(-view0[1][0] * face_view.x, view0[2][1] * face_view.y,
                          view0[0][2] * face_view.z + view0[3][2], face_view.z)
                   : view0 * vec4(p, 1.0);
  bool in_front = clip.w > 1e-12;
  vec3 ndc = clip.xyz / (in_front ? clip.w : 1.0);
  /* No map, behind the view or outside it: lit. */
  bool inside = faces != 0 && in_front && !(abs(ndc.x) > 1.0 || abs(ndc.y) > 1.0 || ndc.z > 1.0);
  float threshold = (cube ? face_view.z : -dot(p, axis0)) - DEPTH_BIAS_TEXELS * texel;
  vec2 uv = (ndc.xy * 0.5 + 0.5) * float(size) - 0.5;
  vec2 origin = floor(uv);
  vec2 f = uv - origin;
  /* Taps outside the view repeat its edge texel (as shadowmap.py clamps each tap). */
  f = mix(f, vec2(0.0), lessThan(origin, vec2(0.0)));
  f = mix(f, vec2(1.0), greaterThan(origin, vec2(float(size - 2))));
  origin = clamp(origin, vec2(0.0), vec2(float(size - 2)));
  vec2 tile = cube ? face_tile * float(size) : vec2(0.0);
  /* One gather at the corner shared by the 2x2 texels: w = (x0, y0), z = (x1, y0),
     x = (x0, y1), y = (x1, y1). */
  vec4 depth = textureGather(shadow_map, (tile + origin + 1.0) / vec2(textureSize(shadow_map, 0)), 0);
  vec4 lit = vec4(greaterThanEqual(depth, vec4(threshold)));
  return inside ? mix(mix(lit.w, lit.z, f.x), mix(lit.x, lit.y, f.x), f.y) : 1.0;
}

/* shading.light_incidence: direction to the light and irradiance before shadows and cosine. */
vec3 incidence(int i, int kind, vec3 position, out vec3 direction) {
  vec3 color = lights.light[i].color_kind.rgb;
  vec3 axis = lights.light[i].direction.xyz;
  vec3 to_light = lights.light[i].position_radius.xyz - position;
  float dist = length(to_light);
  vec3 towards = to_light / max(dist, 1e-6);
  float cos_angle = -dot(towards, axis);
  /* area: cosine-weighted panel; point: isotropic; spot: isotropic with the cone's smoothstep */
  float spot = clamp((cos_angle - lights.light[i].spot.x) / max(lights.light[i].spot.y - lights.light[i].spot.x, 1e-6),
                     0.0, 1.0);
  float intensity = kind == 3 ? clamp(cos_angle, 0.0, 1.0) * PHRT_INV_PI
                              : 0.25 * PHRT_INV_PI * (kind == 2 ? spot * spot * (3.0 - 2.0 * spot) : 1.0);
  float radius = lights.light[i].position_radius.w;
  bool sun = kind == 0;
  direction = sun ? -axis : towards;
  return sun ? color : color * (intensity / (dist * dist + radius * radius));
}

/* One light at one layer's surface; with ``measure_change`` where the tracer replaced the
   shadow map, ``change`` gains the luminance of what that changed (the error-aware relevance). */
vec3 light_layer(int i, int kind, int map, sampler2D shadow_map, Surface s, float traced_visibility,
                 inout float change) {
  vec3 direction;
  vec3 irradiance = incidence(i, kind, s.position, direction);
  vec3 unshadowed = brdf_cosine(s, direction) * irradiance;
  /* The shadow map's lit fraction (1 for a light without one), or the tracer's where it ran. */
  float mapped = map == 0 ? 1.0 : shadow_lit(i, map == 2, shadow_map, s.position, s.normal);
  bool traced = lights.light[i].spot.z > 0.5 && traced_visibility >= 0.0;
  change += measure_change != 0 && traced
            ? min(dot(abs(unshadowed * (traced_visibility - mapped)), PHRT_LUMINANCE), 1.0) : 0.0;
  return unshadowed * (traced ? traced_visibility : mapped);
}

/* One layer and up to LIGHTS_PER_PASS lights per pass (a variant per count: llvmpipe runs
   every branch for every pixel, so a light slot that is not used must not be compiled).
   The transparent layer's passes are drawn only where it covers the pixel (depth-tested
   against the mask the resolve pass writes), so a frame pays for glass only where there is
   glass.  PHRT_ADD_LIGHTS becomes one light_layer() call per light (build_lighting). */
void main() {
  ivec2 pixel = ivec2(gl_FragCoord.xy);
  float change = 0.0;
  Surface s = read_surface(texelFetch(layer_position, pixel, 0), texelFetch(layer_normal, pixel, 0),
                           texelFetch(layer_albedo, pixel, 0));
  vec3 total = vec3(0.0);
  /* traced_lights, bit i: the tracer's lit fractions of light i on this layer were uploaded. */
PHRT_ADD_LIGHTS
  /* A pixel the layer does not cover gets nothing (selected, not branched: see shadow_lit). */
  out_light = vec4(s.covered ? total : vec3(0.0), 0.0);
  out_change = vec4(0.0, s.covered ? change : 0.0, 0.0, 0.0);
#if WITH_COMPOSITE
  /* The opaque layer's composite in the same pass (COMPOSITE_FRAG's composite_pixel without
     the transparent layer, which its own masked pass draws over it). */
  float transmissive;
  float fresnel_t;
  vec4 traced = camera.traced.x > 0.5 ? texelFetch(opaque_reflection, pixel, 0) : vec4(0.0);
  vec3 image = finite_radiance(s.covered ? shade_layer(s, total, traced, transmissive, fresnel_t) : camera.world.rgb);
  out_combined = vec4(image, 1.0);
  /* What the traced reflection changed (x) and the traced shadows (y), as the composite writes it. */
  vec3 raster = finite_radiance(s.covered ? shade_layer(s, total, vec4(0.0), transmissive, fresnel_t)
                                          : camera.world.rgb);
  out_traced_change = vec4(min(dot(abs(image - raster), PHRT_LUMINANCE), 1.0), min(out_change.y, 1.0), 0.0, 0.0);
#endif
}
"""

RESOLVE_FRAG = """
void main() {
  ivec2 pixel = ivec2(gl_FragCoord.xy);
  vec4 opaque = texelFetch(opaque_position, pixel, 0);
  vec4 transparent = texelFetch(transparent_position, pixel, 0);
  bool front_transparent = transparent.w > 0.5;
  vec4 front = front_transparent ? transparent : opaque;
  vec3 normal = front_transparent ? texelFetch(transparent_normal, pixel, 0).xyz
                                  : texelFetch(opaque_normal, pixel, 0).xyz;
  float depth = front.w > 0.5 ? dot(front.xyz, camera.forward_ortho.xyz) : 1e10;
  out_normal_depth = vec4(front.w > 0.5 ? normal : vec3(0.0), depth);
  out_element = front_transparent ? texelFetch(transparent_element, pixel, 0).r
                                  : texelFetch(opaque_element, pixel, 0).r;
  /* The transparent layer's mask for the lighting passes: near where it covers the pixel. */
  gl_FragDepth = front_transparent ? 0.0 : 1.0;
}
"""

COMPOSITE_FRAG = """
/* The pixel's colour with the traced terms (``use_traced``) or the raster ones.  The variant
   WITH_TRANSPARENT 0 shades the opaque layer only: it is drawn over the whole frame, and the
   full variant then only where the transparent layer covers the pixel (depth-tested against
   its mask; llvmpipe runs a branch's code for every pixel, so the glass is compiled out). */
vec3 composite_pixel(ivec2 pixel, Surface opaque, Surface transparent, bool use_traced) {
  /* Every term is computed and the covered ones chosen by selects (see shadow_lit). */
  vec4 no_trace = vec4(0.0);
  float transmissive;
  float fresnel_t;
  vec4 traced = use_traced && camera.traced.x > 0.5 ? texelFetch(opaque_reflection, pixel, 0) : no_trace;
  vec3 opaque_color = shade_layer(opaque, texelFetch(opaque_light, pixel, 0).rgb, traced, transmissive, fresnel_t);
  vec3 image = opaque.covered ? opaque_color : camera.world.rgb;
#if WITH_TRANSPARENT
  traced = use_traced && camera.traced.y > 0.5 ? texelFetch(transparent_reflection, pixel, 0) : no_trace;
  vec3 surface_color = shade_layer(transparent, texelFetch(transparent_light, pixel, 0).rgb, traced,
                                   transmissive, fresnel_t);
  /* The transmitted part: straight through in raster, the refracted radiance where traced;
     the 1 - alpha part goes straight on (as the tracer's alpha pass-through does). */
  vec4 traced_refraction = texelFetch(refraction, pixel, 0);
  vec3 refracted = use_traced && camera.traced.z > 0.5 && traced_refraction.a > 0.5 ? traced_refraction.rgb : image;
  vec3 transmitted = (transmissive * (1.0 - fresnel_t)) * transparent.albedo * refracted;
  float alpha = transparent.alpha_blend;
  image = transparent.covered ? alpha * (surface_color + transmitted) + (1.0 - alpha) * image : image;
#endif
  return finite_radiance(image);
}

void main() {
  ivec2 pixel = ivec2(gl_FragCoord.xy);
  Surface opaque = read_surface(texelFetch(opaque_position, pixel, 0), texelFetch(opaque_normal, pixel, 0),
                                texelFetch(opaque_albedo, pixel, 0));
  Surface transparent;
#if WITH_TRANSPARENT
  transparent = read_surface(texelFetch(transparent_position, pixel, 0), texelFetch(transparent_normal, pixel, 0),
                             texelFetch(transparent_albedo, pixel, 0));
#endif
  vec3 image = composite_pixel(pixel, opaque, transparent, true);
  out_combined = vec4(image, 1.0);
  out_change = vec4(0.0);
  if (measure_change != 0) {
    /* What the traced reflections and refractions changed (x) and the traced shadows (y). */
    vec3 raster = composite_pixel(pixel, opaque, transparent, false);
    out_change = vec4(min(dot(abs(image - raster), PHRT_LUMINANCE), 1.0),
                      min(texelFetch(shadow_change, pixel, 0).y, 1.0), 0.0, 0.0);
  }
}
"""

CAMERA_STRUCT = """
struct CameraData {
  vec4 forward_ortho;  /* camera axis, w = 1 for orthographic */
  vec4 world;          /* uniform environment colour */
  vec4 traced;         /* x: opaque reflections, y: transparent reflections, z: refractions uploaded */
};
"""

FRAME_STRUCT = "struct FrameData { mat4 view_proj; vec4 axis; };"

LIGHT_STRUCT = """
struct LightData {
  mat4 face_view_proj[6];  /* shadow views, acting on positions relative to the view origin */
  vec4 face_axis[6];       /* each view's +Z axis: light-space depth = -dot(p, axis) */
  vec4 color_kind;         /* linear colour * strength, kind code */
  vec4 position_radius;    /* camera-relative position, soft radius (>= 1e-3) */
  vec4 direction;          /* unit direction the light travels */
  vec4 spot;               /* cos outer, cos inner, casts shadows, unused */
  vec4 shadow_offset;      /* camera position - view origin, number of views (0: no map) */
  vec4 shadow_params;      /* texel angle, near, orthographic, view size in texels */
};
struct LightSet {
  LightData light[LIGHTS_PER_PASS];
};
"""


def _defines(info, normal_offset_texels, depth_bias_texels):
    info.define("MATERIAL_TABLE_WIDTH", str(MATERIAL_TABLE_WIDTH))
    info.define("ATLAS_COLUMNS", str(ATLAS_COLUMNS))
    info.define("NORMAL_OFFSET_TEXELS", repr(float(normal_offset_texels)))
    info.define("DEPTH_BIAS_TEXELS", repr(float(depth_bias_texels)))


def _layer_samplers(info, first_slot, with_albedo=True, with_element=False, layers=("opaque", "transparent")):
    slot = first_slot
    for layer in layers:
        info.sampler(slot, "FLOAT_2D", f"{layer}_position")
        info.sampler(slot + 1, "FLOAT_2D", f"{layer}_normal")
        slot += 2
        if with_albedo:
            info.sampler(slot, "FLOAT_2D", f"{layer}_albedo")
            slot += 1
        if with_element:
            info.sampler(slot, "UINT_2D", f"{layer}_element")
            slot += 1
    return slot


def build_gbuffer(gpu, textured=True):
    """The G-buffer pass; ``textured``: the base colour is multiplied by ``base_tex`` (the
    variant for materials with an image; the other reads no texture)."""
    info = gpu.types.GPUShaderCreateInfo()
    info.define("WITH_TEXTURE", "1" if textured else "0")
    info.typedef_source(FRAME_STRUCT)
    info.uniform_buf(0, "FrameData", "frame")
    info.push_constant("MAT4", "model")
    info.push_constant("VEC4", "base_color")
    info.push_constant("VEC4", "params")  # roughness, metallic, has_texture, unused
    info.push_constant("IVEC2", "ids")  # material index, element index (-1: none)
    if textured:
        info.sampler(0, "FLOAT_2D", "base_tex")
    interface = gpu.types.GPUStageInterfaceInfo("phrt_gbuffer_iface")
    interface.smooth("VEC3", "v_position")
    interface.smooth("VEC3", "v_normal")
    interface.smooth("VEC2", "v_uv")
    info.vertex_in(0, "VEC3", "pos")
    info.vertex_in(1, "VEC3", "nor")
    info.vertex_in(2, "VEC2", "uv")
    info.vertex_out(interface)
    info.fragment_out(0, "VEC4", "out_position")
    info.fragment_out(1, "VEC4", "out_normal")
    info.fragment_out(2, "VEC4", "out_albedo")
    info.fragment_out(3, "UINT", "out_element")
    info.vertex_source(GBUFFER_VERT)
    info.fragment_source(GBUFFER_FRAG)
    return gpu.shader.create_from_info(info)


def build_shadow(gpu):
    info = gpu.types.GPUShaderCreateInfo()
    info.typedef_source(FRAME_STRUCT)
    info.uniform_buf(0, "FrameData", "frame")
    info.push_constant("MAT4", "model")
    interface = gpu.types.GPUStageInterfaceInfo("phrt_shadow_iface")
    interface.smooth("FLOAT", "v_axis_depth")
    info.vertex_in(0, "VEC3", "pos")
    info.vertex_out(interface)
    info.fragment_out(0, "FLOAT", "out_depth")
    info.vertex_source(SHADOW_VERT)
    info.fragment_source(SHADOW_FRAG)
    return gpu.shader.create_from_info(info)


def _fullscreen_pass(gpu, typedefs, samplers, outputs, fragment_source, *, uniform_blocks=(("CameraData", "camera"),),
                     layers=None, defines=None, measure_change=False, depth_write=None, extra_defines=None):
    """A shader drawn over the whole frame (``FULLSCREEN_VERT``) that reads the G-buffer layers:
    ``layers`` are ``_layer_samplers`` keywords, ``samplers`` the FLOAT_2D samplers after them,
    ``outputs`` (type, name) per colour target, ``defines`` (normal offset, depth bias) for
    ``_defines``."""
    info = gpu.types.GPUShaderCreateInfo()
    info.typedef_source(typedefs)
    for slot, (type_name, name) in enumerate(uniform_blocks):
        info.uniform_buf(slot, type_name, name)
    slot = _layer_samplers(info, 0, **(layers or {}))
    for offset, name in enumerate(samplers):
        info.sampler(slot + offset, "FLOAT_2D", name)
    if defines is not None:
        _defines(info, *defines)
    for name, value in (extra_defines or {}).items():
        info.define(name, value)
    if measure_change:
        info.push_constant("INT", "measure_change")
    if depth_write is not None:
        info.depth_write(depth_write)
    info.vertex_in(0, "VEC2", "pos")
    for index, (type_name, name) in enumerate(outputs):
        info.fragment_out(index, type_name, name)
    info.vertex_source(FULLSCREEN_VERT)
    info.fragment_source(fragment_source)
    return gpu.shader.create_from_info(info)


def lighting_samplers(light_count: int, with_composite: bool = False) -> int:
    """Samplers a lighting variant binds (see build_lighting)."""
    return 4 + 2 * int(light_count) + int(bool(with_composite))


# A lighting variant has the kind and the shadow map of each light slot compiled in: llvmpipe
# runs both sides of every select, and computing every kind's and map's terms for every light
# cost a fifth of arcade's light passes.  Per slot two letters: the kind, then the map.
KIND_LETTERS = {0: "s", 1: "p", 2: "t", 3: "a"}  # LIGHT_KIND_CODES: sun, point, spot (t), area
MAP_LETTERS = {0: "n", 1: "v", 2: "c"}  # no map, one view, cube map


def lighting_name(slots, composite: bool = False) -> str:
    """The name of a lighting variant for ``slots`` [(kind code, map code)] (map: 0 none, 1 one
    view, 2 cube), ``composite``: the opaque layer's pass that also composites."""
    letters = "".join(KIND_LETTERS[int(kind)] + MAP_LETTERS[int(shadow)] for kind, shadow in slots)
    return f"lighting{len(slots)}{'_composite' if composite else ''}_{letters}"


def parse_lighting_name(name: str):
    """(slots, composite) of a ``lighting_name``, or None."""
    match = re.fullmatch(r"lighting(\d+)(_composite)?_((?:[spta][nvc])+)", name)
    if match is None or int(match.group(1)) != len(match.group(3)) // 2 \
            or not 1 <= int(match.group(1)) <= LIGHTS_PER_PASS:
        return None
    kinds = {letter: code for code, letter in KIND_LETTERS.items()}
    maps = {letter: code for code, letter in MAP_LETTERS.items()}
    letters = match.group(3)
    slots = [(kinds[letters[j]], maps[letters[j + 1]]) for j in range(0, len(letters), 2)]
    return slots, match.group(2) is not None


def build_lighting(gpu, normal_offset_texels, depth_bias_texels, slots, with_composite=False):
    """``slots`` [(kind code, map code)] lights over one G-buffer layer (bound as ``layer_*``),
    added to its light target (see ``lighting_name``); ``with_composite``: also the opaque
    layer's composite (all its lights in this one pass), written to Combined (and the traced
    change when measured)."""
    light_count = len(slots)
    info = gpu.types.GPUShaderCreateInfo()
    info.define("LIGHTS_PER_PASS", str(LIGHTS_PER_PASS))
    info.define("WITH_COMPOSITE", "1" if with_composite else "0")
    info.typedef_source(CAMERA_STRUCT + LIGHT_STRUCT)
    info.uniform_buf(0, "CameraData", "camera")
    info.uniform_buf(1, "LightSet", "lights")
    names = ["layer_position", "layer_normal", "layer_albedo", "material_table"]
    for i in range(light_count):
        names += [f"shadow_map{i}", f"visibility{i}"]
    if with_composite:
        names.append("opaque_reflection")
    assert len(names) == lighting_samplers(light_count, with_composite)
    for slot, name in enumerate(names):
        info.sampler(slot, "FLOAT_2D", name)
    _defines(info, normal_offset_texels, depth_bias_texels)
    info.push_constant("INT", "measure_change")
    info.push_constant("INT", "traced_lights")
    info.vertex_in(0, "VEC2", "pos")
    # Colour targets in this order: light, [combined,] shadow change[, traced change] (the
    # change targets are attached only when measured: the last ones may be missing).
    outputs = ["out_light", "out_combined", "out_change", "out_traced_change"] if with_composite \
        else ["out_light", "out_change"]
    for index, name in enumerate(outputs):
        info.fragment_out(index, "VEC4", name)
    info.vertex_source(FULLSCREEN_VERT)
    info.fragment_source(COMMON_LIB + LIGHTING_FRAG.replace("PHRT_ADD_LIGHTS\n", "".join(
        f"  total += light_layer({i}, {int(slots[i][0])}, {int(slots[i][1])}, shadow_map{i}, s, "
        f"(traced_lights & {1 << i}) != 0 "
        f"? texelFetch(visibility{i}, pixel, 0).r : -1.0, change);\n" for i in range(light_count))))
    return gpu.shader.create_from_info(info)


def build_resolve(gpu):
    return _fullscreen_pass(gpu, CAMERA_STRUCT, (), (("VEC4", "out_normal_depth"), ("UINT", "out_element")),
                            RESOLVE_FRAG, layers={"with_albedo": False, "with_element": True}, depth_write="ANY")


def build_composite(gpu, normal_offset_texels, depth_bias_texels, with_transparent=True):
    """Emission, ambient, reflections and transparency over the accumulated lights; without
    ``with_transparent``, the opaque layer only (see COMPOSITE_FRAG)."""
    samplers = ["material_table", "opaque_light", "opaque_reflection", "shadow_change"]
    if with_transparent:
        samplers += ["transparent_light", "transparent_reflection", "refraction"]
    return _fullscreen_pass(
        gpu, CAMERA_STRUCT, samplers, (("VEC4", "out_combined"), ("VEC4", "out_change")),
        COMMON_LIB + COMPOSITE_FRAG, defines=(normal_offset_texels, depth_bias_texels), measure_change=True,
        layers={"layers": ("opaque", "transparent") if with_transparent else ("opaque",)},
        extra_defines={"WITH_TRANSPARENT": "1" if with_transparent else "0"})

