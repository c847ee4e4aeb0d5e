#version 430
// The one pass after the geometry: resolves the MSAA samples, puts the background behind
// the asset, and turns linear radiance into display pixels (exposure, tone mapping, sRGB).
// Doing the background here, once per pixel instead of per sample, and resolving here
// instead of with a blit, is what makes MSAA affordable on a CPU rasteriser.
// BACKGROUND: 0 transparent, 1 colour, 2 environment, 3 the studio gradient. SHADOW 1: the
// ground contact shadow (renderer/shadow.py) darkens the background, never the object.
// OBJECT 0: a region of the frame the object does not reach (renderer.raster.final draws the pass
// in scissored regions, each with only the work its pixels need): no MSAA fetch, coverage 0.
// Outputs: display RGBA8 (straight alpha) and linear RGBA float (premultiplied). OUTPUT 1:
// display alone, 2: linear alone (each at location 0: a thumbnail draws no linear image and
// the linear pass no tone mapping), 3: both (locations 0 and 1).
// renderer/frame.py holds the same tone-mapping arithmetic in numpy.
#include "ibl.glsl"

#ifndef OBJECT
#define OBJECT 1
#endif
#ifndef SUPERSAMPLE
#define SUPERSAMPLE 1
#endif
// ROWS 1 (BACKGROUND 3): the gradient's value per row, linear and display, read from a column
// that this same program drew without ROWS (renderer.raster.final._gradient_rows): the gradient
// depends on the row alone, and reading it costs less than the sRGB arithmetic.
#ifndef ROWS
#define ROWS 0
#endif
#if ROWS
uniform sampler2D u_rows_linear;
uniform sampler2D u_rows_display;
#endif
#if SAMPLES > 1
uniform sampler2DMS u_frame;
#else
uniform sampler2D u_frame;
#endif
#ifdef EDGE
uniform sampler2D u_edge;       // per pixel: step to the neighbour across an edge x its weight
#endif
uniform int u_height;
uniform float u_exposure_scale; // 2^EV
uniform vec3 u_background;      // BACKGROUND 1: sRGB colour
uniform mat3 u_camera_basis;    // BACKGROUND 2: columns right, up, forward (world)
uniform vec2 u_tan_half_fov;    //   x horizontal, y vertical
uniform float u_blur;           //   roughness of the environment mip shown
uniform vec3 u_gradient_top;    // BACKGROUND 3: sRGB colours at the top and bottom rows
uniform vec3 u_gradient_bottom;
uniform sampler2D u_shadow;     // SHADOW 1: blurred top-down shade map
uniform vec4 u_shadow_rect;     //   x0, z0, width, depth it covers on the ground
uniform float u_ground;         //   world y of the ground
uniform float u_shadow_strength;
uniform vec3 u_camera_position;
in vec2 v_ndc;
#ifndef OUTPUT
#define OUTPUT 3
#endif
#if OUTPUT == 1
layout(location = 0) out vec4 f_display;
vec4 f_linear;   // not an output: the compiler drops what only it needs
#elif OUTPUT == 2
layout(location = 0) out vec4 f_linear;
vec4 f_display;
#else
layout(location = 0) out vec4 f_display;
layout(location = 1) out vec4 f_linear;
#endif

vec3 pbr_neutral(vec3 c) {  // Khronos PBR Neutral
    const float start = 0.8 - 0.04;
    const float desat = 0.15;
    float x = min(c.r, min(c.g, c.b));
    float offset = x < 0.08 ? x - 6.25 * x * x : 0.04;
    c -= offset;
    float peak = max(c.r, max(c.g, c.b));
    if (peak < start) return c;
    const float d = 1.0 - start;
    float new_peak = 1.0 - d * d / (peak + d - start);
    c *= new_peak / peak;
    float g = 1.0 - 1.0 / (desat * (peak - new_peak) + 1.0);
    return mix(c, vec3(new_peak), g);
}

vec3 aces_hill(vec3 c) {  // Stephen Hill's RRT+ODT fit, 1/0.6 bias as the glTF Sample Viewer
    const mat3 ACES_IN = mat3(0.59719, 0.07600, 0.02840, 0.35458, 0.90834, 0.13383,
                              0.04823, 0.01566, 0.83777);
    const mat3 ACES_OUT = mat3(1.60475, -0.10208, -0.00327, -0.53108, 1.10813, -0.07276,
                               -0.07367, -0.00605, 1.07602);
    c = ACES_IN * (c / 0.6);
    c = (c * (c + 0.0245786) - 0.000090537) / (c * (0.983729 * c + 0.4329510) + 0.238081);
    return ACES_OUT * c;
}

vec3 srgb_encode(vec3 c) {
    c = clamp(c, 0.0, 1.0);
    return mix(12.92 * c, 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055, step(vec3(0.0031308), c));
}

vec3 display(vec3 c) {
    c = max(c, vec3(0.0)) * u_exposure_scale;
#if TONEMAP == 1
    c = pbr_neutral(c);
#elif TONEMAP == 2
    c = aces_hill(c);
#endif
    return srgb_encode(c);
}

