// Refraction helpers: the GLSL twins of renderer/optics.py (same conventions) and Wyman's
// exit-distance estimate (paper section 4.2.2).
//   d: unit direction of travel toward the surface; n: unit normal on the side the ray comes
//   from (dot(d, n) <= 0); eta = n_incident / n_transmitted (1/1.5 entering glass, 1.5 leaving).
#ifndef REFRACTION_GLSL
#define REFRACTION_GLSL

// Snell's law in vector form (paper section 3.2). Returns false on total internal
// reflection, where `t` is the mirror direction instead (always a finite unit vector).
bool refract_ray(vec3 d, vec3 n, float eta, out vec3 t) {
    float cos_i = clamp(-dot(d, n), 0.0, 1.0);
    float k = (1.0 - eta * eta) + eta * eta * cos_i * cos_i;  // cos^2 of the transmitted angle
    if (k < 0.0) {
        t = reflect(d, n);
        return false;
    }
    t = normalize(eta * d + (eta * cos_i - sqrt(k)) * n);
    return true;
}

// Exact unpolarised dielectric Fresnel reflectance; 1 beyond the critical angle. Written with
// eta = n1/n2 so that IOR 1.0 reflects exactly nothing (an invisible object).
float fresnel_dielectric(float cos_i, float eta) {
    cos_i = clamp(cos_i, 0.0, 1.0);
    float cos2_t = (1.0 - eta * eta) + eta * eta * cos_i * cos_i;
    if (cos2_t <= 0.0) return 1.0;
    float cos_t = sqrt(cos2_t);
    float rs = (eta * cos_i - cos_t) / max(eta * cos_i + cos_t, 1e-12);
    float rp = (cos_i - eta * cos_t) / max(cos_i + eta * cos_t, 1e-12);
    return 0.5 * (rs * rs + rp * rp);
}

// Wyman's interpolation between the unrefracted distance (front to back face along the view
// ray) and the baked distance along the inverted normal, by theta_r / theta_i. At normal
// incidence the ratio tends to eta (sin theta_r ~ eta sin theta_i).
float exit_distance(float cos_i, float cos_r, float eta, float d_view, float d_interior) {
    float theta_i = acos(clamp(cos_i, -1.0, 1.0));
    float theta_r = acos(clamp(cos_r, -1.0, 1.0));
    float ratio = theta_i > 1e-3 ? clamp(theta_r / theta_i, 0.0, 1.0) : clamp(eta, 0.0, 1.0);
    return ratio * d_view + (1.0 - ratio) * d_interior;
}

// Beer-Lambert transmittance over a path of `dist` scene units.
vec3 beer_lambert(vec3 sigma, float dist) {
    return exp(-sigma * max(dist, 0.0));
}
#endif
