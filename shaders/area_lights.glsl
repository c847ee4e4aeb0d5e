// Emissive polygons as area lights (core.area_lights), unshadowed. Compiled in only when the
// asset has some (AREA_LIGHT_COUNT > 0: no emitters leaves the program as it was).
// Diffuse: the exact irradiance of a uniform Lambertian polygon, sum over its edges of the
// angle they subtend times the edge plane's normal (Lambert's form factor), after clipping
// the polygon to the surface's horizon. Specular: a linearly transformed cosine (Heitz 2016)
// with an analytic, not fitted, matrix: the clamped cosine about the lobe's dominant
// direction, squeezed by 2 alpha across it (that matches GGX's peak and half width at normal
// view for small alpha), scaled by the lobe's directional albedo. Its integral over the whole
// sphere is that albedo, so a light filling the view gives what the split sum gives.
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

const int AREA_MAX_CORNERS = 8;  // a quad clipped by two planes has at most 6

// Sutherland-Hodgman against the half space dot(p, axis) >= 0, in place.
int area_clip(inout vec3 p[AREA_MAX_CORNERS], int count, vec3 axis) {
    vec3 o[AREA_MAX_CORNERS];
    int k = 0;
    for (int i = 0; i < count; ++i) {
        vec3 a = p[i], b = p[(i + 1) % count];
        float da = dot(a, axis), db = dot(b, axis);
        if (da >= 0.0 && k < AREA_MAX_CORNERS) o[k++] = a;
        if ((da >= 0.0) != (db >= 0.0) && k < AREA_MAX_CORNERS) o[k++] = mix(a, b, da / (da - db));
    }
    for (int i = 0; i < k; ++i) p[i] = o[i];
    return k;
}

vec3 area_edge(vec3 a, vec3 b) {  // a, b unit
    vec3 c = cross(a, b);
    float s = length(c);
    return s > 1e-7 ? c * (atan(s, dot(a, b)) / s) : vec3(0.0);
}

// Sum over the edges of the angle each subtends times its plane's unit normal; its dot with
// a direction z is 2 pi x the form factor about z (for a polygon above z's horizon).
vec3 area_edge_sum(vec3 p[AREA_MAX_CORNERS], int count) {
    vec3 sum = vec3(0.0);
    vec3 a = normalize(p[0]);
    for (int i = 0; i < count; ++i) {
        vec3 b = normalize(p[(i + 1) % count]);
        sum += area_edge(a, b);
        a = b;
    }
    return sum;
}

// area_edge_sum of an unclipped quad, without the arrays (slow to index on a CPU rasteriser).
vec3 area_quad_sum(vec3 p0, vec3 p1, vec3 p2, vec3 p3) {
    p0 = normalize(p0); p1 = normalize(p1); p2 = normalize(p2); p3 = normalize(p3);
    return area_edge(p0, p1) + area_edge(p1, p2) + area_edge(p2, p3) + area_edge(p3, p0);
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
        float e, f;
        if (all(greaterThan(h, vec4(0.0))) && min(min(q0.z, q1.z), min(q2.z, q3.z)) > 0.0) {
            // wholly above both horizons (most lights, most pixels): no clipping
            e = abs(dot(area_quad_sum(c0, c1, c2, c3), n)) * 0.5;
            f = abs(area_quad_sum(q0, q1, q2, q3).z) / (2.0 * BRDF_PI);
        } else {
            vec3 p[AREA_MAX_CORNERS];
            p[0] = c0; p[1] = c1; p[2] = c2; p[3] = c3;
            int count = area_clip(p, 4, n);
            if (count < 3) continue;
            e = abs(dot(area_edge_sum(p, count), n)) * 0.5;  // irradiance / radiance
            vec3 q[AREA_MAX_CORNERS];
            for (int k = 0; k < count; ++k) {
                vec3 x = p[k];
                q[k] = vec3(dot(x, t1) / a, dot(x, t2) / a, dot(x, r));
            }
            int qc = area_clip(q, count, vec3(0.0, 0.0, 1.0));
            f = qc < 3 ? 0.0 : abs(area_edge_sum(q, qc).z) / (2.0 * BRDF_PI);
        }
        lobes.base += (diffuse * e + spec_albedo * f) * radiance;
    }
}
#endif
#endif
