// Headless-browser check of the web renderer's rigs: on a stage whose
// puppet carries a grid or a skeleton (played by a replay), the overlay
// draws the rig from rig frames, and a performer's paint strokes are taken
// without errors.
//
//   PUPPETRY_URL='http://127.0.0.1:PORT/?role=performer&token=T' \
//   PUPPETRY_POINT='640,360' node rigs.mjs
//
// Optional: PUPPETRY_SCREENSHOTS=DIR, CHROMIUM=/path/to/chromium.
// Prints one JSON line; exits 0 only on success, and within 2 minutes either way.

import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { chromium } from 'playwright-core';
import { heldStill } from './page-common.mjs';
import { removeProfile } from './profile.mjs';

const url = process.env.PUPPETRY_URL;
const point = (process.env.PUPPETRY_POINT ?? '').split(',').map(Number);
const shotDir = process.env.PUPPETRY_SCREENSHOTS;
const summary = { ok: false, url };
const userDataDir = fs.mkdtempSync(path.join(os.tmpdir(), 'puppetry-chromium-'));

function finish(ok, reason) {
  removeProfile(userDataDir, summary);
  Object.assign(summary, { ok }, reason ? { reason } : {});
  console.log(JSON.stringify(summary));
  process.exit(ok ? 0 : 1);
}

if (!url || point.length !== 2 || point.some((v) => !Number.isFinite(v))) {
  finish(false, 'set PUPPETRY_URL and PUPPETRY_POINT="x,y"');
}
setTimeout(() => finish(false, 'timed out'), 55_000);

const pageErrors = [];
let context;
let page;
try {
  context = await chromium.launchPersistentContext(userDataDir, {
    executablePath: process.env.CHROMIUM ?? '/usr/bin/chromium',
    headless: true,
    timeout: 20_000,
    args: [
      '--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
      '--disable-background-networking', '--disable-component-update', '--disable-sync',
      '--use-gl=angle', '--use-angle=swiftshader', '--enable-unsafe-swiftshader',
    ],
    viewport: { width: 1280, height: 720 },
  });
  page = context.pages()[0] ?? await context.newPage();
  page.setDefaultTimeout(15_000);
  page.on('pageerror', (err) => pageErrors.push(`pageerror: ${err.message}`));
  page.on('console', (msg) => {
    if (msg.type() === 'error') pageErrors.push(`console: ${msg.text()}`);
  });
  await page.goto(url);
  await page.waitForFunction(() => window.puppetry?.connected && window.puppetry.ready);
  await page.waitForFunction(() => window.puppetry.rigFrames > 5);
  await page.evaluate(() => new Promise((r) => requestAnimationFrame(() => requestAnimationFrame(r))));
  // Rig lines and dots are drawn in their own colours on the overlay.
  const rigPixels = await page.evaluate(() => {
    const c = document.getElementById('overlay');
    const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
    let n = 0;
    for (let i = 0; i < d.length; i += 4) {
      const [r, g, b, a] = [d[i], d[i + 1], d[i + 2], d[i + 3]];
      if (a > 60 && ((b > 150 && r < 120) || (r > 180 && g > 60 && g < 160 && b < 80))) n++;
    }
    return n;
  });
  summary.rigPixels = rigPixels;
  summary.kind = await page.evaluate(() => window.puppetry.stage.puppets[0].rig.kind);
  if (shotDir) {
    fs.mkdirSync(shotDir, { recursive: true });
    fs.writeFileSync(path.join(shotDir, `rig-${summary.kind}.png`), await page.screenshot());
  }
  // A paint stroke across the puppet.
  await page.click('#paint-tool');
  const weightsBefore = await page.evaluate(() => window.puppetry.weightsReceived);
  const [x, y] = await heldStill(page, point);
  await page.mouse.move(x - 40, y);
  await page.mouse.down();
  for (let i = 1; i <= 10; i++) {
    await page.waitForTimeout(16);
    await page.mouse.move(x - 40 + 8 * i, y);
  }
  await page.mouse.up();
  // The painted triangles come back as a weights message and are tinted.
  await page.waitForFunction((n) => window.puppetry.weightsReceived > n, weightsBefore);
  if (shotDir) fs.writeFileSync(path.join(shotDir, `painted-${summary.kind}.png`), await page.screenshot());
  summary.errors = [...(await page.evaluate(() => window.puppetry.errors)), ...pageErrors];
  await context.close();
  if (summary.errors.length) finish(false, 'the page reported errors');
  if (rigPixels < 200) finish(false, `the rig is not drawn (${rigPixels} pixels)`);
  finish(true);
} catch (err) {
  summary.errors = pageErrors;
  await context?.close().catch(() => {});
  finish(false, err.message.split('\n')[0]);
}
