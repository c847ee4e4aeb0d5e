#version 430
// Wyman's preliminary pass (paper section 4.2.2): the nearest back faces of refractive
// objects, drawn with front faces culled, into float textures read by refraction.frag; the
// exit's sqrt(base colour) with them, the tint the light takes leaving the volume there.
// Vertex stage: pbr.vert.
#include "material_info.glsl"

uniform vec3 u_camera_position;
layout(location = 0) out vec4 f_position;  // xyz world position, w roughness
layout(location = 1) out vec4 f_normal;    // xyz outward world normal, w coverage (1)
layout(location = 2) out vec4 f_tint;      // rgb sqrt(base colour) (a crossing's transmission tint), w coverage (1)

void main() {
    MaterialInfo m = material_info(normalize(u_camera_position - v_world));
    vec3 n = m.n;
#ifdef DOUBLE_SIDED
    if (!gl_FrontFacing) n = -n;  // material_info turned it toward the viewer: undo
#endif
    f_position = vec4(v_world, m.roughness);
    f_normal = vec4(n, 1.0);
    f_tint = vec4(sqrt(max(m.base_color.rgb, vec3(0.0))), 1.0);
}
