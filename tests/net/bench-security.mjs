#!/usr/bin/env node
// bench-security.mjs - the attacks of docs/security.md re-measured against the real server
// ($SQUISH, default build/squish), on loopback. Prints one line per figure (and --json FILE).
//
//   SQUISH=build/squish node tests/net/bench-security.mjs [--seconds 60] [--scene organ]
import { readFileSync, writeFileSync } from 'node:fs';
import net from 'node:net';
import os from 'node:os';
import path from 'node:path';
import { SquishClient } from './client.mjs';
import { startServer, sleep, rssKiB, ROOT } from './harness.mjs';

const arg = (name, def) => { const i = process.argv.indexOf(name); return i > 0 ? process.argv[i + 1] : def; };
const SECONDS = Number(arg('--seconds', 60));
const SCENE = arg('--scene', 'organ');
const SCENES = path.join(ROOT, 'meshes/scenes');
const out = {};
const say = (k, v) => { out[k] = v; console.log(`${k}: ${typeof v === 'object' ? JSON.stringify(v) : v}`); };
const load = () => os.loadavg().map(x => x.toFixed(2)).join(' ');
const cpu = pid => { const f = readFileSync(`/proc/${pid}/stat`, 'utf8').split(') ')[1].split(' '); return (Number(f[11]) + Number(f[12])) / 100; };

async function rate(c, ms) {
  let n = 0; const on = () => { n++; };
  c.on('binary', on); await sleep(ms); c.off('binary', on);
  return n / (ms / 1000);
}

async function stopTimed(srv, graceMs = 120000) {
  const t0 = Date.now(); const r = await srv.stop('SIGTERM', graceMs); return { ms: Date.now() - t0, code: r.code };
}

say('load average at start', load());

// 2. nodes amplification: 10 non-reading viewers sending nodes at the rate limit
{
  const srv = await startServer(['--scenes', SCENES]);
  const ctl = await SquishClient.connect(srv.url);
  const o = await ctl.open(SCENE);
  const honest = await SquishClient.connect(srv.url, { role: 'view', decode: false });
  await honest.join(o.session);
  const base = await rate(honest, 3000);
  const rss0 = rssKiB(srv.pid);
  const spam = await Promise.all(Array.from({ length: 10 }, () => SquishClient.connect(srv.url, { role: 'view', decode: false })));
  await Promise.all(spam.map(s => s.join(o.session)));
  for (const s of spam) s.ws._socket.pause();
  const msg = JSON.stringify({ type: 'nodes', body: 0 });
  const timer = setInterval(() => { for (const s of spam) for (let i = 0; i < 20; i++) s.sendRaw(msg); }, 100);
  let rssMax = rss0, during = [];
  for (let t = 0; t < SECONDS; t += 5) {
    during.push(await rate(honest, 5000));
    rssMax = Math.max(rssMax, rssKiB(srv.pid));
  }
  clearInterval(timer);
  for (const s of spam) s.ws.terminate();
  const t1 = Date.now();
  let after = 0;
  while (Date.now() - t1 < 120000 && (after = await rate(honest, 1000)) < 0.8 * base);
  say(`nodes spam (${SECONDS} s, scene ${SCENE}): honest viewer frames/s before, min and mean during, after`,
    [base, Math.min(...during), during.reduce((a, b) => a + b, 0) / during.length, after].map(x => +x.toFixed(1)));
  say('nodes spam: RSS kB before, max during', [rss0, rssMax]);
  say('nodes spam: s from the end of the spam to 80% of the honest rate', +((Date.now() - t1) / 1000 - 1).toFixed(1));
  await honest.close(); await ctl.close();
  say('nodes spam: SIGTERM', await stopTimed(srv));
}

// 3. CPU through set: the 2^16-substep material; set flood at 140/s
{
  const srv = await startServer(['--scenes', SCENES]);
  const victim = await SquishClient.connect(srv.url);
  await victim.open(SCENE);
  await sleep(1000);
  const b0 = await victim.stats(), v0 = Date.now();
  await sleep(10000);
  const b1 = await victim.stats(), v1 = Date.now();
  say(`other session (${SCENE}) alone, 10 s: frames/s, deadline misses`, [+((b1.frame - b0.frame) / ((v1 - v0) / 1000)).toFixed(1), b1.deadline_misses - b0.deadline_misses]);
  const att = await SquishClient.connect(srv.url);
  await att.open('paper-cube');
  await sleep(1000);
  const s0 = await victim.stats(), w0 = Date.now();
  const e = await att.set({ material: { E: 1e10, density: 1 } }).then(() => null, x => x);
  say('set E=1e10 density=1 (paper-cube)', e ? `${e.code}: ${e.reply.message}` : 'accepted');
  const viewer = await SquishClient.connect(srv.url, { role: 'view', decode: false });
  await viewer.join(att.session);
  let last = Date.now(), gap = 0;
  viewer.on('binary', () => { const t = Date.now(); gap = Math.max(gap, t - last); last = t; });
  const flood = setInterval(() => { for (let i = 0; i < 14; i++) att.sendRaw(JSON.stringify({ type: 'set', material: { E: 2e5 + i } })); }, 100);
  await sleep(10000);
  clearInterval(flood);
  const s1 = await victim.stats(), w1 = Date.now();
  say(`set flood 140/s for 10 s: longest frame gap of the flooder's viewer, ms`, gap);
  say(`other session (${SCENE}) meanwhile: frames/s, deadline misses`, [+((s1.frame - s0.frame) / ((w1 - w0) / 1000)).toFixed(1), s1.deadline_misses - s0.deadline_misses]);
  await Promise.all([victim, att, viewer].map(c => c.close()));
  say('set attack: SIGTERM', await stopTimed(srv));
}
{
  // an operator who allows anything (--frame-budget 1e6): SIGTERM during a long frame
  const srv = await startServer(['--scenes', SCENES, '--frame-budget', '1e6']);
  const c = await SquishClient.connect(srv.url);
  await c.open('paper-cube');
  // E / density = 6.4e11: 2^20 substeps per frame, the engine's limit (one frame ~30 s)
  const r = await c.set({ material: { E: 1e10, density: 0.015625 } }).catch(e => e);
  say('long-frame set', r.type === 'ack' ? `substeps of the level: ${JSON.stringify(r.bodies[0].settings.levels.map(l => l.dt && Math.round(0.02 / l.dt)))}` : r.message);
  await sleep(3000);
  say('SIGTERM 3 s into a 2^20-substep frame of paper-cube (--frame-budget 1e6)', await stopTimed(srv));
}

