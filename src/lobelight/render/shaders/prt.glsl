// Green et al. 2006, section 5: Gaussians interpolated across views per vertex and across the
// triangle per pixel, each integrated against the lighting with prefiltered lookups.
// Interpolation follows lobelight.model.blend_lobes: the light a lobe carries (e, its weight
// times its integral) blends linearly; width and mean blend over the live records (carrying at
// least FLOOR) with renormalised barycentrics. Per pixel the rasteriser does that with
// varyings premultiplied by the live flag, divided by the interpolated flag.
// Stages are selected by VERTEX_SHADER / FRAGMENT_SHADER; N_GAUSSIANS (Gaussians per view),
// N_INDIRECT (how many of the last hold indirect glossy transport,
// lobelight.model.Model.indirect_gaussians), HAS_SUN (the lighting has a sun), SUN_GLOSSY (its
// glossy reflection is shaded per pixel) and SUN_SHAPE (a sharp lobe reads its shape), ALBEDO_TEX (the diffuse albedo is read per pixel from
// textures, albedo.glsl, and the diffuse transfer is per unit albedo), SPECULAR_TEX (the glossy
// light is scaled per pixel by the textures' F0 over the vertices', render/_albedo.py) and DEPTH_ONLY (1: the
// depth pre-pass, which projects the vertices and shades nothing) are defined by the loader, and the per-frame values (camera,
// rotation, SH lighting, sun) come from frame.glsl's block. The torch path (render/_torch.py)
// mirrors this file step by step.
//
// The vertex stage's view interpolation and SH products depend on the camera and the lighting,
// not on the sub-pixel sample: with STAGE_PASS 1 they run once per frame, one vertex per
// vertex, captured by transform feedback as STAGE_TEXELS RGBA texels per vertex (stage.glsl),
// which the renderer copies into stage_tex; with FROM_STAGE 1 the shading pass's vertices
// read them there instead of computing them again for every sample.
//
// Two vec4 varyings per Gaussian: a float array varying takes a whole interpolator slot per
// element on many GPUs, so (e, live) and (mu offset, sigma) share slots; the sun's per-vertex
// inputs are compiled out when they are not shaded.

#if defined VERTEX_SHADER

in vec3 in_pos;
in vec3 in_normal;
#if HAS_SUN && !ALBEDO_TEX
in vec3 in_albedo;
#endif
#if ALBEDO_TEX
in vec2 in_uv;                 // lobelight.scene.AlbedoTexture: UV, layer, per-vertex factor
in float in_layer;
in vec3 in_factor;
#if defined(SPECULAR_TEX) && SPECULAR_TEX
in vec3 in_f0;                 // the bake's per-vertex F0 (render/_albedo.py specular_f0)
#endif
#endif
#if SUN_GLOSSY || LOBE_VIS_PASS
in vec4 in_sb0;                // the BRDF (render/_sun_glossy.py): alpha, specular (the sun's
in vec3 in_eta;                // widened by its disc; the correction pass's as it is), conductor
in vec3 in_k;                  // index eta + i k
#endif
#if LOBE_VIS && !FROM_STAGE
// the factor on this vertex's direct Gaussians' light this frame (lobe_visibility.glsl), from
// the correction pass's transform feedback
in vec3 in_rho;
#endif

uniform sampler2D gauss_tex;   // RGBA32F, 2 texels per record (e.rgb, sigma), (mu.xyz, 0)
uniform sampler2D diff_tex;    // RGBA32F, N_SH texels per vertex: transfer RGB
uniform sampler2D bounce_tex;  // RGBA32F, N_SH texels per vertex: its interreflected part
// the geodesic triangles and locate_triangle() come from geodesic.glsl
uniform int tex_width;         // width of gauss_tex and diff_tex

