// main.js - the squish viewer: session handling, frames, heads-up panel, controls, input.
// Talks protocol v1 (docs/protocol.md) with `squish serve` over /ws.

import { Link } from './net.js';
import { KIND_TOPOLOGY, KIND_FRAME, KIND_NODES } from './codec.js';
import { Renderer, hexToRgb } from './render.js';
import { OrbitCamera, sub, len, normalize, addScaled } from './camera.js';
import { raycast, rayPlane } from './pick.js';

// the shared palette (web/palette.json); these values are its fallback copy
const FALLBACK_PALETTE = {
  level: ['#4e79a7', '#59a14f', '#edc948', '#f28e2b', '#e15759', '#b07aa1'],
  plain: '#d9a38c', background: '#20242b', floor: '#5b6270', floor_line: '#737b8a', tool: '#c8ccd4',
  probe: '#ff3ea5',
};

// our own tool ids (scripted scene tools use small ids from 0)
const GRAB_ID = 6;
const PUSH_ID = 7;
// tool poses are sent at most this often (the server also limits commands per second)
const TOOL_SEND_MS = 33;
// stats are polled at this period when the server does not push them
const STATS_POLL_MS = 500;
// recent frame checksums kept for comparisons between pages
const FRAME_LOG = 600;

const $ = (id) => document.getElementById(id);
const params = new URLSearchParams(location.search);

/** the whole viewer state; also exposed as window.squish for automation (see docs/viewer.md) */
const app = {
  status: 'offline',
  role: params.get('role') === 'view' ? 'view' : 'control',
  token: params.get('token') || undefined,
  session: params.get('session') || null,
  scene: params.get('scene') || null,
  scenes: [],
  bodies: new Map(),
  framesReceived: 0,
  lastFrame: -1,
  frameLog: new Map(),
  stats: null,
  viewers: null,
  paused: false,
  latencyMs: null,
  lastError: null,
  problems: [],
  welcomed: false,
  opens: 0,
  joinPending: false,
  bytesPerSecond: 0,
  simRate: 0,
  notice: null,          // the role notice shown ({kind, text}), null when none
  pictureRate: 0,        // pictures drawn per second while frames were waiting to be drawn
  autoScale: null,       // render scale chosen automatically (null: not lowered)
  debugDrawDelayMs: 0,   // tests: busy-wait this long in every picture (a slow machine)
};
window.squish = app;

const opts = { useLevels: true, wire: false, nodes: false, floor: true };
const camera = new OrbitCamera();
let renderer = null;
let palette = FALLBACK_PALETTE;
let dirty = true;
let fitted = false;
let fittedScene = null;
let size = 1;
let link = null;

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
  palette = await loadPalette();
  document.documentElement.style.setProperty('--bg', palette.background);
  try {
    renderer = new Renderer($('view'), palette);
    app.softwareGl = renderer.software;
    // for machines without a GPU: fewer pixels (scale) or fewer pictures per second (fps)
    const scale = Number(params.get('scale'));
    if (scale > 0 && scale <= 4) { renderer.pixelScale = scale; userScale = true; }
    if (params.get('autoscale') === '0') userScale = true;
    const fps = Number(params.get('fps'));
    if (fps >= 1) maxFps = fps;
  } catch (e) {
    showEvent(e.message, true);
  }
  if (params.get('large') === '1') setLarge(true);
  setRole(app.role);
  buildLegend([0], 1, null);
  wireUi();
  wireInput();
  const proto = location.protocol === 'https:' ? 'wss:' : 'ws:';
  // the session in the WebSocket URL lets a proxy route to the instance holding it
  // (docs/deploy.md); re-read at each reconnection, as the session may have changed
  const wsUrl = () => `${proto}//${location.host}/ws${app.session ? `?session=${encodeURIComponent(app.session)}` : ''}`;
  link = new Link(params.get('ws') || wsUrl);
  app.link = link;
  link.onStatus = onLinkStatus;
  link.onOpen = () => link.send(hello());
  link.onMessage = onMessage;
  link.onBinary = onBinary;
  link.onProblem = (text) => { app.problems.push(text); showEvent(text, true); };
  link.connect();
  setInterval(tick, 1000);
  setInterval(pollStats, STATS_POLL_MS);
  requestAnimationFrame(frameLoop);
}

function hello() {
  const m = { type: 'hello', client: 'squish-web/1', role: app.role };
  if (app.token) m.token = app.token;
  return m;
}

// ---------------------------------------------------------------- connection

function setStatus(state, text) {
  app.status = state;
  const el = $('conn');
  el.textContent = text;
  el.className = `conn ${state === 'connected' ? 'conn-on' : state === 'offline' || state === 'refused' ? 'conn-off' : 'conn-wait'}`;
}

