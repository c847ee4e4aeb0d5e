#version 430
// Resample an equirectangular panorama onto cube faces: bilinear (wraps in u, clamps in v),
// averaged over SUPERSAMPLE^2 points per texel when the faces are coarser than the panorama.
#include "cube_atlas.glsl"

uniform sampler2D u_panorama;
uniform int u_size;
out vec4 f_color;

void main() {
    vec2 pixel;
    int face = atlas_face(u_size, pixel);
    vec2 base = floor(pixel);
    vec3 sum = vec3(0.0);
    for (int j = 0; j < SUPERSAMPLE; ++j) {
        for (int i = 0; i < SUPERSAMPLE; ++i) {
            vec2 st = (base + (vec2(i, j) + 0.5) / float(SUPERSAMPLE)) / float(u_size);
            sum += textureLod(u_panorama, equirect_uv(cube_direction(face, st)), 0.0).rgb;
        }
    }
    f_color = vec4(sum / float(SUPERSAMPLE * SUPERSAMPLE), 1.0);
}
