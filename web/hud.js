// hud.js - the heads-up panel: the read-outs of the stats and of the page (rates, budget,
// active nodes, health warnings, viewers, tool force), the level legend, the event line, the
// role notice, the Pause button's label, and the automatic resolution drop.

import { len } from './camera.js';
import { app, view, $, STATS_POLL_MS } from './state.js';
import { autoScaleState, nextScale, MIN_PICTURE_RATE } from './autoscale.js';

// one role notice at a time: kind 'demoted' | 'viewer' | 'left' | 'taken' | 'control' | 'nosession' | null
export function setNotice(kind, text, take = false) {
  app.notice = kind ? { kind, text, take } : null;
  $('notice').hidden = !kind;
  $('notice-text').textContent = kind ? text : '';
  $('btn-take').hidden = !take;
}

// ---------------------------------------------------------------- stats and panel

// frame numbers seen in the last 4 s give the simulation rate
export const frameCounter = {
  samples: [],
  push(t, f) { this.samples.push([t, f]); while (this.samples.length > 2 && t - this.samples[0][0] > 4000) this.samples.shift(); },
  rate() {
    const s = this.samples;
    if (s.length < 2) return 0;
    const dt = (s[s.length - 1][0] - s[0][0]) / 1000;
    return dt > 0 ? (s[s.length - 1][1] - s[0][1]) / dt : 0;
  },
};

let lastStatsAt = 0;
export const boxSizes = new Map();
let lastBytesIn = 0;

// stats are pushed (subscribe); ask for them only when the pushes stop
export function pollStats() {
  if (!app.welcomed || !app.session) return;
  if (performance.now() - lastStatsAt < 3 * STATS_POLL_MS) return;
  view.link.send({ type: 'stats' });
}