function onLinkStatus(state, detail) {
  if (state === 'connecting') setStatus('connecting', 'connecting...');
  else if (state === 'open') setStatus('handshake', 'handshake...');
  else if (state === 'waiting') {
    app.welcomed = false;
    setStatus('offline', `offline - retry in ${(detail / 1000).toFixed(1)} s`);
    endTool(false);
  }
}

/** after welcome: re-join the session if we had one, else open a scene */
function enterSession() {
  if (app.session) {
    app.joinPending = true;
    link.send({ type: 'join', session: Number(app.session), role: app.role, ref: 'join' });
  } else if (app.role === 'control') {
    openScene(app.scene);
  } else {
    setNotice('nosession', 'No session to watch: ask the controller for the share link, or open this page without role=view to start your own session.');
  }
}

// without a scene in the address: the paper's cube when the server has it, else the first
const PREFERRED_SCENES = ['paper-cube', 'default'];

function openScene(name) {
  const pref = PREFERRED_SCENES.find((n) => app.scenes.some((s) => s.name === n));
  const scene = name || pref || (app.scenes[0] && app.scenes[0].name);
  if (!scene) { showEvent('the server lists no scenes', true); return; }
  app.scene = scene;
  app.session = null;
  link.send({ type: 'open', scene, ref: 'open' });
}

// ---------------------------------------------------------------- text messages

function onMessage(m) {
  switch (m.type) {
    case 'welcome':
      app.welcomed = true;
      if (m.role === 'view' || m.role === 'control') setRole(m.role);
      link.resetBackoff();
      setStatus('connected', 'connected');
      if (Array.isArray(m.scenes)) setScenes(m.scenes);
      link.send({ type: 'list_scenes' });
      enterSession();
      break;
    case 'scenes':
      setScenes(m.scenes || []);
      break;
    case 'opened':
    case 'joined':
      onSession(m);
      break;
    case 'stats':
      onStats(m);
      break;
    case 'error':
      onError(m);
      break;
    case 'ack':
      onAck(m);
      break;
    case 'event':
      onEvent(m);
      break;
    default:
      break;
  }
}

function setScenes(list) {
  app.scenes = list.map((s) => (typeof s === 'string' ? { name: s } : s));
  const sel = $('scene-select');
  const keep = app.scene || sel.value;
  sel.replaceChildren(...app.scenes.map((s) => {
    const o = document.createElement('option');
    o.value = s.name;
    o.textContent = s.name;
    if (s.description) o.title = s.description;
    return o;
  }));
  if (keep && app.scenes.some((s) => s.name === keep)) sel.value = keep;
}

function onSession(m) {
  app.joinPending = false;
  app.session = String(m.session);
  if (m.scene) app.scene = typeof m.scene === 'string' ? m.scene : m.scene.name;
  app.opens++;
  app.paused = !!m.paused;
  setPaused(app.paused);
  if (m.role === 'view' || m.role === 'control') setRole(m.role);
  if (m.demoted) {
    setNotice('demoted', 'This session already has a controller: you are watching it (read only). You can take control if the controller leaves.');
  } else if (app.role === 'control') {
    setNotice(null);
  } else {
    setNotice('viewer', 'You are watching this session (read only): drag to turn your own view.');
  }
  link.send({ type: 'subscribe', stats: true, stats_hz: 4 });
  // a tool of ours left active by a dropped connection is released
  if (app.role === 'control' && Array.isArray(m.tools)) {
    for (const t of m.tools) {
      if ((t.id === GRAB_ID || t.id === PUSH_ID) && t.active && !(tool && tool.id === t.id)) {
        link.send({ type: 'tool', id: t.id, active: false });
      }
    }
  }
  renderer && renderer.clearBodies();
  app.bodies.clear();
  // nothing of the previous scene stays in the panel
  $('hud-force').textContent = '-';
  peakForce = 0.01;
  app.stats = null;
  // a re-join of the same scene (after a reconnect) keeps the user's camera
  if (app.scene !== fittedScene) fitted = false;
  fittedScene = app.scene;
  const bodies = m.bodies || [];
  for (const b of bodies) {
    app.bodies.set(b.id, { id: b.id, name: b.name || `body ${b.id}`, levels: b.levels || [], info: b,
      rest: null, tris: null, pos: null, levelArr: null, tools: [], frame: -1,
      probes: Array.isArray(b.probes) ? b.probes : [] });
  }
  const sel = $('body-select');
  sel.replaceChildren(...bodies.map((b) => {
    const o = document.createElement('option');
    o.value = b.id;
    o.textContent = b.name || `body ${b.id}`;
    return o;
  }));
  fillControls(bodies[0]);
  nodesPending = false;
  for (const [id, topo] of pendingTopology) {
    const b = app.bodies.get(id);
    if (b) applyTopology(b, topo);
  }
  pendingTopology = new Map();
  refit();
  // the loaded levels, by their number in the scene file (as in frames and stats)
  const shown = new Set();
  let listed = 1;
  for (const b of bodies) {
    (b.levels || []).forEach((l, k) => shown.add(Number.isInteger(l.index) ? l.index : k));
    listed = Math.max(listed, Number.isInteger(b.listed_levels) ? b.listed_levels : (b.levels || []).length);
  }
  buildLegend(shown.size ? [...shown].sort((a, b) => a - b) : [0], listed, null);
  if (app.scene) $('scene-select').value = app.scene;
  // the address bar and the share link name this session
  const u = new URL(location.href);
  u.searchParams.set('session', app.session);
  if (app.scene) u.searchParams.set('scene', app.scene);
  history.replaceState(null, '', u);
  const share = new URL(location.href);
  share.search = '';
  share.searchParams.set('session', app.session);
  share.searchParams.set('role', 'view');
  $('share-link').value = share.toString();
  showEvent(`${m.type === 'opened' ? 'opened' : 'joined'} session ${app.session}${app.scene ? ` (${app.scene})` : ''}`);
  showSceneInfo(m);
  showHint();
  holdScript(m);
  dirty = true;
}

