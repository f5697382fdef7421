// service.test.mjs - many viewers, slow readers, lockstep determinism, blow-up isolation and
// clean shutdown, against the real server.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { createHash } from 'node:crypto';
import { mkdtempSync } from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { SquishClient } from './client.mjs';
import { startServer, rssKiB, sleep, makeBoxScene } from './harness.mjs';

test('100 concurrent viewers on one session all receive frames', async () => {
  const srv = await startServer();
  try {
    const ctl = await SquishClient.connect(srv.url);
    const o = await ctl.open('default');
    const viewers = await Promise.all(Array.from({ length: 100 }, (_, i) =>
      SquishClient.connect(srv.url, { role: 'view', client: `v${i}`, decode: false })));
    await Promise.all(viewers.map(v => v.join(o.session)));
    const counts = viewers.map(() => 0);
    viewers.forEach((v, i) => v.on('binary', () => { counts[i]++; }));
    await sleep(1500);
    const s = await ctl.stats();
    assert.equal(s.clients, 101);
    assert.equal(s.viewers, 100);
    // 1.5 s at 50 Hz = 75 frames; allow for a loaded machine, but every viewer must stream
    const min = Math.min(...counts);
    assert.ok(min >= 20, `slowest viewer got ${min} frames`);
    await Promise.all([...viewers, ctl].map(c => c.close()));
  } finally {
    await srv.stop();
  }
});

test('stalled readers: server memory stays bounded, frames are skipped (latest wins)', async () => {
  const dir = await makeBoxScene(mkdtempSync(path.join(os.tmpdir(), 'squish-net-')), 'box16', 16);
  // a fine quantisation step makes big frames, which fill the stalled sockets quickly
  const srv = await startServer(['--scenes', dir, '--precision', '1e-6']);
  try {
    const ctl = await SquishClient.connect(srv.url);
    const o = await ctl.open('box16');
    // keep the body moving so that frames do not compress to nothing
    await ctl.tool({ id: 1, shape: 'grab', pos: [0.5, 0.5, 1.0], radius: 0.3 });
    let z = 1.0, up = true;
    const mover = setInterval(() => {
      z += up ? 0.02 : -0.02;
      if (z > 1.3 || z < 1.0) up = !up;
      ctl.tool({ id: 1, pos: [0.5, 0.5, z] }).catch(() => {});
    }, 40);
    const stalled = await Promise.all(Array.from({ length: 20 }, () => SquishClient.connect(srv.url, { role: 'view', decode: false })));
    await Promise.all(stalled.map(c => c.join(o.session)));
    let bytes = 0;
    ctl.on('binary', b => { bytes += b.length; });
    await sleep(1000);
    const frameBytes = bytes / 50;
    for (const c of stalled) c.ws._socket.pause(); // stop reading: the server must not queue for them
    const rss0 = rssKiB(srv.pid);
    await sleep(5000);
    const rss1 = rssKiB(srv.pid);
    clearInterval(mover);
    // unbounded queues would hold 20 clients x 250 frames x frameBytes
    const unbounded = 20 * 250 * frameBytes / 1024;
    assert.ok(rss1 - rss0 < 8192, `server RSS grew by ${rss1 - rss0} KiB in 5 s (unbounded queues: ~${unbounded.toFixed(0)} KiB)`);
    // the readers come back: they get fresh frames and their skip counters show what they missed
    for (const c of stalled) c.ws._socket.resume();
    const skipped = await Promise.all(stalled.map(c => c.stats().then(s => s.skipped)));
    assert.ok(Math.min(...skipped) > 0, `skipped per stalled client: ${skipped}`);
    const sim = await ctl.stats();
    assert.ok(sim.frame > 100, 'the simulation kept going');
    await Promise.all([...stalled, ctl].map(c => c.close()));
  } finally {
    await srv.stop();
  }
});

/** one lockstep run: the bytes of every binary message, hashed */
async function lockstepRun() {
  const srv = await startServer(['--lockstep']);
  try {
    const c = await SquishClient.connect(srv.url);
    assert.equal(c.welcome.lockstep, true);
    const bins = [];
    c.on('binary', b => bins.push(Buffer.from(b)));
    await c.open('default');
    await c.tool({ id: 2, shape: 'grab', pos: [0.5, 0.5, 1.0], radius: 0.15 });
    const st = await c.step(10);
    assert.equal(st.type, 'stepped');
    assert.equal(st.frames, 10);
    await c.tool({ id: 2, pos: [0.5, 0.5, 1.2] });
    await c.step(20);
    await assert.rejects(c.pause(), e => e.code === 'lockstep');
    const frames = bins.filter(b => b[6] === 2).map(b => b.readUInt32LE(12));
    await c.close();
    return { hash: createHash('sha256').update(Buffer.concat(bins)).digest('hex'), frames, n: bins.length };
  } finally {
    await srv.stop();
  }
}

