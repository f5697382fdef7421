// levels.test.mjs - one level numbering everywhere: a body's levels are numbered as its scene
// file lists them, in frames, nodes, opened/joined and stats, whatever levels it loaded.
import { test, before, after } from 'node:test';
import assert from 'node:assert/strict';
import path from 'node:path';
import { SquishClient } from './client.mjs';
import { startServer, ROOT } from './harness.mjs';

let srv;
before(async () => { srv = await startServer(['--scenes', path.join(ROOT, 'meshes/scenes'), '--grace', '0']); });
after(async () => { await srv.stop(); });

test('paper-cube (4 levels listed, fixed at level 2, only that one loaded) says level 2 everywhere', async () => {
  const c = await SquishClient.connect(srv.url);
  const o = await c.open('paper-cube');
  const b = o.bodies[0];
  assert.equal(b.listed_levels, 4);
  assert.equal(b.levels.length, 1, 'a fixed body loads its simulated level alone');
  assert.equal(b.levels[0].index, 2);
  // every surface vertex of every frame carries level byte 2 (not the loaded index 0)
  const f = await c.waitFor(g => g.body === 0, 5000, 'frame');
  assert.equal(f.levels.length, b.surface.vertices);
  assert.ok(f.levels.every(l => l === 2), `levels seen: ${[...new Set(f.levels)]}`);
  // stats: active nodes indexed by listed level, zeros for the levels not loaded
  const s = await c.stats();
  assert.equal(s.active_nodes.length, 3);
  assert.deepEqual(s.active_nodes.slice(0, 2), [0, 0]);
  assert.equal(s.active_nodes[2], b.levels[0].nodes);
  assert.deepEqual(s.bodies[0].active_nodes, s.active_nodes);
  assert.equal(s.bodies[0].substeps.length, 3);
  assert.ok(s.bodies[0].substeps[2] >= 1 && s.bodies[0].substeps[0] === 0);
  // nodes: the simulated level's nodes, all level 2
  const { reply, nodes } = await c.nodes(0);
  assert.equal(reply.level, 2);
  assert.equal(reply.count, b.levels[0].nodes);
  assert.ok(nodes.levels.every(l => l === 2));
  await c.close();
});

test('an adaptive body with every level loaded keeps indices 0..n-1', async () => {
  const c = await SquishClient.connect(srv.url);
  const o = await c.open('cube-poke');
  const b = o.bodies[0];
  assert.deepEqual(b.levels.map(l => l.index), b.levels.map((_, k) => k));
  const f = await c.waitFor(g => g.body === 0, 5000, 'frame');
  assert.ok(f.levels.every(l => l < b.levels.length));
  await c.close();
});

test('settings and set count levels as listed too; a level the body did not load is refused by name', async () => {
  const c = await SquishClient.connect(srv.url);
  const o = await c.open('paper-cube');
  const st = o.bodies[0].settings;
  assert.equal(st.lod.level, 2);
  assert.equal(st.levels[0].index, 2);
  const a = await c.set({ lod: { level: 2 } });
  assert.equal(a.bodies[0].settings.lod.level, 2);
  await assert.rejects(c.set({ lod: { level: 1 } }), e => e.code === 'refused' && /level 1 is not loaded/.test(e.message));
  // cube-poke loads listed levels 0..2: fixed at listed level 1 streams level 1
  const p = await c.open('cube-poke');
  const r = await c.set({ lod: { mode: 'fixed', level: 1 } });
  assert.equal(r.bodies[0].settings.lod.level, 1);
  assert.equal(r.bodies[0].settings.lod.mode, 'fixed');
  const f = await c.waitFor(g => g.body === 0 && g.frame > r.frame, 5000, 'frame');
  assert.ok(f.levels.every(l => l === 1), `levels seen: ${[...new Set(f.levels)]}`);
  assert.equal(p.bodies[0].settings.lod.max_level, 2);
  await c.close();
});

test('lod.adapt_every: 1 by default in settings, set and reported back, out of range refused by name', async () => {
  const c = await SquishClient.connect(srv.url);
  const o = await c.open('cube-poke');
  assert.equal(o.bodies[0].settings.lod.adapt_every, 1);
  const a = await c.set({ lod: { adapt_every: 3 } });
  assert.equal(a.bodies[0].settings.lod.adapt_every, 3);
  await assert.rejects(c.set({ lod: { adapt_every: 5000 } }),
    e => e.code === 'out_of_range' && /set\.lod\.adapt_every/.test(e.message));
  const s = await c.set({ lod: { split: 0.01 } }); // another lod change keeps it
  assert.equal(s.bodies[0].settings.lod.adapt_every, 3);
  await c.close();
});

test('a body asleep keeps reporting its active nodes (and no node updates)', async () => {
  const c = await SquishClient.connect(srv.url);
  const o = await c.open('cube-poke');
  const n0 = o.bodies[0].levels[0].nodes;
  // untouched, the cube is calm from the start and sleeps after 25 frames (0.5 s); 10 s cap
  let s = await c.stats();
  for (let t = 0; t < 100 && !s.bodies[0].sleeping; t++) {
    await new Promise(r => setTimeout(r, 100));
    s = await c.stats();
  }
  assert.equal(s.bodies[0].sleeping, true, 'the untouched cube falls asleep within 10 s');
  // the frame that fell asleep still integrated: read a frame stepped asleep
  const fell = s.frame;
  for (let t = 0; t < 100 && s.frame <= fell; t++) {
    await new Promise(r => setTimeout(r, 50));
    s = await c.stats();
  }
  assert.ok(s.frame > fell && s.bodies[0].sleeping, 'a frame stepped asleep');
  assert.equal(s.active_nodes[0], n0, 'asleep, the coarse level still counts as active');
  assert.equal(s.bodies[0].node_updates, 0, 'asleep, nothing is integrated');
  await c.close();
});

test('before its first frame a session already reports its active nodes and substeps (lockstep, no step)', async () => {
  const ls = await startServer(['--scenes', path.join(ROOT, 'meshes/scenes'), '--grace', '0', '--lockstep']);
  try {
    const c = await SquishClient.connect(ls.url);
    const o = await c.open('paper-cube');
    const s = await c.stats();
    assert.equal(s.frame, 0, 'nothing stepped');
    assert.equal(s.active_nodes[2], o.bodies[0].levels[0].nodes);
    // the steps the level runs per frame, as the first stepped frame then reports them
    const sub0 = s.bodies[0].substeps;
    assert.ok(sub0[2] >= 1 && sub0[0] === 0, `substeps before any step: ${sub0}`);
    await c.step(1);
    assert.deepEqual((await c.stats()).bodies[0].substeps, sub0);
    // an adaptive body: its coarsest level's steps (nothing is refined yet)
    const a = await c.open('cube-poke');
    const sa = await c.stats();
    assert.equal(sa.frame, 0);
    assert.ok(sa.bodies[0].substeps[0] >= 1, `adaptive substeps before any step: ${sa.bodies[0].substeps}`);
    assert.ok(a.session > 0);
    await c.close();
  } finally {
    await ls.stop();
  }
});
