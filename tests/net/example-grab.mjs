#!/usr/bin/env node
// example-grab.mjs - open a scene, grab the top of the first body, pull it up, print the force.
//
//   node tests/net/example-grab.mjs [ws://127.0.0.1:8080/ws] [scene] [lift_m]
//
// Start a server first (`make run`, or `squish serve`). With `squish serve --lockstep` the
// script steps the simulation itself (10 frames per pull), else it lets the clock run 0.1 s.
// Uses the client library web/squish-client.js (in Node 20 it needs the npm package ws:
// `make node-deps` in a squish checkout).
import { SquishClient } from '../../web/squish-client.js';

const url = process.argv[2] || 'ws://127.0.0.1:8080/ws';
const lift = Number(process.argv[4] || 0.1);
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

const c = await SquishClient.connect(url, { client: 'example-grab', role: 'control' });
const scene = process.argv[3] || (c.welcome.scenes.includes('paper-cube') ? 'paper-cube' : c.welcome.scenes[0]);
const opened = await c.open(scene);
console.log(`opened scene "${scene}" as session ${opened.session}: ${opened.bodies.length} body(ies), ` +
  `${opened.bodies[0].surface.vertices} surface vertices, ${opened.frame_rate} Hz` +
  `${c.welcome.lockstep ? ', lockstep' : ''}`);

// grab point: the highest rest surface vertex nearest to the body's centre (in x, y)
const rest = c.bodies.get(0).rest;
let cx = 0, cy = 0, zmax = -Infinity;
const n = rest.length / 3;
for (let i = 0; i < n; i++) { cx += rest[3 * i] / n; cy += rest[3 * i + 1] / n; zmax = Math.max(zmax, rest[3 * i + 2]); }
let best = 0, bestD = Infinity;
for (let i = 0; i < n; i++) {
  const d = Math.hypot(rest[3 * i] - cx, rest[3 * i + 1] - cy) + 10 * (zmax - rest[3 * i + 2]);
  if (d < bestD) { bestD = d; best = i; }
}
const p = [rest[3 * best], rest[3 * best + 1], rest[3 * best + 2]];
console.log(`grabbing vertex ${best} at [${p.map((v) => v.toFixed(3)).join(', ')}]`);
await c.tool({ id: 1, shape: 'grab', pos: p, radius: 0.1, active: true });

// pull up in 10 steps, reading the feedback force after each
for (let k = 1; k <= 10; k++) {
  const z = p[2] + lift * k / 10;
  await c.tool({ id: 1, pos: [p[0], p[1], z] });
  if (c.welcome.lockstep) await c.step(10);
  else await sleep(100);
  const s = await c.stats();
  const fb = s.feedback.find((f) => f.tool === 1 && f.body === 0);
  const f = fb ? fb.force : [0, 0, 0];
  const v = c.frames.get(0).positions;
  console.log(`lift ${(z - p[2]).toFixed(3)} m: force [${f.map((x) => x.toFixed(2)).join(', ')}] N ` +
    `(|F| = ${Math.hypot(...f).toFixed(2)} N, ${fb ? fb.nodes : 0} nodes held), vertex z ${v[3 * best + 2].toFixed(3)} m, ` +
    `frame ${s.frame}`);
}
await c.tool({ id: 1, active: false });
console.log('released');
await c.close();
