// The per-frame values of a PRT frame, one std140 block shared by prt.glsl, background.glsl and
// shadow.glsl; render/_gl.py's _FrameBlock fills a copy in Python and writes it to the buffer in
// one write when a value changes (a still frame writes nothing). Each scalar fills the fourth
// float after a vec3, where std140 places it; _gl.py's FRAME_LAYOUT offsets (in floats) are the ones in
// the comments. N_SH is defined by the loader.
layout(std140) uniform Frame {
    vec3 eye;            float sun_on;         // 0: camera origin; the sun shaded this frame
    vec3 cam_left;       float shadow_scale;   // 4: camera frame (Mitsuba's perspective sensor)
    vec3 cam_up;         float shadow_offset;  // 8: normal offset against self-shadowing (world)
    vec3 cam_dir;        float shadow_bias;    // 12: depth bias (shadow-map depth units)
    vec3 sun_dir;        float diffuse_on;     // 16: towards the sun, rotated with the lighting
    vec3 sun_e;          float glossy_on;      // 20: the sun's irradiance at normal incidence
    vec3 shadow_center;  float frame_unused;   // 24
    vec2 tan_half;       vec2 depth_range;     // 28: tan of the half field of view; near, far
    mat3 rot_t;          // 32: R^T, the rotated lighting seen by mu is the original at R^T mu
    mat3 shadow_frame;   // 44: rows two tangents, then the direction towards the sun
    vec4 sh_light[N_SH]; // 56: the rotated lighting's SH coefficients (rgb)
    vec4 sh_sun[N_SH];   // 56 + 4 N_SH: the rotated sun alone as SH (zeros without a sun)
};

// The sample's shift from the pixel centre in NDC units (Renderer's supersampling; zero for one
// sample per pixel), and the directions over the sun's disc its soft shadow takes (every
// tap_step-th from tap_first: render/_sun_shadow.py sample_taps; 0 and 1 for one sample per
// pixel): one record per sample in a buffer written when the samples change, bound by range
// for each sample's pass
layout(std140) uniform Sample { vec2 jitter; float tap_first; float tap_step; };
