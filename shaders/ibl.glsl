// Image-based lighting: split-sum specular (prefiltered cube mip chosen from roughness, times
// the BRDF LUT's scale and bias for F0, Karis 2013) and Lambert diffuse from the bake's
// irradiance cube (the exact cosine integral of the cube's texels, core/irradiance.py). MULTISCATTER (on by default) adds
// Fdez-Aguera's (2019) energy compensation, which restores what single scattering loses on
// rough surfaces (spread like the single-scattered lobe: ibl()). Dielectrics layer as glTF
// writes it: the specular lobe over the diffuse base, the base weighted by 1 - the lobe's
// directional albedo (energy-conserving).
#ifndef IBL_GLSL
#define IBL_GLSL
#include "brdf.glsl"
#include "lobes.glsl"

uniform samplerCube u_env;
uniform sampler2D u_brdf_lut;   // x = N.V, y = roughness -> (scale, bias, sheen albedo)
uniform float u_env_max_lod;
uniform samplerCube u_irradiance;  // E / pi, bilinear and seamless across faces

// pipeline.environment.roughness_to_lod: the GGX bake stores roughness m/(levels-1) at mip m,
// and the paper's baseline maps LOD = roughness x max LOD; both are this linear map.
float roughness_to_lod(float roughness) {
    return roughness * u_env_max_lod;
}

// ENV_ROTATED: the environment turned about +Y (RenderOptions.env_rotation); world
// directions are turned back into the panorama's frame before every lookup.
#ifdef ENV_ROTATED
uniform mat3 u_env_rotation;  // world -> environment
#define ENV_DIR(d) (u_env_rotation * (d))
#else
#define ENV_DIR(d) (d)
#endif

vec3 env_radiance(vec3 dir, float roughness) {
    return textureLod(u_env, ENV_DIR(dir), roughness_to_lod(roughness)).rgb;
}

// Where a GGX lobe's reflected light comes from: toward the normal as the lobe widens (its
// peak leaves the mirror direction; Lagarde & de Rousiers 2014's dominant direction,
// mix(n, r, s(sqrt(s) + alpha)) with s = 1 - alpha); the split-sum's mips were prefiltered
// about this axis.
vec3 specular_dir(vec3 n, vec3 v, float roughness) {
    float alpha = roughness * roughness, gloss = 1.0 - alpha;
    return normalize(mix(n, reflect(-v, n), gloss * (sqrt(gloss) + alpha)));
}

// Cosine-weighted mean radiance about n (irradiance / pi): what a white Lambertian surface
// reflects.
vec3 env_diffuse(vec3 n) {
    return texture(u_irradiance, ENV_DIR(n)).rgb;
}

// The split-sum's horizon (core/horizon.py): the share h of the prefiltered kernel about d
// that lies under the plane of ng reads the ground through the surface, where the true lobe
// is cut there. P = (1 - h) S + h G solved for the part above, S, with G the cosine-weighted
// mean of the lower hemisphere (the irradiance about -ng): exact under a uniform ground.
#ifdef HORIZON_TABLE
float horizon_below(float s, float roughness) {
    const float table[] = HORIZON_TABLE;
    const int n = 17;  // core.horizon.ROWS = COLUMNS
    float x = clamp(s, 0.0, 1.0) * float(n - 1), y = clamp(roughness, 0.0, 1.0) * float(n - 1);
    int i = min(int(x), n - 2), j = min(int(y), n - 2);
    float fx = x - float(i), fy = y - float(j);
    float a = mix(table[i * n + j], table[(i + 1) * n + j], fx);
    float b = mix(table[i * n + j + 1], table[(i + 1) * n + j + 1], fx);
    return mix(a, b, fy);
}
#endif

vec3 env_radiance_above(vec3 dir, float roughness, vec3 ng) {
    vec3 p = env_radiance(dir, roughness);
#ifdef HORIZON_TABLE
    float h = horizon_below(dot(dir, ng), roughness);
    if (h > 1e-4) p = max((p - h * env_diffuse(-ng)) / (1.0 - h), vec3(0.0));
#endif
    return p;
}

// Directional albedo of the specular lobe for F0 and F90 (KHR_materials_specular) at N.V:
// single scattering FssEss (the split-sum LUT) and, with MULTISCATTER, the multiply
// scattered FmsEms (Fdez-Aguera 2019, eq. 10-12); 1 - FssEss - FmsEms is what reaches a
// dielectric's diffuse base.
void specular_albedo(vec3 f0, float f90, float NdotV, float roughness, out vec3 FssEss,
                     out vec3 FmsEms) {
    vec2 ab = texture(u_brdf_lut, vec2(NdotV, roughness)).rg;
    FssEss = f0 * ab.x + f90 * ab.y;
#ifdef MULTISCATTER
    float Ems = max(1.0 - (ab.x + ab.y), 0.0);  // the LUT is filtered: never above 1
    vec3 Favg = f0 + (1.0 - f0) / 21.0;
    FmsEms = Ems * FssEss * Favg / (1.0 - Ems * Favg);
#else
    FmsEms = vec3(0.0);
#endif
}

