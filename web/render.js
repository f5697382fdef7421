// render.js - WebGL2 drawing of the bodies, nodes, tools, force arrows, obstacles and floor.
// Building what to draw (the viewer's other modules keep the state: state.js, session.js) is
// kept apart from drawing it (here).

import { alignZ, translateScale, len } from './camera.js';

// both programs share attribute locations, so one vertex array serves both
const A_POS = 0, A_NORMAL = 1, A_LEVEL = 2;

const LIT_VS = `#version 300 es
layout(location = 0) in vec3 aPos;
layout(location = 1) in vec3 aNormal;
layout(location = 2) in float aLevel;
uniform mat4 uVP;
uniform mat4 uModel;
out vec3 vNormal;
flat out int vLevel;
void main() {
  vNormal = mat3(uModel) * aNormal;
  vLevel = int(aLevel + 0.5);
  gl_Position = uVP * uModel * vec4(aPos, 1.0);
}`;

// lighting only scales the base colour (no white highlight), so a lit pixel keeps the hue
// of its level colour: the legend and automated pixel checks can rely on it
const LIT_FS = `#version 300 es
precision highp float;
in vec3 vNormal;
flat in int vLevel;
uniform vec3 uLevelColors[6];
uniform int uUseLevels;
uniform vec4 uColor;
uniform vec3 uKey;
uniform vec3 uFill;
out vec4 outColor;
void main() {
  vec3 n = normalize(vNormal);
  if (!gl_FrontFacing) n = -n;
  float light = 0.32 + 0.55 * max(dot(n, uKey), 0.0) + 0.18 * max(dot(n, uFill), 0.0);
  vec3 base = uUseLevels == 1 ? uLevelColors[clamp(vLevel, 0, 5)] : uColor.rgb;
  outColor = vec4(base * min(light, 1.0), uColor.a);
}`;

const FLAT_VS = `#version 300 es
layout(location = 0) in vec3 aPos;
layout(location = 2) in float aLevel;
uniform mat4 uVP;
uniform mat4 uModel;
uniform float uPointSize;
flat out int vLevel;
void main() {
  vLevel = int(aLevel + 0.5);
  gl_Position = uVP * uModel * vec4(aPos, 1.0);
  gl_PointSize = uPointSize;
}`;

const FLAT_FS = `#version 300 es
precision highp float;
flat in int vLevel;
uniform vec3 uLevelColors[6];
uniform int uUseLevels;
uniform vec4 uColor;
out vec4 outColor;
void main() {
  outColor = uUseLevels == 1 ? vec4(uLevelColors[clamp(vLevel, 0, 5)], uColor.a) : uColor;
}`;

// force arrows: cyan, a hue no level colour has
const ARROW_COLOR = [0.25, 0.82, 0.88, 1];
const IDENTITY = new Float32Array([1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]);

/** '#rrggbb' -> [r, g, b] in 0..1 */
export function hexToRgb(hex) {
  const m = /^#?([0-9a-f]{2})([0-9a-f]{2})([0-9a-f]{2})$/i.exec(String(hex).trim());
  if (!m) return [1, 0, 1];
  return [parseInt(m[1], 16) / 255, parseInt(m[2], 16) / 255, parseInt(m[3], 16) / 255];
}

/** area-weighted vertex normals of a triangle mesh into out (n x 3) */
export function computeNormals(pos, tris, out) {
  out.fill(0);
  for (let t = 0; t < tris.length; t += 3) {
    const a = tris[t] * 3, b = tris[t + 1] * 3, c = tris[t + 2] * 3;
    const ux = pos[b] - pos[a], uy = pos[b + 1] - pos[a + 1], uz = pos[b + 2] - pos[a + 2];
    const vx = pos[c] - pos[a], vy = pos[c + 1] - pos[a + 1], vz = pos[c + 2] - pos[a + 2];
    const nx = uy * vz - uz * vy, ny = uz * vx - ux * vz, nz = ux * vy - uy * vx;
    out[a] += nx; out[a + 1] += ny; out[a + 2] += nz;
    out[b] += nx; out[b + 1] += ny; out[b + 2] += nz;
    out[c] += nx; out[c + 1] += ny; out[c + 2] += nz;
  }
}

/** faces meeting at more than 45 degrees keep separate normals (as squish render does) */
export const CREASE_COS = 0.7071;

/**
 * split a surface's vertices at creases, from the rest shape: the triangles around a vertex
 * are grouped by normal (a face joins the first group whose mean normal is within 45 degrees
 * of its own), and each group gets a vertex of its own. Smooth parts keep one vertex, a box
 * edge gets two, a box corner three, so area-weighted normals of the split mesh are smooth on
 * curved parts and sharp at box edges, as in server/render/drawlist.c.
 * returns {map: Uint32Array (split vertex -> source vertex), tris: Uint32Array (split indices)}
 */
