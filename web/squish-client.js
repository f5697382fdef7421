// squish-client.js - a client library for the squish protocol v1 (docs/protocol.md), for test
// scripts and bots, in Node 20+ and in browsers. Binary messages are decoded by codec.js, the
// very module the viewer's decoder worker runs, so a script and the viewer see the same numbers.
//
//   import { SquishClient } from './web/squish-client.js';
//   const c = await SquishClient.connect('ws://127.0.0.1:8080/ws', { role: 'control' });
//   const opened = await c.open('paper-cube');         // topology of every body in c.bodies
//   c.on('frame', (f) => console.log(f.frame, f.positions[0]));
//   await c.tool({ id: 1, shape: 'grab', pos: [0.5, 0.5, 1], radius: 0.1 });
//   if (c.welcome.lockstep) await c.step(10);          // `squish serve --lockstep`
//   const s = await c.stats();
//   await c.close();
//
// Requests return promises resolved with the reply (matched by an automatic `ref`) and
// rejected with a SquishError (`code`, `message`, `reply`) when the server answers `error`.
//
// WebSocket: in Node the npm package `ws` is used when it can be found (next to the script, or
// in a squish checkout's tests/node_modules after `make node-deps`), else the runtime's own
// WebSocket (Node 22+, browsers). Pass { WebSocket } in the options to choose one yourself.

import {
  decodeBinary, decodeBinarySync, parseHeader, toArrayBuffer, HEADER_BYTES,
  KIND_TOPOLOGY, KIND_FRAME, KIND_NODES,
} from './codec.js';

export { HEADER_BYTES, KIND_TOPOLOGY, KIND_FRAME, KIND_NODES, parseHeader };
/** message kinds by name */
export const KIND = { topology: KIND_TOPOLOGY, frame: KIND_FRAME, nodes: KIND_NODES };

const IS_NODE = typeof process !== 'undefined' && !!(process.versions && process.versions.node);

/** An `error` reply of the server, as an exception: `code` is the protocol's error code. */
export class SquishError extends Error {
  constructor(reply) {
    super(`${reply.code}: ${reply.message}`);
    this.name = 'SquishError';
    this.code = reply.code;
    this.reply = reply;
  }
}

// Node's synchronous inflate (decoding then keeps arrival order without a queue); null elsewhere
let nodeInflate = null;
if (IS_NODE) {
  try {
    const zlib = await import('node:zlib');
    nodeInflate = (bytes) => zlib.inflateSync(bytes);
  } catch (e) {
    nodeInflate = null;
  }
}

/** the WebSocket class to use: options.WebSocket, else npm `ws` (Node), else globalThis.WebSocket */
export async function findWebSocket(options = {}) {
  if (options.WebSocket) return options.WebSocket;
  if (IS_NODE) {
    try {
      return (await import('ws')).default;
    } catch (e) {
      // not beside the script: a squish checkout keeps it in tests/node_modules (make node-deps)
    }
    try {
      const { createRequire } = await import('node:module');
      const { pathToFileURL } = await import('node:url');
      const req = createRequire(new URL('../tests/package.json', import.meta.url));
      return (await import(pathToFileURL(req.resolve('ws')).href)).default;
    } catch (e) {
      // not in a checkout either
    }
  }
  if (typeof globalThis.WebSocket === 'function') return globalThis.WebSocket;
  throw new Error('squish-client: no WebSocket implementation found. Node 20 has none built in: ' +
    'in a squish checkout run `make node-deps` (it installs the npm package ws into tests/node_modules), ' +
    'elsewhere run `npm install ws` next to your script, or use Node 22 or later');
}

// found once, when the module loads (so `new SquishClient(url)` can work synchronously)
let defaultWebSocket = null;
let noWebSocket = null;
try {
  defaultWebSocket = await findWebSocket();
} catch (e) {
  noWebSocket = e;
}

/** rest + displacement, per coordinate */
export function positionsOf(rest, displacement) {
  const out = new Float32Array(displacement.length);
  for (let i = 0; i < out.length; i++) out[i] = rest[i] + displacement[i];
  return out;
}

