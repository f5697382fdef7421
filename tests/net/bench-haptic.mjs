#!/usr/bin/env node
// bench-haptic.mjs - the haptic channel on loopback against the real server ($SQUISH, default
// build/squish): a controller presses cube-poke's top through the channel at 1 kHz (a pose
// every 1 ms, each answered by a force) while the body steps at 50 Hz and N viewers (default
// 20) watch the session. Reports pose-in to force-out round trips (p50, p99, max, on this
// client's clock), the server's own share of them (stats.haptic.channels[].latency: pose read
// to force written, on the server's clock), and the frame CPU (stats.frame_ms pushed at 10 Hz)
// with and without the channel open, runs interleaved.
//
// --method apart (the default): the viewers and the stats watcher run in a process of their
// own (bench-viewers.mjs); this process is the device alone, and it sleeps between poses
// (Atomics.wait) instead of spinning, so it neither delays its own reads nor takes a core from
// the server. --method shared: the first form of this bench, kept for comparison: the viewers
// in this process's event loop (their frames received, not inflated), the stats on the
// device's own connection, the device spinning on setImmediate between poses; there the round
// trip's tail includes this client's reading of the viewers' frames, not the server's only.
//
//   SQUISH=build/squish node tests/net/bench-haptic.mjs [--viewers 20] [--seconds 5] [--rounds 2]
//        [--method apart|shared] [--io-priority N] [--json FILE]
// --io-priority N is passed to the server (squish serve --io-priority: its service thread
// SCHED_FIFO at N); without it the server runs at normal priority.
import { writeFileSync } from 'node:fs';
import { fork } from 'node:child_process';
import os from 'node:os';
import { SquishClient } from './client.mjs';
import { startServer, sleep } from './harness.mjs';

const arg = (name, def) => { const i = process.argv.indexOf(name); return i > 0 ? process.argv[i + 1] : def; };
const VIEWERS = Number(arg('--viewers', 20));
const SECONDS = Number(arg('--seconds', 5));
const ROUNDS = Number(arg('--rounds', 2));
const METHOD = arg('--method', 'apart');
if (METHOD !== 'apart' && METHOD !== 'shared') throw new Error(`--method ${METHOD}: use apart or shared`);
const pct = (a, p) => { const s = [...a].sort((x, y) => x - y); return s[Math.min(s.length - 1, Math.floor(p * s.length))]; };
const mono = () => Number(process.hrtime.bigint()) / 1e9; // CLOCK_MONOTONIC, the server's clock
const nap = new Int32Array(new SharedArrayBuffer(4));
const sleepMs = (ms) => { if (ms > 0) Atomics.wait(nap, 0, 0, ms); };
const depth = (t) => 1.2 - 0.13 * (0.5 - 0.5 * Math.cos(2 * Math.PI * t / 2.5));

