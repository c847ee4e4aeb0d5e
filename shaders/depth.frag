#version 430
// Light shadow maps (renderer/raster/light_shadows.py): depth only, no colour. An alpha-mask
// caster (ALPHA_MASK) discards where its base-colour alpha is under the cutoff, as the main
// pass does, so light passes its cut-outs. SHADOW_TINT_PASS: the tint atlas's pass.
#if defined(ALPHA_MASK) || defined(SHADOW_TINT_COLOUR)
#include "textures.glsl"
uniform vec4 u_base_color;
#ifdef HAS_COLORS
in vec4 v_color;
#endif
#endif
#ifdef ALPHA_MASK
uniform float u_alpha_cutoff;
#endif

#ifdef SHADOW_TINT_PASS
// A blend / transmissive caster: what it lets through, and its depth (blended by MIN).
// SHADOW_TINT_COLOUR: u_tint times the texel's base colour (sqrt'd for a volume glass's layer:
// SHADOW_TINT_SQRT), for transmissive casters whose colour varies.
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
    vec3 tint = u_tint;
#ifdef SHADOW_TINT_COLOUR
    vec3 c = u_base_color.rgb;
#ifdef HAS_BASE_COLOR_MAP
    c *= SAMPLE_MAP(base_color, BASE_COLOR_UV).rgb;
#endif
#ifdef HAS_COLORS
    c *= v_color.rgb;
#endif
#ifdef SHADOW_TINT_SQRT
    c = sqrt(max(c, vec3(0.0)));
#endif
    tint *= c;
#endif
    f_tint = vec4(tint, gl_FragCoord.z);
#endif
}