vec3 view_direction() {  // world direction through this pixel (rows flipped, see main)
    return u_camera_basis * vec3(vec2(v_ndc.x, -v_ndc.y) * u_tan_half_fov, 1.0);
}

float ground_shade() {  // 0..1: how much the contact shadow darkens this background pixel
#if SHADOW
    vec3 d = view_direction();
    if (d.y >= 0.0) return 0.0;
    vec3 p = u_camera_position + d * ((u_ground - u_camera_position.y) / d.y);
    vec2 uv = (p.xz - u_shadow_rect.xy) / u_shadow_rect.zw;
    if (any(lessThan(uv, vec2(0.0))) || any(greaterThan(uv, vec2(1.0)))) return 0.0;
    return u_shadow_strength * min(1.0, 1.5 * textureLod(u_shadow, uv, 0.0).r);  // 1.5: darker core
#else
    return 0.0;
#endif
}

vec3 srgb_to_linear(vec3 c) {
    return mix(c / 12.92, pow((c + 0.055) / 1.055, vec3(2.4)), step(vec3(0.04045), c));
}

// COVERAGE_ALPHA: alpha is the object's coverage over any background (the colour still holds
// the background behind it); otherwise only a transparent background has alpha < 1.
#ifdef COVERAGE_ALPHA
#define OUT_ALPHA a
#else
#define OUT_ALPHA 1.0
#endif

void main() {
    // Output row 0 is the image top (what numpy and image files expect), so the source row
    // and the view direction are flipped vertically.
    ivec2 xy = ivec2(gl_FragCoord.x, u_height - 1 - int(gl_FragCoord.y));
#if !OBJECT
    vec4 p = vec4(0.0);
#elif SUPERSAMPLE > 1  // renderer.raster.render.render_supersampled: a box over K x K texels
    vec4 p = vec4(0.0);
    for (int j = 0; j < SUPERSAMPLE; ++j)
        for (int i = 0; i < SUPERSAMPLE; ++i) p += texelFetch(u_frame, xy * SUPERSAMPLE + ivec2(i, j), 0);
    p /= float(SUPERSAMPLE * SUPERSAMPLE);
#elif SAMPLES > 1
    vec4 p = vec4(0.0);
    for (int i = 0; i < SAMPLES; ++i) p += texelFetch(u_frame, xy, i);
    p /= float(SAMPLES);
#elif defined(EDGE)  // renderer.edges: mixed with the neighbour across an edge crossing it
    vec4 p = texelFetch(u_frame, xy, 0);
    vec2 e = texelFetch(u_edge, xy, 0).xy;
    p = mix(p, texelFetch(u_frame, xy + ivec2(sign(e)), 0), abs(e.x) + abs(e.y));
#else
    vec4 p = texelFetch(u_frame, xy, 0);
#endif
    // A NaN from any shader stops here rather than reaching an image.
    if (any(isnan(p)) || any(isinf(p))) p = vec4(0.0);
    float a = clamp(p.a, 0.0, 1.0);
#if BACKGROUND == 2
    vec3 c = p.rgb;
    if (a < 1.0) {  // covered pixels skip the environment lookup
        c += (1.0 - a) * env_radiance(normalize(view_direction()), u_blur);
    }
    f_linear = vec4(c, OUT_ALPHA);
    f_display = vec4(display(c), OUT_ALPHA);
#elif BACKGROUND == 1 || BACKGROUND == 3
#if ROWS
    ivec2 row = ivec2(0, gl_FragCoord.y);
#if !OBJECT && !SHADOW
    f_linear = vec4(texelFetch(u_rows_linear, row, 0).rgb, OUT_ALPHA);
    f_display = vec4(texelFetch(u_rows_display, row, 0).rgb, OUT_ALPHA);
    return;
#endif
    vec3 bg_linear = texelFetch(u_rows_linear, row, 0).rgb;
#else
#if BACKGROUND == 1
    vec3 bg = u_background;
#else
    vec3 bg = mix(u_gradient_bottom, u_gradient_top, 0.5 - 0.5 * v_ndc.y);  // v_ndc.y: -1 at the top row
#endif
    vec3 bg_linear = srgb_to_linear(bg);
#endif
    bg_linear *= (a < 1.0 ? 1.0 - ground_shade() : 1.0);
    f_linear = vec4(p.rgb + (1.0 - a) * bg_linear, OUT_ALPHA);
    // The background shows the colour asked for (not tone-mapped), darkened by the shadow.
#if OBJECT
    f_display = vec4(display(p.rgb / max(a, 1e-6)) * a + srgb_encode(bg_linear) * (1.0 - a), OUT_ALPHA);
#else  // a = 0: the same value, without tone mapping a black that is then weighted by 0
    f_display = vec4(srgb_encode(bg_linear), OUT_ALPHA);
#endif
#else
    // Transparent: the shadow is black with its own alpha, under the object.
    float s = a < 1.0 ? ground_shade() : 0.0;
    float alpha = a + (1.0 - a) * s;
    f_linear = vec4(p.rgb, alpha);
#if OBJECT
    f_display = vec4(display(p.rgb / max(a, 1e-6)) * a / max(alpha, 1e-6), alpha);
#else
    f_display = vec4(vec3(0.0), alpha);
#endif
#endif
}
