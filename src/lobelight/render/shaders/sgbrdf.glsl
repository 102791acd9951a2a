// SG-BRDF shading (the EM paper's sec. V) and its filtered-importance-sampling baseline.
// The torch path (lobelight.sgbrdf.shade / shade_fis, sphere_hits) mirrors this file step by
// step; render/_gl_sgbrdf.py loads it with these defines:
//   SPHERE      1: the unit sphere at the origin, ray cast per pixel on a full-screen quad
//               (as sphere_hits, so images are pixel-comparable); 0: a rasterised mesh
//   ORTHO       1: sphere_hits' default camera (orthographic from +Z, the sphere fills the
//               image); 0: a lobelight.geometry.camera.Camera (Mitsuba's perspective sensor)
//   HAS_TANGENT mesh only: per-vertex tangents are given (else the frame of sphere.frame)
//   METHOD_FIS  0: our lobes with prefiltered.glsl's integrate(); 1: 40-sample FIS
//   GEODESIC    ours only, 1: the 92-view geodesic layout, 0: the elevation layout
//   GREY        ours only, 1: every lobe mass is grey (one texel per view and lobe)
//   NL, N_VIEWS lobes per view and views (ours);  NS samples (FIS);  MAX_LEVELS (prefiltered)
//   GRID, GRID_K the geodesic layout's candidate-triangle grid (cells per side, slots per cell)

#if defined VERTEX_SHADER

#if SPHERE
in vec2 in_xy;
void main() { gl_Position = vec4(in_xy, 0.0, 1.0); }
#else
in vec3 in_pos;
in vec3 in_nrm;
#if HAS_TANGENT
in vec3 in_tan;
out vec3 v_tan;
#endif
out vec3 v_pos;
out vec3 v_nrm;
uniform vec3 eye;
uniform vec3 cam_left;
uniform vec3 cam_up;
uniform vec3 cam_dir;
uniform vec2 tan_half;      // tan of the half field of view along x and y
uniform vec2 depth_range;   // near, far (perspective); centre z, half depth (orthographic)

void main() {
    v_pos = in_pos;
    v_nrm = in_nrm;
#if HAS_TANGENT
    v_tan = in_tan;
#endif
#if ORTHO
    // sphere_hits' default view: x right, y up, looking along -z, [-1, 1]^2 fills the image
    gl_Position = vec4(in_pos.xy, (depth_range.x - in_pos.z) / depth_range.y, 1.0);
#else
    // Mitsuba's perspective sensor: x runs against cam_left, y along cam_up (as prt.glsl)
    vec3 q = in_pos - eye;
    float zc = dot(q, cam_dir);
    float n = depth_range.x, fa = depth_range.y;
    gl_Position = vec4(-dot(q, cam_left) / tan_half.x, dot(q, cam_up) / tan_half.y,
                       zc * (fa + n) / (fa - n) - 2.0 * fa * n / (fa - n), zc);
#endif
}
#endif

#elif defined FRAGMENT_SHADER

uniform vec2 viewport;      // width, height in pixels
uniform vec3 eye;
uniform vec3 cam_left;
uniform vec3 cam_up;
uniform vec3 cam_dir;
uniform vec2 tan_half;
uniform float eye_c;        // |eye|^2 - 1, computed in float64 (the ray-sphere constant term)

#if !SPHERE
in vec3 v_pos;
in vec3 v_nrm;
#if HAS_TANGENT
in vec3 v_tan;
#endif
#endif

out vec4 frag;

const float PI = 3.141592653589793;
const float TINY = 1.17549435e-38;  // torch.finfo(float32).tiny, the clamps of the torch path

// sphere.frame (Duff et al. 2017): tangent and bitangent of a unit normal; copysign as torch
void duff_frame(vec3 n, out vec3 t, out vec3 b) {
    float sgn = n.z >= 0.0 ? 1.0 : -1.0;
    float a = -1.0 / (sgn + n.z);
    float c = n.x * n.y * a;
    t = vec3(1.0 + sgn * n.x * n.x * a, sgn * c, -sgn * n.x);
    b = vec3(c, sgn + n.y * n.y * a, -n.y);
}

// the tangent t0 made orthonormal to n (Gram-Schmidt, as shade()); the frame's when degenerate
void tangent_frame(vec3 n, vec3 t0, out vec3 t, out vec3 b) {
    vec3 tf, bf;
    duff_frame(n, tf, bf);
    vec3 tp = t0 - dot(t0, n) * n;
    float len = length(tp);
    t = len > 1e-6 ? tp / len : tf;
    b = cross(n, t);
}

#if METHOD_FIS
// ---- filtered importance sampling (lobelight.sgbrdf.shade_fis) with Ward (brdf.Ward) ----
uniform samplerCube env_mip;  // box-filtered mip chain (glGenerateMipmap), seamless
uniform vec2 ham[NS];         // Hammersley points, float32 as hammersley(NS, dtype=float32)
uniform vec3 ks;              // Ward's specular colour
uniform vec2 alpha;           // Ward's (alpha_x, alpha_y)
uniform float base_res;       // face resolution of level 0
uniform float max_lod;        // last mip level
uniform float lod_bias;       // Colbert & Krivanek's + 1

