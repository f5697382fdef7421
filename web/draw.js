// draw.js - the pictures: the animation-frame loop (uploads, camera framing beside the panel,
// tools, force arrows and obstacles), the force labels and probe rings over the canvas.

import { len, normalize, addScaled } from './camera.js';
import { app, view, opts, camera, $, FALLBACK_PALETTE } from './state.js';
import { pictures, boxSizes } from './hud.js';
import { tool, flushTool } from './input.js';
import { requestNodes } from './controls.js';

// ---------------------------------------------------------------- drawing

// arrow length: grows with the force and saturates, so small and large forces both read
function arrowScale(f) {
  if (!(f > 1e-6)) return 0;
  view.peakForce = Math.max(view.peakForce * 0.999, f);
  return view.size * 0.6 * (f / (f + view.peakForce * 0.5));
}

let lastLoopAt = 0;
export function frameLoop() {
  requestAnimationFrame(frameLoop);
  const loopAt = performance.now();
  // time during which something was waiting to be drawn (counts towards the picture check)
  if (view.dirty && lastLoopAt) pictures.busyMs += Math.min(loopAt - lastLoopAt, 1000);
  lastLoopAt = loopAt;
  flushTool(false);
  if (opts.nodes && app.lastFrame !== nodesFrame && !view.nodesPending) { nodesFrame = app.lastFrame; requestNodes(); }
  if (!view.renderer || !view.dirty) return;
  const t0 = performance.now();
  if (view.maxFps && t0 - lastDrawAt < 1000 / view.maxFps - 2) return;
  lastDrawAt = t0;
  view.dirty = false;
  pictures.count++;
  if (app.debugDrawDelayMs > 0) { const until = t0 + app.debugDrawDelayMs; while (performance.now() < until) { /* a slow machine */ } }
  for (const b of app.bodies.values()) {
    if (b.gpuDirty && b.pos) { view.renderer.updateBody(b.id, b.pos, b.levelArr); b.gpuDirty = false; }
  }
  const [w, h] = view.renderer.resize();
  camera.aspect = w / Math.max(h, 1);
  // centre the picture in the part of the window the side panel leaves free
  const panel = $('panel');
  const pr = panel.classList.contains('hidden') ? null : panel.getBoundingClientRect();
  camera.shiftX = pr && pr.left > w * 0.4 && pr.height > h * 0.5 ? -(w - pr.left) / w : 0;
  // a bottom sheet (narrow screens): centre in the part above it
  camera.shiftY = pr && pr.top > h * 0.4 && pr.width > w * 0.8 ? 1 - pr.top / h : 0;
  // tools: the server's view of every tool, plus ours while we drag it
  const tools = [];
  for (const b of app.bodies.values()) {
    for (const t of b.tools || []) {
      if (!t.active || tools.some((x) => x.id === t.id)) continue;
      const size = boxSizes.get(t.id);
      tools.push({ ...t, half: size ? size.map((v) => v / 2) : undefined });
    }
  }
  if (tool) {
    const t = tools.find((x) => x.id === tool.id);
    if (t) { t.pos = tool.pos; t.own = true; } else tools.push({ id: tool.id, shape: tool.shape, pos: tool.pos, radius: tool.radius, active: true, own: true });
  }
  view.renderer.draw({ vp: camera.viewProj(), eye: camera.eye(), target: camera.target, useLevels: opts.useLevels,
    wire: opts.wire, nodes: opts.nodes, floor: opts.floor, tools, arrowScale, arrowWidth: view.size * 0.012,
    grabMarker: view.size * 0.015, pointSize: Math.max(3, 4 * (window.devicePixelRatio || 1)),
    offsets: app.obstacleOffsets });
  app.obstaclesDrawn = view.renderer.obstaclesDrawn;
  drawLabels(tools, w, h);
  const t1 = performance.now();
  const dt = t1 - t0;
  app.drawMs = app.drawMs === undefined ? dt : app.drawMs * 0.9 + dt * 0.1;
  // the picture's own time counts too: frames that arrive while it draws wait for the next
  // one (a frame decoded after the next loop began was otherwise seen only from that loop on,
  // so an 80 ms picture counted as a few ms of waiting); the next loop counts from here
  pictures.busyMs += Math.min(t1 - loopAt, 1000);
  lastLoopAt = t1;
}
let nodesFrame = -1;
let lastDrawAt = 0;

// the part of the window the labels may use: left of the side panel, below the top bar
function labelArea(w, h) {
  const panel = $('panel');
  const pr = panel.classList.contains('hidden') ? null : panel.getBoundingClientRect();
  const top = $('topbar').getBoundingClientRect().bottom;
  let right = w, bottom = h;
  if (pr && pr.left > w * 0.4) right = pr.left - 6;
  else if (pr && pr.top > h * 0.4) bottom = pr.top - 6;
  return { top: top + 4, right, bottom };
}

// force values next to the arrow tips, probe rings on their vertices
function drawLabels(tools, w, h) {
  const layer = $('labels');
  const seen = new Set();
  const area = labelArea(w, h);
  for (const b of app.bodies.values()) {
    if (!b.pos) continue;
    for (const [k, pr] of b.probes.entries()) {
      const v = Number.isInteger(pr.vertex) && pr.vertex >= 0 && pr.vertex * 3 < b.pos.length ? pr.vertex : -1;
      const at = v >= 0 ? [b.pos[3 * v], b.pos[3 * v + 1], b.pos[3 * v + 2]] : Array.isArray(pr.point) ? pr.point : null;
      if (!at) continue;
      const key = `probe-${b.id}-${k}`;
      seen.add(key);
      seen.add(`${key}-name`);
      let ring = document.getElementById(key), name = document.getElementById(`${key}-name`);
      if (!ring) {
        ring = document.createElement('div');
        ring.id = key;
        ring.className = 'probe-marker';
        // the palette's probe colour, as squish render draws probes
        ring.style.borderColor = view.palette.probe || FALLBACK_PALETTE.probe;
        name = document.createElement('div');
        name.id = `${key}-name`;
        name.className = 'probe-name';
        layer.append(ring, name);
      }
      name.textContent = pr.name || `probe ${k}`;
      const p = camera.project(at, w, h);
      const off = !p || p[0] > area.right || p[1] < area.top || p[1] > area.bottom;
      ring.hidden = name.hidden = off;
      if (off) continue;
      ring.style.left = name.style.left = `${p[0]}px`;
      ring.style.top = name.style.top = `${p[1]}px`;
    }
  }
  for (const t of tools) {
    if (!t.force) continue;
    const f = len(t.force);
    const key = `force-${t.id}`;
    seen.add(key);
    let el = document.getElementById(key);
    if (!el) {
      el = document.createElement('div');
      el.id = key;
      el.className = 'force-label';
      layer.append(el);
    }
    const L = arrowScale(f);
    const tip = L > 0 ? addScaled(t.pos, normalize(t.force), L) : t.pos;
    const p = camera.project(tip, w, h);
    if (!p) { el.hidden = true; continue; }
    el.hidden = false;
    el.textContent = `${f >= 100 ? f.toFixed(0) : f >= 1 ? f.toFixed(2) : f.toPrecision(3)} N`;
    // centred above the tip, moved left/down so that it never sits under the panel or the top bar
    const half = (el.offsetWidth || 60) / 2, tall = el.offsetHeight || 20;
    el.style.left = `${Math.max(half + 2, Math.min(p[0], area.right - half))}px`;
    el.style.top = `${Math.max(area.top + tall * 1.3, Math.min(p[1], area.bottom))}px`;
  }
  for (const el of [...layer.children]) if (!seen.has(el.id)) el.remove();
}
