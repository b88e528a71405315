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
  if (summary.kind === 'grid') {
    // A direct drag (the puppet, not a grid handle), held: the grid's
    // lines stay untangled (they once joined its Bernstein control
    // points, which crossed 17 times after this drag).
    const [gx, gy] = await heldStill(page, point);
    await page.mouse.move(gx, gy);
    await page.mouse.down();
    for (let i = 1; i <= 25; i++) {
      await page.waitForTimeout(16);
      await page.mouse.move(gx + (110 * i) / 25, gy - (140 * i) / 25);
    }
    const frames = await page.evaluate(() => window.puppetry.rigFrames);
    await page.waitForFunction((n) => window.puppetry.rigFrames > n + 3, frames);
    await page.evaluate(() => new Promise((r) => requestAnimationFrame(() => requestAnimationFrame(r))));
    // Crossings of rows with rows and columns with columns: of the lines
    // drawn, and of the control net the overlay once drew (its handles
    // joined up) in the same pose.
    summary.gridCrossings = await page.evaluate(() => {
      const cross = (a, b, c, d) => {
        const side = (p, q, r) => Math.sign((q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0]));
        return side(a, b, c) * side(a, b, d) < 0 && side(c, d, a) * side(c, d, b) < 0;
      };
      const crossings = (groups) => {
        let n = 0;
        for (const group of groups) {
          for (let i = 0; i < group.length; i++) {
            for (let j = i + 1; j < group.length; j++) {
              for (let a = 1; a < group[i].length; a++) {
                for (let b = 1; b < group[j].length; b++) {
                  if (cross(group[i][a - 1], group[i][a], group[j][b - 1], group[j][b])) n++;
                }
              }
            }
          }
        }
        return n;
      };
      // A row's pieces are horizontal: they start and end at about one t.
      const { lines } = window.puppetry.rigLines()[0];
      const horizontal = (l) => Math.abs(l[l.length - 1][0] - l[0][0]) >= Math.abs(l[l.length - 1][1] - l[0][1]);
      const drawn = crossings([lines.filter(horizontal), lines.filter((l) => !horizontal(l))]);
      const { rig } = window.puppetry.stage.puppets[0];
      const q = window.puppetry.rigPoints(0);
      const at = (i) => [q[2 * i], q[2 * i + 1]];
      const rows = Array.from({ length: rig.rows }, (_, r) => Array.from({ length: rig.columns }, (_, c) => at(r * rig.columns + c)));
      const columns = Array.from({ length: rig.columns }, (_, c) => Array.from({ length: rig.rows }, (_, r) => at(r * rig.columns + c)));
      return { drawn, controlNet: crossings([rows, columns]) };
    });
    if (shotDir) fs.writeFileSync(path.join(shotDir, 'grid-held.png'), await page.screenshot());
    await page.mouse.up();
    const { drawn, controlNet } = summary.gridCrossings;
    if (controlNet > 0 && drawn * 3 > controlNet) finish(false, `the grid's lines cross ${drawn} times after a drag (its control net ${controlNet})`);
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
