// The vertex stage's results for this frame (prt.glsl STAGE_PASS, captured once per frame),
// read by the shading pass's vertices (FROM_STAGE) and by a sharp reflection's hit points
// (reflection.glsl): STAGE_TEXELS RGBA32F texels per vertex, STAGE_PER_ROW vertices per row
// of stage_tex (lobelight.render.layout.stage_layout). A vertex's texels: the 2 N_GAUSSIANS
// lobe varyings as prt.glsl's v_lobe holds them, its diffuse colour, the light its direct
// Gaussians carry.
uniform sampler2D stage_tex;

// a vertex's texels after its lobes: its diffuse colour, its direct Gaussians' light
#define STAGE_DIFFUSE (2 * N_GAUSSIANS)
#define STAGE_DIRECT (2 * N_GAUSSIANS + 1)

// the first texel of vertex v (a division by a constant, once per vertex)
ivec2 stage_at(int v) {
    return ivec2((v % STAGE_PER_ROW) * STAGE_TEXELS, v / STAGE_PER_ROW);
}

vec4 stage_texel(ivec2 first, int i) { return texelFetch(stage_tex, first + ivec2(i, 0), 0); }
