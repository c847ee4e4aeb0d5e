#version 430
// Front faces of transmissive materials (renderer/refraction.py), the paper's split
//   f_r = kd f_lambert + kr f_refraction + ks f_cook,  kd + kr + ks = 1:
// metallic m takes the split-sum reflection; of the dielectric rest, exact Fresnel F at the
// entry reflects, (1 - F) transmission refracts and (1 - F)(1 - transmission) is Lambert.
// The refracted ray: `single` samples the environment with the first refraction; WYMAN
// estimates the exit point (Wyman 2005, paper 4.2.2) from the back-face textures and the
// baked interior vector, refines it onto the back surface, refracts out through the
// back-face normal there; TIR_REFLECT reflects a totally internally reflected ray and
// marches it between the front- and back-face layers to a second exit. SCREEN_OPAQUE:
// rays that reach opaque geometry drawn before take its colour (screen-space march).
// THIN_WALLED (glTF: no volume or thickness 0): straight through, no absorption; THIN_BACK:
// the nearest back faces of the thin items (backface.frag), the far sheet of a closed one.
#include "material_info.glsl"
#include "ibl.glsl"
#include "punctual.glsl"
#include "refraction.glsl"

uniform vec3 u_camera_position;
uniform mat4 u_view_proj;
uniform vec2 u_viewport;
uniform float u_transmission;
uniform vec3 u_sigma;            // Beer-Lambert absorption per scene unit (KHR_materials_volume)
uniform float u_thickness;       // path length without baked interior vectors
uniform float u_trace_length;
#if defined(WYMAN) || defined(THIN_BACK)
uniform sampler2D u_back_tint;   // sqrt(base colour), w coverage, of the back faces (backface.frag)
#endif
#if defined(THIN_BACK) && !defined(WYMAN)
uniform sampler2D u_back_position;  // xyz world position, w roughness
#endif
uniform float u_pixel_angle;     // a pixel's height over its distance from the camera
#ifdef MATERIAL_DISPERSION
uniform float u_dispersion;      // half the IOR spread between the red and blue channels
#endif    // the scene's bounding diameter: how far rays are marched
#ifdef HAS_INTERIOR
in vec3 v_interior;              // world-space vertex->exit vector (pbr.vert)
#endif
// Scale of a rough lobe's angular width over GGX alpha times the deviation a microfacet
// tilt causes (|ior - 1| through an interface, 2 on reflection): fitted to the path tracer's
// blur of stripes behind rough slabs (tests/test_rough_transmission.py; 1.0 left every slab
// sharper than the tracer's, 1.2 matches thin and solid within 0.04 at IOR 1.33, 1.5 and 2).
#define BLUR_SCALE 1.2
#ifndef EXIT_REFINE
#define EXIT_REFINE 0
#endif
#ifdef WYMAN
uniform sampler2D u_back_position;  // xyz world position, w roughness
uniform sampler2D u_back_normal;    // xyz outward normal, w coverage
#ifdef TIR_REFLECT
uniform sampler2D u_front_position; // the same for the nearest front faces
uniform sampler2D u_front_normal;
#endif
#endif
#ifdef SCREEN_OPAQUE
uniform sampler2D u_opaque_color;   // opaque geometry drawn before, premultiplied linear
uniform sampler2D u_opaque_depth;
uniform vec2 u_near_far;
uniform vec3 u_camera_forward;
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
// A surface layer: world position + roughness and outward normal + coverage textures of the
// nearest back faces (side +1) or, for TIR_REFLECT, the nearest front faces (side -1).
bool covered(sampler2D normals, vec2 uv) {
    return all(greaterThanEqual(uv, vec2(0.0))) && all(lessThanEqual(uv, vec2(1.0)))
        && texelFetch(normals, texel_of(uv), 0).w > 0.5;
}

