// One MaterialInfo per fragment: factors x textures x vertex colour, the shading normal, and
// the derived F0 / diffuse colour. Everything the lighting code needs flows through it.
// Each Khronos extension has one getter below, compiled in only under its MATERIAL_* define
// (renderer/raster/materials.py sets them from the rows of core/lobes.py), so a material pays
// only for what it uses.
#ifndef MATERIAL_INFO_GLSL
#define MATERIAL_INFO_GLSL
#include "textures.glsl"
#include "iridescence.glsl"

uniform vec4 u_base_color;
uniform float u_metallic;
uniform float u_roughness;
uniform float u_normal_scale;
uniform float u_occlusion_strength;
uniform vec3 u_emissive;        // factor x strength
uniform float u_alpha_cutoff;
uniform float u_ior;            // KHR_materials_ior (also the refraction's)
#ifdef MATERIAL_SPECULAR
uniform float u_specular;
uniform vec3 u_specular_color;
#endif
#ifdef MATERIAL_CLEARCOAT
uniform float u_clearcoat;
uniform float u_clearcoat_roughness;
uniform float u_clearcoat_normal_scale;
#endif
#ifdef MATERIAL_IRIDESCENCE
uniform float u_iridescence;
uniform float u_iridescence_ior;
uniform vec2 u_iridescence_thickness;  // nm: minimum, maximum
#endif
#ifdef MATERIAL_DIFFUSE_TRANSMISSION
uniform vec4 u_diffuse_transmission;  // colour, factor
#endif
#ifdef MATERIAL_ANISOTROPY
uniform vec3 u_anisotropy;      // cos, sin of the rotation; strength
#endif
#ifdef MATERIAL_SHEEN
uniform vec3 u_sheen_color;
uniform float u_sheen_roughness;
#endif

in vec3 v_world;
in vec3 v_normal;
#ifdef FACE_VIEWER
uniform vec3 u_view_axis;  // the camera's axis toward the viewer
#endif
#ifdef HAS_TANGENTS
in vec4 v_tangent;
#endif
#ifdef HAS_COLORS
in vec4 v_color;
#endif
#ifdef HAS_AO
in vec2 v_ao;  // front, back side
#endif
#ifdef HAS_BENT
in vec3 v_bent;       // bent normals (pipeline.occlusion), world space, front side
in vec3 v_bent_back;  // and back side
#endif

struct MaterialInfo {
    vec4 base_color;     // linear, with alpha
    float metallic;
    float roughness;     // perceptual; alpha = roughness^2
    vec3 f0;             // normal-incidence reflectance (dielectric from IOR x specular, or metal)
    float f90;           // grazing reflectance (KHR_materials_specular scales it for dielectrics)
    vec3 diffuse_color;  // base colour x (1 - metallic)
    float occlusion;     // the occlusion texture's (glTF), 1 without
    float ao;            // baked ambient visibility of the geometry (pipeline.occlusion), 1 without
    vec3 emissive;
    vec3 n;              // shading normal, world space, facing the viewer on double-sided
    vec3 ng;             // geometric normal, same side
    vec3 bent;           // the shading normal bent toward the unoccluded directions (baked), n without
    float clearcoat;     // KHR_materials_clearcoat: 0 = no coat
    float clearcoat_roughness;
    vec3 clearcoat_n;
    vec3 sheen_color;    // KHR_materials_sheen: black = no sheen
    float sheen_roughness;
    float iridescence;   // KHR_materials_iridescence: 0 = no film
    vec3 iridescence_fresnel;  // the film's reflectance at N.V
    float anisotropy;    // KHR_materials_anisotropy: 0 = isotropic
    vec3 anisotropy_t;   // world direction of the stretched highlight (the grain)
    vec3 anisotropy_b;
    vec3 diffuse_transmission;  // KHR_materials_diffuse_transmission: colour x factor
};

vec3 geometric_normal() {
    vec3 ng = normalize(v_normal);
#ifdef DOUBLE_SIDED
    if (!gl_FrontFacing) ng = -ng;
#endif
    return ng;
}

