"""GLSL shared by the lighting and composite passes: a G-buffer pixel read as a surface and its
response to light and environment, ``phrt_addon/scene/shading.py`` line for line (Lambert +
GGX/Smith/Schlick, the uniform-environment ambient, exact dielectric Fresnel).  Each function
names its numpy twin; ``tests/integration/test_gpu_frame.py`` renders one G-buffer through both.

G-buffer layout (one texture set per layer, opaque and transparent):
- ``position``  RGBA32F: camera-relative position (float32 keeps precision at any
  world coordinate), w = material index + 1 (0 = nothing drawn);
- ``normal``    RGBA32F: shading normal (front-facing), w = roughness;
- ``albedo``    RGBA8:   sqrt of the base colour with its texture applied (8 bits are
  enough for shading inputs once the darks get more codes), a = metallic;
- ``element``   R32UI:   element index + 1 (0 = not part of an element), 32 bits.
"""

# Materials are stored in a float texture, MATERIAL_TABLE_WIDTH per row pair:
# row 2k: (transmission, ior, alpha, 0); row 2k+1: (emission rgb, 0).
MATERIAL_TABLE_WIDTH = 1024

SURFACE_LIB = """
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

// numpy twin: phrt_addon/scene/shading.py MaterialTable (packed by resources.GPUResources.material_table)
vec4 material_row(int index, int row) {
  ivec2 texel = ivec2(index % MATERIAL_TABLE_WIDTH, (index / MATERIAL_TABLE_WIDTH) * 2 + row);
  return texelFetch(material_table, texel, 0);
}

// numpy twin: phrt_addon/scene/shading.py f0_dielectric
float f0_dielectric(float ior) {
  float r = (ior - 1.0) / (ior + 1.0);
  return r * r;
}

// numpy twin: phrt_addon/scene/shading.py SurfaceSamples (as phrt_addon/raster/reference_raster.py ReferenceRaster builds it)
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

// numpy twin: phrt_addon/scene/shading.py specular_f90
/* Reflectance at grazing incidence: 1, fading to 0 for a surface with almost no specular
   reflection (F0 below 2%: an IOR-1 surface reflects nothing, not a bright rim). */
float specular_f90(vec3 f0) {
  return clamp(50.0 * (f0.r + f0.g + f0.b) / 3.0, 0.0, 1.0);
}

// numpy twin: phrt_addon/scene/shading.py fresnel_schlick
vec3 fresnel_schlick(vec3 f0, float cos_theta) {
  float m = 1.0 - clamp(cos_theta, 0.0, 1.0);
  return f0 + (specular_f90(f0) - f0) * (m * m * m * m * m);
}

// numpy twin: phrt_addon/scene/shading.py fresnel_dielectric
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

// numpy twin: phrt_addon/scene/shading.py brdf_cosine
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

// numpy twin: phrt_addon/raster/reference_raster.py ReferenceRaster.shade (one layer's colour; shading.py ambient)
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

// numpy twin: phrt_addon/scene/shading.py finite
vec3 finite_radiance(vec3 c) {
  bvec3 bad = isnan(c);
  c = vec3(bad.x ? 0.0 : c.x, bad.y ? 0.0 : c.y, bad.z ? 0.0 : c.z);
  return clamp(c, 0.0, 1e6);
}
"""
