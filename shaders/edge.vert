#version 430
// An edge to smooth (renderer.edges): both ends in window pixels on every vertex.
in vec3 in_ndc;
in vec4 in_line;
flat out vec4 v_line;
void main() {
    v_line = in_line;
    gl_Position = vec4(in_ndc, 1.0);
}