// per Gaussian k: [2k] (carried light e, 1 if the vertex's lobe is live else 0),
// [2k + 1] (live flag times (mean - the vertex's mirror direction), live flag times sigma)
out vec4 v_lobe[2 * N_GAUSSIANS];
out vec3 v_diffuse;
out vec3 v_pos;
out vec3 v_normal;
#if HAS_SUN && !ALBEDO_TEX
out vec3 v_albedo;
#endif
#if ALBEDO_TEX
out vec2 v_uv;
flat out int v_layer;
#if defined(SPECULAR_TEX) && SPECULAR_TEX
out vec3 v_f0;
#endif
out vec3 v_factor;
#endif
#if LOBE_VIS_PASS
// the correction pass (LOBE_VIS_PASS): each vertex's factor, captured by transform feedback
out vec3 v_rho;
#endif
#if STAGE_PASS
// WebGL 2's transform feedback captures no array nor array element: the stage's texels as
// outputs of their own, v_stage<i> texel i (lobelight.render.layout.stage_varyings)
out vec4 v_stage0;
#if STAGE_TEXELS > 1
out vec4 v_stage1;
#endif
#if STAGE_TEXELS > 2
out vec4 v_stage2;
#endif
#if STAGE_TEXELS > 3
out vec4 v_stage3;
#endif
#if STAGE_TEXELS > 4
out vec4 v_stage4;
#endif
#if STAGE_TEXELS > 5
out vec4 v_stage5;
#endif
#if STAGE_TEXELS > 6
out vec4 v_stage6;
#endif
#if STAGE_TEXELS > 7
out vec4 v_stage7;
#endif
#if STAGE_TEXELS > 8
out vec4 v_stage8;
#endif
#if STAGE_TEXELS > 9
out vec4 v_stage9;
#endif
#if STAGE_TEXELS > 10
out vec4 v_stage10;
#endif
#if STAGE_TEXELS > 11
out vec4 v_stage11;
#endif
#if STAGE_TEXELS > 12
out vec4 v_stage12;
#endif
#if STAGE_TEXELS > 13
out vec4 v_stage13;
#endif
#if STAGE_TEXELS > 14
out vec4 v_stage14;
#endif
#if STAGE_TEXELS > 15
out vec4 v_stage15;
#endif
#endif
#if SUN_GLOSSY || LOBE_VIS_PASS
out vec4 v_sb0;
out vec3 v_eta;
out vec3 v_k;
#endif

#if defined(GL_ES) && defined(SHARP) && SHARP && !STAGE_PASS
// OpenGL ES 3.00 has no gl_PrimitiveID: the web viewer draws the triangles unindexed, each
// corner carrying its vertex's id and its triangle's (reflection.glsl corners)
in float in_vertex;
in float in_face;
flat out int v_face;
#endif

// the depth pre-pass and the shading pass must rasterise the same depths
invariant gl_Position;

// Mitsuba's perspective sensor: x runs against cam_left, y along cam_up
vec4 project(vec3 p) {
    vec3 q = p - eye;
    float zc = dot(q, cam_dir);
    float n = depth_range.x, fa = depth_range.y;
    // the image moves by the sample's offset so that the pixel centres see the sample points
    // (Renderer's supersampling; zero for one sample per pixel)
    return vec4(-dot(q, cam_left) / tan_half.x + jitter.x * zc,
                dot(q, cam_up) / tan_half.y + jitter.y * zc,
                zc * (fa + n) / (fa - n) - 2.0 * fa * n / (fa - n), zc);
}

#if DEPTH_ONLY
void main() {
    gl_Position = project(in_pos);
}
#else
ivec2 at(int i) { return ivec2(i % tex_width, i / tex_width); }

