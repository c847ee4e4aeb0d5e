#version 430
// Front faces of transmissive materials (renderer/refraction.py), the paper's split
//   f_r = kd f_lambert + kr f_refraction + ks f_cook,  kd + kr + ks = 1:
// metallic m takes the split-sum reflection; of the dielectric rest, exact Fresnel F at the
// entry reflects, (1 - F) transmission refracts and (1 - F)(1 - transmission) is Lambert.
// The refracted ray: `single` samples the environment with the first refraction; WYMAN
// estimates the exit point (Wyman 2005, paper 4.2.2) from the back-face textures and the
// baked interior vector, refracts out through the back-face normal there. SCREEN_OPAQUE:
// rays that reach opaque geometry drawn before take its colour (screen-space march).
#include "material_info.glsl"
#include "ibl.glsl"
#include "punctual.glsl"
#include "refraction.glsl"

uniform vec3 u_camera_position;
uniform mat4 u_view_proj;
uniform vec2 u_viewport;
uniform float u_ior;
uniform float u_transmission;
uniform vec3 u_sigma;            // Beer-Lambert absorption per scene unit (KHR_materials_volume)
uniform float u_thickness;       // path length without baked interior vectors
#ifdef HAS_INTERIOR
in vec3 v_interior;              // world-space vertex->exit vector (pbr.vert)
#endif
#ifndef EXIT_REFINE
#define EXIT_REFINE 0
#endif
#ifdef WYMAN
uniform sampler2D u_back_position;  // xyz world position, w roughness
uniform sampler2D u_back_normal;    // xyz outward normal, w coverage
#endif
#ifdef SCREEN_OPAQUE
uniform sampler2D u_opaque_color;   // opaque geometry drawn before, premultiplied linear
uniform sampler2D u_opaque_depth;
uniform vec2 u_near_far;
uniform vec3 u_camera_forward;
uniform float u_trace_length;
#endif
#ifdef DEBUG_VIEW
uniform float u_debug_scale;        // exit distance shown as D x scale
#endif
out vec4 f_color;

ivec2 texel_of(vec2 uv) {
    return clamp(ivec2(uv * u_viewport), ivec2(0), ivec2(u_viewport) - 1);
}

bool project(vec3 p, out vec2 uv) {
    vec4 clip = u_view_proj * vec4(p, 1.0);
    if (clip.w <= 1e-6) return false;
    uv = clip.xy / clip.w * 0.5 + 0.5;
    return true;
}

#ifdef WYMAN
bool covered(vec2 uv) {
    return all(greaterThanEqual(uv, vec2(0.0))) && all(lessThanEqual(uv, vec2(1.0)))
        && texelFetch(u_back_normal, texel_of(uv), 0).w > 0.5;
}

// The back face seen at uv; where uv misses the object (an exit estimate just outside the
// silhouette), the last covered texel on the segment from this fragment's uv0 (bisection),
// so the exit takes the silhouette's normal rather than none.
bool back_face(vec2 uv0, vec2 uv, out vec4 pos, out vec3 n) {
    if (!covered(uv)) {
        if (!covered(uv0)) return false;
        vec2 lo = uv0, hi = uv;
        for (int i = 0; i < 8; ++i) {
            vec2 mid = 0.5 * (lo + hi);
            if (covered(mid)) lo = mid; else hi = mid;
        }
        uv = lo;
    }
    pos = texelFetch(u_back_position, texel_of(uv), 0);
    // Bilinear over covered texels only (w is coverage): the nearest texel's normal alone
    // cost 0.05 of relative error on the IOR 1.5 sphere.
    vec4 nl = texture(u_back_normal, uv);
    n = normalize(nl.xyz / max(nl.w, 1e-6));
    return true;
}