// the codec's message in the client's shape (names kept from the first Node client)
function shape(m, bytes, rest) {
  const h = m.header;
  h.zbytes = h.zBytes;
  const out = { header: h, kind: h.kind, body: h.body, frame: h.frame, time: h.time, flags: h.flags, bytes };
  if (h.kind === KIND_TOPOLOGY) {
    out.rest = m.rest;
    out.triangles = m.tris;
  } else if (h.kind === KIND_FRAME) {
    out.displacement = m.disp;
    if (rest && rest.length === m.disp.length) out.positions = positionsOf(rest, m.disp);
    out.levels = m.levels;
    out.tools = m.tools;
    out.reset = m.reset;
  } else {
    out.positions = m.pos;
    out.levels = m.levels;
  }
  return out;
}

/**
 * Decode one binary message (ArrayBuffer, Uint8Array or Buffer) into the client's shape:
 * { header, kind, body, frame, time, flags, bytes, ... } with, for a topology, `rest`
 * (Float32Array, n x 3) and `triangles` (Uint32Array); for a frame, `displacement`,
 * `positions` (when `rest` is given), `levels`, `tools` [{id, shape, active, pos, radius,
 * force}], `reset`; for nodes, `positions` and `levels`. Synchronous in Node (throws on bad
 * input); a Promise in browsers.
 */
export function decodeMessage(buf, rest) {
  const bytes = buf.byteLength;
  if (nodeInflate) return shape(decodeBinarySync(buf, nodeInflate), bytes, rest);
  return decodeBinary(buf).then((m) => shape(m, bytes, rest));
}

// UTF-8 length of a text message
const encoder = new TextEncoder();
function textBytes(s) {
  return IS_NODE && typeof Buffer === 'function' ? Buffer.byteLength(s) : encoder.encode(s).length;
}

// a minimal event emitter (browsers have no node:events)
class Emitter {
  constructor() { this._handlers = new Map(); }
  on(name, fn) {
    if (!this._handlers.has(name)) this._handlers.set(name, []);
    this._handlers.get(name).push(fn);
    return this;
  }
  off(name, fn) {
    const l = this._handlers.get(name);
    if (l) { const i = l.indexOf(fn); if (i >= 0) l.splice(i, 1); }
    return this;
  }
  once(name, fn) {
    const w = (...a) => { this.off(name, w); fn(...a); };
    return this.on(name, w);
  }
  emit(name, ...args) {
    const l = this._handlers.get(name);
    if (!l || !l.length) return false;
    for (const fn of l.slice()) fn(...args);
    return true;
  }
}

/**
 * A connection to `squish serve`. Events: 'frame' (decoded frame), 'topology', 'nodes',
 * 'binary' (the raw bytes of every binary message, a Uint8Array), 'stats' (pushed stats),
 * 'event' (reset, control, shutdown, ...), 'control' (the `event` of kind control), 'message'
 * (every text message), 'servererror' (an `error` matching no pending request), 'close'.
 */
/** haptic channel messages: pose 48 bytes in, force 104 bytes out (little-endian) */
export const HAPTIC_POSE_BYTES = 48, HAPTIC_FORCE_BYTES = 104;
export const HAPTIC_CONTACT = 1, HAPTIC_RELEASED = 2, HAPTIC_NO_MODEL = 4, HAPTIC_DISSIPATING = 8;
export function encodePose(channel, seq, t, pos) {
  const b = new ArrayBuffer(HAPTIC_POSE_BYTES), v = new DataView(b), u = new Uint8Array(b);
  u.set([0x53, 0x51, 0x48, 0x50]);
  v.setUint16(4, 1, true); v.setUint8(6, 1);
  v.setUint32(8, channel, true); v.setUint32(12, seq, true); v.setFloat64(16, t, true);
  for (let c = 0; c < 3; c++) v.setFloat64(24 + 8 * c, pos[c], true);
  return u;
}
export function decodeForce(bytes) {
  const v = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const f64 = (o) => [v.getFloat64(o, true), v.getFloat64(o + 8, true), v.getFloat64(o + 16, true)];
  const flags = v.getUint8(7);
  return { channel: v.getUint32(8, true), seq: v.getUint32(12, true), frame: v.getUint32(16, true),
           t: v.getFloat64(24, true), flags, contact: !!(flags & 1), released: !!(flags & 2),
           noModel: !!(flags & 4), force: f64(32), torque: f64(56), tool: f64(80) };
}

