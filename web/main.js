// main.js - the squish viewer's start-up and wiring: the palette, the renderer, the WebSocket
// link and its handlers, the timers and the drawing loop, and the helpers of window.squish
// (docs/viewer.md). The roles live beside it: state.js (shared state), session.js (connection,
// messages, frames), hud.js (heads-up panel), controls.js (settings and buttons), input.js
// (pointer, keys, tools), firstvisit.js (hint, description, scripted hold), draw.js (pictures).

import { Link } from './net.js';
import { Renderer, hexToRgb } from './render.js';
import { app, view, camera, $, params, FALLBACK_PALETTE, STATS_POLL_MS } from './state.js';
import { hello, onLinkStatus, onMessage, onBinary, setRole, openScene, takeControl } from './session.js';
import { showEvent, buildLegend, tick, pollStats } from './hud.js';
import { setLarge, wireUi } from './controls.js';
import { wireInput, wireKeys } from './input.js';
import { frameLoop } from './draw.js';

// ---------------------------------------------------------------- start-up

async function loadPalette() {
  try {
    const r = await fetch('palette.json', { cache: 'no-cache' });
    if (r.ok) {
      const p = await r.json();
      if (Array.isArray(p.level) && p.level.length) return { ...FALLBACK_PALETTE, ...p };
    }
  } catch (e) {
    // the fallback copy holds the same values
  }
  return FALLBACK_PALETTE;
}

async function start() {
  view.palette = await loadPalette();
  document.documentElement.style.setProperty('--bg', view.palette.background);
  try {
    view.renderer = new Renderer($('view'), view.palette);
    app.softwareGl = view.renderer.software;
    // for machines without a GPU: fewer pixels (scale) or fewer pictures per second (fps)
    const scale = Number(params.get('scale'));
    if (scale > 0 && scale <= 4) { view.renderer.pixelScale = scale; view.userScale = true; }
    if (params.get('autoscale') === '0') view.userScale = true;
    const fps = Number(params.get('fps'));
    if (fps >= 1) view.maxFps = fps;
  } catch (e) {
    showEvent(e.message, true);
  }
  if (params.get('large') === '1') setLarge(true);
  setRole(app.role);
  buildLegend([0], 1, null);
  wireUi({ openScene, takeControl });
  wireInput();
  wireKeys();
  const proto = location.protocol === 'https:' ? 'wss:' : 'ws:';
  // the session in the WebSocket URL lets a proxy route to the instance holding it
  // (docs/deploy.md); re-read at each reconnection, as the session may have changed
  const wsUrl = () => `${proto}//${location.host}/ws${app.session ? `?session=${encodeURIComponent(app.session)}` : ''}`;
  view.link = new Link(params.get('ws') || wsUrl);
  app.link = view.link;
  view.link.onStatus = onLinkStatus;
  view.link.onOpen = () => view.link.send(hello());
  view.link.onMessage = onMessage;
  view.link.onBinary = onBinary;
  view.link.onProblem = (text) => { app.problems.push(text); showEvent(text, true); };
  view.link.connect();
  setInterval(tick, 1000);
  setInterval(pollStats, STATS_POLL_MS);
  requestAnimationFrame(frameLoop);
}

// screen position (CSS pixels in the canvas) of a world point, for automated clients
app.screenPoint = (p) => {
  const c = $('view');
  return camera.project(p, c.clientWidth, c.clientHeight);
};
// the camera (orbit angles az/el in radians, dist in m, target)
app.camera = camera;
// largest surface displacement of any body in the last frame (m)
app.maxDisplacement = () => {
  let m = 0;
  for (const b of app.bodies.values()) {
    if (!b.pos) continue;
    for (let i = 0; i < b.pos.length; i += 3) {
      m = Math.max(m, Math.hypot(b.pos[i] - b.rest[i], b.pos[i + 1] - b.rest[i + 1], b.pos[i + 2] - b.rest[i + 2]));
    }
  }
  return m;
};
// surface vertices per active level over all bodies (last frame)
app.levelHistogram = () => {
  const hist = [0, 0, 0, 0, 0, 0];
  for (const b of app.bodies.values()) if (b.levelArr) for (const l of b.levelArr) hist[Math.min(l, 5)]++;
  return hist;
};
// colour of a level, for callers that inspect pixels
app.levelColor = (i) => hexToRgb(view.palette.level[Math.min(i, view.palette.level.length - 1)]).map((v) => Math.round(v * 255));
app.backgroundColor = () => hexToRgb(view.palette.background).map((v) => Math.round(v * 255));

start();