// The surface seen at uv; where uv misses the object (an exit estimate just outside the
// silhouette), the last covered texel on the segment from this fragment's uv0 (bisection),
// so the exit takes the silhouette's normal rather than none.
bool surface_at(sampler2D positions, sampler2D normals, vec2 uv0, inout vec2 uv, out vec4 pos,
                out vec3 n) {
    if (!covered(normals, uv)) {
        if (!covered(normals, uv0)) return false;
        vec2 lo = uv0, hi = uv;
        for (int i = 0; i < 8; ++i) {
            vec2 mid = 0.5 * (lo + hi);
            if (covered(normals, mid)) lo = mid; else hi = mid;
        }
        uv = lo;
    }
    pos = texelFetch(positions, texel_of(uv), 0);
    // Bilinear over covered texels only (w is coverage): the nearest texel's normal alone
    // cost 0.05 of relative error on the IOR 1.5 sphere.
    vec4 nl = texture(normals, uv);
    n = normalize(nl.xyz / max(nl.w, 1e-6));
    return true;
}

// How far beyond q (side +1) or before it (side -1) the surface seen through q's pixel lies,
// along that pixel's view ray: > 0 while q is still inside. False off the object or screen.
bool surface_gap(sampler2D positions, sampler2D normals, float side, vec3 q, out float gap,
                 out vec3 ray) {
    vec2 uv;
    if (!project(q, uv) || any(lessThan(uv, vec2(0.0))) || any(greaterThan(uv, vec2(1.0))))
        return false;
    vec4 nl = texture(normals, uv);
    if (nl.w <= 0.5) return false;
    vec3 b = texture(positions, uv).xyz / nl.w;
    ray = normalize(q - u_camera_position);
    gap = side * dot(b - q, ray);
    return true;
}

// Refine the exit distance t along p + r t: the exit point belongs on the surface seen
// through its own pixel. Each step moves t by the gap (a Newton step along the view ray),
// kept inside a bracket: past the surface or off the object is too far, short of it too
// near. Starts from Wyman's estimate; EXIT_REFINE 0 keeps the paper's estimate. Returns
// whether t ends on the surface the camera sees (within 2%): where the true exit is hidden
// behind another face of the layer (concave shapes, a teapot's base) it does not.
bool refine_exit(sampler2D positions, sampler2D normals, float side, vec3 p, vec3 r,
                 inout float t) {
    float lo = 0.0, hi = 1e30, gap;
    vec3 ray;
    for (int i = 0; i < EXIT_REFINE; ++i) {
        float next = -1.0;
        if (surface_gap(positions, normals, side, p + r * t, gap, ray)) {
            if (gap > 0.0) lo = t; else hi = t;
            float rate = side * dot(r, ray);  // how fast t moves the point toward the surface
            if (rate > 0.05) next = t + gap / rate;
        } else {
            hi = t;
        }
        t = (next >= lo && next <= hi) ? next : (hi < 1e30 ? 0.5 * (lo + hi) : 2.0 * t);
    }
    return surface_gap(positions, normals, side, p + r * t, gap, ray)
        && abs(gap) < 0.02 * t + PIXEL_TOL * u_pixel_angle * distance(p + r * t, u_camera_position);
}

#ifdef TIR_REFLECT
// How deep q lies inside the volume between the nearest front and back faces at its pixel
// (> 0 inside); `back` says which layer is the nearer one to leave by.
float inside_depth(vec3 q, out bool back) {
    float gb, gf;
    vec3 ray;
    bool cb = surface_gap(u_back_position, u_back_normal, 1.0, q, gb, ray);
    bool cf = surface_gap(u_front_position, u_front_normal, -1.0, q, gf, ray);
    if (!cb || !cf) {
        back = cb;
        return -1.0;
    }
    back = gb < gf;
    return min(gb, gf);
}

// March a ray reflected inside from p until it leaves the volume (16 steps over the bounding
// diameter, then bisection); t and the outward normal of the layer it left by.
bool second_exit(vec3 p, vec3 r, vec2 uv0, out float t, out vec3 n) {
    const int STEPS = 16;
    float step_len = u_trace_length / float(STEPS);
    float lo = 0.0, hi = -1.0;
    bool back = true;
    for (int i = 1; i <= STEPS && hi < 0.0; ++i) {
        float ti = step_len * float(i);
        if (inside_depth(p + r * ti, back) > 0.0) lo = ti; else hi = ti;
    }
    if (hi < 0.0) return false;
    for (int i = 0; i < 6; ++i) {
        float mid = 0.5 * (lo + hi);
        if (inside_depth(p + r * mid, back) > 0.0) lo = mid; else hi = mid;
    }
    t = 0.5 * (lo + hi);
    inside_depth(p + r * lo, back);
    vec2 uv;
    vec4 pos;
    return project(p + r * t, uv) && (back
        ? surface_at(u_back_position, u_back_normal, uv0, uv, pos, n)
        : surface_at(u_front_position, u_front_normal, uv0, uv, pos, n));
}
#endif
#endif

