// camera.js - small column-major 4x4 matrix helpers and an orbit camera (z up).

/** v = a - b */
export function sub(a, b) { return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]; }
/** v = a + b * s */
export function addScaled(a, b, s) { return [a[0] + b[0] * s, a[1] + b[1] * s, a[2] + b[2] * s]; }
/** dot product */
export function dot(a, b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
/** cross product */
export function cross(a, b) {
  return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
}
/** euclidean length */
export function len(a) { return Math.hypot(a[0], a[1], a[2]); }
/** unit vector (zero stays zero) */
export function normalize(a) { const l = len(a) || 1; return [a[0] / l, a[1] / l, a[2] / l]; }

/** c = a * b (column-major 4x4) */
export function mul(a, b) {
  const c = new Float32Array(16);
  for (let i = 0; i < 4; i++) {
    for (let j = 0; j < 4; j++) {
      let s = 0;
      for (let k = 0; k < 4; k++) s += a[k * 4 + i] * b[j * 4 + k];
      c[j * 4 + i] = s;
    }
  }
  return c;
}

/** perspective projection, fovy in radians */
export function perspective(fovy, aspect, near, far) {
  const f = 1 / Math.tan(fovy / 2), m = new Float32Array(16);
  m[0] = f / aspect; m[5] = f; m[10] = (far + near) / (near - far); m[11] = -1;
  m[14] = (2 * far * near) / (near - far);
  return m;
}

/** view matrix looking from eye at target */
export function lookAt(eye, target, up) {
  const z = normalize(sub(eye, target));
  const x = normalize(cross(up, z));
  const y = cross(z, x);
  const m = new Float32Array(16);
  m[0] = x[0]; m[4] = x[1]; m[8] = x[2]; m[12] = -dot(x, eye);
  m[1] = y[0]; m[5] = y[1]; m[9] = y[2]; m[13] = -dot(y, eye);
  m[2] = z[0]; m[6] = z[1]; m[10] = z[2]; m[14] = -dot(z, eye);
  m[15] = 1;
  return m;
}

/** general 4x4 inverse (null if singular) */
export function invert(m) {
  const inv = new Float32Array(16);
  inv[0] = m[5] * m[10] * m[15] - m[5] * m[11] * m[14] - m[9] * m[6] * m[15] + m[9] * m[7] * m[14] + m[13] * m[6] * m[11] - m[13] * m[7] * m[10];
  inv[4] = -m[4] * m[10] * m[15] + m[4] * m[11] * m[14] + m[8] * m[6] * m[15] - m[8] * m[7] * m[14] - m[12] * m[6] * m[11] + m[12] * m[7] * m[10];
  inv[8] = m[4] * m[9] * m[15] - m[4] * m[11] * m[13] - m[8] * m[5] * m[15] + m[8] * m[7] * m[13] + m[12] * m[5] * m[11] - m[12] * m[7] * m[9];
  inv[12] = -m[4] * m[9] * m[14] + m[4] * m[10] * m[13] + m[8] * m[5] * m[14] - m[8] * m[6] * m[13] - m[12] * m[5] * m[10] + m[12] * m[6] * m[9];
  inv[1] = -m[1] * m[10] * m[15] + m[1] * m[11] * m[14] + m[9] * m[2] * m[15] - m[9] * m[3] * m[14] - m[13] * m[2] * m[11] + m[13] * m[3] * m[10];
  inv[5] = m[0] * m[10] * m[15] - m[0] * m[11] * m[14] - m[8] * m[2] * m[15] + m[8] * m[3] * m[14] + m[12] * m[2] * m[11] - m[12] * m[3] * m[10];
  inv[9] = -m[0] * m[9] * m[15] + m[0] * m[11] * m[13] + m[8] * m[1] * m[15] - m[8] * m[3] * m[13] - m[12] * m[1] * m[11] + m[12] * m[3] * m[9];
  inv[13] = m[0] * m[9] * m[14] - m[0] * m[10] * m[13] - m[8] * m[1] * m[14] + m[8] * m[2] * m[13] + m[12] * m[1] * m[10] - m[12] * m[2] * m[9];
  inv[2] = m[1] * m[6] * m[15] - m[1] * m[7] * m[14] - m[5] * m[2] * m[15] + m[5] * m[3] * m[14] + m[13] * m[2] * m[7] - m[13] * m[3] * m[6];
  inv[6] = -m[0] * m[6] * m[15] + m[0] * m[7] * m[14] + m[4] * m[2] * m[15] - m[4] * m[3] * m[14] - m[12] * m[2] * m[7] + m[12] * m[3] * m[6];
  inv[10] = m[0] * m[5] * m[15] - m[0] * m[7] * m[13] - m[4] * m[1] * m[15] + m[4] * m[3] * m[13] + m[12] * m[1] * m[7] - m[12] * m[3] * m[5];
  inv[14] = -m[0] * m[5] * m[14] + m[0] * m[6] * m[13] + m[4] * m[1] * m[14] - m[4] * m[2] * m[13] - m[12] * m[1] * m[6] + m[12] * m[2] * m[5];
  inv[3] = -m[1] * m[6] * m[11] + m[1] * m[7] * m[10] + m[5] * m[2] * m[11] - m[5] * m[3] * m[10] - m[9] * m[2] * m[7] + m[9] * m[3] * m[6];
  inv[7] = m[0] * m[6] * m[11] - m[0] * m[7] * m[10] - m[4] * m[2] * m[11] + m[4] * m[3] * m[10] + m[8] * m[2] * m[7] - m[8] * m[3] * m[6];
  inv[11] = -m[0] * m[5] * m[11] + m[0] * m[7] * m[9] + m[4] * m[1] * m[11] - m[4] * m[3] * m[9] - m[8] * m[1] * m[7] + m[8] * m[3] * m[5];
  inv[15] = m[0] * m[5] * m[10] - m[0] * m[6] * m[9] - m[4] * m[1] * m[10] + m[4] * m[2] * m[9] + m[8] * m[1] * m[6] - m[8] * m[2] * m[5];
  let det = m[0] * inv[0] + m[1] * inv[4] + m[2] * inv[8] + m[3] * inv[12];
  if (det === 0) return null;
  det = 1 / det;
  for (let i = 0; i < 16; i++) inv[i] *= det;
  return inv;
}

/** transform point p by m (with perspective divide); returns [x, y, z, w] */
export function transform(m, p) {
  const x = m[0] * p[0] + m[4] * p[1] + m[8] * p[2] + m[12];
  const y = m[1] * p[0] + m[5] * p[1] + m[9] * p[2] + m[13];
  const z = m[2] * p[0] + m[6] * p[1] + m[10] * p[2] + m[14];
  const w = m[3] * p[0] + m[7] * p[1] + m[11] * p[2] + m[15];
  return [x / w, y / w, z / w, w];
}

/** model matrix: translate to pos, rotate +z onto dir (unit), scale (sx, sy, sz) */
export function alignZ(pos, dir, sx, sy, sz) {
  const z = normalize(dir);
  const ref = Math.abs(z[2]) < 0.9 ? [0, 0, 1] : [1, 0, 0];
  const x = normalize(cross(ref, z));
  const y = cross(z, x);
  return new Float32Array([
    x[0] * sx, x[1] * sx, x[2] * sx, 0,
    y[0] * sy, y[1] * sy, y[2] * sy, 0,
    z[0] * sz, z[1] * sz, z[2] * sz, 0,
    pos[0], pos[1], pos[2], 1,
  ]);
}

/** model matrix: translate and scale per axis */
export function translateScale(pos, sx, sy, sz) {
  return new Float32Array([sx, 0, 0, 0, 0, sy, 0, 0, 0, 0, sz, 0, pos[0], pos[1], pos[2], 1]);
}

/** an orbit camera around a target, z up; angles in radians */
export class OrbitCamera {
  constructor() {
    this.target = [0, 0, 0];
    this.dist = 3;
    this.az = -Math.PI / 3;
    this.el = 0.45;
    this.fovy = (40 * Math.PI) / 180;
    this.aspect = 1;
    this.shiftX = 0; // shift of the picture in NDC units (to clear a side or bottom panel)
    this.shiftY = 0;
  }

  /** eye position in world space */
  eye() {
    const c = Math.cos(this.el);
    return [this.target[0] + this.dist * c * Math.cos(this.az),
      this.target[1] + this.dist * c * Math.sin(this.az),
      this.target[2] + this.dist * Math.sin(this.el)];
  }

  view() { return lookAt(this.eye(), this.target, [0, 0, 1]); }
  proj() {
    const m = perspective(this.fovy, this.aspect, this.dist * 0.01, this.dist * 100);
    m[8] = -this.shiftX;
    m[9] = -this.shiftY;
    return m;
  }
  viewProj() { return mul(this.proj(), this.view()); }

  /** rotate by a drag of (dx, dy) pixels */
  orbit(dx, dy) {
    this.az -= dx * 0.008;
    this.el = Math.max(-1.5, Math.min(1.5, this.el + dy * 0.008));
  }

  /** move the target by a drag of (dx, dy) pixels in a view of height h pixels */
  pan(dx, dy, h) {
    const v = this.view();
    const right = [v[0], v[4], v[8]], up = [v[1], v[5], v[9]];
    const k = (2 * this.dist * Math.tan(this.fovy / 2)) / Math.max(h, 1);
    this.target = addScaled(addScaled(this.target, right, -dx * k), up, dy * k);
  }

  /** multiply the distance by f (f < 1 zooms in) */
  zoom(f) { this.dist = Math.max(1e-3, Math.min(1e4, this.dist * f)); }

  /** frame an axis-aligned box [min, max] */
  fit(min, max) {
    this.target = [(min[0] + max[0]) / 2, (min[1] + max[1]) / 2, (min[2] + max[2]) / 2];
    const r = Math.max(len(sub(max, min)) / 2, 1e-3);
    this.dist = (r / Math.sin(this.fovy / 2)) * 1.15;
  }

  /** world-space ray through pixel (px, py) of a w x h view: {origin, dir} */
  ray(px, py, w, h) {
    const inv = invert(this.viewProj());
    const nx = (2 * px) / w - 1, ny = 1 - (2 * py) / h;
    const a = transform(inv, [nx, ny, -1]), b = transform(inv, [nx, ny, 1]);
    return { origin: [a[0], a[1], a[2]], dir: normalize(sub(b, a)) };
  }

  /** screen pixel of a world point, or null if behind the camera */
  project(p, w, h) {
    const q = transform(this.viewProj(), p);
    if (q[3] <= 0) return null;
    return [((q[0] + 1) / 2) * w, ((1 - q[1]) / 2) * h];
  }
}
