// badinput.test.mjs - every bad input of docs/protocol.md gets an `error` with its code; the
// connection stays open and nothing changes in the session.
import { test, before, after } from 'node:test';
import assert from 'node:assert/strict';
import { SquishClient } from './client.mjs';
import { startServer, sleep } from './harness.mjs';

let srv;
before(async () => { srv = await startServer(['--max-message', '4096', '--rate', '50', '--token', 'sesame']); });
after(async () => { await srv.stop(); });

/** send raw text (a string, or a Buffer sent as a text frame), return the next error reply */
async function rawError(c, text) {
  const e = c.waitFor(m => m.type === 'error', 5000);
  c.sendRaw(text, { binary: false });
  return e;
}

test('before hello: hello_required; wrong or missing token: bad_token', async () => {
  const c = new SquishClient(srv.url);
  await c._opened;
  let e = await rawError(c, JSON.stringify({ type: 'list_scenes', ref: 'x' }));
  assert.equal(e.code, 'hello_required');
  assert.equal(e.ref, 'x');
  e = await rawError(c, JSON.stringify({ type: 'hello', role: 'control' }));
  assert.equal(e.code, 'bad_token');
  e = await rawError(c, JSON.stringify({ type: 'hello', role: 'control', token: 'nope' }));
  assert.equal(e.code, 'bad_token');
  // a viewer needs no token, but cannot join as control without it
  const w = await c.request({ type: 'hello', role: 'view' });
  assert.equal(w.role, 'view');
  await c.close();
});

test('malformed input of every kind: coded error, connection open, session unchanged', async () => {
  const c = await SquishClient.connect(srv.url, { token: 'sesame' });
  const o = await c.open('default');
  await c.tool({ id: 1, shape: 'sphere', pos: [0.5, 0.5, 1.5], radius: 0.1 });
  await sleep(100);
  const before = await c.stats();

  const cases = [
    ['not json', 'bad_json'],
    ['{"type":"tool",', 'bad_json'],
    ['[1,2,3]', 'bad_json'],
    ['{"type":"ping"} trailing', 'bad_json'],
    ['{"type":"tool","id":1,"pos":[NaN,0,0]}', 'bad_json'],
    ['{"type":"tool","id":1,"pos":[Infinity,0,0]}', 'bad_json'],
    ['{"type":"launch"}', 'bad_type'],
    ['{"type":7}', 'bad_type'],
    ['{"id":1}', 'bad_type'],
    ['{"type":"tool","id":"one"}', 'bad_field'],
    ['{"type":"tool","id":1,"pos":"up"}', 'bad_field'],
    ['{"type":"tool","id":1,"active":"yes"}', 'bad_field'],
    ['{"type":"tool","id":1,"colour":"red"}', 'bad_field'],
    ['{"type":"set","material":{"E":"soft"}}', 'bad_field'],
    ['{"type":"tool","id":1,"pos":[1e999,0,0]}', 'out_of_range'],
    ['{"type":"tool","id":1,"pos":[5000,0,0]}', 'out_of_range'],
    ['{"type":"tool","id":1,"radius":-1}', 'out_of_range'],
    ['{"type":"tool","id":999}', 'out_of_range'],
    ['{"type":"set","material":{"nu":0.5}}', 'out_of_range'],
    ['{"type":"set","material":{"E":-5}}', 'out_of_range'],
    ['{"type":"set","lod":{"budget":2}}', 'out_of_range'],
    ['{"type":"set","lod":{"adapt_every":0}}', 'out_of_range'],
    ['{"type":"set","lod":{"adapt_every":2.5}}', 'out_of_range'],
    ['{"type":"join","session":123456789}', 'unknown_session'],
    ['{"type":"open","scene":"no-such-scene"}', 'unknown_scene'],
    ['{"type":"set","body":7,"operator":"fem"}', 'unknown_body'],
    ['{"type":"nodes","body":3}', 'unknown_body'],
    ['{"type":"tool","id":42,"pos":[0,0,1]}', 'unknown_tool'],
    ['{"type":"step","frames":2}', 'not_lockstep'],
  ];
  for (const [text, code] of cases) {
    const e = await rawError(c, text);
    assert.equal(e.code, code, `${text} -> ${e.code}: ${e.message}`);
    assert.ok(e.message.length > 10, `message for ${text}`);
  }
  // oversized message (> --max-message 4096)
  const big = JSON.stringify({ type: 'ping', pad: 'x'.repeat(10000) });
  let e = await rawError(c, big);
  assert.equal(e.code, 'too_large');
  // binary from the client
  const bin = c.waitFor(m => m.type === 'error', 5000);
  c.sendRaw(Buffer.from([1, 2, 3]), { binary: true });
  e = await bin;
  assert.equal(e.code, 'bad_json');
  assert.match(e.message, /binary/);
  // non-ASCII input quoted in a message (cut after 37 bytes, inside a UTF-8 sequence): the
  // error stays valid UTF-8, so the client keeps its connection
  e = await rawError(c, JSON.stringify({ type: 'tool', id: 'x' + 'é'.repeat(30) }));
  assert.equal(e.code, 'bad_field');
  // a text frame that is not UTF-8 at all (its ref is not echoed: it is not text)
  e = await rawError(c, Buffer.concat([Buffer.from('{"type":"open","ref":"'), Buffer.from([0xff, 0xfe]), Buffer.from('"}')]));
  assert.equal(e.code, 'bad_json');
  assert.match(e.message, /UTF-8/);

  // still connected, same session, nothing changed
  const pong = await c.ping(1);
  assert.equal(pong.type, 'pong');
  const after = await c.stats();
  assert.equal(after.session, o.session);
  assert.deepEqual(after.tools, before.tools);
  const set = await c.set({ operator: 'fem' });
  assert.equal(set.bodies[0].settings.material.nu, o.bodies[0].settings.material.nu);
  await c.close();
});