// What a rough interface lets through and reflects of the light meeting it, (T, R): the means
// over GGX's visible normals m of (1 - F(v.m)) G1(t) and F(v.m) G1(r) (TIR on m: F = 1), Walter
// et al.'s rough dielectric with the separable Smith masking of the way out, the expectation
// of the ray tracer's sampled weights (renderer/methods/optics.py sample_rough_dielectric;
// Mitsuba's roughdielectric). A fixed stratified quadrature, so the frame stays noise-free.
// cos_i: the incident direction's cosine to the macro normal on its side; eta = n_incident /
// n_transmitted. Smooth: (1 - F, F) exactly. MULTISCATTER: single scattering, E = T + R, and
// glass_ms puts back what bounces between the facets, as the tracers do
// (path_bsdf.glass_albedo, glass_ms). Without it the reflection keeps the smooth Fresnel F,
// so what passes is capped at 1 - F (at grazing views the facets turned toward the viewer
// would let more through).
float smith_g1(float c, float alpha) {
    float c2 = clamp(c * c, 1e-12, 1.0);
    return 2.0 / (1.0 + sqrt(1.0 + alpha * alpha * (1.0 - c2) / c2));
}

vec3 visible_normal(vec3 v, float alpha, vec2 u) {  // Heitz 2018, local frame (n = +z)
    vec3 vh = normalize(vec3(alpha * v.x, alpha * v.y, v.z));
    float lensq = vh.x * vh.x + vh.y * vh.y;
    vec3 t1 = lensq > 0.0 ? vec3(-vh.y, vh.x, 0.0) * inversesqrt(lensq) : vec3(1.0, 0.0, 0.0);
    vec3 t2 = cross(vh, t1);
    float r = sqrt(u.x), phi = 6.28318530717959 * u.y;
    float p1 = r * cos(phi), p2 = r * sin(phi);
    float s = 0.5 * (1.0 + vh.z);
    p2 = (1.0 - s) * sqrt(max(1.0 - p1 * p1, 0.0)) + s * p2;
    vec3 nh = p1 * t1 + p2 * t2 + sqrt(max(1.0 - p1 * p1 - p2 * p2, 0.0)) * vh;
    return normalize(vec3(alpha * nh.x, alpha * nh.y, max(nh.z, 1e-7)));
}

vec2 rough_interface(float cos_i, float alpha, float eta) {
    cos_i = clamp(abs(cos_i), 1e-4, 1.0);
    float smooth_f = fresnel_dielectric(cos_i, eta);
    if (alpha <= 1e-4) return vec2(1.0 - smooth_f, smooth_f);
    const int N = 6;
    vec3 v = vec3(sqrt(1.0 - cos_i * cos_i), 0.0, cos_i);
    vec2 sum = vec2(0.0);
    for (int i = 0; i < N; ++i) {
        for (int j = 0; j < N; ++j) {
            vec3 m = visible_normal(v, alpha, (vec2(i, j) + 0.5) / float(N));
            float f = fresnel_dielectric(dot(v, m), eta);
            vec3 r = reflect(-v, m), t;
            if (refract_ray(-v, m, eta, t) && t.z < 0.0)
                sum.x += (1.0 - f) * smith_g1(-t.z, alpha);
            if (r.z > 0.0 && dot(r, m) > 0.0)
                sum.y += f * smith_g1(r.z, alpha);
        }
    }
    sum /= float(N * N);
#ifdef MULTISCATTER
    return sum;
#else
    return vec2(min(sum.x, 1.0 - smooth_f), smooth_f);
#endif
}

// The scale of both shares (T, R) of an interface whose crossing tints by `tint`: light that
// bounces between the facets, losing 1 - E of what is left each time and crossing again,
// leaves in the end (path_bsdf.glass_ms: 1 / E for white glass, so nothing is lost).
vec3 glass_ms(vec2 tr, vec3 tint) {
#ifdef MULTISCATTER
    return 1.0 / (1.0 - (1.0 - max(tr.x + tr.y, 0.05)) * tint);  // path_bsdf.GLASS_E_MIN
#else
    return vec3(1.0);
#endif
}

