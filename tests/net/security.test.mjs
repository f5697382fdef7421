// security.test.mjs - the attacks of docs/security.md, each against the real server with real
// clients on loopback, bounded in time and count: every test here failed before its fix.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import net from 'node:net';
import { SquishClient } from './client.mjs';
import { startServer, sleep } from './harness.mjs';

/** raw HTTP/1.1 over one TCP connection: send `text`, collect what comes back until the
 * server closes or `ms` pass; resolves with { text, closed } */
function rawHttp(port, text, ms = 5000) {
  return new Promise(resolve => {
    const s = net.connect(port, '127.0.0.1');
    let got = '', closed = false;
    const done = () => { clearTimeout(timer); s.destroy(); resolve({ text: got, closed }); };
    const timer = setTimeout(done, ms);
    s.on('data', d => { got += d.toString('latin1'); });
    s.on('error', () => {});
    s.on('close', () => { closed = true; done(); });
    s.on('connect', () => s.write(text));
  });
}

const snapGet = (id, size = '64x64') =>
  `GET /snapshot.png?session=${id}&size=${size} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n`;

test('pipelined snapshots on one keep-alive connection: closed, no slot leaked, server alive', async () => {
  const srv = await startServer();
  try {
    const a = await SquishClient.connect(srv.url);
    const b = await SquishClient.connect(srv.url);
    const oa = await a.open('default'), ob = await b.open('default');
    // 12 pipelined pairs: more than the 8 server-wide snapshot places, so a place leaked per
    // pair (the old behaviour) would leave every later snapshot at 429
    for (let k = 0; k < 12; k++) {
      const r = await rawHttp(srv.port, snapGet(oa.session) + snapGet(ob.session), 5000);
      assert.ok(r.closed, `pair ${k}: the connection is closed, not left hanging`);
      await sleep(300); // the per-session snapshot interval (0.25 s)
    }
    await sleep(500);
    const res = await fetch(`${srv.http}/snapshot.png?session=${oa.session}&size=64x64`);
    assert.equal(res.status, 200, `a snapshot after the pipelined pairs: ${res.status} ${await res.text()}`);
    // one request per connection still works as before, on keep-alive
    const one = await rawHttp(srv.port, snapGet(ob.session), 5000);
    assert.match(one.text, /^HTTP\/1.1 200/);
    assert.equal((await a.ping(1)).t, 1);
    await a.close(); await b.close();
  } finally {
    const { code } = await srv.stop();
    assert.equal(code, 0);
  }
});

test('8 concurrent 2048x2048 snapshots are all answered (none cut by a 5 s timeout)', async () => {
  const srv = await startServer();
  try {
    const cs = [], os = [];
    for (let i = 0; i < 8; i++) {
      const c = await SquishClient.connect(srv.url);
      cs.push(c);
      os.push(await c.open('default'));
    }
    const t0 = Date.now();
    const rs = await Promise.all(os.map(o => fetch(`${srv.http}/snapshot.png?session=${o.session}&size=2048x2048`)
      .then(async r => ({ status: r.status, bytes: (await r.arrayBuffer()).byteLength, ms: Date.now() - t0 }))
      .catch(e => ({ status: 'error', bytes: 0, ms: Date.now() - t0, e: e.message }))));
    for (const r of rs) {
      assert.equal(r.status, 200, JSON.stringify(rs));
      assert.ok(r.bytes > 1000);
    }
    await Promise.all(cs.map(c => c.close()));
  } finally {
    await srv.stop();
  }
});

/** frames per second a client receives over `ms` */
async function frameRate(c, ms) {
  let n = 0;
  const on = () => { n++; };
  c.on('binary', on);
  await sleep(ms);
  c.off('binary', on);
  return n / (ms / 1000);
}

