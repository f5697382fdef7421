// viewer.test.mjs - the web viewer in real headless chromium against the real `squish serve`.
// Run by tests/stages/web.sh (node --test); SQUISH names the server binary.

import { describe, it, before, after } from 'node:test';
import assert from 'node:assert/strict';
import {
  startServer, launchBrowser, openViewer, waitFrames, state, pixelStats, snapPixels, pixelChange,
  topFacePoint, dragFrom, docShot, TEST_SCENES,
} from './helpers.mjs';

// the body fills a good part of a 1280x800 view after the automatic camera fit
const MIN_BODY_FRACTION = 0.04;
// a level colour counts as present above this fraction of the canvas (a few hundred pixels)
const MIN_LEVEL_FRACTION = 0.0005;

describe('web viewer', () => {
  // server: the shipped scenes (or the built-in default); adaptive: the test's adaptive cube
  let server, adaptive, browser;

  before(async () => {
    server = await startServer();
    adaptive = await startServer(0, { scenes: TEST_SCENES });
    browser = await launchBrowser();
  });
  after(async () => {
    if (browser) await browser.close();
    if (server) await server.stop();
    if (adaptive) await adaptive.stop();
  });

  it('loads with no console errors and shows the body in level colours', async () => {
    const page = await openViewer(browser, server.url);
    try {
      await page.waitForFunction(() => window.squish.bounds && window.squish.status === 'connected');
      await waitFrames(page, 5);
      const st = await state(page);
      assert.equal(st.role, 'control');
      assert.ok(await page.evaluate(() => !!window.squish.link.worker), 'binary messages are decoded in a worker');
      assert.ok(st.session, 'a session was opened');
      const px = await pixelStats(page);
      assert.ok(px.nonBackground > MIN_BODY_FRACTION, `body and floor cover ${px.nonBackground} of the canvas`);
      // at rest every surface vertex has some level; that level's colour must be on screen
      const lvl = st.hist.findIndex((n) => n > 0);
      assert.ok(lvl >= 0, 'frames carry per-vertex levels');
      assert.ok(px.level[lvl] > MIN_LEVEL_FRACTION, `level ${lvl} colour covers ${px.level[lvl]} of the canvas`);
      // the legend lists the body's levels with their palette colours
      const legend = await page.locator('#legend-list li').count();
      assert.ok(legend >= 1);
      // the shipped paper-cube lists four levels and simulates level 2 alone: frames, colours
      // and legend all number it 2, as renders do (not 0, its index among the loaded levels)
      assert.equal(await page.evaluate(() => window.squish.scene), 'paper-cube', 'the viewer opens paper-cube first');
      assert.equal(lvl, 2, `paper-cube frames carry level ${lvl}`);
      assert.equal(legend, 1);
      assert.match(await page.locator('#legend-list li').first().innerText(), /level 2\b/);
      await docShot(page, 'viewer_default.png');
      // plain shading: level colours leave the picture
      await page.locator('#view').focus();
      await page.keyboard.press('l');
      await page.waitForTimeout(200);
      const plain = await pixelStats(page);
      assert.ok(plain.level[lvl] < px.level[lvl] * 0.2, `plain shading still shows level colour (${plain.level[lvl]})`);
      await page.keyboard.press('l');
      // wireframe draws the triangle edges over the body: pixels change
      await snapPixels(page, 'shaded');
      await page.keyboard.press('w');
      await page.waitForTimeout(300);
      assert.ok(await pixelChange(page, 'shaded') > 0.005, 'wireframe visible');
      await page.keyboard.press('w');
      // active-node points come from `nodes` requests
      await page.keyboard.press('n');
      await page.waitForFunction(() => window.squish.nodesShown > 0, null, { timeout: 15000 });
      assert.ok(page.sent.includes('nodes'));
      await page.keyboard.press('n');
      assert.deepEqual(page.problems, [], 'no console errors');
    } finally {
      await page.close();
    }
  });

  it('a drag deforms the body, and a viewer of the share link sees the same frames', async (t) => {
    const ctl = await openViewer(browser, adaptive.url);
    let viewer;
    try {
      await ctl.waitForFunction(() => window.squish.bounds);
      await waitFrames(ctl, 5);
      const shareLink = await ctl.locator('#share-link').inputValue();
      assert.match(shareLink, /[?&]session=\d+/);
      assert.match(shareLink, /[?&]role=view/);
      viewer = await openViewer(browser, shareLink);
      const vs = await state(viewer);
      const cs = await state(ctl);
      assert.equal(vs.role, 'view');
      assert.equal(vs.session, cs.session, 'the viewer joined the controller\'s session');
      // the controller sees one viewer (stats are pushed a few times per second)
      await ctl.waitForFunction(() => window.squish.viewers === 1, null, { timeout: 15000 });
      await ctl.waitForFunction(() => /1 viewer/.test(document.getElementById('watchers').textContent));

      const rest = await state(ctl);
      await snapPixels(ctl, 'rest');
      const p = await topFacePoint(ctl);
      assert.ok(p, 'the top face is in view');
      // pull the top face upwards by 100 pixels (about 0.2 m) and hold it
      await dragFrom(ctl, p[0], p[1], 0, -100);
      await waitFrames(ctl, 20);
      const pulled = await state(ctl);
      const size = Math.hypot(...[0, 1, 2].map((a) => rest.bounds.max[a] - rest.bounds.min[a]));
      // the grab moves the surface by a visible amount: at least 2% of the body's diagonal
      assert.ok(pulled.maxDisp > rest.maxDisp + 0.02 * size,
        `surface moved ${pulled.maxDisp} m (at rest ${rest.maxDisp} m, body ${size} m)`);
      const changed = await pixelChange(ctl, 'rest');
      assert.ok(changed > 0.005, `rendered pixels changed on ${changed} of the canvas`);
      // the force arrow carries its value in N
      await ctl.waitForFunction(() => [...document.querySelectorAll('.force-label')].some((e) => /N$/.test(e.textContent)));
      // the poke refined the adaptive cube: at least two level colours are on screen
      await ctl.waitForFunction(() => window.squish.levelHistogram().filter((n) => n > 0).length >= 2, null, { timeout: 10000 });
      const px = await pixelStats(ctl);
      const shown = px.level.filter((f) => f > MIN_LEVEL_FRACTION).length;
      assert.ok(shown >= 2, `level colours on screen: ${px.level.map((f) => f.toFixed(4)).join(', ')}`);
      await docShot(ctl, 'viewer_poke.png');

      // the viewer got the very same frames: equal checksums for every frame number both saw
      // (each page may skip frames when it falls behind, so collect until 5 are in common)
      let common = [];
      let cMap = new Map();
      for (let tries = 0; tries < 40 && common.length < 5; tries++) {
        await waitFrames(viewer, 5);
        const cmp = await Promise.all([ctl, viewer].map((pg) => pg.evaluate(() => [...window.squish.frameLog.entries()])));
        cMap = new Map(cmp[0]);
        common = cmp[1].filter(([f]) => cMap.has(f));
      }
      assert.ok(common.length >= 5, `only ${common.length} frames in common`);
      for (const [f, sum] of common) assert.equal(sum, cMap.get(f), `frame ${f} differs between controller and viewer`);
      const vPulled = await state(viewer);
      assert.ok(vPulled.maxDisp > rest.maxDisp + 0.02 * size, `viewer sees ${vPulled.maxDisp} m`);
      // what the page measured while poking (headless software rendering: slower than a GPU)
      const m = await ctl.evaluate(() => ({ lat: window.squish.latencyMs, rate: window.squish.simRate,
        bps: window.squish.bytesPerSecond, draw: window.squish.drawMs }));
      t.diagnostic(`tool-to-frame latency ${m.lat && m.lat.toFixed(1)} ms, sim rate ${m.rate.toFixed(1)} Hz, ` +
        `${(m.bps / 1000).toFixed(1)} kB/s received, draw ${m.draw && m.draw.toFixed(2)} ms (JS side)`);
      await ctl.mouse.up();

      // a viewer cannot poke: its drags on the body orbit its own camera, no tool is sent
      assert.ok(ctl.sent.includes('tool'), 'the controller sent tool poses');
      const az0 = await viewer.evaluate(() => window.squish.camera.az);
      const vp = await topFacePoint(viewer);
      await dragFrom(viewer, vp[0], vp[1], 60, 0, { steps: 4 });
      await viewer.mouse.up();
      await waitFrames(viewer, 3);
      assert.ok(!viewer.sent.includes('tool'), `the viewer sent: ${viewer.sent.join(', ')}`);
      assert.notEqual(await viewer.evaluate(() => window.squish.camera.az), az0, 'the viewer\'s camera turned');
      assert.deepEqual(ctl.problems, [], 'controller console clean');
      assert.deepEqual(viewer.problems, [], 'viewer console clean');
    } finally {
      await ctl.mouse.up().catch(() => {});
      if (viewer) await viewer.close();
      await ctl.close();
    }
  });

  it('Shift+drag pushes with a sphere tool that the frames carry', async () => {
    const page = await openViewer(browser, server.url);
    try {
      await page.waitForFunction(() => window.squish.bounds);
      await waitFrames(page, 5);
      const p = await topFacePoint(page);
      await dragFrom(page, p[0], p[1], 0, 60, { shift: true, steps: 6 });
      await page.waitForFunction(() => [...window.squish.bodies.values()].some(
        (b) => (b.tools || []).some((t) => t.shape === 'sphere' && t.active)), null, { timeout: 15000 });
      await page.mouse.up();
      // released: the tool goes inactive in later frames
      await page.waitForFunction(() => ![...window.squish.bodies.values()].some(
        (b) => (b.tools || []).some((t) => t.shape === 'sphere' && t.active)), null, { timeout: 15000 });
      assert.deepEqual(page.problems, []);
    } finally {
      await page.close();
    }
  });

  it('touch: two fingers pinch to zoom, one finger on empty space orbits', async () => {
    const ctx = await browser.newContext({ viewport: { width: 900, height: 600 }, hasTouch: true });
    const page = await ctx.newPage();
    try {
      await page.goto(server.url);
      await waitFrames(page, 3);
      const cdp = await ctx.newCDPSession(page);
      const touch = (type, points) => cdp.send('Input.dispatchTouchEvent', { type, touchPoints: points.map(([x, y], id) => ({ x, y, id })) });
      const cam = () => page.evaluate(() => ({ dist: window.squish.camera.dist, az: window.squish.camera.az }));
      const c0 = await cam();
      // one finger in the empty top-left corner drags sideways: the camera turns
      await touch('touchStart', [[40, 80]]);
      for (let i = 1; i <= 5; i++) await touch('touchMove', [[40 + 30 * i, 80]]);
      await touch('touchEnd', []);
      const c1 = await cam();
      assert.ok(Math.abs(c1.az - c0.az) > 0.3, `orbit: azimuth ${c0.az} -> ${c1.az}`);
      // fingers 100 px apart move to 300 px apart: zoom in by about 3x
      await touch('touchStart', [[250, 300], [350, 300]]);
      for (let i = 1; i <= 5; i++) await touch('touchMove', [[250 - 20 * i, 300], [350 + 20 * i, 300]]);
      await touch('touchEnd', []);
      const c2 = await cam();
      assert.ok(c2.dist < c1.dist * 0.6, `pinch: distance ${c1.dist} -> ${c2.dist}`);
    } finally {
      await ctx.close();
    }
  });

  it('a refused setting shows the server\'s reason next to the control', async () => {
    // a tall window, so the panel screenshot shows the whole panel
    const page = await openViewer(browser, server.url, { viewport: { width: 1280, height: 1280 } });
    try {
      // the setting groups are folded: open Material
      await page.locator('#form-material').locator('xpath=..').locator('summary').click();
      await page.fill('#in-nu', '0.7');
      await page.locator('#form-material button[type=submit]').click();
      const err = page.locator('#err-material');
      await err.waitFor({ state: 'visible', timeout: 15000 });
      await page.waitForFunction(() => document.getElementById('err-material').textContent.length > 0);
      const text = await err.textContent();
      const last = await page.evaluate(() => window.squish.lastError);
      assert.ok(last && last.code, 'the server answered with an error');
      assert.ok(text.includes(last.message), `shown "${text}" is the server's message "${last.message}"`);
      assert.match(text, /nu/);
      // an accepted value clears the error and is confirmed
      await page.fill('#in-nu', '0.3');
      await page.locator('#form-material button[type=submit]').click();
      await page.waitForFunction(() => document.getElementById('err-material').textContent === 'applied', null, { timeout: 15000 });
      // other screens: the panel, the help overlay and large text
      await docShot(page.locator('#panel'), 'viewer_panel.png');
      await page.locator('#view').focus();
      await page.keyboard.press('?');
      assert.ok(await page.locator('#help').isVisible());
      await page.keyboard.press('Escape');
      assert.ok(!(await page.locator('#help').isVisible()));
      const small = await page.evaluate(() => parseFloat(getComputedStyle(document.documentElement).fontSize));
      await page.keyboard.press('t');
      const large = await page.evaluate(() => parseFloat(getComputedStyle(document.documentElement).fontSize));
      assert.ok(large > small * 1.3, `large text ${large}px against ${small}px`);
      assert.deepEqual(page.problems, []);
    } finally {
      await page.close();
    }
  });

  it('pause stops the frames and resume restarts them', async () => {
    const page = await openViewer(browser, server.url);
    try {
      await page.locator('#btn-pause').click();
      await page.waitForFunction(() => document.getElementById('btn-pause').textContent === 'Resume');
      await page.waitForTimeout(300);
      const f1 = await page.evaluate(() => window.squish.lastFrame);
      await page.waitForTimeout(500);
      const f2 = await page.evaluate(() => window.squish.lastFrame);
      assert.equal(f2, f1, 'no new frame while paused');
      await page.locator('#btn-pause').click();
      await waitFrames(page, 3);
      assert.ok((await page.evaluate(() => window.squish.lastFrame)) > f2);
    } finally {
      await page.close();
    }
  });
});