export function onStats(m) {
  lastStatsAt = performance.now();
  app.stats = m;
  const fmt = (v, d = 0) => (typeof v === 'number' && Number.isFinite(v) ? v.toFixed(d) : '-');
  if (typeof m.budget_used === 'number') {
    const pct = m.budget_used * 100;
    $('hud-budget').textContent = typeof m.frame_ms === 'number' ? `${fmt(pct, 0)} % (${fmt(m.frame_ms, 1)} ms)` : `${fmt(pct, 0)} %`;
    $('hud-budget').className = pct > 95 ? 'bad' : '';
  }
  $('hud-misses').textContent = fmt(m.deadline_misses);
  if (Array.isArray(m.active_nodes)) {
    // indexed by listed level: zeros for levels no body loaded are left out
    const shown = legendShown.slice();
    m.active_nodes.forEach((n, i) => { if (n > 0 && !shown.includes(i)) shown.push(i); });
    shown.sort((a, b) => a - b);
    $('hud-active').textContent = shown.map((i) => `L${i}: ${m.active_nodes[i] || 0}`).join('  ');
    buildLegend(shown, Math.max(legendListed, m.active_nodes.length), m.active_nodes);
  }
  $('hud-updates').textContent = fmt(m.node_updates);
  // implicit bodies: the frame's CG iterations and final relative residual ('-' when none is implicit)
  if (typeof m.cg_iterations === 'number')
    $('hud-cg').textContent = m.cg_iterations > 0 ? `${fmt(m.cg_iterations)} (res ${m.cg_residual.toExponential(1)})` : '-';
  if (Array.isArray(m.bodies)) {
    // health warnings by kind, summed over bodies (sleep and wake are routine: left out)
    const sum = {};
    for (const b of m.bodies)
      for (const [k, h] of Object.entries((b && b.health) || {}))
        if (k !== 'sleep' && k !== 'wake' && h && typeof h.count === 'number') sum[k] = (sum[k] || 0) + h.count;
    const keys = Object.keys(sum).sort();
    $('hud-health').textContent = keys.length ? keys.map((k) => `${k} ${sum[k]}`).join(', ') : 'none';
    $('hud-health').className = keys.some((k) => k.startsWith('blowup')) ? 'bad' : '';
  }
  if (m.sleeping !== undefined) $('hud-sleeping').textContent = typeof m.sleeping === 'boolean' ? (m.sleeping ? 'yes' : 'no') : fmt(m.sleeping);
  if (typeof m.paused === 'boolean') setPaused(m.paused);
  // viewers: the server's own count when it gives one, else the other clients of the session
  let v = null;
  if (typeof m.viewers === 'number') v = m.viewers;
  else if (typeof m.clients === 'number') v = Math.max(0, m.clients - 1);
  if (v !== null) {
    app.viewers = v;
    $('watchers').textContent = `${v} ${v === 1 ? 'viewer' : 'viewers'} watching`;
  }
  if (Array.isArray(m.feedback)) {
    // per tool and body: "grab #6 on cube: 1.23 N"
    const shapes = new Map((m.tools || []).map((t) => [t.id, t.shape]));
    const f = m.feedback.map((x) => {
      const b = app.bodies.get(x.body);
      return `${shapes.get(x.tool) || 'tool'} #${x.tool} on ${b ? b.name : `body ${x.body}`}: ${len(x.force || [0, 0, 0]).toFixed(2)} N`;
    });
    $('hud-force').textContent = f.length ? f.join('; ') : '-';
  }
  // contact of the selected body with the obstacles and other bodies (stats bodies[].contact)
  if (Array.isArray(m.bodies)) {
    const sel = Number($('body-select').value || 0);
    const b = m.bodies.find((x, i) => (x && Number.isInteger(x.id) ? x.id : i) === sel);
    const c = b && b.contact;
    $('hud-contact').textContent = c && Array.isArray(c.force)
      ? `${len(c.force).toFixed(2)} N on ${fmt(c.nodes)} nodes${typeof c.depth === 'number' && c.depth > 0 ? `, ${(c.depth * 1000).toFixed(1)} mm deep` : ''}`
      : '-';
  }
  // a viewer of a session nobody controls may take it over
  const kind = app.notice ? app.notice.kind : null;
  if (m.controller === false && app.role === 'view' && !app.takeUnsupported && !['left', 'taken', 'unsupported'].includes(kind)) {
    setNotice('left', 'Nobody controls this session.', true);
  } else if (m.controller === true && app.role === 'view' && (kind === 'left' || kind === 'taken')) {
    setNotice('viewer', 'Someone controls this session again: you are watching it (read only).');
  }
  if (typeof m.skipped === 'number') app.skipped = m.skipped;
  // box extents are only in stats (frames carry a radius)
  if (Array.isArray(m.tools)) for (const t of m.tools) if (Array.isArray(t.size)) boxSizes.set(t.id, t.size);
}

// once a second: rates measured in the page
export function tick() {
  if (!view.link) return;
  app.bytesPerSecond = view.link.bytesIn - lastBytesIn;
  lastBytesIn = view.link.bytesIn;
  app.simRate = frameCounter.rate();
  const rate = app.bytesPerSecond >= 1e6 ? `${(app.bytesPerSecond / 1e6).toFixed(2)} MB/s`
    : `${(app.bytesPerSecond / 1e3).toFixed(1)} kB/s`;
  // frames skipped because this page read slower than the simulation (server and page side)
  const skipped = (app.skipped || 0) + view.link.framesSkipped;
  $('hud-bytes').textContent = skipped ? `${rate} (${skipped} frames skipped)` : rate;
  $('hud-rate').textContent = `${app.simRate.toFixed(1)} Hz`;
  if (app.simTime !== undefined) $('hud-time').textContent = `${app.simTime.toFixed(2)} s`;
  $('hud-latency').textContent = app.latencyMs === null ? '-' : `${app.latencyMs.toFixed(1)} ms`;
  pictureCheck();
}

// ---------------------------------------------------------------- automatic resolution

export const pictures = { count: 0, busyMs: 0, since: 0 };
const scaleRule = autoScaleState();