test('nodes amplification: 10 non-reading viewers spamming nodes cannot starve an honest viewer', async () => {
  const { mkdtempSync } = await import('node:fs');
  const os = await import('node:os');
  const path = await import('node:path');
  const { makeBoxScene, rssKiB } = await import('./harness.mjs');
  const dir = await makeBoxScene(mkdtempSync(path.join(os.tmpdir(), 'squish-sec-')), 'box16', 16);
  const srv = await startServer(['--scenes', dir]);
  try {
    const ctl = await SquishClient.connect(srv.url);
    const o = await ctl.open('box16');
    const honest = await SquishClient.connect(srv.url, { role: 'view', decode: false });
    await honest.join(o.session);
    const base = await frameRate(honest, 2000);
    const rss0 = rssKiB(srv.pid);
    const spammers = await Promise.all(Array.from({ length: 10 }, () =>
      SquishClient.connect(srv.url, { role: 'view', decode: false })));
    await Promise.all(spammers.map(s => s.join(o.session)));
    for (const s of spammers) s.ws._socket.pause(); // never read a reply
    // each sends 20 nodes requests every 100 ms (200/s, the default --rate) for 6 s
    const msg = JSON.stringify({ type: 'nodes', body: 0 });
    const spam = setInterval(() => { for (const s of spammers) for (let i = 0; i < 20; i++) s.sendRaw(msg); }, 100);
    await sleep(2000);
    const during = await frameRate(honest, 4000);
    clearInterval(spam);
    const rss1 = rssKiB(srv.pid);
    // a 50 Hz session on a loaded 2-vCPU machine: the honest viewer keeps at least half its rate
    console.log(`# honest viewer ${base.toFixed(1)} -> ${during.toFixed(1)} frames/s; RSS +${rss1 - rss0} KiB`);
    assert.ok(during >= 0.5 * base, `honest viewer: ${base.toFixed(1)} frames/s before, ${during.toFixed(1)} during the spam`);
    assert.ok(rss1 - rss0 < 64 * 1024, `server RSS grew by ${rss1 - rss0} KiB`);
    for (const s of spammers) s.ws.terminate();
    await sleep(300);
    // the session goes on, and a nodes request of a reading client is answered at once
    const reply = await honest.request({ type: 'nodes', body: 0 }, 5000);
    assert.equal(reply.count, 17 * 17 * 17);
    await honest.close();
    await ctl.close();
  } finally {
    const t0 = Date.now();
    const { code } = await srv.stop();
    assert.equal(code, 0);
    assert.ok(Date.now() - t0 < 2000, `SIGTERM took ${Date.now() - t0} ms`);
  }
});

test('compute budget: a set predictably over the frame budget is refused with its predicted cost; others keep their rate', async () => {
  const srv = await startServer();
  try {
    const victim = await SquishClient.connect(srv.url);
    await victim.open('default');
    const attacker = await SquishClient.connect(srv.url);
    await attacker.open('default');
    await sleep(500);
    const before = await victim.stats();
    // E = 1e10 Pa at 1 kg/m^3 needs 2^16 substeps per frame on the default cube
    const e = await attacker.set({ material: { E: 1e10, density: 1 } }).then(() => null, x => x);
    assert.ok(e, 'the set was refused');
    assert.equal(e.code, 'over_budget');
    assert.match(e.message, /predicted cost [\d.]+ ms of CPU per frame .*65536 substeps x 729 nodes.*frame budget of 20\.0 ms/);
    // nothing changed, and a set within the budget still passes
    const s = await attacker.stats();
    assert.equal(s.paused, false);
    const ok = await attacker.set({ material: { E: 2e5 } });
    assert.equal(ok.type, 'ack');
    // a set flood (the default --rate of 200/s, for 2 s) does not freeze the flooder's viewers
    const viewer = await SquishClient.connect(srv.url, { role: 'view', decode: false });
    await viewer.join(attacker.session);
    const base = await frameRate(viewer, 2000);
    const flood = setInterval(() => {
      for (let i = 0; i < 20; i++)
        attacker.sendRaw(JSON.stringify({ type: 'set', material: { E: 1e10, density: 1 } }));
    }, 100);
    const rate = await frameRate(viewer, 2000);
    clearInterval(flood);
    // on a loaded 2-vCPU machine: at least half the rate it had before (a frozen viewer gets 0)
    assert.ok(rate >= 0.5 * base, `the flooder's viewer: ${base} frames/s before, ${rate} during the set flood`);
    const after = await victim.stats();
    const frames = after.frame - before.frame;
    assert.ok(frames > 50, `the other session stepped ${frames} frames`);
    await Promise.all([victim, attacker, viewer].map(c => c.close()));
  } finally {
    await srv.stop();
  }
});

