// haptic.test.mjs - the haptic channel through the JS client library (web/squish-client.js:
// hapticOpen, haptic, hapticClose) against the real server in lockstep (docs/protocol.md,
// "Haptic channel"): a pose answered by one force with its seq, the channel's `ramp` option
// (each frame's substeps take the pose interpolated from the frame before), and the same run
// giving the same forces twice.
import { test, before, after } from 'node:test';
import assert from 'node:assert/strict';
import { SquishClient } from './client.mjs';
import { startServer } from './harness.mjs';

let srv;
before(async () => { srv = await startServer(['--grace', '1', '--lockstep', '--scenes', 'meshes/scenes']); });
after(async () => { await srv.stop(); });

// cube-poke with its scripted finger off and a sphere of ours on the top face (z = 1)
async function pressed(ramp) {
  const c = await SquishClient.connect(srv.url);
  await c.open('cube-poke');
  await c.set({ lod: { mode: 'fixed', level: 2 } }); // smooth forces: no split or merge near the tool
  await c.tool({ id: 1, shape: 'sphere', pos: [0.5, 0.5, 1.3], active: false });
  await c.tool({ id: 2, shape: 'sphere', pos: [0.5, 0.5, 1.1], radius: 0.12 });
  const opened = await c.hapticOpen(2, { stiffness: 0, damping: 0, ramp });
  return { c, opened };
}

const along = f => f[2]; // the body's push back on the tool, up (+z), against the press

// frames with the tool pressing 5 mm further each frame: the frame forces, one per frame
async function pressFrames(c, ch, frames) {
  const out = [];
  for (let k = 1; k <= frames; k++) {
    await c.haptic(ch, [0.5, 0.5, 1.1 - 0.005 * k], 0.02 * k - 0.001);
    await c.step(1);
    out.push(along(c.frames.get(0).tools.find(t => t.id === 2).force));
  }
  return out;
}

test('a pose is answered by one force with its seq; a closed channel is said closed', async () => {
  const { c, opened } = await pressed(undefined);
  assert.equal(opened.type, 'haptic');
  assert.equal(typeof opened.channel, 'number');
  assert.equal(opened.ramp, false);
  await c.step(1);
  const seq = c.hapticSend(opened.channel, [0.5, 0.5, 1.08], 0.001) + 1;
  const f = await c.haptic(opened.channel, [0.5, 0.5, 1.08], 0.002);
  assert.equal(f.seq, seq);
  assert.equal(f.force.length, 3);
  assert.ok(f.force.every(Number.isFinite), `force ${f.force}`);
  const closed = await c.hapticClose(2);
  assert.equal(closed.type, 'haptic');
  assert.equal(closed.open, false);
  await c.close();
});

test('ramp: a frame ramped to a deeper pose presses less than one at that pose from its start', async () => {
  // the same poses with and without ramp: without, each frame holds the new pose at all its
  // substeps; with ramp, its substeps move from the last frame's pose to the new one, so the
  // frame's mean reaction is smaller while the press goes on (the ramped tool is half a step
  // behind on average)
  const plain = await pressed(false);
  const ramped = await pressed(true);
  assert.equal(ramped.opened.ramp, true);
  const fp = await pressFrames(plain.c, plain.opened.channel, 8);
  const fr = await pressFrames(ramped.c, ramped.opened.channel, 8);
  // the sphere's bottom starts 2 cm inside the top face: both press from frame 1, which is
  // the same in both (no frame before it to ramp from); then the ramped one lags (measured:
  // plain 164.5 ... 546.4 N, ramped 116.7 ... 525.9 N in frames 2-8)
  assert.ok(fp[0] > 1 && fp[7] > fp[0], `plain press force ${fp}`);
  for (let k = 1; k < 8; k++)
    assert.ok(fr[k] < fp[k], `frame ${k + 1}: ramped ${fr[k]} N should be below plain ${fp[k]} N`);
  // and the ramped run is deterministic: the same poses give the same forces, bit for bit
  const again = await pressed(true);
  const fa = await pressFrames(again.c, again.opened.channel, 8);
  assert.deepEqual(fa, fr);
  for (const s of [plain, ramped, again])
    await s.c.close();
});
