// render.test.mjs - the viewer's crease split (web/render.js) in node: box edges get separate
// normals as in squish render (server/render/drawlist.c, 45 degrees), smooth surfaces stay shared.

import { describe, it } from 'node:test';
import assert from 'node:assert/strict';
import { creaseSplit, gather, computeNormals } from '../../web/render.js';

// unit cube, 8 corners, 12 outward triangles
const V = [0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0, 0, 0, 1, 1, 0, 1, 1, 1, 1, 0, 1, 1];
const T = [0, 2, 1, 0, 3, 2, 4, 5, 6, 4, 6, 7, 0, 1, 5, 0, 5, 4, 1, 2, 6, 1, 6, 5, 2, 3, 7, 2, 7, 6, 3, 0, 4, 3, 4, 7];

describe('crease normals', () => {
  it('a cube corner gets one vertex per face, each with its face normal', () => {
    const s = creaseSplit(new Float32Array(V), new Uint32Array(T));
    assert.equal(s.map.length, 24, '8 corners x 3 faces');
    const pos = gather(new Float32Array(V), s.map, 3, new Float32Array(s.map.length * 3));
    const n = new Float32Array(pos.length);
    computeNormals(pos, s.tris, n);
    for (let i = 0; i < s.map.length; i++) {
      const v = [n[3 * i], n[3 * i + 1], n[3 * i + 2]];
      const l = Math.hypot(...v);
      // axis-aligned to 1e-6: exactly one component is +-1 after normalising
      const big = v.map((x) => Math.abs(x / l)).filter((x) => x > 1 - 1e-6).length;
      assert.equal(big, 1, `vertex ${i} normal ${v}`);
    }
    // the split keeps every triangle and its source corners
    for (let c = 0; c < T.length; c++) assert.equal(s.map[s.tris[c]], T[c]);
  });

  it('a finely faceted sphere keeps one vertex per source vertex', () => {
    const pos = [], tris = [], nu = 24, nv = 12;
    for (let j = 0; j <= nv; j++) for (let i = 0; i < nu; i++) {
      const th = (j / nv) * Math.PI, ph = (i / nu) * 2 * Math.PI;
      pos.push(Math.sin(th) * Math.cos(ph), Math.sin(th) * Math.sin(ph), Math.cos(th));
    }
    for (let j = 1; j < nv - 1; j++) for (let i = 0; i < nu; i++) {
      const a = j * nu + i, b = j * nu + ((i + 1) % nu), c = a + nu, d = b + nu;
      tris.push(a, c, b, b, c, d);
    }
    const s = creaseSplit(new Float32Array(pos), new Uint32Array(tris));
    const used = new Set(tris);
    assert.equal(s.map.length, used.size, 'no vertex split');
  });
});
