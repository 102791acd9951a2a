// Green et al. 2006, section 5: Gaussians interpolated across views per vertex and across the
// triangle per pixel, each integrated against the lighting with prefiltered lookups.
// Stages are selected by VERTEX_SHADER / FRAGMENT_SHADER; NL (Gaussians per view) is defined
// by the loader. The torch path (render/_torch.py) mirrors this file step by step.

#if defined VERTEX_SHADER

in vec3 in_pos;

uniform sampler2D gauss_tex;   // RGBA32F, 2 texels per record (w.rgb, sigma), (mu.xyz, 0)
uniform sampler2D diff_tex;    // RGBA32F, N_SH texels per vertex: transfer RGB
// the geodesic triangles' planes and test_face() come from geodesic.glsl
uniform sampler2D cand_tex;    // RGBA32F, candidate triangles per cube-map texel (-1 padded):
                               // CAND_TEXELS texels per cell, [face * CAND_RES + row, col]
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

    // the geodesic triangle holding d: largest smallest barycentric (as sphere.locate_views),
    // among the few candidates of d's texel in a cube-map table (sphere.triangle_candidates)
    // rather than all 180 (the full scan was three quarters of an H100 frame)
    vec3 ad = abs(d);
    int face;
    vec2 uv;
    if (ad.x >= ad.y && ad.x >= ad.z) {
        face = d.x >= 0.0 ? 0 : 1; uv = vec2(d.x >= 0.0 ? -d.z : d.z, -d.y) / ad.x;
    } else if (ad.y >= ad.z) {
        face = d.y >= 0.0 ? 2 : 3; uv = vec2(d.x, d.y >= 0.0 ? d.z : -d.z) / ad.y;
    } else {
        face = d.z >= 0.0 ? 4 : 5; uv = vec2(d.z >= 0.0 ? d.x : -d.x, -d.y) / ad.z;
    }
    ivec2 cell = clamp(ivec2(floor((uv + 1.0) * 0.5 * float(CAND_RES))), 0, CAND_RES - 1);
    float best = -1e30;
    vec3 bdet = vec3(0.0);
    ivec3 views = ivec3(0);
    for (int q = 0; q < CAND_TEXELS; ++q) {
        vec4 c4 = texelFetch(cand_tex, ivec2(cell.x * CAND_TEXELS + q, face * CAND_RES + cell.y), 0);
        for (int e = 0; e < 4; ++e) {
            int f = int(c4[e]);
            if (f < 0) break;
            test_face(f, d, best, bdet, views);
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

// the prefiltered lookups (integrate, level_lookup) come from prefiltered.glsl
uniform mat3 rot_t;               // R^T: the rotated lighting seen by mu is the original at R^T mu
uniform vec2 parts;               // (diffuse on, glossy on)

out vec4 frag;

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
