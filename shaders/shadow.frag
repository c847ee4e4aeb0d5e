#version 430
// Ground contact shadow, first step: the object seen from straight above (orthographic), each
// fragment writing how much it shades the ground below it: 1 at the ground, fading to 0 at
// u_fade above it. Blended with MAX, so the map holds the lowest surface over each texel.
in vec3 v_world;
uniform float u_ground;  // world y of the ground (the bounds' minimum)
uniform float u_fade;    // height above the ground at which a surface stops shading it
out vec4 f_shade;

void main() {
    float h = max(v_world.y - u_ground, 0.0) / u_fade;
    float s = 1.0 - clamp(h, 0.0, 1.0);
    f_shade = vec4(s * s, 0.0, 0.0, 1.0);
}
