// A sharp reflection placed per pixel (render/_reflection.py, whose formulas these are): the
// material's own lobe, a mixture of MIXTURE Gaussians, at the pixel's reflected direction,
// times its directional albedo; where a corner's hit tile (lobelight.model.hit_tiles) finds
// the object, the object shaded where it is seen (object_light: where the pixel's own ray,
// walked from a tile's triangle, meets the object, there and in the whole lobe), and the
// environment in the rest of the lobe. A hit's own visible fraction is read from its corners'
// octahedral visibility tiles (lobelight.model.visibility_tiles). Included in prt.glsl's fragment stage
// when SHARP is 1; VIS_RES, MIXTURE, MIXTURE_LIVE, SHARP_LIVE, HIT_TILES and ALBEDO_STEPS are
// defined by the loader.

uniform isampler2D face_tex;      // RGB32I, face_width wide: each triangle's corner vertex ids,
                                  // then from texel nbr_offset each triangle's neighbours
                                  // (lobelight.geometry.adjacency.face_neighbours)
uniform int face_width;
uniform int nbr_offset;
uniform sampler2D pos_tex;        // RGBA32F, face_width wide: vertex positions and each vertex's
                                  // hit-tile slot (-1: its tile finds nothing)
uniform sampler2D nrm_tex;        // RGB32F: vertex normals, face_width wide
uniform sampler2D alb_tex;        // RGB32F: vertex diffuse albedos, face_width wide
// the hit tiles (lobelight.model.hit_tiles) of the vertices whose tile finds the object, each
// at its vertex's slot, hit_per_row tiles per row: R32I triangle ids (-1: none), R16F distances
uniform isampler2D hit_face_tex;
uniform sampler2D hit_dist_tex;
uniform int hit_per_row;

// the first texel of hit-tile slot s
ivec2 hit_origin(int s) { return ivec2(s % hit_per_row, s / hit_per_row) * VIS_RES; }
uniform float sharp_weight[MIXTURE];
// the mixture's Gaussians of non-zero weight, MIXTURE_LIVE of them (a Phong lobe is one of the
// five; lobelight.render.layout.sharp_shader_defines): the loops over the mixture run over these
// alone, as a rasteriser that runs every branch for every pixel (SwiftShader, llvmpipe) would
// still pay a skipped Gaussian's arithmetic
const int sharp_live[MIXTURE_LIVE] = int[MIXTURE_LIVE](SHARP_LIVE);
uniform float sharp_lam[MIXTURE];
uniform float sharp_warp;         // 1: the sharpness divides by n.v (microfacet lobes)
uniform vec3 sharp_albedo[ALBEDO_STEPS];
#ifndef SHARP_VARYING
#define SHARP_VARYING 0
#endif
#if SHARP_VARYING
// a glTF lobe varying per vertex (lobelight.brdf.SharpLobe): sharp_lam is the mixture at
// roughness VARYING_ALPHA_REF; each vertex's alpha and F0, face_width wide, alpha negative at
// a vertex the Gaussians shade; the albedo's scale and bias of F0 over (n.v, log alpha)
// (lobelight.brdf.schlick_split), ALBEDO_STEPS x SPLIT_ALPHAS
uniform sampler2D lobe_tex;       // RGBA32F: alpha (signed), F0
uniform sampler2D split_tex;      // RG32F
#endif

// a point's lobe (lobelight.brdf.SharpLobe.at): its sharpness factor over sharp_lam's, and
// for a lobe varying per vertex its roughness and F0
struct Lobe {
    float scale;
    float alpha;
    vec3 f0;
};

