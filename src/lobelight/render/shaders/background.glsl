// The environment behind the object: the ray of each pixel (Mitsuba's perspective sensor)
// looked up in the rotated environment. Drawn after the object at the far plane with the depth
// test on, so only the pixels the object leaves uncovered run it; the camera, rotation and
// jitter come from frame.glsl.

#if defined VERTEX_SHADER

in vec2 in_xy;
out vec2 v_ndc;

void main() {
    v_ndc = in_xy;
    gl_Position = vec4(in_xy, 1.0, 1.0);
}

#elif defined FRAGMENT_SHADER

in vec2 v_ndc;
uniform samplerCube env;
out vec4 frag;

void main() {
    vec2 ndc = v_ndc - jitter;  // the sample point this pixel centre stands for
    vec3 d = normalize(-ndc.x * tan_half.x * cam_left + ndc.y * tan_half.y * cam_up + cam_dir);
    frag = vec4(textureLod(env, rot_t * d, 0.0).rgb, 0.0);
}

#endif