test('compute budget: a scene far over its budget is paused with an over_budget event', async () => {
  const { mkdtempSync } = await import('node:fs');
  const os = await import('node:os');
  const path = await import('node:path');
  const { makeBoxScene } = await import('./harness.mjs');
  // a 0.2 ms budget: the 20^3 box needs about 3 ms per frame, 15x over (the pause needs 10
  // frames in a row over 2x the budget; the 12^3 box, at 0.3 ms with the sharp step bound, was
  // not far enough over to be sure of it)
  const dir = await makeBoxScene(mkdtempSync(path.join(os.tmpdir(), 'squish-sec-')), 'box20', 20);
  const srv = await startServer(['--scenes', dir, '--frame-budget', '0.01']);
  try {
    const c = await SquishClient.connect(srv.url);
    const ev = c.waitFor(e => e.kind === 'over_budget', 10000, 'event');
    await c.open('box20');
    const e = await ev;
    assert.match(e.message, /session paused: its frames take [\d.]+ ms of CPU, over the frame budget of 0\.2 ms/);
    assert.ok(e.frame_ms > e.budget_ms);
    const s = await c.stats();
    assert.equal(s.paused, true);
    await c.close();
  } finally {
    await srv.stop();
  }
});

test('SIGTERM within 2 s while a 16 s frame is being computed (the frame is abandoned)', async () => {
  const { mkdtempSync } = await import('node:fs');
  const os = await import('node:os');
  const path = await import('node:path');
  const { makeBoxScene } = await import('./harness.mjs');
  const dir = await makeBoxScene(mkdtempSync(path.join(os.tmpdir(), 'squish-sec-')), 'box16', 16);
  // an operator who allows anything: frames of 2^16 substeps x 4913 nodes
  const srv = await startServer(['--scenes', dir, '--frame-budget', '1e6']);
  const c = await SquishClient.connect(srv.url);
  await c.open('box16');
  await c.set({ material: { E: 1e10, density: 1 } });
  await sleep(1500); // well inside the first long frame
  const t0 = Date.now();
  const { code } = await srv.stop('SIGTERM', 20000);
  const ms = Date.now() - t0;
  assert.equal(code, 0);
  assert.ok(ms < 2000, `SIGTERM took ${ms} ms`);
});

test('sessions per address: --max-sessions-per-addr caps what one address opens without the token', async () => {
  const srv = await startServer(['--token', 'sesame', '--max-sessions', '16', '--grace', '30',
    '--max-sessions-per-addr', '2']);
  try {
    // one client opens and leaves sessions as fast as it can: each stays, empty, for the grace time
    const v = await SquishClient.connect(srv.url, { role: 'view' });
    const ids = [];
    let refused = null;
    for (let i = 0; i < 6 && !refused; i++)
      await v.open('default').then(o => ids.push(o.session), e => { refused = e; });
    assert.equal(ids.length, 2, 'two sessions from 127.0.0.1, then refused');
    assert.equal(refused.code, 'server_full');
    assert.match(refused.message, /2 sessions opened from 127\.0\.0\.1 are running \(--max-sessions-per-addr 2\)/);
    // another connection from the same address is under the same cap, and may still join
    const w = await SquishClient.connect(srv.url, { role: 'view' });
    await assert.rejects(w.open('default'), e => e.code === 'server_full');
    assert.equal((await w.join(ids[0])).session, ids[0]);
    // the token holder is not counted against the address
    const t = await SquishClient.connect(srv.url, { token: 'sesame' });
    for (let i = 0; i < 3; i++) assert.ok((await t.open('default')).session > 0);
    await Promise.all([v, w, t].map(c => c.close()));
  } finally {
    await srv.stop();
  }
});

