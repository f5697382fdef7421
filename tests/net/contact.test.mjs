// contact.test.mjs - obstacles and contact forces in the protocol (docs/protocol.md), against the
// real server: the obstacles of opened, the contact force of stats in lockstep runs, the
// "obstacles" message of a moving obstacle, and a broken obstacle skipped with its fix named.
import { test, before, after } from 'node:test';
import assert from 'node:assert/strict';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import { SquishClient } from './client.mjs';
import { startServer } from './harness.mjs';

const ROOT = path.resolve(path.dirname(fileURLToPath(import.meta.url)), '../..');
const CUBE = path.join(ROOT, 'meshes/cube/cube_l1.msh');

// a scene directory: a cube dropped onto a floor under a sphere that moves, and a broken scene
const dir = fs.mkdtempSync(path.join(os.tmpdir(), 'squish-contact-'));
const body = {
  name: 'block', levels: [CUBE], scale: 0.2, offset: [0, 0, 0.01],
  material: { E: 30000, nu: 0.3, density: 1000, damping: { rayleigh_mass: 4.0 } },
  elasticity: 'corotational', lod: { mode: 'fixed' },
};
fs.writeFileSync(path.join(dir, 'moving.json'), JSON.stringify({
  name: 'moving', bodies: [body],
  obstacles: [
    { name: 'floor', type: 'plane', point: [0, 0, 0], friction: { static: 0.6, kinetic: 0.4 } },
    { name: 'ball', type: 'sphere', center: [0.5, 0.1, 0.1], radius: 0.05,
      keyframes: [{ t: 0, pos: [0, 0, 0] }, { t: 1, pos: [0.1, 0, 0] }] },
  ],
}));
fs.writeFileSync(path.join(dir, 'broken.json'), JSON.stringify({
  name: 'broken', bodies: [body], obstacles: [{ name: 'slab', type: 'box', center: [0, 0, -1], size: [1, -1, 1] }],
}));

let srv;
before(async () => { srv = await startServer(['--grace', '1', '--scenes', dir, '--lockstep']); });
after(async () => { await srv.stop(); fs.rmSync(dir, { recursive: true, force: true }); });

test('a broken obstacle skips its scene with the obstacle and the fix named; the others load', async () => {
  const c = await SquishClient.connect(srv.url);
  const names = (await c.listScenes()).map(s => s.name);
  assert.ok(names.includes('moving'));
  assert.ok(!names.includes('broken'));
  assert.match(srv.stderr(), /broken\.json: obstacles\[0\]: obstacle "slab": box size .* must be positive/);
  await c.close();
});

test('opened lists the obstacles; stats report the contact force (lockstep: the weight at rest)', async () => {
  const c = await SquishClient.connect(srv.url);
  const o = await c.open('moving');
  assert.equal(o.obstacles.length, 2);
  const [floor, ball] = o.obstacles;
  assert.deepEqual([floor.name, floor.type, floor.normal, floor.moving], ['floor', 'plane', [0, 0, 1], false]);
  assert.deepEqual(floor.friction, { static: 0.6, kinetic: 0.4 });
  assert.deepEqual([ball.type, ball.radius, ball.moving], ['sphere', 0.05, true]);
  // the moving ball: one "obstacles" message per stepped frame with its offset
  const moves = [];
  c.on('message', m => { if (m.type === 'obstacles') moves.push(m); });
  await c.step(100);
  assert.ok(moves.length >= 100, `${moves.length} obstacles messages for 100 frames`);
  const last = moves[moves.length - 1];
  assert.equal(last.obstacles[1].name, 'ball');
  assert.ok(Math.abs(last.obstacles[1].offset[0] - 0.1) < 1e-9, `ball offset ${last.obstacles[1].offset}`);
  assert.deepEqual(last.obstacles[0].offset, [0, 0, 0]);
  await c.step(50);
  const s = await c.stats();
  const ct = s.bodies[0].contact;
  // 8 kg (0.2 m cube, 1000 kg/m^3) resting after 3 s with strong damping: the floor carries
  // its weight, 78.48 N, within 2 % (what is left of the landing)
  assert.ok(Math.abs(ct.force[2] - 78.48) < 0.02 * 78.48, `contact force ${ct.force}`);
  assert.ok(ct.nodes > 0);
  assert.ok(ct.depth >= 0 && ct.depth < 0.002, `depth ${ct.depth}`);
  assert.equal(s.obstacles.length, 2);
  assert.equal(s.resets, 0);
  await c.close();
});