// Baked visibility (pipeline.occlusion) applied to the image light only (core.lobes holds the
// same arithmetic for the ray tracer and the tests). Diffuse: the visible fraction of the
// cosine-weighted hemisphere, lifted by what interreflection brings back on bright albedos
// (Jimenez et al. 2016's multi-bounce fit): the references trace those bounces. Specular:
// Lagarde & de Rousiers 2014's estimate of the share of the lobe the occluded cone blocks,
// from the visibility, N.V and alpha (a narrow lobe at normal view keeps more of its sky),
// lifted by the same multi-bounce fit on F0.
vec3 ao_multibounce(float ao, vec3 albedo) {
    vec3 a = 2.0404 * albedo - 0.3324;
    vec3 b = -4.7951 * albedo + 0.6417;
    vec3 c = 2.7552 * albedo + 0.6903;
    return max(vec3(ao), ((ao * a + b) * ao + c) * ao);
}

float specular_occlusion(float NdotV, float ao, float roughness) {
    float alpha = roughness * roughness;
    return clamp(pow(NdotV + ao, exp2(-16.0 * alpha - 1.0)) - 1.0 + ao, 0.0, 1.0);
}

#ifdef MATERIAL_INFO_GLSL  // the lookups above also serve the background pass
#ifdef MATERIAL_ANISOTROPY
// The prefiltered light of the anisotropic lobe (alpha_t = mix(alpha, 1, strength^2) along the
// grain t, alpha_b = alpha across it): the lobe's microfacet slopes along t, spread by the
// one-axis marginal of anisotropic GGX (1 / (2 a (1 + (x/a)^2)^1.5), its quantiles below),
// each tap an isotropic lookup at the narrow width (widened to the taps' spacing, so they
// blend). A normal bent across the grain (Filament's and the Sample Viewer's shortcut) sends
// the whole lobe one way: on a ring whose grain runs around it, every point mirrored the same
// patch of sky, where the lobe (the path tracer's, sampled) smears each point's reflection
// along the grain.
const int ANISO_TAPS = 8;
vec3 env_radiance_anisotropic(MaterialInfo m, vec3 v) {
    float ab = max(m.roughness * m.roughness, 1e-4);
    float at = mix(ab, 1.0, m.anisotropy * m.anisotropy);
    float spread = sqrt(max(at * at - ab * ab, 0.0));  // what the narrow lookup lacks along t
    float tap_alpha = max(ab, spread / float(ANISO_TAPS));
    float tap_roughness = min(sqrt(tap_alpha), 1.0);
    vec3 sum = vec3(0.0);
    for (int i = 0; i < ANISO_TAPS; ++i) {
        float u = (float(i) + 0.5) / float(ANISO_TAPS) * 2.0 - 1.0;  // 2 F - 1 of the quantile
        float x = spread * u * inversesqrt(1.0 - u * u);
        vec3 h = normalize(m.n + x * m.anisotropy_t);
        vec3 r = reflect(-v, h);
        // below the horizon the facet is masked: fold the tap back above it
        r -= 2.0 * min(dot(r, m.n), 0.0) * m.n;
        sum += env_radiance(r, tap_roughness);
    }
    return sum / float(ANISO_TAPS);
}
#endif

#ifdef SHOW_BACK_FACES
// Storm's (A, B) at N.E = 0 for roughness 0..1 (core/storm.py), read linearly
vec2 storm_back_ab(float roughness) {
    const vec2 table[] = STORM_BACK_TABLE;
    float x = clamp(roughness, 0.0, 1.0) * float(table.length() - 1);
    int i = min(int(x), table.length() - 2);
    return mix(table[i], table[i + 1], x - float(i));
}
#endif

