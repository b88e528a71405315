// Headless-browser check of the web renderer: a performer drags a puppet and
// the picture must change.
//
//   PUPPETRY_URL='http://127.0.0.1:PORT/?role=performer&token=T' \
//   PUPPETRY_POINT='400,300' node drag.mjs
//
// Optional: PUPPETRY_INPUT=mouse|touch (default mouse), PUPPETRY_MIN_CHANGED
// (pixels that must change, default 500), PUPPETRY_SCREENSHOTS=DIR (keep the
// before/after PNGs there), CHROMIUM=/path/to/chromium.
// Prints one JSON line; exits 0 only on success, and within 2 minutes either way.

import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { chromium } from 'playwright-core';

const DEADLINE_MS = 55_000;
const url = process.env.PUPPETRY_URL;
const point = (process.env.PUPPETRY_POINT ?? '').split(',').map(Number);
const input = process.env.PUPPETRY_INPUT ?? 'mouse';
const minChanged = Number(process.env.PUPPETRY_MIN_CHANGED ?? 500);
const shotDir = process.env.PUPPETRY_SCREENSHOTS;
const t0 = Date.now();
const summary = { ok: false, input, url };

let userDataDir;

function finish(ok, reason) {
  // process.exit skips `finally` blocks: clean up here.
  if (userDataDir) fs.rmSync(userDataDir, { recursive: true, force: true });
  Object.assign(summary, { ok, ms: Date.now() - t0 }, reason ? { reason } : {});
  console.log(JSON.stringify(summary));
  process.exit(ok ? 0 : 1);
}

if (!url || point.length !== 2 || point.some((v) => !Number.isFinite(v))) {
  finish(false, 'set PUPPETRY_URL and PUPPETRY_POINT="x,y"');
}

// The hard stop: whatever hangs (browser launch, page, server), we exit in time.
// (Playwright kills the browser it launched when this process exits.)
const watchdog = setTimeout(() => {
  finish(false, `timed out after ${DEADLINE_MS} ms`);
}, DEADLINE_MS);

userDataDir = fs.mkdtempSync(path.join(os.tmpdir(), 'puppetry-chromium-'));
const pageErrors = [];
let context;
let page;

// waitForFunction, failing with a message that says what did not happen.
async function waitFor(what, fn, arg) {
  try {
    await page.waitForFunction(fn, arg);
  } catch {
    throw new Error(`timed out waiting for ${what}`);
  }
}