#if defined(HAS_NORMAL_MAP) || defined(HAS_CLEARCOAT_NORMAL_MAP) || defined(MATERIAL_ANISOTROPY)
// Tangent frame (t, b) about ng: the baked tangents, else from the derivatives of position
// and `uv`, else any frame (a mesh with no UVs).
void tangent_frame(vec3 ng, vec2 uv, out vec3 t, out vec3 b) {
#ifdef HAS_TANGENTS
    t = normalize(v_tangent.xyz - ng * dot(ng, v_tangent.xyz));
    b = cross(ng, t) * v_tangent.w;
#else
    // No baked tangents: derive the frame from screen-space derivatives of position and UV.
    vec3 dp_dx = dFdx(v_world), dp_dy = dFdy(v_world);
    vec2 duv_dx = dFdx(uv), duv_dy = dFdy(uv);
    float det = duv_dx.x * duv_dy.y - duv_dy.x * duv_dx.y;
    t = (duv_dy.y * dp_dx - duv_dx.y * dp_dy) / (abs(det) > 1e-12 ? det : 1e-12);
    t = t - ng * dot(ng, t);
    t = dot(t, t) > 1e-20 ? normalize(t) : normalize(cross(ng, abs(ng.y) < 0.99 ? vec3(0, 1, 0) : vec3(1, 0, 0)));
    b = cross(ng, t) * (det < 0.0 ? -1.0 : 1.0);
#endif
#ifdef DOUBLE_SIDED
    if (!gl_FrontFacing) { t = -t; b = -b; }
#endif
}
#endif

#if defined(HAS_NORMAL_MAP) || defined(HAS_CLEARCOAT_NORMAL_MAP)
// A normal map's normal sampled at uv; `tn` is its texel in 0..1, xy scaled by `scale`
// (glTF normalTexture.scale).
vec3 perturbed_normal(vec3 ng, vec2 uv, vec3 tn, float scale) {
    vec3 t, b;
    tangent_frame(ng, uv, t, b);
    tn = tn * 2.0 - 1.0;
    tn.xy *= scale;
    return normalize(mat3(t, b, ng) * tn);
}
#endif

vec3 shading_normal(vec3 ng) {
#ifdef HAS_NORMAL_MAP
    return perturbed_normal(ng, NORMAL_UV, SAMPLE_MAP(normal, NORMAL_UV).xyz, u_normal_scale);
#else
    return ng;
#endif
}

// KHR_materials_ior: dielectric F0 = ((ior - 1) / (ior + 1))^2; 0.04 is ior 1.5.
float dielectric_f0() {
#ifdef MATERIAL_IOR
    float r = (u_ior - 1.0) / (u_ior + 1.0);
    return r * r;
#else
    return 0.04;
#endif
}

// KHR_materials_specular: the dielectric F0 tinted by the specular colour (clamped to 1) and
// both F0 and F90 scaled by the specular factor; metals keep F0 = base colour, F90 = 1.
void material_specular(inout MaterialInfo m) {
    vec3 f0 = vec3(dielectric_f0());
    float weight = 1.0;
#ifdef MATERIAL_SPECULAR
    vec3 tint = u_specular_color;
    weight = u_specular;
#ifdef HAS_SPECULAR_COLOR_MAP
    tint *= SAMPLE_MAP(specular_color, SPECULAR_COLOR_UV).rgb;  // sRGB texture
#endif
#ifdef HAS_SPECULAR_MAP
    weight *= SAMPLE_MAP(specular, SPECULAR_UV).a;
#endif
    f0 = min(f0 * tint, vec3(1.0)) * weight;
#endif
    m.f0 = mix(f0, m.base_color.rgb, m.metallic);
    m.f90 = mix(weight, 1.0, m.metallic);
}

