// Depth of the mesh seen from the sun (orthographic), for prt.glsl's shadow test. The light
// frame and scale are those of prt.glsl's shadow lookup: q = shadow_frame * (p - centre) * scale
// lies in [-1, 1]^3 for the whole mesh, and depth grows away from the sun; the frame, centre and
// scale come from frame.glsl.

#if defined VERTEX_SHADER

in vec3 in_pos;

void main() {
    vec3 q = shadow_frame * (in_pos - shadow_center) * shadow_scale;
    gl_Position = vec4(q.x, q.y, -q.z, 1.0);
}

#elif defined FRAGMENT_SHADER

void main() {}

#endif
