// augsplat's WebGL2 splat viewer (payload layout version 1, see pack.rs). Self-contained: it
// reads the JSON in #augsplat-viewer-data and draws one pane per model on a shared camera.
// Rendering follows the CPU rasteriser (gsplat classic): the same projection, Jacobian clamp,
// 0.3 px² blur, opacity-aware radius, 1/255 cutoff and 0.99 alpha clamp, composited back to
// front (a Gaussian sort per frame) into a half-float target, then over the background.
// URL hash options: camera=<name> (start there), orbit=<dx>,<dy> (then orbit by that drag, in
// pixels), readback (no frusta; each pane's canvas as a PNG data URL in
// <pre id="viewer-readback-K">, the camera as JSON in <pre id="viewer-view">), bench=<frames>
// (frame times in <pre id="viewer-bench">).
(function () {
  "use strict";
  var root = document.getElementById("augsplat-viewer");
  var data = JSON.parse(document.getElementById("augsplat-viewer-data").textContent);
  var NEAR = 0.01, TEXW = 4096, PER_ROW = TEXW / 4;
  var C0 = 0.28209479177387814;
  var hash = {};
  location.hash.replace(/^#/, "").split("&").forEach(function (kv) {
    if (!kv) return;
    var i = kv.indexOf("=");
    hash[decodeURIComponent(i < 0 ? kv : kv.slice(0, i))] = i < 0 ? "" : decodeURIComponent(kv.slice(i + 1));
  });
  var status = root.querySelector(".viewer-status");
  function say(msg) { status.textContent = msg; }

  // ---- decoding --------------------------------------------------------------------------
  var HALF = new Float32Array(65536);
  (function () {
    for (var h = 0; h < 65536; h++) {
      var s = h & 0x8000 ? -1 : 1, e = (h >> 10) & 31, m = h & 1023;
      HALF[h] = e === 0 ? s * m * Math.pow(2, -24)
        : e === 31 ? (m ? NaN : s * Infinity)
        : s * (1 + m / 1024) * Math.pow(2, e - 15);
    }
  })();
  function bytes(b64) {
    var bin = atob(b64), n = bin.length, u = new Uint8Array(n);
    for (var i = 0; i < n; i++) u[i] = bin.charCodeAt(i);
    return u;
  }
  // Returns {count, pos: Float32Array(3n), tex: Float32Array(16n)}: per Gaussian four RGBA
  // texels [x y z opacity] [Σ00 Σ01 Σ02 Σ11] [Σ12 Σ22 r g] [b 0 0 0].
  function decode(model) {
    var u8 = bytes(model.payload), n = model.count;
    var dv = new DataView(u8.buffer);
    var lo = model.bounds.slice(0, 3), hi = model.bounds.slice(3, 6);
    var pos = new Float32Array(3 * n), tex = new Float32Array(16 * Math.max(1, Math.ceil(n / PER_ROW)) * PER_ROW);
    for (var i = 0; i < n; i++) {
      var o = 24 * i, t = 16 * i;
      for (var a = 0; a < 3; a++) {
        var v = lo[a] + dv.getUint16(o + 2 * a, true) / 65535 * (hi[a] - lo[a]);
        pos[3 * i + a] = v; tex[t + a] = v;
      }
      var s0 = Math.exp(HALF[dv.getUint16(o + 6, true)]), s1 = Math.exp(HALF[dv.getUint16(o + 8, true)]),
        s2 = Math.exp(HALF[dv.getUint16(o + 10, true)]);
      var qw = dv.getInt8(o + 20), qx = dv.getInt8(o + 21), qy = dv.getInt8(o + 22), qz = dv.getInt8(o + 23);
      var qn = Math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz) || 1;
      qw /= qn; qx /= qn; qy /= qn; qz /= qn;
      var r00 = 1 - 2 * (qy * qy + qz * qz), r01 = 2 * (qx * qy - qw * qz), r02 = 2 * (qx * qz + qw * qy);
      var r10 = 2 * (qx * qy + qw * qz), r11 = 1 - 2 * (qx * qx + qz * qz), r12 = 2 * (qy * qz - qw * qx);
      var r20 = 2 * (qx * qz - qw * qy), r21 = 2 * (qy * qz + qw * qx), r22 = 1 - 2 * (qx * qx + qy * qy);
      var a0 = s0 * s0, a1 = s1 * s1, a2 = s2 * s2;
      tex[t + 3] = HALF[dv.getUint16(o + 18, true)];
      tex[t + 4] = r00 * r00 * a0 + r01 * r01 * a1 + r02 * r02 * a2;
      tex[t + 5] = r00 * r10 * a0 + r01 * r11 * a1 + r02 * r12 * a2;
      tex[t + 6] = r00 * r20 * a0 + r01 * r21 * a1 + r02 * r22 * a2;
      tex[t + 7] = r10 * r10 * a0 + r11 * r11 * a1 + r12 * r12 * a2;
      tex[t + 8] = r10 * r20 * a0 + r11 * r21 * a1 + r12 * r22 * a2;
      tex[t + 9] = r20 * r20 * a0 + r21 * r21 * a1 + r22 * r22 * a2;
      for (var c = 0; c < 3; c++) {
        tex[t + 10 + c] = Math.max(0.5 + C0 * HALF[dv.getUint16(o + 12 + 2 * c, true)], 0);
      }
    }
    return { count: n, pos: pos, tex: tex };
  }

  // ---- the shared camera -----------------------------------------------------------------
  // R: world-to-camera rotation, row-major; t: translation; OpenCV axes (x right, y down,
  // z forward). `target` is the orbit centre; `at` the camera index the view sits on, if any.
  var cams = data.cameras;
  var sceneCentre = [0, 0, 0], sceneRadius = 1;
  (function () {
    var pts = [];
    cams.forEach(function (c) { pts.push(centreOf(c)); });
    if (!pts.length && data.models.length) {
      var b = data.models[0].bounds;
      pts.push(b.slice(0, 3), b.slice(3, 6));
    }
    if (!pts.length) return;
    for (var a = 0; a < 3; a++) sceneCentre[a] = pts.reduce(function (s, p) { return s + p[a]; }, 0) / pts.length;
    var d = pts.map(function (p) { return Math.hypot(p[0] - sceneCentre[0], p[1] - sceneCentre[1], p[2] - sceneCentre[2]); });
    d.sort(function (x, y) { return x - y; });
    sceneRadius = d[d.length >> 1] || 1;
  })();
  function centreOf(c) { // −Rᵀt
    var R = c.R, t = c.t;
    return [0, 1, 2].map(function (a) { return -(R[a] * t[0] + R[3 + a] * t[1] + R[6 + a] * t[2]); });
  }
  function mulR(R, p) { return [R[0] * p[0] + R[1] * p[1] + R[2] * p[2], R[3] * p[0] + R[4] * p[1] + R[5] * p[2], R[6] * p[0] + R[7] * p[1] + R[8] * p[2]]; }
  function mulRt(R, p) { return [R[0] * p[0] + R[3] * p[1] + R[6] * p[2], R[1] * p[0] + R[4] * p[1] + R[7] * p[2], R[2] * p[0] + R[5] * p[1] + R[8] * p[2]]; }
  function matmul(A, B) {
    var C = new Array(9);
    for (var i = 0; i < 3; i++) for (var j = 0; j < 3; j++) C[3 * i + j] = A[3 * i] * B[j] + A[3 * i + 1] * B[3 + j] + A[3 * i + 2] * B[6 + j];
    return C;
  }
  var view = null;
  function jumpTo(k) {
    var c = cams[k];
    var ahead = mulRt(c.R, [0, 0, 1]), C = centreOf(c);
    // Orbit around the point of the optical axis nearest the scene centre (at least 0.1 r).
    var s = Math.max(0.1 * sceneRadius, (sceneCentre[0] - C[0]) * ahead[0] + (sceneCentre[1] - C[1]) * ahead[1] + (sceneCentre[2] - C[2]) * ahead[2]);
    view = { R: c.R.slice(), t: c.t.slice(), fx: c.fx, fy: c.fy, cx: c.cx, cy: c.cy, width: c.width, height: c.height,
      target: [C[0] + s * ahead[0], C[1] + s * ahead[1], C[2] + s * ahead[2]], at: k };
    select.value = String(k);
    changed();
  }
  function defaultView() {
    var w = 800, h = 600, d = 2.5 * sceneRadius;
    view = { R: [1, 0, 0, 0, 1, 0, 0, 0, 1], t: [-sceneCentre[0], -sceneCentre[1], -sceneCentre[2] + d],
      fx: 0.9 * w, fy: 0.9 * w, cx: w / 2, cy: h / 2, width: w, height: h, target: sceneCentre.slice(), at: null };
  }
  function moved() { view.at = null; select.value = ""; changed(); }
  function targetInCamera() { return mulR(view.R, view.target).map(function (v, a) { return v + view.t[a]; }); }
  function orbit(dx, dy) {
    var Tc = targetInCamera(), a = -dx * 0.005, b = dy * 0.005;
    var Ry = [Math.cos(a), 0, Math.sin(a), 0, 1, 0, -Math.sin(a), 0, Math.cos(a)];
    var Rx = [1, 0, 0, 0, Math.cos(b), -Math.sin(b), 0, Math.sin(b), Math.cos(b)];
    view.R = matmul(matmul(Ry, Rx), view.R);
    var Rt = mulR(view.R, view.target);
    view.t = [Tc[0] - Rt[0], Tc[1] - Rt[1], Tc[2] - Rt[2]];
    moved();
  }
  function translate(d) { // moves the camera by d (camera axes), carrying the target along
    view.t = [view.t[0] - d[0], view.t[1] - d[1], view.t[2] - d[2]];
    var w = mulRt(view.R, d);
    view.target = [view.target[0] + w[0], view.target[1] + w[1], view.target[2] + w[2]];
    moved();
  }
  function zoom(steps) {
    var Tc = targetInCamera(), dist = Math.max(Tc[2], 1e-3 * sceneRadius);
    var step = Math.min(dist * (1 - Math.pow(0.9, steps)), 0.9 * dist);
    view.t = [view.t[0], view.t[1], view.t[2] - step];
    moved();
  }

  // ---- WebGL -----------------------------------------------------------------------------
  var SPLAT_VS = "#version 300 es\nprecision highp float;precision highp int;precision highp sampler2D;\n" +
    "uniform sampler2D u_data;uniform mat3 u_rot;uniform vec3 u_trans;uniform vec4 u_intr;uniform vec4 u_lim;uniform vec2 u_size;\n" +
    "layout(location=0) in vec2 a_corner;layout(location=1) in uint a_index;\n" +
    "flat out vec3 v_color;flat out float v_opacity;flat out vec3 v_conic;flat out vec2 v_center;\n" +
    "void main(){int i=int(a_index);ivec2 b=ivec2((i%" + PER_ROW + ")*4,i/" + PER_ROW + ");\n" +
    "vec4 t0=texelFetch(u_data,b,0),t1=texelFetch(u_data,b+ivec2(1,0),0),t2=texelFetch(u_data,b+ivec2(2,0),0),t3=texelFetch(u_data,b+ivec2(3,0),0);\n" +
    "gl_Position=vec4(0.0,0.0,2.0,1.0);vec3 p=u_rot*t0.xyz+u_trans;if(!(p.z>=" + NEAR.toFixed(3) + "))return;\n" +
    "mat3 S=mat3(t1.x,t1.y,t1.z,t1.y,t1.w,t2.x,t1.z,t2.x,t2.y);mat3 C=u_rot*S*transpose(u_rot);\n" +
    "float rz=1.0/p.z;float tx=clamp(p.x*rz,-u_lim.y,u_lim.x),ty=clamp(p.y*rz,-u_lim.w,u_lim.z);\n" +
    "vec3 j0=vec3(u_intr.x*rz,0.0,-u_intr.x*tx*rz),j1=vec3(0.0,u_intr.y*rz,-u_intr.y*ty*rz);\n" +
    "float a=dot(j0,C*j0)+0.3,bb=dot(j0,C*j1),c=dot(j1,C*j1)+0.3;float det=a*c-bb*bb;if(!(det>0.0))return;\n" +
    "float op=t0.w;if(!(op>=1.0/255.0))return;float ext=min(3.33,sqrt(2.0*log(255.0*op)));\n" +
    "vec2 r=ceil(ext*sqrt(vec2(a,c)));if(!(r.x>0.0&&r.y>0.0))return;\n" +
    "vec2 m=vec2(u_intr.x*p.x*rz+u_intr.z,u_intr.y*p.y*rz+u_intr.w);vec2 q=m+a_corner*r;\n" +
    "gl_Position=vec4(q.x/u_size.x*2.0-1.0,1.0-q.y/u_size.y*2.0,0.0,1.0);\n" +
    "v_conic=vec3(c,-bb,a)/det;v_center=m;v_opacity=op;v_color=vec3(t2.z,t2.w,t3.x);}";
  var SPLAT_FS = "#version 300 es\nprecision highp float;\nuniform vec2 u_size;\n" +
    "flat in vec3 v_color;flat in float v_opacity;flat in vec3 v_conic;flat in vec2 v_center;out vec4 o;\n" +
    "void main(){vec2 d=vec2(gl_FragCoord.x,u_size.y-gl_FragCoord.y)-v_center;\n" +
    "float pw=-0.5*(v_conic.x*d.x*d.x+v_conic.z*d.y*d.y)-v_conic.y*d.x*d.y;if(pw>0.0)discard;\n" +
    "float al=min(0.99,v_opacity*exp(pw));if(al<1.0/255.0)discard;o=vec4(v_color*al,al);}";
  var BLIT_VS = "#version 300 es\nlayout(location=0) in vec2 a_corner;out vec2 v_uv;void main(){v_uv=a_corner*0.5+0.5;gl_Position=vec4(a_corner,0.0,1.0);}";
  var BLIT_FS = "#version 300 es\nprecision highp float;uniform sampler2D u_img;uniform vec3 u_bg;in vec2 v_uv;out vec4 o;\n" +
    "void main(){vec4 c=texture(u_img,v_uv);o=vec4(clamp(c.rgb+(1.0-c.a)*u_bg,0.0,1.0),1.0);}";
  var LINE_VS = "#version 300 es\nuniform mat3 u_rot;uniform vec3 u_trans;uniform mat4 u_proj;layout(location=0) in vec3 a_pos;layout(location=1) in vec3 a_color;out vec3 v_color;\n" +
    "void main(){v_color=a_color;gl_Position=u_proj*vec4(u_rot*a_pos+u_trans,1.0);}";
  var LINE_FS = "#version 300 es\nprecision highp float;in vec3 v_color;out vec4 o;void main(){o=vec4(v_color,1.0);}";

  function program(gl, vs, fs) {
    function shader(type, src) {
      var s = gl.createShader(type);
      gl.shaderSource(s, src);
      gl.compileShader(s);
      if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error("shader: " + gl.getShaderInfoLog(s));
      return s;
    }
    var p = gl.createProgram();
    gl.attachShader(p, shader(gl.VERTEX_SHADER, vs));
    gl.attachShader(p, shader(gl.FRAGMENT_SHADER, fs));
    gl.linkProgram(p);
    if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error("link: " + gl.getProgramInfoLog(p));
    var u = {}, n = gl.getProgramParameter(p, gl.ACTIVE_UNIFORMS);
    for (var i = 0; i < n; i++) { var name = gl.getActiveUniform(p, i).name; u[name] = gl.getUniformLocation(p, name); }
    return { p: p, u: u };
  }

  function Pane(model, container) {
    this.label = model.label;
    var el = document.createElement("div");
    el.className = "viewer-pane";
    var h = document.createElement("div");
    h.className = "viewer-label";
    h.textContent = model.label + (model.count < model.total ? " (" + model.count + " of " + model.total + " Gaussians)" : " (" + model.count + " Gaussians)");
    this.canvas = document.createElement("canvas");
    el.appendChild(h);
    el.appendChild(this.canvas);
    container.appendChild(el);
    var gl = this.canvas.getContext("webgl2", { antialias: false, alpha: false, depth: false, preserveDrawingBuffer: "readback" in hash, premultipliedAlpha: false });
    if (!gl) throw new Error("this browser has no WebGL2");
    this.gl = gl;
    var d = decode(model);
    this.count = d.count;
    this.pos = d.pos;
    var maxTex = gl.getParameter(gl.MAX_TEXTURE_SIZE), rows = Math.max(1, Math.ceil(d.count / PER_ROW));
    if (rows > maxTex) throw new Error(model.label + ": " + d.count + " Gaussians exceed this adapter's texture limit (" + maxTex * PER_ROW + ")");
    this.data = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, this.data);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA32F, TEXW, rows, 0, gl.RGBA, gl.FLOAT, d.tex);
    [gl.TEXTURE_MIN_FILTER, gl.TEXTURE_MAG_FILTER].forEach(function (f) { gl.texParameteri(gl.TEXTURE_2D, f, gl.NEAREST); });
    this.splat = program(gl, SPLAT_VS, SPLAT_FS);
    this.blit = program(gl, BLIT_VS, BLIT_FS);
    this.line = program(gl, LINE_VS, LINE_FS);
    this.halfFloat = !!gl.getExtension("EXT_color_buffer_float");
    this.quad = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, this.quad);
    gl.bufferData(gl.ARRAY_BUFFER, new Float32Array([-1, -1, 1, -1, -1, 1, 1, 1]), gl.STATIC_DRAW);
    this.order = gl.createBuffer();
    this.vao = gl.createVertexArray();
    gl.bindVertexArray(this.vao);
    gl.bindBuffer(gl.ARRAY_BUFFER, this.quad);
    gl.enableVertexAttribArray(0);
    gl.vertexAttribPointer(0, 2, gl.FLOAT, false, 0, 0);
    gl.bindBuffer(gl.ARRAY_BUFFER, this.order);
    gl.bufferData(gl.ARRAY_BUFFER, 4 * Math.max(1, d.count), gl.DYNAMIC_DRAW);
    gl.enableVertexAttribArray(1);
    gl.vertexAttribIPointer(1, 1, gl.UNSIGNED_INT, 0, 0);
    gl.vertexAttribDivisor(1, 1);
    this.blitVao = gl.createVertexArray();
    gl.bindVertexArray(this.blitVao);
    gl.bindBuffer(gl.ARRAY_BUFFER, this.quad);
    gl.enableVertexAttribArray(0);
    gl.vertexAttribPointer(0, 2, gl.FLOAT, false, 0, 0);
    this.lineVao = gl.createVertexArray();
    this.lineBuf = gl.createBuffer();
    gl.bindVertexArray(this.lineVao);
    gl.bindBuffer(gl.ARRAY_BUFFER, this.lineBuf);
    gl.bufferData(gl.ARRAY_BUFFER, frusta, gl.STATIC_DRAW);
    gl.enableVertexAttribArray(0);
    gl.vertexAttribPointer(0, 3, gl.FLOAT, false, 24, 0);
    gl.enableVertexAttribArray(1);
    gl.vertexAttribPointer(1, 3, gl.FLOAT, false, 24, 12);
    gl.bindVertexArray(null);
    this.idx = new Uint32Array(d.count);
    this.keys = new Uint32Array(d.count);
    this.idx2 = new Uint32Array(d.count);
    this.keys2 = new Uint32Array(d.count);
    this.zf = new Float32Array(1);
    this.zu = new Uint32Array(this.zf.buffer);
    this.visible = 0;
    this.target = null;
    this.size = [0, 0];
  }
  // Back-to-front order of the Gaussians in front of the near plane: a stable LSD radix sort
  // on the float bits of the camera depth (descending), ties in descending index order so the
  // lower index lies in front, as in the CPU's front-to-back order.
  Pane.prototype.sort = function () {
    var R = view.R, t = view.t, pos = this.pos, keys = this.keys, idx = this.idx, m = 0;
    for (var i = this.count - 1; i >= 0; i--) {
      var z = R[6] * pos[3 * i] + R[7] * pos[3 * i + 1] + R[8] * pos[3 * i + 2] + t[2];
      if (!(z >= NEAR)) continue;
      this.zf[0] = z;
      keys[m] = ~this.zu[0] >>> 0;
      idx[m] = i;
      m++;
    }
    var k2 = this.keys2, i2 = this.idx2, count = new Uint32Array(256);
    for (var shift = 0; shift < 32; shift += 8) {
      count.fill(0);
      for (var j = 0; j < m; j++) count[(keys[j] >>> shift) & 255]++;
      for (var s = 0, b = 0; b < 256; b++) { var c = count[b]; count[b] = s; s += c; }
      for (j = 0; j < m; j++) { var d = count[(keys[j] >>> shift) & 255]++; k2[d] = keys[j]; i2[d] = idx[j]; }
      var tk = keys; keys = k2; k2 = tk;
      var ti = idx; idx = i2; i2 = ti;
    }
    this.visible = m;
    var gl = this.gl;
    gl.bindBuffer(gl.ARRAY_BUFFER, this.order);
    gl.bufferSubData(gl.ARRAY_BUFFER, 0, idx.subarray(0, m));
  };
  Pane.prototype.ensureTarget = function (w, h) {
    var gl = this.gl;
    if (this.size[0] === w && this.size[1] === h) return;
    this.canvas.width = w;
    this.canvas.height = h;
    if (this.target) { gl.deleteFramebuffer(this.target.fb); gl.deleteTexture(this.target.tex); }
    var tex = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, tex);
    gl.texImage2D(gl.TEXTURE_2D, 0, this.halfFloat ? gl.RGBA16F : gl.RGBA8, w, h, 0, gl.RGBA, this.halfFloat ? gl.HALF_FLOAT : gl.UNSIGNED_BYTE, null);
    [gl.TEXTURE_MIN_FILTER, gl.TEXTURE_MAG_FILTER].forEach(function (f) { gl.texParameteri(gl.TEXTURE_2D, f, gl.NEAREST); });
    var fb = gl.createFramebuffer();
    gl.bindFramebuffer(gl.FRAMEBUFFER, fb);
    gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, tex, 0);
    this.target = { fb: fb, tex: tex };
    this.size = [w, h];
  };
  Pane.prototype.draw = function (showFrusta) {
    var gl = this.gl, v = view, w = v.width, h = v.height;
    this.ensureTarget(w, h);
    var tanx = 0.5 * w / v.fx, tany = 0.5 * h / v.fy;
    gl.bindFramebuffer(gl.FRAMEBUFFER, this.target.fb);
    gl.viewport(0, 0, w, h);
    gl.clearColor(0, 0, 0, 0);
    gl.clear(gl.COLOR_BUFFER_BIT);
    gl.enable(gl.BLEND);
    gl.blendFunc(gl.ONE, gl.ONE_MINUS_SRC_ALPHA);
    var sp = this.splat;
    gl.useProgram(sp.p);
    gl.activeTexture(gl.TEXTURE0);
    gl.bindTexture(gl.TEXTURE_2D, this.data);
    gl.uniform1i(sp.u.u_data, 0);
    gl.uniformMatrix3fv(sp.u.u_rot, true, v.R);
    gl.uniform3fv(sp.u.u_trans, v.t);
    gl.uniform4f(sp.u.u_intr, v.fx, v.fy, v.cx, v.cy);
    gl.uniform4f(sp.u.u_lim, (w - v.cx) / v.fx + 0.3 * tanx, v.cx / v.fx + 0.3 * tanx, (h - v.cy) / v.fy + 0.3 * tany, v.cy / v.fy + 0.3 * tany);
    gl.uniform2f(sp.u.u_size, w, h);
    gl.bindVertexArray(this.vao);
    if (this.visible > 0) gl.drawArraysInstanced(gl.TRIANGLE_STRIP, 0, 4, this.visible);
    gl.disable(gl.BLEND);
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    gl.viewport(0, 0, w, h);
    gl.useProgram(this.blit.p);
    gl.bindTexture(gl.TEXTURE_2D, this.target.tex);
    gl.uniform1i(this.blit.u.u_img, 0);
    gl.uniform3fv(this.blit.u.u_bg, data.background);
    gl.bindVertexArray(this.blitVao);
    gl.drawArrays(gl.TRIANGLE_STRIP, 0, 4);
    if (showFrusta && frustaVertices > 0) {
      var lp = this.line, n = 0.01 * sceneRadius, f = 1000 * sceneRadius;
      gl.useProgram(lp.p);
      gl.uniformMatrix3fv(lp.u.u_rot, true, v.R);
      gl.uniform3fv(lp.u.u_trans, v.t);
      // Column-major: camera coordinates → clip space with the pixel mapping of the splats.
      gl.uniformMatrix4fv(lp.u.u_proj, false, [
        2 * v.fx / w, 0, 0, 0,
        0, -2 * v.fy / h, 0, 0,
        2 * v.cx / w - 1, -(2 * v.cy / h - 1), (f + n) / (f - n), 1,
        0, 0, -2 * f * n / (f - n), 0]);
      gl.bindVertexArray(this.lineVao);
      gl.drawArrays(gl.LINES, 0, frustaVertices);
    }
    gl.bindVertexArray(null);
  };

  // ---- frusta ----------------------------------------------------------------------------
  var TRAIN = [0.3, 0.55, 1.0], HELD = [1.0, 0.55, 0.15];
  var frustaVertices = 0, frusta = new Float32Array(0), frustumPoints = [];
  (function () {
    var s = 0.08 * sceneRadius, out = [];
    cams.forEach(function (c) {
      var C = centreOf(c);
      var corners = [[0, 0], [c.width, 0], [c.width, c.height], [0, c.height]].map(function (px) {
        var x = [(px[0] - c.cx) / c.fx * s, (px[1] - c.cy) / c.fy * s, s];
        var w = mulRt(c.R, [x[0] - 0, x[1] - 0, x[2] - 0]);
        return [w[0] + C[0], w[1] + C[1], w[2] + C[2]];
      });
      frustumPoints.push([C].concat(corners));
      var col = c.held_out ? HELD : TRAIN;
      for (var k = 0; k < 4; k++) {
        out.push.apply(out, C.concat(col, corners[k], col));
        out.push.apply(out, corners[k].concat(col, corners[(k + 1) % 4], col));
      }
    });
    frusta = new Float32Array(out);
    frustaVertices = out.length / 6;
  })();
  // The camera whose frustum passes within 8 CSS pixels of (x, y) on `canvas`, or −1.
  function pick(canvas, x, y) {
    var rect = canvas.getBoundingClientRect(), sx = view.width / rect.width, sy = view.height / rect.height;
    var px = (x - rect.left) * sx, py = (y - rect.top) * sy, best = -1, bestD = 8 * sx;
    function project(p) {
      var q = mulR(view.R, p), z = q[2] + view.t[2];
      if (z < NEAR) return null;
      return [view.fx * (q[0] + view.t[0]) / z + view.cx, view.fy * (q[1] + view.t[1]) / z + view.cy];
    }
    frustumPoints.forEach(function (pts, k) {
      if (k === view.at) return;
      var p = pts.map(project);
      var segs = [[0, 1], [0, 2], [0, 3], [0, 4], [1, 2], [2, 3], [3, 4], [4, 1]];
      segs.forEach(function (sg) {
        var a = p[sg[0]], b = p[sg[1]];
        if (!a || !b) return;
        var dx = b[0] - a[0], dy = b[1] - a[1], l2 = dx * dx + dy * dy;
        var u = l2 > 0 ? Math.max(0, Math.min(1, ((px - a[0]) * dx + (py - a[1]) * dy) / l2)) : 0;
        var d = Math.hypot(a[0] + u * dx - px, a[1] + u * dy - py);
        if (d < bestD) { bestD = d; best = k; }
      });
    });
    return best;
  }

  // ---- page ------------------------------------------------------------------------------
  var select = root.querySelector(".viewer-camera");
  var frustaBox = root.querySelector(".viewer-frusta");
  var panesEl = root.querySelector(".viewer-panes");
  var opt = document.createElement("option");
  opt.value = "";
  opt.textContent = "(free)";
  select.appendChild(opt);
  cams.forEach(function (c, k) {
    var o = document.createElement("option");
    o.value = String(k);
    o.textContent = (c.held_out ? "held-out: " : "training: ") + c.name;
    select.appendChild(o);
  });
  var panes = [], dirty = false;
  try {
    data.models.forEach(function (m) { panes.push(new Pane(m, panesEl)); });
  } catch (e) {
    say("The 3-D viewer cannot start: " + e.message);
    return;
  }
  var gtPane = document.createElement("div");
  gtPane.className = "viewer-pane";
  gtPane.innerHTML = "<div class=\"viewer-label\">ground truth</div>";
  var gtImg = document.createElement("img");
  var gtNote = document.createElement("div");
  gtNote.className = "viewer-gt-note";
  gtNote.textContent = "shown at the held-out cameras";
  gtPane.appendChild(gtImg);
  gtPane.appendChild(gtNote);
  if (cams.some(function (c) { return c.gt; })) panesEl.appendChild(gtPane);

  function render() {
    dirty = false;
    var showFrusta = frustaBox.checked && !("readback" in hash);
    panes.forEach(function (p) { p.sort(); p.draw(showFrusta); });
    var c = view.at === null ? null : cams[view.at];
    if (c && c.gt) { gtImg.src = c.gt; gtImg.style.display = ""; gtNote.style.display = "none"; }
    else { gtImg.style.display = "none"; gtNote.style.display = ""; }
    say(view.at === null ? "free camera" : (cams[view.at].held_out ? "held-out camera " : "training camera ") + cams[view.at].name);
  }
  function changed() {
    if (!dirty) { dirty = true; requestAnimationFrame(render); }
  }
  select.addEventListener("change", function () { if (select.value === "") return; jumpTo(Number(select.value)); });
  frustaBox.addEventListener("change", changed);

  var drag = null;
  panes.forEach(function (p) {
    var cv = p.canvas;
    cv.tabIndex = 0;
    cv.addEventListener("contextmenu", function (e) { e.preventDefault(); });
    cv.addEventListener("pointerdown", function (e) { drag = { x: e.clientX, y: e.clientY, pan: e.button === 2 || e.shiftKey, moved: false, canvas: cv }; cv.setPointerCapture(e.pointerId); });
    cv.addEventListener("pointermove", function (e) {
      if (!drag) return;
      var dx = e.clientX - drag.x, dy = e.clientY - drag.y;
      if (!drag.moved && Math.hypot(dx, dy) < 3) return;
      drag.moved = true; drag.x = e.clientX; drag.y = e.clientY;
      if (drag.pan) {
        var rect = cv.getBoundingClientRect(), Tc = targetInCamera(), k = Math.max(Tc[2], 1e-3) / view.fx * view.width / rect.width;
        translate([-dx * k, -dy * k, 0]);
      } else orbit(dx, dy);
    });
    cv.addEventListener("pointerup", function (e) {
      if (drag && !drag.moved && frustaBox.checked) { var k = pick(cv, e.clientX, e.clientY); if (k >= 0) jumpTo(k); }
      drag = null;
    });
    cv.addEventListener("wheel", function (e) { e.preventDefault(); zoom(e.deltaY < 0 ? 1 : -1); }, { passive: false });
    cv.addEventListener("keydown", function (e) {
      var s = 0.05 * sceneRadius, d = { w: [0, 0, s], s: [0, 0, -s], a: [-s, 0, 0], d: [s, 0, 0], q: [0, s, 0], e: [0, -s, 0] }[e.key.toLowerCase()];
      if (d) { e.preventDefault(); translate(d); }
    });
  });

  // Start: the camera named in the URL, else the first held-out camera, else the first one.
  var start = cams.findIndex(function (c) { return c.name === hash.camera; });
  if (start < 0) start = cams.findIndex(function (c) { return c.held_out; });
  if (start < 0 && cams.length) start = 0;
  if (start >= 0) jumpTo(start); else defaultView();
  if (hash.orbit) {
    var drag0 = hash.orbit.split(",").map(Number);
    if (drag0.length === 2 && drag0.every(isFinite)) orbit(drag0[0], drag0[1]);
  }
  render();
  if ("readback" in hash) {
    panes.forEach(function (p, k) {
      var pre = document.createElement("pre");
      pre.id = "viewer-readback-" + k;
      pre.hidden = true;
      pre.textContent = p.canvas.toDataURL("image/png");
      root.appendChild(pre);
    });
    var cam = document.createElement("pre");
    cam.id = "viewer-view";
    cam.hidden = true;
    cam.textContent = JSON.stringify({ width: view.width, height: view.height, fx: view.fx, fy: view.fy, cx: view.cx, cy: view.cy,
      world_to_camera: [view.R.slice(0, 3).concat([view.t[0]]), view.R.slice(3, 6).concat([view.t[1]]), view.R.slice(6, 9).concat([view.t[2]]), [0, 0, 0, 1]] });
    root.appendChild(cam);
  }
  if ("bench" in hash && panes.length) {
    var frames = Math.max(2, Number(hash.bench) || 20), p0 = panes[0], times = [], sorts = [], px = new Uint8Array(4);
    for (var f = 0; f < frames; f++) {
      orbit(2, 0);
      var t0 = performance.now();
      p0.sort();
      var t1 = performance.now();
      p0.draw(false);
      p0.gl.readPixels(0, 0, 1, 1, p0.gl.RGBA, p0.gl.UNSIGNED_BYTE, px);
      var t2 = performance.now();
      times.push(t2 - t0);
      sorts.push(t1 - t0);
    }
    var med = function (a) { var b = a.slice(1).sort(function (x, y) { return x - y; }); return b[b.length >> 1]; };
    var pre = document.createElement("pre");
    pre.id = "viewer-bench";
    pre.textContent = JSON.stringify({ gaussians: p0.count, width: view.width, height: view.height, frames: frames, median_ms: med(times), median_sort_ms: med(sorts) });
    root.appendChild(pre);
  }
})();
