// Green et al. 2006, section 5: Gaussians interpolated across views per vertex and across the
// triangle per pixel, each integrated against the lighting with prefiltered lookups.
// Stages are selected by VERTEX_SHADER / FRAGMENT_SHADER; NL (Gaussians per view) is defined
// by the loader. The torch path (render/_torch.py) mirrors this file step by step.

#if defined VERTEX_SHADER

in vec3 in_pos;

uniform sampler2D gauss_tex;   // RGBA32F, 2 texels per record (w.rgb, sigma), (mu.xyz, 0)
uniform sampler2D diff_tex;    // RGBA32F, N_SH texels per vertex: transfer RGB
uniform sampler2D planes_tex;  // RGBA32F, 540 x 1: 3 great-circle normals per geodesic
                               // triangle, .w = the view index of the opposite corner
uniform int tex_width;         // width of gauss_tex and diff_tex
uniform vec3 sh_light[N_SH];   // the rotated lighting's SH coefficients
uniform vec3 eye;
uniform vec3 cam_left;
uniform vec3 cam_up;
uniform vec3 cam_dir;
uniform vec2 tan_half;         // tan of the half field of view along x and y
uniform vec2 depth_range;      // near, far

out vec3 v_w[NL];
out vec3 v_mu[NL];
out float v_sigma[NL];
out vec3 v_diffuse;

ivec2 at(int i) { return ivec2(i % tex_width, i / tex_width); }

void main() {
    int v = gl_VertexID;
    vec3 d = normalize(eye - in_pos);

    // the geodesic triangle holding d: largest smallest barycentric (as sphere.locate_views)
    float best = -1e30;
    vec3 bdet = vec3(0.0);
    ivec3 views = ivec3(0);
    for (int f = 0; f < 180; ++f) {
        vec4 p0 = texelFetch(planes_tex, ivec2(3 * f, 0), 0);
        vec4 p1 = texelFetch(planes_tex, ivec2(3 * f + 1, 0), 0);
        vec4 p2 = texelFetch(planes_tex, ivec2(3 * f + 2, 0), 0);
        vec3 det = vec3(dot(p0.xyz, d), dot(p1.xyz, d), dot(p2.xyz, d));
        float m = min(det.x, min(det.y, det.z));
        if (m > best) {
            best = m;
            bdet = det;
            views = ivec3(int(p0.w + 0.5), int(p1.w + 0.5), int(p2.w + 0.5));
        }
    }
    vec3 b = max(bdet, vec3(0.0));
    b /= max(b.x + b.y + b.z, 1e-30);

    for (int k = 0; k < NL; ++k) {
        vec3 w = vec3(0.0);
        vec3 mu = vec3(0.0);
        float sigma = 0.0;
        for (int c = 0; c < 3; ++c) {
            int r = 2 * ((v * 92 + views[c]) * NL + k);
            vec4 a = texelFetch(gauss_tex, at(r), 0);
            vec4 m = texelFetch(gauss_tex, at(r + 1), 0);
            w += b[c] * a.rgb;
            sigma += b[c] * a.a;
            mu += b[c] * m.xyz;
        }
        v_w[k] = w;
        v_mu[k] = normalize(mu);
        v_sigma[k] = sigma;
    }

    vec3 diffuse = vec3(0.0);
    for (int i = 0; i < N_SH; ++i) {
        diffuse += texelFetch(diff_tex, at(v * N_SH + i), 0).rgb * sh_light[i];
    }
    v_diffuse = diffuse;

    // Mitsuba's perspective sensor: x runs against cam_left, y along cam_up
    vec3 q = in_pos - eye;
    float zc = dot(q, cam_dir);
    float n = depth_range.x, fa = depth_range.y;
    gl_Position = vec4(-dot(q, cam_left) / tan_half.x, dot(q, cam_up) / tan_half.y,
                       zc * (fa + n) / (fa - n) - 2.0 * fa * n / (fa - n), zc);
}

#elif defined FRAGMENT_SHADER

in vec3 v_w[NL];
in vec3 v_mu[NL];
in float v_sigma[NL];
in vec3 v_diffuse;

uniform sampler2D atlas;          // every prefiltered level's six faces with seamless borders
uniform vec2 atlas_size;
uniform float level_y[MAX_LEVELS]; // row of each level in the atlas
uniform float level_res[MAX_LEVELS];
uniform int n_levels;
uniform float lam0;               // sharpness of level 0
uniform float log_rho;            // log of the sharpness ratio between levels
uniform mat3 rot_t;               // R^T: the rotated lighting seen by mu is the original at R^T mu
uniform vec2 parts;               // (diffuse on, glossy on)

out vec4 frag;

// Bilinear lookup of level k at direction d: the GL major-axis face rule, then hardware
// bilinear filtering inside the face's padded tile (its one-texel border holds the
// neighbouring faces' texels, so this equals a seamless cube-map lookup)
vec3 level_lookup(int k, vec3 d) {
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
    return texture(atlas, tcoord / atlas_size).rgb;
}

// int G(w; mu, lam) L(w) dw: the two levels around lam, blended with the weight that minimises
// the L2 distance of the blended kernel to the requested one (Prefiltered.level_coords, "l2")
vec3 integrate(vec3 mu, float lam) {
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
    vec3 l = (1.0 - t) * level_lookup(k0, mu) + t * level_lookup(k0 + 1, mu);
    float z = 6.283185307179586 / lam * (1.0 - exp(-2.0 * lam));
    return l * z;
}

void main() {
    vec3 c = parts.x * v_diffuse;
    if (parts.y > 0.0) {
        for (int k = 0; k < NL; ++k) {
            if (max(v_w[k].r, max(v_w[k].g, v_w[k].b)) <= 0.0) continue;
            float lam = 1.0 / (v_sigma[k] * v_sigma[k]);
            c += v_w[k] * integrate(rot_t * normalize(v_mu[k]), lam);
        }
    }
    frag = vec4(c, 1.0);
}

#endif
