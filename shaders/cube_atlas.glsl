// Cube faces rendered as one S x 6S atlas: face f occupies rows [f*S, (f+1)*S), row = t, column = s,
// so a read-back reshapes to 6 x S x S in pipeline/cubemap.py's order and orientation.
const float PI = 3.14159265358979;

// Unit direction through (s, t) in [0, 1]^2 of `face`, from the OpenGL cube-map face table.
vec3 cube_direction(int face, vec2 st) {
    vec2 c = st * 2.0 - 1.0;
    vec3 d;
    if (face == 0)      d = vec3(1.0, -c.y, -c.x);
    else if (face == 1) d = vec3(-1.0, -c.y, c.x);
    else if (face == 2) d = vec3(c.x, 1.0, c.y);
    else if (face == 3) d = vec3(c.x, -1.0, -c.y);
    else if (face == 4) d = vec3(c.x, -c.y, 1.0);
    else                d = vec3(-c.x, -c.y, -1.0);
    return normalize(d);
}

// Face index and in-face texel position (pixels, texel centres at +0.5) of this fragment.
int atlas_face(int size, out vec2 pixel) {
    int face = min(int(gl_FragCoord.y) / size, 5);
    pixel = vec2(gl_FragCoord.x, gl_FragCoord.y - float(face * size));
    return face;
}

// Mitsuba's envmap convention (pipeline/cubemap.py): u = 0.5 + atan2(-x, z) / 2pi, v = acos(y) / pi.
vec2 equirect_uv(vec3 d) {
    return vec2(0.5 + atan(-d.x, d.z) / (2.0 * PI), acos(clamp(d.y, -1.0, 1.0)) / PI);
}
