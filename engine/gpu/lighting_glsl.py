"""GLSL of the lighting pass: per light, its incidence at a G-buffer pixel, its shadow-map lookup
(or the tracer's visibility where it replaced it) and the BRDF of ``surface_glsl``; summed over
the pass's lights into the layer's light target.  ``lighting.build`` puts it together, with
one ``light_layer()`` call per light slot (``PHRT_ADD_LIGHTS``) and the kind and map codes
(``LIGHT_*``: ``phrt_addon/scene/lights.py LightKind``; ``MAP_*``: ``lighting.MapKind``) defined."""

LIGHTING_FRAG = """
/* llvmpipe runs both sides of every branch for every pixel, with mask bookkeeping on top:
   the per-pixel code below chooses with selects rather than branches and early returns. */
// numpy twin: phrt_addon/raster/shadowmap.py cube_face_view
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

// numpy twin: phrt_addon/raster/shadowmap.py shadow_visibility
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

// numpy twin: phrt_addon/scene/shading.py light_incidence
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
  float intensity = kind == LIGHT_AREA
                    ? clamp(cos_angle, 0.0, 1.0) * PHRT_INV_PI
                    : 0.25 * PHRT_INV_PI * (kind == LIGHT_SPOT ? spot * spot * (3.0 - 2.0 * spot) : 1.0);
  float radius = lights.light[i].position_radius.w;
  bool sun = kind == LIGHT_SUN;
  direction = sun ? -axis : towards;
  return sun ? color : color * (intensity / (dist * dist + radius * radius));
}

// numpy twin: phrt_addon/raster/reference_raster.py ReferenceRaster.shade (one light's term at one layer)
/* One light at one layer's surface; with ``measure_change`` where the tracer replaced the
   shadow map, ``change`` gains the luminance of what that changed (the error-aware relevance). */
vec3 light_layer(int i, int kind, int map, sampler2D shadow_map, Surface s, float traced_visibility,
                 inout float change) {
  vec3 direction;
  vec3 irradiance = incidence(i, kind, s.position, direction);
  vec3 unshadowed = brdf_cosine(s, direction) * irradiance;
  /* The shadow map's lit fraction (1 for a light without one), or the tracer's where it ran. */
  float mapped = map == MAP_NONE ? 1.0 : shadow_lit(i, map == MAP_CUBE, shadow_map, s.position, s.normal);
  bool traced = lights.light[i].spot.z > 0.5 && traced_visibility >= 0.0;
  change += measure_change != 0 && traced
            ? min(dot(abs(unshadowed * (traced_visibility - mapped)), PHRT_LUMINANCE), 1.0) : 0.0;
  return unshadowed * (traced ? traced_visibility : mapped);
}

// numpy twin: phrt_addon/raster/reference_raster.py ReferenceRaster.shade (a layer's lights, and the opaque composite)
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