// Refine the exit distance t along p + r t against the back faces: the point belongs on the
// back surface seen through its own pixel. Each step moves t by the gap between the back
// surface's and the point's distance from the camera (a Newton step along the view ray),
// kept inside a bracket: behind a back face or off the object is too far, in front of it
// too near. Starts from Wyman's estimate; EXIT_REFINE 0 is the paper's method unchanged.
float refine_exit(vec3 p, vec3 r, float t) {
    float lo = 0.0, hi = 1e30;
    for (int i = 0; i < EXIT_REFINE; ++i) {
        vec3 q = p + r * t;
        vec2 uv;
        float next;
        vec4 nl;
        if (project(q, uv) && all(greaterThanEqual(uv, vec2(0.0))) && all(lessThanEqual(uv, vec2(1.0)))
                && (nl = texture(u_back_normal, uv)).w > 0.5) {
            vec3 b = texture(u_back_position, uv).xyz / nl.w;
            vec3 ray = normalize(q - u_camera_position);
            float gap = dot(b - u_camera_position, ray) - dot(q - u_camera_position, ray);
            if (gap > 0.0) lo = t; else hi = t;
            float rate = dot(r, ray);  // how fast t moves the point along the view ray
            next = rate > 0.05 ? t + gap / rate : -1.0;
        } else {
            hi = t;
            next = -1.0;
        }
        t = (next >= lo && next <= hi) ? next : (hi < 1e30 ? 0.5 * (lo + hi) : 2.0 * t);
    }
    return t;
}
#endif

#ifdef SCREEN_OPAQUE
float view_depth(float d) {  // depth buffer value -> distance along the view axis
    float n = u_near_far.x, f = u_near_far.y, z = d * 2.0 - 1.0;
    return 2.0 * n * f / (f + n - z * (f - n));
}

// March along the ray; the first point that lands just behind opaque geometry drawn at its
// pixel takes that geometry's colour.
bool trace_opaque(vec3 origin, vec3 dir, float len, out vec3 color) {
    const int STEPS = 24;
    float step_len = len / float(STEPS);
    for (int i = 1; i <= STEPS; ++i) {
        vec3 q = origin + dir * (step_len * float(i));
        vec2 uv;
        if (!project(q, uv) || any(lessThan(uv, vec2(0.0))) || any(greaterThan(uv, vec2(1.0))))
            return false;
        float depth = texelFetch(u_opaque_depth, texel_of(uv), 0).r;
        if (depth >= 1.0) continue;
        float behind = dot(q - u_camera_position, u_camera_forward) - view_depth(depth);
        if (behind > 0.0 && behind < 2.0 * step_len) {
            color = texelFetch(u_opaque_color, texel_of(uv), 0).rgb;
            return true;
        }
    }
    return false;
}
#endif

// Radiance arriving along a ray that leaves the object at `origin`, from environment mip `lod`.
vec3 outside_radiance(vec3 origin, vec3 dir, float lod) {
#ifdef SCREEN_OPAQUE
    vec3 c;
    if (trace_opaque(origin, dir, u_trace_length, c)) return c;
#endif
    return textureLod(u_env, dir, lod).rgb;
}

