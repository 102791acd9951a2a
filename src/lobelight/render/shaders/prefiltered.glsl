// Integration of a spherical Gaussian against the lighting by the Gaussian-prefiltered chain
// (lobelight.envmap.Prefiltered, laid out by render/_gl.py's atlas). Included in fragment
// shaders by render/_gl.py's _program(..., include=["prefiltered"]), and in the lobe
// visibility pass's vertex stage (LOBE_VISIBILITY_INCLUDE); MAX_LEVELS is defined by the loader.

uniform sampler2D atlas;          // every prefiltered level's six faces with seamless borders
uniform vec2 atlas_size;
uniform float level_y[MAX_LEVELS]; // row of each level in the atlas
uniform float level_res[MAX_LEVELS];
uniform int n_levels;
uniform float lam0;               // sharpness of level 0
uniform float log_rho;            // log of the sharpness ratio between levels
// Bilinear lookup of level k of the atlas tex at direction d: the GL major-axis face rule, then
// hardware bilinear filtering inside the face's padded tile (its one-texel border holds the
// neighbouring faces' texels, so this equals a seamless cube-map lookup)
vec3 level_lookup_in(sampler2D tex, int k, vec3 d) {
    vec3 a = abs(d);
    int face;
    float sc, tc, ma;
    if (a.x >= a.y && a.x >= a.z) {
        face = d.x >= 0.0 ? 0 : 1; ma = a.x; sc = d.x >= 0.0 ? -d.z : d.z; tc = -d.y;
    } else if (a.y >= a.z) {
        face = d.y >= 0.0 ? 2 : 3; ma = a.y; sc = d.x; tc = d.y >= 0.0 ? d.z : -d.z;
    } else {
        face = d.z >= 0.0 ? 4 : 5; ma = a.z; sc = d.z >= 0.0 ? d.x : -d.x; tc = -d.y;
    }
    float res = level_res[k];
    vec2 uv = vec2(sc, tc) / max(ma, 1e-30);
    vec2 x = clamp((uv + 1.0) * 0.5 * res + 0.5, 0.5, res + 0.5);  // padded texel index
    vec2 tcoord = vec2(float(face) * (res + 2.0) + x.x + 0.5, level_y[k] + x.y + 0.5);
    return texture(tex, tcoord / atlas_size).rgb;
}

// The lighting averaged under the normalised Gaussian, int G L dw / int G dw, in the atlas tex
// (atlas, or another chain of its layout): the two levels around lam, blended with the weight
// that minimises the L2 distance of the blended kernel to the requested one
// (Prefiltered.level_coords, "l2")
vec3 prefiltered_lookup_in(sampler2D tex, vec3 mu, float lam) {
    float kf = log(lam0 / lam) / log_rho;
    int kmax = n_levels - 1;
    int k0 = clamp(int(floor(kf)), 0, kmax - 1);
    // the blend weight is scale-free: measure variances in units of level k0's
    float s = exp(-float(k0) * log_rho) * lam0 / lam;
    float sa = 1.0, sb = exp(log_rho);
    float num = 1.0 / (s + sb) - 1.0 / (s + sa) - 1.0 / (sa + sb) + 1.0 / (2.0 * sa);
    float den = 1.0 / (2.0 * sa) - 2.0 / (sa + sb) + 1.0 / (2.0 * sb);
    float t = num / den;
    if (kf < 0.0) t = 0.0;
    if (kf > float(kmax)) t = 1.0;
    t = clamp(t, 0.0, 1.0);
    return (1.0 - t) * level_lookup_in(tex, k0, mu) + t * level_lookup_in(tex, k0 + 1, mu);
}

vec3 prefiltered_lookup(vec3 mu, float lam) { return prefiltered_lookup_in(atlas, mu, lam); }

// int G(w; mu, lam) L(w) dw
vec3 integrate(vec3 mu, float lam) {
    return prefiltered_lookup(mu, lam) * (6.283185307179586 / lam * (1.0 - exp(-2.0 * lam)));
}
