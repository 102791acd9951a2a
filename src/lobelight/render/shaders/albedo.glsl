// The diffuse albedo read per pixel from a model's textures (lobelight.scene.AlbedoTexture,
// render/_gl_albedo.py): the layers in one texture array of a common size, each with its UV
// transform and its wrap modes applied here. The mip level comes from the derivatives of the
// unwrapped UVs, so a repeat's seam picks no coarse level, scaled to one sample's share of the
// pixel (the samples of a supersampled pixel average its footprint together); a repeat's bilinear footprint wraps
// by the sampler's own REPEAT, clamp and mirror stop half a texel inside the edge (a mirror
// repeats its edge texel). ALBEDO_LAYERS is defined by the loader; layer 0 is white.

uniform sampler2DArray albedo_tex;
uniform vec3 albedo_xform[2 * ALBEDO_LAYERS];  // per layer: the rows of its 2 x 3 UV transform
uniform vec3 albedo_mode[ALBEDO_LAYERS];       // wrap along U, along V (0 repeat, 1 clamp,
                                               // 2 mirror), 1 if read at the nearest texel
uniform vec2 albedo_size;                      // the layers' texels across and down
uniform float albedo_grad_scale;               // a sample's share of the pixel, across
                                               // (1 / sqrt(samples per pixel))

float albedo_wrap(float x, float mode, float n) {
    if (mode < 0.5) return fract(x);
    if (mode > 1.5) x = 1.0 - abs(mod(x, 2.0) - 1.0);
    return clamp(x, 0.5 / n, 1.0 - 0.5 / n);
}

// the texture array tex's value at uv of layer, read as albedo_tex's layers are (the specular
// textures' F0 layers share their layers' transforms and modes); call it in uniform control
// flow (it takes derivatives)
vec3 texture_at(sampler2DArray tex, vec2 uv, int layer) {
    vec3 q = vec3(uv, 1.0);
    vec2 t = vec2(dot(albedo_xform[2 * layer], q), dot(albedo_xform[2 * layer + 1], q));
    vec2 gx = dFdx(t) * albedo_grad_scale, gy = dFdy(t) * albedo_grad_scale;
    vec3 mode = albedo_mode[layer];
    t = vec2(albedo_wrap(t.x, mode.x, albedo_size.x), albedo_wrap(t.y, mode.y, albedo_size.y));
    if (mode.z > 0.5) t = (floor(t * albedo_size) + 0.5) / albedo_size;
    return textureGrad(tex, vec3(t, float(layer)), gx, gy).rgb;
}

// the texture's albedo at uv of layer (before the per-vertex factor); layer 0 is white; call
// it in uniform control flow
vec3 albedo_at(vec2 uv, int layer) {
    vec3 a = texture_at(albedo_tex, uv, layer);
    return layer == 0 ? vec3(1.0) : a;
}
