// Display transform of linear radiance: exposure, optional ACES fit (Narkowicz 2015), sRGB.

#if defined VERTEX_SHADER

in vec2 in_xy;
out vec2 v_uv;

void main() {
    v_uv = in_xy * 0.5 + 0.5;
    gl_Position = vec4(in_xy, 0.0, 1.0);
}

#elif defined FRAGMENT_SHADER

in vec2 v_uv;
uniform sampler2D image;
uniform float scale;  // 2^exposure
uniform int curve;    // 0 clamp, 1 ACES
out vec4 frag;

vec3 srgb(vec3 x) {
    return mix(12.92 * x, 1.055 * pow(x, vec3(1.0 / 2.4)) - 0.055, step(vec3(0.0031308), x));
}

void main() {
    vec3 x = max(texture(image, v_uv).rgb * scale, vec3(0.0));
    if (curve == 1) {
        x = clamp(x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0);
    }
    frag = vec4(srgb(clamp(x, 0.0, 1.0)), 1.0);
}

#endif