// the share of the hit-tile texels of slot s around direction d that find no hit, bilinear
// (render/_reflection.py hit_free_fraction); all of them for a vertex without hits (s < 0)
float hit_free(int s, vec3 d) {
    if (s < 0) return 1.0;
    ivec2 x0;
    vec2 f;
    tile_bilinear(d, x0, f);
    ivec2 o = hit_origin(s) + x0;
    float a = texelFetch(hit_face_tex, o, 0).r < 0 ? 1.0 : 0.0;
    float b = texelFetch(hit_face_tex, o + ivec2(1, 0), 0).r < 0 ? 1.0 : 0.0;
    float c = texelFetch(hit_face_tex, o + ivec2(0, 1), 0).r < 0 ? 1.0 : 0.0;
    float e = texelFetch(hit_face_tex, o + ivec2(1, 1), 0).r < 0 ? 1.0 : 0.0;
    return mix(mix(a, b, f.x), mix(c, e, f.x), f.y);
}

ivec2 at_face_width(int i) { return ivec2(i % face_width, i / face_width); }

// the barycentrics of p projected onto the plane of triangle (p0, p1, p2), unclamped
// (render/_reflection.py _barycentrics)
vec3 barycentrics(vec3 p0, vec3 p1, vec3 p2, vec3 p) {
    vec3 n = cross(p1 - p0, p2 - p0);
    float inv = 1.0 / max(dot(n, n), 1e-30);
    float b1 = dot(cross(p - p0, p2 - p0), n) * inv;
    float b2 = dot(cross(p1 - p0, p - p0), n) * inv;
    return vec3(1.0 - b1 - b2, b1, b2);
}

// how far the ray from p along r goes to the plane of triangle (p0, p1, p2): t (the tile's
// distance) where the ray runs nearly along the plane, meets it behind p, or crosses it off the
// triangle (render/_reflection.py _plane_distance)
float plane_distance(vec3 p0, vec3 p1, vec3 p2, vec3 p, vec3 r, float t) {
    vec3 n = cross(p1 - p0, p2 - p0);
    float rn = dot(r, n);
    float tp = dot(p0 - p, n) / (rn != 0.0 ? rn : 1.0);
    // the crossing on the triangle or near it
    vec3 b = barycentrics(p0, p1, p2, p + tp * r);
    bool near = min(min(b.x, b.y), b.z) >= -HIT_PLANE_MARGIN;
    return abs(rn) >= HIT_PLANE_COS_MIN * length(r) * length(n) && tp > 0.0 && near ? tp : t;
}

// the triangle g the ray from p along r meets, and how far along the ray (t), found by walking
// from triangle f across the edge beyond which the ray crosses the current triangle's plane, at
// most HIT_WALK_STEPS triangles (render/_reflection.py walk_to_hit); false where the walk does
// not arrive: the ray runs nearly along a plane or meets it behind p, an edge has no
// neighbour, the steps run out, or the triangle it arrives at faces away from the ray (its
// corners' normals on the ray's side)
bool walk_to_hit(int f, vec3 p, vec3 r, out int g, out float t) {
    g = f;
    t = 0.0;
    for (int k = 0; k < HIT_WALK_STEPS; ++k) {
        ivec3 c = texelFetch(face_tex, at_face_width(g), 0).xyz;
        vec3 p0 = texelFetch(pos_tex, at_face_width(c.x), 0).xyz;
        vec3 p1 = texelFetch(pos_tex, at_face_width(c.y), 0).xyz;
        vec3 p2 = texelFetch(pos_tex, at_face_width(c.z), 0).xyz;
        vec3 n = cross(p1 - p0, p2 - p0);
        float rn = dot(r, n);
        // (a triangle of no area has no plane to cross)
        if (abs(rn) == 0.0 || abs(rn) < HIT_PLANE_COS_MIN * length(r) * length(n)) return false;
        t = dot(p0 - p, n) / rn;
        if (t <= 0.0) return false;
        vec3 b = barycentrics(p0, p1, p2, p + t * r);
        float m = min(min(b.x, b.y), b.z);
        if (m >= 0.0) {
            vec3 ns = texelFetch(nrm_tex, at_face_width(c.x), 0).xyz
                      + texelFetch(nrm_tex, at_face_width(c.y), 0).xyz
                      + texelFetch(nrm_tex, at_face_width(c.z), 0).xyz;
            return dot(ns, r) < 0.0;
        }
        ivec3 nb = texelFetch(face_tex, at_face_width(nbr_offset + g), 0).xyz;
        g = b.x == m ? nb.x : (b.y == m ? nb.y : nb.z);
        if (g < 0) return false;
    }
    return false;
}