vec3 ward_eval(vec3 wi, vec3 wo) {
    vec3 h = wi + wo;
    float hz2 = max(h.z * h.z, TINY);
    float ex = ((h.x / alpha.x) * (h.x / alpha.x) + (h.y / alpha.y) * (h.y / alpha.y)) / hz2;
    return ks * (dot(h, h) / (PI * alpha.x * alpha.y * hz2 * hz2) * exp(-ex));
}

float ward_pdf(vec3 wi, vec3 wo) {
    vec3 s = wi + wo;
    vec3 h = normalize(s);
    float wo_h = 0.5 * length(s);
    float hz = h.z;
    float hz2 = max(hz * hz, TINY);
    float ex = ((h.x / alpha.x) * (h.x / alpha.x) + (h.y / alpha.y) * (h.y / alpha.y)) / hz2;
    float pdf_h = exp(-ex) / (PI * alpha.x * alpha.y * hz2 * hz);
    return hz > 0.0 ? pdf_h / (4.0 * max(wo_h, TINY)) : 0.0;
}

vec3 shade(vec3 n, vec3 t, vec3 b, vec3 o) {
    vec3 lo = vec3(dot(o, t), dot(o, b), dot(o, n));
    if (lo.z <= 0.0) return vec3(0.0);
    vec3 acc = vec3(0.0);
    // the solid angle of a base texel is (2 / R)^2 / (1 + u^2 + v^2)^(3/2) = (2 / R)^2 ma^3
    // for a unit direction whose major-axis component is ma (MipChain.texel_solid_angle)
    float texel = (2.0 / base_res) * (2.0 / base_res);
    for (int i = 0; i < NS; ++i) {
        // Ward's sampling in stretched form (brdf.Ward._sample_dir)
        float r = sqrt(-log(1.0 - ham[i].x));
        float phi = 2.0 * PI * ham[i].y;
        vec3 h = normalize(vec3(r * alpha.x * cos(phi), r * alpha.y * sin(phi), 1.0));
        vec3 li = 2.0 * dot(lo, h) * h - lo;
        float pdf = ward_pdf(li, lo);
        if (!(li.z > 0.0 && pdf > 0.0 && pdf < 3.0e38)) continue;  // weight 0, as BRDF.sample
        vec3 w = ward_eval(li, lo) * (li.z / max(pdf, TINY));
        vec3 wi = li.x * t + li.y * b + li.z * n;
        vec3 a = abs(wi);
        float ma = max(a.x, max(a.y, a.z));
        float omega_s = 1.0 / (float(NS) * max(pdf, 1e-30));  // the sample's share
        float omega_p = texel * ma * ma * ma;
        float lod = clamp(0.5 * log2(omega_s / omega_p) + lod_bias, 0.0, max_lod);
        acc += w * textureLod(env_mip, wi, lod).rgb;
    }
    return acc / float(NS);
}

#else
// ---- our method: lobes interpolated between the fixed views, integrated by prefiltered ----
// The table of SGBRDF.params, laid out once at upload (_gl_sgbrdf.lobe_table): for view j,
// lobe k, texel (2k, j) = (lobe mass w Z(kappa), log kappa) and texel (2k + 1, j) = (mu, 0)
// (kappa clamped to KAPPA_MIN first, exactly as SGBRDF.lobes), so the shader blends what
// SGBRDF.lobes blends. GREY (all masses grey, e.g. Ward with a grey ks): one texel (k, j) =
// (mass, log kappa, octahedral mu), half the fetches, which bound the frame on a GPU
uniform sampler2D lobe_tex;

#if GREY
// octahedral map of the unit sphere onto [-1, 1]^2 (lobe_table's encoding), inverted
vec3 oct_decode(vec2 e) {
    vec3 v = vec3(e, 1.0 - abs(e.x) - abs(e.y));
    if (v.z < 0.0) {
        vec2 sgn = vec2(v.x >= 0.0 ? 1.0 : -1.0, v.y >= 0.0 ? 1.0 : -1.0);
        v.xy = (1.0 - abs(v.yx)) * sgn;
    }
    return normalize(v);
}
#endif
#if GEODESIC
// the geodesic triangles and locate_triangle() come from geodesic.glsl
#define CORNERS 3
#else
uniform float view_theta[N_VIEWS];  // elevation of each view, increasing
#define CORNERS 2
#endif

