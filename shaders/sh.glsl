// Diffuse lighting from 9 radiance spherical-harmonic coefficients (real SH, l <= 2) made by
// pipeline/environment.py. Basis in world coordinates, order: Y00; Y1-1 (y), Y10 (z), Y11 (x);
// Y2-2 (xy), Y2-1 (yz), Y20 (3z^2 - 1), Y21 (xz), Y22 (x^2 - y^2).
// Returns irradiance / pi at unit normal n (Ramamoorthi & Hanrahan 2001 convolution
// constants A0 = pi, A1 = 2pi/3, A2 = pi/4, then divided by pi): the outgoing radiance of a
// white Lambertian surface, so a constant environment L gives exactly L.
#ifndef SH_GLSL
#define SH_GLSL
vec3 sh_irradiance(vec3 sh[9], vec3 n) {
    const float c0 = 0.282095;           // A0/pi * Y00
    const float c1 = 0.488603 * 2.0 / 3.0;
    const float c2 = 1.092548 * 0.25;
    const float c3 = 0.315392 * 0.25;
    const float c4 = 0.546274 * 0.25;
    return c0 * sh[0]
         + c1 * (n.y * sh[1] + n.z * sh[2] + n.x * sh[3])
         + c2 * (n.x * n.y * sh[4] + n.y * n.z * sh[5] + n.x * n.z * sh[7])
         + c3 * (3.0 * n.z * n.z - 1.0) * sh[6]
         + c4 * (n.x * n.x - n.y * n.y) * sh[8];
}
#endif
