// client.mjs - a small Node client for the squish protocol v1 (docs/protocol.md).
//
// Used by the integration tests and benchmarks, and reusable by any automated client:
//
//   import { SquishClient } from './client.mjs';
//   const c = await SquishClient.connect('ws://127.0.0.1:8080/ws', { role: 'control' });
//   const opened = await c.open('default');           // topology of every body in c.bodies
//   c.on('frame', f => console.log(f.frame, f.positions[0]));
//   await c.tool({ id: 1, shape: 'grab', pos: [0.5, 0.5, 1], radius: 0.1 });
//   const s = await c.stats();
//   c.close();
//
// Requests return promises resolved with the reply object (matched by an automatic `ref`) and
// rejected with a SquishError (code, message) when the server answers with `error`.
import { inflateSync } from 'node:zlib';
import { EventEmitter } from 'node:events';
import WebSocket from 'ws';

export const HEADER_BYTES = 64;
export const KIND = { topology: 1, frame: 2, nodes: 3 };
const SHAPES = ['sphere', 'box', 'grab'];

/** An `error` reply of the server, as an exception. */
export class SquishError extends Error {
  constructor(reply) {
    super(`${reply.code}: ${reply.message}`);
    this.code = reply.code;
    this.reply = reply;
  }
}

/** Decode the 64-byte header of a binary message (a Buffer or Uint8Array). */
export function decodeHeader(buf) {
  const b = Buffer.from(buf.buffer, buf.byteOffset, buf.byteLength);
  if (b.length < HEADER_BYTES || b.toString('latin1', 0, 4) !== 'SQSH')
    throw new Error(`not a squish binary message (${b.length} bytes)`);
  return {
    version: b.readUInt16LE(4),
    kind: b.readUInt8(6),
    flags: b.readUInt8(7),
    body: b.readUInt32LE(8),
    frame: b.readUInt32LE(12),
    time: b.readDoubleLE(16),
    count0: b.readUInt32LE(24),
    count1: b.readUInt32LE(28),
    offset: [b.readFloatLE(32), b.readFloatLE(36), b.readFloatLE(40)],
    scale: [b.readFloatLE(44), b.readFloatLE(48), b.readFloatLE(52)],
    rawBytes: b.readUInt32LE(56),
    zbytes: b.readUInt32LE(60),
  };
}

/**
 * Decode a whole binary message. `rest` (Float32Array of the body's rest surface positions)
 * is needed for frames to give absolute positions.
 * Returns { header, ...kind-specific fields, bytes }.
 */
export function decodeBinary(buf, rest) {
  const h = decodeHeader(buf);
  const b = Buffer.from(buf.buffer, buf.byteOffset, buf.byteLength);
  if (b.length !== HEADER_BYTES + h.zbytes) throw new Error(`zbytes ${h.zbytes} but ${b.length - 64} payload bytes`);
  const raw = inflateSync(b.subarray(HEADER_BYTES));
  if (raw.length !== h.rawBytes) throw new Error(`payload inflates to ${raw.length}, header says ${h.rawBytes}`);
  const out = { header: h, kind: h.kind, body: h.body, frame: h.frame, time: h.time, flags: h.flags, bytes: b.length };
  const n = h.count0;
  if (h.kind === KIND.topology) {
    out.rest = new Float32Array(n * 3);
    for (let i = 0; i < 3 * n; i++) out.rest[i] = raw.readFloatLE(4 * i);
    out.triangles = new Uint32Array(h.count1 * 3);
    for (let i = 0; i < 3 * h.count1; i++) out.triangles[i] = raw.readUInt32LE(12 * n + 4 * i);
  } else if (h.kind === KIND.frame) {
    out.displacement = new Float32Array(n * 3);
    for (let k = 0; k < 3; k++)
      for (let i = 0; i < n; i++)
        out.displacement[3 * i + k] = h.offset[k] + raw.readUInt16LE(2 * (k * n + i)) * h.scale[k];
    if (rest) {
      out.positions = new Float32Array(n * 3);
      for (let i = 0; i < 3 * n; i++) out.positions[i] = rest[i] + out.displacement[i];
    }
    out.levels = new Uint8Array(raw.subarray(6 * n, 7 * n));
    out.tools = [];
    for (let t = 0; t < h.count1; t++) {
      const o = 7 * n + 36 * t;
      out.tools.push({
        id: raw.readUInt32LE(o),
        shape: SHAPES[raw.readUInt8(o + 4)] ?? raw.readUInt8(o + 4),
        active: raw.readUInt8(o + 5) !== 0,
        pos: [raw.readFloatLE(o + 8), raw.readFloatLE(o + 12), raw.readFloatLE(o + 16)],
        radius: raw.readFloatLE(o + 20),
        force: [raw.readFloatLE(o + 24), raw.readFloatLE(o + 28), raw.readFloatLE(o + 32)],
      });
    }
  } else if (h.kind === KIND.nodes) {
    out.positions = new Float32Array(n * 3);
    out.levels = new Uint8Array(n);
    for (let i = 0; i < n; i++) {
      for (let k = 0; k < 3; k++) out.positions[3 * i + k] = raw.readFloatLE(13 * i + 4 * k);
      out.levels[i] = raw.readUInt8(13 * i + 12);
    }
  }
  return out;
}

