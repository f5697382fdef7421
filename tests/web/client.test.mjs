// client.test.mjs - the client library web/squish-client.js loaded by a real chromium page (its
// own WebSocket, DecompressionStream decoding) and by Node (npm ws, zlib) against the same real
// server: the two decode the same frame to the same numbers.

import { describe, it, before, after } from 'node:test';
import assert from 'node:assert/strict';
import { startServer, launchBrowser } from './helpers.mjs';
import { SquishClient } from '../../web/squish-client.js';

describe('client library in a browser and in Node', () => {
  let server, browser;
  before(async () => {
    server = await startServer(0, { args: ['--lockstep'] });
    browser = await launchBrowser();
  });
  after(async () => {
    if (browser) await browser.close();
    if (server) await server.stop();
  });

  it('steps a lockstep session from a page and decodes what Node decodes', async () => {
    const page = await browser.newPage();
    const problems = [];
    page.on('pageerror', (e) => problems.push(e.message));
    const ws = `ws://127.0.0.1:${server.port}/ws`;
    try {
      await page.goto(`${server.url}favicon.png`);
      const got = await page.evaluate(async (url) => {
        let stage = 'import /squish-client.js';
        const { SquishClient } = await import('/squish-client.js');
        // a failure names the stage it happened in (the assertion below prints it)
        let c, o, st, f;
        try {
          stage = 'connect'; c = await SquishClient.connect(url, { client: 'page' });
          stage = 'open paper-cube'; o = await c.open('paper-cube');
          stage = 'step 5'; st = await c.step(5);
          stage = `wait for frame ${st.frame}`; f = await c.waitFrame(st.frame);
        } catch (e) {
          return { failed: `${stage}: ${e && e.message}` };
        }
        let err = null;
        try { await c.set({ material: { nu: 0.7 } }); } catch (e) { err = e.code; }
        const out = { session: o.session, frame: f.frame, stepped: st.frames, err,
          n: f.positions.length, pos: Array.from(f.positions.slice(0, 30)), lockstep: c.welcome.lockstep };
        c.leave();
        return out;
      }, ws);
      assert.equal(got.failed, undefined, 'the page drives the session');
      assert.equal(got.lockstep, true);
      assert.equal(got.stepped, 5);
      assert.equal(got.err, 'out_of_range', 'an error reply rejects with its code');
      // Node joins the page's session (kept for the grace period) and reads the same frame
      const c = await SquishClient.connect(ws, { client: 'node', role: 'view' });
      try {
        await c.join(got.session).catch((e) => { throw new Error(`node joins session ${got.session}: ${e.message}`); });
        const f = await c.waitFrame(got.frame).catch((e) => { throw new Error(`node waits for frame ${got.frame}: ${e.message}`); });
        assert.equal(f.frame, got.frame);
        assert.equal(f.positions.length, got.n);
        assert.deepEqual(Array.from(f.positions.slice(0, 30)), got.pos, 'same positions, bit for bit');
      } finally {
        await c.close();
      }
      assert.deepEqual(problems, []);
    } finally {
      await page.close();
    }
  });

  it('a frame decoded before its topology was handled still gets positions (browser decode is async)', async () => {
    const page = await browser.newPage();
    const ws = `ws://127.0.0.1:${server.port}/ws`;
    try {
      await page.goto(`${server.url}favicon.png`);
      const got = await page.evaluate(async (url) => {
        const { SquishClient } = await import('/squish-client.js');
        const c = await SquishClient.connect(url, { client: 'page' });
        const raw = [];
        c.on('binary', (d) => raw.push(new Uint8Array(d)));
        await c.open('paper-cube');
        const st = await c.step(2);
        await c.waitFrame(st.frame);
        c.leave();
        // replay topology and frames into a second client in one tick: every frame's decode
        // starts before the topology ahead of it is handled, as when they arrive back to back
        const r = await SquishClient.connect(url, { client: 'replay' });
        for (const d of raw) r._receive(d, true);
        const f = await r.waitFrame(st.frame);
        const body = r.bodies.get(0);
        await r.close();
        await c.close();
        return { messages: raw.length, has: !!f.positions, n: f.positions ? f.positions.length : -1,
          rest: body ? body.rest.length : -1,
          first: f.positions ? f.positions[0] : null, want: body ? Math.fround(body.rest[0] + f.displacement[0]) : null };
      }, ws);
      assert.ok(got.messages >= 2, `a topology and at least one frame were received (${got.messages})`);
      assert.ok(got.has, 'the replayed frame has positions');
      assert.equal(got.n, got.rest, 'one position per rest coordinate');
      assert.equal(got.first, got.want, 'position = rest + displacement');
    } finally {
      await page.close();
    }
  });
});