test('session slots: a client without the token cannot take the slots kept for token holders', async () => {
  const srv = await startServer(['--token', 'sesame', '--max-sessions', '4', '--grace', '30']);
  try {
    // a viewer (no token) opens sessions as fast as it can: each open leaves an empty one
    const v = await SquishClient.connect(srv.url, { role: 'view' });
    const ids = [];
    let refused = null;
    for (let i = 0; i < 8 && !refused; i++)
      await v.open('default').then(o => ids.push(o.session), e => { refused = e; });
    assert.equal(ids.length, 3, 'a quarter of --max-sessions 4 (one) is kept');
    assert.equal(refused.code, 'server_full');
    assert.match(refused.message, /kept for clients with the control token/);
    // the token holder still gets a session
    const t = await SquishClient.connect(srv.url, { token: 'sesame' });
    const o = await t.open('default');
    assert.ok(o.session > 0);
    // ids are random, not sequential: integers below 2^53 that differ in their high bits
    const all = [...ids, o.session];
    for (const id of all) assert.ok(Number.isSafeInteger(id) && id > 1024, `id ${id}`);
    const gens = all.map(id => Math.floor(id / 1024));
    assert.equal(new Set(gens).size, gens.length);
    assert.ok(Math.max(...gens) > 2 ** 20, `generations ${gens} look sequential`);
    // an id is good for joins and snapshots; a neighbouring id is not
    const w = await SquishClient.connect(srv.url, { role: 'view' });
    assert.equal((await w.join(o.session)).session, o.session);
    await assert.rejects(w.join(o.session + 1024), e => e.code === 'unknown_session');
    assert.equal((await fetch(`${srv.http}/snapshot.png?session=${o.session}&size=32x32`)).status, 200);
    await Promise.all([v, t, w].map(c => c.close()));
  } finally {
    await srv.stop();
  }
});

/** CPU seconds (user + system) a process has used */
async function cpuSeconds(pid) {
  const { readFileSync } = await import('node:fs');
  const f = readFileSync(`/proc/${pid}/stat`, 'utf8').split(') ')[1].split(' ');
  return (Number(f[11]) + Number(f[12])) / 100; // clock ticks of 10 ms
}

/** open a TCP connection from a loopback source address; resolves with the socket or null */
function tcpFrom(port, localAddress) {
  return new Promise(resolve => {
    const s = net.connect({ port, host: '127.0.0.1', localAddress });
    s.on('error', () => resolve(null));
    s.on('connect', () => resolve(s));
  });
}

test('connections: per-address cap, no busy loop or log flood at the fd limit, /healthz reachable', async () => {
  // a file-descriptor limit of 200 (soft and hard), as a small container would have
  const srv = await startServer(['--max-conns-per-addr', '40'], { prefix: ['prlimit', '--nofile=200:200', '--'] });
  const socks = [];
  try {
    const cpu0 = await cpuSeconds(srv.pid);
    // 400 connections from 127.0.0.2, more than the fds the process has
    for (let i = 0; i < 400; i++) {
      const s = await tcpFrom(srv.port, '127.0.0.2');
      if (s) { s.on('close', () => { s.gone = true; }); socks.push(s); }
    }
    await sleep(2000);
    const open = socks.filter(s => !s.gone && !s.destroyed).length;
    assert.ok(open <= 40, `${open} connections of one address stayed open (cap 40)`);
    const cpu = await cpuSeconds(srv.pid) - cpu0;
    assert.ok(cpu < 1.0, `the server used ${cpu} s of CPU for 400 connection attempts`);
    // another address still gets its health check, and the metrics count the refusals
    const h = await fetch(`${srv.http}/healthz`);
    assert.equal(h.status, 200);
    const m = await (await fetch(`${srv.http}/metrics`)).text();
    const refused = Number(m.match(/^squish_connections_refused_total (\d+)/m)[1]);
    assert.ok(refused >= 300, `refused ${refused}`);
    assert.ok(srv.stderr().length < 20000, `stderr has ${srv.stderr().length} bytes`);
  } finally {
    for (const s of socks) s.destroy();
    await srv.stop();
  }
});

