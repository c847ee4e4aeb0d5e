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

#if SHADOW_VIEWS > 0
// Shadow maps (renderer/raster/light_shadows.py): one depth atlas, a tile per view.
uniform sampler2DShadow u_shadow_map;
uniform mat4 u_shadow_matrix[SHADOW_VIEWS];  // world -> atlas (u, v, depth) before the divide
uniform vec4 u_shadow_tile[SHADOW_VIEWS];    // usable uv rectangle of the view's tile
uniform vec2 u_shadow_texel[SHADOW_VIEWS];   // world texel size: x + y * distance along the view
uniform vec2 u_light_shadow[LIGHT_COUNT];    // first view, views (0: casts none; 6: a cube)
uniform vec3 u_shadow_color[LIGHT_COUNT];    // what blocked light is multiplied by
uniform vec2 u_shadow_step;                  // one atlas texel in uv
#ifdef SHADOW_TINT
uniform sampler2D u_shadow_tint;  // blend / transmissive casters: RGB let through, A their depth
#endif

// How much of light i reaches pos (normal n on the light's side, l toward the light).
vec3 shadow_visibility(int i, vec3 pos, vec3 n, vec3 l) {
    int count = int(u_light_shadow[i].y);
    if (count == 0) return vec3(1.0);
    int view = int(u_light_shadow[i].x);
    vec3 d = pos - u_light_position[i].xyz;
    float dist = dot(d, u_light_direction[i].xyz);  // a spot's depth along its axis
    if (count == 6) {  // the cube face of the major axis
        vec3 a = abs(d);
        if (a.x >= a.y && a.x >= a.z) { view += d.x > 0.0 ? 0 : 1; dist = a.x; }
        else if (a.y >= a.z) { view += d.y > 0.0 ? 2 : 3; dist = a.y; }
        else { view += d.z > 0.0 ? 4 : 5; dist = a.z; }
    }
    float texel = u_shadow_texel[view].x + u_shadow_texel[view].y * max(dist, 0.0);
    // Slope-scaled bias: the 3 x 3 bilinear footprint spans 2 texels each way, across which a
    // surface at angle t to the light changes depth by 2 texels x tan t.
    float c = clamp(dot(n, l), 1e-3, 1.0);
    float slope = min(sqrt(1.0 - c * c) / c, 8.0);
    vec3 p = pos + n * texel + l * texel * (1.0 + 2.0 * slope);
    vec4 s = u_shadow_matrix[view] * vec4(p, 1.0);
    if (s.w <= 0.0) return vec3(1.0);
    vec3 uvz = s.xyz / s.w;
    vec4 tile = u_shadow_tile[view];
    if (uvz.z >= 1.0 || any(lessThan(uvz.xy, tile.xy)) || any(greaterThan(uvz.xy, tile.zw)))
        return vec3(1.0);  // outside the map: nothing of the asset lies between
    float lit = 0.0;
    for (int y = -1; y <= 1; ++y)
        for (int x = -1; x <= 1; ++x)
            lit += texture(u_shadow_map, vec3(clamp(uvz.xy + vec2(x, y) * u_shadow_step,
                                                    tile.xy, tile.zw), uvz.z));
    vec3 visible = mix(u_shadow_color[i], vec3(1.0), lit / 9.0);
#ifdef SHADOW_TINT
    vec4 tint = texture(u_shadow_tint, uvz.xy);
    if (uvz.z > tint.a) visible *= tint.rgb;  // behind the nearest see-through layer
#endif
    return visible;
}
#endif

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
#if SHADOW_VIEWS > 0
        radiance *= shadow_visibility(i, pos, dot(n, l) < 0.0 ? -n : n, l);
#endif
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
#ifdef SHOW_BACK_FACES
        if (!gl_FrontFacing) {  // Storm's back face (core/storm.py): N.E = 0 leaves no specular
            lobes.base += brdf_lambert(m.diffuse_color) * (1.0 - F_schlick(m.f0, m.f90, VdotH))
                        * radiance * NdotL;
            continue;
        }
#endif
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
