#version 430
// Light shadow maps (renderer/raster/light_shadows.py): depth only, no colour. An alpha-mask
// caster (ALPHA_MASK) discards where its base-colour alpha is under the cutoff, as the main
// pass does, so light passes its cut-outs.
#ifdef ALPHA_MASK
#include "textures.glsl"
uniform vec4 u_base_color;
uniform float u_alpha_cutoff;
#ifdef HAS_COLORS
in vec4 v_color;
#endif
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
}
