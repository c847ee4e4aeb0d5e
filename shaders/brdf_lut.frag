#version 430
// Split-sum BRDF LUT (Karis 2013): texel (column i, row j) holds, for N.V = (i + 0.5) / N and
// roughness = (j + 0.5) / N, the scale and bias to F0 of the specular GGX BRDF's directional
// albedo: integral of f * cos = F0 * scale + bias. Importance-sampled GGX with a Hammersley set.
//
// Blue: the directional albedo of the sheen lobe (shaders/brdf.glsl, Charlie D with its
// visibility, sheen colour 1) at sheen roughness (j + 0.5) / N, by a midpoint rule over the
// hemisphere (SHEEN_THETA x SHEEN_PHI cells, uniform in cos theta; the lobe is symmetric in
// phi about the view plane): KHR_materials_sheen's albedo-scaling term for the base beneath.
// Clamped to 1: Estevez & Kulla's fitted visibility is not energy conserving at grazing views
// on smooth sheen (the integral reaches 2.2 at N.V < 0.06, roughness < 0.1), and reflecting
// more than arrives would make 1 - E negative under the base.
//
// G is brdf.glsl's G_smith (height-correlated Smith GGX), as the lights use it.
#include "brdf.glsl"
const float PI = 3.14159265358979;
const int SHEEN_THETA = 48;
const int SHEEN_PHI = 24;

uniform int u_size;
out vec4 f_color;

float radical_inverse(uint bits) {
    bits = (bits << 16u) | (bits >> 16u);
    bits = ((bits & 0x55555555u) << 1u) | ((bits & 0xAAAAAAAAu) >> 1u);
    bits = ((bits & 0x33333333u) << 2u) | ((bits & 0xCCCCCCCCu) >> 2u);
    bits = ((bits & 0x0F0F0F0Fu) << 4u) | ((bits & 0xF0F0F0F0u) >> 4u);
    bits = ((bits & 0x00FF00FFu) << 8u) | ((bits & 0xFF00FF00u) >> 8u);
    return float(bits) * 2.3283064365386963e-10;
}

void main() {
    float n_dot_v = gl_FragCoord.x / float(u_size);
    float roughness = gl_FragCoord.y / float(u_size);
    float alpha = roughness * roughness;
    vec3 v = vec3(sqrt(1.0 - n_dot_v * n_dot_v), 0.0, n_dot_v);  // N = +z
    vec2 sum = vec2(0.0);
    for (uint i = 0u; i < uint(SAMPLES); ++i) {
        // GGX half vector: cos^2(theta_h) = (1 - xi) / (1 + (alpha^2 - 1) xi).
        float xi = radical_inverse(i);
        float phi = 2.0 * PI * (float(i) + 0.5) / float(SAMPLES);
        float cos_h = sqrt((1.0 - xi) / (1.0 + (alpha * alpha - 1.0) * xi));
        float sin_h = sqrt(max(1.0 - cos_h * cos_h, 0.0));
        vec3 h = vec3(sin_h * cos(phi), sin_h * sin(phi), cos_h);
        float v_dot_h = dot(v, h);
        vec3 l = 2.0 * v_dot_h * h - v;
        if (l.z > 0.0 && v_dot_h > 0.0) {
            // estimator f * cos / pdf with pdf = D * N.H / (4 V.H): G * V.H / (N.H * N.V)
            float g = G_smith(n_dot_v, l.z, alpha);
            float g_vis = g * v_dot_h / (cos_h * n_dot_v);
            float fc = pow(1.0 - v_dot_h, 5.0);
            sum += vec2(1.0 - fc, fc) * g_vis;
        }
    }
    float sheen = 0.0;
    for (int i = 0; i < SHEEN_THETA; ++i) {
        float cos_l = (float(i) + 0.5) / float(SHEEN_THETA);
        float sin_l = sqrt(1.0 - cos_l * cos_l);
        for (int j = 0; j < SHEEN_PHI; ++j) {
            float phi = PI * (float(j) + 0.5) / float(SHEEN_PHI);
            vec3 l = vec3(sin_l * cos(phi), sin_l * sin(phi), cos_l);
            vec3 h = normalize(v + l);
            sheen += D_charlie(roughness, h.z) * V_sheen(n_dot_v, cos_l, roughness) * cos_l;
        }
    }
    sheen *= 2.0 * PI / float(SHEEN_THETA * SHEEN_PHI);  // d(cos) d(phi) over 2 x [0, pi]
    // A lobe reflects at most what arrives: the quadrature overshoots 1 by up to 2e-4 where
    // the lobe is near a mirror, and 1 - E_ss < 0 would make the multiscatter term negative.
    vec2 e = sum / float(SAMPLES);
    e /= max(e.x + e.y, 1.0);
    f_color = vec4(e, min(sheen, 1.0), 1.0);
}
