#version 430
// The paper's baseline (section 4.1): each mip is the previous one blurred by a 3x3 Gaussian
// and halved, per face, clamped at the face's own edges with no knowledge of its neighbours
// (hence the seams of the paper's Figure 2, kept on purpose). Blur-then-halve equals one 4x4
// kernel [1 3 3 1]/8 in each axis over the source texels 2x-1 .. 2x+2.
#include "cube_atlas.glsl"

uniform sampler2D u_previous;  // S x 6S atlas of the previous mip
uniform int u_size;            // this mip's face size (source face is 2 * u_size)
out vec4 f_color;

void main() {
    vec2 pixel;
    int face = atlas_face(u_size, pixel);
    ivec2 p = ivec2(pixel) * 2;
    int src = u_size * 2;
    const float k[4] = float[4](1.0, 3.0, 3.0, 1.0);
    vec3 sum = vec3(0.0);
    for (int j = 0; j < 4; ++j) {
        for (int i = 0; i < 4; ++i) {
            ivec2 q = clamp(p + ivec2(i - 1, j - 1), ivec2(0), ivec2(src - 1));
            sum += k[i] * k[j] * texelFetch(u_previous, ivec2(q.x, q.y + face * src), 0).rgb;
        }
    }
    f_color = vec4(sum / 64.0, 1.0);
}