// a scripted scene opened here waits a moment before its tools move, so its poke is seen
const SCRIPT_HOLD_MS = 2000;
let holdTimer = 0;
function holdScript(m) {
  clearTimeout(holdTimer);
  holdTimer = 0;
  if (m.type !== 'opened' || app.role !== 'control' || !app.scripted || m.lockstep || m.paused) return;
  link.send({ type: 'pause' });
  showEvent(`the scene's scripted tools start in ${SCRIPT_HOLD_MS / 1000} s (Replay runs them again)`);
  holdTimer = setTimeout(() => { holdTimer = 0; link.send({ type: 'resume' }); }, SCRIPT_HOLD_MS);
}

// the scene's description under the top bar; Replay when the scene has scripted tools
function showSceneInfo(m) {
  const sc = app.scenes.find((s) => s.name === app.scene);
  $('scene-desc').textContent = sc && sc.description ? sc.description : (app.scene || '');
  const scripted = Array.isArray(m.tools) && m.tools.some((t) => t.id !== GRAB_ID && t.id !== PUSH_ID);
  app.scripted = scripted;
  $('btn-replay').hidden = !scripted;
}

// ---------------------------------------------------------------- first-visit hint and notices

const HINT_KEY = 'squish.hint.v1';
function hintSeen() {
  try { return localStorage.getItem(HINT_KEY) === 'seen'; } catch (e) { return false; }
}
function showHint() {
  if (hintSeen() || params.get('hint') === '0') return;
  $('hint-text').textContent = app.role === 'control'
    ? 'Drag on the body to pull it. Shift + drag to push it. Drag elsewhere to turn the view, wheel to zoom. ? lists every key.'
    : 'You are watching: drag to turn the view, wheel to zoom. ? lists every key.';
  $('hint').hidden = false;
}
function dismissHint() {
  if ($('hint').hidden) return;
  $('hint').hidden = true;
  try { localStorage.setItem(HINT_KEY, 'seen'); } catch (e) { /* private mode: shown again next time */ }
}

// one role notice at a time: kind 'demoted' | 'viewer' | 'left' | 'taken' | 'control' | 'nosession' | null
function setNotice(kind, text, take = false) {
  app.notice = kind ? { kind, text, take } : null;
  $('notice').hidden = !kind;
  $('notice-text').textContent = kind ? text : '';
  $('btn-take').hidden = !take;
}

function takeControl() {
  const m = { type: 'take_control', ref: 'take' };
  if (app.token) m.token = app.token;
  link.send(m);
}

// fill the setting forms from what the server says about a body (when it says it)
function fillControls(b) {
  if (!b) return;
  const st = b.settings || b;
  const mat = st.material || {};
  const set = (id, v) => { if (typeof v === 'number' && Number.isFinite(v)) $(id).value = String(+v.toPrecision(6)); };
  set('in-E', mat.E);
  set('in-nu', mat.nu);
  const d = st.damping || {};
  set('in-damp-mass', d.mass);
  set('in-damp-stiff', d.stiffness);
  if (st.operator === 'paper' || st.operator === 'fem') $('in-operator').value = st.operator;
  const lod = st.lod || {};
  if (lod.mode === 'adaptive' || lod.mode === 'fixed') $('in-lod-mode').value = lod.mode;
  set('in-split', lod.split);
  set('in-merge', lod.merge);
}