test('control requests from a viewer: not_controller, nothing changes', async () => {
  const ctl = await SquishClient.connect(srv.url, { token: 'sesame' });
  const o = await ctl.open('default');
  const v = await SquishClient.connect(srv.url, { role: 'view' });
  await v.join(o.session);
  await assert.rejects(v.join(o.session, 'control'), e => e.code === 'bad_token');
  for (const msg of [{ type: 'tool', id: 1, shape: 'grab', pos: [0, 0, 0] }, { type: 'set', operator: 'paper' },
    { type: 'pause' }, { type: 'resume' }, { type: 'reset' }])
    await assert.rejects(v.request(msg), e => e.code === 'not_controller', msg.type);
  const s = await ctl.stats();
  assert.equal(s.tools.length, 0);
  assert.equal(s.paused, false);
  await v.close();
  await ctl.close();
});

test('more requests than --rate per second: rate_limited, then served again', async () => {
  const c = await SquishClient.connect(srv.url, { token: 'sesame' });
  const replies = [];
  c.on('message', m => replies.push(m));
  for (let i = 0; i < 120; i++) c.sendRaw(JSON.stringify({ type: 'ping', t: i }));
  await sleep(500);
  const limited = replies.filter(m => m.type === 'error' && m.code === 'rate_limited').length;
  const pongs = replies.filter(m => m.type === 'pong').length;
  assert.ok(limited > 0, 'some requests were limited');
  assert.ok(pongs >= 49 && pongs <= 120 - limited, `pongs ${pongs}`);
  await sleep(1100);
  assert.equal((await c.ping(5)).t, 5);
  await c.close();
});

test('session limits: server_full and session_full', async () => {
  const s2 = await startServer(['--max-sessions', '1', '--max-clients', '1']);
  try {
    const a = await SquishClient.connect(s2.url);
    const o = await a.open('default');
    const b = await SquishClient.connect(s2.url);
    await assert.rejects(b.open('default'), e => e.code === 'server_full');
    await assert.rejects(b.join(o.session), e => e.code === 'session_full');
    await a.close();
    await b.close();
  } finally {
    await s2.stop();
  }
});

test('origin allow-list: other origins are refused at the upgrade', async () => {
  const s2 = await startServer(['--origin', 'http://good.example']);
  try {
    const ok = await SquishClient.connect(s2.url, { origin: 'http://good.example' });
    await ok.close();
    await assert.rejects(SquishClient.connect(s2.url, { origin: 'http://evil.example' }));
    await assert.rejects(SquishClient.connect(s2.url));
  } finally {
    await s2.stop();
  }
});
