// KHR_materials_iridescence: reflectance of a thin dielectric film over the base (Belcour &
// Barla 2017, "A Practical Extension to Microfacet Theory for the Modeling of Varying
// Iridescence"): the Airy sum of the film's first two interference orders, integrated
// against the CIE colour-matching functions by their Gaussian fit, in linear Rec. 709.
#ifndef IRIDESCENCE_GLSL
#define IRIDESCENCE_GLSL

const float FILM_PI = 3.14159265358979;
const mat3 XYZ_TO_REC709 = mat3(3.2404542, -0.9692660, 0.0556434,
                                -1.5371385, 1.8760108, -0.2040259,
                                -0.4985314, 0.0415560, 1.0572252);

float f0_of_ior(float n_t, float n_i) {
    float r = (n_t - n_i) / (n_t + n_i);
    return r * r;
}

vec3 ior_of_f0(vec3 f0) {
    vec3 s = sqrt(clamp(f0, 0.0, 0.9999));
    return (1.0 + s) / (1.0 - s);
}

// The interference term of order m for an optical path difference `opd` (nm) and phase
// shift, per Rec. 709 channel (the colour-matching functions as Gaussians in phase space).
vec3 film_sensitivity(float opd, vec3 shift) {
    float phase = 2.0 * FILM_PI * opd * 1.0e-9;
    vec3 val = vec3(5.4856e-13, 4.4201e-13, 5.2481e-13);
    vec3 pos = vec3(1.6810e+06, 1.7953e+06, 2.2084e+06);
    vec3 var = vec3(4.3278e+09, 9.3046e+09, 6.6121e+09);
    vec3 xyz = val * sqrt(2.0 * FILM_PI * var) * cos(pos * phase + shift) * exp(-phase * phase * var);
    xyz.x += 9.7470e-14 * sqrt(2.0 * FILM_PI * 4.5282e+09) * cos(2.2399e+06 * phase + shift.x)
           * exp(-4.5282e+09 * phase * phase);
    return XYZ_TO_REC709 * (xyz / 1.0685e-7);
}

// Reflectance at incidence cosine `cos1` (from air) of a film of index `film_ior` and
// `thickness` nm over a base of normal-incidence reflectance `base_f0`. Interfaces use
// Schlick from their own F0, as the rest of the raster path.
vec3 thin_film_fresnel(float cos1, float film_ior, float thickness, vec3 base_f0) {
    // a vanishing film fades to no film (the index blends to air's below 30 nm)
    float n2 = mix(1.0, film_ior, smoothstep(0.0, 30.0, thickness));
    float sin2_sq = (1.0 - cos1 * cos1) / (n2 * n2);
    float cos2_sq = 1.0 - sin2_sq;
    if (cos2_sq < 0.0) return vec3(1.0);  // total internal reflection in the film
    float cos2 = sqrt(cos2_sq);
    // air -> film
    float r12 = f0_of_ior(n2, 1.0);
    float R12 = r12 + (1.0 - r12) * pow(1.0 - cos1, 5.0);
    float T121 = 1.0 - R12;
    float phi12 = n2 < 1.0 ? FILM_PI : 0.0;
    float phi21 = FILM_PI - phi12;
    // film -> base
    vec3 n3 = ior_of_f0(base_f0);
    vec3 r23 = (n3 - n2) / (n3 + n2);
    r23 *= r23;
    vec3 R23 = r23 + (1.0 - r23) * pow(1.0 - cos2, 5.0);
    vec3 phi23 = vec3(n3.x < n2 ? FILM_PI : 0.0, n3.y < n2 ? FILM_PI : 0.0, n3.z < n2 ? FILM_PI : 0.0);
    float opd = 2.0 * n2 * thickness * cos2;
    vec3 phi = vec3(phi21) + phi23;
    vec3 R123 = clamp(R12 * R23, 1e-5, 0.9999);
    vec3 r123 = sqrt(R123);
    vec3 Rs = T121 * T121 * R23 / (1.0 - R123);
    vec3 I = R12 + Rs;           // order 0: incoherent sum
    vec3 Cm = Rs - T121;
    for (int k = 1; k <= 2; ++k) {
        Cm *= r123;
        I += Cm * 2.0 * film_sensitivity(float(k) * opd, float(k) * phi);
    }
    return clamp(I, 0.0, 1.0);
}
#endif
