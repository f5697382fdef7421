// elasticity.test.mjs - "elasticity" in set and settings (docs/protocol.md), against the real
// server: switching at run time, the refused combinations (paper operator, adaptive lod) with
// the supported one named, all-or-nothing requests, and a bad value.
import { test, before, after } from 'node:test';
import assert from 'node:assert/strict';
import { SquishClient, SquishError } from './client.mjs';
import { startServer, sleep } from './harness.mjs';

let srv;
before(async () => { srv = await startServer(['--grace', '1', '--scenes', 'meshes/scenes']); });
after(async () => { await srv.stop(); });

const refused = (re) => e => {
  assert.ok(e instanceof SquishError);
  assert.equal(e.code, 'refused');
  assert.match(e.message, re);
  return true;
};

test('set elasticity: default linear, corotational on, refusals change nothing', async () => {
  const c = await SquishClient.connect(srv.url);
  await c.open('paper-cube');
  let a = await c.set({ damping: { mass: 1 } });
  assert.equal(a.bodies[0].settings.elasticity, 'linear');
  a = await c.set({ elasticity: 'corotational' });
  assert.equal(a.bodies[0].settings.elasticity, 'corotational');
  // the paper operator has no corotational form: refused, naming the supported combination
  await assert.rejects(c.set({ operator: 'paper' }), refused(/needs the fem operator/));
  a = await c.set({ damping: { mass: 1 } });
  assert.equal(a.bodies[0].settings.elasticity, 'corotational');
  assert.equal(a.bodies[0].settings.operator, 'fem');
  // linear is applied before the operator in the same request
  a = await c.set({ elasticity: 'linear', operator: 'paper' });
  assert.equal(a.bodies[0].settings.elasticity, 'linear');
  assert.equal(a.bodies[0].settings.operator, 'paper');
  // corotational with paper: refused, and the request's other change is undone too
  await assert.rejects(c.set({ elasticity: 'corotational', damping: { mass: 3 } }), refused(/fem operator/));
  a = await c.set({ operator: 'fem', elasticity: 'corotational' });
  assert.equal(a.bodies[0].settings.damping.mass, 1);
  assert.equal(a.bodies[0].settings.elasticity, 'corotational');
  await assert.rejects(c.set({ elasticity: 'rotated' }), e => {
    assert.ok(e instanceof SquishError);
    assert.equal(e.code, "out_of_range"); // the enum code, as for set.operator
    assert.match(e.message, /set\.elasticity/);
    return true;
  });
  await c.close();
});

test('set elasticity: corotational runs in adaptive lod too (sphere-grab ships corotational, fixed)', async () => {
  const c = await SquishClient.connect(srv.url);
  await c.open('sphere-grab');
  let a = await c.set({ damping: { mass: 1.5 } });
  assert.equal(a.bodies[0].settings.elasticity, 'corotational');
  a = await c.set({ lod: { mode: 'adaptive' } });
  assert.equal(a.bodies[0].settings.elasticity, 'corotational');
  assert.equal(a.bodies[0].settings.lod.mode, 'adaptive');
  a = await c.set({ elasticity: 'linear' });
  assert.equal(a.bodies[0].settings.elasticity, 'linear');
  assert.equal(a.bodies[0].settings.lod.mode, 'adaptive');
  a = await c.set({ elasticity: 'corotational' });
  assert.equal(a.bodies[0].settings.elasticity, 'corotational');
  a = await c.set({ lod: { mode: 'fixed' }, elasticity: 'corotational' });
  assert.equal(a.bodies[0].settings.elasticity, 'corotational');
  assert.equal(a.bodies[0].settings.lod.mode, 'fixed');
  await c.close();
});

test('set pressure: nodal on a fixed linear fem body, refused with corotational', async () => {
  const c = await SquishClient.connect(srv.url);
  await c.open('paper-cube');
  let a = await c.set({ pressure: 'nodal' });
  assert.equal(a.bodies[0].settings.pressure, 'nodal');
  await assert.rejects(c.set({ elasticity: 'corotational' }), refused(/nodal pressure tets/));
  a = await c.set({ pressure: 'element', elasticity: 'corotational' });
  assert.equal(a.bodies[0].settings.pressure, 'element');
  assert.equal(a.bodies[0].settings.elasticity, 'corotational');
  await assert.rejects(c.set({ pressure: 'nodal' }), refused(/linear elasticity/));
  a = await c.set({ elasticity: 'linear', pressure: 'nodal' });
  assert.equal(a.bodies[0].settings.pressure, 'nodal');
  await c.close();
});

test('set integrator: implicit on a fixed body, CG figures in stats; bad settings and adaptive lod refused, nothing changes', async () => {
  const c = await SquishClient.connect(srv.url);
  await c.open('sphere-grab');
  let a = await c.set({ integrator: 'implicit', implicit: { substeps: 2, cg_tolerance: 1e-5, preconditioner: 'multigrid' } });
  let st = a.bodies[0].settings;
  assert.equal(st.integrator, 'implicit');
  assert.equal(st.implicit.substeps, 2);
  assert.equal(st.implicit.cg_tolerance, 1e-5);
  assert.equal(st.implicit.preconditioner, 'multigrid');
  assert.equal(st.implicit.cg_max_iterations, 500);
  // the solve runs: a frame later the stats carry its CG iterations and residual
  let s;
  for (let k = 0; k < 50; k++) {
    s = await c.stats();
    if (s.cg_iterations > 0) break;
    await sleep(40);
  }
  assert.ok(s.cg_iterations > 0, `cg_iterations ${s.cg_iterations}`);
  assert.ok(s.bodies[0].cg_residual <= 1e-5, `cg_residual ${s.bodies[0].cg_residual}`);
  await assert.rejects(c.set({ implicit: { cg_tolerance: 0 } }), e => e.code === 'out_of_range' && /cg_tolerance/.test(e.message));
  await assert.rejects(c.set({ implicit: { cg_max_iterations: 10001 } }), e => e.code === 'out_of_range' && /10000/.test(e.message));
  await assert.rejects(c.set({ integrator: 'verlet' }), e => e.code === 'out_of_range' && /set\.integrator/.test(e.message));
  await assert.rejects(c.set({ lod: { mode: 'adaptive' } }), refused(/implicit integrator runs with fixed lod/));
  a = await c.set({ damping: { mass: 1.5 } });
  st = a.bodies[0].settings;
  assert.equal(st.integrator, 'implicit');
  assert.equal(st.implicit.cg_tolerance, 1e-5);
  assert.equal(st.lod.mode, 'fixed');
  a = await c.set({ integrator: 'explicit' });
  assert.equal(a.bodies[0].settings.integrator, 'explicit');
  await c.close();
});
