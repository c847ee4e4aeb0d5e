#version 430
// Copies one mip level of a baked cubemap (6 faces x S x S, RGBA float) from a storage
// buffer into the cube texture: moderngl has no per-level cube upload, image stores do.
layout(local_size_x = 8, local_size_y = 8) in;
layout(rgba16f, binding = 0) uniform writeonly imageCube u_cube;
layout(std430, binding = 1) readonly buffer Source { vec4 texels[]; };
uniform int u_size;

void main() {
    ivec3 p = ivec3(gl_GlobalInvocationID);  // (s, t, face)
    if (p.x >= u_size || p.y >= u_size) return;
    imageStore(u_cube, p, texels[(p.z * u_size + p.y) * u_size + p.x]);
}