export class SquishClient extends Emitter {
  /**
   * Connect and say hello. options: { client, role ('control'|'view'), token, origin (Node
   * `ws` only), decode (default true; false keeps only 'binary' events), WebSocket (a class) }.
   * Resolves with the client; the welcome reply is in client.welcome.
   */
  static async connect(url, options = {}) {
    const WS = options.WebSocket || defaultWebSocket || await findWebSocket(options);
    const c = new SquishClient(url, options, WS);
    await c._opened;
    const hello = { type: 'hello', client: options.client ?? 'squish-client.js', role: options.role ?? 'control' };
    if (options.token !== undefined) hello.token = options.token;
    c.welcome = await c.request(hello);
    return c;
  }

  /** A connection without hello (connect() says hello); `await client._opened` before sending. */
  constructor(url, options = {}, WS = options.WebSocket || defaultWebSocket) {
    super();
    if (!WS) throw noWebSocket || new Error('squish-client: no WebSocket implementation');
    this.url = url;
    this.options = options;
    this.nextRef = 1;
    this.pending = new Map();
    this._hapticWaits = new Map(); // pose seq -> waiting haptic() call
    this._hapticSeq = 0;
    this.bodies = new Map();      // body id -> { rest, triangles }
    this.session = null;
    this.opened = null;           // the last opened/joined reply
    this.role = options.role ?? 'control';
    this.decode = options.decode !== false;
    this.framesReceived = 0;
    this.bytesReceived = 0;
    this.lastFrame = null;
    this.frames = new Map();      // body id -> newest decoded frame
    this._chain = Promise.resolve();
    const nodeWs = typeof WS.prototype.on === 'function' && typeof WS.prototype.terminate === 'function';
    let closeResolve;
    this.closed = new Promise((resolve) => { closeResolve = resolve; });
    const onClose = (code, reason) => {
      for (const p of this.pending.values()) p.reject(new Error(`connection closed (code ${code}) before the reply`));
      this.pending.clear();
      this.emit('close', code, reason);
      closeResolve(code);
    };
    if (nodeWs) {
      const wsOptions = { perMessageDeflate: false, maxPayload: 256 << 20 };
      if (options.origin) wsOptions.origin = options.origin;
      const ws = new WS(url, wsOptions);
      ws.binaryType = 'nodebuffer';
      this.ws = ws;
      this._opened = new Promise((resolve, reject) => {
        ws.once('open', resolve);
        ws.once('error', reject);
        ws.once('unexpected-response', (req, res) => reject(new Error(`HTTP ${res.statusCode} on upgrade to ${url}`)));
      });
      ws.once('close', (code, reason) => onClose(code, String(reason)));
      ws.on('error', (e) => this.emit('wserror', e));
      ws.on('message', (data, isBinary) => this._receive(isBinary ? data : data.toString(), isBinary));
    } else {
      const ws = new WS(url);
      ws.binaryType = 'arraybuffer';
      this.ws = ws;
      this._opened = new Promise((resolve, reject) => {
        ws.addEventListener('open', () => resolve(), { once: true });
        ws.addEventListener('error', () => reject(new Error(`cannot connect to ${url}`)), { once: true });
      });
      ws.addEventListener('close', (ev) => onClose(ev.code, ev.reason));
      ws.addEventListener('error', (e) => this.emit('wserror', e));
      ws.addEventListener('message', (ev) => {
        const bin = typeof ev.data !== 'string';
        this._receive(bin ? new Uint8Array(ev.data) : ev.data, bin);
      });
    }
  }

  // messages are handled in arrival order: in Node at once, in browsers through a queue;
  // haptic forces at once everywhere (they are small and need no decoder)
  _receive(data, isBinary) {
    if (isBinary && data.length === HAPTIC_FORCE_BYTES && data[0] === 0x53 && data[1] === 0x51 &&
        data[2] === 0x48 && data[3] === 0x50) {
      const f = decodeForce(data);
      const w = this._hapticWaits.get(f.seq);
      if (w) { this._hapticWaits.delete(f.seq); clearTimeout(w.timer); w.resolve(f); }
      this.emit('haptic', f);
      return;
    }
    if (nodeInflate || !isBinary || !this.decode) { this._handle(data, isBinary, null); return; }
    const decoded = this._decode(data);
    this._chain = this._chain.then(() => decoded).then((m) => this._handle(data, true, m),
      (e) => this.emit('problem', e));
  }