function onError(m) {
  app.lastError = m;
  const text = `${m.message || 'refused'}${m.code ? ` [${m.code}]` : ''}`;
  if (m.ref === 'take' || m.request === 'take_control') {
    if (m.code === 'controller_present') setNotice('taken', 'Someone else controls this session now: you keep watching.');
    else if (m.code === 'bad_token') setNotice('left', 'Taking control needs the control token: add ?token=... to the address.', true);
    else if (m.code === 'bad_type') {
      // an older server: never offer it again on this page
      app.takeUnsupported = true;
      setNotice('unsupported', 'This server cannot hand control over: open this page without role=view to start your own session.');
    }
    else setNotice('left', `Could not take control: ${text}`, true);
    return;
  }
  if (app.joinPending && (m.ref === 'join' || m.request === 'join')) {
    // the session is gone (e.g. the server restarted): open the scene again
    app.joinPending = false;
    app.session = null;
    if (app.role === 'control') {
      showEvent(`session no longer exists (${text}); opening the scene again`);
      openScene(app.scene);
    } else {
      showEvent(`the session you watched has ended (${text})`, true);
    }
    return;
  }
  if (m.request === 'hello' || m.code === 'bad_token') {
    setStatus('refused', 'refused');
    showEvent(m.code === 'bad_token'
      ? `${text}: this server needs a control token; add ?token=... to the address, or watch a session with its share link`
      : text, true);
    return;
  }
  if (m.request === 'open' && m.code === 'unknown_scene' && app.role === 'control') {
    // a scene named in the address that the server does not have: open its default instead
    const failed = app.scene;
    app.scene = null;
    const fallback = PREFERRED_SCENES.find((n) => n !== failed && app.scenes.some((s) => s.name === n)) ||
      (app.scenes.find((s) => s.name !== failed) || {}).name;
    showEvent(`${text}; opening ${fallback || 'nothing'} instead`, true);
    if (fallback) openScene(fallback);
    return;
  }
  const p = pendingSets.get(m.ref);
  if (p) {
    pendingSets.delete(p.ref);
    clearTimeout(p.timer);
    const el = $(`err-${p.group}`);
    el.className = 'err';
    el.textContent = text;
    const group = el.closest('details');
    if (group) group.open = true;
    return;
  }
  showEvent(text, true);
}

// an ack confirms a request; a set's ack carries the settings now in force
function onAck(m) {
  if (m.request === 'set') {
    const p = pendingSets.get(m.ref);
    if (p) confirmSet(p);
    for (const b of m.bodies || []) {
      const body = app.bodies.get(b.id);
      if (body && b.settings) body.info.settings = b.settings;
    }
    const cur = app.bodies.get(Number($('body-select').value || 0));
    if (cur) fillControls(cur.info);
  } else if (m.request === 'pause' || m.request === 'resume') {
    setPaused(m.request === 'pause');
  } else if (m.request === 'reset') {
    showEvent(app.scripted ? 'scene reset: its scripted tools run again' : 'bodies reset to rest');
  } else if (m.request === 'take_control') {
    setRole('control');
    setNotice('control', 'You control this session now.');
    setTimeout(() => { if (app.notice && app.notice.kind === 'control') setNotice(null); }, 6000);
  }
}

// pushed events: blow-up resets, control hand-over, session end, server shutdown
function onEvent(m) {
  if (m.kind === 'reset') showEvent(`body ${m.body} was reset: ${m.message || 'numerical blow-up'}`, true);
  else if (m.kind === 'control') onControlEvent(m);
  else if (m.kind === 'session_end') showEvent(`session ended: ${m.reason || ''}`, true);
  else if (m.kind === 'shutdown') showEvent('the server is stopping; reconnecting when it is back', true);
}

// the session's controller changed (protocol: event kind control {controller, you, reason})
function onControlEvent(m) {
  if (m.you === true) {
    setRole('control');
    setNotice('control', 'You control this session now.');
    setTimeout(() => { if (app.notice && app.notice.kind === 'control') setNotice(null); }, 6000);
    return;
  }
  const wasControl = app.role === 'control';
  if (typeof m.you === 'boolean' && wasControl) { endTool(false); setRole('view'); }
  if (m.controller === false) {
    setNotice('left', 'The controller left: nobody controls this session.', true);
  } else if (wasControl) {
    setNotice('demoted', m.reason === 'taken' ? 'Someone else took control of this session: you are watching it now (read only).'
      : 'You no longer control this session: you are watching it (read only).');
  } else {
    setNotice('viewer', 'Someone controls this session again: you are watching it (read only).');
  }
}

