// Each vertex's octahedral visibility tile (lobelight.model.Model.visibility), read bilinearly
// along a direction as lobelight.geometry.octahedral.bilinear reads it: by the sharp
// reflection (reflection.glsl) and the lobe visibility correction (lobe_visibility.glsl).
// Included by render/_gl.py's _program(..., include=["tiles"]); VIS_RES is defined by the loader.

uniform sampler2D vis_tex;        // R8 tiles of VIS_RES^2 texels, vis_per_row tiles per row
uniform int vis_per_row;

// octahedral encoding of a unit direction (lobelight.geometry.octahedral.encode)
vec2 oct_encode(vec3 d) {
    vec2 p = d.xy / (abs(d.x) + abs(d.y) + abs(d.z));
    if (d.z < 0.0) {
        vec2 s = vec2(p.x >= 0.0 ? 1.0 : -1.0, p.y >= 0.0 ? 1.0 : -1.0);
        p = (1.0 - abs(p.yx)) * s;
    }
    return p;
}

// the bilinear footprint of direction d in a tile, clamped to the tile
// (lobelight.geometry.octahedral.bilinear): its first texel x0 in the tile and the weights f
void tile_bilinear(vec3 d, out ivec2 x0, out vec2 f) {
    vec2 p = oct_encode(d);
    float r = float(VIS_RES);
    vec2 x = clamp((p + 1.0) * (0.5 * r) - 0.5, 0.0, r - 1.0);
    x0 = min(ivec2(floor(x)), ivec2(VIS_RES - 2));
    f = x - vec2(x0);
}

// the bilinear footprint of direction d in vertex v's visibility tile: its first texel o in
// the atlas and the weights f
void tile_footprint(int v, vec3 d, out ivec2 o, out vec2 f) {
    ivec2 x0;
    tile_bilinear(d, x0, f);
    o = ivec2(v % vis_per_row, v / vis_per_row) * VIS_RES + x0;
}

// the visible fraction of vertex v's tile at direction d, bilinear
float tile_lookup(int v, vec3 d) {
    ivec2 o;
    vec2 f;
    tile_footprint(v, d, o, f);
    float a = texelFetch(vis_tex, o, 0).r;
    float b = texelFetch(vis_tex, o + ivec2(1, 0), 0).r;
    float c = texelFetch(vis_tex, o + ivec2(0, 1), 0).r;
    float e = texelFetch(vis_tex, o + ivec2(1, 1), 0).r;
    return mix(mix(a, b, f.x), mix(c, e, f.x), f.y);
}
