#version 430
// The one place linear radiance becomes display pixels: exposure, tone mapping, sRGB
// encoding, straight alpha, and compositing over a solid background colour in display space.
// renderer/frame.py holds the same arithmetic in numpy.
in vec2 v_ndc;
uniform sampler2D u_linear;     // resolved frame, premultiplied alpha
uniform float u_exposure_scale; // 2^EV
uniform vec4 u_background;      // sRGB colour, a = 1 to composite over it, 0 for none
out vec4 f_color;

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

vec3 srgb_encode(vec3 x) {
    x = clamp(x, 0.0, 1.0);
    return mix(12.92 * x, 1.055 * pow(x, vec3(1.0 / 2.4)) - 0.055, step(vec3(0.0031308), x));
}

void main() {
    vec4 p = texelFetch(u_linear, ivec2(gl_FragCoord.xy), 0);
    float a = clamp(p.a, 0.0, 1.0);
    vec3 c = max(p.rgb / max(a, 1e-6), vec3(0.0)) * u_exposure_scale;
#if TONEMAP == 1
    c = pbr_neutral(c);
#elif TONEMAP == 2
    c = aces_hill(c);
#endif
    vec3 s = srgb_encode(c);
    if (u_background.a > 0.0) {
        s = s * a + u_background.rgb * (1.0 - a);
        a = 1.0;
    }
    f_color = vec4(s, a);
}
