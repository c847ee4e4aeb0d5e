#version 430
// One pixel near an edge (renderer.edges): the share of the pixel's square that lies across
// the edge from its centre (exact for the edge's straight line through the square), and the
// neighbour across the edge on the minor axis, whose colour is that side's. Written: the step
// to that neighbour times the share (the final pass mixes the two pixels by it).
flat in vec4 v_line;            // the edge's ends, window pixels
uniform sampler2D u_depth;      // the frame's depth
uniform ivec2 u_size;
out vec2 f_edge;

float ramp_integral(float u) {  // integral of clamp(u, 0, 1)
    return u < 0.0 ? 0.0 : u < 1.0 ? 0.5 * u * u : u - 0.5;
}

// Area of the unit square beyond a line at offset `a` from its far side, sloping by `s`
// (0..1) along the major axis: the integral of clamp(a + s x, 0, 1) over x in -1/2..1/2.
float beyond(float a, float s) {
    if (s < 1e-4) return clamp(a, 0.0, 1.0);
    return (ramp_integral(a + 0.5 * s) - ramp_integral(a - 0.5 * s)) / s;
}

void main() {
    vec2 a = v_line.xy, d = v_line.zw - v_line.xy;
    vec2 c = gl_FragCoord.xy;
    float t, s;
    vec2 step_;
    if (abs(d.x) >= abs(d.y)) {  // mostly horizontal: the edge's height at this column
        s = d.y / d.x;
        t = a.y + (c.x - a.x) * s - c.y;
        step_ = vec2(0.0, sign(t));
    } else {
        s = d.x / d.y;
        t = a.x + (c.y - a.y) * s - c.x;
        step_ = vec2(sign(t), 0.0);
    }
    float share = beyond(0.5 - abs(t), abs(s));
    if (share <= 0.0) discard;
    ivec2 xy = ivec2(c);
    ivec2 q = clamp(xy + ivec2(step_), ivec2(0), u_size - 1);
    // Hidden: something nearer covers both sides (the far side of a silhouette lies behind it).
    float far = max(texelFetch(u_depth, xy, 0).r, texelFetch(u_depth, q, 0).r);
    if (gl_FragCoord.z > far + 1e-4) discard;
    f_edge = step_ * share;
}
