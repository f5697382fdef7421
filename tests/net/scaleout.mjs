// scaleout.mjs - the Docker topology without Docker: Debian's nginx, started here with
// docker/nginx.conf (only its addresses replaced by loopback ports, plus its own pid, log and
// temp paths), in front of three real `squish serve --instance N`. Run by
// tests/stages/scaleout.sh (node --test). Shows: sessions spread and stick (share links,
// join by id and /snapshot.png reach the instance that holds the session), WebSocket upgrade
// and frames through the proxy, and what an instance lost mid-session does to its clients
// (a clear close; a reconnect lands on a live instance, which refuses the old id with
// unknown_session and opens a new session). Everything is bounded in time.
import test from 'node:test';
import assert from 'node:assert/strict';
import { spawn } from 'node:child_process';
import { mkdtempSync, readFileSync, writeFileSync, rmSync, chmodSync, mkdirSync, existsSync } from 'node:fs';
import net from 'node:net';
import os from 'node:os';
import path from 'node:path';
import { startServer, ROOT, sleep } from './harness.mjs';
import { SquishClient, SquishError } from './client.mjs';

const NGINX = process.env.NGINX || '/usr/sbin/nginx';
const CONF = path.join(ROOT, 'docker/nginx.conf');
const COMPOSE = path.join(ROOT, 'docker/compose.yaml');

function freePort() {
  return new Promise((resolve, reject) => {
    const s = net.createServer();
    s.once('error', reject);
    s.listen(0, '127.0.0.1', () => { const p = s.address().port; s.close(() => resolve(p)); });
  });
}

