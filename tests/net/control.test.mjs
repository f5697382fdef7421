// control.test.mjs - who controls a session: the "control" event, take_control, probes in
// opened/joined and scene names in `scenes` (docs/protocol.md), against the real server.
import { test, before, after } from 'node:test';
import assert from 'node:assert/strict';
import path from 'node:path';
import { SquishClient } from './client.mjs';
import { startServer, ROOT } from './harness.mjs';

let srv, tok;
before(async () => {
  srv = await startServer(['--grace', '1', '--scenes', path.join(ROOT, 'meshes/scenes')]);
  tok = await startServer(['--grace', '1', '--token', 'sesame']);
});
after(async () => { await srv.stop(); await tok.stop(); });

const connect = (opts = {}, s = srv) => SquishClient.connect(s.url, opts);
const controlEvent = c => c.waitFor(e => e.kind === 'control', 5000, 'event');

test('controller leaves: every viewer gets a control event (left), one takes control', async () => {
  const ctl = await connect({ client: 'ctl' });
  const o = await ctl.open('paper-cube');
  const v1 = await connect({ client: 'v1', role: 'view' });
  const v2 = await connect({ client: 'v2', role: 'view' });
  await v1.join(o.session);
  await v2.join(o.session);
  const e1 = controlEvent(v1), e2 = controlEvent(v2);
  await ctl.close();
  for (const e of [await e1, await e2]) {
    assert.equal(e.type, 'event');
    assert.equal(e.session, o.session);
    assert.equal(e.controller, false);
    assert.equal(e.you, false);
    assert.equal(e.reason, 'left');
  }
  // nobody controls: a viewer may take it; both are told, only the taker with you: true
  const t1 = controlEvent(v1), t2 = controlEvent(v2);
  const ack = await v1.request({ type: 'take_control' });
  assert.equal(ack.type, 'ack');
  assert.equal(ack.request, 'take_control');
  assert.equal(ack.role, 'control');
  const [a, b] = [await t1, await t2];
  assert.deepEqual([a.controller, a.you, a.reason], [true, true, 'taken']);
  assert.deepEqual([b.controller, b.you, b.reason], [true, false, 'taken']);
  // the new controller really controls; the other one cannot take it
  const r = await v1.tool({ id: 1, shape: 'sphere', pos: [0.5, 0.5, 1.2], radius: 0.1 });
  assert.equal(r.request, 'tool');
  await assert.rejects(v2.request({ type: 'take_control' }), e => e.code === 'controller_present' &&
    /another client controls/.test(e.message));
  await assert.rejects(v2.tool({ id: 1, pos: [0.5, 0.5, 1.3] }), e => e.code === 'not_controller');
  await v1.close(); await v2.close();
});

test('a controller that joins its own session as a viewer gives control up (demoted)', async () => {
  const ctl = await connect();
  const o = await ctl.open('paper-cube');
  const v = await connect({ role: 'view' });
  await v.join(o.session);
  const ev = controlEvent(v), mine = controlEvent(ctl);
  const j = await ctl.join(o.session, 'view');
  assert.equal(j.role, 'view');
  const [e, m] = [await ev, await mine];
  assert.deepEqual([e.controller, e.you, e.reason], [false, false, 'demoted']);
  assert.deepEqual([m.controller, m.you, m.reason], [false, false, 'demoted']);
  // a control client joining a session without controller gets it: viewers are told (taken)
  const c2 = await connect();
  const ev2 = controlEvent(v);
  const j2 = await c2.join(o.session);
  assert.equal(j2.role, 'control');
  const e2 = await ev2;
  assert.deepEqual([e2.controller, e2.you, e2.reason], [true, false, 'taken']);
  await ctl.close(); await v.close(); await c2.close();
});

test('take_control with --token: refused without it (bad_token), granted with it', async () => {
  const ctl = await connect({ token: 'sesame' }, tok);
  const o = await ctl.open('default');
  const v = await connect({ role: 'view' }, tok);
  await v.join(o.session);
  await assert.rejects(v.request({ type: 'take_control' }), e => e.code === 'controller_present');
  const left = controlEvent(v);
  await ctl.close();
  await left;
  await assert.rejects(v.request({ type: 'take_control' }), e => e.code === 'bad_token');
  await assert.rejects(v.request({ type: 'take_control', token: 'nope' }), e => e.code === 'bad_token');
  await assert.rejects(v.request({ type: 'take_control', token: 7 }), e => e.code === 'bad_field');
  const ack = await v.request({ type: 'take_control', token: 'sesame' });
  assert.equal(ack.role, 'control');
  await v.close();
});

