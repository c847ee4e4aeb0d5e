// KHR_lights_punctual: directional (lux), point and spot (candela) lights, with the
// extension's range and cone falloff. Compiled in only when a scene has lights.
#ifndef PUNCTUAL_GLSL
#define PUNCTUAL_GLSL
#include "brdf.glsl"
#include "lobes.glsl"
#include "ibl.glsl"
#if LIGHT_COUNT > 0
uniform vec4 u_light_position[LIGHT_COUNT];   // xyz world position, w: 0 directional, 1 point, 2 spot
uniform vec4 u_light_direction[LIGHT_COUNT];  // xyz direction the light travels, w range (0 = infinite)
uniform vec3 u_light_color[LIGHT_COUNT];      // colour x intensity
uniform vec2 u_light_cone[LIGHT_COUNT];       // angle scale, angle offset

// Adds every light's share of each lobe to `lobes` (shaders/lobes.glsl composes them).
void punctual(MaterialInfo m, vec3 v, vec3 pos, inout Lobes lobes) {
    vec3 n = m.n;
    float alpha = m.roughness * m.roughness;
    float NdotV = clamp(dot(n, v), 1e-4, 1.0);
    // The same layering as ibl(): the diffuse base gets what the specular lobe's directional
    // albedo leaves, and the lobe is scaled by its multiple-scattering share (Turquin 2019).
    vec3 FssEss, FmsEms;
    specular_albedo(m.f0, m.f90, NdotV, m.roughness, FssEss, FmsEms);
    vec3 diffuse = brdf_lambert(m.diffuse_color) * (1.0 - FssEss - FmsEms);
    vec3 ms_scale = 1.0 + FmsEms / max(FssEss, vec3(1e-4));
    for (int i = 0; i < LIGHT_COUNT; ++i) {
        vec3 l;
        float atten = 1.0;
        if (u_light_position[i].w == 0.0) {
            l = -u_light_direction[i].xyz;
        } else {
            vec3 d = u_light_position[i].xyz - pos;
            float dist2 = max(dot(d, d), 1e-8);
            l = d * inversesqrt(dist2);
            float range = u_light_direction[i].w;
            atten = 1.0 / dist2;
            if (range > 0.0) {
                float r = dist2 / (range * range);
                atten *= clamp(1.0 - r * r, 0.0, 1.0);
            }
            if (u_light_position[i].w == 2.0) {
                float cd = dot(u_light_direction[i].xyz, -l);
                float s = clamp(cd * u_light_cone[i].x + u_light_cone[i].y, 0.0, 1.0);
                atten *= s * s;
            }
        }
        if (atten <= 0.0) continue;
        vec3 radiance = u_light_color[i] * atten;
        vec3 h = normalize(l + v);
        float VdotH = clamp(dot(v, h), 0.0, 1.0);
#ifdef MATERIAL_CLEARCOAT
        vec3 nc = m.clearcoat_n;
        float NcdotL = dot(nc, l);
        if (NcdotL > 0.0) {
            float ac = max(m.clearcoat_roughness * m.clearcoat_roughness, 1e-3);
            lobes.clearcoat += brdf_specular(CLEARCOAT_F0, ac, clamp(dot(nc, v), 1e-4, 1.0), NcdotL,
                                             clamp(dot(nc, h), 0.0, 1.0), VdotH) * radiance * NcdotL;
        }
#endif
        float NdotL = dot(n, l);
#ifdef MATERIAL_DIFFUSE_TRANSMISSION
        if (NdotL < 0.0)  // lit from behind: the share that passes through
            lobes.base += brdf_lambert(m.diffuse_transmission) * radiance * -NdotL;
#endif
        if (NdotL <= 0.0) continue;
        float NdotH = clamp(dot(n, h), 0.0, 1.0);
#ifdef MATERIAL_ANISOTROPY
        float a = max(alpha, 1e-3);
        vec3 spec = F_schlick(m.f0, m.f90, VdotH)
                  * brdf_anisotropic_dv(mix(a, 1.0, m.anisotropy * m.anisotropy), a, n,
                                        m.anisotropy_t, m.anisotropy_b, v, l, h);
#else
        vec3 spec = brdf_specular(m.f0, m.f90, max(alpha, 1e-3), NdotV, NdotL, NdotH, VdotH);
#endif
        lobes.base += (diffuse + spec * ms_scale) * radiance * NdotL;
#ifdef MATERIAL_SHEEN
        lobes.sheen += brdf_sheen(m.sheen_color, m.sheen_roughness, NdotV, NdotL, NdotH)
                     * radiance * NdotL;
#endif
    }
}
#endif
#endif
