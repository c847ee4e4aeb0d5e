#version 430
// Ground contact shadow, second step: one direction of a separable Gaussian (13 taps, sigma
// 3 texels of the 32 x 32 map). Texture fetches dominate on a CPU rasteriser, hence the
// small map: the shadow is soft, and the final pass filters it bilinearly.
uniform sampler2D u_src;
uniform vec2 u_step;  // one texel along the blur direction, in uv
in vec2 v_ndc;
out vec4 f_shade;

void main() {
    vec2 uv = v_ndc * 0.5 + 0.5;
    float sum = 0.0, norm = 0.0;
    for (int i = -6; i <= 6; ++i) {
        float w = exp(-float(i * i) / (2.0 * 3.0 * 3.0));
        sum += w * texture(u_src, uv + float(i) * u_step).r;
        norm += w;
    }
    f_shade = vec4(sum / norm, 0.0, 0.0, 1.0);
}