// Angular radius of a lobe of `variance`: a reflection lobe of GGX alpha spreads directions
// by about 2 alpha (a microfacet tilt bends a reflected ray twice over).
float lobe_spread(float variance) {
    return 2.0 * sqrt(variance);
}

// The spread of two rough interfaces crossed in turn. GGX slopes are heavy-tailed, nearer a
// Cauchy (whose widths add) than a Gaussian (in quadrature): adding in quadrature left a rough
// box 0.13 sharper than the tracer's at roughness 0.3, adding matches it.
float add_spread(float a, float b) {
    return a + b;
}

#ifdef SCREEN_OPAQUE
float view_depth(float d) {  // depth buffer value -> distance along the view axis
    float n = u_near_far.x, f = u_near_far.y, z = d * 2.0 - 1.0;
    return 2.0 * n * f / (f + n - z * (f - n));
}

// Mip of the opaque copy that averages a refracted lobe of angular radius `spread` (radians,
// small-angle) after `dist` scene units: the footprint's diameter in pixels, projected at q.
float footprint_lod(vec3 q, vec3 dir, float dist, float spread) {
    if (spread <= 0.0) return 0.0;
    vec3 side = normalize(cross(dir, abs(dir.y) < 0.99 ? vec3(0.0, 1.0, 0.0) : vec3(1.0, 0.0, 0.0)));
    vec2 a, b;
    if (!project(q, a) || !project(q + side * (dist * spread), b)) return 0.0;
    return log2(max(2.0 * length((b - a) * u_viewport), 1.0));
}

// What a rough lobe of scale `spread` sees of the opaque copy around uv, `dist` beyond where it
// left the object. A GGX lobe is heavy-tailed (its slopes' radial CDF is s^2 / (alpha^2 + s^2):
// half within alpha, a fifth beyond 2 alpha), which one box mip of the lobe's width misses: a
// sharp core that stays sharp too long, then all detail gone at once. So four mips, one per
// shell of that CDF (radii and weights LOBE_SHELL_*), the tail blurring the most.
#ifndef LOBE_SHELLS
#define LOBE_SHELLS 4
#endif
const float LOBE_SHELL_R[4] = float[4](0.35, 0.75, 1.5, 3.5);
const float LOBE_SHELL_W[4] = float[4](0.2, 0.3, 0.3, 0.2);
vec3 lobe_fetch(vec3 q, vec2 uv, vec3 dir, float dist, float spread) {
    if (spread <= 0.0) return texelFetch(u_opaque_color, texel_of(uv), 0).rgb;
    vec3 c = vec3(0.0);
    for (int k = 0; k < LOBE_SHELLS; ++k) {
        float lod = footprint_lod(q, dir, dist, spread * LOBE_SHELL_R[k]);
        c += LOBE_SHELL_W[k] * (lod > 0.0 ? textureLod(u_opaque_color, uv, lod).rgb
                                          : texelFetch(u_opaque_color, texel_of(uv), 0).rgb);
    }
    return c;
}

// March along the ray; the first point that lands just behind opaque geometry drawn at its
// pixel takes that geometry's colour: the texel itself for a smooth interface, or for a lobe
// of angular radius `spread` the copy's mip that covers the lobe's footprint there (the
// blurred view of what lies behind rough glass; renderer.refraction builds the mips).
bool trace_opaque(vec3 origin, vec3 dir, float len, float spread, out vec3 color) {
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
            color = lobe_fetch(q, uv, dir, step_len * float(i), spread);
            return true;
        }
    }
    return false;
}
#endif

// Radiance arriving along a ray that leaves the object at `origin`, through a lobe of
// `variance` (alpha^2 units of the reflection lobes the environment mips hold).
vec3 outside_radiance(vec3 origin, vec3 dir, float variance) {
#ifdef SCREEN_OPAQUE
    vec3 c;
    if (trace_opaque(origin, dir, u_trace_length, lobe_spread(variance), c)) return c;
#endif
    return textureLod(u_env, ENV_DIR(dir), roughness_to_lod(pow(variance, 0.25))).rgb;
}

