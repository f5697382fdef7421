// latency.mjs - measure tool-to-frame latency: a Node WebSocket client, then the viewer in
// headless chromium at two window sizes, against the real `squish serve` (a benchmark, not a
// test: it prints numbers and asserts nothing).
//   SQUISH=build/squish node tests/web/latency.mjs
// Latency = time from sending a tool pose to receiving the first frame that carries exactly it.

import zlib from 'node:zlib';
import WebSocket from 'ws';
import { startServer, launchBrowser } from './helpers.mjs';

const SCENE = 'paper-cube';
const SECONDS = 5;

function percentile(xs, q) {
  const s = [...xs].sort((a, b) => a - b);
  return s[Math.min(s.length - 1, Math.floor(q * s.length))];
}

// a grab on the top face moved by 1 mm steps at 30 Hz; the frame's tool record gives the pose
function nodeClient(port) {
  return new Promise((resolve, reject) => {
    const ws = new WebSocket(`ws://127.0.0.1:${port}/ws`);
    const sent = [], lats = [];
    let k = 0, timer = 0;
    ws.on('error', reject);
    ws.on('open', () => ws.send(JSON.stringify({ type: 'hello', client: 'latency' })));
    ws.on('message', (d, binary) => {
      if (binary) {
        if (d.readUInt8(6) !== 2) return;
        const n = d.readUInt32LE(24), ntools = d.readUInt32LE(28);
        const raw = zlib.inflateSync(d.subarray(64));
        for (let t = 0; t < ntools; t++) {
          const b = n * 7 + t * 36;
          if (raw.readUInt32LE(b) !== 6) continue;
          const z = raw.readFloatLE(b + 16);
          const i = sent.findIndex((s) => s.z === z);
          if (i >= 0) { lats.push(performance.now() - sent[i].t); sent.splice(0, i + 1); }
        }
        return;
      }
      const m = JSON.parse(d.toString());
      if (m.type === 'welcome') ws.send(JSON.stringify({ type: 'open', scene: m.scenes.includes(SCENE) ? SCENE : m.scenes[0] }));
      if (m.type === 'opened') {
        timer = setInterval(() => {
          const z = Math.fround(1 + 0.001 * (k++ % 100));
          sent.push({ t: performance.now(), z });
          ws.send(JSON.stringify({ type: 'tool', id: 6, shape: 'grab', pos: [0.5, 0.5, z], radius: 0.1, active: true }));
        }, 33);
        setTimeout(() => { clearInterval(timer); ws.close(); resolve(lats); }, SECONDS * 1000);
      }
    });
  });
}

// the viewer: pointer events dispatched inside the page at 60 Hz (no driver round trips)
async function viewer(browser, url, width, height) {
  const page = await browser.newPage({ viewport: { width, height } });
  await page.goto(`${url}?scene=${SCENE}`);
  await page.waitForFunction(() => window.squish && window.squish.framesReceived > 5 && window.squish.bounds, null, { timeout: 30000 });
  const r = await page.evaluate(async (seconds) => {
    const s = window.squish, b = s.bounds;
    const p = s.screenPoint([(b.min[0] + b.max[0]) / 2, (b.min[1] + b.max[1]) / 2, b.max[2]]);
    const cv = document.getElementById('view');
    const ev = (type, x, y) => cv.dispatchEvent(new PointerEvent(type, { clientX: x, clientY: y, pointerId: 1,
      button: 0, buttons: 1, bubbles: true, isPrimary: true }));
    ev('pointerdown', p[0], p[1]);
    const steps = Math.round(seconds * 60);
    for (let i = 0; i < steps; i++) {
      await new Promise((res) => setTimeout(res, 16));
      ev('pointermove', p[0] + 20 * Math.sin(i / 10), p[1] - 30 + 20 * Math.cos(i / 10));
    }
    ev('pointerup', p[0], p[1]);
    return { latency: s.latencyMs, bytes: s.bytesPerSecond, rate: s.simRate, draw: s.drawMs, software: s.softwareGl };
  }, SECONDS);
  await page.close();
  return r;
}

const server = await startServer();
try {
  const lats = await nodeClient(server.port);
  console.log(`node client: ${lats.length} poses, latency p50 ${percentile(lats, 0.5).toFixed(1)} ms, ` +
    `p90 ${percentile(lats, 0.9).toFixed(1)} ms, max ${Math.max(...lats).toFixed(1)} ms`);
  const browser = await launchBrowser();
  for (const [w, h] of [[1280, 800], [320, 200]]) {
    const r = await viewer(browser, server.url, w, h);
    console.log(`viewer ${w}x${h}${r.software ? ' (software GL)' : ''}: latency ${r.latency === null ? '-' : r.latency.toFixed(1)} ms ` +
      `(mean of the last 30), sim rate ${r.rate.toFixed(1)} Hz, ${(r.bytes / 1000).toFixed(1)} kB/s, ` +
      `JS per picture ${r.draw.toFixed(2)} ms`);
  }
  await browser.close();
} finally {
  await server.stop();
}