export function creaseSplit(rest, tris) {
  const nv = rest.length / 3, nt = tris.length / 3;
  const fu = new Float64Array(nt * 3);
  for (let t = 0; t < nt; t++) {
    const a = tris[3 * t] * 3, b = tris[3 * t + 1] * 3, c = tris[3 * t + 2] * 3;
    const ux = rest[b] - rest[a], uy = rest[b + 1] - rest[a + 1], uz = rest[b + 2] - rest[a + 2];
    const vx = rest[c] - rest[a], vy = rest[c + 1] - rest[a + 1], vz = rest[c + 2] - rest[a + 2];
    const nx = uy * vz - uz * vy, ny = uz * vx - ux * vz, nz = ux * vy - uy * vx;
    const l = Math.hypot(nx, ny, nz) || 1;
    fu[3 * t] = nx / l; fu[3 * t + 1] = ny / l; fu[3 * t + 2] = nz / l;
  }
  // vertex -> incident corners (CSR)
  const start = new Uint32Array(nv + 1);
  for (let i = 0; i < tris.length; i++) start[tris[i] + 1]++;
  for (let i = 0; i < nv; i++) start[i + 1] += start[i];
  const fill = start.slice(0, nv), inc = new Uint32Array(tris.length);
  for (let i = 0; i < tris.length; i++) inc[fill[tris[i]]++] = i;
  const map = [], out = new Uint32Array(tris.length);
  for (let v = 0; v < nv; v++) {
    const groups = [];   // {sum: [x, y, z], id}
    for (let j = start[v]; j < start[v + 1]; j++) {
      const corner = inc[j], t = (corner / 3) | 0;
      const n = [fu[3 * t], fu[3 * t + 1], fu[3 * t + 2]];
      let g = groups.find((q) => {
        const l = Math.hypot(q.sum[0], q.sum[1], q.sum[2]) || 1;
        return (q.sum[0] * n[0] + q.sum[1] * n[1] + q.sum[2] * n[2]) / l >= CREASE_COS;
      });
      if (!g) { g = { sum: [0, 0, 0], id: map.length }; map.push(v); groups.push(g); }
      g.sum[0] += n[0]; g.sum[1] += n[1]; g.sum[2] += n[2];
      out[corner] = g.id;
    }
  }
  return { map: new Uint32Array(map), tris: out };
}

/** gather per-vertex values (stride k) of the source vertices into the split vertices */
export function gather(src, map, k, out) {
  for (let i = 0; i < map.length; i++) {
    const s = map[i] * k, d = i * k;
    for (let c = 0; c < k; c++) out[d + c] = src[s + c];
  }
  return out;
}

/** unique edges of a triangle list, as a line index list */
export function edgesOf(tris) {
  const seen = new Set(), out = [];
  for (let t = 0; t < tris.length; t += 3) {
    for (let k = 0; k < 3; k++) {
      const a = tris[t + k], b = tris[t + ((k + 1) % 3)];
      const key = a < b ? a * 4294967296 + b : b * 4294967296 + a;
      if (!seen.has(key)) { seen.add(key); out.push(a, b); }
    }
  }
  return new Uint32Array(out);
}

// unit sphere (positions double as normals)
function sphereMesh(nu, nv) {
  const pos = [], idx = [];
  for (let j = 0; j <= nv; j++) {
    const th = (j / nv) * Math.PI;
    for (let i = 0; i <= nu; i++) {
      const ph = (i / nu) * 2 * Math.PI;
      pos.push(Math.sin(th) * Math.cos(ph), Math.sin(th) * Math.sin(ph), Math.cos(th));
    }
  }
  for (let j = 0; j < nv; j++) {
    for (let i = 0; i < nu; i++) {
      const a = j * (nu + 1) + i, b = a + nu + 1;
      idx.push(a, b, a + 1, a + 1, b, b + 1);
    }
  }
  return { pos: new Float32Array(pos), normal: new Float32Array(pos), idx: new Uint32Array(idx) };
}

// unit cube [-1, 1]^3 with face normals
function cubeMesh() {
  const pos = [], nrm = [], idx = [];
  const faces = [[0, 1], [0, -1], [1, 1], [1, -1], [2, 1], [2, -1]];
  for (const [axis, s] of faces) {
    const u = (axis + 1) % 3, v = (axis + 2) % 3, base = pos.length / 3;
    for (const [a, b] of [[-1, -1], [1, -1], [1, 1], [-1, 1]]) {
      const p = [0, 0, 0], n = [0, 0, 0];
      p[axis] = s; p[u] = a * s; p[v] = b; n[axis] = s;
      pos.push(...p); nrm.push(...n);
    }
    idx.push(base, base + 1, base + 2, base, base + 2, base + 3);
  }
  return { pos: new Float32Array(pos), normal: new Float32Array(nrm), idx: new Uint32Array(idx) };
}

