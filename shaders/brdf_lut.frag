#version 430
// Split-sum BRDF LUT (Karis 2013): texel (column i, row j) holds, for N.V = (i + 0.5) / N and
// roughness = (j + 0.5) / N, the scale and bias to F0 of the specular GGX BRDF's directional
// albedo: integral of f * cos = F0 * scale + bias. Importance-sampled GGX with a Hammersley set.
//
// Smith-Schlick G with k = alpha / 2: Karis's fit of Schlick's form to the Smith GGX masking
// function for image-based lighting. The paper's k = alpha / pi matches neither Smith GGX nor
// Karis's punctual-light remapping and leaves rough surfaces too bright (too little masking).
const float PI = 3.14159265358979;

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

float g1_schlick(float n_dot_x, float k) {
    return n_dot_x / (n_dot_x * (1.0 - k) + k);
}

void main() {
    float n_dot_v = gl_FragCoord.x / float(u_size);
    float roughness = gl_FragCoord.y / float(u_size);
    float alpha = roughness * roughness;
    float k = alpha * 0.5;
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
            float g = g1_schlick(n_dot_v, k) * g1_schlick(l.z, k);
            float g_vis = g * v_dot_h / (cos_h * n_dot_v);
            float fc = pow(1.0 - v_dot_h, 5.0);
            sum += vec2(1.0 - fc, fc) * g_vis;
        }
    }
    f_color = vec4(sum / float(SAMPLES), 0.0, 1.0);
}
