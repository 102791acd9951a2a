// The BRDFs the renderers evaluate per pixel (lobelight.brdf's; render/_sun_glossy.py): the
// sun's glossy reflection and the lobe visibility correction (render/_lobe_visibility.py)
// read them through brdf_cos with a vertex's parameters. Included in fragment shaders by
// render/_gl.py's _program(..., include=["brdf"]), and in the lobe visibility pass's vertex
// stage (LOBE_VISIBILITY_INCLUDE).

uniform int sun_model;            // 0 GGX, 1 Beckmann, 2 modified Phong, 3 Blinn-Phong
uniform float sun_fresnel;        // 1 conductor Fresnel, 2 Schlick's (F0 in eta), 0 none

const float BRDF_PI = 3.14159265358979;

// microfacet distribution at a half vector with cosine c to the normal (brdf/microfacet.py's
// _Microfacet._D)
float mf_d(float c, float a) {
    float c2 = c * c;
    float s2 = max(1.0 - c2, 0.0);
    float r;
    if (sun_model == 1) {
        r = exp(-(s2 / (a * a)) / c2) / (BRDF_PI * a * a * c2 * c2);
    } else {
        float t = s2 / (a * a) + c2;
        r = 1.0 / (BRDF_PI * a * a * t * t);
    }
    return r * c > 1e-20 ? r : 0.0;
}

// Smith's masking of direction v (cosine vz to the normal) for the microfacet normal m
float mf_g1(float vz, float vm, float a) {
    float xy = a * a * max(1.0 - vz * vz, 0.0);
    if (vm * vz <= 0.0) return 0.0;
    if (xy == 0.0) return 1.0;
    float tan2 = xy / (vz * vz);
    if (sun_model == 1) {
        float b = inversesqrt(tan2);
        return b >= 1.6 ? 1.0 : (3.535 * b + 2.181 * b * b) / (1.0 + 2.276 * b + 2.577 * b * b);
    }
    return 2.0 / (1.0 + sqrt(1.0 + tan2));
}

// unpolarised conductor Fresnel (brdf.microfacet, _fresnel_conductor)
vec3 fresnel_conductor(float c, vec3 eta, vec3 k) {
    float c2 = c * c;
    float s2 = 1.0 - c2;
    float s4 = s2 * s2;
    vec3 t1 = eta * eta - k * k - s2;
    vec3 a2pb2 = sqrt(max(t1 * t1 + 4.0 * k * k * eta * eta, 0.0));
    vec3 a = sqrt(max(0.5 * (a2pb2 + t1), 0.0));
    vec3 term1 = a2pb2 + c2;
    vec3 term2 = 2.0 * c * a;
    vec3 rs = (term1 - term2) / (term1 + term2);
    vec3 term3 = a2pb2 * c2 + s4;
    vec3 term4 = term2 * s2;
    vec3 rp = rs * (term3 - term4) / (term3 + term4);
    return 0.5 * (rs + rp);
}

// pos(a.w)^e for unit vectors, from the half squared chord (brdf._base._cospow: precise near
// the peak)
float cospow(vec3 a, vec3 w, float e) {
    if (dot(a, w) <= 0.0) return 0.0;
    vec3 d = a - w;
    float h = min(0.5 * dot(d, d), 1.0 - 1.2e-7);
    float lg = h < 1e-3 ? -h * (1.0 + h * (0.5 + h / 3.0)) : log(1.0 - h);
    return exp(e * lg);
}

// f_s(l, v) max(n.l, 0) (0 where l or v is below the horizon) of the BRDF whose per-vertex
// parameters are sb0 (alpha or exponent, specular RGB), eta (F0 for Schlick's) and k
// (render/_sun_glossy.py sun_glossy_vertex_params)
vec3 brdf_cos(vec3 l, vec3 v, vec3 n, vec4 sb0, vec3 eta, vec3 k) {
    float zi = dot(n, l), zo = dot(n, v);
    if (zi <= 0.0 || zo <= 0.0) return vec3(0.0);
    if (sun_model == 2) {  // modified Phong: ks (e + 2) / (2 pi) pos(r.l)^e
        float e = sb0.x;
        vec3 r = 2.0 * zo * n - v;
        return sb0.yzw * ((e + 2.0) / (2.0 * BRDF_PI) * cospow(r, l, e) * zi);
    }
    if (sun_model == 3) {  // Blinn-Phong: ks c(e) pos(n.h)^e
        float e = sb0.x;
        float c = (e + 2.0) * (e + 4.0) / (8.0 * BRDF_PI * (exp2(-0.5 * e) + e));
        return sb0.yzw * (c * cospow(n, normalize(l + v), e) * zi);
    }
    float a = max(sb0.x, 1e-4);
    vec3 h = normalize(l + v);
    float ch = dot(n, h), oh = dot(v, h);
    float val = mf_d(ch, a) * mf_g1(zo, oh, a) * mf_g1(zi, dot(l, h), a) / (4.0 * zo);
    vec3 f = sb0.yzw;
    if (sun_fresnel > 1.5) {  // Schlick's, F0 + (1 - F0) (1 - v.h)^5 (brdf/gltf.py)
        float m = clamp(1.0 - oh, 0.0, 1.0);
        f *= eta + (1.0 - eta) * (m * m * m * m * m);
    } else if (sun_fresnel > 0.0) {
        f *= fresnel_conductor(oh, eta, k);
    }
    return f * val;
}
