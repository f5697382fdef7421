// pictures.mjs - pictures per second the viewer draws in headless chromium at 1280x800, at full
// resolution (?autoscale=0) and with the automatic resolution drop, on paper-cube. Not a test:
//   SQUISH=build/squish node tests/web/pictures.mjs
import { startServer, launchBrowser } from './helpers.mjs';

const server = await startServer();
const browser = await launchBrowser();
async function run(query, settleMs) {
  const page = await browser.newPage({ viewport: { width: 1280, height: 800 } });
  await page.goto(`${server.url}?hint=0${query}`);
  await page.waitForTimeout(settleMs);
  const rates = [];
  let scale = null;
  for (let i = 0; i < 5; i++) {
    await page.waitForTimeout(1000);
    const r = await page.evaluate(() => [window.squish.pictureRate, window.squish.autoScale]);
    rates.push(r[0]);
    scale = r[1];
  }
  await page.close();
  rates.sort((a, b) => a - b);
  return `median ${rates[2].toFixed(1)}/s (min ${rates[0].toFixed(1)}, max ${rates[4].toFixed(1)}), scale ${scale === null ? 1 : scale}`;
}
try {
  for (let k = 0; k < 2; k++) {
    console.log(`full resolution: ${await run('&autoscale=0', 3000)}`);
    console.log(`automatic:       ${await run('', 8000)}`);
  }
} finally {
  await browser.close();
  await server.stop();
}
