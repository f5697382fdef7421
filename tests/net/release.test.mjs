// release.test.mjs - a departing controller's tools are released: when the control client of a
// session disconnects (or leaves), the server deactivates every tool it set.
import { test, before, after } from 'node:test';
import assert from 'node:assert/strict';
import { SquishClient } from './client.mjs';
import { startServer, sleep } from './harness.mjs';

let srv;
before(async () => { srv = await startServer(['--grace', '2']); });
after(async () => { await srv.stop(); });

const connect = (opts = {}) => SquishClient.connect(srv.url, opts);

test('a controller that disconnects mid-drag: its grab and push go inactive, the body is let go', async () => {
  const ctl = await connect({ client: 'dragger' });
  const o = await ctl.open('default');
  const v = await connect({ client: 'watcher', role: 'view' });
  await v.join(o.session);
  // a grab pulled up 10 cm and an active push sphere, both left active
  await ctl.tool({ id: 3, shape: 'grab', pos: [0.5, 0.5, 1.0], radius: 0.15, active: true });
  await ctl.tool({ id: 3, pos: [0.5, 0.5, 1.1] });
  await ctl.tool({ id: 6, shape: 'sphere', pos: [0.1, 0.1, 1.05], radius: 0.1, active: true });
  await v.waitFor(f => f.tools.some(t => t.id === 3 && t.active && Math.abs(t.pos[2] - 1.1) < 1e-6) &&
    f.tools.some(t => t.id === 6 && t.active), 5000, 'frame');
  let s = await v.stats();
  assert.ok(s.feedback.find(e => e.tool === 3).nodes > 0, 'the grab holds nodes');
  const seen = [];
  v.on('message', m => seen.push(m));
  // the controller's connection drops (no tool active:false sent)
  ctl.ws.terminate();
  const f = await v.waitFor(g => g.tools.every(t => !t.active), 5000, 'frame');
  assert.ok(f.tools.some(t => t.id === 3) && f.tools.some(t => t.id === 6), 'the tools stay known');
  await sleep(100);
  s = await v.stats();
  assert.equal(s.controller, false);
  for (const e of s.feedback) assert.equal(e.nodes, 0, `tool ${e.tool} holds nothing`);
  for (const t of s.tools) assert.equal(t.active, false, `tool ${t.id}`);
  // the viewer saw no ack of the release jobs (they answer the departed client only)
  assert.ok(!seen.some(m => m.type === 'ack' || m.type === 'error'), JSON.stringify(seen.slice(0, 3)));
  await v.close();
});

test('a viewer leaving releases nothing; a controller leaving releases only its own tools', async () => {
  const ctl = await connect({ client: 'first' });
  const o = await ctl.open('default');
  const v = await connect({ client: 'watcher', role: 'view' });
  await v.join(o.session);
  await ctl.tool({ id: 2, shape: 'sphere', pos: [0.5, 0.5, 1.05], radius: 0.1, active: true });
  await v.close();
  await sleep(150);
  assert.equal((await ctl.stats()).tools.find(t => t.id === 2).active, true, 'a viewer leaving changes nothing');
  // the first controller leaves (a `leave`, connection kept): its tool goes inactive
  await ctl.leave();
  const c2 = await connect({ client: 'second' });
  const j = await c2.join(o.session);
  assert.equal(j.role, 'control');
  await c2.waitFor(g => g.tools.every(t => !t.active), 5000, 'frame');
  // the second controller's own new tool stays active while it is connected
  await c2.tool({ id: 4, shape: 'sphere', pos: [0.2, 0.2, 1.05], radius: 0.1, active: true });
  await sleep(150);
  const s = await c2.stats();
  assert.equal(s.tools.find(t => t.id === 4).active, true);
  assert.equal(s.tools.find(t => t.id === 2).active, false);
  await c2.close();
  await ctl.close();
});
