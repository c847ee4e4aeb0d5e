#version 430
// Opaque / mask / blend PBR: emissive + image-based lighting + punctual and emissive area lights, linear
// radiance out (premultiplied by alpha through the blend state for BLEND materials, or in the
// shader for OPACITY_PREMULTIPLIED ones).
#include "material_info.glsl"
#include "ibl.glsl"
#include "punctual.glsl"
#include "area_lights.glsl"

uniform vec3 u_camera_position;
out vec4 f_color;

void main() {
    vec3 v = normalize(u_camera_position - v_world);
    MaterialInfo m = material_info(v);
#ifdef ALPHA_MASK
    if (m.base_color.a < u_alpha_cutoff) discard;
#endif
#ifdef OPACITY_PREMULTIPLIED
    // UsdPreviewSurface as Storm blends it: the output is premultiplied (blend ONE, 1 - alpha)
    // and opacity fades only the diffuse share, so a clear sheet keeps its highlights
    m.diffuse_color *= m.base_color.a;
#endif
#ifdef UNLIT
    vec3 color = m.base_color.rgb;
#ifdef OPACITY_PREMULTIPLIED
    color *= m.base_color.a;
#endif
#else
    Lobes lobes = ibl_lobes(m, v);
#if LIGHT_COUNT > 0
    punctual(m, v, v_world, lobes);
#endif
#if AREA_LIGHT_COUNT > 0
    area_lights(m, v, v_world, lobes);
#endif
    vec3 color = compose(m, v, lobes, u_brdf_lut);
#endif
    color = max(color, vec3(0.0));  // radiance is never negative (float rounding in the lobes' sums)
#ifdef ALPHA_BLEND
    f_color = vec4(color, m.base_color.a);
#else
    f_color = vec4(color, 1.0);
#endif
}