/** docker/nginx.conf with squishN:8080 -> 127.0.0.1:ports[N-1] and listen 80 -> the test's port */
export function loopbackConfig(text, ports, listen, dir) {
  let out = text;
  ports.forEach((p, i) => {
    const host = `squish${i + 1}:8080`;
    assert.ok(out.includes(host), `docker/nginx.conf names ${host}`);
    out = out.split(host).join(`127.0.0.1:${p}`);
  });
  assert.ok(/\n\s*listen 80;/.test(out), 'docker/nginx.conf listens on port 80');
  out = out.replace(/\n(\s*)listen 80;/, `\n$1listen 127.0.0.1:${listen};`);
  // the test's own files (the compose image uses nginx's defaults)
  const own = ['client_body', 'proxy', 'fastcgi', 'uwsgi', 'scgi']
    .map(t => `    ${t}_temp_path ${dir}/${t};`).join('\n');
  out = out.replace(/\nhttp \{\n/, `\nhttp {\n${own}\n    access_log ${dir}/access.log;\n`);
  return out;
}

async function waitHttp(url, ms = 10000) {
  const until = Date.now() + ms;
  for (;;) {
    try {
      const r = await fetch(url);
      if (r.ok) return r;
    } catch (e) { /* not up yet */ }
    if (Date.now() > until) throw new Error(`${url} did not answer within ${ms} ms`);
    await sleep(100);
  }
}

/** instance number named by a session id (its last two decimal digits) */
const instanceOf = id => id % 100;

test('scale-out: nginx (docker/nginx.conf) in front of three instances', { timeout: 120000 }, async t => {
  assert.ok(existsSync(NGINX), `${NGINX} missing: make deps installs Debian's nginx`);
  const dir = mkdtempSync(path.join(os.tmpdir(), 'squish-scaleout-'));
  // nginx workers run as an unprivileged user when the test runs as root: they need the temp dirs
  chmodSync(dir, 0o755);
  for (const t of ['client_body', 'proxy', 'fastcgi', 'uwsgi', 'scgi']) { mkdirSync(path.join(dir, t)); chmodSync(path.join(dir, t), 0o777); }
  const servers = [];
  let nginx = null, browser = null;
  const clients = [];
  const track = c => { clients.push(c); return c; };
  try {
    for (let k = 1; k <= 3; k++)
      servers.push(await startServer(['--instance', String(k), '--web', path.join(ROOT, 'web'), '--grace', '5']));
    const port = await freePort();
    const conf = loopbackConfig(readFileSync(CONF, 'utf8'), servers.map(s => s.port), port, dir);
    writeFileSync(path.join(dir, 'nginx.conf'), conf);
    let nginxErr = '';
    nginx = spawn(NGINX, ['-p', dir, '-c', path.join(dir, 'nginx.conf'),
      '-g', `daemon off; pid ${dir}/nginx.pid; error_log ${dir}/error.log notice;`], { stdio: ['ignore', 'ignore', 'pipe'] });
    nginx.stderr.on('data', d => { nginxErr += d; });
    const nginxExit = new Promise(res => nginx.on('exit', code => res(code)));
    const base = `http://127.0.0.1:${port}`, ws = `ws://127.0.0.1:${port}/ws`;
    await Promise.race([waitHttp(`${base}/healthz`),
      nginxExit.then(code => { throw new Error(`nginx exited with ${code}: ${nginxErr}`); })]);

    await t.test('compose runs the tested config', () => {
      const compose = readFileSync(COMPOSE, 'utf8');
      assert.match(compose, /\.\/nginx\.conf:\/etc\/nginx\/nginx\.conf/);
      for (let k = 1; k <= 3; k++) {
        assert.match(compose, new RegExp(`squish${k}:[\\s\\S]*?command: \\["--instance", "${k}"`));
        assert.match(readFileSync(CONF, 'utf8'), new RegExp(`"~\\^\\[0-9\\]\\*0${k}\\$"\\s+squish_${k};`));
      }
    });

    // six controllers open sessions through nginx; each session gets two viewers that join
    // through nginx by id, as a share link does
    const sessions = [];
    await t.test('sessions spread over the instances and stick', async () => {
      for (let i = 0; i < 6; i++) {
        const c = track(await SquishClient.connect(ws, { role: 'control' }));
        const r = await c.open('default');
        sessions.push({ id: r.session, controller: c, viewers: [] });
        // the controller's connection stays open: least_conn sends the next one elsewhere
      }
      const used = new Set(sessions.map(s => instanceOf(s.id)));
      assert.deepEqual([...used].sort(), [1, 2, 3], `sessions ${sessions.map(s => s.id)} use every instance`);
      for (const s of sessions) {
        for (let v = 0; v < 2; v++) {
          const c = track(await SquishClient.connect(`${ws}?session=${s.id}`, { role: 'view' }));
          const r = await c.join(s.id, 'view');
          assert.equal(r.session, s.id);
          s.viewers.push(c);
        }
      }
      // frames flow to every viewer through the proxy
      await sleep(600);
      for (const s of sessions) for (const c of s.viewers) assert.ok(c.framesReceived > 3, `viewer of ${s.id}: ${c.framesReceived} frames`);
      // the routing is real: the session is only in the instance its id names
      const s0 = sessions[0], own = instanceOf(s0.id);
      for (let k = 1; k <= 3; k++) {
        const c = track(await SquishClient.connect(servers[k - 1].url, { role: 'view' }));
        if (k === own) assert.equal((await c.join(s0.id, 'view')).session, s0.id);
        else await assert.rejects(c.join(s0.id, 'view'), e => e instanceof SquishError && e.code === 'unknown_session');
        c.close();
      }
    });

    await t.test('the viewer page and /snapshot.png of every session through nginx', async () => {
      const page = await fetch(`${base}/?session=${sessions[0].id}&role=view`);
      assert.equal(page.status, 200);
      assert.match(await page.text(), /<html/i);
      const js = await fetch(`${base}/main.js`);
      assert.match(await js.text(), /\/ws\$\{app\.session \? `\?session=/, 'the viewer puts the session in its WebSocket URL');
      for (const s of sessions.slice(0, 3)) {
        const r = await fetch(`${base}/snapshot.png?session=${s.id}&size=160x120`);
        assert.equal(r.status, 200, `snapshot of ${s.id}: ${r.status} ${r.status !== 200 ? await r.text() : ''}`);
        assert.equal(r.headers.get('content-type'), 'image/png');
        const b = Buffer.from(await r.arrayBuffer());
        assert.equal(b.subarray(1, 4).toString(), 'PNG');
      }
      // an id that names instance 2 but no session there: a clear 404 from instance 2
      const r = await fetch(`${base}/snapshot.png?session=99999902`);
      assert.equal(r.status, 404);
      assert.match(await r.text(), /no session 99999902/);
    });

    // the real viewer in Debian's chromium: a controller page opens a scene through nginx,
    // three share-link pages join it (each must reach the session's instance: with three
    // instances a viewer that ignored the session in its WebSocket URL would miss it)
    let ctlPage = null, browserSession = null;
    await t.test('the viewer in chromium: share links join through nginx', async () => {
      const { launchBrowser } = await import('../web/helpers.mjs');
      browser = await launchBrowser();
      ctlPage = await browser.newPage();
      await ctlPage.goto(`${base}/?scene=default`);
      await ctlPage.waitForFunction(() => window.squish.session && window.squish.status === 'connected', null, { timeout: 20000 });
      browserSession = Number(await ctlPage.evaluate(() => window.squish.session));
      for (let v = 0; v < 3; v++) {
        const page = await browser.newPage();
        await page.goto(`${base}/?session=${browserSession}&role=view`);
        await page.waitForFunction(() => window.squish.session && window.squish.framesReceived > 2, null, { timeout: 20000 });
        assert.equal(Number(await page.evaluate(() => window.squish.session)), browserSession);
        await page.close();
      }
    });

    // an instance stopped (docker stop: SIGTERM) and one killed (SIGKILL) mid-session
    for (const [signal, label] of [['SIGTERM', 'stopped'], ['SIGKILL', 'killed']]) {
      await t.test(`an instance ${label} mid-session: its clients see a clear close, a reconnect lands on a live one`, async () => {
        const live = sessions.filter(s => servers[instanceOf(s.id) - 1].proc.exitCode === null &&
                                          servers[instanceOf(s.id) - 1].proc.signalCode === null);
        // SIGTERM: the instance of the browser's session, so the page must move too
        const victim = (signal === 'SIGTERM' && browserSession && live.find(s => instanceOf(s.id) === instanceOf(browserSession))) || live[0];
        const k = instanceOf(victim.id);
        const others = live.filter(s => instanceOf(s.id) !== k);
        assert.ok(others.length > 0, 'sessions on other instances remain');
        const members = [victim.controller, ...victim.viewers];
        const events = members.map(c => c.waitFor(m => m.type === 'event' && m.kind === 'shutdown', 5000, 'event').then(() => true, () => false));
        const t0 = Date.now();
        const framesBefore = others.map(s => s.viewers[0].framesReceived);
        servers[k - 1].proc.kill(signal);
        const codes = await Promise.all(members.map(c => Promise.race([c.closed, sleep(5000).then(() => 'open')])));
        const ms = Date.now() - t0;
        // SIGTERM: the server says why (event shutdown) and closes; SIGKILL: nginx closes at once
        for (const code of codes) assert.notEqual(code, 'open', `a client of instance ${k} is still connected after 5 s`);
        assert.ok(ms < 5000, `clients closed after ${ms} ms`);
        if (signal === 'SIGTERM') assert.deepEqual(await Promise.all(events), members.map(() => true), 'every client got the shutdown event');
        t.diagnostic(`${signal}: ${members.length} clients of instance ${k} closed within ${ms} ms, close codes ${[...new Set(codes)]}`);
        // the other instances' sessions kept running
        await sleep(400);
        others.forEach((s, i) => assert.ok(s.viewers[0].framesReceived > framesBefore[i], `session ${s.id} kept running`));
        // the share link again: nginx takes it to a live instance, which says the session is gone
        const again = track(await SquishClient.connect(`${ws}?session=${victim.id}`, { role: 'control' }));
        await assert.rejects(again.join(victim.id, 'control'), e => e instanceof SquishError && e.code === 'unknown_session');
        // ... and the client opens its scene there, as the viewer does
        const r = await again.open('default');
        assert.notEqual(instanceOf(r.session), k);
        const v = track(await SquishClient.connect(`${ws}?session=${r.session}`, { role: 'view' }));
        assert.equal((await v.join(r.session, 'view')).session, r.session);
        const snap = await fetch(`${base}/snapshot.png?session=${r.session}&size=64x48`);
        assert.equal(snap.status, 200);
        victim.id = r.session;
        victim.controller = again;
        victim.viewers = [v];
        // the controller page reconnects by itself, is refused the old id and opens its scene
        // on a live instance
        if (ctlPage && instanceOf(browserSession) === k) {
          await ctlPage.waitForFunction(old => window.squish.session && window.squish.session !== old &&
                                        window.squish.status === 'connected', String(browserSession), { timeout: 20000 });
          const moved = Number(await ctlPage.evaluate(() => window.squish.session));
          assert.notEqual(instanceOf(moved), k);
          t.diagnostic(`the browser's session ${browserSession} (instance ${k}) is now ${moved} (instance ${instanceOf(moved)})`);
          browserSession = moved;
        }
      });
    }
    assert.equal(nginx.exitCode, null, `nginx still runs: ${nginxErr}`);
    if (browser) await browser.close();
    browser = null;
  } finally {
    if (browser) await browser.close().catch(() => {});
    for (const c of clients) { try { c.ws.terminate(); } catch (e) { /* already closed */ } }
    if (nginx && nginx.exitCode === null) {
      nginx.kill('SIGTERM');
      await Promise.race([new Promise(r => nginx.on('exit', r)), sleep(3000).then(() => nginx.kill('SIGKILL'))]);
    }
    for (const s of servers) await s.stop('SIGTERM').catch(() => {});
    rmSync(dir, { recursive: true, force: true });
  }
});