function setRole(role) {
  app.role = role;
  document.body.classList.toggle('viewer', role === 'view');
  $('scene-select').disabled = role === 'view';
  $('scene-select').title = role === 'view' ? 'the controller chooses the scene' : '';
  $('role-badge').textContent = role === 'view' ? 'viewer (read only)' : 'controller';
}

// ---------------------------------------------------------------- binary messages

// topology messages come before `opened`/`joined`: kept here until the session is known
let pendingTopology = new Map();

function applyTopology(body, msg) {
  body.rest = msg.rest;
  body.tris = msg.tris;
  body.pos = new Float32Array(msg.rest);
  body.levelArr = new Uint8Array(msg.rest.length / 3);
  if (renderer) renderer.setBody(body.id, msg.rest, msg.tris);
}

function onBinary(msg) {
  const h = msg.header;
  if (h.kind === KIND_TOPOLOGY) {
    pendingTopology.set(h.body, msg);
    return;
  }
  const body = app.bodies.get(h.body);
  if (!body) return;
  if (h.kind === KIND_FRAME) {
    if (!body.rest || msg.disp.length !== body.rest.length) return;
    const pos = body.pos, rest = body.rest, d = msg.disp;
    let sum = 0;
    for (let i = 0; i < pos.length; i++) {
      pos[i] = rest[i] + d[i];
      sum += d[i] * ((i % 7) + 1);
    }
    body.levelArr = msg.levels;
    body.tools = msg.tools;
    body.frame = h.frame;
    body.time = h.time;
    // uploaded when the next picture is drawn: frames may come faster than the GPU draws
    body.gpuDirty = true;
    app.framesReceived++;
    app.lastFrame = h.frame;
    app.simTime = h.time;
    frameCounter.push(performance.now(), h.frame);
    if (h.body === firstBodyId()) {
      app.frameLog.set(h.frame, sum);
      if (app.frameLog.size > FRAME_LOG) app.frameLog.delete(app.frameLog.keys().next().value);
    }
    if (msg.reset) showEvent(`body ${body.name} was reset (numerical blow-up recovered)`, true);
    measureLatency(msg.tools);
    updateLegendFromFrame();
    dirty = true;
  } else if (h.kind === KIND_NODES) {
    if (renderer) renderer.setNodes(msg.pos, msg.levels);
    app.nodesShown = msg.levels.length;
    nodesPending = false;
    dirty = true;
  }
}

function firstBodyId() {
  const it = app.bodies.keys().next();
  return it.done ? -1 : it.value;
}

// camera and floor from the rest bounding box of all bodies
function refit() {
  const min = [Infinity, Infinity, Infinity], max = [-Infinity, -Infinity, -Infinity];
  for (const b of app.bodies.values()) {
    if (!b.rest) continue;
    for (let i = 0; i < b.rest.length; i++) {
      const a = i % 3;
      if (b.rest[i] < min[a]) min[a] = b.rest[i];
      if (b.rest[i] > max[a]) max[a] = b.rest[i];
    }
  }
  if (!(min[0] <= max[0])) return;
  size = Math.max(len(sub(max, min)), 1e-3);
  app.bounds = { min, max };
  if (!fitted) { camera.fit(min, max); fitted = true; }
  if (renderer) renderer.setFloor(min[2] - size * 0.002, (min[0] + max[0]) / 2, (min[1] + max[1]) / 2, size * 1.2);
  dirty = true;
}

// ---------------------------------------------------------------- stats and panel

