// The geodesic view triangles (lobelight.geometry.sphere) and the lookup of the one holding a
// direction, shared by prt.glsl (vertex stage) and sgbrdf.glsl (fragment stage); render/_gl.py's
// upload_geodesic() makes the block, the texture and the defines (CAND_RES, CAND_TEXELS), and
// _program(..., include / vertex_include=("geodesic",)) prepends this file.

// 3 great-circle normals per geodesic triangle, .w = the view index of the opposite corner.
// A uniform block, not a texture: every invocation reads the same entry at the same time, which
// the constant cache broadcasts (as a texture, the 540 fetches per vertex of a full scan would
// dominate a GPU frame)
layout(std140) uniform Planes { vec4 planes[540]; };

// Triangle f's unnormalised barycentrics of d; keep it when its smallest beats the best so far
// (the largest smallest barycentric wins, as sphere.locate_views: robust on edges)
void test_face(int f, vec3 d, inout float best, inout vec3 bary, inout ivec3 vid) {
    vec4 p0 = planes[3 * f];
    vec4 p1 = planes[3 * f + 1];
    vec4 p2 = planes[3 * f + 2];
    vec3 det = vec3(dot(p0.xyz, d), dot(p1.xyz, d), dot(p2.xyz, d));
    float m = min(det.x, min(det.y, det.z));
    if (m > best) {
        best = m;
        bary = det;
        vid = ivec3(int(p0.w + 0.5), int(p1.w + 0.5), int(p2.w + 0.5));
    }
}

// Candidate triangles per cube-map texel (sphere.triangle_candidates, -1 padded): CAND_TEXELS
// RGBA texels per cell at [face * CAND_RES + row, col * CAND_TEXELS + q]
uniform sampler2D cand_tex;

// The geodesic triangle holding d: largest smallest barycentric (as sphere.locate_views), among
// the few candidates of d's texel rather than all 180 (a full scan would dominate a GPU
// frame). Returns its views and unnormalised barycentrics.
void locate_triangle(vec3 d, out vec3 bary, out ivec3 vid) {
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
    bary = vec3(0.0);
    vid = ivec3(0);
    for (int q = 0; q < CAND_TEXELS; ++q) {
        vec4 c4 = texelFetch(cand_tex, ivec2(cell.x * CAND_TEXELS + q, face * CAND_RES + cell.y), 0);
        for (int e = 0; e < 4; ++e) {
            int f = int(c4[e]);
            if (f < 0) break;
            test_face(f, d, best, bary, vid);
        }
    }
}