void main() {
#if defined(GL_ES) && defined(SHARP) && SHARP && !STAGE_PASS
    int v = int(in_vertex + 0.5);
    v_face = int(in_face + 0.5);
#else
    int v = gl_VertexID;
#endif
#if FROM_STAGE
    ivec2 first = stage_at(v);  // stage.glsl
    for (int i = 0; i < 2 * N_GAUSSIANS; ++i) v_lobe[i] = stage_texel(first, i);
    v_diffuse = stage_texel(first, STAGE_DIFFUSE).rgb;
#else
    vec3 d = normalize(eye - in_pos);

    vec3 bdet;
    ivec3 views;
    locate_triangle(d, bdet, views);  // geodesic.glsl
    vec3 b = max(bdet, vec3(0.0));
    b /= max(b.x + b.y + b.z, 1e-30);

    vec3 mirror = 2.0 * dot(in_normal, d) * in_normal - d;
    for (int k = 0; k < N_GAUSSIANS; ++k) {
        vec3 e = vec3(0.0), mu = vec3(0.0);
        float sigma = 0.0, say = 0.0, above = 0.0;
        for (int c = 0; c < 3; ++c) {
            int r = 2 * ((v * 92 + views[c]) * N_GAUSSIANS + k);
            vec4 rec = texelFetch(gauss_tex, at(r), 0);
            vec4 m = texelFetch(gauss_tex, at(r + 1), 0);  // mean, above-the-horizon flag
            float live = (rec.r + rec.g + rec.b) / 3.0 >= FLOOR ? b[c] : 0.0;
            e += b[c] * rec.rgb;
            above += b[c] * m.w;
            say += live;
            sigma += live * rec.a;
            mu += live * m.xyz;
        }
        // the light averaged over the records above the horizon (model.horizon_scale)
        e = dot(in_normal, d) > 0.0 && above >= MIN_SAY ? e / above : e;
#if LOBE_VIS
        if (k < N_GAUSSIANS - N_INDIRECT) e *= in_rho;  // what the object blocks of the lighting
#endif
        bool ok = say >= MIN_SAY;
        float live = ok && (e.r + e.g + e.b) / 3.0 >= FLOOR ? 1.0 : 0.0;
        // the mean as an offset from this vertex's mirror direction (divide first: no underflow)
        v_lobe[2 * k] = vec4(ok ? e : vec3(0.0), live);
        v_lobe[2 * k + 1] = vec4(ok ? live * (normalize(mu / say) - mirror) : vec3(0.0),
                                 ok ? live * sigma / say : 0.0);
    }

    vec3 diffuse = vec3(0.0);
    for (int i = 0; i < N_SH; ++i) {
        diffuse += texelFetch(diff_tex, at(v * N_SH + i), 0).rgb * sh_light[i].rgb;
    }
#if HAS_BOUNCE
    // the sun's light bounced off the object (lobelight.model.Model.bounce)
    for (int i = 0; i < N_SH; ++i) {
        diffuse += texelFetch(bounce_tex, at(v * N_SH + i), 0).rgb * sh_sun[i].rgb;
    }
#endif
    v_diffuse = diffuse;
#if STAGE_PASS
    // texel i: v_lobe[i] below 2 N_GAUSSIANS, then the diffuse colour, then the direct light
    // (one line: GLSL 3.30 has no line continuation)
    vec3 direct = vec3(0.0);
    for (int k = 0; k < N_GAUSSIANS - N_INDIRECT; ++k) direct += v_lobe[2 * k].rgb;
    vec4 tail[2] = vec4[2](vec4(diffuse, 0.0), vec4(direct, 0.0));
#define STAGE_TEXEL(i) ((i) < 2 * N_GAUSSIANS ? v_lobe[min(i, 2 * N_GAUSSIANS - 1)] : tail[max(i - 2 * N_GAUSSIANS, 0)])
    v_stage0 = STAGE_TEXEL(0);
#if STAGE_TEXELS > 1
    v_stage1 = STAGE_TEXEL(1);
#endif
#if STAGE_TEXELS > 2
    v_stage2 = STAGE_TEXEL(2);
#endif
#if STAGE_TEXELS > 3
    v_stage3 = STAGE_TEXEL(3);
#endif
#if STAGE_TEXELS > 4
    v_stage4 = STAGE_TEXEL(4);
#endif
#if STAGE_TEXELS > 5
    v_stage5 = STAGE_TEXEL(5);
#endif
#if STAGE_TEXELS > 6
    v_stage6 = STAGE_TEXEL(6);
#endif
#if STAGE_TEXELS > 7
    v_stage7 = STAGE_TEXEL(7);
#endif
#if STAGE_TEXELS > 8
    v_stage8 = STAGE_TEXEL(8);
#endif
#if STAGE_TEXELS > 9
    v_stage9 = STAGE_TEXEL(9);
#endif
#if STAGE_TEXELS > 10
    v_stage10 = STAGE_TEXEL(10);
#endif
#if STAGE_TEXELS > 11
    v_stage11 = STAGE_TEXEL(11);
#endif
#if STAGE_TEXELS > 12
    v_stage12 = STAGE_TEXEL(12);
#endif
#if STAGE_TEXELS > 13
    v_stage13 = STAGE_TEXEL(13);
#endif
#if STAGE_TEXELS > 14
    v_stage14 = STAGE_TEXEL(14);
#endif
#if STAGE_TEXELS > 15
    v_stage15 = STAGE_TEXEL(15);
#endif
#endif
#endif  // FROM_STAGE
    v_pos = in_pos;
    v_normal = in_normal;
#if HAS_SUN && !ALBEDO_TEX
    v_albedo = in_albedo;
#endif
#if ALBEDO_TEX
    v_uv = in_uv;
    v_layer = int(in_layer + 0.5);
    v_factor = in_factor;
#if defined(SPECULAR_TEX) && SPECULAR_TEX
    v_f0 = in_f0;
#endif
#endif
#if SUN_GLOSSY || LOBE_VIS_PASS
    v_sb0 = in_sb0;
    v_eta = in_eta;
    v_k = in_k;
#endif

#if LOBE_VIS_PASS
    v_rho = lobe_visibility(v, in_normal, d, v_lobe, in_sb0, in_eta, in_k);
#endif
    gl_Position = project(in_pos);
}
#endif