// frame numbers seen in the last 4 s give the simulation rate
const frameCounter = {
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
const boxSizes = new Map();
let lastBytesIn = 0;

// stats are pushed (subscribe); ask for them only when the pushes stop
function pollStats() {
  if (!app.welcomed || !app.session) return;
  if (performance.now() - lastStatsAt < 3 * STATS_POLL_MS) return;
  link.send({ type: 'stats' });
}

function onStats(m) {
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
function tick() {
  if (!link) return;
  app.bytesPerSecond = link.bytesIn - lastBytesIn;
  lastBytesIn = link.bytesIn;
  app.simRate = frameCounter.rate();
  const rate = app.bytesPerSecond >= 1e6 ? `${(app.bytesPerSecond / 1e6).toFixed(2)} MB/s`
    : `${(app.bytesPerSecond / 1e3).toFixed(1)} kB/s`;
  // frames skipped because this page read slower than the simulation (server and page side)
  const skipped = (app.skipped || 0) + link.framesSkipped;
  $('hud-bytes').textContent = skipped ? `${rate} (${skipped} frames skipped)` : rate;
  $('hud-rate').textContent = `${app.simRate.toFixed(1)} Hz`;
  if (app.simTime !== undefined) $('hud-time').textContent = `${app.simTime.toFixed(2)} s`;
  $('hud-latency').textContent = app.latencyMs === null ? '-' : `${app.latencyMs.toFixed(1)} ms`;
  pictureCheck();
}

// ---------------------------------------------------------------- automatic resolution

// below this many pictures per second (with frames waiting to be drawn) the resolution drops
const MIN_PICTURE_RATE = 20;
const AUTO_SCALES = [0.5, 0.35];
let userScale = false;
const pictures = { count: 0, busyMs: 0, since: 0, slowSeconds: 0 };

// once a second: pictures drawn while frames kept arriving; two slow seconds lower the scale
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
  const scale = renderer ? (renderer.pixelScale || 1) : 1;
  const pct = Math.round(scale * 100);
  let text = n ? `${rate.toFixed(1)}/s at ${pct} %` : '-';
  if (app.autoScale !== null) text += ' (auto)';
  $('hud-pictures').textContent = text;
  $('hud-pictures').className = demanded && rate < MIN_PICTURE_RATE ? 'bad' : '';
  if (!renderer || userScale || !demanded) { pictures.slowSeconds = 0; return; }
  pictures.slowSeconds = rate < MIN_PICTURE_RATE ? pictures.slowSeconds + 1 : 0;
  if (pictures.slowSeconds < 2) return;
  const next = AUTO_SCALES.find((s) => s < scale - 1e-6);
  if (next === undefined) return;
  pictures.slowSeconds = 0;
  renderer.pixelScale = next;
  app.autoScale = next;
  dirty = true;
  const note = `${rate.toFixed(0)} pictures/s: resolution lowered to ${Math.round(next * 100)} % (?scale=1 keeps full resolution)`;
  $('res-note').textContent = note;
  $('res-note').hidden = false;
  showEvent(note);
}

let legendShown = [0];   // level numbers (as listed in the scene file) in the legend
let legendListed = 1;    // levels the scene file lists
let legendCounts = null;

// one legend row per loaded level, named and coloured by its number in the scene file
function buildLegend(shown, nlisted, counts) {
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
      sw.style.background = palette.level[Math.min(i, palette.level.length - 1)];
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
function updateLegendFromFrame() {
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
function showEvent(text, bad = false) {
  const el = $('event');
  el.textContent = text;
  el.style.color = bad ? 'var(--bad)' : '';
  clearTimeout(eventTimer);
  eventTimer = setTimeout(() => { el.textContent = ''; }, 8000);
}

// ---------------------------------------------------------------- controls

// settings sent and not yet answered, by request ref
const pendingSets = new Map();
let setSeq = 0;

function confirmSet(p) {
  if (!pendingSets.delete(p.ref)) return;
  clearTimeout(p.timer);
  const el = $(`err-${p.group}`);
  el.className = 'ok';
  el.textContent = 'applied';
  setTimeout(() => { if (el.textContent === 'applied') el.textContent = ''; }, 2500);
}

function num(form, name) {
  const input = form.elements[name];
  const text = input.value.trim();
  const v = Number(text);
  if (text === '' || !Number.isFinite(v)) throw new Error(`${name}: "${text}" is not a number`);
  return v;
}

function sendSet(group, fields) {
  const el = $(`err-${group}`);
  if (!app.welcomed || !app.session) { el.className = 'err'; el.textContent = 'not connected'; return; }
  const body = Number($('body-select').value || 0);
  const ref = `set-${group}-${++setSeq}`;
  const m = { type: 'set', body, ...fields, ref };
  el.textContent = '';
  const p = { group, ref, t: performance.now() };
  // every request is answered (ack or error); say so if the answer does not come
  p.timer = setTimeout(() => {
    if (!pendingSets.delete(ref)) return;
    el.className = 'err';
    el.textContent = 'no answer from the server';
  }, 5000);
  pendingSets.set(ref, p);
  link.send(m);
}

function submitSetting(ev) {
  ev.preventDefault();
  const form = ev.currentTarget, group = form.dataset.group;
  try {
    if (group === 'material') sendSet(group, { material: { E: num(form, 'E'), nu: num(form, 'nu') } });
    else if (group === 'damping') {
      sendSet(group, { damping: { mass: num(form, 'mass'), stiffness: num(form, 'stiffness') } });
    } else if (group === 'operator') sendSet(group, { operator: form.elements.operator.value });
    else if (group === 'lod') {
      sendSet(group, { lod: { mode: form.elements.mode.value, split: num(form, 'split'), merge: num(form, 'merge') } });
    }
  } catch (e) {
    const el = $(`err-${group}`);
    el.className = 'err';
    el.textContent = e.message;
  }
}

function setPaused(p) {
  app.paused = p;
  $('btn-pause').textContent = p ? 'Resume' : 'Pause';
}

function togglePause() {
  if (app.role !== 'control' || !app.session) return;
  // the user decides: no automatic resume after the first-open wait
  clearTimeout(holdTimer);
  holdTimer = 0;
  const next = !app.paused;
  link.send({ type: next ? 'pause' : 'resume' });
}

function resetBodies() {
  if (app.role !== 'control' || !app.session) return;
  link.send({ type: 'reset' });
}

function setLarge(on) {
  document.documentElement.classList.toggle('large', on);
  $('btn-large').setAttribute('aria-pressed', String(on));
  dirty = true;
}

function toggleOpt(key, checkbox) {
  opts[key] = !opts[key];
  $(checkbox).checked = opts[key];
  if (key === 'nodes') requestNodes();
  dirty = true;
}

let nodesPending = false;
let nodesAskedAt = 0;
function requestNodes() {
  if (!opts.nodes || !app.welcomed || !app.session) return;
  const now = performance.now();
  if (nodesPending && now - nodesAskedAt < 2000) return;
  nodesPending = true;
  nodesAskedAt = now;
  link.send({ type: 'nodes', body: Number($('body-select').value || 0) });
}

function toggleHelp(show) {
  const h = $('help');
  const on = show === undefined ? h.classList.contains('hidden') : show;
  h.classList.toggle('hidden', !on);
  if (on) $('help-card').focus();
}

function wireUi() {
  for (const f of document.querySelectorAll('form.setting')) f.addEventListener('submit', submitSetting);
  // viewers have no Open (it would silently start a session of their own); see the notices
  $('btn-open').addEventListener('click', () => { if (app.role === 'control') openScene($('scene-select').value); });
  $('btn-replay').addEventListener('click', resetBodies);
  $('btn-take').addEventListener('click', takeControl);
  $('btn-hint-close').addEventListener('click', dismissHint);
  $('btn-share').addEventListener('click', () => $('btn-copy').click());
  $('btn-pause').addEventListener('click', togglePause);
  $('btn-reset').addEventListener('click', resetBodies);
  $('btn-help').addEventListener('click', () => toggleHelp());
  $('btn-help-close').addEventListener('click', () => toggleHelp(false));
  $('help').addEventListener('click', (e) => { if (e.target === $('help')) toggleHelp(false); });
  $('btn-large').addEventListener('click', () => setLarge(!document.documentElement.classList.contains('large')));
  $('btn-copy').addEventListener('click', async () => {
    const input = $('share-link');
    $('share').open = true;
    input.select();
    // the clipboard API needs a secure context (https or localhost); else the older command
    try {
      await navigator.clipboard.writeText(input.value);
      showEvent('share link copied');
    } catch (e) {
      showEvent(document.execCommand('copy') ? 'share link copied' : 'the link is selected: copy it with Ctrl+C');
    }
  });
  const bind = (id, key) => $(id).addEventListener('change', () => { opts[key] = $(id).checked; if (key === 'nodes') requestNodes(); dirty = true; });
  bind('opt-levels', 'useLevels');
  bind('opt-wire', 'wire');
  bind('opt-nodes', 'nodes');
  bind('opt-floor', 'floor');
  $('body-select').addEventListener('change', () => {
    const b = app.bodies.get(Number($('body-select').value));
    if (b) fillControls(b.info);
  });

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
      case 'c': case 'C': if (app.bounds) { camera.fit(app.bounds.min, app.bounds.max); dirty = true; } break;
      case 'p': case 'P': $('panel').classList.toggle('hidden'); dirty = true; break;
      case 't': case 'T': setLarge(!document.documentElement.classList.contains('large')); break;
      default: return;
    }
  });
  // the overlays and the panel sit below the top bar, which wraps on narrow screens
  const topbarHeight = () => document.documentElement.style.setProperty('--topbar', `${$('topbar').offsetHeight}px`);
  topbarHeight();
  if (typeof ResizeObserver === 'function') new ResizeObserver(topbarHeight).observe($('topbar'));
  window.addEventListener('resize', () => { topbarHeight(); dirty = true; });
}