  // decoded without the rest shape: in browsers a frame can be decoded before the topology
  // ahead of it has been handled, so positions are added in _handle, in arrival order
  _decode(data) {
    return decodeMessage(data);
  }

  _handle(data, isBinary, decoded) {
    if (isBinary) {
      this.bytesReceived += data.byteLength;
      this.emit('binary', data);
      if (!this.decode) return;
      let m;
      try {
        m = decoded || this._decode(data);
      } catch (e) {
        this.emit('problem', e);
        return;
      }
      if (m.kind === KIND_TOPOLOGY) {
        this.bodies.set(m.body, { rest: m.rest, triangles: m.triangles });
        this.emit('topology', m);
      } else if (m.kind === KIND_FRAME) {
        const body = this.bodies.get(m.body);
        if (body && body.rest && body.rest.length === m.displacement.length) m.positions = positionsOf(body.rest, m.displacement);
        this.framesReceived++;
        this.lastFrame = m;
        this.frames.set(m.body, m);
        this.emit('frame', m);
      } else {
        this.emit('nodes', m);
      }
      return;
    }
    this.bytesReceived += textBytes(data);
    let msg;
    try {
      msg = JSON.parse(data);
    } catch (e) {
      this.emit('problem', new Error(`server sent text that is not JSON: ${e.message}`));
      return;
    }
    this.emit('message', msg);
    if (msg.type === 'event' && msg.kind === 'control' && typeof msg.you === 'boolean') {
      this.role = msg.you ? 'control' : 'view';
    }
    if (msg.ref !== undefined && msg.ref !== null && this.pending.has(msg.ref)) {
      const p = this.pending.get(msg.ref);
      this.pending.delete(msg.ref);
      if (msg.type === 'error') p.reject(new SquishError(msg));
      else p.resolve(msg);
      return;
    }
    if (msg.type === 'stats') this.emit('stats', msg);
    else if (msg.type === 'event') {
      this.emit('event', msg);
      if (msg.kind === 'control') this.emit('control', msg);
    } else if (msg.type === 'error') this.emit('servererror', msg);
  }

  /** Send a request object (a `ref` is added) and wait for its reply (timeoutMs, default 10 s). */
  request(msg, timeoutMs = 10000) {
    const ref = this.nextRef++;
    const text = JSON.stringify({ ...msg, ref });
    return new Promise((resolve, reject) => {
      const timer = setTimeout(() => {
        this.pending.delete(ref);
        reject(new Error(`no reply to ${msg.type} within ${timeoutMs} ms`));
      }, timeoutMs);
      this.pending.set(ref, {
        resolve: (v) => { clearTimeout(timer); resolve(v); },
        reject: (e) => { clearTimeout(timer); reject(e); },
      });
      try {
        this.ws.send(text);
      } catch (e) {
        this.pending.delete(ref);
        clearTimeout(timer);
        reject(e);
      }
    });
  }

  /** Send raw text (or bytes) without waiting for anything (for tests of bad input). */
  sendRaw(data, options) { if (options) this.ws.send(data, options); else this.ws.send(data); }

  /** Wait for the next `event` emission (default 'message') satisfying pred, with a timeout. */
  waitFor(pred, timeoutMs = 10000, event = 'message') {
    return new Promise((resolve, reject) => {
      const on = (m) => { if (pred(m)) { clearTimeout(timer); this.off(event, on); resolve(m); } };
      const timer = setTimeout(() => { this.off(event, on); reject(new Error(`timeout waiting for ${event} after ${timeoutMs} ms`)); }, timeoutMs);
      this.on(event, on);
    });
  }

  /** Resolves with the newest frame of `body` once one numbered >= minFrame has arrived. */
  waitFrame(minFrame = 0, body = 0, timeoutMs = 10000) {
    const have = this.frames.get(body);
    if (have && have.frame >= minFrame) return Promise.resolve(have);
    return this.waitFor((f) => f.body === body && f.frame >= minFrame, timeoutMs, 'frame');
  }