#elif defined FRAGMENT_SHADER && DEPTH_ONLY

void main() {}

#elif defined FRAGMENT_SHADER && (LOBE_VIS_PASS || STAGE_PASS)

// the correction pass writes its transform feedback and rasterises nothing
out vec4 frag;

void main() { frag = vec4(0.0); }

#elif defined FRAGMENT_SHADER

in vec4 v_lobe[2 * N_GAUSSIANS];
in vec3 v_diffuse;
in vec3 v_pos;
in vec3 v_normal;
#if ALBEDO_TEX
in vec2 v_uv;
flat in int v_layer;
#if defined(SPECULAR_TEX) && SPECULAR_TEX
in vec3 v_f0;
// each layer's F0 (lobelight.scene.AlbedoTexture.specular), albedo_tex's layout
uniform sampler2DArray specular_tex;
#endif
in vec3 v_factor;
#endif
#if HAS_SUN
#if !ALBEDO_TEX
in vec3 v_albedo;
#endif

// the sun taken out of the diffuse lighting (render/_lighting.py), with its shadow map; its
// direction, irradiance and the map's frame are frame.glsl's
uniform sampler2DShadow shadow_map;
uniform sampler2D shadow_depth;   // the same map's depths, read without comparison
uniform float sun_tan;            // tan of the disc's angular radius (render/_sun_shadow.py)
uniform float shadow_res;         // the map's texels across

// point i of n of the Vogel spiral over the unit disc (render/_sun_shadow.py disc_points)
vec2 disc_point(int i, int n) {
    float a = float(i) * 2.399963229728653;
    return sqrt((float(i) + 0.5) / float(n)) * vec2(cos(a), sin(a));
}

