// helpers.mjs - start the real `squish serve` on a free loopback port, drive Debian's chromium
// with playwright-core, and inspect the viewer's canvas pixels.

import { spawn } from 'node:child_process';
import net from 'node:net';
import http from 'node:http';
import path from 'node:path';
import fs from 'node:fs';
import { fileURLToPath } from 'node:url';
import { chromium } from 'playwright-core';

/** repository root */
export const ROOT = path.resolve(path.dirname(fileURLToPath(import.meta.url)), '../..');
/** the server binary (tests/run.sh sets SQUISH) */
export const SQUISH = process.env.SQUISH || path.join(ROOT, 'build/squish');
/** Debian's chromium */
export const CHROMIUM = process.env.CHROMIUM || '/usr/bin/chromium';
/** scenes of the browser tests (an adaptive cube) */
export const TEST_SCENES = path.join(ROOT, 'tests/web/scenes');
/** where the suite saves its screenshots: build/screenshots, so a test run leaves the tree
 * clean; SQUISH_SHOTS=docs/img refreshes the docs' pictures (docs/viewer.md) */
export const IMG_DIR = path.resolve(ROOT, process.env.SQUISH_SHOTS || 'build/screenshots');

const CHROMIUM_ARGS = ['--enable-unsafe-swiftshader', '--disable-background-networking',
  '--disable-component-update', '--disable-sync', '--disable-quic', '--no-first-run'];

/** a TCP port that was free a moment ago on 127.0.0.1 */
export function freePort() {
  return new Promise((resolve, reject) => {
    const s = net.createServer();
    s.once('error', reject);
    s.listen(0, '127.0.0.1', () => {
      const { port } = s.address();
      s.close(() => resolve(port));
    });
  });
}

function httpGet(url) {
  return new Promise((resolve) => {
    const req = http.get(url, (res) => {
      let body = '';
      res.on('data', (d) => { body += d; });
      res.on('end', () => resolve({ status: res.statusCode, body }));
    });
    req.on('error', () => resolve(null));
    req.setTimeout(1000, () => { req.destroy(); resolve(null); });
  });
}

/**
 * start `squish serve` with web/ and the shipped scenes (or opts.scenes, a directory) on port
 * (a free one if not given), plus opts.args;
 * resolves when /healthz answers. Returns {port, url, proc, log(), stop()}.
 */
export async function startServer(port, { scenes, args: extra = [] } = {}) {
  if (!fs.existsSync(SQUISH)) throw new Error(`server binary ${SQUISH} not found: build it with "make squish" or set SQUISH`);
  port = port || await freePort();
  const args = ['serve', '--host', '127.0.0.1', '--port', String(port), '--web', path.join(ROOT, 'web')];
  // the shipped scenes when there are some, else the built-in default scene
  const dir = scenes || path.join(ROOT, 'meshes/scenes');
  if (fs.existsSync(dir)) args.push('--scenes', dir);
  args.push(...extra);
  const proc = spawn(SQUISH, args, { cwd: ROOT, stdio: ['ignore', 'pipe', 'pipe'] });
  let out = '';
  proc.stdout.on('data', (d) => { out += d; });
  proc.stderr.on('data', (d) => { out += d; });
  const exited = new Promise((resolve) => proc.once('exit', (code, sig) => resolve({ code, sig })));
  const url = `http://127.0.0.1:${port}/`;
  const deadline = Date.now() + 15000;
  for (;;) {
    if (proc.exitCode !== null) throw new Error(`squish serve exited with ${proc.exitCode} before answering:\n${out}`);
    const r = await httpGet(`${url}healthz`);
    if (r && r.status === 200) break;
    if (Date.now() > deadline) { proc.kill('SIGKILL'); throw new Error(`squish serve did not answer on ${url} within 15 s:\n${out}`); }
    await new Promise((r2) => setTimeout(r2, 100));
  }
  return {
    port, url, proc,
    log: () => out,
    async stop() {
      if (proc.exitCode !== null || proc.signalCode !== null) return;
      proc.kill('SIGTERM');
      const t = setTimeout(() => proc.kill('SIGKILL'), 5000);
      await exited;
      clearTimeout(t);
    },
  };
}

/** headless chromium with the flags this machine needs */
export function launchBrowser() {
  return chromium.launch({ executablePath: CHROMIUM, args: CHROMIUM_ARGS });
}

// console lines that are not the page's errors: GPU driver chatter of software rendering
const NOISE = [/GL Driver Message/i, /GPU stall/i, /swiftshader/i, /WebGL.*fallback/i];

/**
 * open the viewer in a new page (with ?autoscale=0 unless autoScale is true); collects console errors and uncaught exceptions in
 * page.problems and the types of the requests it sends in page.sent. Waits until `minFrames`
 * frames were received.
 */
export async function openViewer(browser, url, { minFrames = 3, viewport = { width: 1280, height: 800 }, autoScale = false } = {}) {
  const page = await browser.newPage({ viewport });
  // pixel comparisons need one canvas size: the automatic resolution drop is off unless asked
  if (!autoScale) {
    const u = new URL(url);
    if (!u.searchParams.has('autoscale')) u.searchParams.set('autoscale', '0');
    url = u.toString();
  }
  page.problems = [];
  page.on('console', (m) => {
    if ((m.type() === 'error' || m.type() === 'warning') && !NOISE.some((r) => r.test(m.text()))) {
      if (m.type() === 'error') page.problems.push(`console error: ${m.text()}`);
    }
  });
  page.on('pageerror', (e) => page.problems.push(`uncaught: ${e.message}`));
  // the types of the JSON requests the page sends, in order
  page.sent = [];
  page.on('websocket', (ws) => ws.on('framesent', (f) => {
    if (typeof f.payload !== 'string') return;
    try { page.sent.push(JSON.parse(f.payload).type); } catch (e) { page.sent.push('(not JSON)'); }
  }));
  page.on('requestfailed', (r) => page.problems.push(`request failed: ${r.url()} ${r.failure() && r.failure().errorText}`));
  await page.goto(url);
  if (minFrames > 0) await waitFrames(page, minFrames);
  return page;
}