// arrow along +z from 0 to 1: shaft radius 1 up to z = 0.75, head radius 2.5
function arrowMesh(n) {
  const pos = [], nrm = [], idx = [];
  const ring = (r, z, nz) => {
    const base = pos.length / 3;
    for (let i = 0; i <= n; i++) {
      const a = (i / n) * 2 * Math.PI, c = Math.cos(a), s = Math.sin(a);
      pos.push(r * c, r * s, z); nrm.push(c, s, nz);
    }
    return base;
  };
  const band = (a, b) => {
    for (let i = 0; i < n; i++) idx.push(a + i, a + i + 1, b + i, b + i, a + i + 1, b + i + 1);
  };
  band(ring(1, 0, 0), ring(1, 0.75, 0));
  band(ring(2.5, 0.75, 0.4), ring(0.001, 1, 0.4));
  return { pos: new Float32Array(pos), normal: new Float32Array(nrm), idx: new Uint32Array(idx) };
}

// flat-shaded triangles (one normal per face) from positions and indices
function flatMesh(pos, tris) {
  const p = new Float32Array(tris.length * 3), n = new Float32Array(tris.length * 3);
  for (let t = 0; t < tris.length; t += 3) {
    const a = tris[t] * 3, b = tris[t + 1] * 3, c = tris[t + 2] * 3;
    const ux = pos[b] - pos[a], uy = pos[b + 1] - pos[a + 1], uz = pos[b + 2] - pos[a + 2];
    const vx = pos[c] - pos[a], vy = pos[c + 1] - pos[a + 1], vz = pos[c + 2] - pos[a + 2];
    let nx = uy * vz - uz * vy, ny = uz * vx - ux * vz, nz = ux * vy - uy * vx;
    const l = Math.hypot(nx, ny, nz) || 1;
    nx /= l; ny /= l; nz /= l;
    for (let k = 0; k < 3; k++) {
      const s = tris[t + k] * 3, d = (t + k) * 3;
      p[d] = pos[s]; p[d + 1] = pos[s + 1]; p[d + 2] = pos[s + 2];
      n[d] = nx; n[d + 1] = ny; n[d + 2] = nz;
    }
  }
  return { pos: p, normal: n, idx: Uint32Array.from({ length: tris.length }, (_, i) => i) };
}

// an orthonormal pair across unit vector n
function basisOf(n) {
  const a = Math.abs(n[0]) > 0.9 ? [0, 1, 0] : [1, 0, 0];
  const d = a[0] * n[0] + a[1] * n[1] + a[2] * n[2];
  const e1 = [a[0] - d * n[0], a[1] - d * n[1], a[2] - d * n[2]];
  const l = Math.hypot(...e1) || 1;
  e1[0] /= l; e1[1] /= l; e1[2] /= l;
  const e2 = [n[1] * e1[2] - n[2] * e1[1], n[2] * e1[0] - n[0] * e1[2], n[0] * e1[1] - n[1] * e1[0]];
  return [e1, e2];
}

// append mesh m moved by (scale, shift) to acc
function appendMesh(acc, m, scale, shift) {
  const base = acc.pos.length / 3;
  for (let i = 0; i < m.pos.length; i += 3) {
    for (let k = 0; k < 3; k++) { acc.pos.push(m.pos[i + k] * scale[k] + shift[k]); acc.normal.push(m.normal[i + k]); }
  }
  for (const i of m.idx) acc.idx.push(base + i);
}

/**
 * the solid of an obstacle of opened/joined (box, sphere, capsule, mesh) at its placement, as
 * {pos, normal, idx}; null for a plane (drawn as a tiled square, see setObstacles) or bad data
 */
export function obstacleMesh(o) {
  const num = (v) => typeof v === 'number' && Number.isFinite(v);
  const vec = (v) => Array.isArray(v) && v.length === 3 && v.every(num);
  const acc = { pos: [], normal: [], idx: [] };
  if (o.type === 'box' && vec(o.center) && vec(o.size)) {
    appendMesh(acc, cubeMesh(), o.size.map((v) => v / 2), o.center);
  } else if (o.type === 'sphere' && vec(o.center) && num(o.radius)) {
    appendMesh(acc, sphereMesh(24, 12), [o.radius, o.radius, o.radius], o.center);
  } else if (o.type === 'capsule' && vec(o.a) && vec(o.b) && num(o.radius)) {
    const r = o.radius, ball = sphereMesh(24, 12);
    appendMesh(acc, ball, [r, r, r], o.a);
    appendMesh(acc, ball, [r, r, r], o.b);
    const ax = [o.b[0] - o.a[0], o.b[1] - o.a[1], o.b[2] - o.a[2]], l = Math.hypot(...ax);
    if (l > 0) {
      const [e1, e2] = basisOf(ax.map((v) => v / l)), n = 24, base = acc.pos.length / 3;
      for (let j = 0; j <= n; j++) {
        const ph = (j / n) * 2 * Math.PI, c = Math.cos(ph), sn = Math.sin(ph);
        const d = [0, 1, 2].map((k) => c * e1[k] + sn * e2[k]);
        for (const end of [o.a, o.b]) {
          acc.pos.push(end[0] + r * d[0], end[1] + r * d[1], end[2] + r * d[2]);
          acc.normal.push(...d);
        }
      }
      for (let j = 0; j < n; j++) { const q = base + 2 * j; acc.idx.push(q, q + 2, q + 3, q, q + 3, q + 1); }
    }
  } else if (o.type === 'mesh' && Array.isArray(o.vertices) && Array.isArray(o.triangles)) {
    const nv = o.vertices.length / 3;
    if (!o.triangles.every((i) => Number.isInteger(i) && i >= 0 && i < nv)) return null;
    return flatMesh(o.vertices, o.triangles);
  } else {
    return null;
  }
  return { pos: new Float32Array(acc.pos), normal: new Float32Array(acc.normal), idx: new Uint32Array(acc.idx) };
}

