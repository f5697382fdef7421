// input.js - input: the pointer (mouse and touch: orbit, pan, pinch, poke), the keyboard
// shortcuts, and our tools (grab and push): picking the body, sending tool poses at most every
// TOOL_SEND_MS, and the tool-to-frame latency.

import { normalize, addScaled } from './camera.js';
import { raycast, rayPlane } from './pick.js';
import { app, view, camera, $, GRAB_ID, PUSH_ID, TOOL_SEND_MS } from './state.js';
import { dismissHint } from './firstvisit.js';
import { toggleHelp, togglePause, resetBodies, toggleOpt, setLarge } from './controls.js';

// ---------------------------------------------------------------- tools (poke)

// our tool: {id, shape, pos, radius, plane: {p, n}, sentAt, dirty}
export let tool = null;
const sentPoses = [];

function pickBody(x, y, w, h) {
  const ray = camera.ray(x, y, w, h);
  let best = null;
  for (const b of app.bodies.values()) {
    if (!b.pos) continue;
    const hit = raycast(b.pos, b.tris, ray.origin, ray.dir);
    if (hit && (!best || hit.t < best.t)) best = { ...hit, body: b.id };
  }
  return best ? { hit: best, ray } : { hit: null, ray };
}

function beginTool(hit, ray, push) {
  const viewDir = ray.dir;
  if (push) {
    // the sphere starts just touching the surface on the viewer's side
    const r = view.size * 0.12;
    const c = addScaled(hit.point, hit.normal, r);
    tool = { id: PUSH_ID, shape: 'sphere', pos: c, radius: r, plane: { p: c, n: viewDir }, dirty: true };
  } else {
    tool = { id: GRAB_ID, shape: 'grab', pos: hit.point, radius: view.size * 0.08, plane: { p: hit.point, n: viewDir }, dirty: true };
    // the server captures the nodes around the pose of this activating message, so moves
    // may follow at once (they do not shift the capture)
  }
  flushTool(true);
}

function moveTool(x, y, w, h) {
  if (!tool) return;
  const ray = camera.ray(x, y, w, h);
  const p = rayPlane(ray.origin, ray.dir, tool.plane.p, tool.plane.n);
  if (!p) return;
  tool.pos = p;
  tool.dirty = true;
  view.dirty = true;
  scheduleFlush();
}

// tool poses go out from input events (not from the drawing loop, which a slow GPU delays),
// at most one per TOOL_SEND_MS
let flushTimer = 0;
function scheduleFlush() {
  if (flushTimer || !tool) return;
  const wait = Math.max(0, TOOL_SEND_MS - (performance.now() - (tool.sentAt || 0)));
  flushTimer = setTimeout(() => { flushTimer = 0; flushTool(false); if (tool && tool.dirty) scheduleFlush(); }, wait);
}

// wheel while pushing: move the sphere along the view direction
function deepenTool(dy) {
  if (!tool || tool.shape !== 'sphere') return false;
  const step = -Math.sign(dy) * view.size * 0.02;
  const n = normalize(tool.plane.n);
  tool.plane.p = addScaled(tool.plane.p, n, -step);
  tool.pos = addScaled(tool.pos, n, -step);
  tool.dirty = true;
  view.dirty = true;
  scheduleFlush();
  return true;
}

function toolMessage(active) {
  const m = { type: 'tool', id: tool.id, shape: tool.shape, pos: tool.pos.map((v) => Math.fround(v)), active };
  m.radius = tool.radius;
  return m;
}

export function flushTool(force) {
  if (!tool || !tool.dirty) return;
  const now = performance.now();
  if (!force && now - (tool.sentAt || 0) < TOOL_SEND_MS) return;
  if (view.link.send(toolMessage(true))) {
    tool.sentAt = now;
    tool.dirty = false;
    sentPoses.push({ t: now, id: tool.id, pos: tool.pos.map((v) => Math.fround(v)) });
    if (sentPoses.length > 64) sentPoses.shift();
  }
}

export function endTool(send) {
  if (!tool) return;
  if (send) view.link.send(toolMessage(false));
  // the user found out how to poke: the hint has done its job
  dismissHint();
  tool = null;
  view.dirty = true;
}

// tool-to-frame latency: time from sending a pose to the first frame that carries it
const latencySamples = [];
export function measureLatency(tools) {
  if (!sentPoses.length) return;
  for (const t of tools) {
    for (let i = sentPoses.length - 1; i >= 0; i--) {
      const s = sentPoses[i];
      if (s.id !== t.id) continue;
      const tol = 1e-6 * Math.max(1, view.size);
      if (Math.abs(s.pos[0] - t.pos[0]) <= tol && Math.abs(s.pos[1] - t.pos[1]) <= tol && Math.abs(s.pos[2] - t.pos[2]) <= tol) {
        latencySamples.push(performance.now() - s.t);
        if (latencySamples.length > 30) latencySamples.shift();
        app.latencyMs = latencySamples.reduce((a, b) => a + b, 0) / latencySamples.length;
        sentPoses.splice(0, i + 1);
        break;
      }
    }
  }
}

