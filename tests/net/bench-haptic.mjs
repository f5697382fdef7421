#!/usr/bin/env node
// bench-haptic.mjs - the haptic channel on loopback against the real server ($SQUISH, default
// build/squish): a controller presses cube-poke's top through the channel at 1 kHz (a pose
// every 1 ms, each answered by a force) while the body steps at 50 Hz and N viewers (default
// 20) watch the session. Reports pose-in to force-out round trips (p50, p99, max, on this
// client's clock: an upper bound of the server's share), and the frame CPU (stats.frame_ms
// pushed at 10 Hz) with and without the channel open, runs interleaved.
//
//   SQUISH=build/squish node tests/net/bench-haptic.mjs [--viewers 20] [--seconds 5] [--rounds 2] [--json FILE]
import { writeFileSync } from 'node:fs';
import os from 'node:os';
import { SquishClient } from './client.mjs';
import { startServer, sleep } from './harness.mjs';

const arg = (name, def) => { const i = process.argv.indexOf(name); return i > 0 ? process.argv[i + 1] : def; };
const VIEWERS = Number(arg('--viewers', 20));
const SECONDS = Number(arg('--seconds', 5));
const ROUNDS = Number(arg('--rounds', 2));
const pct = (a, p) => { const s = [...a].sort((x, y) => x - y); return s[Math.min(s.length - 1, Math.floor(p * s.length))]; };

const srv = await startServer(['--scenes', 'meshes/scenes']);
const results = { viewers: VIEWERS, seconds: SECONDS, rounds: ROUNDS, load: os.loadavg()[0] };
try {
  const c = await SquishClient.connect(srv.url);
  const o = await c.open('cube-poke');
  await c.tool({ id: 1, shape: 'sphere', pos: [0.5, 0.5, 1.3], active: false });
  await c.tool({ id: 2, shape: 'sphere', pos: [0.5, 0.5, 1.2], radius: 0.12 });
  const viewers = [];
  for (let i = 0; i < VIEWERS; i++) {
    // decode: false: the viewers share this process's event loop with the timed channel; their
    // frames are received (real WebSocket clients) but not inflated here
    const v = await SquishClient.connect(srv.url, { role: 'view', decode: false });
    await v.join(o.session, 'view');
    v.binaries = 0;
    v.on('binary', () => v.binaries++);
    viewers.push(v);
  }
  const frameMs = { open: [], closed: [] };
  let phase = 'closed';
  c.on('stats', s => { if (s.frame_ms !== undefined) frameMs[phase].push(s.frame_ms); });
  await c.subscribe({ stats: true, stats_hz: 10 });
  const rtt = [];
  let answered = 0, sent = 0;
  for (let round = 0; round < ROUNDS; round++) {
    // without the channel: the tool pressed by tool requests at 50 Hz (same motion)
    phase = 'closed';
    const t0 = performance.now();
    while (performance.now() - t0 < SECONDS * 1000) {
      const t = (performance.now() - t0) / 1000;
      await c.tool({ id: 2, pos: [0.5, 0.5, 1.2 - 0.13 * (0.5 - 0.5 * Math.cos(2 * Math.PI * t / 2.5))] });
      await sleep(20);
    }
    // with it: a pose every 1 ms, the next one sent when its time has come and the last is answered
    const { channel } = await c.hapticOpen(2);
    phase = 'open';
    const t1 = performance.now();
    let next = t1;
    while (performance.now() - t1 < SECONDS * 1000) {
      const now = performance.now();
      if (now < next) { await new Promise(r => setImmediate(r)); continue; }
      next = Math.max(next + 1, now + 0.5); // late: no catch-up burst past the channel's rate
      const t = (now - t1) / 1000;
      const a = performance.now();
      sent++;
      await c.haptic(channel, [0.5, 0.5, 1.2 - 0.13 * (0.5 - 0.5 * Math.cos(2 * Math.PI * t / 2.5))], t);
      rtt.push(performance.now() - a);
      answered++;
    }
    await c.hapticClose(2);
  }
  const st = await c.stats();
  results.poses = sent;
  results.answered = answered;
  results.rate_hz = +(answered / (ROUNDS * SECONDS)).toFixed(1);
  results.rtt_ms = { p50: +pct(rtt, 0.5).toFixed(3), p99: +pct(rtt, 0.99).toFixed(3), max: +Math.max(...rtt).toFixed(3) };
  const fm = (a) => ({ n: a.length, p50: +pct(a, 0.5).toFixed(2), p95: +pct(a, 0.95).toFixed(2) });
  results.frame_cpu_ms = { channel_closed: fm(frameMs.closed), channel_open: fm(frameMs.open) };
  results.deadline_misses = st.deadline_misses;
  results.viewer_frames = viewers.map(v => v.binaries).reduce((a, b) => Math.min(a, b), Infinity);
  for (const v of viewers) await v.close();
  await c.close();
  console.log(`haptic channel, ${VIEWERS} viewers, cube-poke at 50 Hz, ${ROUNDS} x ${SECONDS} s each way, load ${results.load.toFixed(2)}:`);
  console.log(`  poses answered ${answered} of ${sent} (${results.rate_hz} per s)`);
  console.log(`  pose-in to force-out round trip: p50 ${results.rtt_ms.p50} ms, p99 ${results.rtt_ms.p99} ms, max ${results.rtt_ms.max} ms (aim p99 < 1 ms)`);
  console.log(`  frame CPU: channel closed p50 ${results.frame_cpu_ms.channel_closed.p50} ms p95 ${results.frame_cpu_ms.channel_closed.p95} ms (n ${results.frame_cpu_ms.channel_closed.n}); ` +
              `open p50 ${results.frame_cpu_ms.channel_open.p50} ms p95 ${results.frame_cpu_ms.channel_open.p95} ms (n ${results.frame_cpu_ms.channel_open.n})`);
  console.log(`  deadline misses ${results.deadline_misses}; fewest binary messages (frames) a viewer got ${results.viewer_frames}`);
  const j = arg('--json', null);
  if (j) writeFileSync(j, JSON.stringify(results, null, 2));
} finally {
  await srv.stop();
}
