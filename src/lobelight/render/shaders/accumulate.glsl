// One sample of a supersampled frame added into the result (additive blending): the pass's
// texel times 1 / samples, alpha (1 on the object, 0 elsewhere) summing to the coverage.

#if defined VERTEX_SHADER

in vec2 in_xy;

void main() {
    gl_Position = vec4(in_xy, 0.0, 1.0);
}

#elif defined FRAGMENT_SHADER

uniform sampler2D image;  // the pass's colour, the size of the result
uniform float weight;     // 1 / samples
out vec4 frag;

void main() {
    frag = weight * texelFetch(image, ivec2(gl_FragCoord.xy), 0);
}

#endif
