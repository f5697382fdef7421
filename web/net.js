// net.js - the WebSocket link to `squish serve` (/ws): JSON text messages, binary meshes
// decoded in arrival order, automatic reconnect with exponential backoff.

import { decodeBinary, parseHeader, KIND_FRAME } from './codec.js';

/** reconnect delays grow from BACKOFF_MIN_MS, doubling, up to BACKOFF_MAX_MS */
export const BACKOFF_MIN_MS = 250;
export const BACKOFF_MAX_MS = 8000;

/**
 * A connection that keeps itself open.
 * Callbacks: onStatus(state, detail) with state 'connecting' | 'open' | 'waiting';
 * onOpen() after each (re)connect; onMessage(obj) per JSON message; onBinary(msg) per decoded
 * binary message (in arrival order); onProblem(text) for undecodable input.
 */
export class Link {
  constructor(url) {
    this.url = url;
    this.ws = null;
    this.delay = BACKOFF_MIN_MS;
    this.timer = 0;
    this.queue = [];
    this.draining = false;
    this.framesSkipped = 0;
    this.bytesIn = 0;
    this.bytesOut = 0;
    this.onStatus = () => {};
    this.onOpen = () => {};
    this.onMessage = () => {};
    this.onBinary = () => {};
    this.onProblem = () => {};
    this.closedByUser = false;
    this.worker = null;
    this.jobs = new Map();
    this.jobSeq = 0;
    this.startWorker();
  }

  // binary messages are inflated in a worker when the browser allows it, else here
  startWorker() {
    try {
      this.worker = new Worker(new URL('./decoder.worker.js', import.meta.url), { type: 'module' });
    } catch (e) {
      this.worker = null;
      return;
    }
    this.worker.onmessage = (ev) => {
      const job = this.jobs.get(ev.data.id);
      if (!job) return;
      this.jobs.delete(ev.data.id);
      if (ev.data.error) job.reject(new Error(ev.data.error));
      else job.resolve(ev.data.msg);
    };
    this.worker.onerror = () => {
      // no worker after all (e.g. blocked): fail the waiting jobs over to the main thread
      const w = this.worker;
      this.worker = null;
      if (w) w.terminate();
      for (const job of this.jobs.values()) decodeBinary(job.buf).then(job.resolve, job.reject);
      this.jobs.clear();
    };
  }

  decode(buf) {
    if (!this.worker) return decodeBinary(buf);
    return new Promise((resolve, reject) => {
      const id = ++this.jobSeq;
      // keep a copy for the fallback: the original is transferred to the worker
      this.jobs.set(id, { resolve, reject, buf: buf.slice(0) });
      this.worker.postMessage({ id, buf }, [buf]);
    });
  }

  /** open (or re-open) the socket */
  connect() {
    clearTimeout(this.timer);
    // the URL may be a function: asked again at every (re)connection
    const url = typeof this.url === 'function' ? this.url() : this.url;
    this.onStatus('connecting', url);
    let ws;
    try {
      ws = new WebSocket(url);
    } catch (e) {
      this.onProblem(`cannot open ${url}: ${e.message}`);
      this.scheduleReconnect();
      return;
    }
    ws.binaryType = 'arraybuffer';
    this.ws = ws;
    ws.onopen = () => {
      this.onStatus('open', url);
      this.onOpen();
    };
    ws.onmessage = (ev) => this.receive(ev.data);
    ws.onclose = () => {
      if (this.ws !== ws) return;
      this.ws = null;
      if (!this.closedByUser) this.scheduleReconnect();
    };
    // errors are followed by close, which schedules the retry
    ws.onerror = () => {};
  }

  /** the socket is open */
  get isOpen() { return !!this.ws && this.ws.readyState === WebSocket.OPEN; }

  /** the server answered: reset the backoff */
  resetBackoff() { this.delay = BACKOFF_MIN_MS; }

  scheduleReconnect() {
    const d = this.delay;
    this.delay = Math.min(BACKOFF_MAX_MS, this.delay * 2);
    this.onStatus('waiting', d);
    this.timer = setTimeout(() => this.connect(), d);
  }

  /** send a JSON message; false if not connected */
  send(obj) {
    if (!this.isOpen) return false;
    const text = JSON.stringify(obj);
    this.ws.send(text);
    this.bytesOut += text.length;
    return true;
  }

  receive(data) {
    if (typeof data === 'string') {
      this.bytesIn += data.length;
      let obj;
      try {
        obj = JSON.parse(data);
      } catch (e) {
        this.onProblem(`server sent text that is not JSON (${e.message})`);
        return;
      }
      this.queue.push({ obj });
    } else {
      this.bytesIn += data.byteLength;
      let header;
      try {
        header = parseHeader(data);
      } catch (e) {
        this.onProblem(e.message);
        return;
      }
      this.queue.push({ buf: data, header, at: performance.now() });
    }
    if (!this.draining) this.drain();
  }

  // deliver queued messages in arrival order, one inflate at a time; latest frame wins:
  // a frame with a newer frame of the same body behind it in the queue is skipped
  async drain() {
    this.draining = true;
    while (this.queue.length) {
      const item = this.queue.shift();
      if (item.obj) { this.deliver(this.onMessage, item.obj); continue; }
      const h = item.header;
      if (h.kind === KIND_FRAME && this.queue.some((q) => q.header && q.header.kind === KIND_FRAME && q.header.body === h.body)) {
        this.framesSkipped++;
        continue;
      }
      let msg;
      try {
        msg = await this.decode(item.buf);
      } catch (e) {
        this.onProblem(e.message);
        continue;
      }
      // time from arrival to delivery (waiting in the queue plus inflating), averaged
      const d = performance.now() - item.at;
      this.decodeMs = this.decodeMs === undefined ? d : this.decodeMs * 0.9 + d * 0.1;
      this.deliver(this.onBinary, msg);
    }
    this.draining = false;
  }

  /** call a handler; a handler's exception is reported, never breaks the ordering chain */
  deliver(fn, arg) {
    try {
      fn(arg);
    } catch (e) {
      this.onProblem(`viewer error: ${e.message}`);
      console.warn(e);
    }
  }

  /** close for good (no reconnect) */
  close() {
    this.closedByUser = true;
    clearTimeout(this.timer);
    if (this.ws) this.ws.close();
  }
}