test('idle timeout: a WebSocket that neither reads nor answers pings is closed; a reading client stays', async () => {
  const srv = await startServer(['--idle-timeout', '2']);
  try {
    const stuck = await SquishClient.connect(srv.url, { role: 'view', decode: false });
    const reader = await SquishClient.connect(srv.url, { role: 'view', decode: false });
    const o = await reader.open('default');
    await stuck.join(o.session);
    assert.equal((await reader.stats()).clients, 2);
    stuck.ws._socket.pause(); // it reads nothing from now on, pings included
    const t0 = Date.now();
    let clients = 2;
    while (clients === 2 && Date.now() - t0 < 8000) {
      await sleep(250);
      clients = (await reader.stats()).clients;
    }
    assert.equal(clients, 1, 'the server closed the stuck client');
    assert.ok(Date.now() - t0 < 7000, `after ${Date.now() - t0} ms`);
    assert.equal(reader.ws.readyState, 1, 'the reading client (it answers pings) is still open');
    assert.equal((await reader.ping(5)).t, 5);
    await reader.close();
    stuck.ws.terminate();
  } finally {
    await srv.stop();
  }
});

test('/healthz: HEAD answers 200; a frozen session makes it 503 with the reason', async () => {
  const { mkdtempSync } = await import('node:fs');
  const os = await import('node:os');
  const path = await import('node:path');
  const { makeBoxScene } = await import('./harness.mjs');
  const dir = await makeBoxScene(mkdtempSync(path.join(os.tmpdir(), 'squish-sec-')), 'box16', 16);
  const srv = await startServer(['--scenes', dir, '--frame-budget', '1e6']);
  try {
    const head = await fetch(`${srv.http}/healthz`, { method: 'HEAD' });
    assert.equal(head.status, 200);
    const c = await SquishClient.connect(srv.url);
    await c.open('box16');
    assert.equal((await fetch(`${srv.http}/healthz`)).status, 200);
    await c.set({ material: { E: 1e10, density: 1 } }); // 16 s frames from now on
    await sleep(3500);
    const r = await fetch(`${srv.http}/healthz`);
    const text = await r.text();
    assert.equal(r.status, 503, text);
    assert.match(text, /unhealthy: session \d+ has not finished a frame for [\d.]+ s/);
    assert.equal((await fetch(`${srv.http}/healthz`, { method: 'HEAD' })).status, 503);
    c.ws.terminate();
  } finally {
    await srv.stop('SIGTERM', 20000);
  }
});