/** wait until the page has received n more frames than now (or n in total if from0) */
export async function waitFrames(page, n, timeout = 30000) {
  const start = await page.evaluate(() => (window.squish ? window.squish.framesReceived : 0));
  await page.waitForFunction((want) => window.squish && window.squish.framesReceived >= want,
    start + n, { timeout, polling: 50 });
}

/** the viewer's state summary */
export function state(page) {
  return page.evaluate(() => {
    const s = window.squish;
    return { status: s.status, session: s.session, role: s.role, frames: s.framesReceived,
      lastFrame: s.lastFrame, viewers: s.viewers, opens: s.opens, maxDisp: s.maxDisplacement(),
      hist: s.levelHistogram(), bounds: s.bounds, latency: s.latencyMs, problems: s.problems };
  });
}

/**
 * pixel statistics of the canvas: fraction of non-background pixels and, per level colour,
 * the fraction of pixels that are that colour under some light (the viewer's lighting only
 * scales the base colour, so a lit pixel keeps its colour's direction in RGB space; cosine
 * above 0.997 and at least 25% of its brightness counts as a match).
 */
export function pixelStats(page) {
  return page.evaluate(() => {
    const s = window.squish;
    const c = document.getElementById('view');
    const w = c.width, h = c.height;
    const cv = document.createElement('canvas');
    cv.width = w; cv.height = h;
    const ctx = cv.getContext('2d');
    ctx.drawImage(c, 0, 0);
    const d = ctx.getImageData(0, 0, w, h).data;
    const bg = s.backgroundColor();
    const cols = [0, 1, 2, 3, 4, 5].map((i) => s.levelColor(i));
    const norms = cols.map((q) => Math.hypot(q[0], q[1], q[2]));
    const counts = new Array(6).fill(0);
    let nonBg = 0;
    for (let i = 0; i < d.length; i += 4) {
      const r = d[i], g = d[i + 1], b = d[i + 2];
      if (Math.abs(r - bg[0]) + Math.abs(g - bg[1]) + Math.abs(b - bg[2]) > 12) nonBg++;
      const n = Math.hypot(r, g, b);
      if (n < 1) continue;
      for (let k = 0; k < 6; k++) {
        const q = cols[k];
        const cos = (r * q[0] + g * q[1] + b * q[2]) / (n * norms[k]);
        if (cos > 0.997 && n > 0.25 * norms[k]) { counts[k]++; break; }
      }
    }
    const total = w * h;
    return { width: w, height: h, nonBackground: nonBg / total, level: counts.map((x) => x / total) };
  });
}

/** keep a copy of the canvas pixels in the page under a name */
export function snapPixels(page, name) {
  return page.evaluate((key) => {
    const c = document.getElementById('view');
    const cv = document.createElement('canvas');
    cv.width = c.width; cv.height = c.height;
    const ctx = cv.getContext('2d');
    ctx.drawImage(c, 0, 0);
    window.__snaps = window.__snaps || {};
    window.__snaps[key] = ctx.getImageData(0, 0, c.width, c.height).data;
  }, name);
}

/** fraction of pixels that differ (sum of channel differences > 48) from a kept copy */
export function pixelChange(page, name) {
  return page.evaluate((key) => {
    const c = document.getElementById('view');
    const cv = document.createElement('canvas');
    cv.width = c.width; cv.height = c.height;
    const ctx = cv.getContext('2d');
    ctx.drawImage(c, 0, 0);
    const a = window.__snaps[key], b = ctx.getImageData(0, 0, c.width, c.height).data;
    if (a.length !== b.length) return 1;
    let n = 0;
    for (let i = 0; i < a.length; i += 4) {
      if (Math.abs(a[i] - b[i]) + Math.abs(a[i + 1] - b[i + 1]) + Math.abs(a[i + 2] - b[i + 2]) > 48) n++;
    }
    return n / (a.length / 4);
  }, name);
}

/** screen point of the centre of the body's top face (rest bounding box), in page pixels */
export async function topFacePoint(page) {
  return page.evaluate(() => {
    const b = window.squish.bounds;
    const p = [(b.min[0] + b.max[0]) / 2, (b.min[1] + b.max[1]) / 2, b.max[2]];
    return window.squish.screenPoint(p);
  });
}

/** press at (x, y), drag by (dx, dy) in steps, optionally with Shift; the button stays down */
export async function dragFrom(page, x, y, dx, dy, { steps = 12, shift = false, stepMs = 30 } = {}) {
  if (shift) await page.keyboard.down('Shift');
  await page.mouse.move(x, y);
  await page.mouse.down();
  for (let i = 1; i <= steps; i++) {
    await page.mouse.move(x + (dx * i) / steps, y + (dy * i) / steps);
    await page.waitForTimeout(stepMs);
  }
  if (shift) await page.keyboard.up('Shift');
}

/** save a screenshot under IMG_DIR (the docs' pictures when SQUISH_SHOTS=docs/img) */
export async function docShot(target, name) {
  fs.mkdirSync(IMG_DIR, { recursive: true });
  await target.screenshot({ path: path.join(IMG_DIR, name) });
}