/**
 * A connection to `squish serve`. Events: 'frame' (decoded frame), 'topology', 'nodes',
 * 'binary' (raw Buffer of every binary message), 'stats' (pushed stats), 'event', 'message'
 * (every text message), 'close'.
 */
export class SquishClient extends EventEmitter {
  /**
   * Connect and say hello. options: { client, role ('control'|'view'), token, origin,
   * decode (default true: decode frames; false keeps only raw 'binary' events) }.
   * Resolves with the client; the welcome reply is in client.welcome.
   */
  static async connect(url, options = {}) {
    const c = new SquishClient(url, options);
    await c._opened;
    const hello = { type: 'hello', client: options.client ?? 'node', role: options.role ?? 'control' };
    if (options.token !== undefined) hello.token = options.token;
    c.welcome = await c.request(hello);
    return c;
  }

  constructor(url, options = {}) {
    super();
    this.options = options;
    this.nextRef = 1;
    this.pending = new Map();
    this.bodies = new Map(); // body id -> { rest, triangles }
    this.session = null;
    this.decode = options.decode !== false;
    this.framesReceived = 0;
    this.bytesReceived = 0;
    const wsOptions = { perMessageDeflate: false, maxPayload: 256 << 20 };
    if (options.origin) wsOptions.origin = options.origin;
    this.ws = new WebSocket(url, wsOptions);
    this.ws.binaryType = 'nodebuffer';
    this._opened = new Promise((resolve, reject) => {
      this.ws.once('open', resolve);
      this.ws.once('error', reject);
      this.ws.once('unexpected-response', (req, res) => reject(new Error(`HTTP ${res.statusCode} on upgrade`)));
    });
    this.closed = new Promise(resolve => this.ws.once('close', (code, reason) => {
      for (const p of this.pending.values()) p.reject(new Error('connection closed'));
      this.pending.clear();
      this.emit('close', code, reason);
      resolve(code);
    }));
    this.ws.on('error', e => this.emit('wserror', e));
    this.ws.on('message', (data, isBinary) => this._onMessage(data, isBinary));
  }

