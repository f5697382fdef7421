#!/usr/bin/env node
// bench-capacity.mjs - how far one `squish serve` goes: N sessions of a shipped scene, each
// with a controller that pokes (a grab moved every 33 ms) and V viewers, for S seconds. The
// server's own CPU time (/proc/PID/stat, so other load on the machine does not count) gives
// the cores one session and one viewer cost; frames and deadline misses come from `stats`.
//
//   SQUISH=build/squish node tests/net/bench-capacity.mjs [--scene cube-poke] [--sessions 1,4]
//       [--viewers 0,50] [--seconds 10] [--grab x,y,z,radius] [--json FILE]
// Prints one line per (sessions, viewers) pair and the load average. See docs/deploy.md.
import { readFileSync, writeFileSync } from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { SquishClient } from './client.mjs';
import { startServer, sleep, ROOT } from './harness.mjs';

const arg = (name, def) => { const i = process.argv.indexOf(name); return i > 0 ? process.argv[i + 1] : def; };
const SCENE = arg('--scene', 'cube-poke');
const SESSIONS = arg('--sessions', '1,4').split(',').map(Number);
const VIEWERS = arg('--viewers', '0,50').split(',').map(Number);
const SECONDS = Number(arg('--seconds', 10));
// where the controllers grab (x,y,z,radius; the top centre of the body) and how far they pull
// (0.6 radius up and down): defaults for the shipped scenes
const GRABS = { 'cube-poke': [0.5, 0.5, 1.0, 0.25], organ: [0.136, 0.096, 0.12, 0.04] };
const GRAB = (arg('--grab', null) || (GRABS[SCENE] || GRABS['cube-poke']).join(',')).split(',').map(Number);
const TICK = 100; // USER_HZ: /proc/PID/stat counts CPU time in 1/100 s on Linux
const cpuSeconds = pid => {
  const f = readFileSync(`/proc/${pid}/stat`, 'utf8').split(') ')[1].split(' ');
  return (Number(f[11]) + Number(f[12])) / TICK; // utime + stime
};

async function run(nsessions, nviewers) {
  const srv = await startServer(['--scenes', path.join(ROOT, 'meshes/scenes'), '--max-sessions', String(Math.max(16, nsessions)),
    '--max-clients', String(nviewers + 8)]);
  const clients = [];
  const stop = { now: false };
  try {
    const ctl = [];
    for (let s = 0; s < nsessions; s++) {
      const c = await SquishClient.connect(srv.url, { decode: false });
      clients.push(c);
      const o = await c.open(SCENE);
      ctl.push({ c, id: o.session });
      for (let v = 0; v < nviewers; v++) {
        const w = await SquishClient.connect(srv.url, { role: 'view', decode: false });
        clients.push(w);
        await w.join(o.session, 'view');
      }
    }
    // every controller pokes: a grab at the top, moved up and down (period 1.2 s)
    const pokes = ctl.map(async ({ c }, i) => {
      const [gx, gy, gz, gr] = GRAB;
      await c.tool({ id: 1, shape: 'grab', pos: [gx, gy, gz], radius: gr, active: true });
      const t0 = Date.now();
      while (!stop.now) {
        const ph = ((Date.now() - t0) / 1200 + i / 7) * 2 * Math.PI;
        c.sendRaw(JSON.stringify({ type: 'tool', id: 1, pos: [gx, gy, gz + 0.6 * gr * (1 - Math.cos(ph)) / 2] }));
        await sleep(33);
      }
    });
    await sleep(1500); // warm-up
    const s0 = await Promise.all(ctl.map(({ c }) => c.request({ type: 'stats' })));
    const cpu0 = cpuSeconds(srv.pid), t0 = Date.now();
    await sleep(SECONDS * 1000);
    const cpu1 = cpuSeconds(srv.pid), t1 = Date.now();
    const s1 = await Promise.all(ctl.map(({ c }) => c.request({ type: 'stats' })));
    stop.now = true;
    await Promise.all(pokes);
    const wall = (t1 - t0) / 1000;
    const frames = s1.reduce((a, s, i) => a + s.frame - s0[i].frame, 0);
    const misses = s1.reduce((a, s, i) => a + s.deadline_misses - s0[i].deadline_misses, 0);
    const budget = s1.reduce((a, s) => a + s.budget_used, 0) / s1.length;
    return {
      scene: SCENE, sessions: nsessions, viewers_per_session: nviewers, seconds: +wall.toFixed(1),
      server_cores: +((cpu1 - cpu0) / wall).toFixed(3),
      frame_rate_per_session: +(frames / nsessions / wall).toFixed(1),
      server_cpu_ms_per_frame: +((cpu1 - cpu0) * 1000 / Math.max(1, frames)).toFixed(2),
      deadline_misses: misses, budget_used_last: +budget.toFixed(3),
      node_updates_last: s1.reduce((a, s) => a + (s.node_updates || 0), 0),
      grabbed_nodes: s1.reduce((a, s) => a + (s.feedback || []).reduce((b, f) => b + f.nodes, 0), 0),
      sleeping_bodies: s1.reduce((a, s) => a + (s.sleeping || 0), 0),
      load_average: os.loadavg().map(x => +x.toFixed(2)),
    };
  } finally {
    stop.now = true;
    for (const c of clients) { try { c.ws.terminate(); } catch (e) { /* closed */ } }
    await srv.stop();
  }
}

const results = [];
for (const n of SESSIONS) for (const v of VIEWERS) {
  const r = await run(n, v);
  results.push(r);
  console.log(JSON.stringify(r));
}
const file = arg('--json', null);
if (file) writeFileSync(file, JSON.stringify(results, null, 2));
