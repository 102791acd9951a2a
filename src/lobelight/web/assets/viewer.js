// lobelight's WebGL 2 viewer: a fitted model relit under environment maps, shaded by the
// desktop renderer's own shader files (lobelight/render/shaders, assembled in the GLSL ES 3.00
// dialect into shaders.js). The textures, uniform blocks and vertex attributes are the ones
// lobelight/render/_gl.py uploads; docs/web-viewer.md describes the data files and this page.
// A classic script (not a module): a page opened from file:// may load classic scripts only.
"use strict";

(function () {
  const store = {};

  // every data file calls this: lobelight_data(kind, {header, arrays}); a map's file hands its
  // document to the loadScript that added it (maps load side by side, in any order)
  window.lobelight_data = function (kind, doc) {
    if (kind === "env") {
      const s = document.currentScript;
      if (s && s.lobelightResolve) s.lobelightResolve(doc);
      return;
    }
    store[kind] = doc;
  };

  // ---------------------------------------------------------------------------------------
  // data

  // base64 to bytes: the browser's own decoder where it has one (no intermediate string),
  // else atob and a copy; either way a fresh buffer at offset 0, so typed views align
  function bytesOf(b64) {
    if (typeof Uint8Array.fromBase64 === "function") return Uint8Array.fromBase64(b64);
    const s = atob(b64);
    const n = s.length;
    const out = new Uint8Array(n);
    for (let i = 0; i < n; ++i) out[i] = s.charCodeAt(i);
    return out;
  }

  const ARRAY_TYPES = {
    "<f4": Float32Array, "<f2": Uint16Array, "<u4": Uint32Array, "|u1": Uint8Array,
    "<i2": Int16Array, "<i4": Int32Array,
  };

  // the `size` bytes a gzip member holds, inflated natively (DecompressionStream) into one
  // buffer of that size: the member written whole and its chunks copied as they come, which
  // costs a quarter less than a Response gathering them; a member that inflates to more or
  // fewer bytes is refused, as lobelight/web/_format.py refuses it
  async function inflate(packed, size, name) {
    const ds = new DecompressionStream("gzip");
    const writer = ds.writable.getWriter();
    writer.write(packed).catch(function () {});  // a damaged member fails the reader too
    writer.close().catch(function () {});
    const reader = ds.readable.getReader(), out = new Uint8Array(size);
    let at = 0;
    try {
      for (;;) {
        const { value, done } = await reader.read();
        if (done) break;
        if (at + value.length > size) { at = -1; break; }
        out.set(value, at);
        at += value.length;
      }
    } catch (e) {
      at = -1;
    }
    if (at !== size) {
      reader.cancel().catch(function () {});
      throw new Error("The data array " + name + " does not inflate to its shape's " + size +
                      " bytes: the folder is damaged; export it again.");
    }
    return out;
  }

  // one array record: its bytes inflated where the exporter gzipped them
  // (lobelight/web/_format.py)
  async function decode(rec, name) {
    const T = ARRAY_TYPES[rec.dtype];
    if (!T) throw new Error("unknown array type " + rec.dtype);
    const size = rec.shape.reduce(function (a, b) { return a * b; }, 1) * T.BYTES_PER_ELEMENT;
    let bytes = bytesOf(rec.b64);
    if (rec.gzip) bytes = await inflate(bytes, size, name);
    else if (bytes.length !== size) {
      throw new Error("The data array " + name + " holds " + bytes.length + " bytes, its " +
                      "shape needs " + size + ": the folder is damaged; export it again.");
    }
    return { data: new T(bytes.buffer), shape: rec.shape };
  }

  // the arrays of a data file's document (those named in `only`, where given)
  async function decodeAll(doc, only) {
    const keys = Object.keys(doc.arrays).filter(function (k) { return !only || only.includes(k); });
    const arrays = await Promise.all(keys.map(function (k) { return decode(doc.arrays[k], k); }));
    const out = {};
    keys.forEach(function (k, i) { out[k] = arrays[i]; });
    return out;
  }

  // tiles of r x r texels per row of the tile atlas for nv vertices: the desktop's row (w
  // texels across), narrowed to the device's largest texture (maxTex) and widened where its
  // rows would not fit it (SwiftShader's 8192: 50K vertices take 12,576 rows at 4096 across)
  function tilesPerRow(nv, r, w, maxTex) {
    const most = Math.max(1, Math.floor(maxTex / r));  // tiles across the largest texture
    let perRow = Math.max(1, Math.min(nv, Math.floor(w / r), most));
    if (Math.ceil(nv / perRow) > most) perRow = Math.min(most, Math.ceil(nv / most));
    return perRow;
  }

  // a map's data file added to the page: its document once it has run (a file that runs
  // without handing one over, or does not load, rejects)
  function loadScript(src) {
    return new Promise(function (resolve, reject) {
      const s = document.createElement("script");
      s.src = src;
      s.lobelightResolve = resolve;
      s.onerror = function () { reject(new Error("cannot load " + src)); };
      s.onload = function () { reject(new Error(src + " holds no map")); };  // after resolve: no-op
      document.head.appendChild(s);
    });
  }

  // each map's file read and its arrays decoded, once: [document, arrays]; the first map
  // starts while the model's arrays decode, so its script is parsed meanwhile
  const envLoads = {};
  function loadEnv(file) {
    if (!envLoads[file]) {
      envLoads[file] = loadScript(file).then(function (doc) {
        return decodeAll(doc).then(function (arrays) { return [doc, arrays]; });
      });
    }
    return envLoads[file];
  }


  // half-float bits of a number (round to nearest even), for the few values made here
  const f32 = new Float32Array(1);
  const u32 = new Uint32Array(f32.buffer);
  function toHalf(x) {
    f32[0] = x;
    const b = u32[0];
    const sign = (b >>> 16) & 0x8000;
    const e = ((b >>> 23) & 0xff) - 127 + 15;
    let m = b & 0x7fffff;
    if (e >= 31) return sign | 0x7c00;
    if (e <= 0) {
      if (e < -10) return sign;
      m = (m | 0x800000) >> (1 - e);
      return sign | ((m + 0x1000) >> 13);
    }
    return sign | ((e << 10) + ((m + 0x1000) >> 13));
  }
  const HALF_ONE = toHalf(1.0);

  // ---------------------------------------------------------------------------------------
  // spherical harmonics in lobelight's basis (lobelight.lobes.sh.basis: real, orthonormal,
  // k = l^2 + l + m, polar axis +z, no Condon-Shortley phase), in float64

  function shBasis(x, y, z, order) {
    const n = Math.hypot(x, y, z);
    x /= n; y /= n; z /= n;
    const re = [1], im = [0];
    for (let m = 1; m < order; ++m) {
      re.push(x * re[m - 1] - y * im[m - 1]);
      im.push(x * im[m - 1] + y * re[m - 1]);
    }
    const out = [1 / Math.sqrt(4 * Math.PI)];
    let prev2 = null, prev = [out[0]];
    for (let l = 1; l < order; ++l) {
      const q = [];
      for (let m = 0; m <= l - 2; ++m) {
        const a = Math.sqrt((4 * l * l - 1) / (l * l - m * m));
        const b = Math.sqrt(((l - 1) * (l - 1) - m * m) / (4 * (l - 1) * (l - 1) - 1));
        q.push(a * (z * prev[m] - b * prev2[m]));
      }
      const top = prev[l - 1];
      q.push(Math.sqrt(2 * l + 1) * z * top);
      q.push(Math.sqrt((2 * l + 1) / (2 * l)) * top);
      for (let m = l; m >= 1; --m) out.push(q[m] * im[m] * Math.SQRT2);
      out.push(q[0]);
      for (let m = 1; m <= l; ++m) out.push(q[m] * re[m] * Math.SQRT2);
      prev2 = prev;
      prev = q;
    }
    return out;
  }

  // ---------------------------------------------------------------------------------------
  // small linear algebra (float64; matrices row-major arrays of 9)

  function sub(a, b) { return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]; }
  function dot(a, b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
  function cross(a, b) {
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
  }
  function normalize(a) { const n = Math.hypot(a[0], a[1], a[2]); return [a[0] / n, a[1] / n, a[2] / n]; }
  function matVec(r, v) {
    return [r[0] * v[0] + r[1] * v[1] + r[2] * v[2], r[3] * v[0] + r[4] * v[1] + r[5] * v[2],
            r[6] * v[0] + r[7] * v[1] + r[8] * v[2]];
  }
  function matTVec(r, v) {
    return [r[0] * v[0] + r[3] * v[1] + r[6] * v[2], r[1] * v[0] + r[4] * v[1] + r[7] * v[2],
            r[2] * v[0] + r[5] * v[1] + r[8] * v[2]];
  }
  // lobelight.render.as_rotation(angle): degrees about +y
  function rotationY(deg) {
    const a = deg * Math.PI / 180, c = Math.cos(a), s = Math.sin(a);
    return [c, 0, s, 0, 1, 0, -s, 0, c];
  }
  // rows u, v, l of the shadow map's frame (render/_sun_shadow.py sun_frame)
  function sunFrame(l) {
    l = normalize(l);
    const a = Math.abs(l[0]) < 0.9 ? [1, 0, 0] : [0, 1, 0];
    const u = normalize(cross(l, a));
    const v = cross(l, u);
    return [u, v, l];
  }
  // Mitsuba's perspective sensor (lobelight.geometry.camera.Camera.frame, tan_half)
  function cameraFrame(origin, target, up) {
    const d = normalize(sub(target, origin));
    const left = normalize(cross(up, d));
    return { eye: origin, left: left, up: cross(d, left), dir: d };
  }
  function tanHalf(fov, axis, w, h) {
    const t = Math.tan(fov * Math.PI / 360), aspect = w / h;
    if (axis === "smaller") axis = w <= h ? "x" : "y";
    else if (axis === "larger") axis = w >= h ? "x" : "y";
    return axis === "y" ? [t * aspect, t] : [t, t / aspect];
  }

  // ---------------------------------------------------------------------------------------
  // the viewer

  class LimitError extends Error {}

  // offsets in floats of frame.glsl's Frame block: the model file's frame_layout
  // (lobelight.render.layout.FRAME_LAYOUT), set when the model is read
  let FRAME = null;
  const PLANES_BINDING = 0, FRAME_BINDING = 1, SAMPLE_BINDING = 2;
  const UNITS = {
    gauss_tex: 0, diff_tex: 1, cand_tex: 2, atlas: 3, env: 4, image: 5, shadow_map: 6,
    specular_tex: 7, bounce_tex: 8, shadow_depth: 9, albedo_tex: 10,
    // a sharp material's per-pixel reflection (reflection.glsl) and the whole map's chain
    vis_tex: 11, face_tex: 12, pos_tex: 13, nrm_tex: 14, alb_tex: 15, hit_face_tex: 16,
    hit_dist_tex: 17, whole_atlas: 20,
    // the vertex stage's results per vertex (prt.glsl FROM_STAGE, reflection.glsl)
    stage_tex: 18,
    // a glTF lobe varying per vertex
    lobe_tex: 21, split_tex: 22,
  };
  const CURVE_NEUTRAL = 2;
  // the model's arrays the page decodes after it has queued its first draw (start, fill):
  // the per-record and per-texel ones, most of the file. A rasteriser may compile a program
  // for the GPU at its first draw (SwiftShader does, for a second or so on a large shader);
  // it then compiles while these decode
  const LATER = ["flags", "light", "sigma", "mean", "diffuse", "bounce", "vis_tiles",
                 "hit_step", "hit_face_step", "hit_dist"];
  // the linear image's format, of every frame the page draws
  const FRAME_FORMAT = "RGBA16F";

  class Viewer {
    // model: the model file's header and its decoded arrays (decodeAll)
    constructor(gl, model, arrays, shaders, options) {
      this.gl = gl;
      this.h = model.header;
      FRAME = this.h.frame_layout;
      this.shaders = shaders;
      this.options = options;
      // the depth pre-pass, unless the page's URL says: where the rasteriser shades a
      // fragment before its depth test (SwiftShader), the pre-pass spares no shading and
      // costs a pass (docs/web-viewer.md)
      this.prepass = options.prepass != null ? options.prepass : rendererRejectsEarly(gl);
      // a closed surface wound outward (the header's closed): its triangles seen from behind
      // are hidden from outside it, and left out; a rasteriser that shades before its depth
      // test (SwiftShader) would shade them all
      this.cull = !!this.h.closed && options.cull !== false;
      this.maxTex = Math.min(gl.getParameter(gl.MAX_TEXTURE_SIZE), options.maxTexture || 1e9);
      this.a = arrays;
      this.programs = {};
      this.envs = [];
      this.env = null;
      this.targets = {};
      this.checkLimits();
      this.uploadModel();
    }

    // the model's data textures: one width for the records and the transfers; refused with
    // the numbers when they exceed this device's texture size
    checkLimits() {
      const h = this.h, gl = this.gl;
      const recs = h.n_vertices * h.n_views * h.n_gaussians * 2;
      const diff = h.n_vertices * h.n_sh;
      const t = Math.max(recs, diff);
      // the width long arrays wrap at (lobelight.render.layout.TEX_WIDTH)
      let width = Math.min(h.tex_width, this.maxTex);
      while (Math.ceil(t / width) > this.maxTex && width < this.maxTex) width *= 2;
      width = Math.min(width, this.maxTex);
      if (Math.ceil(t / width) > this.maxTex) {
        throw new LimitError(
          "This model is too large for this device's textures: its " + h.n_vertices +
          " vertices × " + h.n_views + " views × " + h.n_gaussians + " Gaussians need " +
          t + " texels, and the largest texture here holds " + this.maxTex + " × " +
          this.maxTex + " = " + this.maxTex * this.maxTex + ".");
      }
      if (h.shadow.res > this.maxTex) {
        throw new LimitError("The sun's shadow map needs " + h.shadow.res + "² texels; this " +
                             "device's largest texture is " + this.maxTex + "².");
      }
      // prt.glsl's varyings: two vec4 per Gaussian, the diffuse light, position, normal and
      // albedo, the sun's BRDF (three), the albedo textures' UV, layer and factor (three), the
      // bake's F0 where the specular colour is per texel, and a sharp material's triangle id
      const at = h.albedo_textures;
      const need = 2 * h.n_gaussians + 4 + (h.sun_glossy ? 3 : 0) + (at ? 3 : 0) +
                   (at && at.specular ? 1 : 0) + (h.sharp ? 1 : 0);
      const have = gl.getParameter(gl.MAX_VARYING_VECTORS);
      if (need > have) {
        throw new LimitError("This model's " + h.n_gaussians + " Gaussians per view need " +
                             need + " varying vectors; this device has " + have + ".");
      }
      // the vertex stage's pass captures 2 N + 2 vectors per vertex (stagePass)
      const captured = 4 * h.stage_varyings.length;
      const capture = gl.getParameter(gl.MAX_TRANSFORM_FEEDBACK_INTERLEAVED_COMPONENTS);
      if (captured > capture) {
        throw new LimitError("This model's " + h.n_gaussians + " Gaussians per view need a " +
                             "transform feedback of " + captured + " components; this " +
                             "device captures " + capture + ".");
      }
      this.texWidth = width;
    }

    dataTexture(width, rows, internal, format, type, data) {
      const gl = this.gl, t = gl.createTexture();
      gl.bindTexture(gl.TEXTURE_2D, t);
      gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
      gl.texImage2D(gl.TEXTURE_2D, 0, internal, width, rows, 0, format, type, data);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
      return t;
    }

    // the Gaussian records as render/_gl.py's gauss_tex: two RGBA texels per (vertex, view,
    // Gaussian), (e, sigma) then (mu, above); the records left out of the file are zero
    gaussTexture() {
      const gl = this.gl, h = this.h, a = this.a, w = this.texWidth;
      const nv = h.n_vertices, nj = h.n_views, n = h.n_gaussians;
      const texels = nv * nj * n * 2;
      const rows = Math.ceil(texels / w);
      const half = a.light.data instanceof Uint16Array;
      const out = half ? new Uint16Array(rows * w * 4) : new Float32Array(rows * w * 4);
      const one = half ? HALF_ONE : 1.0;
      const flags = a.flags.data, light = a.light.data, sigma = a.sigma.data, mean = a.mean.data;
      let r = 0;
      for (let vj = 0; vj < nv * nj; ++vj) {
        const f = flags[vj];
        for (let k = 0; k < n; ++k) {
          const o = 8 * (vj * n + k);
          if (f & 2) out[o + 7] = one;
          if (!(f & 1)) continue;
          const s = r * n + k;
          out[o] = light[3 * s]; out[o + 1] = light[3 * s + 1]; out[o + 2] = light[3 * s + 2];
          out[o + 3] = sigma[s];
          out[o + 4] = mean[3 * s]; out[o + 5] = mean[3 * s + 1]; out[o + 6] = mean[3 * s + 2];
        }
        if (f & 1) r += 1;
      }
      return half ? this.dataTexture(w, rows, gl.RGBA16F, gl.RGBA, gl.HALF_FLOAT, out)
                  : this.dataTexture(w, rows, gl.RGBA32F, gl.RGBA, gl.FLOAT, out);
    }

    // (V, n, 3) half (or single) floats as one RGBA16F (RGBA32F) texel per coefficient
    rgbTexture(arr) {
      const gl = this.gl, w = this.texWidth;
      const src = arr.data, t = src.length / 3;
      const rows = Math.max(1, Math.ceil(t / w));
      const half = src instanceof Uint16Array;
      const out = half ? new Uint16Array(rows * w * 4) : new Float32Array(rows * w * 4);
      for (let i = 0; i < t; ++i) {
        out[4 * i] = src[3 * i]; out[4 * i + 1] = src[3 * i + 1]; out[4 * i + 2] = src[3 * i + 2];
      }
      return half ? this.dataTexture(w, rows, gl.RGBA16F, gl.RGBA, gl.HALF_FLOAT, out)
                  : this.dataTexture(w, rows, gl.RGBA32F, gl.RGBA, gl.FLOAT, out);
    }

    buffer(target, data) {
      const gl = this.gl, b = gl.createBuffer();
      gl.bindBuffer(target, b);
      gl.bufferData(target, data, gl.STATIC_DRAW);
      return b;
    }

    // everything but the arrays of LATER (fill): the geometry's buffers, the small textures,
    // the vertex stage's buffer; the tile atlases' layouts checked against the device
    uploadModel() {
      const gl = this.gl, a = this.a, h = this.h;
      const cand = a.candidates;
      this.candTex = this.dataTexture(cand.shape[1], cand.shape[0], gl.RGBA32F, gl.RGBA,
                                      gl.FLOAT, Float32Array.from(cand.data));
      this.planes = this.buffer(gl.UNIFORM_BUFFER, a.planes.data);
      this.vbo = this.buffer(gl.ARRAY_BUFFER, a.positions.data);
      this.nbo = this.buffer(gl.ARRAY_BUFFER, a.normals.data);
      this.abo = this.buffer(gl.ARRAY_BUFFER, a.albedo.data);
      this.ibo = this.buffer(gl.ELEMENT_ARRAY_BUFFER, a.faces.data);
      this.nIndices = a.faces.data.length;
      if (a.albedo_layers) this.uploadAlbedo();
      if (h.sharp) this.uploadSharp();
      if (h.lobe_visibility) this.uploadLobeVisibility();
      if (h.sharp || h.lobe_visibility) this.visibilityLayout(this.visRes());
      this.uploadStage();
      this.quad = this.buffer(gl.ARRAY_BUFFER, new Float32Array([-1, -1, 1, -1, -1, 1, 1, 1]));
      this.frameData = new Float32Array(FRAME.sh_light + 8 * h.n_sh);
      this.frameUbo = gl.createBuffer();
      gl.bindBuffer(gl.UNIFORM_BUFFER, this.frameUbo);
      gl.bufferData(gl.UNIFORM_BUFFER, this.frameData.byteLength, gl.DYNAMIC_DRAW);
      // jitter 0, every direction over the sun's disc (setJitter)
      this.sampleUbo = this.buffer(gl.UNIFORM_BUFFER, new Float32Array([0, 0, 0, 1]));
      this.center = h.center;
      this.radius = h.radius;
      this.shadowRes = h.shadow.res;
      this.shadowKey = null;
    }

    // the arrays of LATER, decoded while the programs compile (start): the Gaussian records,
    // the SH transfers, the visibility tiles and a sharp material's hits
    fill(arrays) {
      const a = Object.assign(this.a, arrays), h = this.h;
      this.gaussTex = this.gaussTexture();
      this.diffTex = this.rgbTexture(a.diffuse);
      this.bounceTex = a.bounce ? this.rgbTexture(a.bounce)
                                : this.rgbTexture({ data: new Uint16Array(3 * h.n_sh) });
      if (h.sharp || h.lobe_visibility) this.uploadVisibility(this.visRes());
      if (h.sharp) {
        this.uploadHits();
        for (const v in this.programs) {
          this.uniform(this.programs[v].prt, "hit_per_row", "uniform1i", this.hitPerRow);
        }
      }
    }

    // the albedo textures (albedo.glsl): one mipmapped RGBA16F texture array, and the
    // per-vertex UVs, layers and factors; where the specular colour is per texel, its F0
    // layers in a second array of the same layout and the bake's per-vertex F0
    uploadAlbedo() {
      const gl = this.gl, a = this.a, al = a.albedo_layers;
      const [n, h, w] = al.shape;
      if (w > this.maxTex || h > this.maxTex) {
        throw new LimitError("The model's albedo textures are " + w + " × " + h + " texels; " +
                             "this device's largest texture is " + this.maxTex + ".");
      }
      this.albedoTex = this.layerTexture(al);
      this.uvbo = this.buffer(gl.ARRAY_BUFFER, a.uvs.data);
      this.lbo = this.buffer(gl.ARRAY_BUFFER, a.layer.data);
      this.factorBo = this.buffer(gl.ARRAY_BUFFER, a.factor.data);
      if (a.specular_layers) {
        this.specularTex = this.layerTexture(a.specular_layers);
        this.f0bo = this.buffer(gl.ARRAY_BUFFER, a.f0.data);
      }
    }

    // a mipmapped, repeating RGBA16F texture array of (L, H, W, 3) half-float layers
    layerTexture(al) {
      const gl = this.gl;
      const [n, h, w] = al.shape;
      const rgba = new Uint16Array(n * h * w * 4);
      for (let i = 0; i < n * h * w; ++i) {
        rgba[4 * i] = al.data[3 * i]; rgba[4 * i + 1] = al.data[3 * i + 1];
        rgba[4 * i + 2] = al.data[3 * i + 2]; rgba[4 * i + 3] = HALF_ONE;
      }
      const t = gl.createTexture();
      gl.bindTexture(gl.TEXTURE_2D_ARRAY, t);
      gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
      gl.texImage3D(gl.TEXTURE_2D_ARRAY, 0, gl.RGBA16F, w, h, n, 0, gl.RGBA, gl.HALF_FLOAT, rgba);
      gl.generateMipmap(gl.TEXTURE_2D_ARRAY);
      gl.texParameteri(gl.TEXTURE_2D_ARRAY, gl.TEXTURE_MIN_FILTER, gl.LINEAR_MIPMAP_LINEAR);
      gl.texParameteri(gl.TEXTURE_2D_ARRAY, gl.TEXTURE_MAG_FILTER, gl.LINEAR);
      gl.texParameteri(gl.TEXTURE_2D_ARRAY, gl.TEXTURE_WRAP_S, gl.REPEAT);
      gl.texParameteri(gl.TEXTURE_2D_ARRAY, gl.TEXTURE_WRAP_T, gl.REPEAT);
      return t;
    }

    // per-vertex tiles (V, R, R) laid out perRow to a row of one image (render/_gl.py's tile
    // atlas); returns the image's texels and its width and height
    tileAtlas(src, perRow, r) {
      const nv = this.h.n_vertices, rows = Math.ceil(nv / perRow), w = perRow * r;
      const out = new src.constructor(rows * r * w);
      // copied in 32-bit words where a tile's row is a whole number of them (a per-row
      // subarray and set cost several times the copy: 50K tiles of 32 rows); the decoded
      // arrays start at offset 0 (decode), so the words align
      const per = 4 / src.BYTES_PER_ELEMENT;
      const words = Number.isInteger(per) && r % per === 0 && src.byteOffset % 4 === 0;
      const s = words ? new Uint32Array(src.buffer, src.byteOffset, src.length / per) : src;
      const o = words ? new Uint32Array(out.buffer) : out;
      const rw = words ? r / per : r, ww = words ? w / per : w;
      for (let v = 0; v < nv; ++v) {
        const x0 = (v % perRow) * rw, y0 = Math.floor(v / perRow) * r;
        let i = v * r * rw;
        for (let y = 0; y < r; ++y) {
          const row = (y0 + y) * ww + x0;
          for (let x = 0; x < rw; ++x) o[row + x] = s[i++];
        }
      }
      return { data: out, w: w, h: rows * r };
    }

    // n items of `size` values as the rows of a texture `width` wide (zero-padded)
    padded(src, size, width, Ctor) {
      const n = src.length / size, rows = Math.max(1, Math.ceil(n / width));
      const out = new Ctor(rows * width * size);
      out.set(src);
      return { data: out, rows: rows };
    }

    // a sharp material's per-pixel reflection (render/_gl.py _upload_sharp), but for the
    // arrays of LATER (uploadVisibility, uploadHits): the triangles' corners and the vertices'
    // normals and albedos as textures, and the per-corner buffers of the unindexed draw (each
    // corner its vertex's id and its triangle's: OpenGL ES has no gl_PrimitiveID)
    uploadSharp() {
      const gl = this.gl, a = this.a, w = this.h.tex_width;
      // the corners, then from nbrOffset the triangles across each edge (reflection.glsl
      // walk_to_hit)
      const faces = this.padded(new Int32Array(a.faces.data.buffer), 3, w, Int32Array);
      const nbrs = this.padded(a.face_neighbours.data, 3, w, Int32Array);
      const both = new Int32Array(faces.data.length + nbrs.data.length);
      both.set(faces.data);
      both.set(nbrs.data, faces.data.length);
      this.nbrOffset = faces.rows * w;
      this.faceTex = this.dataTexture(w, faces.rows + nbrs.rows, gl.RGB32I, gl.RGB_INTEGER,
                                      gl.INT, both);
      for (const [name, arr] of [["nrmTex", a.normals], ["albTex", a.albedo]]) {
        const p = this.padded(arr.data, 3, w, Float32Array);
        this[name] = this.dataTexture(w, p.rows, gl.RGB32F, gl.RGB, gl.FLOAT, p.data);
      }
      if (this.h.sharp.varying) {  // each vertex's roughness and F0, and the albedo's split table
        const l = this.padded(a.lobe.data, 4, w, Float32Array);
        this.lobeTex = this.dataTexture(w, l.rows, gl.RGBA32F, gl.RGBA, gl.FLOAT, l.data);
        const [sa, st] = a.split.shape;
        this.splitTex = this.dataTexture(st, sa, gl.RG32F, gl.RG, gl.FLOAT, a.split.data);
      }
      // the unindexed draw: every per-vertex buffer repeated per corner, and the ids
      const f = a.faces.data, nc = f.length;
      const ids = new Float32Array(nc), tri = new Float32Array(nc);
      for (let c = 0; c < nc; ++c) { ids[c] = f[c]; tri[c] = Math.floor(c / 3); }
      this.corner = {
        in_vertex: [this.buffer(gl.ARRAY_BUFFER, ids), 1],
        in_face: [this.buffer(gl.ARRAY_BUFFER, tri), 1],
        in_pos: [this.buffer(gl.ARRAY_BUFFER, this.perCorner(a.positions.data, 3)), 3],
        in_normal: [this.buffer(gl.ARRAY_BUFFER, this.perCorner(a.normals.data, 3)), 3],
        in_albedo: [this.buffer(gl.ARRAY_BUFFER, this.perCorner(a.albedo.data, 3)), 3],
      };
      if (a.uvs) {
        this.corner.in_uv = [this.buffer(gl.ARRAY_BUFFER, this.perCorner(a.uvs.data, 2)), 2];
        this.corner.in_layer = [this.buffer(gl.ARRAY_BUFFER, this.perCorner(a.layer.data, 1)), 1];
        this.corner.in_factor = [this.buffer(gl.ARRAY_BUFFER, this.perCorner(a.factor.data, 3)),
                                 3];
      }
      if (a.f0) this.corner.in_f0 = [this.buffer(gl.ARRAY_BUFFER, this.perCorner(a.f0.data, 3)), 3];
      this.nCorners = nc;
    }

    // a sharp material's hit tiles and the vertices' positions with their hit-tile slots
    // (render/_gl.py _upload_sharp), from the arrays of LATER
    uploadHits() {
      const gl = this.gl, a = this.a, h = this.h, r = h.sharp.vis_res, w = h.tex_width;
      const nv = h.n_vertices;
      // the hit tiles, stored as their texels that see the object: a slot for each vertex
      // whose tile has one (in vertex order: the texels ascend), its tile at the slot's place
      // in the atlas, -1 (none) at its other texels (render/_gl.py hit_slots)
      // the texels' flat indices and triangles, stored as steps from the one before
      // (lobelight/web/_export.py)
      const steps = a.hit_step.data, faceSteps = a.hit_face_step.data, rr = r * r;
      const at = new Uint32Array(steps.length), hitFace = new Int32Array(steps.length);
      const slot = new Int32Array(nv).fill(-1);
      let slots = 0;
      for (let i = 0, t = 0, f = 0; i < steps.length; ++i) {
        t += steps[i];
        f += faceSteps[i];
        at[i] = t;
        hitFace[i] = f;
        const v = Math.floor(t / rr);
        if (slot[v] < 0) slot[v] = slots++;
      }
      const hitRow = tilesPerRow(Math.max(slots, 1), r, h.tex_width, this.maxTex);
      const hw = hitRow * r, hh = Math.ceil(Math.max(slots, 1) / hitRow) * r;
      const hf = { data: new Int32Array(hw * hh).fill(-1), w: hw, h: hh };
      const hd = { data: new Uint16Array(hw * hh), w: hw, h: hh };
      for (let i = 0; i < at.length; ++i) {
        const v = Math.floor(at[i] / rr), t = at[i] - v * rr, y = Math.floor(t / r);
        const s = slot[v];
        const p = (Math.floor(s / hitRow) * r + y) * hw + (s % hitRow) * r + (t - y * r);
        hf.data[p] = hitFace[i];
        hd.data[p] = a.hit_dist.data[i];
      }
      this.hitPerRow = hitRow;
      this.hitFaceTex = this.dataTexture(hf.w, hf.h, gl.R32I, gl.RED_INTEGER, gl.INT, hf.data);
      this.hitDistTex = this.dataTexture(hd.w, hd.h, gl.R16F, gl.RED, gl.HALF_FLOAT, hd.data);
      // the positions and each vertex's hit-tile slot
      const pos = this.padded(a.positions.data, 3, w, Float32Array);
      const pos4 = new Float32Array(pos.rows * w * 4);
      for (let v = 0; v < nv; ++v) {
        pos4[4 * v] = pos.data[3 * v];
        pos4[4 * v + 1] = pos.data[3 * v + 1];
        pos4[4 * v + 2] = pos.data[3 * v + 2];
        pos4[4 * v + 3] = slot[v];
      }
      this.posTex = this.dataTexture(w, pos.rows, gl.RGBA32F, gl.RGBA, gl.FLOAT, pos4);
    }

    // the visibility tiles' resolution: the lobe visibility correction's where the model has
    // one, else the sharp reflection's (both read the one atlas)
    visRes() {
      const lv = this.h.lobe_visibility;
      return lv ? lv.vis_res : this.h.sharp.vis_res;
    }

    // the visibility tiles' atlas laid out to fit the device (render/_gl.py
    // _upload_visibility): sets visPerRow, refuses an atlas beyond the device's textures
    visibilityLayout(r) {
      const nv = this.h.n_vertices;
      this.visPerRow = tilesPerRow(nv, r, this.h.tex_width, this.maxTex);
      const w = this.visPerRow * r, rows = Math.ceil(nv / this.visPerRow) * r;
      if (w > this.maxTex || rows > this.maxTex) {
        throw new LimitError("This model's visibility tiles need an image of " + w + " × " +
                             rows + " texels; this device's largest texture is " +
                             this.maxTex + ".");
      }
    }

    // the vertices' visibility tiles (R x R each) as one R8 texture in visibilityLayout's
    // atlas: sets visTex
    uploadVisibility(r) {
      const gl = this.gl;
      const vis = this.tileAtlas(this.a.vis_tiles.data, this.visPerRow, r);
      this.visTex = this.dataTexture(vis.w, vis.h, gl.R8, gl.RED, gl.UNSIGNED_BYTE, vis.data);
    }

    // the lobe visibility correction (render/_gl.py _upload_lobe_visibility): the visibility
    // tiles as a texture, the BRDF's parameters as they are (a buffer, or one row for every
    // vertex), and the buffer of each vertex's factor the pass writes by transform feedback
    uploadLobeVisibility() {
      const gl = this.gl, nv = this.h.n_vertices;
      this.rhoBuf = gl.createBuffer();
      gl.bindBuffer(gl.ARRAY_BUFFER, this.rhoBuf);
      gl.bufferData(gl.ARRAY_BUFFER, 12 * nv, gl.DYNAMIC_COPY);
      gl.bindBuffer(gl.ARRAY_BUFFER, null);
      this.rhoFeedback = gl.createTransformFeedback();
    }

    // the vertex stage's pass (render/_gl.py _stage_pass): a buffer its transform feedback
    // fills, STAGE_TEXELS RGBA32F texels per vertex, copied into the texture of the header's
    // layout (stage.glsl) that the shading pass reads
    uploadStage() {
      const gl = this.gl, [, w, rows] = this.h.stage_layout;
      this.stageWidth = w;
      this.stageRows = rows;
      if (w > this.maxTex || rows > this.maxTex) {
        throw new LimitError("This model's vertex stage needs a texture of " + w + " × " +
                             rows + " texels; this device's largest is " + this.maxTex + ".");
      }
      this.stageBuf = gl.createBuffer();
      gl.bindBuffer(gl.ARRAY_BUFFER, this.stageBuf);
      gl.bufferData(gl.ARRAY_BUFFER, 16 * w * this.stageRows, gl.DYNAMIC_COPY);
      gl.bindBuffer(gl.ARRAY_BUFFER, null);
      this.stageTex = gl.createTexture();
      gl.bindTexture(gl.TEXTURE_2D, this.stageTex);
      gl.texStorage2D(gl.TEXTURE_2D, 1, gl.RGBA32F, w, this.stageRows);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
      this.stageFeedback = gl.createTransformFeedback();
    }

    // per-vertex values (`size` each) repeated at each triangle corner
    perCorner(src, size) {
      const f = this.a.faces.data, out = new Float32Array(f.length * size);
      for (let c = 0; c < f.length; ++c) {
        const v = f[c];
        for (let k = 0; k < size; ++k) out[c * size + k] = src[v * size + k];
      }
      return out;
    }

    compile(name, stages, varyings) {
      const gl = this.gl;
      const prog = gl.createProgram();
      const kinds = [gl.VERTEX_SHADER, gl.FRAGMENT_SHADER];
      for (let i = 0; i < 2; ++i) {
        const s = gl.createShader(kinds[i]);
        gl.shaderSource(s, stages[i]);
        gl.compileShader(s);
        if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) {
          throw new Error("The " + name + " shader does not compile here (" +
                          (i ? "fragment" : "vertex") + " stage):\n" + gl.getShaderInfoLog(s));
        }
        gl.attachShader(prog, s);
      }
      // a transform feedback's outputs are named before the link
      if (varyings) gl.transformFeedbackVaryings(prog, varyings, gl.INTERLEAVED_ATTRIBS);
      gl.linkProgram(prog);
      if (!gl.getProgramParameter(prog, gl.LINK_STATUS)) {
        throw new Error("The " + name + " program does not link here:\n" +
                        gl.getProgramInfoLog(prog));
      }
      for (const [block, binding] of [["Frame", FRAME_BINDING], ["Planes", PLANES_BINDING],
                                      ["Sample", SAMPLE_BINDING]]) {
        const i = gl.getUniformBlockIndex(prog, block);
        if (i !== gl.INVALID_INDEX) gl.uniformBlockBinding(prog, i, binding);
      }
      gl.useProgram(prog);
      for (const u in UNITS) {
        const loc = gl.getUniformLocation(prog, u);
        if (loc) gl.uniform1i(loc, UNITS[u]);
      }
      return prog;
    }

    uniform(prog, name, kind, value) {
      const gl = this.gl, loc = gl.getUniformLocation(prog, name);
      if (!loc) return;  // compiled out
      gl.useProgram(prog);
      gl[kind](loc, value);
    }

    attribute(prog, name, buffer, size, stride, offset) {
      const gl = this.gl, loc = gl.getAttribLocation(prog, name);
      if (loc < 0) return;
      gl.bindBuffer(gl.ARRAY_BUFFER, buffer);
      gl.enableVertexAttribArray(loc);
      gl.vertexAttribPointer(loc, size, gl.FLOAT, false, stride || 0, offset || 0);
    }

    // the programs of one shader variant and their vertex arrays
    programsFor(variant, env) {
      if (this.programs[variant]) return this.programs[variant];
      const gl = this.gl, src = this.shaders.header[variant];
      const p = {};
      for (const name of ["prt", "depth", "shadow", "background", "tonemap", "accumulate"]) {
        if (src[name]) p[name] = this.compile(name, src[name]);
      }
      p.stage = this.compile("stage", src.stage, this.h.stage_varyings);
      if (src.lobevis) p.lobevis = this.compile("lobevis", src.lobevis, ["v_rho"]);
      const size = gl.getActiveUniformBlockParameter(
        p.prt, gl.getUniformBlockIndex(p.prt, "Frame"), gl.UNIFORM_BLOCK_DATA_SIZE);
      if (size !== this.frameData.byteLength) {
        throw new Error("frame.glsl's block has " + size + " bytes; the page fills " +
                        this.frameData.byteLength);
      }
      const sampleSize = gl.getActiveUniformBlockParameter(
        p.prt, gl.getUniformBlockIndex(p.prt, "Sample"), gl.UNIFORM_BLOCK_DATA_SIZE);
      gl.bindBuffer(gl.UNIFORM_BUFFER, this.sampleUbo);
      const sample = new Float32Array(Math.max(4, sampleSize / 4));
      sample[3] = 1;  // setJitter's tap_step for one sample per pixel
      gl.bufferData(gl.UNIFORM_BUFFER, sample, gl.STATIC_DRAW);
      this.uniform(p.prt, "tex_width", "uniform1i", this.texWidth);
      const at = this.h.albedo_textures;
      if (at) {
        this.uniform(p.prt, "albedo_xform", "uniform3fv", at.xform);
        this.uniform(p.prt, "albedo_mode", "uniform3fv", at.mode);
        this.uniform(p.prt, "albedo_size", "uniform2fv", at.size);
        this.uniform(p.prt, "albedo_grad_scale", "uniform1f", 1.0);  // one sample per pixel
      }
      p.vao = this.h.sharp ? this.cornerArray(p.prt) : this.vertexArray(p.prt, true);
      this.uniform(p.stage, "tex_width", "uniform1i", this.texWidth);
      p.stageVao = this.vertexArray(p.stage, true);
      if (this.h.sharp) this.sharpUniforms(p);
      if (p.lobevis) this.lobeVisibilityUniforms(p);
      p.depthVao = this.vertexArray(p.depth, false);
      p.shadowVao = this.vertexArray(p.shadow, false);
      p.bgVao = this.quadArray(p.background);
      p.tmVao = this.quadArray(p.tonemap);
      p.accVao = this.quadArray(p.accumulate);
      this.programs[variant] = p;
      return p;
    }

    vertexArray(prog, full) {
      const gl = this.gl, vao = gl.createVertexArray();
      gl.bindVertexArray(vao);
      this.attribute(prog, "in_pos", this.vbo, 3);
      if (full) {
        this.attribute(prog, "in_normal", this.nbo, 3);
        this.attribute(prog, "in_albedo", this.abo, 3);
        if (this.albedoTex) {
          this.attribute(prog, "in_uv", this.uvbo, 2);
          this.attribute(prog, "in_layer", this.lbo, 1);
          this.attribute(prog, "in_factor", this.factorBo, 3);
        }
        if (this.specularTex) this.attribute(prog, "in_f0", this.f0bo, 3);
        if (this.rhoBuf) this.attribute(prog, "in_rho", this.rhoBuf, 3);  // prt.glsl LOBE_VIS
      }
      gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, this.ibo);
      gl.bindVertexArray(null);
      return vao;
    }

    // the unindexed draw's vertex array: each corner's values and ids (uploadSharp)
    cornerArray(prog) {
      const gl = this.gl, vao = gl.createVertexArray();
      gl.bindVertexArray(vao);
      for (const name in this.corner) {
        const [buffer, size] = this.corner[name];
        this.attribute(prog, name, buffer, size);
      }
      gl.bindVertexArray(null);
      return vao;
    }

    // a sharp material's uniforms (render/_gl.py _upload_sharp)
    sharpUniforms(p) {
      const s = this.h.sharp;
      this.uniform(p.prt, "vis_per_row", "uniform1i", this.visPerRow);
      this.uniform(p.prt, "hit_per_row", "uniform1i", this.hitPerRow);
      this.uniform(p.prt, "face_width", "uniform1i", this.h.tex_width);
      this.uniform(p.prt, "nbr_offset", "uniform1i", this.nbrOffset);
      this.uniform(p.prt, "sharp_weight", "uniform1fv", s.weights);
      this.uniform(p.prt, "sharp_lam", "uniform1fv", s.lam);
      this.uniform(p.prt, "sharp_warp", "uniform1f", s.warp);
      if (!s.varying) this.uniform(p.prt, "sharp_albedo", "uniform3fv", s.albedo.flat());
    }

    // the lobe visibility correction's uniforms and vertex array (render/_gl.py's lv_vao):
    // the per-vertex buffers with the BRDF's parameters as they are
    lobeVisibilityUniforms(p) {
      const gl = this.gl, lv = this.h.lobe_visibility, prog = p.lobevis;
      this.uniform(prog, "tex_width", "uniform1i", this.texWidth);
      this.uniform(prog, "vis_per_row", "uniform1i", this.visPerRow);
      this.uniform(prog, "sun_model", "uniform1i", lv.brdf.model);
      this.uniform(prog, "sun_fresnel", "uniform1f", lv.brdf.fresnel);
      this.uniform(prog, "lv_samples", "uniform1i", lv.samples);
      p.lvVao = this.vertexArray(prog, true);
      // a buffer even where every vertex has the same: a constant attribute value is the
      // context's, not the vertex array's, and the sun's shading sets its own
      let sp = this.a.lv_params;
      if (sp.shape[0] === 1) {
        const nv = this.h.n_vertices, rows = new Float32Array(10 * nv);
        for (let v = 0; v < nv; ++v) rows.set(sp.data.subarray(0, 10), 10 * v);
        sp = { data: rows, shape: [nv, 10] };
      }
      this.brdfAttributes(sp, prog, p.lvVao, "lvBuffer", this, false);
    }

    quadArray(prog) {
      const gl = this.gl, vao = gl.createVertexArray();
      gl.bindVertexArray(vao);
      this.attribute(prog, "in_xy", this.quad, 2);
      gl.bindVertexArray(null);
      return vao;
    }

    // the sun's glossy BRDF per vertex (render/_sun_glossy.py): a buffer, or constant
    // attribute values when every vertex has the same
    sunAttributes(env, prog, vao) {
      const corners = !!(this.h.sharp && vao === env.programs.vao);
      this.brdfAttributes(env.arrays.sun_params, prog, vao,
                          corners ? "sunCornerBuffer" : "sunBuffer", env, corners);
    }

    // a BRDF's parameters per vertex sp ((V or 1, 10): in_sb0, in_eta, in_k) as prog's
    // attributes in vao: a buffer kept as owner[key] (repeated per corner for the unindexed
    // draw), or constant attribute values when every vertex has the same
    brdfAttributes(sp, prog, vao, key, owner, corners) {
      const gl = this.gl;
      gl.bindVertexArray(vao);
      const names = [["in_sb0", 4, 0], ["in_eta", 3, 4], ["in_k", 3, 7]];
      if (sp.shape[0] === 1) {
        for (const [name, size, off] of names) {
          const loc = gl.getAttribLocation(prog, name);
          if (loc < 0) continue;
          gl.disableVertexAttribArray(loc);
          const v = sp.data.slice(off, off + size);
          gl.vertexAttrib4f(loc, v[0], v[1], v[2], size === 4 ? v[3] : 1);
        }
      } else {
        if (!owner[key]) {
          owner[key] = this.buffer(gl.ARRAY_BUFFER, corners ? this.perCorner(sp.data, 10) : sp.data);
        }
        for (const [name, size, off] of names) {
          this.attribute(prog, name, owner[key], size, 40, 4 * off);
        }
      }
      gl.bindVertexArray(null);
    }

    // one map: its chain's atlas, its background cube, its SH and sun (arrays: decodeAll's)
    addEnv(doc, arrays) {
      const gl = this.gl, h = doc.header;
      const at = arrays.atlas;
      const [ah, aw] = at.shape;
      if (aw > this.maxTex || ah > this.maxTex) {
        throw new LimitError("The map " + h.name + "'s prefiltered chain is " + aw + " × " + ah +
                             " texels; this device's largest texture is " + this.maxTex + ".");
      }
      const atlas = gl.createTexture();
      gl.bindTexture(gl.TEXTURE_2D, atlas);
      gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
      gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGB16F, aw, ah, 0, gl.RGB, gl.HALF_FLOAT, at.data);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.LINEAR);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.LINEAR);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
      const bg = arrays.background, res = bg.shape[1];
      const cube = gl.createTexture();
      gl.bindTexture(gl.TEXTURE_CUBE_MAP, cube);
      const face = res * res * 3;
      for (let f = 0; f < 6; ++f) {
        gl.texImage2D(gl.TEXTURE_CUBE_MAP_POSITIVE_X + f, 0, gl.RGB16F, res, res, 0, gl.RGB,
                      gl.HALF_FLOAT, bg.data.subarray(f * face, (f + 1) * face));
      }
      gl.texParameteri(gl.TEXTURE_CUBE_MAP, gl.TEXTURE_MIN_FILTER, gl.LINEAR);
      gl.texParameteri(gl.TEXTURE_CUBE_MAP, gl.TEXTURE_MAG_FILTER, gl.LINEAR);
      gl.texParameteri(gl.TEXTURE_CUBE_MAP, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
      gl.texParameteri(gl.TEXTURE_CUBE_MAP, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
      const env = { header: h, arrays: arrays, atlas: atlas, cube: cube, wholeAtlas: null };
      if (arrays.whole_atlas) {  // a sharp lobe's view of the sun's shape (prt.glsl sun_shape)
        const t = gl.createTexture();
        gl.bindTexture(gl.TEXTURE_2D, t);
        gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGB16F, aw, ah, 0, gl.RGB, gl.HALF_FLOAT,
                      arrays.whole_atlas.data);
        gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.LINEAR);
        gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.LINEAR);
        gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
        gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
        env.wholeAtlas = t;
      }
      const p = this.programsFor(h.variant, env);
      const pf = h.prefiltered;
      // the shading's lookups, and the rough lobe's correction's, read the same chain
      for (const prog of p.lobevis ? [p.prt, p.lobevis] : [p.prt]) {
        this.uniform(prog, "atlas_size", "uniform2fv", pf.atlas_size);
        this.uniform(prog, "level_y", "uniform1fv", pf.level_y);
        this.uniform(prog, "level_res", "uniform1fv", pf.level_res);
        this.uniform(prog, "n_levels", "uniform1i", pf.n_levels);
        this.uniform(prog, "lam0", "uniform1f", pf.lam0);
        this.uniform(prog, "log_rho", "uniform1f", pf.log_rho);
      }
      env.programs = p;
      this.envs.push(env);
      return env;
    }

    useEnv(i) {
      const env = this.envs[i], p = env.programs, h = env.header;
      this.env = env;
      this.rot = null;
      this.shadowKey = null;
      if (h.sun) {
        this.uniform(p.prt, "sun_tan", "uniform1f", h.sun.tan);
        this.uniform(p.prt, "shadow_res", "uniform1f", this.shadowRes);
        this.makeShadowMap();
        const f = this.frameData;
        const scale = 1 / (1.02 * this.radius);
        const texel = 2 / (scale * this.shadowRes);
        f.set(h.sun.irradiance, FRAME.sun_e);
        f.set(this.center, FRAME.shadow_center);
        f[FRAME.shadow_scale] = scale;
        f[FRAME.shadow_offset] = 1.5 * texel;
        f[FRAME.shadow_bias] = 1 / this.shadowRes;
      }
      if (h.sun_glossy) {
        this.uniform(p.prt, "sun_model", "uniform1i", h.sun_brdf.model);
        this.uniform(p.prt, "sun_fresnel", "uniform1f", h.sun_brdf.fresnel);
        this.uniform(p.prt, "sun_spread", "uniform1f", h.sun.spread);
        if (h.sun_tail != null) this.uniform(p.prt, "sun_tail", "uniform1f", h.sun_tail);
        this.sunAttributes(env, p.prt, p.vao);
        this.sunAttributes(env, p.stage, p.stageVao);
      }
    }

    // the sun's depth map (render/_gl.py _make_shadow_map): compared with 2x2 filtering on
    // its unit, read without comparison through a sampler on another
    makeShadowMap() {
      if (this.shadowTex) return;
      const gl = this.gl, r = this.shadowRes;
      const t = gl.createTexture();
      gl.bindTexture(gl.TEXTURE_2D, t);
      gl.texStorage2D(gl.TEXTURE_2D, 1, gl.DEPTH_COMPONENT24, r, r);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_COMPARE_MODE, gl.COMPARE_REF_TO_TEXTURE);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_COMPARE_FUNC, gl.LEQUAL);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.LINEAR);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.LINEAR);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
      this.shadowTex = t;
      const s = gl.createSampler();
      gl.samplerParameteri(s, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
      gl.samplerParameteri(s, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
      gl.samplerParameteri(s, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
      gl.samplerParameteri(s, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
      gl.samplerParameteri(s, gl.TEXTURE_COMPARE_MODE, gl.NONE);
      this.shadowSampler = s;
      this.shadowFbo = gl.createFramebuffer();
      gl.bindFramebuffer(gl.FRAMEBUFFER, this.shadowFbo);
      gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.DEPTH_ATTACHMENT, gl.TEXTURE_2D, t, 0);
      gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    }

    // the RGBA16F target of a frame of `scale` times the canvas's pixels across (bilinearly
    // filtered when it is smaller, for the tone mapping's stretch onto the canvas)
    movingTarget(w, h, scale) {
      if (scale >= 1) return this.target(w, h, this.gl[FRAME_FORMAT]);
      const gl = this.gl;
      const sw = Math.max(1, Math.round(w * scale)), sh = Math.max(1, Math.round(h * scale));
      const t = this.target(sw, sh, gl[FRAME_FORMAT], "moving");
      if (!t.linear) {
        gl.bindTexture(gl.TEXTURE_2D, t.color);
        gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.LINEAR);
        gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.LINEAR);
        gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
        gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
        t.linear = true;
      }
      return t;
    }

    // a float colour target with a depth buffer, kept by size and type
    target(w, h, internal, tag) {
      const key = w + "x" + h + ":" + internal + ":" + (tag || "");
      if (this.targets[key]) return this.targets[key];
      const gl = this.gl;
      const color = gl.createTexture();
      gl.bindTexture(gl.TEXTURE_2D, color);
      gl.texStorage2D(gl.TEXTURE_2D, 1, internal, w, h);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
      const depth = gl.createRenderbuffer();
      gl.bindRenderbuffer(gl.RENDERBUFFER, depth);
      gl.renderbufferStorage(gl.RENDERBUFFER, gl.DEPTH_COMPONENT24, w, h);
      const fbo = gl.createFramebuffer();
      gl.bindFramebuffer(gl.FRAMEBUFFER, fbo);
      gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, color, 0);
      gl.framebufferRenderbuffer(gl.FRAMEBUFFER, gl.DEPTH_ATTACHMENT, gl.RENDERBUFFER, depth);
      if (gl.checkFramebufferStatus(gl.FRAMEBUFFER) !== gl.FRAMEBUFFER_COMPLETE) {
        throw new Error("A float colour target cannot be rendered to here.");
      }
      gl.bindFramebuffer(gl.FRAMEBUFFER, null);
      const t = { fbo: fbo, color: color, w: w, h: h, internal: internal };
      this.targets[key] = t;
      return t;
    }

    // frame.glsl's block for a camera {eye, left, up, dir, tan} and rotation R (row-major)
    fillFrame(cam, rot, diffuse, glossy) {
      const f = this.frameData, env = this.env, h = env.header, n = this.h.n_sh;
      f.set(cam.eye, FRAME.eye);
      f.set(cam.left, FRAME.cam_left);
      f.set(cam.up, FRAME.cam_up);
      f.set(cam.dir, FRAME.cam_dir);
      f.set(cam.tan, FRAME.tan_half);
      const dist = Math.hypot(...sub(cam.eye, this.center));
      const near = Math.max(dist - 1.01 * this.radius, 1e-3 * this.radius);
      f.set([near, dist + 1.01 * this.radius], FRAME.depth_range);
      const key = rot.join(",");
      if (key !== this.rot) {
        for (let j = 0; j < 3; ++j) f.set(rot.slice(3 * j, 3 * j + 3), FRAME.rot_t + 4 * j);
        const sh = this.rotateSH(env.arrays.sh.data, rot);
        for (let i = 0; i < n; ++i) f.set(sh[i], FRAME.sh_light + 4 * i);
        if (h.sun) {
          const l = matVec(rot, h.sun.direction);
          const fr = sunFrame(l);
          for (let j = 0; j < 3; ++j) {
            f.set([fr[0][j], fr[1][j], fr[2][j]], FRAME.shadow_frame + 4 * j);
          }
          f.set(fr[2], FRAME.sun_dir);
          this.sunFrameKey = fr.join(",");
          if (h.has_bounce) {
            const y = shBasis(l[0], l[1], l[2], Math.round(Math.sqrt(n)));
            const e = h.sun.irradiance;
            for (let i = 0; i < n; ++i) {
              f.set([y[i] * e[0], y[i] * e[1], y[i] * e[2]], FRAME.sh_light + 4 * n + 4 * i);
            }
          }
        }
        this.rot = key;
      }
      const sunOn = !!h.sun && (diffuse || (glossy && h.sun_glossy));
      f[FRAME.diffuse_on] = diffuse ? 1 : 0;
      f[FRAME.glossy_on] = glossy ? 1 : 0;
      f[FRAME.sun_on] = sunOn ? 1 : 0;
      const gl = this.gl;
      gl.bindBuffer(gl.UNIFORM_BUFFER, this.frameUbo);
      gl.bufferSubData(gl.UNIFORM_BUFFER, 0, this.frameData);
      return sunOn;
    }

    // the rotated lighting's SH, L(R^T w): evaluated at fixed directions and refitted
    rotateSH(c, rot) {
      const a = this.a, n = this.h.n_sh, order = Math.round(Math.sqrt(n));
      const dirs = a.sh_dirs.data, fit = a.sh_fit.data, nd = a.sh_dirs.shape[0];
      const vals = [];
      for (let i = 0; i < nd; ++i) {
        const d = matTVec(rot, [dirs[3 * i], dirs[3 * i + 1], dirs[3 * i + 2]]);
        const y = shBasis(d[0], d[1], d[2], order);
        const v = [0, 0, 0];
        for (let k = 0; k < n; ++k) {
          v[0] += y[k] * c[3 * k]; v[1] += y[k] * c[3 * k + 1]; v[2] += y[k] * c[3 * k + 2];
        }
        vals.push(v);
      }
      const out = [];
      for (let k = 0; k < n; ++k) {
        const s = [0, 0, 0];
        for (let i = 0; i < nd; ++i) {
          const w = fit[k * nd + i];
          s[0] += w * vals[i][0]; s[1] += w * vals[i][1]; s[2] += w * vals[i][2];
        }
        out.push(s);
      }
      return out;
    }

    bindBlocks() {
      const gl = this.gl;
      gl.bindBufferBase(gl.UNIFORM_BUFFER, FRAME_BINDING, this.frameUbo);
      gl.bindBufferBase(gl.UNIFORM_BUFFER, PLANES_BINDING, this.planes);
      gl.bindBufferBase(gl.UNIFORM_BUFFER, SAMPLE_BINDING, this.sampleUbo);
    }

    shadowPass(p) {
      if (this.sunFrameKey === this.shadowKey) return;
      const gl = this.gl;
      this.shadowKey = this.sunFrameKey;
      gl.bindFramebuffer(gl.FRAMEBUFFER, this.shadowFbo);
      gl.viewport(0, 0, this.shadowRes, this.shadowRes);
      gl.enable(gl.DEPTH_TEST);
      gl.depthFunc(gl.LESS);
      gl.depthMask(true);
      gl.clear(gl.DEPTH_BUFFER_BIT);
      gl.useProgram(p.shadow);
      gl.bindVertexArray(p.shadowVao);
      gl.drawElements(gl.TRIANGLES, this.nIndices, gl.UNSIGNED_INT, 0);
      gl.bindVertexArray(null);
    }

    // the vertex stage's results for this frame's view and lighting into stageTex: its
    // transform feedback, one vertex per vertex, nothing rasterised, then the buffer copied
    // into the texture (render/_gl.py _stage_pass)
    stagePass(p) {
      const gl = this.gl;
      this.bindVertexStage();
      this.feedback(p.stage, p.stageVao, this.stageFeedback, this.stageBuf);
      gl.bindBuffer(gl.PIXEL_UNPACK_BUFFER, this.stageBuf);
      this.bindTexture(UNITS.stage_tex, gl.TEXTURE_2D, this.stageTex);
      gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, this.stageWidth, this.stageRows, gl.RGBA,
                       gl.FLOAT, 0);
      gl.bindBuffer(gl.PIXEL_UNPACK_BUFFER, null);
    }

    // each vertex's factor on its direct Gaussians' light for this frame's view and lighting
    // into rhoBuf, by transform feedback of the correction's vertex stage, nothing rasterised
    // (render/_gl.py _lobe_visibility_pass)
    lobeVisibilityPass(p, moving) {
      const gl = this.gl, lv = this.h.lobe_visibility;
      // fewer directions while the view moves, as fewer pixels then (MOVING_SAMPLES)
      this.uniform(p.lobevis, "lv_samples", "uniform1i", moving ? lv.moving_samples : lv.samples);
      this.bindVertexStage();
      this.bindTexture(UNITS.atlas, gl.TEXTURE_2D, this.env.atlas);
      this.bindTexture(UNITS.vis_tex, gl.TEXTURE_2D, this.visTex);
      this.feedback(p.lobevis, p.lvVao, this.rhoFeedback, this.rhoBuf);
    }

    // prog's vertex stage over every vertex (one point each, nothing rasterised), its
    // outputs captured into buf through the transform feedback object tf
    feedback(prog, vao, tf, buf) {
      const gl = this.gl;
      gl.useProgram(prog);
      gl.bindVertexArray(vao);
      gl.enable(gl.RASTERIZER_DISCARD);
      gl.bindTransformFeedback(gl.TRANSFORM_FEEDBACK, tf);
      gl.bindBufferBase(gl.TRANSFORM_FEEDBACK_BUFFER, 0, buf);
      gl.beginTransformFeedback(gl.POINTS);
      gl.drawArrays(gl.POINTS, 0, this.h.n_vertices);
      gl.endTransformFeedback();
      // unbound before another pass reads the buffer (a vertex attribute, a texture's copy)
      gl.bindBufferBase(gl.TRANSFORM_FEEDBACK_BUFFER, 0, null);
      gl.bindTransformFeedback(gl.TRANSFORM_FEEDBACK, null);
      gl.disable(gl.RASTERIZER_DISCARD);
      gl.bindVertexArray(null);
    }

    // the textures prt.glsl's vertex stage reads on their units (render/_gl.py
    // _use_vertex_stage_textures)
    bindVertexStage() {
      const gl = this.gl;
      this.bindTexture(UNITS.gauss_tex, gl.TEXTURE_2D, this.gaussTex);
      this.bindTexture(UNITS.diff_tex, gl.TEXTURE_2D, this.diffTex);
      this.bindTexture(UNITS.cand_tex, gl.TEXTURE_2D, this.candTex);
      this.bindTexture(UNITS.bounce_tex, gl.TEXTURE_2D, this.bounceTex);
    }

    // the sharp reflection's textures on their units (render/_gl.py _draw_sample)
    bindSharp(env) {
      const gl = this.gl, T = gl.TEXTURE_2D;
      const tex = [["vis_tex", this.visTex], ["face_tex", this.faceTex], ["pos_tex", this.posTex],
                   ["nrm_tex", this.nrmTex], ["alb_tex", this.albTex],
                   ["hit_face_tex", this.hitFaceTex], ["hit_dist_tex", this.hitDistTex]];
      for (const [name, t] of tex) this.bindTexture(UNITS[name], T, t);
      if (env.wholeAtlas) this.bindTexture(UNITS.whole_atlas, T, env.wholeAtlas);
      if (this.lobeTex) {
        this.bindTexture(UNITS.lobe_tex, T, this.lobeTex);
        this.bindTexture(UNITS.split_tex, T, this.splitTex);
      }
    }

    // with passTimes set (api.profile), the milliseconds since the last mark added to pass
    // `name`, the GPU's work finished first
    mark(name) {
      if (!this.passTimes) return;
      const gl = this.gl, bound = gl.getParameter(gl.FRAMEBUFFER_BINDING);
      // a pixel of the target just drawn read back: the work before it finished
      if (bound === null) gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, new Uint8Array(4));
      else if (bound !== this.shadowFbo) {
        gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.FLOAT, new Float32Array(4));
      }
      const now = performance.now();
      this.passTimes[name] = (this.passTimes[name] || 0) + now - this.markT;
      this.markT = now;
    }

    bindTexture(unit, target, tex) {
      const gl = this.gl;
      gl.activeTexture(gl.TEXTURE0 + unit);
      gl.bindTexture(target, tex);
    }

    // one sample of a small image of camera cam queued and not read back, before the arrays
    // of LATER are filled: the programs' pipelines for the frame's format are made while
    // those decode (LATER); the image is of no use
    warmUp(cam, rot) {
      this.draw(this.target(8, 8, this.gl[FRAME_FORMAT], "warm-up"), cam, rot,
                { diffuse: true, glossy: true, background: true });
      this.gl.flush();
    }

    // one frame into target t (GLRenderer.draw): with several sub-pixel sample offsets
    // ([x, y] in [0, 1), x right, y down), one pass per sample with the image shifted
    // (frame.glsl's jitter) added into t with weight 1 / S (accumulate.glsl); alpha is then
    // the fraction of the pixel's samples on the object
    draw(t, cam, rot, opts) {
      const gl = this.gl, env = this.env, p = env.programs;
      this.mark("other");
      const sunOn = this.fillFrame(cam, rot, opts.diffuse, opts.glossy);
      this.bindBlocks();
      this.mark("uniforms");
      if (sunOn) this.shadowPass(p);
      this.mark("shadow");
      if (p.lobevis && opts.glossy) this.lobeVisibilityPass(p, opts.moving);
      this.mark("lobe visibility");
      this.stagePass(p);
      this.mark("stage");
      const offsets = opts.offsets && opts.offsets.length > 1 ? opts.offsets : null;
      if (!offsets) {
        this.setJitter(opts.offsets ? opts.offsets[0] : [0.5, 0.5], t, 0, 1);
        this.drawSample(t, opts.background);
        return;
      }
      const pass = this.target(t.w, t.h, t.internal, "pass");
      gl.bindFramebuffer(gl.FRAMEBUFFER, t.fbo);
      gl.clearColor(0, 0, 0, 0);
      gl.clear(gl.COLOR_BUFFER_BIT);
      for (const [i, o] of offsets.entries()) {
        this.setJitter(o, t, i, offsets.length);
        this.drawSample(pass, opts.background);
        gl.bindFramebuffer(gl.FRAMEBUFFER, t.fbo);
        gl.viewport(0, 0, t.w, t.h);
        gl.disable(gl.DEPTH_TEST);
        gl.enable(gl.BLEND);
        gl.blendFunc(gl.ONE, gl.ONE);
        gl.blendEquation(gl.FUNC_ADD);
        this.bindTexture(UNITS.image, gl.TEXTURE_2D, pass.color);
        this.uniform(p.accumulate, "weight", "uniform1f", 1 / offsets.length);
        gl.useProgram(p.accumulate);
        gl.bindVertexArray(p.accVao);
        gl.drawArrays(gl.TRIANGLE_STRIP, 0, 4);
        gl.bindVertexArray(null);
        gl.disable(gl.BLEND);
      }
    }

    // the NDC shift that puts the sample at offset o under the pixel centre (GL's y runs up),
    // and the directions over the sun's disc that sample i of n takes (frame.glsl's tap_first
    // and tap_step, render/_sun_shadow.py sample_taps)
    setJitter(o, t, i, n) {
      const gl = this.gl;
      const step = Math.min(n, this.h.shadow.samples);
      gl.bindBuffer(gl.UNIFORM_BUFFER, this.sampleUbo);
      gl.bufferSubData(gl.UNIFORM_BUFFER, 0, new Float32Array(
        [2 * (0.5 - o[0]) / t.w, 2 * (o[1] - 0.5) / t.h, i % step, step]));
    }

    // one sample of every pixel into t: the object's depth, its shading where the depth is
    // the front-most, then the background where the object left the far plane
    drawSample(t, background) {
      const gl = this.gl, env = this.env, p = env.programs;
      gl.bindFramebuffer(gl.FRAMEBUFFER, t.fbo);
      gl.viewport(0, 0, t.w, t.h);
      gl.clearColor(0, 0, 0, 0);
      gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
      gl.enable(gl.DEPTH_TEST);
      gl.depthFunc(gl.LESS);
      if (this.cull) {
        gl.enable(gl.CULL_FACE);
        gl.cullFace(gl.BACK);  // counter-clockwise in the image is the front, as GL's default
      }
      if (this.prepass) {
        gl.colorMask(false, false, false, false);
        gl.useProgram(p.depth);
        gl.bindVertexArray(p.depthVao);
        gl.drawElements(gl.TRIANGLES, this.nIndices, gl.UNSIGNED_INT, 0);
        gl.colorMask(true, true, true, true);
      }
      this.mark("depth");
      gl.depthFunc(gl.LEQUAL);
      this.bindTexture(UNITS.stage_tex, gl.TEXTURE_2D, this.stageTex);
      this.bindTexture(UNITS.atlas, gl.TEXTURE_2D, env.atlas);
      if (this.albedoTex) this.bindTexture(UNITS.albedo_tex, gl.TEXTURE_2D_ARRAY, this.albedoTex);
      if (this.specularTex) {
        this.bindTexture(UNITS.specular_tex, gl.TEXTURE_2D_ARRAY, this.specularTex);
      }
      if (env.header.sun) {
        this.bindTexture(UNITS.shadow_map, gl.TEXTURE_2D, this.shadowTex);
        this.bindTexture(UNITS.shadow_depth, gl.TEXTURE_2D, this.shadowTex);
        gl.bindSampler(UNITS.shadow_depth, this.shadowSampler);
      }
      if (this.h.sharp) this.bindSharp(env);
      gl.useProgram(p.prt);
      gl.bindVertexArray(p.vao);
      if (this.h.sharp) gl.drawArrays(gl.TRIANGLES, 0, this.nCorners);
      else gl.drawElements(gl.TRIANGLES, this.nIndices, gl.UNSIGNED_INT, 0);
      if (env.header.sun) gl.bindSampler(UNITS.shadow_depth, null);
      gl.disable(gl.CULL_FACE);
      this.mark("prt");
      if (background) {
        this.bindTexture(UNITS.env, gl.TEXTURE_CUBE_MAP, env.cube);
        gl.useProgram(p.background);
        gl.bindVertexArray(p.bgVao);
        gl.drawArrays(gl.TRIANGLE_STRIP, 0, 4);
      }
      gl.bindVertexArray(null);
      gl.depthFunc(gl.LESS);
      this.mark("background");
    }

    // the frame tone-mapped onto the canvas (tonemap.glsl: exposure, Khronos PBR Neutral, sRGB)
    present(t, exposure) {
      const gl = this.gl, p = this.env.programs;
      gl.bindFramebuffer(gl.FRAMEBUFFER, null);
      gl.viewport(0, 0, gl.drawingBufferWidth, gl.drawingBufferHeight);
      gl.disable(gl.DEPTH_TEST);
      this.bindTexture(UNITS.image, gl.TEXTURE_2D, t.color);
      this.uniform(p.tonemap, "scale", "uniform1f", Math.pow(2, exposure));
      this.uniform(p.tonemap, "curve", "uniform1i", CURVE_NEUTRAL);
      gl.useProgram(p.tonemap);
      gl.bindVertexArray(p.tmVao);
      gl.drawArrays(gl.TRIANGLE_STRIP, 0, 4);
      gl.bindVertexArray(null);
      this.mark("tonemap");
    }

    // linear RGBA of target t, rows top first
    readLinear(t) {
      const gl = this.gl, w = t.w, h = t.h;
      gl.bindFramebuffer(gl.FRAMEBUFFER, t.fbo);
      const px = new Float32Array(w * h * 4);
      gl.readPixels(0, 0, w, h, gl.RGBA, gl.FLOAT, px);
      gl.bindFramebuffer(gl.FRAMEBUFFER, null);
      const out = new Float32Array(w * h * 4);
      for (let y = 0; y < h; ++y) {
        out.set(px.subarray((h - 1 - y) * w * 4, (h - y) * w * 4), y * w * 4);
      }
      return out;
    }
  }

  // ---------------------------------------------------------------------------------------
  // the page

  const api = window.lobelight = {
    ready: null,
    status: { ok: false, message: "loading" },
    viewer: null,
    shBasis: shBasis,
  };

  function showMessage(text) {
    const m = document.getElementById("message");
    if (m) {
      m.textContent = text;
      m.style.display = "flex";
    }
    api.status = { ok: false, message: text };
  }

  // whether this WebGL's rasteriser rejects a fragment by its depth before shading it, as
  // GPUs and llvmpipe do; SwiftShader (Chrome's software WebGL) runs the fragment shader on
  // every covered pixel and tests the depth after it (measured in docs/benchmarks.md: a heavy
  // shader costs as much behind a depth test that fails everywhere). A renderer not named is
  // taken to reject early.
  function rendererRejectsEarly(gl) {
    const e = gl.getExtension("WEBGL_debug_renderer_info");
    const name = String(gl.getParameter(e ? e.UNMASKED_RENDERER_WEBGL : gl.RENDERER));
    return !/swiftshader/i.test(name);
  }

  function pageOptions() {
    const q = new URLSearchParams(window.location.search);
    const o = {};
    if (q.get("max_texture")) o.maxTexture = parseInt(q.get("max_texture"), 10);
    if (q.get("size")) o.size = q.get("size").split("x").map(function (s) { return parseInt(s, 10); });
    o.env = parseInt(q.get("env") || "0", 10);
    // prepass=0: no depth pre-pass (each covered pixel may then be shaded more than once);
    // prepass=1: one; without: the Viewer chooses (rendererRejectsEarly)
    if (q.get("prepass") === "0" || q.get("prepass") === "1") o.prepass = q.get("prepass") === "1";
    // cull=0: a closed surface's triangles seen from behind are drawn too
    if (q.get("cull") === "0") o.cull = false;
    o.still = q.get("still") === "1";
    // moving=S: the frames drawn while the view changes have S times the canvas's pixels
    // across (0 < S <= 1); without it the page chooses S (MOVING_MIN..1) for MOVING_FPS
    if (q.get("moving")) o.moving = Math.max(0.1, Math.min(1, parseFloat(q.get("moving"))));
    return o;
  }

  function decodeB64Floats(b64) { return new Float32Array(bytesOf(b64).buffer); }
  function floatsB64(arr) {
    const b = new Uint8Array(arr.buffer, arr.byteOffset, arr.byteLength);
    let s = "";
    for (let i = 0; i < b.length; i += 0x8000) {
      s += String.fromCharCode.apply(null, b.subarray(i, i + 0x8000));
    }
    return btoa(s);
  }
  api._floats = decodeB64Floats;
  api._tilesPerRow = tilesPerRow;

  // the interactive state: an orbit about the exported camera's target, a light turn about +y
  function makeOrbit(cam) {
    const off = sub(cam.origin, cam.target);
    const up = normalize(cam.up);
    const dist = Math.hypot(off[0], off[1], off[2]);
    const upPart = dot(off, up) / dist;
    const flat = sub(off, up.map(function (u) { return u * dot(off, up); }));
    const fwd = normalize(Math.hypot(...flat) > 1e-9 ? flat : cross(up, [1, 0, 0]));
    return { target: cam.target, up: up, fwd: fwd, side: cross(up, fwd), dist: dist,
             pitch: Math.asin(Math.max(-1, Math.min(1, upPart))), yaw: 0, fov: cam.fov,
             axis: cam.fov_axis || "x" };
  }

  function orbitCamera(o, w, h) {
    const cp = Math.cos(o.pitch), sp = Math.sin(o.pitch);
    const cy = Math.cos(o.yaw), sy = Math.sin(o.yaw);
    const dir = [0, 1, 2].map(function (i) {
      return cp * (cy * o.fwd[i] + sy * o.side[i]) + sp * o.up[i];
    });
    const eye = [0, 1, 2].map(function (i) { return o.target[i] + o.dist * dir[i]; });
    const f = cameraFrame(eye, o.target, o.up);
    f.tan = tanHalf(o.fov, o.axis, w, h);
    return f;
  }

  function bindControls(state, canvas, viewer) {
    const byId = function (id) { return document.getElementById(id); };
    const changed = function () { if (api.redraw) api.redraw(); };
    const exp = byId("exposure");
    exp.value = state.exposure.toFixed(1);
    byId("exposure-value").textContent = exp.value;
    exp.addEventListener("input", function () {
      state.exposure = parseFloat(exp.value);
      byId("exposure-value").textContent = exp.value;
      changed();
    });
    byId("parts").addEventListener("change", function (e) {
      state.parts = e.target.value;
      changed();
    });
    byId("background").addEventListener("change", function (e) {
      state.background = e.target.checked;
      changed();
    });
    const sel = byId("env");
    viewer.h.envs.forEach(function (e, i) {
      const opt = document.createElement("option");
      opt.value = String(i);
      opt.textContent = e.name;
      sel.appendChild(opt);
    });
    sel.value = String(state.env);
    sel.addEventListener("change", function () {
      api.setEnv(parseInt(sel.value, 10)).then(changed);
    });
    let drag = null;
    canvas.addEventListener("contextmenu", function (e) { e.preventDefault(); });
    canvas.addEventListener("pointerdown", function (e) {
      drag = { x: e.clientX, y: e.clientY, light: e.shiftKey || e.button === 2 };
      canvas.setPointerCapture(e.pointerId);
    });
    canvas.addEventListener("pointerup", function () { drag = null; });
    canvas.addEventListener("pointermove", function (e) {
      if (!drag) return;
      const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
      drag.x = e.clientX; drag.y = e.clientY;
      if (drag.light) {
        state.light += dx * 0.5;
      } else {
        state.orbit.yaw -= dx * 0.01;
        state.orbit.pitch = Math.max(-1.55, Math.min(1.55, state.orbit.pitch + dy * 0.01));
      }
      changed();
    });
    canvas.addEventListener("wheel", function (e) {
      e.preventDefault();
      const o = state.orbit;
      o.dist = Math.max(1.05 * viewer.radius,
                        Math.min(50 * viewer.radius, o.dist * Math.exp(e.deltaY * 0.001)));
      changed();
    }, { passive: false });
  }

  // an exposure that puts the object's bright pixels near the top of the display range
  function autoExposure(viewer, state) {
    // in the frames' format: the programs made for it serve the first frame too
    const t = viewer.target(64, 64, viewer.gl[FRAME_FORMAT]);
    viewer.draw(t, orbitCamera(state.orbit, 64, 64), rotationY(state.light),
                { diffuse: true, glossy: true, background: false });
    const px = viewer.readLinear(t);
    const lum = [];
    for (let i = 0; i < px.length; i += 4) {
      if (px[i + 3] > 0.5) lum.push(0.2126 * px[i] + 0.7152 * px[i + 1] + 0.0722 * px[i + 2]);
    }
    if (!lum.length) return 0;
    lum.sort(function (a, b) { return a - b; });
    const hi = lum[Math.floor(0.9 * (lum.length - 1))];
    return hi > 0 ? Math.max(-10, Math.min(10, Math.log2(0.8 / hi))) : 0;
  }

  // frames on demand: while the view changes, one sample per pixel (the frames per second
  // shown are of these); once it has been still for IDLE_MS, one frame with the desktop
  // renderer's samples per pixel, then nothing until the next change
  const IDLE_MS = 300;
  // while the view changes, the page draws fewer pixels (down to MOVING_MIN of the canvas's
  // across, a quarter of its pixels at 0.5) to keep MOVING_FPS frames per second; the frame
  // drawn once the view rests has every pixel and the desktop's samples
  const MOVING_FPS = 10, MOVING_MIN = 0.5;

  // the moving frames' scale after a frame that took dt milliseconds: in steps of 1/8 (a few
  // target sizes) between MOVING_MIN and 1
  function adaptScale(scale, dt) {
    const want = 1000 / MOVING_FPS;
    if (dt > 1.15 * want) return Math.max(MOVING_MIN, scale - 0.125);
    if (dt < 0.7 * want) return Math.min(1, scale + 0.125);
    return scale;
  }

  function loop(viewer, state, canvas) {
    const fpsEl = document.getElementById("fps");
    let frames = 0, t0 = performance.now(), pending = false, last = null;
    function draw(offsets, scale) {
      const t = viewer.movingTarget(canvas.width, canvas.height, scale || 1);
      const w = t.w, h = t.h;
      const cam = orbitCamera(state.orbit, w, h);
      viewer.draw(t, cam, rotationY(state.light), {
        diffuse: state.parts !== "glossy", glossy: state.parts !== "diffuse",
        background: state.background, offsets: offsets, moving: !offsets,
      });
      viewer.present(t, state.exposure);
      if (api.timings.shown == null) {
        // a pixel of the canvas read back: the first frame is on it
        const gl = viewer.gl;
        gl.bindFramebuffer(gl.FRAMEBUFFER, null);
        gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, new Uint8Array(4));
        api.timings.shown = performance.now();
      }
    }
    function frame() {
      pending = false;
      const now = performance.now();
      if (now - state.changedAt > IDLE_MS) {
        draw(viewer.h.samples);
        frames = 0;
        return;
      }
      if (frames > 0 && state.moving == null) state.scale = adaptScale(state.scale, now - last);
      last = now;
      draw(null, state.moving == null ? state.scale : state.moving);
      if (frames === 0) t0 = now;
      frames += 1;
      if (frames > 1 && now - t0 >= 500) {
        api.fps = (frames - 1) * 1000 / (now - t0);
        const s = state.moving == null ? state.scale : state.moving;
        fpsEl.textContent = api.fps.toFixed(1) + " fps · " + canvas.width + "×" + canvas.height +
                            (s < 1 ? " (" + Math.round(100 * s) + " % across while moving)" : "");
      }
      request();
    }
    function request() {
      if (!pending) {
        pending = true;
        requestAnimationFrame(frame);
      }
    }
    // something changed: a still page (still=1) draws its full frame at once, else frames
    // follow until the view is still
    api.redraw = function () {
      if (state.still) {
        draw(viewer.h.samples);
        return;
      }
      state.changedAt = performance.now();
      request();
    };
    state.changedAt = performance.now();
    if (state.still) draw(viewer.h.samples);
    else request();
  }

  function sizeCanvas(canvas, options) {
    if (options.size) {
      canvas.width = options.size[0];
      canvas.height = options.size[1];
      canvas.style.width = options.size[0] + "px";
      canvas.style.height = options.size[1] + "px";
    } else {
      canvas.width = Math.max(1, canvas.clientWidth);
      canvas.height = Math.max(1, canvas.clientHeight);
    }
  }

  async function start() {
    // milliseconds since the page's navigation began: the scripts read and parsed (scripts),
    // the model's geometry and small arrays decoded and uploaded (model), the first map's
    // (env), the rest of the model decoded and uploaded while the first draw's programs
    // compile (decoded), the exposure chosen (first_frame) and the first frame on the canvas
    // (shown, set by loop)
    const timings = api.timings = { scripts: performance.now() };
    const options = pageOptions();
    const canvas = document.getElementById("view");
    const gl = canvas.getContext("webgl2", { antialias: false, preserveDrawingBuffer: true });
    if (!gl) {
      showMessage("This browser has no WebGL 2: the viewer needs it (a current Chrome, " +
                  "Firefox, Safari or Edge, with hardware acceleration on).");
      return;
    }
    if (!gl.getExtension("EXT_color_buffer_float")) {
      showMessage("This browser's WebGL 2 lacks EXT_color_buffer_float: the viewer renders " +
                  "linear radiance into float targets and cannot run without it.");
      return;
    }
    if (!store.model || !store.shaders) {
      showMessage("The model's data files (model.js, shaders.js) did not load: open the " +
                  "folder that lobelight export --web wrote, whole.");
      return;
    }
    const envs = store.model.header.envs || [];
    if (envs[options.env]) loadEnv(envs[options.env].file).catch(function () {});  // setEnv says
    let viewer;
    try {
      const first = Object.keys(store.model.arrays).filter(function (k) {
        return !LATER.includes(k);
      });
      viewer = new Viewer(gl, store.model, await decodeAll(store.model, first), store.shaders,
                          options);
      timings.model = performance.now();
    } catch (e) {
      showMessage(e.message);
      return;
    }
    api.viewer = viewer;
    const notes = viewer.h.notes || [];
    if (notes.length) {
      const el = document.getElementById("notes");
      el.textContent = notes.join(" ");
      el.style.display = "block";
    }
    const state = {
      orbit: makeOrbit(viewer.h.camera), light: 0, exposure: 0, parts: "both",
      background: true, env: options.env, still: options.still, moving: options.moving,
      scale: 1,
    };
    api.state = state;
    api.setEnv = async function (i) {
      if (!viewer.envs[i]) {
        for (let k = viewer.envs.length; k <= i; ++k) {
          const [doc, arrays] = await loadEnv(viewer.h.envs[k].file);
          viewer.addEnv(doc, arrays);
        }
      }
      viewer.useEnv(i);
      state.env = i;
    };
    try {
      await api.setEnv(state.env);
      timings.env = performance.now();
      sizeCanvas(canvas, options);
      // the first draw queued, so that its programs compile while the rest of the model
      // decodes (LATER)
      viewer.warmUp(orbitCamera(state.orbit, 8, 8), rotationY(state.light));
      viewer.fill(await decodeAll(store.model, LATER));
      timings.decoded = performance.now();
      state.exposure = autoExposure(viewer, state);
      timings.first_frame = performance.now();
    } catch (e) {
      showMessage(e.message);
      return;
    }
    bindControls(state, canvas, viewer);
    window.addEventListener("resize", function () {
      sizeCanvas(canvas, options);
      if (api.redraw) api.redraw();
    });
    api.status = { ok: true, message: "ready" };
    loop(viewer, state, canvas);
  }

  api.start = function () {
    api.ready = start().catch(function (e) { showMessage(String(e && e.message || e)); });
    return api.ready;
  };

  // Test hook: render a camera {origin, left, up, dir, tan_half} (or {origin, target, up,
  // fov, fov_axis}), a lighting rotation (row-major 3 x 3, or degrees about +y), the parts and
  // the map into an RGBA32F target; returns {width, height, b64}: linear RGBA float32, rows
  // top first, alpha 1 on the object.
  api.renderLinear = async function (req) {
    const v = api.viewer;
    await api.setEnv(req.env || 0);
    const w = req.width, h = req.height;
    let cam;
    if (req.left) {
      cam = { eye: req.origin, left: req.left, up: req.up, dir: req.dir, tan: req.tan_half };
    } else {
      cam = cameraFrame(req.origin, req.target, req.up || [0, 1, 0]);
      cam.tan = tanHalf(req.fov, req.fov_axis || "x", w, h);
    }
    let rot = req.rotation == null ? rotationY(0) : req.rotation;
    if (typeof rot === "number") rot = rotationY(rot);
    const t = v.target(w, h, v.gl.RGBA32F);
    v.draw(t, cam, rot, {
      diffuse: req.diffuse !== false, glossy: req.glossy !== false,
      background: !!req.background, offsets: req.offsets,
    });
    return { width: w, height: h, b64: floatsB64(v.readLinear(t)) };
  };

  // milliseconds per pass of the interactive path's frames (as benchmark's, each pass finished
  // before the next is timed: the sum is above a frame's time), averaged over `frames`
  api.profile = function (frames, still, parts) {
    const v = api.viewer;
    api.benchmark(1, 1, still, parts);
    v.passTimes = {};
    v.markT = performance.now();
    const r = api.benchmark(frames, 0, still, parts);
    const out = {};
    for (const k in v.passTimes) out[k] = v.passTimes[k] / frames;
    v.passTimes = null;
    out.frame = 1000 * r.seconds / frames;
    return out;
  };

  // frames per second of the interactive path (draw and tone-map into the canvas) at the
  // canvas's size, over `frames` frames after `warm` unmeasured ones, each finished
  // (a pixel read back) before the next; `still`: the still frames (the desktop's samples
  // per pixel) instead; `parts`: {diffuse, glossy, background} (default all shown); `scale`:
  // the frames drawn at that fraction of the canvas's pixels across (as while moving)
  api.benchmark = function (frames, warm, still, parts, scale) {
    const shown = Object.assign({ diffuse: true, glossy: true, background: true }, parts || {});
    const v = api.viewer, s = api.state, gl = v.gl;
    const canvas = gl.canvas;
    s.still = true;
    const px = new Uint8Array(4);
    const one = function () {
      const t = v.movingTarget(canvas.width, canvas.height, still ? 1 : scale || 1);
      v.draw(t, orbitCamera(s.orbit, t.w, t.h), rotationY(s.light),
             { diffuse: shown.diffuse, glossy: shown.glossy, background: shown.background,
               offsets: still ? v.h.samples : null, moving: !still });
      v.present(t, s.exposure);
      gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, px);
      s.orbit.yaw += 0.01;
    };
    for (let i = 0; i < (warm == null ? 2 : warm); ++i) one();
    const t0 = performance.now();
    for (let i = 0; i < frames; ++i) one();
    const dt = (performance.now() - t0) / 1000;
    return { frames: frames, seconds: dt, fps: frames / dt, width: canvas.width,
             height: canvas.height };
  };
})();