  /** The scenes the server offers: [{ name, description, bodies, levels, frame_rate }]. */
  async listScenes() { return (await this.request({ type: 'list_scenes' })).scenes; }

  /** Open a new session of a scene; resolves with `opened` (topologies are in this.bodies). */
  async open(scene) {
    this.bodies.clear();
    this.frames.clear();
    const r = await this.request({ type: 'open', scene });
    this.session = r.session;
    this.opened = r;
    this.role = r.role || this.role;
    return r;
  }

  /** Join a session (role optional: 'control' | 'view'); resolves with `joined`. */
  async join(session, role) {
    this.bodies.clear();
    this.frames.clear();
    const msg = { type: 'join', session };
    if (role) msg.role = role;
    const r = await this.request(msg);
    this.session = r.session;
    this.opened = r;
    this.role = r.role || this.role;
    return r;
  }

  leave() { return this.request({ type: 'leave' }); }
  /** Set a tool: { id, shape?, pos?, radius?, size?, active? }. */
  tool(t) { return this.request({ type: 'tool', ...t }); }
  /** Change settings: { body?, material?, operator?, damping?, lod? }; resolves with the ack. */
  set(s) { return this.request({ type: 'set', ...s }); }
  pause() { return this.request({ type: 'pause' }); }
  resume() { return this.request({ type: 'resume' }); }
  reset(body) { return this.request(body === undefined ? { type: 'reset' } : { type: 'reset', body }); }
  /** Lockstep: advance `frames` frames; resolves with `stepped` after all their frames arrived. */
  step(frames = 1) { return this.request({ type: 'step', frames }, 60000); }
  stats() { return this.request({ type: 'stats' }); }
  /** { stats: bool, stats_hz: number, frames: bool } */
  subscribe(s) { return this.request({ type: 'subscribe', ...s }); }
  /** Become the controller of a session that has none (token when the server needs one). */
  async takeControl(token) {
    const r = await this.request(token === undefined ? { type: 'take_control' } : { type: 'take_control', token });
    this.role = r.role || 'control';
    return r;
  }
  /** Resolves with { reply, nodes }: nodes is the decoded binary message. */
  async nodes(body = 0) {
    const bin = this.waitFor(() => true, 10000, 'nodes');
    const reply = await this.request({ type: 'nodes', body });
    return { reply, nodes: await bin };
  }
  ping(t = Date.now()) { return this.request({ type: 'ping', t }); }

  // ---- haptic channel (docs/protocol.md, "Haptic channel")
  /** Open the haptic channel of tool `tool`: resolves with { channel, max_rate, stiffness, damping, ... }. */
  hapticOpen(tool, { stiffness, damping, ramp, deviceMass, focus } = {}) {
    const m = { type: 'haptic', tool };
    if (focus !== undefined) m.focus = focus; // tool sizes an adaptive body keeps at its finest level about the tool
    if (deviceMass !== undefined) m.device_mass = deviceMass; // kg: bounds the passivity controller's damping
    if (stiffness !== undefined) m.stiffness = stiffness;
    if (damping !== undefined) m.damping = damping;
    if (ramp !== undefined) m.ramp = !!ramp; // lockstep: poses ramped over each frame's substeps
    return this.request(m);
  }
  hapticClose(tool) { return this.request({ type: 'haptic', tool, open: false }); }
  /** Send one pose (device position pos [x, y, z] m at device time t s); returns its seq. */
  hapticSend(channel, pos, t) {
    const seq = this._hapticSeq = (this._hapticSeq + 1) >>> 0;
    this.ws.send(encodePose(channel, seq, t, pos));
    return seq;
  }
  /** Send a pose and resolve with its force { seq, frame, flags, contact, released, force, torque, tool, t }. */
  haptic(channel, pos, t, timeoutMs = 10000) {
    const seq = this.hapticSend(channel, pos, t);
    return new Promise((resolve, reject) => {
      const timer = setTimeout(() => { this._hapticWaits.delete(seq); reject(new Error(`no haptic force for pose ${seq} within ${timeoutMs} ms`)); }, timeoutMs);
      this._hapticWaits.set(seq, { resolve, timer });
    });
  }

  /** Close the connection; resolves with the close code. */
  close() {
    this.ws.close();
    return this.closed;
  }
}