  _onMessage(data, isBinary) {
    this.bytesReceived += data.length;
    if (isBinary) {
      this.emit('binary', data);
      if (!this.decode) return;
      const h = decodeHeader(data);
      if (h.kind === KIND.topology) {
        const t = decodeBinary(data);
        this.bodies.set(t.body, { rest: t.rest, triangles: t.triangles });
        this.emit('topology', t);
      } else if (h.kind === KIND.frame) {
        this.framesReceived++;
        const body = this.bodies.get(h.body);
        const f = decodeBinary(data, body && body.rest);
        this.lastFrame = f;
        this.emit('frame', f);
      } else {
        this.emit('nodes', decodeBinary(data));
      }
      return;
    }
    const msg = JSON.parse(data.toString());
    this.emit('message', msg);
    if (msg.ref !== undefined && this.pending.has(msg.ref)) {
      const p = this.pending.get(msg.ref);
      this.pending.delete(msg.ref);
      if (msg.type === 'error') p.reject(new SquishError(msg));
      else p.resolve(msg);
      return;
    }
    if (msg.type === 'stats') this.emit('stats', msg);
    else if (msg.type === 'event') this.emit('event', msg);
    else if (msg.type === 'error') this.emit('servererror', msg);
  }

  /** Send a request object (a `ref` is added) and wait for its reply. */
  request(msg, timeoutMs = 10000) {
    const ref = this.nextRef++;
    const body = JSON.stringify({ ...msg, ref });
    return new Promise((resolve, reject) => {
      const timer = setTimeout(() => {
        this.pending.delete(ref);
        reject(new Error(`no reply to ${msg.type} within ${timeoutMs} ms`));
      }, timeoutMs);
      this.pending.set(ref, {
        resolve: v => { clearTimeout(timer); resolve(v); },
        reject: e => { clearTimeout(timer); reject(e); },
      });
      this.ws.send(body);
    });
  }

  /** Send raw text (or a Buffer) without waiting for anything (for tests of bad input). */
  sendRaw(data, options) { this.ws.send(data, options); }

  /** Wait for the next message satisfying pred (text messages), with a timeout. */
  waitFor(pred, timeoutMs = 10000, event = 'message') {
    return new Promise((resolve, reject) => {
      const on = m => { if (pred(m)) { clearTimeout(timer); this.off(event, on); resolve(m); } };
      const timer = setTimeout(() => { this.off(event, on); reject(new Error(`timeout waiting for ${event}`)); }, timeoutMs);
      this.on(event, on);
    });
  }

  async listScenes() { return (await this.request({ type: 'list_scenes' })).scenes; }

  /** Open a scene instance; resolves with the `opened` reply (topologies are in this.bodies). */
  async open(scene) {
    this.bodies.clear();
    const r = await this.request({ type: 'open', scene });
    this.session = r.session;
    return r;
  }

  /** Join a session (role optional: 'control' | 'view'). */
  async join(session, role) {
    this.bodies.clear();
    const msg = { type: 'join', session };
    if (role) msg.role = role;
    const r = await this.request(msg);
    this.session = r.session;
    return r;
  }

  leave() { return this.request({ type: 'leave' }); }
  /** Set a tool: { id, shape?, pos?, radius?, size?, active? }. */
  tool(t) { return this.request({ type: 'tool', ...t }); }
  /** Change settings: { body?, material?, operator?, damping?, lod? }. */
  set(s) { return this.request({ type: 'set', ...s }); }
  pause() { return this.request({ type: 'pause' }); }
  resume() { return this.request({ type: 'resume' }); }
  reset(body) { return this.request(body === undefined ? { type: 'reset' } : { type: 'reset', body }); }
  /** Lockstep: advance `frames` frames; resolves with `stepped` after the frames arrived. */
  step(frames) { return this.request({ type: 'step', frames }, 60000); }
  stats() { return this.request({ type: 'stats' }); }
  subscribe(s) { return this.request({ type: 'subscribe', ...s }); }
  /** Resolves with { reply, nodes } where nodes is the decoded binary message. */
  async nodes(body = 0) {
    const bin = this.waitFor(() => true, 10000, 'nodes');
    const reply = await this.request({ type: 'nodes', body });
    return { reply, nodes: await bin };
  }
  ping(t = Date.now()) { return this.request({ type: 'ping', t }); }

  close() {
    this.ws.close();
    return this.closed;
  }
}
