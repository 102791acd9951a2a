// Green et al. 2006, section 5: Gaussians interpolated across views per vertex and across the
// triangle per pixel, each integrated against the lighting with prefiltered lookups.
// Stages are selected by VERTEX_SHADER / FRAGMENT_SHADER; NL (Gaussians per view) is defined
// by the loader. The torch path (render/_torch.py) mirrors this file step by step.

#if defined VERTEX_SHADER

in vec3 in_pos;

uniform sampler2D gauss_tex;   // RGBA32F, 2 texels per record (w.rgb, sigma), (mu.xyz, 0)
uniform sampler2D diff_tex;    // RGBA32F, N_SH texels per vertex: transfer RGB
// the geodesic triangles and locate_triangle() come from geodesic.glsl
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

    vec3 bdet;
    ivec3 views;
    locate_triangle(d, bdet, views);  // geodesic.glsl
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