// the visible fraction of the sun's disc at pos (world; n its shading normal) on a triangle of
// normal ng (the shadow map's frame, on the viewer's side): percentage-closer soft shadows over
// the directions of the torch path's rays (render/_sun_shadow.py), those of this sample's share
// (frame.glsl's tap_first and tap_step: a pixel's samples together take every direction)
float sun_visibility(vec3 pos, vec3 n, vec3 ng) {
    // pos in the map's [-1, 1]^3 frame
    vec3 q = shadow_frame * (pos - shadow_center) * shadow_scale;
    // the blocker search spans the penumbra of the farthest possible blocker (the bounding
    // sphere's side towards the sun, q.z = 1)
    float search = sun_tan * (1.0 - q.z) * 0.5;
    if (search * shadow_res < 1.0) {
        // hardware 2x2 percentage-closer filtering of the depth comparison at the point lifted
        // along its normal: a hard shadow
        q = shadow_frame * (pos + shadow_offset * n - shadow_center) * shadow_scale;
        return texture(shadow_map, vec3(q.xy * 0.5 + 0.5, -q.z * 0.5 + 0.5 - shadow_bias));
    }
    vec2 uv = q.xy * 0.5 + 0.5;
    float z = -q.z * 0.5 + 0.5 - shadow_bias;
    // every tap compares against the triangle's plane there, depth z + dot(dz, offset), less
    // the plane's rise over a texel (the hardware filter's 2x2 footprint)
    vec2 dz = ng.xy / max(abs(ng.z), 0.1 * length(ng)) * sign(ng.z);
    z -= (abs(dz.x) + abs(dz.y)) / shadow_res;
    float height = 0.0;
    int blockers = 0;
    for (int i = 0; i < BLOCKER_SAMPLES; ++i) {
        vec2 o = search * disc_point(i, BLOCKER_SAMPLES);
        float zr = z + dot(dz, o);
        float zb = texture(shadow_depth, uv + o).r;
        if (zb < zr) {
            height += zr - zb;
            blockers += 1;
        }
    }
    // directions below the triangle's plane are blocked by the surface itself, as the torch
    // path's rays that leave into the solid
    bool above = ng.z > sun_tan * length(ng.xy);
    if (blockers == 0 && above) return 1.0;
    // the penumbra's radius in map coordinates: tan(r) times the blockers' mean height
    float w = blockers > 0 ? sun_tan * height / float(blockers) : 0.0;
    float vis = 0.0;
    float taps = 0.0;
    for (int i = int(tap_first); i < SHADOW_SAMPLES; i += max(int(tap_step), 1)) {
        taps += 1.0;
        vec2 p = disc_point(i, SHADOW_SAMPLES);
        if (ng.z + sun_tan * dot(ng.xy, p) <= 0.0) continue;
        // the ray towards direction i, placed by the blockers' mean height, is moved to the
        // height of the blocker found there (a ray at height h crosses the map at tan(r) h p):
        // blockers at several heights each get their own offset
        float wi = w;
        float h = z + w * dot(dz, p) - texture(shadow_depth, uv + w * p).r;
        if (h > 0.0) wi = sun_tan * h;
        vis += texture(shadow_map, vec3(uv + wi * p, z + wi * dot(dz, p)));
    }
    return vis / taps;
}
#endif
#if SUN_GLOSSY
in vec4 v_sb0;
in vec3 v_eta;
in vec3 v_k;

// the sun's glossy reflection per pixel (render/_sun_glossy.py): then the Gaussians' lighting is
// the map without the sun; the BRDFs are lobelight.brdf's
uniform float sun_spread;         // the sun disc's RMS angle (radians)
#endif

const float PI = 3.14159265358979;

#if SUN_GLOSSY
// the sun's BRDF at this pixel: the vertices' parameters widened by its disc
vec3 sun_brdf_cos(vec3 l, vec3 v, vec3 n) { return brdf_cos(l, v, n, v_sb0, v_eta, v_k); }

// what the sun sends through an indirect Gaussian of sharpness lam, per unit carried light
// (render/_sun_glossy.py sun_through: the lobe widened by the disc, its integral kept)
float sun_through(vec3 mu, float lam) {
    float ratio = 1.0 / (1.0 + lam * 0.5 * sun_spread * sun_spread);
    vec3 dd = mu - sun_dir;
    float g = exp(-lam * ratio * 0.5 * dot(dd, dd));
    float integral = lam < 1e-4 ? 4.0 * PI * (1.0 - lam) : 2.0 * PI * (1.0 - exp(-2.0 * lam)) / lam;
    return ratio * g / integral;
}

#if defined(SHARP) && SHARP
uniform sampler2D whole_atlas;  // the whole map's chain, atlas's layout (atlas: without the sun)
uniform float sun_tail;         // the analytic highlight's tail factor (_sun_glossy.py tail_scale)

