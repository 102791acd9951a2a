// Green et al. 2006, section 5: Gaussians interpolated across views per vertex and across the
// triangle per pixel, each integrated against the lighting with prefiltered lookups.
// Interpolation follows lobelight.model.blend_lobes: the light a lobe carries (e, its weight
// times its integral) blends linearly; width and mean blend over the live records (carrying at
// least FLOOR) with renormalised barycentrics. Per pixel the rasteriser does that with
// varyings premultiplied by the live flag, divided by the interpolated flag.
// Stages are selected by VERTEX_SHADER / FRAGMENT_SHADER; NL (Gaussians per view) is defined
// by the loader. The torch path (render/_torch.py) mirrors this file step by step.

#if defined VERTEX_SHADER

in vec3 in_pos;
in vec3 in_normal;
in vec3 in_albedo;

uniform sampler2D gauss_tex;   // RGBA32F, 2 texels per record (e.rgb, sigma), (mu.xyz, 0)
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

out vec3 v_e[NL];        // carried light
out float v_live[NL];    // 1 if the vertex's lobe is live (carries light), else 0
out vec3 v_mu[NL];       // live flag times (mean - the vertex's mirror direction)
out float v_sigma[NL];   // live flag times sigma
out vec3 v_diffuse;
out vec3 v_pos;
out vec3 v_normal;
out vec3 v_albedo;

ivec2 at(int i) { return ivec2(i % tex_width, i / tex_width); }

void main() {
    int v = gl_VertexID;
    vec3 d = normalize(eye - in_pos);

    vec3 bdet;
    ivec3 views;
    locate_triangle(d, bdet, views);  // geodesic.glsl
    vec3 b = max(bdet, vec3(0.0));
    b /= max(b.x + b.y + b.z, 1e-30);

    vec3 mirror = 2.0 * dot(in_normal, d) * in_normal - d;
    for (int k = 0; k < NL; ++k) {
        vec3 e = vec3(0.0), mu = vec3(0.0);
        float sigma = 0.0, say = 0.0;
        for (int c = 0; c < 3; ++c) {
            int r = 2 * ((v * 92 + views[c]) * NL + k);
            vec4 rec = texelFetch(gauss_tex, at(r), 0);
            vec3 m = texelFetch(gauss_tex, at(r + 1), 0).xyz;
            float live = (rec.r + rec.g + rec.b) / 3.0 >= FLOOR ? b[c] : 0.0;
            e += b[c] * rec.rgb;
            say += live;
            sigma += live * rec.a;
            mu += live * m;
        }
        bool ok = say >= MIN_SAY;
        float live = ok && (e.r + e.g + e.b) / 3.0 >= FLOOR ? 1.0 : 0.0;
        v_e[k] = ok ? e : vec3(0.0);
        v_live[k] = live;
        v_sigma[k] = ok ? live * sigma / say : 0.0;
        // the mean as an offset from this vertex's mirror direction (divide first: no underflow)
        v_mu[k] = ok ? live * (normalize(mu / say) - mirror) : vec3(0.0);
    }

    vec3 diffuse = vec3(0.0);
    for (int i = 0; i < N_SH; ++i) {
        diffuse += texelFetch(diff_tex, at(v * N_SH + i), 0).rgb * sh_light[i];
    }
    v_diffuse = diffuse;
    v_pos = in_pos;
    v_normal = in_normal;
    v_albedo = in_albedo;

    // Mitsuba's perspective sensor: x runs against cam_left, y along cam_up
    vec3 q = in_pos - eye;
    float zc = dot(q, cam_dir);
    float n = depth_range.x, fa = depth_range.y;
    gl_Position = vec4(-dot(q, cam_left) / tan_half.x, dot(q, cam_up) / tan_half.y,
                       zc * (fa + n) / (fa - n) - 2.0 * fa * n / (fa - n), zc);
}

#elif defined FRAGMENT_SHADER

in vec3 v_e[NL];
in float v_live[NL];
in vec3 v_mu[NL];
in float v_sigma[NL];
in vec3 v_diffuse;
in vec3 v_pos;
in vec3 v_normal;
in vec3 v_albedo;

// the sun taken out of the diffuse lighting (render/_lighting.py), with its shadow map
uniform float sun_on;
uniform vec3 sun_dir;             // towards the sun, rotated with the lighting
uniform vec3 sun_e;               // its irradiance at normal incidence (RGB)
uniform sampler2DShadow shadow_map;
uniform mat3 shadow_frame;        // as in shadow.glsl
uniform vec3 shadow_center;
uniform float shadow_scale;
uniform float shadow_offset;      // normal offset against self-shadowing (world units)
uniform float shadow_bias;        // depth bias (shadow-map depth units)

// the prefiltered lookups (integrate, level_lookup) come from prefiltered.glsl
uniform vec3 eye;
uniform mat3 rot_t;               // R^T: the rotated lighting seen by mu is the original at R^T mu
uniform vec2 parts;               // (diffuse on, glossy on)

out vec4 frag;

void main() {
    vec3 c = parts.x * v_diffuse;
    vec3 n = normalize(v_normal);
    if (parts.x > 0.0 && sun_on > 0.0) {
        float cosine = dot(n, sun_dir);
        if (cosine > 0.0) {
            vec3 q = shadow_frame * (v_pos + shadow_offset * n - shadow_center) * shadow_scale;
            // hardware 2x2 percentage-closer filtering of the depth comparison
            float vis = texture(shadow_map, vec3(q.xy * 0.5 + 0.5, -q.z * 0.5 + 0.5 - shadow_bias));
            c += v_albedo * (0.3183098861837907 * cosine * vis) * sun_e;
        }
    }
    if (parts.y > 0.0) {
        // the pixel's own mirror direction, from its interpolated normal and view direction:
        // the blended offsets are re-based on it (lobelight.model.blend_lobes, frame=)
        vec3 d = normalize(eye - v_pos);
        vec3 mirror = 2.0 * dot(n, d) * n - d;
        for (int k = 0; k < NL; ++k) {
            float say = v_live[k];  // the live corners' barycentric weight
            if (say < MIN_SAY) continue;
            float sigma = v_sigma[k] / say;
            vec3 mu = normalize(mirror + v_mu[k] / say);
            c += v_e[k] * prefiltered_lookup(rot_t * mu, 1.0 / (sigma * sigma));
        }
    }
    frag = vec4(c, 1.0);
}

#endif