// the barycentrics of p projected onto triangle (p0, p1, p2), clamped to it
// (render/_reflection.py _project)
vec3 projected(vec3 p0, vec3 p1, vec3 p2, vec3 p) {
    vec3 b = max(barycentrics(p0, p1, p2, p), 0.0);
    return b / max(b.x + b.y + b.z, 1e-30);
}

// the corners of triangle f, their hit-tile slots s and the barycentrics of p projected onto it
void triangle_at(int f, vec3 p, out ivec3 c, out ivec3 s, out vec3 b) {
    c = texelFetch(face_tex, at_face_width(f), 0).xyz;
    vec4 p0 = texelFetch(pos_tex, at_face_width(c.x), 0);
    vec4 p1 = texelFetch(pos_tex, at_face_width(c.y), 0);
    vec4 p2 = texelFetch(pos_tex, at_face_width(c.z), 0);
    s = ivec3(floor(vec3(p0.w, p1.w, p2.w) + 0.5));
    b = projected(p0.xyz, p1.xyz, p2.xyz, p);
}

#ifdef GL_ES
flat in int v_face;  // the triangle's id from its corners (prt.glsl: OpenGL ES has no gl_PrimitiveID)
#endif

// the fragment's triangle corners, their hit-tile slots and barycentrics, from its primitive
// id and position
void corners(vec3 p, out ivec3 c, out ivec3 s, out vec3 b) {
#ifdef GL_ES
    triangle_at(v_face, p, c, s, b);
#else
    triangle_at(gl_PrimitiveID, p, c, s, b);
#endif
}

// the visible fraction at direction r of a point of corners c and barycentrics b
float visible_fraction(ivec3 c, vec3 b, vec3 r) {
    return b.x * tile_lookup(c.x, r) + b.y * tile_lookup(c.y, r) + b.z * tile_lookup(c.z, r);
}

// E(n.v) of lobe l: linear in the table at n.v = (k + 0.5) / ALBEDO_STEPS, clamped at its
// ends; for a lobe varying per vertex f0 A + B, bilinear in n.v and log alpha
// (lobelight.brdf.SharpLobe.directional_albedo)
vec3 directional_albedo(Lobe l, float nv) {
    float x = clamp(clamp(nv, 0.0, 1.0) * float(ALBEDO_STEPS) - 0.5, 0.0, float(ALBEDO_STEPS - 1));
    int i = min(int(floor(x)), ALBEDO_STEPS - 2);
#if SHARP_VARYING
    float y = (log(max(l.alpha, SPLIT_ALPHA_MIN)) - log(SPLIT_ALPHA_MIN))
              / (log(SPLIT_ALPHA_MAX) - log(SPLIT_ALPHA_MIN));
    y = clamp(y * float(SPLIT_ALPHAS - 1), 0.0, float(SPLIT_ALPHAS - 1));
    int j = min(int(floor(y)), SPLIT_ALPHAS - 2);
    vec2 f = vec2(x - float(i), y - float(j));
    vec2 ab = mix(mix(texelFetch(split_tex, ivec2(i, j), 0).rg,
                      texelFetch(split_tex, ivec2(i + 1, j), 0).rg, f.x),
                  mix(texelFetch(split_tex, ivec2(i, j + 1), 0).rg,
                      texelFetch(split_tex, ivec2(i + 1, j + 1), 0).rg, f.x), f.y);
    return l.f0 * ab.x + ab.y;
#else
    return mix(sharp_albedo[i], sharp_albedo[i + 1], x - float(i));
#endif
}

