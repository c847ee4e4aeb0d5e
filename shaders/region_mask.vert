#version 430
// The object's silhouette bound (renderer/regions.py) as a triangle fan in pixels, y down
// from the image top: the final pass's output rows run top-first (final.frag), so y maps
// straight to window rows. Written at depth 0 into the final pass's depth buffer.
in vec2 in_pixel;
uniform vec2 u_size;
void main() {
    gl_Position = vec4(in_pixel / u_size * 2.0 - 1.0, -1.0, 1.0);
}
