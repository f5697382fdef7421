// serve.test.mjs - what `squish serve` does with the scenes it loads, and replies a client
// matches by ref: scenes that cannot start are left out with a message, error replies to
// unparseable JSON carry the ref, stats pushes keep the asked rate.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { execFileSync } from 'node:child_process';
import { mkdtempSync, writeFileSync } from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { SquishClient } from './client.mjs';
import { startServer, SQUISH, sleep } from './harness.mjs';

const box = (name, { material = { E: 1e5, nu: 0.3, density: 1000 }, fixed = [[-1, -1, -1], [2, 2, 0.001]], levels = ['box.msh'] } = {}) =>
  JSON.stringify({ name, bodies: [{ name: 'box', levels, material, fixed: [{ box: fixed }] }] });

test('scenes that cannot start are left out at start-up, each with a message naming the file and the problem', async () => {
  const dir = mkdtempSync(path.join(os.tmpdir(), 'squish-check-'));
  execFileSync(SQUISH, ['mesh', 'box', '3', '3', '3', '--out', path.join(dir, 'box.msh')]);
  writeFileSync(path.join(dir, 'good.json'), box('good'));
  writeFileSync(path.join(dir, 'all-fixed.json'), box('all-fixed', { fixed: [[-1, -1, -1], [2, 2, 2]] }));
  writeFileSync(path.join(dir, 'stiff.json'), box('stiff', { material: { E: 1e18, nu: 0.3, density: 1000 } }));
  writeFileSync(path.join(dir, 'no-mesh.json'), box('no-mesh', { levels: ['missing.msh'] }));
  const srv = await startServer(['--scenes', dir]);
  try {
    const c = await SquishClient.connect(srv.url);
    assert.deepEqual(c.welcome.scenes, ['good']);
    assert.deepEqual((await c.listScenes()).map(s => s.name), ['good']);
    await c.open('good');
    await c.close();
    const err = srv.stderr();
    assert.match(err, /skipping scene .*all-fixed\.json: bodies\[0\] \("box"\): .*fix all \d+ nodes/);
    assert.match(err, /skipping scene .*stiff\.json: bodies\[0\] \("box"\): .*needs 2\^\d+ substeps.*the limit is 2\^20/);
    assert.match(err, /skipping scene .*no-mesh\.json: bodies\[0\]\.levels\[0\]: mesh file "missing\.msh" .*cannot be read/);
  } finally { await srv.stop(); }
});

test('errors to unparseable JSON carry the ref found in the raw text, else "ref": null', async () => {
  const srv = await startServer();
  try {
    const c = await SquishClient.connect(srv.url);
    const next = () => c.waitFor(m => m.type === 'error', 5000);
    let p = next();
    c.sendRaw('{"type":"ping","ref":"abc","t":1,');            // cut off
    let e = await p;
    assert.equal(e.code, 'bad_json');
    assert.equal(e.ref, 'abc');
    p = next();
    c.sendRaw('{"ref": 17, "type": ping}');                   // bare word
    e = await p;
    assert.deepEqual([e.code, e.ref], ['bad_json', 17]);
    p = next();
    c.sendRaw('{"opts":{"ref":"inner"},"type":}');             // only a nested ref: not taken
    e = await p;
    assert.equal(e.code, 'bad_json');
    assert.ok('ref' in e && e.ref === null, `ref null, got ${JSON.stringify(e)}`);
    p = next();
    c.sendRaw('not json at all');
    e = await p;
    assert.ok('ref' in e && e.ref === null);
    p = next();
    c.sendRaw(Buffer.from([1, 2, 3]), { binary: true });
    e = await p;
    assert.deepEqual([e.code, e.ref], ['bad_json', null]);
    // the connection still works, and a valid request's reply is matched by ref as before
    assert.equal((await c.ping(5)).t, 5);
    await c.close();
  } finally { await srv.stop(); }
});

test('subscribe stats_hz: 2 pushes 2 stats per second, also when the rate is changed after stats: true', async () => {
  const srv = await startServer();
  try {
    const c = await SquishClient.connect(srv.url);
    await c.open('default');
    const at = [];
    c.on('stats', () => at.push(Date.now()));
    const t0 = Date.now();
    const pushed = c.waitFor(() => true, 5000, 'stats');
    await c.subscribe({ stats: true });          // 4 Hz by default, first push at once
    await pushed;
    await c.subscribe({ stats_hz: 2 });          // a rate change: no extra push
    await sleep(1600 - (Date.now() - t0));
    const first = at.filter(t => t - t0 < 1600).length;
    await sleep(4000 - (Date.now() - t0));
    const all = at.filter(t => t - t0 < 4000);
    const gaps = all.slice(1).map((t, i) => t - all[i]);
    console.log(`# stats pushes: ${first} in 1.6 s, ${all.length} in 4 s, gaps ${gaps.join(' ')} ms`);
    // pushes due at 0, 0.5, 1.0, 1.5 s (the 50 ms housekeeping tick and a loaded machine
    // delay them, never add any): at most 4 in the first 1.6 s, 7 to 8 in 4 s
    assert.ok(first <= 4, `${first} stats in 1.6 s at 2 Hz`);
    assert.ok(all.length >= 7 && all.length <= 8, `${all.length} stats in 4 s at 2 Hz`);
    // no two pushes close together: a late push delays the next to half a period (250 ms);
    // 150 ms leaves room for delivery jitter
    assert.ok(Math.min(...gaps) >= 150, `gaps ${gaps}`);
    await c.close();
  } finally { await srv.stop(); }
});