// the lobe at a point of corners c and barycentrics b (lobelight.brdf.SharpLobe.at): the
// material's own, or for a lobe varying per vertex the corners' roughness blended as
// variances and their F0 linearly, over the sharp corners alone with sharp_only; share: the
// sharp corners' barycentric weight (1 for a material constant over the mesh)
Lobe lobe_at(ivec3 c, vec3 b, bool sharp_only, out float share) {
#if SHARP_VARYING
    vec4 l0 = texelFetch(lobe_tex, at_face_width(c.x), 0);
    vec4 l1 = texelFetch(lobe_tex, at_face_width(c.y), 0);
    vec4 l2 = texelFetch(lobe_tex, at_face_width(c.z), 0);
    vec3 s = vec3(l0.r > 0.0 ? 1.0 : 0.0, l1.r > 0.0 ? 1.0 : 0.0, l2.r > 0.0 ? 1.0 : 0.0);
    share = dot(b, s);
    vec3 w = sharp_only ? b * s : b;
    w /= max(w.x + w.y + w.z, 1e-30);
    float a2 = w.x * l0.r * l0.r + w.y * l1.r * l1.r + w.z * l2.r * l2.r;
    vec3 f0 = w.x * l0.gba + w.y * l1.gba + w.z * l2.gba;
    return Lobe(VARYING_ALPHA_REF * VARYING_ALPHA_REF / max(a2, 1e-30), sqrt(a2), f0);
#else
    share = 1.0;
    return Lobe(1.0, 0.0, vec3(0.0));
#endif
}

// the unit direction across r within the plane of r and n (zero where they are parallel)
vec3 across(vec3 n, vec3 r) {
    vec3 t = n - dot(n, r) * r;
    return t * inversesqrt(max(dot(t, t), 1e-30));
}

// sum_i a_i L(R; lam_i): the lighting of the atlas tex under the lobe's mixture at R, t the
// plane of incidence's direction across R (both rotated); a microfacet lobe as two lookups of
// sharpness lam_i / (n.v)^2 at R +- s_i t, s_i^2 = (1 - (n.v)^2) / lam_i; each lookup's
// variance grown by blur; lam_i = sharp_lam[i] scale (render/_reflection.py shade,
// lobe_points), over the Gaussians of non-zero weight (sharp_live)
vec3 sharp_lighting_in(sampler2D tex, vec3 r, vec3 t, float nv, float blur, float scale) {
    vec3 acc = vec3(0.0);
    if (sharp_warp > 0.0) {
        float c = max(nv, SHARP_NV_MIN);
        for (int j = 0; j < MIXTURE_LIVE; ++j) {
            int i = sharp_live[j];
            float lam_i = sharp_lam[i] * scale;
            float lam = 1.0 / ((c * c) / lam_i + blur);
            vec3 step = sqrt(max(1.0 - c * c, 0.0) / lam_i) * t;
            acc += (0.5 * sharp_weight[i]) * (prefiltered_lookup_in(tex, normalize(r + step), lam)
                                              + prefiltered_lookup_in(tex, normalize(r - step), lam));
        }
        return acc;
    }
    for (int j = 0; j < MIXTURE_LIVE; ++j) {
        int i = sharp_live[j];
        acc += sharp_weight[i]
               * prefiltered_lookup_in(tex, r, 1.0 / (1.0 / (sharp_lam[i] * scale) + blur));
    }
    return acc;
}

vec3 sharp_lighting(vec3 r, vec3 t, float nv, float blur, float scale) {
    return sharp_lighting_in(atlas, r, t, nv, blur, scale);
}

// the variance of the directions a hit's own reflection is seen from: the pixel's lobe's
// core Gaussian (its sharpness factor scale), grown by the hit's curvature over the distance
// (render/_reflection.py hit_spread)
float hit_spread(float nv, float dist, float curvature, float scale) {
    float var = 1.0 / (sharp_lam[SPREAD_GAUSSIAN] * scale);
    if (sharp_warp > 0.0) var /= max(nv, SHARP_NV_MIN);
    float g = 1.0 + 2.0 * curvature * dist;
    return var * g * g;
}