vec3 ibl(MaterialInfo m, vec3 v) {
    vec3 n = m.n;
#ifdef SHOW_BACK_FACES
    if (!gl_FrontFacing) {
        // a single-sided USD surface seen from behind, lit as Storm lights it (core/storm.py):
        // its normal faces away, N.E clamps to 0; specular (F0 A + B) of Storm's table there,
        // diffuse (1 - F0) about that normal
        vec2 ab = storm_back_ab(m.roughness);
        vec3 spec = (m.f0 * ab.x + ab.y) * env_radiance(reflect(-v, n), m.roughness);
        vec3 occ_d = min(vec3(m.occlusion), ao_multibounce(m.ao, m.diffuse_color));
        return spec * m.occlusion + m.diffuse_color * (1.0 - m.f0) * env_diffuse(n) * occ_d;
    }
#endif
    float NdotV = clamp(dot(n, v), 1e-4, 1.0);
    vec3 FssEss, FmsEms;
    specular_albedo(m.f0, m.f90, NdotV, m.roughness, FssEss, FmsEms);
#ifdef MATERIAL_ANISOTROPY
    vec3 radiance = env_radiance_anisotropic(m, v);
#else
    vec3 radiance = env_radiance_above(specular_dir(n, v, m.roughness), m.roughness, m.ng);
#endif
    // about the bent normal: the blocked directions' sky is not counted (m.bent = n unbaked)
    vec3 irradiance = env_diffuse(m.bent);
    vec3 kD = m.diffuse_color * (1.0 - FssEss - FmsEms);
    // The occlusion texture and the baked visibility usually record the same geometry (a
    // texture is most often an AO bake): the darker of the two, not their product.
    vec3 diffuse_occ = min(vec3(m.occlusion), ao_multibounce(m.ao, m.diffuse_color));
    // the specular share too gets back what the blocked directions reflect: on a metal
    // (F0 bright) the neighbouring surfaces it sees are lit (Filament does the same)
    // (the bent normal's visible cone against the lobe's, Oat & Sander's cap overlap, was
    // measured in its place and not kept: bench/RESULTS.md "horizon10")
    vec3 specular_occ = min(vec3(m.occlusion),
                            ao_multibounce(specular_occlusion(NdotV, m.ao, m.roughness), m.f0));
    // The multiply scattered share leaves along the lobe, as the punctual lights' ms_scale, the
    // tree tracer's albedo and the path tracer's scaled lobe put it (a metal's second bounce
    // between microfacets stays near the mirror direction), not over the cosine hemisphere:
    // on a rough metal the irradiance brought the sky onto side faces that reflect the horizon.
    return (FssEss + FmsEms) * radiance * specular_occ + kD * irradiance * diffuse_occ;
}

#ifdef MATERIAL_SHEEN
// Sheen under image light: its albedo (LUT blue) times the cosine-weighted mean radiance.
// The Charlie lobe spreads over the whole hemisphere toward grazing at every sheen roughness,
// so the irradiance stands for it better than a GGX mip along the mirror direction; under a
// uniform environment it is exact.
vec3 ibl_sheen(MaterialInfo m, vec3 v) {
    float NdotV = clamp(dot(m.n, v), 1e-4, 1.0);
    float e = texture(u_brdf_lut, vec2(NdotV, m.sheen_roughness)).b;
    return m.sheen_color * e * env_diffuse(m.bent) * min(m.occlusion, m.ao);
}
#endif

#ifdef MATERIAL_CLEARCOAT
// The coat's split-sum specular about its own normal (F0 0.04, F90 1).
vec3 ibl_clearcoat(MaterialInfo m, vec3 v) {
    vec3 n = m.clearcoat_n;
    float NdotV = clamp(dot(n, v), 1e-4, 1.0);
    vec2 ab = texture(u_brdf_lut, vec2(NdotV, m.clearcoat_roughness)).rg;
    return (CLEARCOAT_F0 * ab.x + ab.y)
         * env_radiance_above(specular_dir(n, v, m.clearcoat_roughness), m.clearcoat_roughness, m.ng)
         * min(m.occlusion, specular_occlusion(NdotV, m.ao, m.clearcoat_roughness));
}
#endif

#ifdef MATERIAL_DIFFUSE_TRANSMISSION
// Light through the surface from the far side: the back hemisphere's cosine-weighted mean,
// less what the front's specular reflects (as the reflected diffuse).
vec3 ibl_diffuse_transmission(MaterialInfo m, vec3 v) {
    float NdotV = clamp(dot(m.n, v), 1e-4, 1.0);
    vec2 ab = texture(u_brdf_lut, vec2(NdotV, m.roughness)).rg;
    return m.diffuse_transmission * (1.0 - (m.f0 * ab.x + m.f90 * ab.y)) * env_diffuse(-m.n)
         * m.occlusion;
}
#endif

// Every lobe's image-based light.
Lobes ibl_lobes(MaterialInfo m, vec3 v) {
    Lobes l = no_lobes();
    l.base = ibl(m, v);
#ifdef MATERIAL_DIFFUSE_TRANSMISSION
    l.base += ibl_diffuse_transmission(m, v);
#endif
#ifdef MATERIAL_SHEEN
    l.sheen = ibl_sheen(m, v);
#endif
#ifdef MATERIAL_CLEARCOAT
    l.clearcoat = ibl_clearcoat(m, v);
#endif
    return l;
}
#endif
#endif