// once a second: pictures drawn while frames kept arriving; the rule of autoscale.js lowers
// the resolution when drawing is too slow and brings it back when it has room again
function pictureCheck() {
  const now = performance.now();
  const dt = now - (pictures.since || now);
  const busy = pictures.busyMs;
  const n = pictures.count;
  pictures.since = now;
  pictures.count = 0;
  pictures.busyMs = 0;
  if (!(dt > 0)) return;
  // frames that wait for a picture most of the second: the drawing is the bottleneck
  const demanded = busy > 0.7 * dt;
  const rate = (1000 * n) / dt;
  app.pictureRate = rate;
  const scale = view.renderer ? (view.renderer.pixelScale || 1) : 1;
  const pct = Math.round(scale * 100);
  let text = n ? `${rate.toFixed(1)}/s at ${pct} %` : '-';
  if (app.autoScale !== null) text += ' (auto)';
  $('hud-pictures').textContent = text;
  $('hud-pictures').className = demanded && rate < MIN_PICTURE_RATE ? 'bad' : '';
  if (!view.renderer || view.userScale) return;
  const next = nextScale(scaleRule, rate, demanded, scale);
  if (next === scale) return;
  view.renderer.pixelScale = next;
  app.autoScale = next < 1 ? next : null;
  view.dirty = true;
  const note = next < scale
    ? `${rate.toFixed(0)} pictures/s: resolution lowered to ${Math.round(next * 100)} % (?scale=1 keeps full resolution)`
    : `${rate.toFixed(0)} pictures/s: resolution raised to ${Math.round(next * 100)} %`;
  $('res-note').textContent = note;
  $('res-note').hidden = next >= 1;
  showEvent(note);
}

let legendShown = [0];   // level numbers (as listed in the scene file) in the legend
let legendListed = 1;    // levels the scene file lists
let legendCounts = null;

// one legend row per loaded level, named and coloured by its number in the scene file
export function buildLegend(shown, nlisted, counts) {
  legendCounts = counts;
  const ul = $('legend-list');
  if (shown.join() !== legendShown.join() || nlisted !== legendListed || ul.children.length !== shown.length) {
    legendShown = shown.slice();
    legendListed = nlisted;
    ul.replaceChildren();
    for (const i of shown) {
      const li = document.createElement('li');
      li.dataset.level = String(i);
      const sw = document.createElement('span');
      sw.className = 'swatch';
      sw.style.background = view.palette.level[Math.min(i, view.palette.level.length - 1)];
      const name = document.createElement('span');
      name.className = 'legend-name';
      const tag = nlisted <= 1 ? ' (only level)' : i === 0 ? ' (coarsest)' : i === nlisted - 1 ? ' (finest)' : '';
      name.textContent = `level ${i}${tag}`;
      const c = document.createElement('span');
      c.className = 'legend-count';
      li.append(sw, name, c);
      ul.append(li);
    }
  }
  if (counts) {
    for (const li of ul.children) {
      const n = counts[Number(li.dataset.level)];
      li.querySelector('.legend-count').textContent = n !== undefined ? `${n} nodes` : '';
    }
  }
}

// without server counts, show the share of surface vertices per level
export function updateLegendFromFrame() {
  if (legendCounts) return;
  const ul = $('legend-list');
  const hist = new Array(256).fill(0);
  for (const b of app.bodies.values()) {
    if (!b.levelArr) continue;
    for (const l of b.levelArr) hist[l]++;
  }
  for (const li of ul.children) {
    li.querySelector('.legend-count').textContent = `${hist[Number(li.dataset.level)]} surf.`;
  }
}

let eventTimer = 0;
export function showEvent(text, bad = false) {
  const el = $('event');
  el.textContent = text;
  el.style.color = bad ? 'var(--bad)' : '';
  clearTimeout(eventTimer);
  eventTimer = setTimeout(() => { el.textContent = ''; }, 8000);
}

export function setPaused(p) {
  app.paused = p;
  $('btn-pause').textContent = p ? 'Resume' : 'Pause';
}
