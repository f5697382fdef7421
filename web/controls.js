// controls.js - the controls: the setting forms (material, damping, operator, level of detail)
// sent with set and their refusals or acks shown next to them, Pause/Resume, Reset, display
// toggles, large text, the help, and the panel's buttons (wireUi).

import { app, view, opts, $ } from './state.js';
import { showEvent } from './hud.js';
import { dismissHint, cancelHold } from './firstvisit.js';

// fill the setting forms from what the server says about a body (when it says it)
export function fillControls(b) {
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
  view.link.send(m);
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

export function togglePause() {
  if (app.role !== 'control' || !app.session) return;
  // the user decides: no automatic resume after the first-open wait
  cancelHold();
  const next = !app.paused;
  view.link.send({ type: next ? 'pause' : 'resume' });
}

export function resetBodies() {
  if (app.role !== 'control' || !app.session) return;
  view.link.send({ type: 'reset' });
}

export function setLarge(on) {
  document.documentElement.classList.toggle('large', on);
  $('btn-large').setAttribute('aria-pressed', String(on));
  view.dirty = true;
}

export function toggleOpt(key, checkbox) {
  opts[key] = !opts[key];
  $(checkbox).checked = opts[key];
  if (key === 'nodes') requestNodes();
  view.dirty = true;
}

let nodesAskedAt = 0;
export function requestNodes() {
  if (!opts.nodes || !app.welcomed || !app.session) return;
  const now = performance.now();
  if (view.nodesPending && now - nodesAskedAt < 2000) return;
  view.nodesPending = true;
  nodesAskedAt = now;
  view.link.send({ type: 'nodes', body: Number($('body-select').value || 0) });
}

export function toggleHelp(show) {
  const h = $('help');
  const on = show === undefined ? h.classList.contains('hidden') : show;
  h.classList.toggle('hidden', !on);
  if (on) $('help-card').focus();
}

// openScene and takeControl come from session.js, passed in at wiring time: the modules import
// in one direction (state < hud < firstvisit < controls < input < session, draw < main)
export function wireUi({ openScene, takeControl }) {
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
  const bind = (id, key) => $(id).addEventListener('change', () => { opts[key] = $(id).checked; if (key === 'nodes') requestNodes(); view.dirty = true; });
  bind('opt-levels', 'useLevels');
  bind('opt-wire', 'wire');
  bind('opt-nodes', 'nodes');
  bind('opt-floor', 'floor');
  $('body-select').addEventListener('change', () => {
    const b = app.bodies.get(Number($('body-select').value));
    if (b) fillControls(b.info);
  });

  // the overlays and the panel sit below the top bar, which wraps on narrow screens
  const topbarHeight = () => document.documentElement.style.setProperty('--topbar', `${$('topbar').offsetHeight}px`);
  topbarHeight();
  if (typeof ResizeObserver === 'function') new ResizeObserver(topbarHeight).observe($('topbar'));
  window.addEventListener('resize', () => { topbarHeight(); view.dirty = true; });
}

// a refused setting (an error answering a set): its reason in red next to its form, which
// opens; false when the error answers no setting sent from here
export function showRefusal(ref, text) {
  const p = pendingSets.get(ref);
  if (p) {
    pendingSets.delete(p.ref);
    clearTimeout(p.timer);
    const el = $(`err-${p.group}`);
    el.className = 'err';
    el.textContent = text;
    const group = el.closest('details');
    if (group) group.open = true;
    return true;
  }
  return false;
}

// a set's ack carries the settings now in force: the forms show them
export function onSetAck(m) {
  const p = pendingSets.get(m.ref);
  if (p) confirmSet(p);
  for (const b of m.bodies || []) {
    const body = app.bodies.get(b.id);
    if (body && b.settings) body.info.settings = b.settings;
  }
  const cur = app.bodies.get(Number($('body-select').value || 0));
  if (cur) fillControls(cur.info);
}