const IO_PRIORITY = arg('--io-priority', null);
const srv = await startServer(['--scenes', 'meshes/scenes', ...(IO_PRIORITY ? ['--io-priority', IO_PRIORITY] : [])]);
const results = { method: METHOD, io_priority: IO_PRIORITY ? Number(IO_PRIORITY) : 0, viewers: VIEWERS, seconds: SECONDS, rounds: ROUNDS, load: os.loadavg()[0] };
let child = null;
try {
  const c = await SquishClient.connect(srv.url);
  const o = await c.open('cube-poke');
  await c.tool({ id: 1, shape: 'sphere', pos: [0.5, 0.5, 1.3], active: false });
  await c.tool({ id: 2, shape: 'sphere', pos: [0.5, 0.5, 1.2], radius: 0.12 });
  const viewers = [];
  let frameMs = { open: [], closed: [] }, frameCpu = { open: [], closed: [] };
  let phase = 'closed';
  const setPhase = (p) => { phase = p; if (child) child.send({ phase: p }); };
  if (METHOD === 'shared') {
    for (let i = 0; i < VIEWERS; i++) {
      const v = await SquishClient.connect(srv.url, { role: 'view', decode: false });
      await v.join(o.session, 'view');
      v.binaries = 0;
      v.on('binary', () => v.binaries++);
      viewers.push(v);
    }
    c.on('stats', s => { if (s.frame_ms !== undefined) { frameMs[phase].push(s.frame_ms); frameCpu[phase].push(s.frame_cpu_ms ?? NaN); } });
    await c.subscribe({ stats: true, stats_hz: 10 });
  } else {
    child = fork(new URL('./bench-viewers.mjs', import.meta.url));
    const ready = new Promise((res, rej) => { child.once('message', res); child.once('exit', rej); });
    child.send({ url: srv.url, session: o.session, viewers: VIEWERS });
    await ready;
    await c.subscribe({ frames: false });
  }
  const rtt = [];
  const server = { p50: [], p99: [], max: [] };
  let answered = 0, sent = 0;
  const modelMs = []; // the session thread's CPU for the last frame's haptic model, per round
  for (let round = 0; round < ROUNDS; round++) {
    // without the channel: the tool pressed by tool requests at 50 Hz (same motion)
    setPhase('closed');
    const t0 = performance.now();
    while (performance.now() - t0 < SECONDS * 1000) {
      await c.tool({ id: 2, pos: [0.5, 0.5, depth((performance.now() - t0) / 1000)] });
      await sleep(20);
    }
    // with it: a pose every 1 ms, the next one sent when its time has come and the last is answered
    const { channel } = await c.hapticOpen(2);
    setPhase('open');
    const t1 = performance.now();
    let next = t1;
    while (performance.now() - t1 < SECONDS * 1000) {
      let now = performance.now();
      if (now < next) {
        if (METHOD === 'shared') { await new Promise(r => setImmediate(r)); continue; }
        sleepMs(next - now);
        now = performance.now();
      }
      next = Math.max(next + 1, now + 0.5); // late: no catch-up burst past the channel's rate
      const a = performance.now();
      sent++;
      await c.haptic(channel, [0.5, 0.5, depth((now - t1) / 1000)], mono());
      rtt.push(performance.now() - a);
      answered++;
    }
    const st = await c.stats();
    const ch = (st.haptic?.channels || []).find(x => x.channel === channel);
    if (ch?.latency) for (const k of ['p50', 'p99', 'max']) server[k].push(ch.latency[k]);
    if (st.haptic?.model_ms !== undefined) modelMs.push(st.haptic.model_ms);
    await c.hapticClose(2);
  }
  const st = await c.stats();
  results.poses = sent;
  results.answered = answered;
  results.rate_hz = +(answered / (ROUNDS * SECONDS)).toFixed(1);
  results.rtt_ms = { p50: +pct(rtt, 0.5).toFixed(3), p99: +pct(rtt, 0.99).toFixed(3), max: +Math.max(...rtt).toFixed(3) };
  if (server.p50.length) // per round; the worst round's
    results.server_ms = { p50: +Math.max(...server.p50).toFixed(3), p99: +Math.max(...server.p99).toFixed(3), max: +Math.max(...server.max).toFixed(3) };
  results.deadline_misses = st.deadline_misses;
  if (modelMs.length) results.model_ms = modelMs;
  if (child) {
    const done = new Promise(res => child.once('message', res));
    child.send({ stop: true });
    const r = await done;
    frameMs = { open: r.frameMs.open || [], closed: r.frameMs.closed || [] };
    frameCpu = { open: r.frameCpu.open || [], closed: r.frameCpu.closed || [] };
    results.viewer_frames = r.viewerFrames;
  } else {
    results.viewer_frames = viewers.map(v => v.binaries).reduce((a, b) => Math.min(a, b), Infinity);
    for (const v of viewers) await v.close();
  }
  // (an old server's frames have no frame_cpu_ms: null through the child's IPC, NaN here)
  const fm = (a) => { a = a.filter(Number.isFinite); return a.length ? { n: a.length, p50: +pct(a, 0.5).toFixed(2), p95: +pct(a, 0.95).toFixed(2) } : { n: 0, p50: null, p95: null }; };
  // frame_ms: the frame's wall time (what a viewer waits for); frame_cpu_ms: its session
  // thread's CPU time (what it cost; an old server without it gives NaN)
  results.frame_wall_ms = { channel_closed: fm(frameMs.closed), channel_open: fm(frameMs.open) };
  results.frame_cpu_ms = { channel_closed: fm(frameCpu.closed), channel_open: fm(frameCpu.open) };
  await c.close();
  console.log(`haptic channel, ${VIEWERS} viewers (${METHOD === 'apart' ? 'in a process of their own' : 'in the device\'s process'}), ` +
              `cube-poke at 50 Hz, ${ROUNDS} x ${SECONDS} s each way, ` +
              `${IO_PRIORITY ? `server --io-priority ${IO_PRIORITY}, ` : ''}load ${results.load.toFixed(2)}:`);
  console.log(`  poses answered ${answered} of ${sent} (${results.rate_hz} per s)`);
  console.log(`  pose-in to force-out round trip: p50 ${results.rtt_ms.p50} ms, p99 ${results.rtt_ms.p99} ms, max ${results.rtt_ms.max} ms (aim p99 < 1 ms)`);
  if (results.server_ms)
    console.log(`  the server's share (pose read to force written, worst round): p50 ${results.server_ms.p50} ms, p99 ${results.server_ms.p99} ms, max ${results.server_ms.max} ms`);
  for (const [name, f] of [['wall', results.frame_wall_ms], ['CPU', results.frame_cpu_ms]])
    console.log(`  frame ${name}: channel closed p50 ${f.channel_closed.p50} ms p95 ${f.channel_closed.p95} ms (n ${f.channel_closed.n}); ` +
                `open p50 ${f.channel_open.p50} ms p95 ${f.channel_open.p95} ms (n ${f.channel_open.n})`);
  if (results.model_ms) console.log(`  the haptic model's CPU after a frame (one per round, after the frame is published): ${results.model_ms.map(x => x.toFixed(3)).join(', ')} ms`);
  console.log(`  deadline misses ${results.deadline_misses}; fewest binary messages (frames) a viewer got ${results.viewer_frames}`);
  const j = arg('--json', null);
  if (j) writeFileSync(j, JSON.stringify(results, null, 2));
} finally {
  if (child && child.exitCode === null) child.kill();
  await srv.stop();
}
