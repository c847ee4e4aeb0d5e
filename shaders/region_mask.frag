#version 430
// Depth only (colour writes are masked): marks the pixels the final pass resolves.
out vec4 f_color;
void main() {
    f_color = vec4(0.0);
}