// ---------------------------------------------------------------- tools (poke)

// our tool: {id, shape, pos, radius, plane: {p, n}, sentAt, dirty}
let tool = null;
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
    const r = size * 0.12;
    const c = addScaled(hit.point, hit.normal, r);
    tool = { id: PUSH_ID, shape: 'sphere', pos: c, radius: r, plane: { p: c, n: viewDir }, dirty: true };
  } else {
    tool = { id: GRAB_ID, shape: 'grab', pos: hit.point, radius: size * 0.08, plane: { p: hit.point, n: viewDir }, dirty: true };
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
  dirty = true;
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
  const step = -Math.sign(dy) * size * 0.02;
  const n = normalize(tool.plane.n);
  tool.plane.p = addScaled(tool.plane.p, n, -step);
  tool.pos = addScaled(tool.pos, n, -step);
  tool.dirty = true;
  dirty = true;
  scheduleFlush();
  return true;
}

function toolMessage(active) {
  const m = { type: 'tool', id: tool.id, shape: tool.shape, pos: tool.pos.map((v) => Math.fround(v)), active };
  m.radius = tool.radius;
  return m;
}

function flushTool(force) {
  if (!tool || !tool.dirty) return;
  const now = performance.now();
  if (!force && now - (tool.sentAt || 0) < TOOL_SEND_MS) return;
  if (link.send(toolMessage(true))) {
    tool.sentAt = now;
    tool.dirty = false;
    sentPoses.push({ t: now, id: tool.id, pos: tool.pos.map((v) => Math.fround(v)) });
    if (sentPoses.length > 64) sentPoses.shift();
  }
}