#if HAS_SUN
float sun_visibility(vec3 pos, vec3 n, vec3 ng);  // prt.glsl
#endif
#if SUN_GLOSSY
vec3 sun_brdf_cos(vec3 l, vec3 v, vec3 n);  // prt.glsl
float sun_through(vec3 mu, float lam);      // prt.glsl
#endif

// a triangle the texels of hit-tile slot s around direction d find (its bilinear footprint,
// in the order hit_free reads it), -1 where none does (render/_reflection.py footprint_face)
int footprint_face(int s, vec3 d) {
    ivec2 x0;
    vec2 f;
    tile_bilinear(d, x0, f);
    ivec2 o = hit_origin(s) + x0;
    int a = texelFetch(hit_face_tex, o, 0).r;
    if (a >= 0) return a;
    a = texelFetch(hit_face_tex, o + ivec2(1, 0), 0).r;
    if (a >= 0) return a;
    a = texelFetch(hit_face_tex, o + ivec2(0, 1), 0).r;
    return a >= 0 ? a : texelFetch(hit_face_tex, o + ivec2(1, 1), 0).r;
}

// the texel of hit-tile slot s holding direction d (lobelight.geometry.octahedral.nearest_texel)
ivec2 hit_texel(int s, vec3 d) {
    vec2 p = oct_encode(d);
    ivec2 x = clamp(ivec2(floor((p + 1.0) * (0.5 * float(VIS_RES)))), ivec2(0), ivec2(VIS_RES - 1));
    return hit_origin(s) + x;
}

// a triangle's curvature, radians per unit length: the mean over its edges of the corners'
// normals' turn over the edge's length (render/_reflection.py face_curvature)
float face_curvature(vec3 p0, vec3 p1, vec3 p2, vec3 n0, vec3 n1, vec3 n2) {
    return (length(n0 - n1) / max(length(p0 - p1), 1e-30) + length(n1 - n2) / max(length(p1 - p2), 1e-30)
            + length(n2 - n0) / max(length(p2 - p0), 1e-30)) / 3.0;
}

