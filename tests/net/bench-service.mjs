#!/usr/bin/env node
// bench-service.mjs - service benchmarks against the real server ($SQUISH, default build/squish):
//   1. bytes per surface vertex per frame while a body is poked (aim <= 2; raw float32 is 12)
//   2. tool-to-frame latency on loopback (aim: within one frame period + 5 ms)
//   3. N viewers (default 200) at 30 Hz on one session: simulation deadline misses (aim 0)
//
//   SQUISH=build/squish node tests/net/bench-service.mjs [--viewers 200] [--seconds 10] [--cells 16]
//       [--viewer-cells 12] [--json FILE]
import { mkdtempSync, writeFileSync } from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { SquishClient } from './client.mjs';
import { startServer, sleep, makeBoxScene } from './harness.mjs';

const arg = (name, def) => { const i = process.argv.indexOf(name); return i > 0 ? process.argv[i + 1] : def; };
const VIEWERS = Number(arg('--viewers', 200));
const SECONDS = Number(arg('--seconds', 10));
const CELLS = Number(arg('--cells', 16));        // body of parts 1 and 2
const VCELLS = Number(arg('--viewer-cells', 12)); // body of part 3 (keeps the sim within budget)
const results = {};
const pct = (a, p) => { const s = [...a].sort((x, y) => x - y); return s[Math.min(s.length - 1, Math.floor(p * s.length))]; };

const dir = mkdtempSync(path.join(os.tmpdir(), 'squish-bench-'));
await makeBoxScene(dir, 'box', CELLS, { frameRate: 50 });
await makeBoxScene(dir, 'box30hz', VCELLS, { frameRate: 30 });
const srv = await startServer(['--scenes', dir, '--max-clients', String(VIEWERS + 8)]);

/** a controller that pokes: grab the top centre and move it up and down (period ~1.2 s) */
async function poke(c, ms) {
  await c.tool({ id: 1, shape: 'grab', pos: [0.5, 0.5, 1.0], radius: 0.25 });
  const t0 = Date.now();
  while (Date.now() - t0 < ms) {
    const ph = (Date.now() - t0) / 1200 * 2 * Math.PI;
    await c.tool({ id: 1, pos: [0.5 + 0.1 * Math.sin(ph / 2), 0.5, 1.0 + 0.15 * (1 - Math.cos(ph)) / 2] });
    await sleep(20);
  }
}

try {
  // 1. bytes per surface vertex per frame
  {
    const c = await SquishClient.connect(srv.url);
    const o = await c.open('box');
    const nsurf = o.bodies[0].surface.vertices;
    const sizes = [];
    c.on('frame', f => sizes.push(f.bytes));
    await poke(c, 3000);
    await c.close();
    const mean = sizes.reduce((a, b) => a + b, 0) / sizes.length;
    results.bytes_per_vertex = {
      surface_vertices: nsurf, frames: sizes.length, mean_frame_bytes: Math.round(mean),
      bytes_per_vertex: +(mean / nsurf).toFixed(3), max_bytes_per_vertex: +(Math.max(...sizes) / nsurf).toFixed(3),
      raw_float32: 12,
    };
  }
  // 2. tool-to-frame latency
  {
    const c = await SquishClient.connect(srv.url);
    const o = await c.open('box');
    const period = 1000 / o.frame_rate;
    await c.tool({ id: 1, shape: 'sphere', pos: [0.5, 0.5, 2.0], radius: 0.05 });
    await sleep(200);
    const lat = [];
    for (let k = 0; k < 100; k++) {
      const z = 2.0 + 0.001 * (k + 1);
      const seen = c.waitFor(f => f.tools.some(t => t.id === 1 && Math.abs(t.pos[2] - z) < 1e-5), 2000, 'frame');
      const t0 = performance.now();
      c.sendRaw(JSON.stringify({ type: 'tool', id: 1, pos: [0.5, 0.5, z] }));
      await seen;
      lat.push(performance.now() - t0);
      await sleep(Math.random() * period);
    }
    await c.close();
    results.tool_to_frame_ms = {
      samples: lat.length, frame_period_ms: period, p50: +pct(lat, 0.5).toFixed(2), p95: +pct(lat, 0.95).toFixed(2),
      max: +Math.max(...lat).toFixed(2), aim_ms: period + 5, within_aim: lat.filter(x => x <= period + 5).length,
    };
  }
  // 3. N viewers at 30 Hz
  {
    const ctl = await SquishClient.connect(srv.url);
    const o = await ctl.open('box30hz');
    // baseline: the same session and poking without viewers (misses caused by the machine)
    const b0 = await ctl.stats();
    await poke(ctl, SECONDS * 500);
    const b1 = await ctl.stats();
    const viewers = [];
    for (let i = 0; i < VIEWERS; i += 50)
      viewers.push(...await Promise.all(Array.from({ length: Math.min(50, VIEWERS - i) }, () =>
        SquishClient.connect(srv.url, { role: 'view', decode: false }))));
    await Promise.all(viewers.map(v => v.join(o.session)));
    const counts = new Array(viewers.length).fill(0);
    viewers.forEach((v, i) => v.on('binary', () => { counts[i]++; }));
    await sleep(500);
    counts.fill(0);
    const s0 = await ctl.stats();
    await poke(ctl, SECONDS * 1000);
    const s1 = await ctl.stats();
    const frames = s1.frame - s0.frame;
    const skipped = await Promise.all(viewers.slice(0, 10).map(v => v.stats().then(s => s.skipped)));
    results.viewers = {
      viewers: s1.viewers, seconds: SECONDS, frame_rate: o.frame_rate, frames_simulated: frames,
      deadline_misses: s1.deadline_misses - s0.deadline_misses,
      overruns: s1.overruns - s0.overruns,
      baseline_no_viewers: { seconds: SECONDS / 2, frames_simulated: b1.frame - b0.frame,
        deadline_misses: b1.deadline_misses - b0.deadline_misses, overruns: b1.overruns - b0.overruns },
      frames_per_viewer_min: Math.min(...counts), frames_per_viewer_mean: +(counts.reduce((a, b) => a + b, 0) / counts.length).toFixed(1),
      skipped_first10: skipped, budget_used_last: +s1.budget_used.toFixed(3),
      server_bytes_per_s: Math.round((s1.bytes_sent - s0.bytes_sent) / SECONDS),
    };
    await Promise.all([...viewers, ctl].map(c => c.close()));
  }
} finally {
  await srv.stop();
}
results.load_average = os.loadavg().map(x => +x.toFixed(2));
results.cpus = os.cpus().length;
console.log(JSON.stringify(results, null, 2));
const out = arg('--json', null);
if (out) writeFileSync(out, JSON.stringify(results, null, 2));