const SOFTWARE_GL = /SwiftShader|llvmpipe|softpipe|Software|Basic Render/i;

/** true if the context renders on the CPU (no GPU): then the viewer draws less */
export function isSoftwareGl(gl) {
  const ext = gl.getExtension('WEBGL_debug_renderer_info');
  const name = ext ? gl.getParameter(ext.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER);
  return SOFTWARE_GL.test(String(name));
}

/**
 * a WebGL2 context for the canvas: multisampled on a GPU; on a software rasteriser the canvas
 * is replaced by a fresh one without multisampling (4x the fill cost on a CPU).
 * returns {canvas, gl, software}
 */
export function createContext(canvas, preserve = true) {
  const attrs = { antialias: true, preserveDrawingBuffer: preserve };
  let gl = canvas.getContext('webgl2', attrs);
  if (!gl) throw new Error('this browser has no WebGL2: use a current Chrome, Firefox or Safari');
  const software = isSoftwareGl(gl);
  if (software) {
    const fresh = canvas.cloneNode(false);
    canvas.replaceWith(fresh);
    canvas = fresh;
    gl = canvas.getContext('webgl2', { ...attrs, antialias: false });
  }
  return { canvas, gl, software };
}

/** the WebGL2 renderer of one canvas */
export class Renderer {
  constructor(canvasIn, palette, preserve = true) {
    const { canvas, gl, software } = createContext(canvasIn, preserve);
    this.software = software;
    this.gl = gl;
    this.canvas = canvas;
    this.lit = this.program(LIT_VS, LIT_FS);
    this.flat = this.program(FLAT_VS, FLAT_FS);
    this.bodies = new Map();
    this.nodes = null;
    this.setPalette(palette);
    this.sphere = this.staticMesh(sphereMesh(32, 16));
    this.cube = this.staticMesh(cubeMesh());
    this.arrow = this.staticMesh(arrowMesh(16));
    this.floor = null;
    this.obstacles = [];   // {name, plane, vao, count, nlines, bufs}
    this.obstaclesDrawn = 0;
  }

  /**
   * the scene's obstacles (opened/joined "obstacles"): solids in the palette's obstacle colour,
   * a plane as a tiled square of half side `half` around `centre` projected on it (in the floor
   * colours; it replaces the floor grid)
   */
  setObstacles(list, centre, half) {
    const gl = this.gl;
    for (const o of this.obstacles) {
      for (const b of o.bufs) gl.deleteBuffer(b);
      gl.deleteVertexArray(o.vao);
    }
    this.obstacles = [];
    for (const o of list || []) {
      const name = String(o.name || '');
      if (o.type === 'plane') {
        const p = o.point, nn = o.normal, l = Array.isArray(nn) ? Math.hypot(...nn) : 0;
        if (!Array.isArray(p) || !(l > 0)) continue;
        const n = nn.map((v) => v / l), [e1, e2] = basisOf(n);
        const h = (centre[0] - p[0]) * n[0] + (centre[1] - p[1]) * n[1] + (centre[2] - p[2]) * n[2] + half * 0.0015;
        const c = [0, 1, 2].map((k) => centre[k] - h * n[k]);
        const at = (a, b) => [0, 1, 2].map((k) => c[k] + a * e1[k] + b * e2[k]);
        const quad = [at(-half, -half), at(half, -half), at(half, half), at(-half, -half), at(half, half), at(-half, half)].flat();
        const lines = [], m = 10;
        for (let i = -m; i <= m; i++) {
          const t = (i / m) * half;
          lines.push(...at(-half, t), ...at(half, t), ...at(t, -half), ...at(t, half));
        }
        const vao = gl.createVertexArray();
        gl.bindVertexArray(vao);
        const b = this.buffer(gl.ARRAY_BUFFER, new Float32Array([...quad, ...lines]), gl.STATIC_DRAW);
        gl.enableVertexAttribArray(A_POS);
        gl.vertexAttribPointer(A_POS, 3, gl.FLOAT, false, 0, 0);
        gl.bindVertexArray(null);
        this.obstacles.push({ name, plane: true, vao, bufs: [b], nlines: lines.length / 3 });
        continue;
      }
      const mesh = obstacleMesh(o);
      if (!mesh || !mesh.idx.length) continue;
      const vao = gl.createVertexArray();
      gl.bindVertexArray(vao);
      const pb = this.buffer(gl.ARRAY_BUFFER, mesh.pos, gl.STATIC_DRAW);
      gl.enableVertexAttribArray(A_POS);
      gl.vertexAttribPointer(A_POS, 3, gl.FLOAT, false, 0, 0);
      const nb = this.buffer(gl.ARRAY_BUFFER, mesh.normal, gl.STATIC_DRAW);
      gl.enableVertexAttribArray(A_NORMAL);
      gl.vertexAttribPointer(A_NORMAL, 3, gl.FLOAT, false, 0, 0);
      gl.vertexAttrib1f(A_LEVEL, 0);
      const ib = this.buffer(gl.ELEMENT_ARRAY_BUFFER, mesh.idx, gl.STATIC_DRAW);
      gl.bindVertexArray(null);
      this.obstacles.push({ name, plane: false, vao, bufs: [pb, nb, ib], count: mesh.idx.length });
    }
  }

