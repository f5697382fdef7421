// pick.js - CPU ray casting against the current surface triangles.

/**
 * nearest intersection of a ray with a triangle mesh (both faces count).
 * pos: n x 3 positions, tris: triangle index list, origin/dir: the ray (dir unit).
 * returns {t, tri, point, normal} or null; the normal faces the ray's origin.
 */
export function raycast(pos, tris, origin, dir) {
  const [ox, oy, oz] = origin, [dx, dy, dz] = dir;
  let best = Infinity, bestTri = -1, bn = null;
  for (let t = 0; t < tris.length; t += 3) {
    const a = tris[t] * 3, b = tris[t + 1] * 3, c = tris[t + 2] * 3;
    const e1x = pos[b] - pos[a], e1y = pos[b + 1] - pos[a + 1], e1z = pos[b + 2] - pos[a + 2];
    const e2x = pos[c] - pos[a], e2y = pos[c + 1] - pos[a + 1], e2z = pos[c + 2] - pos[a + 2];
    // Moller-Trumbore
    const px = dy * e2z - dz * e2y, py = dz * e2x - dx * e2z, pz = dx * e2y - dy * e2x;
    const det = e1x * px + e1y * py + e1z * pz;
    if (Math.abs(det) < 1e-20) continue;
    const inv = 1 / det;
    const sx = ox - pos[a], sy = oy - pos[a + 1], sz = oz - pos[a + 2];
    const u = (sx * px + sy * py + sz * pz) * inv;
    if (u < 0 || u > 1) continue;
    const qx = sy * e1z - sz * e1y, qy = sz * e1x - sx * e1z, qz = sx * e1y - sy * e1x;
    const v = (dx * qx + dy * qy + dz * qz) * inv;
    if (v < 0 || u + v > 1) continue;
    const d = (e2x * qx + e2y * qy + e2z * qz) * inv;
    if (d > 0 && d < best) {
      best = d;
      bestTri = t / 3;
      bn = [e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x];
    }
  }
  if (bestTri < 0) return null;
  const l = Math.hypot(bn[0], bn[1], bn[2]) || 1;
  let n = [bn[0] / l, bn[1] / l, bn[2] / l];
  if (n[0] * dx + n[1] * dy + n[2] * dz > 0) n = [-n[0], -n[1], -n[2]];
  return { t: best, tri: bestTri, point: [ox + dx * best, oy + dy * best, oz + dz * best], normal: n };
}

/** intersection of a ray with the plane through p with normal n, or null if parallel */
export function rayPlane(origin, dir, p, n) {
  const den = dir[0] * n[0] + dir[1] * n[1] + dir[2] * n[2];
  if (Math.abs(den) < 1e-9) return null;
  const t = ((p[0] - origin[0]) * n[0] + (p[1] - origin[1]) * n[1] + (p[2] - origin[2]) * n[2]) / den;
  return [origin[0] + dir[0] * t, origin[1] + dir[1] * t, origin[2] + dir[2] * t];
}