// the object's radiance towards -r at the hit on triangle f of the ray from pixel point p along
// r (dist the tile's distance: plane_distance), the pixel's n.v nv_px and its lobe's sharpness
// factor scale_px (render/_reflection.py object_light, _hit_light): its direct
// sharp reflection (its own lobe, blurred by the pixel's, hit_spread), diffuse colour,
// indirect Gaussians (the current view's, re-based on its reflected direction) and the sun's
// light
vec3 hit_light(int f, vec3 p, float dist, vec3 r, float nv_px, float scale_px) {
    ivec3 c = texelFetch(face_tex, at_face_width(f), 0).xyz;
    ivec2 t0 = at_face_width(c.x), t1 = at_face_width(c.y), t2 = at_face_width(c.z);
    vec3 p0 = texelFetch(pos_tex, t0, 0).xyz;
    vec3 p1 = texelFetch(pos_tex, t1, 0).xyz;
    vec3 p2 = texelFetch(pos_tex, t2, 0).xyz;
    // the hit where the pixel's ray meets the triangle's plane, projected onto the triangle
    dist = plane_distance(p0, p1, p2, p, r, dist);
    vec3 b = projected(p0, p1, p2, p + dist * r);
    vec3 n0 = texelFetch(nrm_tex, t0, 0).xyz;
    vec3 n1 = texelFetch(nrm_tex, t1, 0).xyz;
    vec3 n2 = texelFetch(nrm_tex, t2, 0).xyz;
    vec3 pos = b.x * p0 + b.y * p1 + b.z * p2;
    vec3 n = normalize(b.x * n0 + b.y * n1 + b.z * n2);
    vec3 v = -r;
    float nvs = dot(n, v);
    vec3 rh = 2.0 * nvs * n - v;
    float nv = max(nvs, 0.0);
    float vis = visible_fraction(c, b, rh);
    float share;
    Lobe lobe = lobe_at(c, b, false, share);
    vec3 albedo = directional_albedo(lobe, nv);
    float blur = hit_spread(nv_px, dist, face_curvature(p0, p1, p2, n0, n1, n2), scale_px);
    vec3 light = albedo * sharp_lighting(rot_t * rh, rot_t * across(n, rh), nv, blur, lobe.scale)
                 * vis;
    // the corners' vertex stage this frame (stage.glsl)
    ivec2 s0 = stage_at(c.x), s1 = stage_at(c.y), s2 = stage_at(c.z);
#if ALBEDO_TEX
    // the transfer is per unit albedo: the hit's vertices' own albedos (render/_albedo.py
    // hit_diffuse_light)
    light += b.x * stage_texel(s0, STAGE_DIFFUSE).rgb * texelFetch(alb_tex, t0, 0).rgb
             + b.y * stage_texel(s1, STAGE_DIFFUSE).rgb * texelFetch(alb_tex, t1, 0).rgb
             + b.z * stage_texel(s2, STAGE_DIFFUSE).rgb * texelFetch(alb_tex, t2, 0).rgb;
#else
    light += b.x * stage_texel(s0, STAGE_DIFFUSE).rgb
             + b.y * stage_texel(s1, STAGE_DIFFUSE).rgb
             + b.z * stage_texel(s2, STAGE_DIFFUSE).rgb;
#endif
    vec3 direct = (b.x * stage_texel(s0, STAGE_DIRECT) + b.y * stage_texel(s1, STAGE_DIRECT)
                   + b.z * stage_texel(s2, STAGE_DIRECT)).rgb;
    float v_fit = clamp((direct.r + direct.g + direct.b) /
                        max(albedo.r + albedo.g + albedo.b, 1e-30), 0.0, 1.0);
    float scale = clamp((1.0 - vis) / max(1.0 - v_fit, OCCLUDED_FLOOR), 0.0, INDIRECT_SCALE_MAX);
    for (int k = N_GAUSSIANS - N_INDIRECT; k < N_GAUSSIANS; ++k) {
        vec4 el = b.x * stage_texel(s0, 2 * k) + b.y * stage_texel(s1, 2 * k)
                  + b.z * stage_texel(s2, 2 * k);
        vec4 ms = b.x * stage_texel(s0, 2 * k + 1) + b.y * stage_texel(s1, 2 * k + 1)
                  + b.z * stage_texel(s2, 2 * k + 1);
        if (el.w < MIN_SAY) continue;
        float sigma = ms.w / el.w;
        vec3 mu = normalize(rh + ms.xyz / el.w);
        vec3 e = el.rgb * scale;
        light += e * prefiltered_lookup(rot_t * mu, 1.0 / (sigma * sigma));
#if SUN_GLOSSY
        if (sun_on > 0.0) light += e * sun_e * sun_through(mu, 1.0 / (sigma * sigma));
#endif
    }
#if HAS_SUN
    float cosine = dot(n, sun_dir);
    if (sun_on > 0.0 && cosine > 0.0) {
        vec3 ng = cross(p1 - p0, p2 - p0);
        ng = shadow_frame * (dot(ng, v) < 0.0 ? -ng : ng);
        float sv = sun_visibility(pos, n, ng);
        vec3 alb = b.x * texelFetch(alb_tex, t0, 0).rgb + b.y * texelFetch(alb_tex, t1, 0).rgb
                   + b.z * texelFetch(alb_tex, t2, 0).rgb;
        light += alb * (0.3183098861837907 * cosine * sv) * sun_e;
#if SUN_GLOSSY
        light += sun_brdf_cos(sun_dir, v, n) * sv * sun_e;
#endif
    }
#endif
    return light;
}

// what object_light's .a is where the pixel's own ray meets the object (a corners' weight is
// at most 1)
const float EXACT_HIT = 2.0;

