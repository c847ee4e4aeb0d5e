// The layers over the base (KHR_materials_sheen, KHR_materials_clearcoat) and how they stack:
// lights and IBL each add their share of every lobe into one Lobes, and `compose` layers them
// once, as the Khronos sample viewer does:
//   sheen:     base x (1 - max(sheen colour) x E_sheen(N.V)) + sheen
//   clearcoat: (that + emission) x (1 - clearcoat x F_coat(N_coat.V)) + clearcoat x coat
// E_sheen is the sheen albedo baked in the BRDF LUT's third channel; F_coat is Schlick at
// F0 = 0.04 (the coat's IOR 1.5). Both factors depend on the view only, so one compose serves
// every light.
#ifndef LOBES_GLSL
#define LOBES_GLSL
#include "brdf.glsl"

struct Lobes {
    vec3 base;          // diffuse + specular of the base material (transmission included)
    vec3 sheen;         // sheen lobe (colour included)
    vec3 clearcoat;     // coat's specular, before its factor
    vec3 transmission;  // throughput of the refracted share (refraction.frag), for debug views
};

Lobes no_lobes() {
    return Lobes(vec3(0.0), vec3(0.0), vec3(0.0), vec3(0.0));
}

const vec3 CLEARCOAT_F0 = vec3(0.04);

#ifdef MATERIAL_INFO_GLSL
#ifdef MATERIAL_DEBUG
// `render --material-debug LOBE`: one lobe alone (renderer.raster.passes.MATERIAL_DEBUG_VIEWS).
vec3 debug_lobe(MaterialInfo m, Lobes l) {
#if MATERIAL_DEBUG == 1
    return l.base;
#elif MATERIAL_DEBUG == 2
    return m.clearcoat * l.clearcoat;
#elif MATERIAL_DEBUG == 3
    return l.sheen;
#elif MATERIAL_DEBUG == 4
    return m.f0;
#elif MATERIAL_DEBUG == 6
    return m.iridescence * m.iridescence_fresnel;
#else
    return l.transmission;
#endif
}
#endif

vec3 compose(MaterialInfo m, vec3 v, Lobes l, sampler2D brdf_lut) {
#ifdef MATERIAL_DEBUG
    return debug_lobe(m, l);
#endif
    vec3 color = l.base;
#ifdef MATERIAL_SHEEN
    float NdotV = clamp(dot(m.n, v), 1e-4, 1.0);
    float e_sheen = texture(brdf_lut, vec2(NdotV, m.sheen_roughness)).b;
    float peak = max(max(m.sheen_color.r, m.sheen_color.g), m.sheen_color.b);
    color = color * (1.0 - peak * e_sheen) + l.sheen;
#endif
    color += m.emissive;
#ifdef MATERIAL_CLEARCOAT
    float c = clamp(dot(m.clearcoat_n, v), 1e-4, 1.0);
    vec3 f_coat = F_schlick(CLEARCOAT_F0, c);
    color = color * (1.0 - m.clearcoat * f_coat) + m.clearcoat * l.clearcoat;
#endif
    return color;
}
#endif
#endif