try {
  // A persistent context is how Playwright takes a --user-data-dir: a fresh one.
  context = await chromium.launchPersistentContext(userDataDir, {
    executablePath: process.env.CHROMIUM ?? '/usr/bin/chromium',
    headless: true,
    timeout: 20_000,
    args: [
      '--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
      '--disable-background-networking', '--disable-component-update', '--disable-sync',
      // WebGL on the CPU: headless Chromium without a GPU refuses WebGL otherwise.
      '--use-gl=angle', '--use-angle=swiftshader', '--enable-unsafe-swiftshader',
    ],
    viewport: { width: 1280, height: 720 },
    hasTouch: input === 'touch',
  });
  page = context.pages()[0] ?? await context.newPage();
  page.setDefaultTimeout(15_000);
  page.on('pageerror', (err) => pageErrors.push(`pageerror: ${err.message}`));
  page.on('console', (msg) => {
    if (msg.type() === 'error') pageErrors.push(`console: ${msg.text()}`);
  });

  await page.goto(url);
  await waitFor('the stage and its textures', () => window.puppetry?.connected && window.puppetry.ready);
  // Two animation frames: the newest state has been drawn and presented.
  const settle = () => page.evaluate(() => new Promise((r) => requestAnimationFrame(() => requestAnimationFrame(r))));
  await settle();

  const shot = async (name) => {
    const png = await page.screenshot();
    if (shotDir) {
      fs.mkdirSync(shotDir, { recursive: true });
      fs.writeFileSync(path.join(shotDir, `${name}.png`), png);
    }
    return png;
  };
  // The pixel check reads the WebGL canvas alone, so the handle circles of the
  // overlay cannot make it pass: only the puppet's picture counts.
  await page.evaluate(() => { window.__before = window.puppetry.snapshot(); });
  await shot('before');

  const [x, y] = await page.evaluate(([sx, sy]) => window.puppetry.stageToClient(sx, sy), point);
  summary.from = [Math.round(x), Math.round(y)];
  const framesBefore = await page.evaluate(() => window.puppetry.framesReceived);
  const steps = 20;
  const pause = () => page.waitForTimeout(16);

  // Drag upward by 100 CSS px and hold there: the second picture is taken
  // while the contact still holds the puppet, since a server may let it spring
  // back when released.
  let release;
  if (input === 'touch') {
    // Real touch events through the DevTools protocol (pointerType "touch").
    const cdp = await context.newCDPSession(page);
    const touch = (type, px, py) => cdp.send('Input.dispatchTouchEvent', {
      type, touchPoints: type === 'touchEnd' ? [] : [{ x: px, y: py, id: 1 }],
    });
    await touch('touchStart', x, y);
    for (let i = 1; i <= steps; i++) { await pause(); await touch('touchMove', x, y - (100 * i) / steps); }
    release = () => touch('touchEnd');
  } else {
    await page.mouse.move(x, y);
    await page.mouse.down();
    for (let i = 1; i <= steps; i++) { await pause(); await page.mouse.move(x, y - (100 * i) / steps); }
    release = () => page.mouse.up();
  }

  await waitFor('frames after the drag', (n) => window.puppetry.framesReceived > n, framesBefore);
  // The drag's last frames may still be on their way: measure until the
  // picture has changed enough, or the page's time is up.
  const measure = async () => {
    await settle();
    return page.evaluate(() => {
      const a = window.__before;
      const b = window.puppetry.snapshot();
      let changed = 0;
      if (a.length === b.length) {
        for (let i = 0; i < a.length; i += 4) {
          const d = Math.abs(a[i] - b[i]) + Math.abs(a[i + 1] - b[i + 1]) + Math.abs(a[i + 2] - b[i + 2]);
          if (d > 24) changed++; // ignore rounding noise
        }
      } else {
        changed = -1; // canvas resized between the pictures
      }
      const p = window.puppetry;
      return { changed, total: a.length / 4, framesReceived: p.framesReceived, lastSequence: p.lastSequence, errors: p.errors };
    });
  };
  let result = await measure();
  const measureUntil = Date.now() + 15_000;
  while (result.changed < minChanged && result.changed >= 0 && Date.now() < measureUntil) {
    await page.waitForTimeout(100);
    result = await measure();
  }
  await shot('after');
  await release();
  await page.waitForTimeout(100); // a rejected lift would come back as an error
  const lateErrors = await page.evaluate(() => window.puppetry.errors);

  Object.assign(summary, {
    framesBefore, framesAfter: result.framesReceived, lastSequence: result.lastSequence,
    changedPixels: result.changed, totalPixels: result.total,
    errors: [...lateErrors, ...pageErrors],
  });
  if (shotDir) summary.screenshots = shotDir;
  await context.close();
  clearTimeout(watchdog);
  if (summary.errors.length) finish(false, 'the page reported errors');
  if (result.changed < minChanged) finish(false, `only ${result.changed} pixels changed (need ${minChanged})`);
  finish(true);
} catch (err) {
  // What the page knew: its status line and errors say why it failed.
  summary.status = await page?.textContent('#status', { timeout: 1000 }).catch(() => undefined);
  const ownErrors = await page?.evaluate(() => window.puppetry?.errors ?? []).catch(() => []);
  summary.errors = [...(ownErrors ?? []), ...pageErrors];
  await context?.close().catch(() => {});
  finish(false, err.message.split('\n')[0]);
}
