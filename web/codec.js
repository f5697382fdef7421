// codec.js - decode squish protocol v1 binary messages (docs/protocol.md, "Binary messages").
// Every message: a 64-byte little-endian header, then a zlib stream (RFC 1950) that the
// browser inflates with DecompressionStream('deflate'); Node may pass its zlib's inflateSync.
// The one decoder of the project: the viewer's worker and the client library
// (squish-client.js, for browsers and Node scripts) both call it, so they cannot disagree.

/** message kinds (header byte 6) */
export const KIND_TOPOLOGY = 1;
export const KIND_FRAME = 2;
export const KIND_NODES = 3;
/** header size in bytes */
export const HEADER_BYTES = 64;
/** bytes per tool record in a frame payload */
export const TOOL_BYTES = 36;
/** bytes per node record in a nodes payload */
export const NODE_BYTES = 13;
/** tool shapes by code */
export const TOOL_SHAPES = ['sphere', 'box', 'grab'];

/** parse the fixed header; throws an Error naming the problem */
export function parseHeader(buf) {
  buf = toArrayBuffer(buf);
  if (!(buf instanceof ArrayBuffer) || buf.byteLength < HEADER_BYTES) {
    throw new Error(`binary message of ${buf.byteLength} bytes is shorter than the ${HEADER_BYTES}-byte header`);
  }
  const v = new DataView(buf);
  const magic = String.fromCharCode(v.getUint8(0), v.getUint8(1), v.getUint8(2), v.getUint8(3));
  if (magic !== 'SQSH') throw new Error(`binary message: bad magic "${magic}" (expected "SQSH")`);
  const h = {
    version: v.getUint16(4, true),
    kind: v.getUint8(6),
    flags: v.getUint8(7),
    body: v.getUint32(8, true),
    frame: v.getUint32(12, true),
    time: v.getFloat64(16, true),
    count0: v.getUint32(24, true),
    count1: v.getUint32(28, true),
    offset: [v.getFloat32(32, true), v.getFloat32(36, true), v.getFloat32(40, true)],
    scale: [v.getFloat32(44, true), v.getFloat32(48, true), v.getFloat32(52, true)],
    rawBytes: v.getUint32(56, true),
    zBytes: v.getUint32(60, true),
  };
  if (h.version !== 1) throw new Error(`binary message: protocol version ${h.version}, this viewer reads version 1 (reload the page)`);
  if (h.kind < 1 || h.kind > 3) throw new Error(`binary message: unknown kind ${h.kind}`);
  if (HEADER_BYTES + h.zBytes > buf.byteLength) {
    throw new Error(`binary message: header says ${h.zBytes} compressed bytes, only ${buf.byteLength - HEADER_BYTES} follow`);
  }
  return h;
}

/** an ArrayBuffer holding exactly the bytes of buf (an ArrayBuffer, a typed array or a Node Buffer) */
export function toArrayBuffer(buf) {
  if (buf instanceof ArrayBuffer) return buf;
  if (ArrayBuffer.isView(buf)) {
    if (buf.byteOffset === 0 && buf.byteLength === buf.buffer.byteLength && buf.buffer instanceof ArrayBuffer) return buf.buffer;
    return buf.buffer.slice(buf.byteOffset, buf.byteOffset + buf.byteLength);
  }
  return buf;
}

/** inflate a zlib stream to an ArrayBuffer */
export async function inflate(bytes) {
  const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream('deflate'));
  return new Response(stream).arrayBuffer();
}

/** the payload size a header's counts imply */
export function expectedRawBytes(h) {
  switch (h.kind) {
    case KIND_TOPOLOGY: return h.count0 * 12 + h.count1 * 12;
    case KIND_FRAME: return h.count0 * 7 + h.count1 * TOOL_BYTES;
    default: return h.count0 * NODE_BYTES;
  }
}

