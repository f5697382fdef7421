// codec.test.mjs - the viewer's binary decoder (web/codec.js) run in node on messages built
// here byte by byte as docs/protocol.md lays them out, and on broken ones.

import { describe, it } from 'node:test';
import assert from 'node:assert/strict';
import zlib from 'node:zlib';
import { decodeBinary, parseHeader, KIND_TOPOLOGY, KIND_FRAME, KIND_NODES } from '../../web/codec.js';

// one message: 64-byte header + zlib payload; fields may be overridden to break it
function message(kind, payload, f = {}) {
  const z = zlib.deflateSync(payload);
  const h = Buffer.alloc(64);
  h.write(f.magic || 'SQSH', 0, 'latin1');
  h.writeUInt16LE(f.version ?? 1, 4);
  h.writeUInt8(kind, 6);
  h.writeUInt8(f.flags ?? 0, 7);
  h.writeUInt32LE(f.body ?? 0, 8);
  h.writeUInt32LE(f.frame ?? 7, 12);
  h.writeDoubleLE(f.time ?? 0.14, 16);
  h.writeUInt32LE(f.count0, 24);
  h.writeUInt32LE(f.count1 ?? 0, 28);
  (f.offset || [0, 0, 0]).forEach((v, i) => h.writeFloatLE(v, 32 + 4 * i));
  (f.scale || [0, 0, 0]).forEach((v, i) => h.writeFloatLE(v, 44 + 4 * i));
  h.writeUInt32LE(f.rawBytes ?? payload.length, 56);
  h.writeUInt32LE(f.zBytes ?? z.length, 60);
  const whole = Buffer.concat([h, f.truncate ? z.subarray(0, z.length - f.truncate) : z]);
  return whole.buffer.slice(whole.byteOffset, whole.byteOffset + whole.byteLength);
}

function topologyPayload(verts, tris) {
  const b = Buffer.alloc(verts.length * 4 + tris.length * 4);
  verts.forEach((v, i) => b.writeFloatLE(v, 4 * i));
  tris.forEach((t, i) => b.writeUInt32LE(t, verts.length * 4 + 4 * i));
  return b;
}

describe('viewer binary codec', () => {
  const verts = [0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1];
  const tris = [0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3];

  it('decodes a topology message', async () => {
    const m = await decodeBinary(message(KIND_TOPOLOGY, topologyPayload(verts, tris), { count0: 4, count1: 4 }));
    assert.equal(m.header.kind, KIND_TOPOLOGY);
    assert.deepEqual([...m.rest], verts);
    assert.deepEqual([...m.tris], tris);
  });

  it('decodes a frame: quantised displacements, levels and a tool record', async () => {
    const n = 4, q = [[0, 65535, 10, 20], [1, 2, 3, 4], [100, 0, 0, 0]];
    const b = Buffer.alloc(n * 7 + 36);
    q.forEach((axis, a) => axis.forEach((v, i) => b.writeUInt16LE(v, 2 * (a * n + i))));
    [0, 1, 2, 1].forEach((l, i) => b.writeUInt8(l, 6 * n + i));
    const t = 7 * n;
    b.writeUInt32LE(6, t); b.writeUInt8(2, t + 4); b.writeUInt8(1, t + 5);
    [0.5, 0.25, 1.5].forEach((v, i) => b.writeFloatLE(v, t + 8 + 4 * i));
    b.writeFloatLE(0.08, t + 20);
    [1, -2, 3.5].forEach((v, i) => b.writeFloatLE(v, t + 24 + 4 * i));
    const offset = [-0.5, 0, 0.25], scale = [0.001, 0.5, 0.0001];
    const m = await decodeBinary(message(KIND_FRAME, b, { count0: n, count1: 1, offset, scale, flags: 1, frame: 42 }));
    assert.equal(m.header.frame, 42);
    assert.equal(m.reset, true);
    // d = offset + q * scale per axis, in f32 arithmetic of the header's f32 values
    for (let a = 0; a < 3; a++) {
      for (let i = 0; i < n; i++) {
        const want = Math.fround(offset[a]) + q[a][i] * Math.fround(scale[a]);
        assert.ok(Math.abs(m.disp[3 * i + a] - want) < 1e-6, `axis ${a} vertex ${i}: ${m.disp[3 * i + a]} vs ${want}`);
      }
    }
    assert.deepEqual([...m.levels], [0, 1, 2, 1]);
    assert.equal(m.tools.length, 1);
    const tool = m.tools[0];
    assert.equal(tool.id, 6);
    assert.equal(tool.shape, 'grab');
    assert.equal(tool.active, true);
    assert.deepEqual(tool.pos, [0.5, 0.25, 1.5]);
    assert.ok(Math.abs(tool.radius - 0.08) < 1e-7);
    assert.deepEqual(tool.force, [1, -2, 3.5]);
  });

  it('decodes a nodes message', async () => {
    const b = Buffer.alloc(2 * 13);
    [[1, 2, 3, 0], [4, 5, 6, 2]].forEach((r, k) => {
      r.slice(0, 3).forEach((v, i) => b.writeFloatLE(v, 13 * k + 4 * i));
      b.writeUInt8(r[3], 13 * k + 12);
    });
    const m = await decodeBinary(message(KIND_NODES, b, { count0: 2 }));
    assert.deepEqual([...m.pos], [1, 2, 3, 4, 5, 6]);
    assert.deepEqual([...m.levels], [0, 2]);
  });

  it('refuses broken messages with an error that names the problem', async () => {
    const good = topologyPayload(verts, tris);
    const cases = [
      [new ArrayBuffer(10), /shorter than the 64-byte header/],
      [message(KIND_TOPOLOGY, good, { count0: 4, count1: 4, magic: 'XXXX' }), /bad magic/],
      [message(KIND_TOPOLOGY, good, { count0: 4, count1: 4, version: 2 }), /version 2/],
      [message(9, good, { count0: 4, count1: 4 }), /unknown kind 9/],
      [message(KIND_TOPOLOGY, good, { count0: 4, count1: 4, zBytes: 100000 }), /compressed bytes/],
      [message(KIND_TOPOLOGY, good, { count0: 5, count1: 4 }), /counts imply/],
      [message(KIND_TOPOLOGY, good, { count0: 4, count1: 4, rawBytes: 3 }), /header says 3/],
      [message(KIND_TOPOLOGY, topologyPayload(verts, [0, 1, 9, 0, 1, 2, 0, 1, 2, 0, 1, 2]), { count0: 4, count1: 4 }), /uses vertex 9 of 4/],
    ];
    for (const [buf, re] of cases) await assert.rejects(decodeBinary(buf), re);
    // a cut zlib stream fails in the inflater, never yields a short mesh
    await assert.rejects(decodeBinary(message(KIND_TOPOLOGY, good, { count0: 4, count1: 4, truncate: 6 })));
  });

  it('parses the header fields where the protocol puts them', () => {
    const h = parseHeader(message(KIND_FRAME, Buffer.alloc(7), { count0: 1, body: 3, frame: 9, time: 1.25, offset: [1, 2, 3], scale: [0.5, 0.25, 0.125] }));
    assert.equal(h.body, 3);
    assert.equal(h.frame, 9);
    assert.equal(h.time, 1.25);
    assert.deepEqual(h.offset, [1, 2, 3]);
    assert.deepEqual(h.scale, [0.5, 0.25, 0.125]);
  });
});