test('HTTP: POST gets 405, a long request line 414, a refused Origin 403, no symlink out of the web root', async () => {
  const { mkdtempSync, writeFileSync, symlinkSync, mkdirSync } = await import('node:fs');
  const os = await import('node:os');
  const path = await import('node:path');
  const tmp = mkdtempSync(path.join(os.tmpdir(), 'squish-web-'));
  const web = path.join(tmp, 'web');
  mkdirSync(web);
  writeFileSync(path.join(web, 'index.html'), '<p>viewer</p>');
  writeFileSync(path.join(tmp, 'secret.txt'), 'the secret');
  symlinkSync(path.join(tmp, 'secret.txt'), path.join(web, 'leak.txt'));
  symlinkSync(tmp, path.join(web, 'up'));
  const srv = await startServer(['--web', web, '--origin', 'http://good.example']);
  try {
    assert.equal((await fetch(`${srv.http}/`, { method: 'POST', body: 'x=1' })).status, 405);
    assert.equal((await fetch(`${srv.http}/index.html`)).status, 200);
    for (const p of ['/leak.txt', '/up/secret.txt']) {
      const r = await fetch(`${srv.http}${p}`);
      const body = await r.text();
      assert.equal(r.status, 404, p);
      assert.ok(!body.includes('the secret'), p);
    }
    const long = await rawHttp(srv.port, `GET /${'a'.repeat(6000)} HTTP/1.1\r\nHost: x\r\n\r\n`);
    assert.match(long.text, /^HTTP\/1.1 414/);
    const up = await rawHttp(srv.port, 'GET /ws HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n' +
      'Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\nOrigin: http://evil.example\r\n\r\n');
    assert.match(up.text, /^HTTP\/1.[01] 403/);
  } finally {
    await srv.stop();
  }
});

test('token guessing is throttled per address with a clear error', async () => {
  const srv = await startServer(['--token', 'sesame']);
  try {
    const c = new SquishClient(srv.url);
    await c._opened;
    const codes = [];
    for (let i = 0; i < 8; i++)
      codes.push(await c.request({ type: 'hello', role: 'control', token: `guess${i}` }).then(() => 'ok', e => e.code));
    assert.deepEqual(codes.slice(0, 5), Array(5).fill('bad_token'));
    assert.deepEqual(codes.slice(5), Array(3).fill('throttled'));
    // even the right token waits now, from this address
    const e = await c.request({ type: 'hello', role: 'control', token: 'sesame' }).then(() => null, x => x);
    assert.equal(e.code, 'throttled');
    assert.match(e.message, /5 wrong tokens from 127\.0\.0\.1; wait \d+ s/);
    await c.close();
  } finally {
    await srv.stop();
  }
});

test('/metrics: Prometheus text whose counters move', async () => {
  const srv = await startServer();
  try {
    const scrape = async () => {
      const r = await fetch(`${srv.http}/metrics`);
      assert.equal(r.status, 200);
      assert.match(r.headers.get('content-type'), /^text\/plain/);
      const t = await r.text();
      const v = name => { const m = t.match(new RegExp(`^${name} (\\S+)$`, 'm')); return m ? Number(m[1]) : NaN; };
      return { t, v };
    };
    const a = await scrape();
    assert.match(a.t, /# TYPE squish_frames_total counter/);
    assert.equal(a.v('squish_sessions'), 0);
    const c = await SquishClient.connect(srv.url);
    const o = await c.open('default');
    c.sendRaw('not json');
    await assert.rejects(c.set({ material: { E: 1e10, density: 1 } }), e => e.code === 'over_budget');
    await sleep(1000);
    const b = await scrape();
    assert.equal(b.v('squish_sessions'), 1);
    assert.equal(b.v('squish_clients'), 1);
    assert.ok(b.v('squish_frames_total') > a.v('squish_frames_total') + 10);
    assert.ok(b.v('squish_bytes_out_total') > a.v('squish_bytes_out_total'));
    assert.match(b.t, /^squish_refused_total\{code="bad_json"\} 1$/m);
    assert.match(b.t, /^squish_refused_total\{code="over_budget"\} 1$/m); // a session thread's refusal
    assert.match(b.t, new RegExp(`^squish_session_frame_seconds\\{session="${o.session}"\\} [\\d.e-]+$`, 'm'));
    for (const name of ['squish_deadline_misses_total', 'squish_resets_total', 'squish_connections'])
      assert.ok(Number.isFinite(b.v(name)), name);
    await c.close();
  } finally {
    await srv.stop();
  }
});
