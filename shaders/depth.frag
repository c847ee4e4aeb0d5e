#version 430
// Light shadow maps (renderer/raster/light_shadows.py): depth only, no colour. An alpha-mask
// caster (ALPHA_MASK) discards where its base-colour alpha is under the cutoff, as the main
// pass does, so light passes its cut-outs. SHADOW_TINT_PASS: the tint atlas's pass.
#ifdef ALPHA_MASK
#include "textures.glsl"
uniform vec4 u_base_color;
uniform float u_alpha_cutoff;
#ifdef HAS_COLORS
in vec4 v_color;
#endif
#endif

#ifdef SHADOW_TINT_PASS
// A blend / transmissive caster: what it lets through, and its depth (blended by MIN).
uniform vec3 u_tint;
out vec4 f_tint;
#endif

void main() {
#ifdef ALPHA_MASK
    float alpha = u_base_color.a;
#ifdef HAS_BASE_COLOR_MAP
    alpha *= SAMPLE_MAP(base_color, BASE_COLOR_UV).a;
#endif
#ifdef HAS_COLORS
    alpha *= v_color.a;
#endif
    if (alpha < u_alpha_cutoff) discard;
#endif
#ifdef SHADOW_TINT_PASS
    f_tint = vec4(u_tint, gl_FragCoord.z);
#endif
}