  setPalette(p) {
    this.palette = p;
    this.levelColors = new Float32Array(18);
    for (let i = 0; i < 6; i++) this.levelColors.set(hexToRgb(p.level[i] || p.level[p.level.length - 1]), i * 3);
    this.bg = hexToRgb(p.background);
  }

  program(vs, fs) {
    const gl = this.gl;
    const compile = (type, src) => {
      const s = gl.createShader(type);
      gl.shaderSource(s, src);
      gl.compileShader(s);
      if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(`shader: ${gl.getShaderInfoLog(s)}`);
      return s;
    };
    const p = gl.createProgram();
    gl.attachShader(p, compile(gl.VERTEX_SHADER, vs));
    gl.attachShader(p, compile(gl.FRAGMENT_SHADER, fs));
    gl.linkProgram(p);
    if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error(`program: ${gl.getProgramInfoLog(p)}`);
    const u = {};
    const n = gl.getProgramParameter(p, gl.ACTIVE_UNIFORMS);
    for (let i = 0; i < n; i++) {
      const name = gl.getActiveUniform(p, i).name.replace(/\[0\]$/, '');
      u[name] = gl.getUniformLocation(p, name);
    }
    return { p, u };
  }

  buffer(target, data, usage) {
    const gl = this.gl, b = gl.createBuffer();
    gl.bindBuffer(target, b);
    gl.bufferData(target, data, usage);
    return b;
  }

  staticMesh(m) {
    const gl = this.gl, vao = gl.createVertexArray();
    gl.bindVertexArray(vao);
    this.buffer(gl.ARRAY_BUFFER, m.pos, gl.STATIC_DRAW);
    gl.enableVertexAttribArray(A_POS);
    gl.vertexAttribPointer(A_POS, 3, gl.FLOAT, false, 0, 0);
    this.buffer(gl.ARRAY_BUFFER, m.normal, gl.STATIC_DRAW);
    gl.enableVertexAttribArray(A_NORMAL);
    gl.vertexAttribPointer(A_NORMAL, 3, gl.FLOAT, false, 0, 0);
    gl.vertexAttrib1f(A_LEVEL, 0);
    this.buffer(gl.ELEMENT_ARRAY_BUFFER, m.idx, gl.STATIC_DRAW);
    gl.bindVertexArray(null);
    return { vao, count: m.idx.length };
  }

