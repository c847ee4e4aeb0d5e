// One MaterialInfo per fragment: factors x textures x vertex colour, the shading normal, and
// the derived F0 / diffuse colour. Everything the lighting code needs flows through it.
#ifndef MATERIAL_INFO_GLSL
#define MATERIAL_INFO_GLSL
#include "textures.glsl"

uniform vec4 u_base_color;
uniform float u_metallic;
uniform float u_roughness;
uniform float u_normal_scale;
uniform float u_occlusion_strength;
uniform vec3 u_emissive;        // factor x strength
uniform float u_alpha_cutoff;

in vec3 v_world;
in vec3 v_normal;
#ifdef HAS_TANGENTS
in vec4 v_tangent;
#endif
#ifdef HAS_COLORS
in vec4 v_color;
#endif

struct MaterialInfo {
    vec4 base_color;     // linear, with alpha
    float metallic;
    float roughness;     // perceptual; alpha = roughness^2
    vec3 f0;
    vec3 diffuse_color;  // base colour x (1 - metallic)
    float occlusion;
    vec3 emissive;
    vec3 n;              // shading normal, world space, facing the viewer on double-sided
};

vec3 shading_normal(vec3 v) {
    vec3 ng = normalize(v_normal);
#ifdef DOUBLE_SIDED
    if (!gl_FrontFacing) ng = -ng;
#endif
#ifdef HAS_NORMAL_MAP
    vec3 t, b;
#ifdef HAS_TANGENTS
    t = normalize(v_tangent.xyz - ng * dot(ng, v_tangent.xyz));
    b = cross(ng, t) * v_tangent.w;
#else
    // No baked tangents: derive the frame from screen-space derivatives of position and UV.
    vec2 uv = NORMAL_UV;
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
    vec3 tn = SAMPLE_MAP(normal, NORMAL_UV).xyz * 2.0 - 1.0;
    tn.xy *= u_normal_scale;
    vec3 n = normalize(mat3(t, b, ng) * tn);
#else
    vec3 n = ng;
#endif
    return n;
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
    m.f0 = mix(vec3(0.04), m.base_color.rgb, m.metallic);
    m.diffuse_color = m.base_color.rgb * (1.0 - m.metallic);
    m.occlusion = 1.0;
#ifdef HAS_OCCLUSION_MAP
    m.occlusion = 1.0 + u_occlusion_strength * (SAMPLE_MAP(occlusion, OCCLUSION_UV).r - 1.0);
#endif
    m.emissive = u_emissive;
#ifdef HAS_EMISSIVE_MAP
    m.emissive *= SAMPLE_MAP(emissive, EMISSIVE_UV).rgb;
#endif
    m.n = shading_normal(v);
    return m;
}
#endif
