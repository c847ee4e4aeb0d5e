#version 430
// GGX split-sum prefiltering (N = V = R) of a mip-mapped source cube. The sample set is the same
// for every texel in the lobe's own frame, so it is computed once per mip on the CPU
// (pipeline/environment.py): xyz = light direction in the (T, B, N) frame, w = source LOD chosen
// from the sample's pdf solid angle (Karis 2013). Weights are N.L. Filtering happens in direction
// space through a seamless cube lookup, so faces join without seams. Source texels are
// weighted by solid angle (see _ggx_mips), so every LOD averages radiance over the sphere.
#include "cube_atlas.glsl"

uniform samplerCube u_source;  // rgb = radiance x texel solid angle, a = solid angle
uniform int u_size;
uniform int u_count;
uniform vec4 u_samples[MAX_SAMPLES];
out vec4 f_color;

void main() {
    vec2 pixel;
    int face = atlas_face(u_size, pixel);
    vec3 n = cube_direction(face, pixel / float(u_size));
    vec3 up = abs(n.y) < 0.999 ? vec3(0.0, 1.0, 0.0) : vec3(1.0, 0.0, 0.0);
    vec3 t = normalize(cross(up, n));
    vec3 b = cross(n, t);
    vec3 sum = vec3(0.0);
    float weight = 0.0;
    for (int k = 0; k < u_count; ++k) {
        vec4 s = u_samples[k];
        vec3 l = t * s.x + b * s.y + n * s.z;
        vec4 texel = textureLod(u_source, l, s.w);
        sum += texel.rgb / texel.a * s.z;
        weight += s.z;
    }
    f_color = vec4(sum / weight, 1.0);
}