// the object seen along r from point p (n.v nv, lobe's sharpness factor scale) of corners
// with hit-tile slots s and barycentrics b: where the pixel's ray, walked from a corner's
// triangle, meets the object, that hit's light (rgb) and EXACT_HIT (a); else the corners' hits'
// light weighted by their barycentrics, summed (rgb), and the corners' weight (a)
// (render/_reflection.py object_light). One call site of hit_light in
// a loop over a bit mask of the corners with a hit: a loop over the three corners is unrolled
// into three copies, and a rasteriser that runs both sides of a branch under a mask (llvmpipe)
// runs every copy for every pixel
vec4 object_light(vec3 p, vec3 r, float nv, ivec3 s, vec3 b, float scale) {
    // a corner without a slot has no hit anywhere in its tile
    ivec2 t0 = hit_texel(max(s.x, 0), r), t1 = hit_texel(max(s.y, 0), r);
    ivec2 t2 = hit_texel(max(s.z, 0), r);
    ivec3 f = ivec3(s.x >= 0 ? texelFetch(hit_face_tex, t0, 0).r : -1,
                    s.y >= 0 ? texelFetch(hit_face_tex, t1, 0).r : -1,
                    s.z >= 0 ? texelFetch(hit_face_tex, t2, 0).r : -1);
    int mask = (f.x >= 0 && b.x > 0.0 ? 1 : 0) | (f.y >= 0 && b.y > 0.0 ? 2 : 0)
               | (f.z >= 0 && b.z > 0.0 ? 4 : 0);
    // the pixel's own ray, walked from each corner's triangle in turn: where a walk arrives,
    // the ray meets the object there, whatever the other corners' tiles say. A corner whose
    // texel at r finds nothing starts from a triangle its neighbouring texels find: along the
    // silhouette of the object seen in the lobe the pixel's ray may meet what the corner's
    // 6-degree texel misses. One call site of each function in a loop (see above)
    ivec3 start = f;
    if (f.x < 0 && s.x >= 0 && b.x > 0.0) start.x = footprint_face(s.x, r);
    if (f.y < 0 && s.y >= 0 && b.y > 0.0) start.y = footprint_face(s.y, r);
    if (f.z < 0 && s.z >= 0 && b.z > 0.0) start.z = footprint_face(s.z, r);
    int hit = -1;
    float near = 0.0;
    int walks = (start.x >= 0 && b.x > 0.0 ? 1 : 0) | (start.y >= 0 && b.y > 0.0 ? 2 : 0)
                | (start.z >= 0 && b.z > 0.0 ? 4 : 0);
    while (walks != 0 && hit < 0) {
        int i = (walks & 1) != 0 ? 0 : ((walks & 2) != 0 ? 1 : 2);
        walks &= ~(1 << i);
        int g;
        float t;
        if (walk_to_hit(i == 0 ? start.x : (i == 1 ? start.y : start.z), p, r, g, t)) {
            hit = g;
            near = t;
        }
    }
    if (hit >= 0) mask = 8;  // the one hit the pixel's ray meets (bit 3)
    vec3 light = vec3(0.0);
    float w = 0.0;
    while (mask != 0) {
        int i = (mask & 1) != 0 ? 0 : ((mask & 2) != 0 ? 1 : ((mask & 4) != 0 ? 2 : 3));
        mask &= ~(1 << i);
        ivec2 t = i == 0 ? t0 : (i == 1 ? t1 : t2);
        int face = i == 0 ? f.x : (i == 1 ? f.y : (i == 2 ? f.z : hit));
        float dist = i == 3 ? near : texelFetch(hit_dist_tex, t, 0).r;
        float weight = i == 0 ? b.x : (i == 1 ? b.y : (i == 2 ? b.z : 1.0));
        light += weight * hit_light(face, p, dist, r, nv, scale);
        w += weight;
    }
    if (hit >= 0) return vec4(light, EXACT_HIT);
    return vec4(light, min(w, 1.0));
}