// KHR_materials_clearcoat: a GGX layer of IOR 1.5 over everything, with its own normal
// (the geometric one unless it has a normal texture: the base's normal map is under it).
void material_clearcoat(inout MaterialInfo m) {
    m.clearcoat = 0.0;
    m.clearcoat_roughness = 0.0;
    m.clearcoat_n = m.ng;
#ifdef MATERIAL_CLEARCOAT
    m.clearcoat = u_clearcoat;
    m.clearcoat_roughness = u_clearcoat_roughness;
#ifdef HAS_CLEARCOAT_MAP
    m.clearcoat *= SAMPLE_MAP(clearcoat, CLEARCOAT_UV).r;
#endif
#ifdef HAS_CLEARCOAT_ROUGHNESS_MAP
    m.clearcoat_roughness *= SAMPLE_MAP(clearcoat_roughness, CLEARCOAT_ROUGHNESS_UV).g;
#endif
#ifdef HAS_CLEARCOAT_NORMAL_MAP
    m.clearcoat_n = perturbed_normal(m.ng, CLEARCOAT_NORMAL_UV,
                                     SAMPLE_MAP(clearcoat_normal, CLEARCOAT_NORMAL_UV).xyz,
                                     u_clearcoat_normal_scale);
#endif
    m.clearcoat = clamp(m.clearcoat, 0.0, 1.0);
    m.clearcoat_roughness = clamp(m.clearcoat_roughness, 0.0, 1.0);
#endif
}

// KHR_materials_sheen: colour (sRGB texture RGB) and roughness (texture A).
void material_sheen(inout MaterialInfo m) {
    m.sheen_color = vec3(0.0);
    m.sheen_roughness = 0.0;
#ifdef MATERIAL_SHEEN
    m.sheen_color = u_sheen_color;
    m.sheen_roughness = u_sheen_roughness;
#ifdef HAS_SHEEN_COLOR_MAP
    m.sheen_color *= SAMPLE_MAP(sheen_color, SHEEN_COLOR_UV).rgb;
#endif
#ifdef HAS_SHEEN_ROUGHNESS_MAP
    m.sheen_roughness *= SAMPLE_MAP(sheen_roughness, SHEEN_ROUGHNESS_UV).a;
#endif
    m.sheen_roughness = clamp(m.sheen_roughness, 0.0, 1.0);
#endif
}

// KHR_materials_iridescence: the thin film's reflectance at this view angle replaces the
// base's Fresnel (by the factor). It enters as the F0 that Schlick needs to reproduce it at
// N.V, so the split-sum IBL, the lights and the diffuse attenuation all see one Fresnel.
void material_iridescence(inout MaterialInfo m, vec3 v) {
    m.iridescence = 0.0;
    m.iridescence_fresnel = vec3(0.0);
#ifdef MATERIAL_IRIDESCENCE
    m.iridescence = u_iridescence;
#ifdef HAS_IRIDESCENCE_MAP
    m.iridescence *= SAMPLE_MAP(iridescence, IRIDESCENCE_UV).r;
#endif
    float thickness = u_iridescence_thickness.y;
#ifdef HAS_IRIDESCENCE_THICKNESS_MAP
    thickness = mix(u_iridescence_thickness.x, u_iridescence_thickness.y,
                    SAMPLE_MAP(iridescence_thickness, IRIDESCENCE_THICKNESS_UV).g);
#endif
    float c = clamp(dot(m.n, v), 1e-4, 1.0);
    m.iridescence_fresnel = thin_film_fresnel(c, u_iridescence_ior, thickness, m.f0);
    float w = pow(1.0 - c, 5.0);
    vec3 f0 = clamp((m.iridescence_fresnel - m.f90 * w) / max(1.0 - w, 1e-4), 0.0, 1.0);
    m.f0 = mix(m.f0, f0, m.iridescence);
#endif
}

// KHR_materials_anisotropy: direction (texture RG in -1..1, default the tangent) rotated by
// the rotation, strength x texture B; roughness along it becomes mix(alpha, 1, strength^2).
void material_anisotropy(inout MaterialInfo m) {
    m.anisotropy = 0.0;
    m.anisotropy_t = vec3(0.0);
    m.anisotropy_b = vec3(0.0);
#ifdef MATERIAL_ANISOTROPY
    vec2 dir = vec2(1.0, 0.0);
    float strength = u_anisotropy.z;
#ifdef HAS_ANISOTROPY_MAP
    vec3 a = SAMPLE_MAP(anisotropy, ANISOTROPY_UV).rgb;
    dir = normalize(a.rg * 2.0 - 1.0);
    strength *= a.b;
    vec2 uv = ANISOTROPY_UV;
#elif defined(HAS_UV0)
    vec2 uv = v_uv0;
#else
    vec2 uv = vec2(0.0);
#endif
    dir = mat2(u_anisotropy.x, u_anisotropy.y, -u_anisotropy.y, u_anisotropy.x) * dir;
    vec3 t, b;
    tangent_frame(m.ng, uv, t, b);
    vec3 at = t * dir.x + b * dir.y;
    at = normalize(at - m.n * dot(m.n, at));  // onto the shading normal's plane
    m.anisotropy = clamp(strength, 0.0, 1.0);
    m.anisotropy_t = at;
    m.anisotropy_b = cross(m.n, at);
#endif
}

