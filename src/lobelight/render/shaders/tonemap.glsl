// Display transform of linear radiance: exposure, a curve, sRGB; the same as
// lobelight.render.tonemap (curve codes are the indices of _tonemap.CURVES).

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
uniform int curve;    // 0 clip (srgb), 1 ACES (Narkowicz 2015), 2 Khronos PBR Neutral
out vec4 frag;

vec3 srgb(vec3 x) {
    return mix(12.92 * x, 1.055 * pow(x, vec3(1.0 / 2.4)) - 0.055, step(vec3(0.0031308), x));
}

// Khronos PBR Neutral (KhronosGroup/ToneMapping, PBR_Neutral/README.md's specification), as
// lobelight.render._tonemap.neutral: below the shoulder Ks colours pass less the toe's offset;
// above it the brightest channel goes to p_n < 1 and the colour is mixed towards p_n grey.
const float F90 = 0.04;
const float KS = 0.8 - F90;
const float KD = 0.15;

vec3 neutral(vec3 x) {
    float m = min(x.r, min(x.g, x.b));
    float f = m < 2.0 * F90 ? m - m * m / (4.0 * F90) : F90;
    vec3 c = x - f;
    float p = max(c.r, max(c.g, c.b));
    if (p <= KS) {
        return c;
    }
    float d = 1.0 - KS;
    float pn = 1.0 - d * d / (p + d - KS);
    float g = 1.0 / (KD * (p - pn) + 1.0);
    return c * (pn / p) * g + pn * (1.0 - g);
}

void main() {
    vec3 x = max(texture(image, v_uv).rgb * scale, vec3(0.0));
    if (curve == 1) {
        x = x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14);
    } else if (curve == 2) {
        x = neutral(x);
    }
    frag = vec4(srgb(clamp(x, 0.0, 1.0)), 1.0);
}

#endif
