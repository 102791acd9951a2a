// The geodesic view triangles (lobelight.sphere): their great-circle planes and the test that
// locates a direction among them, shared by prt.glsl (vertex stage) and sgbrdf.glsl (fragment
// stage); render/_gl.py's _program(..., include / vertex_include=("geodesic",)) prepends it.

// 3 great-circle normals per geodesic triangle, .w = the view index of the opposite corner.
// A uniform block, not a texture: every invocation reads the same entry at the same time, which
// the constant cache broadcasts (as a texture, the 540 fetches per vertex of the full scan were
// an H100 frame's cost)
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