  /** (re)create the buffers of a body from its topology (split at creases, see creaseSplit) */
  setBody(id, restIn, trisIn) {
    this.removeBody(id);
    const gl = this.gl, vao = gl.createVertexArray();
    const split = creaseSplit(restIn, trisIn);
    const n = split.map.length, tris = split.tris;
    const rest = gather(restIn, split.map, 3, new Float32Array(n * 3));
    gl.bindVertexArray(vao);
    const pos = this.buffer(gl.ARRAY_BUFFER, rest, gl.DYNAMIC_DRAW);
    gl.enableVertexAttribArray(A_POS);
    gl.vertexAttribPointer(A_POS, 3, gl.FLOAT, false, 0, 0);
    const normals = new Float32Array(n * 3);
    computeNormals(rest, tris, normals);
    const nrm = this.buffer(gl.ARRAY_BUFFER, normals, gl.DYNAMIC_DRAW);
    gl.enableVertexAttribArray(A_NORMAL);
    gl.vertexAttribPointer(A_NORMAL, 3, gl.FLOAT, false, 0, 0);
    const lvl = this.buffer(gl.ARRAY_BUFFER, new Uint8Array(n), gl.DYNAMIC_DRAW);
    gl.enableVertexAttribArray(A_LEVEL);
    gl.vertexAttribPointer(A_LEVEL, 1, gl.UNSIGNED_BYTE, false, 0, 0);
    const tri = this.buffer(gl.ELEMENT_ARRAY_BUFFER, tris, gl.STATIC_DRAW);
    gl.bindVertexArray(null);
    // wireframe: the same vertex buffers with an edge index list
    const wvao = gl.createVertexArray();
    gl.bindVertexArray(wvao);
    gl.bindBuffer(gl.ARRAY_BUFFER, pos);
    gl.enableVertexAttribArray(A_POS);
    gl.vertexAttribPointer(A_POS, 3, gl.FLOAT, false, 0, 0);
    const edges = edgesOf(tris);
    const edge = this.buffer(gl.ELEMENT_ARRAY_BUFFER, edges, gl.STATIC_DRAW);
    gl.bindVertexArray(null);
    this.bodies.set(id, { vao, wvao, pos, nrm, lvl, tri, edge, normals, tris, ntri: tris.length,
      nedge: edges.length, map: split.map, spos: rest, slev: new Uint8Array(n) });
  }

  removeBody(id) {
    const b = this.bodies.get(id);
    if (!b) return;
    const gl = this.gl;
    for (const k of ['pos', 'nrm', 'lvl', 'tri', 'edge']) gl.deleteBuffer(b[k]);
    gl.deleteVertexArray(b.vao);
    gl.deleteVertexArray(b.wvao);
    this.bodies.delete(id);
  }

  clearBodies() { for (const id of [...this.bodies.keys()]) this.removeBody(id); this.setNodes(null); }

  /** upload current positions (n x 3) and levels (n) of a body */
  updateBody(id, pos, levels) {
    const b = this.bodies.get(id);
    if (!b) return;
    const gl = this.gl;
    gather(pos, b.map, 3, b.spos);
    computeNormals(b.spos, b.tris, b.normals);
    gl.bindBuffer(gl.ARRAY_BUFFER, b.pos);
    gl.bufferSubData(gl.ARRAY_BUFFER, 0, b.spos);
    gl.bindBuffer(gl.ARRAY_BUFFER, b.nrm);
    gl.bufferSubData(gl.ARRAY_BUFFER, 0, b.normals);
    if (levels) {
      gather(levels, b.map, 1, b.slev);
      gl.bindBuffer(gl.ARRAY_BUFFER, b.lvl);
      gl.bufferSubData(gl.ARRAY_BUFFER, 0, b.slev);
    }
  }

  /** active-node points (positions n x 3, levels n), or null to drop them */
  setNodes(pos, levels) {
    const gl = this.gl;
    if (this.nodes) {
      gl.deleteBuffer(this.nodes.pb);
      gl.deleteBuffer(this.nodes.lb);
      gl.deleteVertexArray(this.nodes.vao);
      this.nodes = null;
    }
    if (!pos) return;
    const vao = gl.createVertexArray();
    gl.bindVertexArray(vao);
    const pb = this.buffer(gl.ARRAY_BUFFER, pos, gl.STATIC_DRAW);
    gl.enableVertexAttribArray(A_POS);
    gl.vertexAttribPointer(A_POS, 3, gl.FLOAT, false, 0, 0);
    const lb = this.buffer(gl.ARRAY_BUFFER, levels, gl.STATIC_DRAW);
    gl.enableVertexAttribArray(A_LEVEL);
    gl.vertexAttribPointer(A_LEVEL, 1, gl.UNSIGNED_BYTE, false, 0, 0);
    gl.bindVertexArray(null);
    this.nodes = { vao, pb, lb, count: levels.length };
  }

  /** a floor grid under the bodies: z height, centre, half size */
  setFloor(z, cx, cy, half) {
    const gl = this.gl;
    if (this.floor) { gl.deleteBuffer(this.floor.b); gl.deleteVertexArray(this.floor.vao); }
    const lines = [], n = 10;
    for (let i = -n; i <= n; i++) {
      const t = (i / n) * half;
      lines.push(cx - half, cy + t, z, cx + half, cy + t, z, cx + t, cy - half, z, cx + t, cy + half, z);
    }
    const quad = [cx - half, cy - half, z, cx + half, cy - half, z, cx + half, cy + half, z,
      cx - half, cy - half, z, cx + half, cy + half, z, cx - half, cy + half, z];
    const data = new Float32Array([...quad, ...lines]);
    const vao = gl.createVertexArray();
    gl.bindVertexArray(vao);
    const b = this.buffer(gl.ARRAY_BUFFER, data, gl.STATIC_DRAW);
    gl.enableVertexAttribArray(A_POS);
    gl.vertexAttribPointer(A_POS, 3, gl.FLOAT, false, 0, 0);
    gl.bindVertexArray(null);
    this.floor = { vao, b, nlines: lines.length / 3 };
  }