/**
 * decode a whole binary message: {header, ...kind-specific fields}; rejects on bad input.
 * inflater(Uint8Array) -> ArrayBuffer | typed array | Promise of one (default: DecompressionStream)
 */
export async function decodeBinary(buf, inflater = inflate) {
  buf = toArrayBuffer(buf);
  const h = parseHeader(buf);
  return decodePayload(h, await inflater(new Uint8Array(buf, HEADER_BYTES, h.zBytes)));
}

/** the same with a synchronous inflater (e.g. Node's zlib.inflateSync); throws on bad input */
export function decodeBinarySync(buf, inflateSync) {
  buf = toArrayBuffer(buf);
  const h = parseHeader(buf);
  return decodePayload(h, inflateSync(new Uint8Array(buf, HEADER_BYTES, h.zBytes)));
}

/** check an inflated payload against its header and decode it by kind */
export function decodePayload(h, raw) {
  raw = toArrayBuffer(raw);
  const want = expectedRawBytes(h);
  if (raw.byteLength !== h.rawBytes || raw.byteLength !== want) {
    throw new Error(`binary message kind ${h.kind}: payload is ${raw.byteLength} bytes, header says ${h.rawBytes}, counts imply ${want}`);
  }
  if (h.kind === KIND_TOPOLOGY) return decodeTopology(h, raw);
  if (h.kind === KIND_FRAME) return decodeFrame(h, raw);
  return decodeNodes(h, raw);
}

/** topology: rest positions (f32 x3) then triangles (u32 x3) */
export function decodeTopology(h, raw) {
  const rest = new Float32Array(raw, 0, h.count0 * 3);
  const tris = new Uint32Array(raw, h.count0 * 12, h.count1 * 3);
  for (let i = 0; i < tris.length; i++) {
    if (tris[i] >= h.count0) throw new Error(`topology of body ${h.body}: triangle ${(i / 3) | 0} uses vertex ${tris[i]} of ${h.count0}`);
  }
  return { header: h, rest, tris };
}

/** frame: planar u16 quantised displacements, u8 levels, tool records; displacement only */
export function decodeFrame(h, raw) {
  const n = h.count0;
  const q = new Uint16Array(raw, 0, n * 3);
  const disp = new Float32Array(n * 3);
  for (let a = 0; a < 3; a++) {
    const o = h.offset[a], s = h.scale[a], base = a * n;
    for (let i = 0; i < n; i++) disp[i * 3 + a] = o + q[base + i] * s;
  }
  const levels = new Uint8Array(raw, n * 6, n);
  const v = new DataView(raw, n * 7);
  const tools = [];
  for (let t = 0; t < h.count1; t++) {
    const b = t * TOOL_BYTES;
    tools.push({
      id: v.getUint32(b, true),
      shape: TOOL_SHAPES[v.getUint8(b + 4)] || 'unknown',
      active: v.getUint8(b + 5) !== 0,
      pos: [v.getFloat32(b + 8, true), v.getFloat32(b + 12, true), v.getFloat32(b + 16, true)],
      radius: v.getFloat32(b + 20, true),
      force: [v.getFloat32(b + 24, true), v.getFloat32(b + 28, true), v.getFloat32(b + 32, true)],
    });
  }
  return { header: h, disp, levels, tools, reset: (h.flags & 1) !== 0 };
}

/** nodes: records of f32 x,y,z and u8 level */
export function decodeNodes(h, raw) {
  const n = h.count0, v = new DataView(raw);
  const pos = new Float32Array(n * 3), levels = new Uint8Array(n);
  for (let i = 0; i < n; i++) {
    const b = i * NODE_BYTES;
    pos[i * 3] = v.getFloat32(b, true);
    pos[i * 3 + 1] = v.getFloat32(b + 4, true);
    pos[i * 3 + 2] = v.getFloat32(b + 8, true);
    levels[i] = v.getUint8(b + 12);
  }
  return { header: h, pos, levels };
}