// ---------------------------------------------------------------- pointer input

export function wireInput() {
  const cv = $('view');
  const pointers = new Map();
  let mode = null;      // 'orbit' | 'pan' | 'tool' | 'pinch'
  let last = null;
  let pinch = null;

  const local = (e) => { const r = cv.getBoundingClientRect(); return [e.clientX - r.left, e.clientY - r.top, r.width, r.height]; };

  cv.addEventListener('contextmenu', (e) => e.preventDefault());
  cv.addEventListener('pointerdown', (e) => {
    cv.focus();
    cv.setPointerCapture(e.pointerId);
    pointers.set(e.pointerId, local(e));
    if (pointers.size === 2) {
      // second finger: the tool lets go, two fingers pinch and pan
      endTool(true);
      const [a, b] = [...pointers.values()];
      pinch = { d: Math.hypot(a[0] - b[0], a[1] - b[1]), mx: (a[0] + b[0]) / 2, my: (a[1] + b[1]) / 2 };
      mode = 'pinch';
      return;
    }
    if (pointers.size > 2) return;
    const [x, y, w, h] = local(e);
    last = [x, y];
    if (e.button === 2 || e.button === 1 || e.ctrlKey) { mode = 'pan'; return; }
    if (e.button !== 0) return;
    if (app.role === 'control' && app.session) {
      const { hit, ray } = pickBody(x, y, w, h);
      if (hit) {
        beginTool(hit, ray, e.shiftKey);
        mode = 'tool';
        cv.classList.add('dragging');
        return;
      }
    }
    mode = 'orbit';
  });
  cv.addEventListener('pointermove', (e) => {
    if (!pointers.has(e.pointerId)) return;
    const [x, y, w, h] = local(e);
    pointers.set(e.pointerId, [x, y, w, h]);
    if (mode === 'pinch' && pointers.size >= 2) {
      const [a, b] = [...pointers.values()];
      const d = Math.hypot(a[0] - b[0], a[1] - b[1]), mx = (a[0] + b[0]) / 2, my = (a[1] + b[1]) / 2;
      if (pinch.d > 0 && d > 0) camera.zoom(pinch.d / d);
      camera.pan(mx - pinch.mx, my - pinch.my, h);
      pinch = { d, mx, my };
      view.dirty = true;
      return;
    }
    if (!last) return;
    const dx = x - last[0], dy = y - last[1];
    last = [x, y];
    if (mode === 'orbit') { camera.orbit(dx, dy); view.dirty = true; }
    else if (mode === 'pan') { camera.pan(dx, dy, h); view.dirty = true; }
    else if (mode === 'tool') moveTool(x, y, w, h);
  });
  const up = (e) => {
    if (!pointers.has(e.pointerId)) return;
    pointers.delete(e.pointerId);
    if (mode === 'tool') { flushTool(true); endTool(true); }
    cv.classList.remove('dragging');
    if (pointers.size === 0) { mode = null; last = null; pinch = null; }
    else if (mode === 'pinch' && pointers.size === 1) { mode = 'orbit'; last = [...pointers.values()][0].slice(0, 2); }
  };
  cv.addEventListener('pointerup', up);
  cv.addEventListener('pointercancel', up);
  cv.addEventListener('wheel', (e) => {
    e.preventDefault();
    if (deepenTool(e.deltaY)) return;
    camera.zoom(Math.exp(e.deltaY * 0.0015));
    view.dirty = true;
  }, { passive: false });
}

// ---------------------------------------------------------------- keyboard (? lists the keys)

export function wireKeys() {
  document.addEventListener('keydown', (e) => {
    const t = e.target;
    if (t && ((t.tagName === 'INPUT' && t.type !== 'checkbox') || t.tagName === 'SELECT' || t.tagName === 'TEXTAREA')) return;
    if (e.ctrlKey || e.metaKey || e.altKey) return;
    switch (e.key) {
      case '?': toggleHelp(); break;
      case 'Escape': toggleHelp(false); endTool(true); break;
      case ' ': e.preventDefault(); togglePause(); break;
      case 'r': case 'R': resetBodies(); break;
      case 'l': case 'L': toggleOpt('useLevels', 'opt-levels'); break;
      case 'w': case 'W': toggleOpt('wire', 'opt-wire'); break;
      case 'n': case 'N': toggleOpt('nodes', 'opt-nodes'); break;
      case 'g': case 'G': toggleOpt('floor', 'opt-floor'); break;
      case 'c': case 'C': if (app.bounds) { camera.fit(app.bounds.min, app.bounds.max); view.dirty = true; } break;
      case 'p': case 'P': $('panel').classList.toggle('hidden'); view.dirty = true; break;
      case 't': case 'T': setLarge(!document.documentElement.classList.contains('large')); break;
      default: return;
    }
  });
}