// Radiance refracted through the object for one IOR: into the front face at n, through the
// volume (WYMAN: out of the estimated back face; else the first refraction alone) to the
// opaque layer or the environment. `path` is the length inside, `D` Wyman's exit distance,
// `tir` whether the exit reflected totally. Sets g_exit_tint to sqrt(base colour) at the
// back face it leaves by, where it found one (negative otherwise).
vec3 g_exit_tint = vec3(-1.0);
vec3 transmitted(vec3 v, vec3 n, float ior, float roughness, float d_interior, out float path,
                 out float D, out bool tir) {
    vec3 d = -v;
    float cos_i = dot(n, v);
    float eta = 1.0 / ior;
    vec3 r1;
    refract_ray(d, n, eta, r1);           // TIR on entry only for IOR < 1, where F = 1
    // Blur of the refracted lookup as a variance in alpha^2 units: a microfacet tilt turns the
    // ray that leaves into air by |ior - 1| (inside, by |1 - eta|, which the flat exit then
    // magnifies by ior; the tracer's thin sheet has one rough face and a flat one), where it
    // turns a reflected one by 2, so each interface's lobe is that much narrower than the
    // reflection lobe the mips were prefiltered for. Looked up at roughness variance^(1/4).
    float alpha = roughness * roughness;
    float variance = pow(alpha * abs(ior - 1.0) * 0.5 * BLUR_SCALE, 2.0);
    float variance_reflected = variance;
    tir = false;
#ifdef THIN_WALLED
    // glTF's thin-walled case (no volume, or thickness 0): a sheet with no inside, so the ray
    // leaves unbent where it entered (the Khronos viewer's refraction over a length of 0) and
    // nothing is absorbed; the roughness still blurs what is seen through it.
    path = 0.0;
    D = 0.0;
    return outside_radiance(v_world, d, variance);
#endif
    path = d_interior;
    D = d_interior;
    vec3 through;
#ifdef WYMAN
    vec2 uv0 = gl_FragCoord.xy / u_viewport;
    vec4 back0 = texelFetch(u_back_position, ivec2(gl_FragCoord.xy), 0);
    vec4 nback0 = texelFetch(u_back_normal, ivec2(gl_FragCoord.xy), 0);
    float d_view = nback0.w > 0.5 ? distance(back0.xyz, v_world) : d_interior;
#ifndef HAS_INTERIOR
    d_interior = d_view;  // no baked vectors (a mesh previewed as glass): D_d alone
#endif
    D = exit_distance(cos_i, dot(r1, -n), eta, d_view, d_interior);
    bool on_surface = refine_exit(u_back_position, u_back_normal, 1.0, v_world, r1, D);
    path = D;
    vec3 p_exit = v_world + r1 * D;
    vec3 origin = p_exit, dir = r1;
    vec2 uv;
    vec4 bpos;
    vec3 n2;
    bool inside_hit = false;
    vec3 exit_T = vec3(1.0);  // what the exit interface lets through (rough_interface)
    vec3 exit_R = vec3(0.0);  // what it reflects back inside: that leaves by the front face,
    vec3 front_R = vec3(0.0); // which reflects front_R of it back again (a slab's series, below);
    vec3 exit_refl = r1;      // it reads the environment along its direction
#ifdef SCREEN_OPAQUE
    inside_hit = trace_opaque(v_world, r1, D, lobe_spread(variance), through);  // opaque parts inside
#endif
    if (!inside_hit && project(p_exit, uv)
            && surface_at(u_back_position, u_back_normal, uv0, uv, bpos, n2)) {
        float alpha_back = bpos.w * bpos.w;
        variance_reflected = variance + alpha_back * alpha_back;
        variance = pow(0.5 * add_spread(lobe_spread(variance), alpha_back * abs(1.0 - ior) * BLUR_SCALE), 2.0);
        // Cycles' convention: each crossing of a volume tints by sqrt(base) of its texel.
        // After a TIR bounce the first back-face texel stands in for wherever it leaves.
        // (bilinear over covered texels only, w being coverage, as the normals)
        vec4 exit_tint = textureLod(u_back_tint, uv, 0.0);
        g_exit_tint = exit_tint.rgb / max(exit_tint.w, 1e-6);
        vec3 r2;
        if (refract_ray(r1, -n2, ior, r2)) {
            dir = r2;
            vec2 back_tr = rough_interface(dot(r1, n2), alpha_back, ior);
            exit_T = back_tr.x * glass_ms(back_tr, g_exit_tint);
            exit_R = back_tr.y * glass_ms(back_tr, g_exit_tint);
            exit_refl = reflect(r1, n2);
            vec2 front_tr = rough_interface(dot(exit_refl, n), alpha, ior);
            front_R = front_tr.y * glass_ms(front_tr, g_exit_tint);
        } else {
            tir = true;
#ifdef TIR_REFLECT
            // Reflect internally and march the reflected ray until it leaves the volume
            // between the front and back layers (it may leave through either); the layer it
            // crossed gives the normal to refract out by. Where the first exit estimate was
            // off the surface (its TIR untrustworthy) or no exit is found: the paper's fallback.
            vec3 r_in = reflect(r1, n2);
            float D2;
            vec3 n3, r3;
            dir = r1;
            if (on_surface && second_exit(p_exit, r_in, uv0, D2, n3)
                    && refract_ray(r_in, -n3, ior, r3)) {
                dir = r3;
                origin = p_exit + r_in * D2;
                path += D2;
            } else {
                path += D;  // the light still crossed the volume again before it left
            }
#else
            dir = r1;  // the paper's fallback: the first refraction alone
#endif
        }
    }
    if (!inside_hit) through = outside_radiance(origin, dir, variance);
    // Light bounces between the two faces: of what reaches the exit, exit_T leaves there and
    // exit_R goes back to the front, which lets 1 - front_R out (toward the viewer's side of
    // the sky) and returns front_R, and so on: the sums over the bounces. A rough interface
    // reflects much from inside (facets tilted past the critical angle): a rough pane shows
    // the sky in front of it through itself, tinted, as the tracers' bounces do.
    vec3 bounces = 1.0 / max(1.0 - exit_R * front_R, 1e-3);
    through = bounces * (exit_T * through + exit_R * (1.0 - front_R)
            * textureLod(u_env, ENV_DIR(exit_refl), roughness_to_lod(pow(variance_reflected, 0.25))).rgb);
#else
    through = outside_radiance(v_world, r1, variance);
#endif
    return through;
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
    float transmission = u_transmission;
#ifdef HAS_TRANSMISSION_MAP
    transmission *= SAMPLE_MAP(transmission, TRANSMISSION_UV).r;
#endif
    float thickness = u_thickness;
#ifdef HAS_THICKNESS_MAP
    thickness *= SAMPLE_MAP(thickness, THICKNESS_UV).g;
#endif
    float F = fresnel_dielectric(cos_i, 1.0 / u_ior);
#ifdef HAS_INTERIOR
    float d_interior = length(v_interior);  // transformed: non-uniform scale holds (4.2.3.2)
#else
    float d_interior = thickness;
#endif
    float D;
    bool tir;
#ifdef MATERIAL_DISPERSION
    // KHR_materials_dispersion: each channel refracts with its own IOR (the spread about the
    // IOR given by the Abbe number, u_dispersion = half the spread), and keeps its own path
    vec3 path, through;
    float path_c;
    bool tir_c;
    through.r = transmitted(v, n, u_ior - u_dispersion, m.roughness, d_interior, path_c, D, tir_c).r;
    path.r = path_c;
    through.b = transmitted(v, n, u_ior + u_dispersion, m.roughness, d_interior, path_c, D, tir_c).b;
    path.b = path_c;
    through.g = transmitted(v, n, u_ior, m.roughness, d_interior, path_c, D, tir).g;
    path.g = path_c;
#else
    float path;
    vec3 through = transmitted(v, n, u_ior, m.roughness, d_interior, path, D, tir);
#endif
    // Transmission tint: base colour once through a thin sheet (glTF); through a volume,
    // sqrt(base) at the entry times sqrt(base) at the exit (Cycles' Principled BSDF), which
    // is base for a solid of one colour; where no exit face was found, the entry's again.
    vec3 tint = m.base_color.rgb;
#if defined(THIN_WALLED) && defined(THIN_BACK)
    // A closed sheet's far side lies straight behind (the ray goes on unbent): a second sheet,
    // base colour again (the tracers'). A back face where this fragment is, is this sheet
    // seen from behind (double-sided): not a second one.
    vec4 far_tint = texelFetch(u_back_tint, ivec2(gl_FragCoord.xy), 0);
    vec3 far_p = texelFetch(u_back_position, ivec2(gl_FragCoord.xy), 0).xyz;
    if (far_tint.w > 0.5 && distance(far_p, v_world) > 1e-4 * u_trace_length)
        tint *= far_tint.rgb * far_tint.rgb;
#endif
#ifndef THIN_WALLED
    vec3 sqrt_in = sqrt(max(m.base_color.rgb, vec3(0.0)));
    tint = sqrt_in * (g_exit_tint.r >= 0.0 ? g_exit_tint : sqrt_in);
#endif
    vec3 refracted = through * exp(-u_sigma * max(path, 0.0)) * tint;

    float dielectric = 1.0 - m.metallic;
    vec3 FssEss, FmsEms;  // the metal lobe, energy-compensated as in ibl()
    specular_albedo(m.base_color.rgb, 1.0, cos_i, m.roughness, FssEss, FmsEms);
    vec3 Fv = vec3(F);
#ifdef MATERIAL_IRIDESCENCE
    Fv = mix(Fv, m.iridescence_fresnel, m.iridescence);  // the film reflects, the rest enters
#endif
    // the rough interface's shares of the smooth one's (iridescence tints the smooth share)
    vec2 front = rough_interface(cos_i, m.roughness * m.roughness, 1.0 / u_ior);
#ifdef THIN_WALLED
    vec3 front_ms = glass_ms(front, m.base_color.rgb);
#else
    vec3 front_ms = glass_ms(front, sqrt(max(m.base_color.rgb, vec3(0.0))));
#endif
    vec3 rough_ratio = front.x * front_ms / max(1.0 - F, 1e-6);
    vec3 reflect_ratio = F > 1e-6 ? front.y * front_ms / F : vec3(1.0);
    vec3 ks = m.metallic * FssEss + dielectric * Fv * mix(vec3(1.0), reflect_ratio, transmission);
    vec3 kr = dielectric * (1.0 - Fv) * transmission * rough_ratio;
    vec3 kd = dielectric * (1.0 - Fv) * (1.0 - transmission);
    vec3 reflected = env_radiance(reflect(d, n), m.roughness);
#ifdef SCREEN_OPAQUE
    // The reflection sees the asset's opaque parts before the sky (AttenuationTest's cube tops
    // mirror the backdrop behind them): the same screen-space march as the refracted ray, a
    // microfacet tilt turning a reflected ray twice over.
    vec3 seen;
    if (trace_opaque(v_world, reflect(d, n), u_trace_length, 2.0 * m.roughness * m.roughness * BLUR_SCALE, seen))
        reflected = seen;
#endif
    Lobes lobes = ibl_lobes(m, v);  // sheen and clearcoat over the glass, as on opaque
    // what the debug view shows: the throughput, share x tint x volume attenuation
    lobes.transmission = kr * exp(-u_sigma * max(path, 0.0)) * tint;
    lobes.base = ((ks + m.metallic * FmsEms) * reflected + kd * m.base_color.rgb * env_diffuse(n))
               * m.occlusion
               + kr * refracted;
#if LIGHT_COUNT > 0
    float f0 = (u_ior - 1.0) / (u_ior + 1.0);
    m.f0 = mix(vec3(f0 * f0), m.base_color.rgb, m.metallic);
    m.diffuse_color *= 1.0 - transmission;
    m.n = n;
    punctual(m, v, v_world, lobes);
#endif
    vec3 color = compose(m, v, lobes, u_brdf_lut);
#if defined(DEBUG_VIEW) && defined(WYMAN)
#if DEBUG_VIEW == 1
    vec4 nback0 = texelFetch(u_back_normal, ivec2(gl_FragCoord.xy), 0);
    color = nback0.w > 0.5 ? nback0.xyz * 0.5 + 0.5 : vec3(0.0);  // paper Fig. 5
#elif DEBUG_VIEW == 2
    if (tir) color = vec3(1.0, 0.0, 0.0);                          // paper Fig. 6
#elif DEBUG_VIEW == 3
    color = vec3(D * u_debug_scale);
#endif
#endif
    f_color = vec4(max(color, vec3(0.0)), 1.0);  // radiance is never negative
}
