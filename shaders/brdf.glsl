// Cook-Torrance microfacet BRDF with the paper's terms (section 4.1):
// GGX / Trowbridge-Reitz D with alpha = roughness^2, Smith with Schlick-GGX G, Schlick F.
#ifndef BRDF_GLSL
#define BRDF_GLSL
const float BRDF_PI = 3.14159265358979;

vec3 F_schlick(vec3 f0, float VdotH) {
    float m = 1.0 - VdotH;
    float m2 = m * m;
    return f0 + (1.0 - f0) * (m2 * m2 * m);
}

float D_ggx(float NdotH, float alpha) {
    float a2 = alpha * alpha;
    float d = NdotH * NdotH * (a2 - 1.0) + 1.0;
    return a2 / (BRDF_PI * d * d);
}

// Schlick-GGX G1 with k = alpha / 2. The paper writes k = alpha / pi; the source it cites
// (Karis 2013, "Specular BRDF Reference") gives k = alpha * sqrt(2/pi) as Schlick's fit to
// Beckmann and k = alpha / 2 as the fit to Smith-GGX. Checked against the separable exact
// Smith-GGX G that the reference renderer (Mitsuba's roughconductor) uses, through the
// directional albedo it produces (tests/test_render_physics.py): alpha / 2 is exact at
// roughness 1 and has the smaller worst-case error for roughness >= 0.5 (0.08 vs 0.43 at
// roughness 0.75), where masking matters; alpha / pi is closer on average below roughness
// 0.5 (mean 0.04 vs 0.08, errors at grazing angles). The split-sum LUT
// (shaders/brdf_lut.frag) integrates with alpha / 2 too, so lights and IBL share one G.
float G1_schlick_ggx(float NdotX, float k) {
    return NdotX / (NdotX * (1.0 - k) + k);
}

float G_smith(float NdotV, float NdotL, float alpha) {
    float k = alpha * 0.5;
    return G1_schlick_ggx(NdotV, k) * G1_schlick_ggx(NdotL, k);
}

// Specular lobe, already divided by 4 N.L N.V; multiply by N.L and the light's radiance.
vec3 brdf_specular(vec3 f0, float alpha, float NdotV, float NdotL, float NdotH, float VdotH) {
    return F_schlick(f0, VdotH) * (D_ggx(NdotH, alpha) * G_smith(NdotV, NdotL, alpha)
                                   / max(4.0 * NdotV * NdotL, 1e-6));
}

vec3 brdf_lambert(vec3 diffuse_color) {
    return diffuse_color / BRDF_PI;
}
#endif
