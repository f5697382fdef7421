// firstvisit.js - the first visit: the hint at the bottom (shown once, remembered in
// localStorage), the scene's description and Replay button under the top bar, and the 2 s
// hold of a scripted scene opened by this page (docs/viewer.md, "A first visit").

import { app, view, $, params, GRAB_ID, PUSH_ID } from './state.js';
import { showEvent } from './hud.js';

// a scripted scene opened here waits a moment before its tools move, so its poke is seen
const SCRIPT_HOLD_MS = 2000;
let holdTimer = 0;
export function holdScript(m) {
  clearTimeout(holdTimer);
  holdTimer = 0;
  if (m.type !== 'opened' || app.role !== 'control' || !app.scripted || m.lockstep || m.paused) return;
  view.link.send({ type: 'pause' });
  showEvent(`the scene's scripted tools start in ${SCRIPT_HOLD_MS / 1000} s (Replay runs them again)`);
  holdTimer = setTimeout(() => { holdTimer = 0; view.link.send({ type: 'resume' }); }, SCRIPT_HOLD_MS);
}

// no automatic resume after the first-open wait (the user pressed Pause/Resume)
export function cancelHold() {
  clearTimeout(holdTimer);
  holdTimer = 0;
}

// the scene's description under the top bar; Replay when the scene has scripted tools
export function showSceneInfo(m) {
  const sc = app.scenes.find((s) => s.name === app.scene);
  $('scene-desc').textContent = sc && sc.description ? sc.description : (app.scene || '');
  const scripted = Array.isArray(m.tools) && m.tools.some((t) => t.id !== GRAB_ID && t.id !== PUSH_ID);
  app.scripted = scripted;
  $('btn-replay').hidden = !scripted;
}

const HINT_KEY = 'squish.hint.v1';
function hintSeen() {
  try { return localStorage.getItem(HINT_KEY) === 'seen'; } catch (e) { return false; }
}
export function showHint() {
  if (hintSeen() || params.get('hint') === '0') return;
  $('hint-text').textContent = app.role === 'control'
    ? 'Drag on the body to pull it. Shift + drag to push it. Drag elsewhere to turn the view, wheel to zoom. ? lists every key.'
    : 'You are watching: drag to turn the view, wheel to zoom. ? lists every key.';
  $('hint').hidden = false;
}
export function dismissHint() {
  if ($('hint').hidden) return;
  $('hint').hidden = true;
  try { localStorage.setItem(HINT_KEY, 'seen'); } catch (e) { /* private mode: shown again next time */ }
}
