#version 430
// The environment behind the asset, seen through the same camera, optionally blurred by
// reading a rougher prefiltered mip.
#include "ibl.glsl"
in vec2 v_ndc;
uniform mat3 u_camera_basis;   // columns: right, up, forward (world)
uniform vec2 u_tan_half_fov;   // x: horizontal, y: vertical
uniform float u_blur;          // roughness of the mip shown
out vec4 f_color;
void main() {
    vec3 d = u_camera_basis * vec3(v_ndc * u_tan_half_fov, 1.0);
    f_color = vec4(env_radiance(normalize(d), u_blur), 1.0);
}