// the sun's glossy light off a sharp lobe, before its visibility (render/_reflection.py
// sun_sharp, docs/method.md equation 12): [tail (A - D) + S]+, A the disc's analytic highlight,
// D what the mixture's lookups read of the sun as the Gaussian disc (per lookup of sharpness
// lam at d, E lam' / (2 pi) exp(lam' (d.l - 1)), 1 / lam' = 1 / lam + sigma^2 / 2), S what they
// read of the sun's own pixels (the whole chain less atlas) for the Gaussians that resolve the
// disc (lam_i sigma^2 >= SUN_RESOLVED), D for the others; with SUN_SHAPE 0 none of them does
// anywhere (lobelight.render.layout.sun_shape_resolved) and the shape's lookups are left out.
// The world frame; lookups rotated. lobe: the point's (reflection.glsl lobe_at), tail its tail
// factor.
vec3 sun_shape(vec3 spec, vec3 n, vec3 d, Lobe lobe, float tail) {
    float nv = max(dot(n, d), 0.0);
    vec3 r = 2.0 * dot(n, d) * n - d;
    vec3 t = across(n, r);
    float s2 = sun_spread * sun_spread;
    bool warp = sharp_warp > 0.0;
    float c = warp ? max(nv, SHARP_NV_MIN) : 1.0;
    float disc_all = 0.0, disc_res = 0.0;
    vec3 shape = vec3(0.0);
    for (int j = 0; j < MIXTURE_LIVE; ++j) {  // the Gaussians of non-zero weight
        int i = sharp_live[j];
        float lam_i = sharp_lam[i] * lobe.scale;
        float lam = warp ? lam_i / (c * c) : lam_i;
        float lw = 1.0 / (1.0 / lam + 0.5 * s2);
        vec3 step = warp ? sqrt(max(1.0 - c * c, 0.0) / lam_i) * t : vec3(0.0);
        vec3 p = normalize(r + step), q = normalize(r - step);
        vec3 a = p - sun_dir, b = q - sun_dir;
        float g = sharp_weight[i] * lw / (2.0 * PI)
                  * 0.5 * (exp(-0.5 * lw * dot(a, a)) + exp(-0.5 * lw * dot(b, b)));
        disc_all += g;
#if SUN_SHAPE
        if (lam_i * s2 < SUN_RESOLVED) continue;
        disc_res += g;
        vec3 rp = rot_t * p, rq = rot_t * q;
        shape += (0.5 * sharp_weight[i])
                 * (prefiltered_lookup_in(whole_atlas, rp, lam) - prefiltered_lookup(rp, lam)
                    + prefiltered_lookup_in(whole_atlas, rq, lam) - prefiltered_lookup(rq, lam));
#endif
    }
    vec3 albedo = directional_albedo(lobe, nv);
    vec3 out_ = tail * (spec - albedo * disc_all * sun_e) + albedo * (disc_all - disc_res) * sun_e
                + albedo * max(shape, 0.0);
    return max(out_, 0.0);
}
#endif
#endif

// the prefiltered lookups (integrate, level_lookup) come from prefiltered.glsl

out vec4 frag;