  /** resize the drawing buffer to the canvas' CSS size; returns [w, h] in CSS pixels */
  resize() {
    const c = this.canvas, dpr = this.pixelScale || (this.software ? 1 : Math.min(window.devicePixelRatio || 1, 2));
    const w = c.clientWidth, h = c.clientHeight;
    const bw = Math.max(1, Math.round(w * dpr)), bh = Math.max(1, Math.round(h * dpr));
    if (c.width !== bw || c.height !== bh) { c.width = bw; c.height = bh; }
    return [w, h];
  }

  /**
   * draw one picture. opts: {vp, eye, useLevels, wire, nodes, floor, tools: [{shape, pos,
   * radius, half, active, force, own}], arrowScale(f) -> length, offsets: Map(obstacle name ->
   * [x, y, z] translation from its placement)}
   */
  draw(opts) {
    const gl = this.gl;
    gl.viewport(0, 0, this.canvas.width, this.canvas.height);
    gl.clearColor(this.bg[0], this.bg[1], this.bg[2], 1);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    gl.enable(gl.DEPTH_TEST);
    gl.disable(gl.CULL_FACE);
    gl.disable(gl.BLEND);

    // key light from over the viewer's shoulder, fill from the other side
    const e = opts.eye, t = opts.target;
    const dx = e[0] - t[0], dy = e[1] - t[1], dz = e[2] - t[2], l = Math.hypot(dx, dy, dz) || 1;
    const key = [dx / l - dy / l * 0.5, dy / l + dx / l * 0.5, dz / l + 0.6];
    const kl = len(key) || 1;

    const lit = this.lit;
    gl.useProgram(lit.p);
    gl.uniformMatrix4fv(lit.u.uVP, false, opts.vp);
    gl.uniformMatrix4fv(lit.u.uModel, false, IDENTITY);
    gl.uniform3fv(lit.u.uLevelColors, this.levelColors);
    gl.uniform3f(lit.u.uKey, key[0] / kl, key[1] / kl, key[2] / kl);
    gl.uniform3f(lit.u.uFill, -dx / l, -dy / l, 0.3);

    // bodies
    gl.uniform1i(lit.u.uUseLevels, opts.useLevels ? 1 : 0);
    gl.uniform4fv(lit.u.uColor, [...hexToRgb(this.palette.plain), 1]);
    if (opts.wire) { gl.enable(gl.POLYGON_OFFSET_FILL); gl.polygonOffset(1, 1); }
    for (const b of this.bodies.values()) {
      gl.bindVertexArray(b.vao);
      gl.drawElements(gl.TRIANGLES, b.ntri, gl.UNSIGNED_INT, 0);
    }
    gl.disable(gl.POLYGON_OFFSET_FILL);

    // grab markers
    gl.uniform1i(lit.u.uUseLevels, 0);
    const toolRgb = hexToRgb(this.palette.tool);
    for (const tool of opts.tools) {
      if (!tool.active && !tool.own) continue;
      if (tool.shape === 'grab') {
        const r = opts.grabMarker;
        gl.uniformMatrix4fv(lit.u.uModel, false, translateScale(tool.pos, r, r, r));
        gl.uniform4fv(lit.u.uColor, [...toolRgb, 1]);
        gl.bindVertexArray(this.sphere.vao);
        gl.drawElements(gl.TRIANGLES, this.sphere.count, gl.UNSIGNED_INT, 0);
      }
    }

    // obstacles: solids lit in the obstacle colour, moved by their offsets
    const offsetOf = (o) => (opts.offsets && opts.offsets.get(o.name)) || null;
    const model = (o) => { const d = offsetOf(o); return d ? translateScale(d, 1, 1, 1) : IDENTITY; };
    let drawn = 0;
    gl.uniform4fv(lit.u.uColor, [...hexToRgb(this.palette.obstacle || '#9a948a'), 1]);
    for (const o of this.obstacles) {
      if (o.plane) continue;
      gl.uniformMatrix4fv(lit.u.uModel, false, model(o));
      gl.bindVertexArray(o.vao);
      gl.drawElements(gl.TRIANGLES, o.count, gl.UNSIGNED_INT, 0);
      drawn++;
    }
    gl.uniformMatrix4fv(lit.u.uModel, false, IDENTITY);

    // floor and grid: a plane obstacle stands for the floor
    const flat = this.flat;
    const planes = this.obstacles.filter((o) => o.plane);
    if (opts.floor && planes.length) {
      gl.useProgram(flat.p);
      gl.uniformMatrix4fv(flat.u.uVP, false, opts.vp);
      gl.uniform1i(flat.u.uUseLevels, 0);
      gl.uniform1f(flat.u.uPointSize, 1);
      for (const o of planes) {
        gl.uniformMatrix4fv(flat.u.uModel, false, model(o));
        gl.bindVertexArray(o.vao);
        gl.enable(gl.POLYGON_OFFSET_FILL);
        gl.polygonOffset(2, 2);
        gl.uniform4fv(flat.u.uColor, [...hexToRgb(this.palette.floor), 1]);
        gl.drawArrays(gl.TRIANGLES, 0, 6);
        gl.disable(gl.POLYGON_OFFSET_FILL);
        gl.uniform4fv(flat.u.uColor, [...hexToRgb(this.palette.floor_line), 1]);
        gl.drawArrays(gl.LINES, 6, o.nlines);
        drawn++;
      }
    } else if (opts.floor && this.floor) {
      gl.useProgram(flat.p);
      gl.uniformMatrix4fv(flat.u.uVP, false, opts.vp);
      gl.uniformMatrix4fv(flat.u.uModel, false, IDENTITY);
      gl.uniform1i(flat.u.uUseLevels, 0);
      gl.uniform1f(flat.u.uPointSize, 1);
      gl.bindVertexArray(this.floor.vao);
      gl.enable(gl.POLYGON_OFFSET_FILL);
      gl.polygonOffset(2, 2);
      gl.uniform4fv(flat.u.uColor, [...hexToRgb(this.palette.floor), 1]);
      gl.drawArrays(gl.TRIANGLES, 0, 6);
      gl.disable(gl.POLYGON_OFFSET_FILL);
      gl.uniform4fv(flat.u.uColor, [...hexToRgb(this.palette.floor_line), 1]);
      gl.drawArrays(gl.LINES, 6, this.floor.nlines);
    }

    // wireframe and node points
    gl.useProgram(flat.p);
    gl.uniformMatrix4fv(flat.u.uVP, false, opts.vp);
    gl.uniformMatrix4fv(flat.u.uModel, false, IDENTITY);
    gl.uniform3fv(flat.u.uLevelColors, this.levelColors);
    if (opts.wire) {
      gl.uniform1i(flat.u.uUseLevels, 0);
      gl.uniform4fv(flat.u.uColor, [0.08, 0.09, 0.11, 1]);
      for (const b of this.bodies.values()) {
        gl.bindVertexArray(b.wvao);
        gl.drawElements(gl.LINES, b.nedge, gl.UNSIGNED_INT, 0);
      }
    }
    if (opts.nodes && this.nodes) {
      gl.disable(gl.DEPTH_TEST);
      gl.uniform1i(flat.u.uUseLevels, 1);
      gl.uniform4fv(flat.u.uColor, [1, 1, 1, 1]);
      gl.uniform1f(flat.u.uPointSize, opts.pointSize || 5);
      gl.bindVertexArray(this.nodes.vao);
      gl.drawArrays(gl.POINTS, 0, this.nodes.count);
      gl.enable(gl.DEPTH_TEST);
    }

    // translucent push tools last
    gl.useProgram(lit.p);
    gl.enable(gl.BLEND);
    gl.blendFunc(gl.SRC_ALPHA, gl.ONE_MINUS_SRC_ALPHA);
    gl.depthMask(false);
    gl.uniform1i(lit.u.uUseLevels, 0);
    gl.uniform4fv(lit.u.uColor, [...toolRgb, 0.35]);
    for (const tool of opts.tools) {
      if (tool.shape === 'grab' || (!tool.active && !tool.own)) continue;
      let m, mesh;
      if (tool.shape === 'box') {
        const h = tool.half || [tool.radius, tool.radius, tool.radius];
        m = translateScale(tool.pos, h[0], h[1], h[2]); mesh = this.cube;
      } else {
        m = translateScale(tool.pos, tool.radius, tool.radius, tool.radius); mesh = this.sphere;
      }
      gl.uniformMatrix4fv(lit.u.uModel, false, m);
      gl.bindVertexArray(mesh.vao);
      gl.drawElements(gl.TRIANGLES, mesh.count, gl.UNSIGNED_INT, 0);
    }
    gl.depthMask(true);
    gl.disable(gl.BLEND);
    this.obstaclesDrawn = drawn;

    // force arrows on top of everything: the reaction often points into the body
    gl.clear(gl.DEPTH_BUFFER_BIT);
    gl.uniform4fv(lit.u.uColor, ARROW_COLOR);
    for (const tool of opts.tools) {
      if (!tool.active || !tool.force || !opts.arrowScale) continue;
      const L = opts.arrowScale(len(tool.force));
      if (!(L > 0)) continue;
      const w = opts.arrowWidth;
      gl.uniformMatrix4fv(lit.u.uModel, false, alignZ(tool.pos, tool.force, w, w, L));
      gl.bindVertexArray(this.arrow.vao);
      gl.drawElements(gl.TRIANGLES, this.arrow.count, gl.UNSIGNED_INT, 0);
    }
    gl.bindVertexArray(null);
  }
}
