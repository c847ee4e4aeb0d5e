// Cook-Torrance microfacet BRDF with the paper's terms (section 4.1):
// GGX / Trowbridge-Reitz D with alpha = roughness^2, height-correlated Smith G, Schlick F.
#ifndef BRDF_GLSL
#define BRDF_GLSL
const float BRDF_PI = 3.14159265358979;

vec3 F_schlick(vec3 f0, float VdotH) {
    float m = 1.0 - VdotH;
    float m2 = m * m;
    return f0 + (1.0 - f0) * (m2 * m2 * m);
}

// Schlick with a grazing reflectance f90 below 1 (KHR_materials_specular).
vec3 F_schlick(vec3 f0, float f90, float VdotH) {
    float m = 1.0 - VdotH;
    float m2 = m * m;
    return f0 + (f90 - f0) * (m2 * m2 * m);
}

float D_ggx(float NdotH, float alpha) {
    float a2 = alpha * alpha;
    float d = NdotH * NdotH * (a2 - 1.0) + 1.0;
    return a2 / (BRDF_PI * d * d);
}

// Height-correlated Smith masking-shadowing of GGX (Heitz 2014), G = 1 / (1 + L(v) + L(l)):
// the glTF 2.0 specification's V_GGX, as the Sample Viewer, Filament, three.js and Cycles
// use it. It masks less than the separable G1(v) G1(l) (Mitsuba's roughconductor; Schlick's
// k = alpha / 2 fit of it was used before): at roughness 1 and N.V 0.42 the directional
// albedo's F0 scale is 0.48, not 0.44, the specular sheen on a rough dielectric seen at a low
// angle (Box's top face; docs/textures.md). The split-sum LUT (shaders/brdf_lut.frag)
// integrates this G too, so lights and IBL share it.
float G_smith(float NdotV, float NdotL, float alpha) {
    float a2 = alpha * alpha;
    float lv = NdotL * sqrt(NdotV * NdotV * (1.0 - a2) + a2);
    float ll = NdotV * sqrt(NdotL * NdotL * (1.0 - a2) + a2);
    return 2.0 * NdotV * NdotL / max(lv + ll, 1e-7);
}

// Specular lobe, already divided by 4 N.L N.V; multiply by N.L and the light's radiance.
vec3 brdf_specular(vec3 f0, float alpha, float NdotV, float NdotL, float NdotH, float VdotH) {
    return F_schlick(f0, VdotH) * (D_ggx(NdotH, alpha) * G_smith(NdotV, NdotL, alpha)
                                   / max(4.0 * NdotV * NdotL, 1e-6));
}

vec3 brdf_specular(vec3 f0, float f90, float alpha, float NdotV, float NdotL, float NdotH,
                   float VdotH) {
    return F_schlick(f0, f90, VdotH) * (D_ggx(NdotH, alpha) * G_smith(NdotV, NdotL, alpha)
                                        / max(4.0 * NdotV * NdotL, 1e-6));
}

// Anisotropic GGX (KHR_materials_anisotropy): alpha_t along the grain t, alpha_b across it,
// with the exact height-correlated Smith masking of that distribution (at alpha_t = alpha_b
// it is isotropic GGX with exact Smith rather than the Schlick fit above). Already divided
// by 4 N.L N.V.
float brdf_anisotropic_dv(float at, float ab, vec3 n, vec3 t, vec3 b, vec3 v, vec3 l, vec3 h) {
    float NdotH = dot(n, h), TdotH = dot(t, h), BdotH = dot(b, h);
    float d = TdotH * TdotH / (at * at) + BdotH * BdotH / (ab * ab) + NdotH * NdotH;
    float D = 1.0 / (BRDF_PI * at * ab * d * d);
    float NdotV = max(dot(n, v), 1e-4), NdotL = max(dot(n, l), 1e-4);
    float lv = sqrt(1.0 + (at * at * pow(dot(t, v), 2.0) + ab * ab * pow(dot(b, v), 2.0))
                          / (NdotV * NdotV));
    float ll = sqrt(1.0 + (at * at * pow(dot(t, l), 2.0) + ab * ab * pow(dot(b, l), 2.0))
                          / (NdotL * NdotL));
    float G = 2.0 / (lv + ll);  // 1 / (1 + Lambda_v + Lambda_l), Lambda = (sqrt(..) - 1) / 2
    return D * G / (4.0 * NdotV * NdotL);
}

// Sheen (KHR_materials_sheen): the "Charlie" distribution (Estevez & Kulla 2017) with their
// visibility term. Roughness below SHEEN_MIN_ROUGHNESS is raised to it: the distribution
// collapses onto the tangent plane there and its albedo needs ever more samples to bake
// (shaders/brdf_lut.frag uses the same floor, so lights and IBL agree).
const float SHEEN_MIN_ROUGHNESS = 0.07;

float D_charlie(float sheen_roughness, float NdotH) {
    float alpha = max(sheen_roughness, SHEEN_MIN_ROUGHNESS);
    alpha *= alpha;
    float inv = 1.0 / alpha;
    float sin2 = max(1.0 - NdotH * NdotH, 0.0);
    return (2.0 + inv) * pow(sin2, 0.5 * inv) / (2.0 * BRDF_PI);
}

float sheen_l(float x, float alpha) {
    float t = (1.0 - alpha) * (1.0 - alpha);
    float a = mix(21.5473, 25.3245, t), b = mix(3.82987, 3.32435, t), c = mix(0.19823, 0.16801, t);
    float d = mix(-1.97760, -1.27393, t), e = mix(-4.32054, -4.85967, t);
    return a / (1.0 + b * pow(x, c)) + d * x + e;
}

float sheen_lambda(float cos_theta, float alpha) {
    return cos_theta < 0.5 ? exp(sheen_l(cos_theta, alpha))
                           : exp(2.0 * sheen_l(0.5, alpha) - sheen_l(1.0 - cos_theta, alpha));
}

// Estevez & Kulla's visibility, already divided by 4 N.L N.V.
float V_sheen(float NdotV, float NdotL, float sheen_roughness) {
    float alpha = max(sheen_roughness, SHEEN_MIN_ROUGHNESS);
    alpha *= alpha;
    return clamp(1.0 / ((1.0 + sheen_lambda(NdotV, alpha) + sheen_lambda(NdotL, alpha))
                        * max(4.0 * NdotV * NdotL, 1e-6)), 0.0, 1.0e4);
}

vec3 brdf_sheen(vec3 sheen_color, float sheen_roughness, float NdotV, float NdotL, float NdotH) {
    return sheen_color * D_charlie(sheen_roughness, NdotH) * V_sheen(NdotV, NdotL, sheen_roughness);
}

vec3 brdf_lambert(vec3 diffuse_color) {
    return diffuse_color / BRDF_PI;
}
#endif
