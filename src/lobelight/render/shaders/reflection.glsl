// A sharp reflection placed per pixel (render/_reflection.py, whose formulas these are): the
// material's own lobe, a mixture of MIXTURE Gaussians, at the pixel's reflected direction,
// times its directional albedo and the environment's visible fraction there, read from the
// triangle's three corners' octahedral visibility tiles (lobelight.model.visibility_tiles)
// and blended with the pixel's barycentrics. Included in prt.glsl's fragment stage when SHARP
// is 1; VIS_RES, MIXTURE and ALBEDO_STEPS are defined by the loader.

uniform sampler2D vis_tex;        // R8 tiles of VIS_RES^2 texels, vis_per_row tiles per row
uniform int vis_per_row;
uniform isampler2D face_tex;      // RGB32I: each triangle's corner vertex ids, face_width wide
uniform int face_width;
uniform sampler2D pos_tex;        // RGB32F: vertex positions, face_width wide
uniform float sharp_weight[MIXTURE];
uniform float sharp_lam[MIXTURE];
uniform float sharp_warp;         // 1: the sharpness divides by n.v (microfacet lobes)
uniform vec3 sharp_albedo[ALBEDO_STEPS];

// octahedral encoding of a unit direction (lobelight.geometry.octahedral.encode)
vec2 oct_encode(vec3 d) {
    vec2 p = d.xy / (abs(d.x) + abs(d.y) + abs(d.z));
    if (d.z < 0.0) {
        vec2 s = vec2(p.x >= 0.0 ? 1.0 : -1.0, p.y >= 0.0 ? 1.0 : -1.0);
        p = (1.0 - abs(p.yx)) * s;
    }
    return p;
}

// the visible fraction of vertex v's tile at direction d, bilinear and clamped to the tile
// (lobelight.geometry.octahedral.bilinear)
float tile_lookup(int v, vec3 d) {
    vec2 p = oct_encode(d);
    float r = float(VIS_RES);
    vec2 x = clamp((p + 1.0) * (0.5 * r) - 0.5, 0.0, r - 1.0);
    ivec2 x0 = min(ivec2(floor(x)), ivec2(VIS_RES - 2));
    vec2 f = x - vec2(x0);
    ivec2 o = ivec2(v % vis_per_row, v / vis_per_row) * VIS_RES + x0;
    float a = texelFetch(vis_tex, o, 0).r;
    float b = texelFetch(vis_tex, o + ivec2(1, 0), 0).r;
    float c = texelFetch(vis_tex, o + ivec2(0, 1), 0).r;
    float e = texelFetch(vis_tex, o + ivec2(1, 1), 0).r;
    return mix(mix(a, b, f.x), mix(c, e, f.x), f.y);
}

// the fragment's triangle corners and barycentrics, from its primitive id and position
void corners(vec3 p, out ivec3 c, out vec3 b) {
    c = texelFetch(face_tex, ivec2(gl_PrimitiveID % face_width, gl_PrimitiveID / face_width), 0).xyz;
    vec3 p0 = texelFetch(pos_tex, ivec2(c.x % face_width, c.x / face_width), 0).xyz;
    vec3 p1 = texelFetch(pos_tex, ivec2(c.y % face_width, c.y / face_width), 0).xyz;
    vec3 p2 = texelFetch(pos_tex, ivec2(c.z % face_width, c.z / face_width), 0).xyz;
    vec3 n = cross(p1 - p0, p2 - p0);
    float inv = 1.0 / max(dot(n, n), 1e-30);
    float b1 = dot(cross(p - p0, p2 - p0), n) * inv;
    float b2 = dot(cross(p1 - p0, p - p0), n) * inv;
    b = clamp(vec3(1.0 - b1 - b2, b1, b2), 0.0, 1.0);
    b /= max(b.x + b.y + b.z, 1e-30);
}

float visible_fraction(vec3 p, vec3 r) {
    ivec3 c;
    vec3 b;
    corners(p, c, b);
    return b.x * tile_lookup(c.x, r) + b.y * tile_lookup(c.y, r) + b.z * tile_lookup(c.z, r);
}

// E(n.v): linear in the table at n.v = (k + 0.5) / ALBEDO_STEPS, clamped at its ends
vec3 directional_albedo(float nv) {
    float x = clamp(clamp(nv, 0.0, 1.0) * float(ALBEDO_STEPS) - 0.5, 0.0, float(ALBEDO_STEPS - 1));
    int i = min(int(floor(x)), ALBEDO_STEPS - 2);
    return mix(sharp_albedo[i], sharp_albedo[i + 1], x - float(i));
}

// sum_i a_i L(R; lam_i (/ n.v)): the lighting under the lobe's mixture, at R (rotated)
vec3 sharp_lighting(vec3 r, float nv) {
    vec3 acc = vec3(0.0);
    float scale = sharp_warp > 0.0 ? 1.0 / max(nv, 0.02) : 1.0;
    for (int i = 0; i < MIXTURE; ++i) {
        acc += sharp_weight[i] * prefiltered_lookup(r, sharp_lam[i] * scale);
    }
    return acc;
}