// 4. session slots with --token
{
  const srv = await startServer(['--scenes', SCENES, '--token', 'sesame']);
  const v = await SquishClient.connect(srv.url, { role: 'view' });
  const t0 = Date.now(); let n = 0, err = null;
  while (!err && n < 20) await v.open('paper-cube').then(() => n++, e => { err = e; });
  say('token-less opens before server_full (of 16), ms', [n, Date.now() - t0, err && err.code]);
  const t = await SquishClient.connect(srv.url, { token: 'sesame' });
  say('token holder opens afterwards', await t.open('paper-cube').then(o => `ok, session ${o.session}`, e => e.code));
  await v.close(); await t.close();
  await stopTimed(srv);
}

// 5. fd limit: 2000 connection attempts from 127.0.0.2 with 200 file descriptors
{
  const srv = await startServer(['--max-conns-per-addr', '40'], { prefix: ['prlimit', '--nofile=200:200', '--'] });
  const c0 = cpu(srv.pid), e0 = srv.stderr().split('\n').length;
  const socks = [];
  const t0 = Date.now();
  for (let i = 0; i < 2000; i++) {
    const s = await new Promise(res => { const s = net.connect({ port: srv.port, host: '127.0.0.1', localAddress: '127.0.0.2' }); s.on('error', () => res(null)); s.on('connect', () => res(s)); });
    if (s) socks.push(s);
  }
  await sleep(2000);
  const health = await fetch(`${srv.http}/healthz`).then(r => r.status, e => e.message);
  say('2000 connections at an fd limit of 200: server CPU s, log lines, wall s, /healthz from 127.0.0.1',
    [+(cpu(srv.pid) - c0).toFixed(2), srv.stderr().split('\n').length - e0, (Date.now() - t0) / 1000, health]);
  for (const s of socks) s.destroy();
  await stopTimed(srv);
}

// 7. token guessing
{
  const srv = await startServer(['--token', 'sesame']);
  const c = new SquishClient(srv.url);
  await c._opened;
  const t0 = Date.now(); const codes = {};
  for (let i = 0; i < 1000; i++) {
    const code = await c.request({ type: 'hello', role: 'control', token: `g${i}` }).then(() => 'ok', e => e.code);
    codes[code] = (codes[code] || 0) + 1;
  }
  say('1000 token guesses: replies by code, ms', [codes, Date.now() - t0]);
  await c.close();
  await stopTimed(srv);
}

// 1. pipelined snapshots and 8 concurrent 2048x2048
{
  const srv = await startServer(['--scenes', SCENES]);
  const cs = [], os_ = [];
  for (let i = 0; i < 8; i++) { const c = await SquishClient.connect(srv.url); cs.push(c); os_.push(await c.open('paper-cube')); }
  for (let k = 0; k < 20; k++) {
    await new Promise(res => {
      const s = net.connect(srv.port, '127.0.0.1');
      s.on('error', res); s.on('close', res);
      s.on('connect', () => s.write([0, 1].map(i => `GET /snapshot.png?session=${os_[i].session}&size=64x64 HTTP/1.1\r\nHost: x\r\n\r\n`).join('')));
      setTimeout(() => { s.destroy(); res(); }, 5000);
    });
    await sleep(300);
  }
  await sleep(500);
  say('after 20 pipelined pairs: a snapshot', (await fetch(`${srv.http}/snapshot.png?session=${os_[2].session}&size=64x64`)).status);
  await sleep(300);
  const t0 = Date.now();
  const st = await Promise.all(os_.map(o => fetch(`${srv.http}/snapshot.png?session=${o.session}&size=2048x2048`).then(r => r.arrayBuffer().then(() => r.status), e => e.message)));
  say('8 concurrent 2048x2048 snapshots: statuses, s', [st, (Date.now() - t0) / 1000]);
  for (const c of cs) await c.close();
  await stopTimed(srv);
}
say('load average at end', load());
const j = arg('--json');
if (j) writeFileSync(j, JSON.stringify(out, null, 2));
