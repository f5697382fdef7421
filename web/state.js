// state.js - the viewer's shared state: `app` (also window.squish, the automation object of
// docs/viewer.md), the page-internal `view` (renderer, link, redraw flag, ...), the display
// options, the camera and the constants every module uses. Imports no other viewer module.

import { OrbitCamera } from './camera.js';

// the shared palette (web/palette.json); these values are its fallback copy
export const FALLBACK_PALETTE = {
  level: ['#4e79a7', '#59a14f', '#edc948', '#f28e2b', '#e15759', '#b07aa1'],
  plain: '#d9a38c', background: '#20242b', floor: '#5b6270', floor_line: '#737b8a', tool: '#c8ccd4',
  probe: '#ff3ea5',
  obstacle: '#9a948a',
};

// our own tool ids (scripted scene tools use small ids from 0)
export const GRAB_ID = 6;
export const PUSH_ID = 7;
// tool poses are sent at most this often (the server also limits commands per second)
export const TOOL_SEND_MS = 33;
// stats are polled at this period when the server does not push them
export const STATS_POLL_MS = 500;
// recent frame checksums kept for comparisons between pages
export const FRAME_LOG = 600;

export const $ = (id) => document.getElementById(id);
export const params = new URLSearchParams(location.search);

/** the whole viewer state; also exposed as window.squish for automation (see docs/viewer.md) */
export const app = {
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
  obstacles: [],         // the scene's obstacles (opened/joined "obstacles")
  obstacleOffsets: new Map(), // name -> [x, y, z] translation from its placement (moving ones)
  obstacleMessages: 0,   // "obstacles" messages received
  obstaclesDrawn: 0,     // obstacles drawn in the last picture (planes included)
};
window.squish = app;

export const opts = { useLevels: true, wire: false, nodes: false, floor: true };
export const camera = new OrbitCamera();

/** the page's own mutable state, shared by the modules (not part of window.squish) */
export const view = {
  renderer: null,
  palette: FALLBACK_PALETTE,
  dirty: true,           // something changed: the next animation frame draws a picture
  size: 1,               // size of the rest bounding box of all bodies (m)
  link: null,            // the WebSocket link (net.js), also app.link
  userScale: false,      // the resolution was chosen in the address: never lowered automatically
  maxFps: 0,             // ?fps=N: at most N pictures per second (0: no limit)
  peakForce: 0.01,       // recent largest tool force, for the arrow length
  nodesPending: false,   // active-node points asked for and not yet received
};
