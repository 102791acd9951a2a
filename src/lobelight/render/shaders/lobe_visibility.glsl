// The direct Gaussians of a rough lobe corrected per vertex for what the object blocks of the
// lighting (render/_lobe_visibility.py, whose formulas these are): the light they carry scaled
// by rho = Q[f cos V L] / Q[G L] per channel, Q one fixed quadrature of lv_samples directions
// drawn from a spherical Gaussian around the lobes. Included in prt.glsl's vertex stage of
// the correction pass (LOBE_VIS_PASS, captured by transform feedback) after frame.glsl,
// prefiltered.glsl, tiles.glsl and brdf.glsl; LV_LAM_SCALE, LV_LAM_MIN and LV_RHO_MAX are defined by the loader.

// the quadrature's directions (_lobe_visibility.py SAMPLES; the web page's frames drawn while
// the view moves take MOVING_SAMPLES)
uniform int lv_samples;

// rho at vertex v (unit normal n, unit view d) whose Gaussians are the vertex stage's
// (prt.glsl v_lobe: carried light and live flag, then the live mean's offset from the mirror
// direction and the width), the BRDF's parameters sb0, eta, k (brdf.glsl brdf_cos)
vec3 lobe_visibility(int v, vec3 n, vec3 d, vec4 lobes[2 * N_GAUSSIANS], vec4 sb0, vec3 eta,
                     vec3 k) {
    const int ND = N_GAUSSIANS - N_INDIRECT;
    vec3 mirror = 2.0 * dot(n, d) * n - d;
    vec3 w[ND];
    vec3 mu[ND];
    float lam[ND];
    vec3 c = vec3(0.0);
    float lam_min = -1.0;
    for (int i = 0; i < ND; ++i) {
        vec4 a = lobes[2 * i], b = lobes[2 * i + 1];
        bool live = a.w > 0.5 && b.w > 0.0;
        lam[i] = live ? 1.0 / (b.w * b.w) : 0.0;
        mu[i] = live ? normalize(b.xyz + mirror) : n;
        // the peak weight from the carried light (lobelight.lobes.sg.integral)
        float integral = 6.283185307179586 / max(lam[i], 1e-30) * (1.0 - exp(-2.0 * lam[i]));
        w[i] = live ? a.rgb / integral : vec3(0.0);
        c += live ? (a.r + a.g + a.b) / 3.0 * mu[i] : vec3(0.0);
        if (live) lam_min = lam_min < 0.0 ? lam[i] : min(lam_min, lam[i]);
    }
    if (lam_min < 0.0) return vec3(1.0);  // no live lobe: nothing to correct
    c = dot(c, c) > 0.0 ? normalize(c) : n;
    float lp = max(lam_min * LV_LAM_SCALE, LV_LAM_MIN);
    float om = 1.0 - exp(-2.0 * lp);
    vec3 axis = abs(c.z) < 0.9 ? vec3(0.0, 0.0, 1.0) : vec3(1.0, 0.0, 0.0);
    vec3 t1 = normalize(cross(axis, c));
    vec3 t2 = cross(c, t1);
    vec3 num = vec3(0.0), den = vec3(0.0);
    float n_s = float(lv_samples);
    for (int s = 0; s < lv_samples; ++s) {
        // a Fibonacci lattice of the unit square (_lobe_visibility.py lattice)
        float u1 = (float(s) + 0.5) / n_s;
        float u2 = fract(float(s) * 0.6180339887498949);
        float ct = clamp(1.0 + log(1.0 - u1 * om) / lp, -1.0, 1.0);
        float st = sqrt(max(1.0 - ct * ct, 0.0));
        float phi = 6.283185307179586 * u2;
        vec3 dir = ct * c + st * cos(phi) * t1 + st * sin(phi) * t2;
        float pdf = lp / (6.283185307179586 * om) * exp(lp * (ct - 1.0));
        // the lighting over the sample's share of the sphere, 1 / (S pdf)
        vec3 light = prefiltered_lookup(rot_t * dir,
                                        6.283185307179586 * n_s * pdf) / pdf;
        vec3 g = vec3(0.0);
        for (int i = 0; i < ND; ++i) g += w[i] * exp(lam[i] * (dot(dir, mu[i]) - 1.0));
        num += brdf_cos(dir, d, n, sb0, eta, k) * tile_lookup(v, dir) * light;
        den += g * light;
    }
    vec3 rho = clamp(num / max(den, vec3(1e-30)), 0.0, LV_RHO_MAX);
    return mix(vec3(1.0), rho, greaterThan(den, vec3(0.0)));
}