// KHR_materials_diffuse_transmission: the factor's share of the diffuse lobe passes through
// the surface (thin-walled, Lambertian, tinted by its colour) instead of reflecting.
void material_diffuse_transmission(inout MaterialInfo m) {
    m.diffuse_transmission = vec3(0.0);
#ifdef MATERIAL_DIFFUSE_TRANSMISSION
    float share = u_diffuse_transmission.a;
    vec3 tint = u_diffuse_transmission.rgb;
#ifdef HAS_DIFFUSE_TRANSMISSION_MAP
    share *= SAMPLE_MAP(diffuse_transmission, DIFFUSE_TRANSMISSION_UV).a;
#endif
#ifdef HAS_DIFFUSE_TRANSMISSION_COLOR_MAP
    tint *= SAMPLE_MAP(diffuse_transmission_color, DIFFUSE_TRANSMISSION_COLOR_UV).rgb;
#endif
    m.diffuse_transmission = tint * share * (1.0 - m.metallic);
    m.diffuse_color *= 1.0 - share;
#endif
}

MaterialInfo material_info(vec3 v) {
    MaterialInfo m;
    m.base_color = u_base_color;
#ifdef HAS_BASE_COLOR_MAP
    m.base_color *= SAMPLE_MAP(base_color, BASE_COLOR_UV);  // sRGB texture: decoded by GL
#endif
#ifdef HAS_COLORS
    m.base_color *= v_color;
#endif
    m.metallic = u_metallic;
    m.roughness = u_roughness;
#ifdef HAS_METALLIC_ROUGHNESS_MAP
    vec4 mr = SAMPLE_MAP(metallic_roughness, METALLIC_ROUGHNESS_UV);
#ifndef METALLIC_OVERRIDDEN
    m.metallic *= mr.b;
#endif
#ifndef ROUGHNESS_OVERRIDDEN
    m.roughness *= mr.g;
#endif
#endif
    m.metallic = clamp(m.metallic, 0.0, 1.0);
    m.roughness = clamp(m.roughness, 0.0, 1.0);
    material_specular(m);
    m.diffuse_color = m.base_color.rgb * (1.0 - m.metallic);
    m.occlusion = 1.0;
#ifdef HAS_OCCLUSION_MAP
    m.occlusion = 1.0 + u_occlusion_strength * (SAMPLE_MAP(occlusion, OCCLUSION_UV).r - 1.0);
#endif
    m.ao = 1.0;
#ifdef HAS_AO
    m.ao = clamp(gl_FrontFacing ? v_ao.x : v_ao.y, 0.0, 1.0);
#endif
    m.emissive = u_emissive;
#ifdef HAS_EMISSIVE_MAP
    m.emissive *= SAMPLE_MAP(emissive, EMISSIVE_UV).rgb;
#endif
    m.ng = geometric_normal();
    m.n = shading_normal(m.ng);
#ifdef FACE_VIEWER
    // a point sprite, a disc turned to the viewer (Material.face_viewer): Storm's eye-space +Z
    m.ng = m.n = u_view_axis;
#endif
    m.bent = m.n;
#if defined(HAS_BENT) && !defined(FACE_VIEWER)
    // the baked bend (mean unoccluded direction less the geometric normal) carried onto the
    // shading normal, so a normal map's detail stays
    vec3 bent_g = gl_FrontFacing ? v_bent : v_bent_back;
    if (dot(bent_g, bent_g) > 1e-12) m.bent = normalize(m.n + normalize(bent_g) - m.ng);
#endif
    material_clearcoat(m);
    material_sheen(m);
    material_iridescence(m, v);
    material_anisotropy(m);
    material_diffuse_transmission(m);
    return m;
}
#endif
