// The environment behind the object: the ray of each pixel (Mitsuba's perspective sensor)
// looked up in the rotated environment.

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
uniform vec3 cam_left;
uniform vec3 cam_up;
uniform vec3 cam_dir;
uniform vec2 tan_half;
uniform mat3 rot_t;
uniform vec2 jitter;  // the sample's shift from the pixel centre (NDC), as in prt.glsl
out vec4 frag;

void main() {
    vec2 ndc = v_ndc - jitter;  // the sample point this pixel centre stands for
    vec3 d = normalize(-ndc.x * tan_half.x * cam_left + ndc.y * tan_half.y * cam_up + cam_dir);
    frag = vec4(textureLod(env, rot_t * d, 0.0).rgb, 0.0);
}

#endif
