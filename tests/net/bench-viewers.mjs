#!/usr/bin/env node
// bench-viewers.mjs - the watching side of tests/net/bench-haptic.mjs, run in a process of
// its own (forked by it, talking over the IPC channel): N viewers join the session (real
// WebSocket clients that receive every frame, not inflated) and one more viewer takes the
// stats pushed at 10 Hz (stats.frame_ms and frame_cpu_ms), tagged with the phase the parent says.
// Kept out of the simulated device's process so that receiving 20 viewers' frames and the
// stats does not delay the device's own reads: the round trip then is the server's.
//
//   parent -> child: { url, session, viewers }, then { phase }, then { stop: true }
//   child -> parent: { ready: true }, then { frameMs: { phase: [...] }, frameCpu, viewerFrames }
import { SquishClient } from './client.mjs';

let viewers = [], stats = null, phase = 'closed';
const frameMs = {}, frameCpu = {};
process.on('message', async (m) => {
  if (m.url) {
    for (let i = 0; i < m.viewers; i++) {
      const v = await SquishClient.connect(m.url, { role: 'view', decode: false });
      await v.join(m.session, 'view');
      v.binaries = 0;
      v.on('binary', () => v.binaries++);
      viewers.push(v);
    }
    stats = await SquishClient.connect(m.url, { role: 'view', decode: false });
    await stats.join(m.session, 'view');
    stats.on('stats', s => {
      if (s.frame_ms === undefined) return;
      (frameMs[phase] ||= []).push(s.frame_ms);
      (frameCpu[phase] ||= []).push(s.frame_cpu_ms ?? NaN);
    });
    await stats.subscribe({ stats: true, stats_hz: 10, frames: false });
    process.send({ ready: true });
  } else if (m.phase) {
    phase = m.phase;
  } else if (m.stop) {
    const viewerFrames = viewers.map(v => v.binaries).reduce((a, b) => Math.min(a, b), Infinity);
    for (const v of viewers) await v.close();
    await stats.close();
    process.send({ frameMs, frameCpu, viewerFrames }, () => process.exit(0));
  }
});
