// session.js - the session: connection state, welcome, join/open of a scene, the server's text
// messages (opened/joined, errors, acks, events, control hand-over, roles) and its binary
// messages (topology, frames, active nodes) applied to the bodies. Protocol v1
// (docs/protocol.md) with `squish serve` over /ws.

import { KIND_TOPOLOGY, KIND_FRAME, KIND_NODES } from './codec.js';
import { sub, len } from './camera.js';
import { app, view, camera, $, GRAB_ID, PUSH_ID, FRAME_LOG } from './state.js';
import { setNotice, showEvent, setPaused, buildLegend, updateLegendFromFrame, onStats, frameCounter } from './hud.js';
import { holdScript, showSceneInfo, showHint } from './firstvisit.js';
import { fillControls, showRefusal, onSetAck } from './controls.js';
import { tool, endTool, measureLatency } from './input.js';

// the camera was fitted to this scene: a re-join of the same scene keeps the user's camera
let fitted = false;
let fittedScene = null;

export function hello() {
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

export function onLinkStatus(state, detail) {
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
    view.link.send({ type: 'join', session: Number(app.session), role: app.role, ref: 'join' });
  } else if (app.role === 'control') {
    openScene(app.scene);
  } else {
    setNotice('nosession', 'No session to watch: ask the controller for the share link, or open this page without role=view to start your own session.');
  }
}

// without a scene in the address: the paper's cube when the server has it, else the first
const PREFERRED_SCENES = ['paper-cube', 'default'];

export function openScene(name) {
  const pref = PREFERRED_SCENES.find((n) => app.scenes.some((s) => s.name === n));
  const scene = name || pref || (app.scenes[0] && app.scenes[0].name);
  if (!scene) { showEvent('the server lists no scenes', true); return; }
  app.scene = scene;
  app.session = null;
  view.link.send({ type: 'open', scene, ref: 'open' });
}

// ---------------------------------------------------------------- text messages

export function onMessage(m) {
  switch (m.type) {
    case 'welcome':
      app.welcomed = true;
      if (m.role === 'view' || m.role === 'control') setRole(m.role);
      view.link.resetBackoff();
      setStatus('connected', 'connected');
      if (Array.isArray(m.scenes)) setScenes(m.scenes);
      view.link.send({ type: 'list_scenes' });
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
      if (Array.isArray(m.obstacles)) setObstacleOffsets(m.obstacles);
      break;
    case 'obstacles':
      app.obstacleMessages++;
      if (Array.isArray(m.obstacles)) setObstacleOffsets(m.obstacles);
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
  view.link.send({ type: 'subscribe', stats: true, stats_hz: 4 });
  // a tool of ours left active by a dropped connection is released
  if (app.role === 'control' && Array.isArray(m.tools)) {
    for (const t of m.tools) {
      if ((t.id === GRAB_ID || t.id === PUSH_ID) && t.active && !(tool && tool.id === t.id)) {
        view.link.send({ type: 'tool', id: t.id, active: false });
      }
    }
  }
  view.renderer && view.renderer.clearBodies();
  app.bodies.clear();
  app.obstacles = Array.isArray(m.obstacles) ? m.obstacles : [];
  app.obstacleOffsets = new Map();
  // nothing of the previous scene stays in the panel
  $('hud-force').textContent = '-';
  $('hud-contact').textContent = '-';
  view.peakForce = 0.01;
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
  view.nodesPending = false;
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
  view.dirty = true;
}


export function takeControl() {
  const m = { type: 'take_control', ref: 'take' };
  if (app.token) m.token = app.token;
  view.link.send(m);
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
  // a refused setting: its reason goes next to its form
  if (showRefusal(m.ref, text)) return;
  showEvent(text, true);
}

// an ack confirms a request; a set's ack carries the settings now in force
function onAck(m) {
  if (m.request === 'set') {
    onSetAck(m);
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

export function setRole(role) {
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
  if (view.renderer) view.renderer.setBody(body.id, msg.rest, msg.tris);
}

export function onBinary(msg) {
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
    view.dirty = true;
  } else if (h.kind === KIND_NODES) {
    if (view.renderer) view.renderer.setNodes(msg.pos, msg.levels);
    app.nodesShown = msg.levels.length;
    view.nodesPending = false;
    view.dirty = true;
  }
}

function firstBodyId() {
  const it = app.bodies.keys().next();
  return it.done ? -1 : it.value;
}

// moving obstacles' translations ([{name, offset}] of an "obstacles" message or stats; the
// offsets of obstacles opened/joined marks as not moving are always zero and left out)
function setObstacleOffsets(list) {
  const moving = new Set(app.obstacles.filter((o) => o && o.moving).map((o) => o.name));
  for (const o of list) {
    if (o && moving.has(o.name) && Array.isArray(o.offset) && o.offset.length === 3 && o.offset.every(Number.isFinite))
      app.obstacleOffsets.set(o.name, o.offset);
  }
  view.dirty = true;
}

// camera, floor and obstacles from the rest bounding box of all bodies
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
  if (!(min[0] <= max[0])) {
    if (view.renderer) view.renderer.setObstacles(app.obstacles, [0, 0, 0], 1);
    return;
  }
  view.size = Math.max(len(sub(max, min)), 1e-3);
  app.bounds = { min, max };
  if (!fitted) { camera.fit(min, max); fitted = true; }
  if (view.renderer) view.renderer.setFloor(min[2] - view.size * 0.002, (min[0] + max[0]) / 2, (min[1] + max[1]) / 2, view.size * 1.2);
  // a plane obstacle (the floor) as a square around the bodies' centre, larger than the grid
  if (view.renderer) view.renderer.setObstacles(app.obstacles, [0, 1, 2].map((k) => (min[k] + max[k]) / 2), view.size * 1.5);
  view.dirty = true;
}