void main() {
#if ALBEDO_TEX
    // the transfer is per unit albedo: times the albedo read here
    vec3 albedo_px = v_factor * albedo_at(v_uv, v_layer);
#endif
#if defined(SPECULAR_TEX) && SPECULAR_TEX
    // the glossy light's factor, the texel's F0 over the vertices' (render/_albedo.py
    // specular_ratio), read in uniform control flow
    vec3 f0_tex = texture_at(specular_tex, v_uv, v_layer);
    vec3 spec_ratio = v_layer == 0 ? vec3(1.0) : f0_tex / max(v_f0, vec3(F0_MIN));
#else
    const vec3 spec_ratio = vec3(1.0);
#endif
#if ALBEDO_TEX
    vec3 c = diffuse_on * v_diffuse * albedo_px;
#elif HAS_SUN
    vec3 albedo_px = v_albedo;
    vec3 c = diffuse_on * v_diffuse;
#else
    vec3 c = diffuse_on * v_diffuse;
#endif
    vec3 n = normalize(v_normal);
    vec3 d = normalize(eye - v_pos);
#if defined(SHARP) && SHARP
    // the pixel's lobe (reflection.glsl lobe_at) and the share of it shaded per pixel, from
    // its sharp corners (render/_torch.py _glossy)
    ivec3 cc, cs;
    vec3 cb;
    corners(v_pos, cc, cs, cb);
    float share;
    Lobe lobe = lobe_at(cc, cb, true, share);
#endif
#if SUN_GLOSSY
    bool sun_gl = glossy_on > 0.0;
#else
    const bool sun_gl = false;
#endif
#if HAS_SUN
    if (sun_on > 0.0 && (diffuse_on > 0.0 || sun_gl)) {
        // the triangle's normal, on the viewer's side, in the map's frame (derivatives before
        // the branch on the cosine, which is not uniform across a quad)
        vec3 ng = cross(dFdx(v_pos), dFdy(v_pos));
        ng = shadow_frame * (dot(ng, d) < 0.0 ? -ng : ng);
        float cosine = dot(n, sun_dir);
        if (cosine > 0.0) {
            float vis = sun_visibility(v_pos, n, ng);
            if (diffuse_on > 0.0) c += albedo_px * (0.3183098861837907 * cosine * vis) * sun_e;
#if SUN_GLOSSY
            if (sun_gl) {
                vec3 spec = sun_brdf_cos(sun_dir, d, n) * sun_e;
#if defined(SHARP) && SHARP
#if SHARP_VARYING
                // tail_scale per point: GGX's widened alpha'^2 = alpha^2 + spread^2 / 4
                float a2 = lobe.alpha * lobe.alpha;
                float tail = a2 / max(a2 + 0.25 * sun_spread * sun_spread, 1e-30);
#else
                float tail = sun_tail;
#endif
                if (share > 0.0) spec = mix(spec, sun_shape(spec, n, d, lobe, tail), share);
#endif
                c += spec * vis * spec_ratio;
            }
#endif
        }
    }
#endif
    if (glossy_on > 0.0) {
        vec3 before = c;  // the glossy light below is scaled by spec_ratio
        // the pixel's own mirror direction, from its interpolated normal and view direction:
        // the blended offsets are re-based on it (lobelight.model.blend_lobes, frame=)
        vec3 mirror = 2.0 * dot(n, d) * n - d;
        float fitted = 1.0;  // the fitted Gaussians' share of the pixel
#if defined(SHARP) && SHARP
        // the material's own lobe at the pixel's reflected direction (reflection.glsl,
        // render/_reflection.py): the object where the pixel's ray meets it, or else where
        // the corners' hit tiles find it, the environment in the rest of the lobe (the tiles'
        // hit-free share around it); a lobe varying per vertex at its sharp corners' share,
        // the Gaussians at the rest
        fitted = 1.0 - share;
        if (share > 0.0) {
            float nv = max(dot(n, d), 0.0);
#if HIT_TILES
            vec4 seen = object_light(v_pos, mirror, nv, cs, cb, lobe.scale);
#else
            // no vertex's hit tile finds the object (a convex mesh): the lobe sees the
            // environment alone, and the hits' code is left out
            const vec4 seen = vec4(0.0);
#endif
            vec3 albedo = directional_albedo(lobe, nv);
            float vis = 1.0;
            vec3 hit = vec3(0.0);
            if (seen.a == EXACT_HIT) {  // the pixel's own ray meets the object
                vis = 0.0;
                hit = seen.rgb;
            } else if (seen.a > 0.0) {
                vis = cb.x * hit_free(cs.x, mirror) + cb.y * hit_free(cs.y, mirror)
                      + cb.z * hit_free(cs.z, mirror);
                hit = seen.rgb / seen.a;
            }
            vec3 env = sharp_lighting(rot_t * mirror, rot_t * across(n, mirror), nv, 0.0,
                                      lobe.scale);
            c += share * albedo * (env * vis + (1.0 - vis) * hit);
        }
#endif
        for (int k = 0; k < N_GAUSSIANS && fitted > 0.0; ++k) {
            vec4 el = v_lobe[2 * k];
            vec4 ms = v_lobe[2 * k + 1];
            float say = el.w;  // the live corners' barycentric weight
            if (say < MIN_SAY) continue;
            float sigma = ms.w / say;
            vec3 mu = normalize(mirror + ms.xyz / say);
            c += fitted * el.rgb * prefiltered_lookup(rot_t * mu, 1.0 / (sigma * sigma));
#if SUN_GLOSSY
            // the sun's light reflected off the object into the indirect lobes
            if (sun_gl && sun_on > 0.0 && k >= N_GAUSSIANS - N_INDIRECT) {
                c += fitted * el.rgb * sun_e * sun_through(mu, 1.0 / (sigma * sigma));
            }
#endif
        }
        c = before + (c - before) * spec_ratio;
    }
    frag = vec4(c, 1.0);
}

#endif