test('lockstep: two runs give identical bytes, every frame in order', async () => {
  const a = await lockstepRun();
  const b = await lockstepRun();
  assert.deepEqual(a.frames, Array.from({ length: 31 }, (_, i) => i)); // frame 0, then 30 stepped
  assert.equal(a.hash, b.hash);
  assert.equal(a.n, b.n);
});

test('a blow-up resets that body and is reported; another session goes on', async () => {
  const srv = await startServer();
  try {
    const a = await SquishClient.connect(srv.url);
    const b = await SquishClient.connect(srv.url);
    await a.open('default');
    await b.open('default');
    const bEvents = [];
    b.on('event', e => bEvents.push(e));
    await a.tool({ id: 1, shape: 'grab', pos: [1, 1, 1], radius: 0.2 });
    await sleep(100);
    const ev = a.waitFor(e => e.kind === 'reset', 5000, 'event');
    const flagged = a.waitFor(f => (f.flags & 1) === 1, 5000, 'frame');
    await a.tool({ id: 1, pos: [1, 1, 900] }); // drags the corner 900 m: far beyond any sane state
    const e = await ev;
    assert.equal(e.body, 0);
    assert.ok(e.message.length > 0);
    await flagged;
    const sa = await a.stats();
    assert.ok(sa.resets >= 1);
    const f0 = (await b.stats()).frame;
    await sleep(300);
    const sb = await b.stats();
    assert.ok(sb.frame > f0 + 5, 'the other session keeps stepping');
    assert.equal(sb.resets, 0);
    assert.equal(bEvents.length, 0);
    await a.close();
    await b.close();
  } finally {
    await srv.stop();
  }
});

for (const sig of ['SIGTERM', 'SIGINT']) {
  test(`${sig}: clients told, connections closed, exit code 0`, async () => {
    const srv = await startServer();
    const c = await SquishClient.connect(srv.url);
    await c.open('default');
    const ev = c.waitFor(e => e.kind === 'shutdown', 5000, 'event');
    const t0 = Date.now();
    const exited = srv.stop(sig);
    await ev;
    await c.closed;
    const { code } = await exited;
    assert.equal(code, 0);
    assert.ok(Date.now() - t0 < 3000, 'stops promptly');
    assert.match(srv.stderr(), /stopped/);
  });
}

test('every shipped scene (meshes/scenes) opens and streams frames matching its topology', async (t) => {
  const { existsSync } = await import('node:fs');
  const { ROOT } = await import('./harness.mjs');
  const dir = path.join(ROOT, 'meshes/scenes');
  if (!existsSync(dir)) { t.skip('no meshes/scenes'); return; }
  const srv = await startServer(['--scenes', dir, '--grace', '0']);
  try {
    const c = await SquishClient.connect(srv.url);
    const scenes = await c.listScenes();
    assert.ok(scenes.length >= 1);
    for (const s of scenes) {
      const o = await c.open(s.name);
      assert.equal(o.bodies.length, s.bodies.length, s.name);
      for (const b of o.bodies) {
        const f = await c.waitFor(f => f.body === b.id, 10000, 'frame');
        assert.equal(f.header.count0, b.surface.vertices, `${s.name} body ${b.id}`);
        assert.ok(f.positions.every(Number.isFinite), `${s.name} body ${b.id} finite`);
      }
    }
    await c.close();
  } finally {
    await srv.stop();
  }
});

test('a client that asks without reading cannot grow server memory', async () => {
  const dir = await makeBoxScene(mkdtempSync(path.join(os.tmpdir(), 'squish-net-')), 'box20', 20);
  const srv = await startServer(['--scenes', dir, '--rate', '2000']);
  try {
    const c = await SquishClient.connect(srv.url, { decode: false });
    await c.open('box20');
    await c.request({ type: 'nodes', body: 0 });
    const rss0 = rssKiB(srv.pid);
    c.ws._socket.pause();
    // 1500 `nodes` replies of ~20 KB each: the server either stops reading this client (its
    // output is stuck) or drops it when its queue passes 32 MiB; it never queues them all
    for (let i = 0; i < 1500; i++) {
      c.sendRaw(JSON.stringify({ type: 'nodes', body: 0 }));
      if (i % 100 === 99) await sleep(50);
    }
    await sleep(2000);
    const rss1 = rssKiB(srv.pid);
    assert.ok(rss1 - rss0 < 40 * 1024, `server RSS grew by ${rss1 - rss0} KiB`);
    // the server goes on serving others
    const d = await SquishClient.connect(srv.url);
    assert.equal((await d.ping(3)).t, 3);
    await d.close();
    c.ws.terminate();
  } finally {
    await srv.stop();
  }
});