describe('web viewer reconnects', () => {
  let server, browser;
  before(async () => { browser = await launchBrowser(); });
  after(async () => {
    if (browser) await browser.close();
    if (server) await server.stop();
  });

  it('re-joins its session after the connection drops while the server runs', async () => {
    server = await startServer();
    const page = await (await browser.newContext({ viewport: { width: 1024, height: 700 } })).newPage();
    // the page's WebSocket goes through a pass-through route we can cut
    const routes = [];
    // (the reconnection carries the session: /ws?session=ID, for proxies; docs/deploy.md)
    await page.routeWebSocket(/\/ws(\?session=\d+)?$/, (ws) => {
      ws.connectToServer();
      routes.push(ws);
    });
    try {
      await page.goto(server.url);
      await waitFrames(page, 5);
      const s1 = await state(page);
      // hold a grab while the connection drops
      const p = await topFacePoint(page);
      await dragFrom(page, p[0], p[1], 0, -30, { steps: 3 });
      const grabActive = () => [...window.squish.bodies.values()].some((b) => (b.tools || []).some((t) => t.shape === 'grab' && t.active));
      await page.waitForFunction(grabActive, null, { timeout: 15000 });
      await routes[routes.length - 1].close();
      await page.waitForFunction(() => window.squish.status !== 'connected', null, { timeout: 15000 });
      await page.waitForFunction(() => window.squish.status === 'connected', null, { timeout: 30000 });
      await waitFrames(page, 5);
      const s2 = await state(page);
      assert.ok(routes.length >= 2, 'a second connection was made');
      assert.ok(!/\?/.test(routes[0].url()), `the first connection has no session yet: ${routes[0].url()}`);
      assert.ok(routes[routes.length - 1].url().endsWith(`/ws?session=${s1.session}`),
        `the reconnection names its session: ${routes[routes.length - 1].url()}`);
      assert.equal(s2.session, s1.session, 'same session');
      assert.equal(s2.opens, s1.opens + 1, 'joined once more');
      assert.equal(s2.role, 'control', 'the controller got its session back');
      // the grab left behind by the drop was released after the re-join
      await page.waitForFunction((f) => !(() => [...window.squish.bodies.values()].some((b) => (b.tools || []).some((t) => t.shape === 'grab' && t.active)))(), null, { timeout: 15000 });
      await page.mouse.up();
    } finally {
      await page.context().close();
      await server.stop();
    }
  });

  it('comes back by itself when the server restarts', async () => {
    server = await startServer();
    const port = server.port;
    const page = await openViewer(browser, server.url);
    try {
      const s1 = await state(page);
      await server.stop();
      // the badge says so while it waits (it retries within a fraction of a second)
      await page.waitForFunction(() => window.squish.status === 'offline' &&
        /offline - retry in/.test(document.getElementById('conn').textContent), null, { timeout: 15000, polling: 10 });
      server = await startServer(port);
      // the backoff is at most a few seconds at this point
      await page.waitForFunction(() => window.squish.status === 'connected', null, { timeout: 30000 });
      await waitFrames(page, 5);
      const s2 = await state(page);
      assert.ok(s2.opens > s1.opens, 'the scene was opened again');
      assert.ok(s2.session, 'in a session again');
      // the address bar names the new session, so a reload re-joins it
      assert.ok(page.url().includes(`session=${s2.session}`));
      // problems during the outage are expected network errors only
      const unexpected = page.problems.filter((p) => !/WebSocket|ERR_CONNECTION_REFUSED|net::/.test(p));
      assert.deepEqual(unexpected, []);
    } finally {
      await page.close();
    }
  });
});