function endTool(send) {
  if (!tool) return;
  if (send) link.send(toolMessage(false));
  // the user found out how to poke: the hint has done its job
  dismissHint();
  tool = null;
  dirty = true;
}

// tool-to-frame latency: time from sending a pose to the first frame that carries it
const latencySamples = [];
function measureLatency(tools) {
  if (!sentPoses.length) return;
  for (const t of tools) {
    for (let i = sentPoses.length - 1; i >= 0; i--) {
      const s = sentPoses[i];
      if (s.id !== t.id) continue;
      const tol = 1e-6 * Math.max(1, size);
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

function wireInput() {
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
      dirty = true;
      return;
    }
    if (!last) return;
    const dx = x - last[0], dy = y - last[1];
    last = [x, y];
    if (mode === 'orbit') { camera.orbit(dx, dy); dirty = true; }
    else if (mode === 'pan') { camera.pan(dx, dy, h); dirty = true; }
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
    dirty = true;
  }, { passive: false });
}

// ---------------------------------------------------------------- drawing

// arrow length: grows with the force and saturates, so small and large forces both read
let peakForce = 0.01;
function arrowScale(f) {
  if (!(f > 1e-6)) return 0;
  peakForce = Math.max(peakForce * 0.999, f);
  return size * 0.6 * (f / (f + peakForce * 0.5));
}

let lastLoopAt = 0;
function frameLoop() {
  requestAnimationFrame(frameLoop);
  const loopAt = performance.now();
  // time during which something was waiting to be drawn (counts towards the picture check)
  if (dirty && lastLoopAt) pictures.busyMs += Math.min(loopAt - lastLoopAt, 1000);
  lastLoopAt = loopAt;
  flushTool(false);
  if (opts.nodes && app.lastFrame !== nodesFrame && !nodesPending) { nodesFrame = app.lastFrame; requestNodes(); }
  if (!renderer || !dirty) return;
  const t0 = performance.now();
  if (maxFps && t0 - lastDrawAt < 1000 / maxFps - 2) return;
  lastDrawAt = t0;
  dirty = false;
  pictures.count++;
  if (app.debugDrawDelayMs > 0) { const until = t0 + app.debugDrawDelayMs; while (performance.now() < until) { /* a slow machine */ } }
  for (const b of app.bodies.values()) {
    if (b.gpuDirty && b.pos) { renderer.updateBody(b.id, b.pos, b.levelArr); b.gpuDirty = false; }
  }
  const [w, h] = renderer.resize();
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
  renderer.draw({ vp: camera.viewProj(), eye: camera.eye(), target: camera.target, useLevels: opts.useLevels,
    wire: opts.wire, nodes: opts.nodes, floor: opts.floor, tools, arrowScale, arrowWidth: size * 0.012,
    grabMarker: size * 0.015, pointSize: Math.max(3, 4 * (window.devicePixelRatio || 1)) });
  drawLabels(tools, w, h);
  const dt = performance.now() - t0;
  app.drawMs = app.drawMs === undefined ? dt : app.drawMs * 0.9 + dt * 0.1;
}
let nodesFrame = -1;
let maxFps = 0;
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
        ring.style.borderColor = palette.probe || FALLBACK_PALETTE.probe;
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
app.levelColor = (i) => hexToRgb(palette.level[Math.min(i, palette.level.length - 1)]).map((v) => Math.round(v * 255));
app.backgroundColor = () => hexToRgb(palette.background).map((v) => Math.round(v * 255));

start();