void main() {
    vec3 v = normalize(u_camera_position - v_world);
    MaterialInfo m = material_info(v);
    vec3 n = m.n;
    // Interpolated normals can face away at the silhouette: bend them to grazing.
    float nv = dot(n, v);
    if (nv < 1e-3) n = normalize(n + v * (1e-3 - nv));
    float cos_i = dot(n, v);
    vec3 d = -v;
    float eta = 1.0 / u_ior;
    vec3 r1;
    refract_ray(d, n, eta, r1);           // TIR on entry only for IOR < 1, where F = 1
    float F = fresnel_dielectric(cos_i, eta);
#ifdef HAS_INTERIOR
    float d_interior = length(v_interior);  // transformed: non-uniform scale holds (4.2.3.2)
#else
    float d_interior = u_thickness;
#endif
    float roughness = m.roughness;
    float path = d_interior;
    bool tir = false;
    vec3 through;
#ifdef WYMAN
    vec2 uv0 = gl_FragCoord.xy / u_viewport;
    vec4 back0 = texelFetch(u_back_position, ivec2(gl_FragCoord.xy), 0);
    vec4 nback0 = texelFetch(u_back_normal, ivec2(gl_FragCoord.xy), 0);
    float d_view = nback0.w > 0.5 ? distance(back0.xyz, v_world) : d_interior;
#ifndef HAS_INTERIOR
    d_interior = d_view;  // no baked vectors (a mesh previewed as glass): D_d alone
#endif
    float D = exit_distance(cos_i, dot(r1, -n), eta, d_view, d_interior);
#if EXIT_REFINE > 0
    D = refine_exit(v_world, r1, D);
#endif
    path = D;
    vec3 p_exit = v_world + r1 * D;
    vec3 origin = p_exit, dir = r1;
    vec2 uv;
    vec4 bpos;
    vec3 n2;
    bool inside_hit = false;
    float exit_F = 0.0;     // exit Fresnel: the internally reflected share reads the
    vec3 exit_refl = r1;    // environment along its direction (as a 2-bounce ray tracer)
#ifdef SCREEN_OPAQUE
    inside_hit = trace_opaque(v_world, r1, D, through);  // opaque parts inside the volume
#endif
    if (!inside_hit && project(p_exit, uv) && back_face(uv0, uv, bpos, n2)) {
        roughness = sqrt(roughness * roughness + bpos.w * bpos.w);
        vec3 r2;
        if (refract_ray(r1, -n2, u_ior, r2)) {
            dir = r2;
            exit_F = fresnel_dielectric(dot(r1, n2), u_ior);
            exit_refl = reflect(r1, n2);
        } else {
            tir = true;
#ifdef TIR_REFLECT
            // Reflect internally and estimate a second exit one more chord D away (exact for a
            // sphere). Heading back toward the camera it leaves through a front face, whose
            // normal is taken as the back face's mirrored across the view ray (a sphere's is).
            vec3 r_in = reflect(r1, n2);
            vec3 p2 = p_exit + r_in * D;
            dir = r_in;
            origin = p2;
            path += D;
            vec4 bpos2;
            vec3 n3;
            if (project(p2, uv) && back_face(uv0, uv, bpos2, n3)) {
                vec3 ray = normalize(p2 - u_camera_position);
                if (dot(r_in, ray) < 0.0) n3 = n3 - 2.0 * dot(n3, ray) * ray;
                vec3 r3;
                if (refract_ray(r_in, -n3, u_ior, r3)) dir = r3;
            }
#else
            dir = r1;  // the paper's fallback: the first refraction alone
#endif
        }
    }
    if (!inside_hit) through = outside_radiance(origin, dir, roughness_to_lod(roughness));
    through = (1.0 - exit_F) * through + exit_F * textureLod(u_env, exit_refl, roughness_to_lod(roughness)).rgb;
#else
    through = outside_radiance(v_world, r1, roughness_to_lod(roughness));
#endif
    vec3 refracted = through * beer_lambert(u_sigma, path) * m.base_color.rgb;

    float dielectric = 1.0 - m.metallic;
    vec2 ab = texture(u_brdf_lut, vec2(cos_i, m.roughness)).rg;
    vec3 ks = m.metallic * (m.base_color.rgb * ab.x + ab.y) + vec3(dielectric * F);
    float kr = dielectric * (1.0 - F) * u_transmission;
    float kd = dielectric * (1.0 - F) * (1.0 - u_transmission);
    vec3 reflected = env_radiance(reflect(d, n), m.roughness);
    vec3 color = m.emissive + (ks * reflected + kd * m.base_color.rgb * env_diffuse(n)) * m.occlusion
               + kr * refracted;
#if LIGHT_COUNT > 0
    float f0 = (u_ior - 1.0) / (u_ior + 1.0);
    m.f0 = mix(vec3(f0 * f0), m.base_color.rgb, m.metallic);
    m.diffuse_color *= 1.0 - u_transmission;
    m.n = n;
    color += punctual(m, v, v_world);
#endif
#if defined(DEBUG_VIEW) && defined(WYMAN)
#if DEBUG_VIEW == 1
    color = nback0.w > 0.5 ? nback0.xyz * 0.5 + 0.5 : vec3(0.0);  // paper Fig. 5
#elif DEBUG_VIEW == 2
    if (tir) color = vec3(1.0, 0.0, 0.0);                          // paper Fig. 6
#elif DEBUG_VIEW == 3
    color = vec3(D * u_debug_scale);
#endif
#endif
    f_color = vec4(color, 1.0);
}