describe('web viewer with a control token', () => {
  let server, browser;
  before(async () => {
    server = await startServer(0, { args: ['--token', 'class-42'] });
    browser = await launchBrowser();
  });
  after(async () => {
    if (browser) await browser.close();
    if (server) await server.stop();
  });

  it('says a token is needed, and controls with ?token=', async () => {
    const page = await openViewer(browser, server.url, { minFrames: 0 });
    try {
      await page.waitForFunction(() => window.squish.status === 'refused', null, { timeout: 15000 });
      assert.match(await page.locator('#event').textContent(), /token/);
      await page.goto(`${server.url}?token=class-42`);
      await waitFrames(page, 3);
      assert.equal((await state(page)).role, 'control');
      // the navigation may cut a module fetch of the refused page short: not a problem
      assert.deepEqual(page.problems.filter((p) => !/net::ERR_ABORTED/.test(p)), []);
    } finally {
      await page.close();
    }
  });
});

describe('web viewer obstacles', () => {
  let server, browser;
  before(async () => {
    server = await startServer();
    browser = await launchBrowser();
  });
  after(async () => {
    if (browser) await browser.close();
    if (server) await server.stop();
  });

  it('draws jelly-drop\'s floor plane from opened and moves it by an offset', async () => {
    const page = await openViewer(browser, `${server.url}?scene=jelly-drop`);
    try {
      await page.waitForFunction(() => window.squish.scene === 'jelly-drop' && window.squish.bounds);
      await waitFrames(page, 3);
      const obs = await page.evaluate(() => window.squish.obstacles);
      assert.equal(obs.length, 1, 'opened carries the floor obstacle');
      assert.equal(obs[0].type, 'plane');
      assert.equal(obs[0].name, 'floor');
      await page.waitForFunction(() => window.squish.obstaclesDrawn >= 1, null, { timeout: 10000 });
      const on = await pixelStats(page);
      // the floor toggle hides the plane: far fewer pixels are covered
      await page.locator('#view').focus();
      await page.keyboard.press('g');
      await page.waitForFunction(() => window.squish.obstaclesDrawn === 0, null, { timeout: 10000 });
      await page.waitForTimeout(200);
      const off = await pixelStats(page);
      assert.ok(on.nonBackground > off.nonBackground + 0.05,
        `floor plane covers ${on.nonBackground} of the canvas with it, ${off.nonBackground} without`);
      await page.keyboard.press('g');
      await page.waitForFunction(() => window.squish.obstaclesDrawn >= 1, null, { timeout: 10000 });
      // an offset (as an "obstacles" message gives a moving one) moves the plane out of view
      await page.evaluate(() => window.squish.obstacleOffsets.set('floor', [0, 0, -1000]));
      await waitFrames(page, 2);
      await page.waitForTimeout(200);
      const moved = await pixelStats(page);
      assert.ok(moved.nonBackground < on.nonBackground - 0.05, `moved floor still covers ${moved.nonBackground} (${on.nonBackground} in place, ${off.nonBackground} hidden)`);
      assert.deepEqual(page.problems, [], 'no console errors');
    } finally {
      await page.close();
    }
  });
});
