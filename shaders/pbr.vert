#version 430
// World-space position, normal and tangent per vertex; one instance per world placement.
in vec3 in_position;
in vec3 in_normal;
in mat4 in_model;
in mat3 in_normal_matrix;
#ifdef HAS_TANGENTS
in vec4 in_tangent;
out vec4 v_tangent;
#endif
#ifdef HAS_UV0
in vec2 in_uv0;
#endif
out vec2 v_uv0;
#ifdef HAS_UV1
in vec2 in_uv1;
out vec2 v_uv1;
#endif
#ifdef HAS_COLORS
in vec4 in_color;
out vec4 v_color;
#endif
out vec3 v_world;
out vec3 v_normal;
#ifdef HAS_AO
#ifdef AO_ROWS
// one row of vertices per placement (BakedMesh.ao_per_placement): uint8 front/back pairs,
// two vertices a word; indexed by the instance's row in the mesh's transforms and the vertex
layout(std430, binding = 0) readonly buffer AoRows { uint ao_words[]; };
uniform int u_ao_vertices;
in float in_instance_row;
#else
in vec2 in_ao;         // baked ambient visibility (pipeline.occlusion), front and back
#endif
out vec2 v_ao;
#endif
#ifdef HAS_BENT
in vec3 in_bent;       // bent normals (pipeline.occlusion), object space, (x + 1) / 2
in vec3 in_bent_back;
out vec3 v_bent;
out vec3 v_bent_back;
#endif
#ifdef HAS_INTERIOR
in vec3 in_interior;   // baked object-space vertex->exit vector (refractive meshes)
out vec3 v_interior;   // in world space: scale and shear apply (paper 4.2.3.2)
#endif

uniform mat4 u_view_proj;

void main() {
    vec4 world = in_model * vec4(in_position, 1.0);
    v_world = world.xyz;
    v_normal = in_normal_matrix * in_normal;
#ifdef HAS_TANGENTS
    // A mirroring transform reverses the handedness of the tangent frame.
    v_tangent = vec4(mat3(in_model) * in_tangent.xyz,
                     determinant(mat3(in_model)) < 0.0 ? -in_tangent.w : in_tangent.w);
#endif
#ifdef HAS_UV0
    v_uv0 = in_uv0;
#else
    v_uv0 = vec2(0.0);
#endif
#ifdef HAS_UV1
    v_uv1 = in_uv1;
#endif
#ifdef HAS_COLORS
    v_color = in_color;
#endif
#ifdef HAS_AO
#ifdef AO_ROWS
    uint i = uint(in_instance_row + 0.5) * uint(u_ao_vertices) + uint(gl_VertexID);
    uint pair = (ao_words[i >> 1] >> ((i & 1u) * 16u)) & 0xffffu;
    v_ao = vec2(float(pair & 0xffu), float(pair >> 8)) / 255.0;
#else
    v_ao = in_ao;
#endif
#endif
#ifdef HAS_BENT
    v_bent = in_normal_matrix * (in_bent * 2.0 - 1.0);
    v_bent_back = in_normal_matrix * (in_bent_back * 2.0 - 1.0);
#endif
#ifdef HAS_INTERIOR
    v_interior = mat3(in_model) * in_interior;
#endif
    gl_Position = u_view_proj * world;
}
