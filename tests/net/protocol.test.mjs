// protocol.test.mjs - the message table of docs/protocol.md against the real server.
import { test, before, after } from 'node:test';
import assert from 'node:assert/strict';
import { SquishClient, SquishError, decodeBinary } from './client.mjs';
import { startServer, sleep } from './harness.mjs';

let srv;
before(async () => { srv = await startServer(['--grace', '1']); });
after(async () => { await srv.stop(); });

const connect = (opts = {}) => SquishClient.connect(srv.url, opts);

test('hello -> welcome with version, scenes and limits', async () => {
  const c = await connect({ client: 'proto' });
  const w = c.welcome;
  assert.equal(w.type, 'welcome');
  assert.equal(w.version, 1);
  assert.match(w.server, /^squish\//);
  assert.equal(w.role, 'control');
  assert.ok(w.scenes.includes('default'));
  assert.equal(w.lockstep, false);
  for (const k of ['max_sessions', 'max_clients', 'max_message', 'rate', 'grace', 'max_step'])
    assert.equal(typeof w.limits[k], 'number', `limits.${k}`);
  await c.close();
});

test('list_scenes -> scenes with bodies, levels, description', async () => {
  const c = await connect();
  const scenes = await c.listScenes();
  const d = scenes.find(s => s.name === 'default');
  assert.ok(d);
  assert.equal(typeof d.description, 'string');
  assert.ok(d.bodies.length >= 1);
  assert.equal(d.levels.length, d.bodies.length);
  assert.ok(d.frame_rate > 0);
  await c.close();
});

test('open -> topology per body, opened, then frames that decode against the topology', async () => {
  const c = await connect();
  const topo = c.waitFor(() => true, 5000, 'topology');
  const o = await c.open('default');
  assert.equal(o.type, 'opened');
  assert.ok(Number.isInteger(o.session) && o.session > 0);
  assert.equal(o.role, 'control');
  assert.equal(o.demoted, false);
  assert.equal(o.frame_rate, 50);
  const b = o.bodies[0];
  assert.equal(b.id, 0);
  assert.ok(b.levels.length >= 1 && b.levels[0].nodes > 0 && b.levels[0].tets > 0);
  for (const k of ['material', 'damping', 'operator', 'lod', 'levels']) assert.ok(k in b.settings, `settings.${k}`);
  const t = await topo; // arrived before opened
  assert.equal(t.rest.length, 3 * b.surface.vertices);
  assert.equal(t.triangles.length, 3 * b.surface.triangles);
  assert.ok(Math.max(...t.triangles) < b.surface.vertices);
  const f = await c.waitFor(f => f.body === 0, 5000, 'frame');
  assert.equal(f.header.count0, b.surface.vertices);
  assert.equal(f.positions.length, 3 * b.surface.vertices);
  assert.equal(f.levels.length, b.surface.vertices);
  assert.ok(f.positions.every(Number.isFinite));
  // frames keep coming in real time, frame numbers increasing
  const f2 = await c.waitFor(g => g.frame > f.frame + 5, 5000, 'frame');
  assert.ok(f2.time > f.time);
  await c.close();
});

test('tool (grab), frames carry the tool and its feedback force, stats shows it', async () => {
  const c = await connect();
  await c.open('default');
  const a = await c.tool({ id: 3, shape: 'grab', pos: [0.5, 0.5, 1.0], radius: 0.15, active: true });
  assert.equal(a.type, 'ack');
  assert.equal(a.request, 'tool');
  // pull up 10 cm, then wait for a frame that shows the pulled tool position
  await c.tool({ id: 3, pos: [0.5, 0.5, 1.1] });
  const f = await c.waitFor(f => f.tools.some(t => t.id === 3 && Math.abs(t.pos[2] - 1.1) < 1e-6), 5000, 'frame');
  const tr = f.tools.find(t => t.id === 3);
  assert.equal(tr.shape, 'grab');
  assert.equal(tr.active, true);
  await sleep(200);
  const s = await c.stats();
  assert.equal(s.type, 'stats');
  for (const k of ['frame', 'time', 'budget_used', 'deadline_misses', 'overruns', 'active_nodes', 'node_updates',
    'sleeping', 'feedback', 'clients', 'viewers', 'bytes_sent', 'skipped', 'tools', 'bodies'])
    assert.ok(k in s, `stats.${k}`);
  const fb = s.feedback.find(e => e.tool === 3);
  assert.ok(fb && fb.nodes > 0, 'the grab holds nodes');
  assert.ok(Math.hypot(...fb.force) > 0, 'pulling gives a feedback force');
  assert.equal(s.clients, 1);
  assert.ok(s.bytes_sent > 0);
  // typed health warnings per body: kinds that occurred, each counted with its last value and frame
  for (const b of s.bodies) {
    assert.equal(typeof b.health, 'object', 'bodies[].health');
    for (const [k, h] of Object.entries(b.health)) {
      assert.match(k, /^(blowup_(nan|stretch|speed)|sleep|wake|budget_(coarse|over|predicted)|node_cap)$/);
      assert.ok(h.count >= 1 && h.last_frame >= 1 && h.last_frame <= s.frame && Number.isFinite(h.last_value), k);
    }
  }
  // a later tool update without shape for the known id is fine; the pulled surface moved up
  const top = c.lastFrame;
  assert.ok(Math.max(...top.displacement.filter((_, i) => i % 3 === 2)) > 0.01);
  await c.close();
});

test('set: valid change acknowledged with settings; unstable one refused with the reason', async () => {
  const c = await connect();
  await c.open('default');
  const a = await c.set({ material: { E: 60000 }, damping: { mass: 1.5 } });
  assert.equal(a.request, 'set');
  assert.ok(Math.abs(a.bodies[0].settings.material.E - 60000) < 1e-6);
  assert.equal(a.bodies[0].settings.damping.mass, 1.5);
  // nearly massless, very stiff: the stability bound would need too many substeps
  await assert.rejects(c.set({ material: { E: 1e10, density: 1e-6 } }), e => {
    assert.ok(e instanceof SquishError);
    assert.equal(e.code, 'refused');
    assert.match(e.message, /body 0/);
    return true;
  });
  // nothing changed by the refusal
  const again = await c.set({ operator: 'fem' });
  assert.ok(Math.abs(again.bodies[0].settings.material.E - 60000) < 1e-6);
  await c.close();
});

test('pause, resume, reset; nodes; ping; subscribe pushes stats; leave', async () => {
  const c = await connect();
  await c.open('default');
  const p = await c.pause();
  assert.equal(p.request, 'pause');
  await sleep(100);
  const s1 = await c.stats();
  await sleep(200);
  const s2 = await c.stats();
  assert.equal(s1.paused, true);
  assert.equal(s2.frame, s1.frame, 'paused: no frames advance');
  await c.resume();
  await sleep(200);
  const s3 = await c.stats();
  assert.ok(s3.frame > s2.frame);
  const r = await c.reset();
  assert.equal(r.request, 'reset');
  const { reply, nodes } = await c.nodes(0);
  assert.equal(reply.type, 'nodes');
  assert.equal(nodes.kind, 3);
  assert.equal(nodes.positions.length, 3 * reply.count);
  assert.ok(nodes.positions.every(Number.isFinite));
  const pong = await c.ping(42);
  assert.equal(pong.t, 42);
  await c.subscribe({ stats: true, stats_hz: 10 });
  const pushed = await c.waitFor(() => true, 3000, 'stats');
  assert.equal(pushed.type, 'stats');
  await c.subscribe({ stats: false });
  const l = await c.leave();
  assert.equal(l.type, 'left');
  await assert.rejects(c.stats(), e => e.code === 'no_session');
  await c.close();
});

test('join: a viewer sees the same session, the controller sees the viewer count; control is single', async () => {
  const ctl = await connect({ client: 'teacher' });
  const o = await ctl.open('default');
  const v = await connect({ client: 'pupil', role: 'view' });
  const j = await v.join(o.session);
  assert.equal(j.type, 'joined');
  assert.equal(j.role, 'view');
  assert.equal(v.bodies.get(0).rest.length, 3 * o.bodies[0].surface.vertices);
  await v.waitFor(() => true, 5000, 'frame');
  const s = await ctl.stats();
  assert.equal(s.clients, 2);
  assert.equal(s.viewers, 1);
  // a second control client is demoted to a viewer
  const c2 = await connect({ client: 'other' });
  const j2 = await c2.join(o.session);
  assert.equal(j2.role, 'view');
  assert.equal(j2.demoted, true);
  await assert.rejects(c2.pause(), e => e.code === 'not_controller');
  // viewers cannot control
  await assert.rejects(v.tool({ id: 1, shape: 'sphere', pos: [0, 0, 2] }), e => e.code === 'not_controller');
  // a move by the controller reaches the viewer's frames
  await ctl.tool({ id: 5, shape: 'sphere', pos: [0.5, 0.5, 1.3], radius: 0.2 });
  await v.waitFor(f => f.tools.some(t => t.id === 5), 5000, 'frame');
  // when the controller leaves, the next control client that joins gets control
  await ctl.close();
  await sleep(100);
  const c3 = await connect({ client: 'next' });
  const j3 = await c3.join(o.session);
  assert.equal(j3.role, 'control');
  await c3.pause();
  for (const c of [v, c2, c3]) await c.close();
});

test('step outside lockstep mode is refused', async () => {
  const c = await connect();
  await c.open('default');
  await assert.rejects(c.step(3), e => e.code === 'not_lockstep');
  await c.close();
});

test('HTTP: /healthz answers, unknown ws path refused', async () => {
  const r = await fetch(`${srv.http}/healthz`);
  assert.equal(r.status, 200);
  assert.equal((await r.text()).trim(), 'ok');
  await assert.rejects(SquishClient.connect(`ws://127.0.0.1:${srv.port}/other`));
});

test('an empty session ends after the grace period', async () => {
  const c = await connect();
  const o = await c.open('default');
  await c.leave();
  await sleep(1600); // --grace 1 plus housekeeping ticks
  await assert.rejects(c.join(o.session), e => e.code === 'unknown_session');
  // a new session may reuse the slot; the old id stays invalid (its generation is gone)
  const o2 = await c.open('default');
  assert.notEqual(o2.session, o.session);
  const other = await connect();
  await assert.rejects(other.join(o.session), e => e.code === 'unknown_session');
  await other.close();
  await c.close();
});

test('decodeBinary rejects a truncated message', () => {
  assert.throws(() => decodeBinary(Buffer.alloc(10)));
});

test('GET /snapshot.png renders the session off the simulation thread; bad requests named', async () => {
  const c = await connect();
  const o = await c.open('default');
  await c.tool({ id: 1, shape: 'grab', pos: [0.5, 0.5, 1.0], radius: 0.2 });
  await c.tool({ id: 1, pos: [0.5, 0.5, 1.2] });
  // two at once: one is rendered, the other rate-limited
  const [r, again] = await Promise.all([1, 2].map(() => fetch(`${srv.http}/snapshot.png?session=${o.session}&size=320x240`)));
  assert.deepEqual([r.status, again.status].sort(), [200, 429]);
  const ok = r.status === 200 ? r : again;
  assert.equal(ok.status, 200);
  assert.equal(ok.headers.get('content-type'), 'image/png');
  const png = Buffer.from(await ok.arrayBuffer());
  assert.equal(png.toString('latin1', 1, 4), 'PNG');
  assert.equal(png.readUInt32BE(16), 320); // IHDR width
  assert.equal(png.readUInt32BE(20), 240); // IHDR height
  assert.equal((await fetch(`${srv.http}/snapshot.png?session=77`)).status, 404);
  await sleep(300);
  const bad = await fetch(`${srv.http}/snapshot.png?session=${o.session}&size=5x5`);
  assert.equal(bad.status, 400);
  assert.match(await bad.text(), /size/);
  // frames kept flowing meanwhile
  const f0 = (await c.stats()).frame;
  await c.waitFor(f => f.frame > f0, 3000, 'frame');
  await c.close();
});

test('HTTP files of --web with the right MIME types; index.html at /; no escape from the root', async () => {
  const { mkdtempSync, writeFileSync } = await import('node:fs');
  const os = await import('node:os');
  const path = await import('node:path');
  const dir = mkdtempSync(path.join(os.tmpdir(), 'squish-web-'));
  const types = { html: 'text/html', js: 'text/javascript', mjs: 'text/javascript', css: 'text/css',
    json: 'application/json', png: 'image/png', svg: 'image/svg+xml', wasm: 'application/wasm' };
  for (const ext of Object.keys(types)) writeFileSync(path.join(dir, `f.${ext}`), 'x');
  writeFileSync(path.join(dir, 'index.html'), '<!doctype html><title>t</title>');
  const s2 = await startServer(['--web', dir]);
  try {
    for (const [ext, type] of Object.entries(types)) {
      const r = await fetch(`${s2.http}/f.${ext}`);
      assert.equal(r.status, 200, ext);
      assert.equal(r.headers.get('content-type'), type, ext);
    }
    const idx = await fetch(`${s2.http}/`);
    assert.equal(idx.status, 200);
    assert.match(await idx.text(), /<title>t<\/title>/);
    // the viewer's scripts must be files: the security headers forbid inline scripts
    assert.match(idx.headers.get('content-security-policy') || '', /script-src 'self'/);
    const esc = await fetch(`${s2.http}/%2e%2e/%2e%2e/etc/passwd`);
    assert.notEqual(esc.status, 200);
    // the WebSocket endpoint still works beside the files
    const c = await SquishClient.connect(s2.url);
    await c.close();
  } finally {
    await s2.stop();
  }
});

test('an empty session stops stepping and goes on where it was when someone joins', async () => {
  const c = await connect();
  const o = await c.open('default');
  await sleep(200);
  const before = (await c.stats()).frame;
  await c.leave();
  await sleep(400); // 20 frames at 50 Hz if it kept stepping; --grace 1 keeps it alive
  const j = await c.join(o.session);
  assert.ok(j.frame - before <= 3, `frame ${before} -> ${j.frame} while empty`);
  await sleep(200);
  assert.ok((await c.stats()).frame > j.frame, 'steps again with a client');
  await c.close();
});