test('take_control before open/join: no_session', async () => {
  const c = await connect();
  await assert.rejects(c.request({ type: 'take_control' }), e => e.code === 'no_session');
  await c.close();
});

test('opened and joined bodies carry the scene probes: name, nearest surface vertex, rest point', async () => {
  const c = await connect();
  const o = await c.open('beam');
  const byName = Object.fromEntries(o.bodies.map(b => [b.name, b]));
  assert.deepEqual(byName['beam-fem'].probes.map(p => p.name), ['fem-tip']);
  assert.deepEqual(byName['beam-paper'].probes.map(p => p.name), ['paper-tip']);
  for (const b of o.bodies) {
    const rest = c.bodies.get(b.id).rest;
    for (const p of b.probes) {
      assert.equal(p.point.length, 3);
      assert.ok(Number.isInteger(p.vertex) && p.vertex >= 0 && p.vertex < b.surface.vertices);
      // the vertex is the surface vertex nearest to the point (brute force over the topology)
      const d = i => Math.hypot(rest[3 * i] - p.point[0], rest[3 * i + 1] - p.point[1], rest[3 * i + 2] - p.point[2]);
      let best = 0;
      for (let i = 1; i < b.surface.vertices; i++) if (d(i) < d(best)) best = i;
      // f32 topology against f64 mesh: equal distances may tie; tolerance 1e-6 m
      assert.ok(d(p.vertex) <= d(best) + 1e-6, `probe ${p.name}: vertex ${p.vertex} at ${d(p.vertex)} m, nearest ${best} at ${d(best)} m`);
      assert.ok(d(p.vertex) < 0.05, `probe ${p.name} lies on the surface (tip probes): ${d(p.vertex)} m`);
    }
  }
  const v = await connect({ role: 'view' });
  const j = await v.join(o.session);
  assert.deepEqual(j.bodies.map(b => b.probes), o.bodies.map(b => b.probes));
  await c.close(); await v.close();
});

test('scenes are listed and opened by the scene file\'s "name"', async () => {
  const { mkdtempSync, writeFileSync, copyFileSync } = await import('node:fs');
  const os = await import('node:os');
  const dir = mkdtempSync(path.join(os.tmpdir(), 'squish-names-'));
  // a file named unlike its scene
  const scene = JSON.parse((await import('node:fs')).readFileSync(path.join(ROOT, 'meshes/scenes/paper-cube.json'), 'utf8'));
  scene.name = 'my-cube';
  scene.bodies[0].levels = scene.bodies[0].levels.map(l => path.join(ROOT, 'meshes/scenes', l));
  writeFileSync(path.join(dir, 'file-name.json'), JSON.stringify(scene));
  copyFileSync(path.join(dir, 'file-name.json'), path.join(dir, 'same-name-again.json'));
  const s = await startServer(['--scenes', dir]);
  try {
    const c = await SquishClient.connect(s.url);
    assert.deepEqual(c.welcome.scenes, ['my-cube']);
    const list = await c.listScenes();
    assert.deepEqual(list.map(x => x.name), ['my-cube']);
    const o = await c.open('my-cube');
    assert.equal(o.scene, 'my-cube');
    await c.close();
    assert.match(s.stderr(), /same-name-again\.json: its name "my-cube" is already the name of .*file-name\.json/);
  } finally { await s.stop(); }
});

test('two viewers racing for control: one ack, one controller_present', async () => {
  const ctl = await connect();
  const o = await ctl.open('paper-cube');
  const v = await Promise.all([connect({ role: 'view' }), connect({ role: 'view' })]);
  await Promise.all(v.map(c => c.join(o.session)));
  const left = v.map(controlEvent);
  await ctl.close();
  await Promise.all(left);
  const r = await Promise.allSettled(v.map(c => c.request({ type: 'take_control' })));
  const won = r.filter(x => x.status === 'fulfilled');
  const lost = r.filter(x => x.status === 'rejected');
  assert.equal(won.length, 1);
  assert.equal(lost.length, 1);
  assert.equal(lost[0].reason.code, 'controller_present');
  const s = await v[0].stats();
  assert.equal(s.controller, true);
  await Promise.all(v.map(c => c.close()));
});
