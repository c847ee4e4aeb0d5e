// Emissive polygons as area lights (core.area_lights), unshadowed. Compiled in only when the
// asset has some (AREA_LIGHT_COUNT > 0: no emitters leaves the program as it was).
// Diffuse: the exact irradiance of a uniform Lambertian polygon, sum over its edges of the
// angle they subtend times the edge plane's normal (Lambert's form factor), after clipping
// the polygon to the surface's horizon. Specular: a linearly transformed cosine (Heitz 2016)
// with an analytic, not fitted, matrix: the clamped cosine about the lobe's dominant
// direction, squeezed by 2 alpha across it (that matches GGX's peak and half width at normal
// view for small alpha), scaled by the lobe's directional albedo. Its integral over the whole
// sphere is that albedo, so a light filling the view gives what the split sum gives. The
// specular's polygon is clipped to the lobe axis' hemisphere, not also to the surface's (one
// clip, no arrays): a light straddling the horizon lends a little glossy light from below it.
#ifndef AREA_LIGHTS_GLSL
#define AREA_LIGHTS_GLSL
#include "brdf.glsl"
#include "lobes.glsl"
#include "ibl.glsl"
#if AREA_LIGHT_COUNT > 0
uniform vec4 u_area_corner[AREA_LIGHT_COUNT * 4];  // xyz world corners, counter-clockwise from the front
uniform vec4 u_area_normal[AREA_LIGHT_COUNT];      // xyz front normal, w 1: emits from both sides
uniform vec4 u_area_radiance[AREA_LIGHT_COUNT];    // rgb linear radiance, w the mesh it is part of
uniform float u_area_self;                         // the mesh being drawn: its own lights skipped

vec3 area_edge(vec3 a, vec3 b) {  // a, b unit
    vec3 c = cross(a, b);
    float s = length(c);
    return s > 1e-7 ? c * (atan(s, dot(a, b)) / s) : vec3(0.0);
}

// One edge a -> b of a convex polygon clipped to dot(x, axis) >= 0: its kept part's term added
// to `sum`; where it leaves or enters the half space, the point (the clipped polygon closes
// along the plane from the exit to the entry). No arrays: a CPU rasteriser (llvmpipe) runs
// indexed local arrays many times slower, even on pixels that never clip.
void area_clip_edge(vec3 a, vec3 b, vec3 axis, inout vec3 sum, inout vec3 leave, inout vec3 enter) {
    float da = dot(a, axis), db = dot(b, axis);
    if (da >= 0.0 && db >= 0.0) {
        sum += area_edge(normalize(a), normalize(b));
    } else if (da >= 0.0) {
        leave = mix(a, b, da / (da - db));
        sum += area_edge(normalize(a), normalize(leave));
    } else if (db >= 0.0) {
        enter = mix(a, b, da / (da - db));
        sum += area_edge(normalize(enter), normalize(b));
    }
}

// Sum over the edges of the quad c0..c3 clipped to dot(x, axis) >= 0 of the angle each
// subtends times its plane's unit normal; its dot with `axis` is 2 pi x the polygon's form
// factor about it (Lambert).
vec3 area_edge_sum(vec3 c0, vec3 c1, vec3 c2, vec3 c3, vec3 axis) {
    vec3 sum = vec3(0.0), leave = vec3(0.0), enter = vec3(0.0);
    area_clip_edge(c0, c1, axis, sum, leave, enter);
    area_clip_edge(c1, c2, axis, sum, leave, enter);
    area_clip_edge(c2, c3, axis, sum, leave, enter);
    area_clip_edge(c3, c0, axis, sum, leave, enter);
    if (leave != enter) sum += area_edge(normalize(leave), normalize(enter));
    return sum;
}

void area_lights(MaterialInfo m, vec3 v, vec3 pos, inout Lobes lobes) {
    vec3 n = m.n;
    float NdotV = clamp(dot(n, v), 1e-4, 1.0);
    vec3 FssEss, FmsEms;
    specular_albedo(m.f0, m.f90, NdotV, m.roughness, FssEss, FmsEms);
    vec3 diffuse = brdf_lambert(m.diffuse_color) * (1.0 - FssEss - FmsEms);
    vec3 spec_albedo = FssEss + FmsEms;
    // the specular lobe's frame: dominant direction r, squeezed across by a (M^-1 divides by a)
    vec3 r = specular_dir(n, v, m.roughness);
    float a = clamp(2.0 * m.roughness * m.roughness, 1e-3, 1.0);
    vec3 t1 = normalize(abs(r.z) < 0.999 ? cross(r, vec3(0.0, 0.0, 1.0)) : cross(r, vec3(1.0, 0.0, 0.0)));
    vec3 t2 = cross(r, t1);
    for (int i = 0; i < AREA_LIGHT_COUNT; ++i) {
        if (u_area_radiance[i].w == u_area_self) continue;
        vec3 ln = u_area_normal[i].xyz;
        float side = dot(pos - u_area_corner[4 * i].xyz, ln);
        if (side <= 0.0 && u_area_normal[i].w == 0.0) continue;  // behind a one-sided emitter
        vec3 c0 = u_area_corner[4 * i].xyz - pos, c1 = u_area_corner[4 * i + 1].xyz - pos;
        vec3 c2 = u_area_corner[4 * i + 2].xyz - pos, c3 = u_area_corner[4 * i + 3].xyz - pos;
        vec4 h = vec4(dot(c0, n), dot(c1, n), dot(c2, n), dot(c3, n));
        if (all(lessThanEqual(h, vec4(0.0)))) continue;  // below the horizon
        vec3 radiance = u_area_radiance[i].rgb;
        vec3 q0 = vec3(dot(c0, t1) / a, dot(c0, t2) / a, dot(c0, r));
        vec3 q1 = vec3(dot(c1, t1) / a, dot(c1, t2) / a, dot(c1, r));
        vec3 q2 = vec3(dot(c2, t1) / a, dot(c2, t2) / a, dot(c2, r));
        vec3 q3 = vec3(dot(c3, t1) / a, dot(c3, t2) / a, dot(c3, r));
        float e = abs(dot(area_edge_sum(c0, c1, c2, c3, n), n)) * 0.5;  // irradiance / radiance
        // the specular lobe clipped to its own axis' hemisphere only (not also the surface's)
        float f = abs(area_edge_sum(q0, q1, q2, q3, vec3(0.0, 0.0, 1.0)).z) / (2.0 * BRDF_PI);
        lobes.base += (diffuse * e + spec_albedo * f) * radiance;
    }
}
#endif
#endif