vec3 shade(vec3 n, vec3 t, vec3 b, vec3 o) {
    vec3 q = vec3(dot(o, t), dot(o, b), dot(o, n));
    if (q.z <= 0.0) return vec3(0.0);  // SGBRDF.lobes: weight 0
    ivec3 vid = ivec3(0);
    vec3 bary = vec3(0.0);
#if GEODESIC
    // the geodesic triangle holding q (sphere.locate_views: largest smallest barycentric),
    // in the geodesic frame (g_x, g_y, g_z) = (q_y, q_z, q_x)
    vec3 d = vec3(q.y, q.z, q.x);
    locate_triangle(d, bary, vid);
    bary = max(bary, vec3(0.0));
    bary /= max(bary.x + bary.y + bary.z, TINY);
#else
    // linear in theta between the two nearest views, clamped (sgbrdf/_fit.py's _elevation_weights)
    float th = clamp(atan(length(q.xy), q.z), view_theta[0], view_theta[N_VIEWS - 1]);
    int j1 = 0;
    for (int j = 0; j < N_VIEWS; ++j) j1 += view_theta[j] < th ? 1 : 0;  // searchsorted
    j1 = clamp(j1, 1, N_VIEWS - 1);
    float s = clamp((th - view_theta[j1 - 1]) / (view_theta[j1] - view_theta[j1 - 1]), 0.0, 1.0);
    vid = ivec3(j1 - 1, j1, 0);
    bary = vec3(1.0 - s, s, 0.0);
    // the table holds azimuth 0: turn the lobes by the view's azimuth about the normal
    float r = length(q.xy);
    vec2 cs = r > 0.0 ? q.xy / r : vec2(1.0, 0.0);
#endif
    vec3 acc = vec3(0.0);
    for (int k = 0; k < NL; ++k) {
        vec3 mass = vec3(0.0);
        vec3 mu = vec3(0.0);
        float logk = 0.0;
        for (int c = 0; c < CORNERS; ++c) {  // 2 views (elevation) or 3 (geodesic)
#if GREY
            vec4 a = texelFetch(lobe_tex, ivec2(k, vid[c]), 0);
            mass += vec3(bary[c] * a.x);
            logk += bary[c] * a.y;
            mu += bary[c] * oct_decode(a.zw);
#else
            vec4 a = texelFetch(lobe_tex, ivec2(2 * k, vid[c]), 0);
            vec4 m = texelFetch(lobe_tex, ivec2(2 * k + 1, vid[c]), 0);
            mass += bary[c] * a.rgb;
            logk += bary[c] * a.a;
            mu += bary[c] * m.xyz;
#endif
        }
        if (max(mass.r, max(mass.g, mass.b)) <= 0.0) continue;
        mu = normalize(mu);
#if !GEODESIC
        mu = vec3(cs.x * mu.x - cs.y * mu.y, cs.y * mu.x + cs.x * mu.y, mu.z);
#endif
        float kappa = exp(logk);
        vec3 mw = mu.x * t + mu.y * b + mu.z * n;  // to the world frame
        // weight = mass / Z(kappa) and integrate() = lookup x Z(kappa) with the same Z
        float z = 6.283185307179586 / kappa * (1.0 - exp(-2.0 * kappa));
        acc += mass / z * integrate(mw, kappa);
    }
    return acc;
}
#endif

void main() {
    vec3 n, o, t, b;
#if SPHERE
#if ORTHO
    // sphere_hits' orthographic rays, one per pixel centre
    float x = gl_FragCoord.x * (2.0 / viewport.x) - 1.0;
    float y = gl_FragCoord.y * (2.0 / viewport.y) - 1.0;
    float r2 = x * x + y * y;
    if (!(r2 < 1.0)) discard;
    n = vec3(x, y, sqrt(max(1.0 - r2, 0.0)));
    o = vec3(0.0, 0.0, 1.0);
#else
    // Camera.rays at the pixel centre (y of the film runs down), then the analytic hit
    float fx = 1.0 - 2.0 * gl_FragCoord.x / viewport.x;
    float fy = 2.0 * gl_FragCoord.y / viewport.y - 1.0;
    vec3 d = normalize(fx * tan_half.x * cam_left + fy * tan_half.y * cam_up + cam_dir);
    float bq = dot(eye, d);
    float disc = bq * bq - eye_c;
    if (!(disc > 0.0)) discard;
    float tq = -bq - sqrt(disc);
    if (!(tq > 0.0)) discard;
    n = normalize(eye + tq * d);
    o = -d;
#endif
    // sphere_hits' tangent: increasing azimuth about +y, the frame's at the poles
    vec3 tf, bf;
    duff_frame(n, tf, bf);
    vec3 ta = vec3(n.z, 0.0, -n.x);
    float tl = length(ta);
    tangent_frame(n, tl > 1e-6 ? ta / tl : tf, t, b);
#else
    n = normalize(v_nrm);
#if ORTHO
    o = vec3(0.0, 0.0, 1.0);
#else
    o = normalize(eye - v_pos);
#endif
#if HAS_TANGENT
    tangent_frame(n, v_tan, t, b);
#else
    duff_frame(n, t, b);
#endif
#endif
    frag = vec4(shade(n, t, b, o), 1.0);
}

#endif
