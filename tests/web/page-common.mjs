// What the page scripts share: a fresh headless Chromium, the one-line JSON
// summary and exit (within 2 minutes whatever hangs), waiting on the page's
// state with messages that say what did not happen, and the canvas snapshot
// comparison.

import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { chromium } from 'playwright-core';
import { removeProfile } from './profile.mjs';

// Generous: a shared 2-core machine under load (CI beside other builds)
// can take seconds per step; a hung script still ends.
const DEADLINE_MS = 115_000;

/**
 * Starts a script run: returns {summary, finish(ok, reason), launch(options)}.
 * finish prints the summary and exits (0 only when ok); a watchdog calls it
 * after DEADLINE_MS, so a hung browser, page or server still ends the run.
 */
/**
 * The environment every page script takes (PUPPETRY_URL, PUPPETRY_POINT,
 * PUPPETRY_SCREENSHOTS), checked, with a run started: {url, point,
 * shotDir, viewerUrl (the same server, no role: a viewer), summary,
 * finish, launch}.
 */
export function startScript() {
  const url = process.env.PUPPETRY_URL;
  const point = (process.env.PUPPETRY_POINT ?? '').split(',').map(Number);
  const shotDir = process.env.PUPPETRY_SCREENSHOTS;
  const summary = { ok: false, url };
  const { finish, launch } = startRun(summary);
  if (!url || point.length !== 2 || point.some((v) => !Number.isFinite(v))) {
    finish(false, 'set PUPPETRY_URL and PUPPETRY_POINT="x,y"');
  }
  const viewer = new URL(url);
  viewer.search = '';
  return { url, point, shotDir, viewerUrl: viewer.toString(), summary, finish, launch };
}

export function startRun(summary) {
  const t0 = Date.now();
  let userDataDir;
  let context;
  const finish = (ok, reason) => {
    // process.exit skips `finally` blocks: clean up here. (Playwright kills
    // the browser it launched when this process exits.)
    if (userDataDir) removeProfile(userDataDir, summary);
    Object.assign(summary, { ok, ms: Date.now() - t0 }, reason ? { reason } : {});
    console.log(JSON.stringify(summary));
    process.exit(ok ? 0 : 1);
  };
  setTimeout(() => finish(false, `timed out after ${DEADLINE_MS} ms${summary.step ? ` (at: ${summary.step})` : ''}`), DEADLINE_MS);

  // A persistent context is how Playwright takes a --user-data-dir: a fresh one.
  const launch = async ({ hasTouch = false } = {}) => {
    userDataDir = fs.mkdtempSync(path.join(os.tmpdir(), 'puppetry-chromium-'));
    context = await chromium.launchPersistentContext(userDataDir, {
      executablePath: process.env.CHROMIUM ?? '/usr/bin/chromium',
      headless: true,
      timeout: 20_000,
      args: [
        '--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
        '--disable-background-networking', '--disable-component-update', '--disable-sync',
        // WebGL on the CPU: headless Chromium without a GPU refuses WebGL otherwise.
        '--use-gl=angle', '--use-angle=swiftshader', '--enable-unsafe-swiftshader',
        // Two pages share the two cores: a page in the background must keep
        // its timers and animation frames going.
        '--disable-background-timer-throttling', '--disable-renderer-backgrounding',
        '--disable-backgrounding-occluded-windows',
        // A page plays a soundtrack after its user picked the file (a
        // gesture); a script's file pick is none.
        '--autoplay-policy=no-user-gesture-required',
      ],
      viewport: { width: 1280, height: 720 },
      hasTouch,
    });
    return context;
  };
  return { finish, launch };
}

/**
 * A page of the context at `url`, its errors collected into `errors`, once
 * connected with its stage and textures ready.
 */
export async function openPage(context, url, errors, label) {
  const page = context.pages().find((p) => p.url() === 'about:blank') ?? await context.newPage();
  page.setDefaultTimeout(30_000);
  page.on('pageerror', (err) => errors.push(`${label} pageerror: ${err.message}`));
  page.on('console', (msg) => {
    if (msg.type() === 'error') errors.push(`${label} console: ${msg.text()}`);
  });
  await page.goto(url);
  await waitFor(page, `${label}: the stage, its textures and who is on it`,
    () => window.puppetry?.connected && window.puppetry.ready && window.puppetry.peopleSeen);
  await layoutSettled(page, label);
  return page;
}

/**
 * Waits until the canvas has kept its size for a few animation frames. The
 * toolbar wraps to a second line when messages after the stage (people,
 * history, takes) widen it, and the stage moves down under it: a picture
 * or a point taken before that is of another layout.
 */
export async function layoutSettled(page, label = 'page') {
  const held = () => page.evaluate(() => new Promise((resolve) => {
    const canvas = document.getElementById('gl');
    const size = () => `${canvas.width}x${canvas.height}`;
    const first = size();
    let frames = 0;
    const step = () => {
      if (size() !== first) return resolve(false);
      if (++frames >= 5) return resolve(true);
      requestAnimationFrame(step);
    };
    requestAnimationFrame(step);
  }));
  for (let tries = 0; tries < 100; tries++) if (await held()) return;
  throw new Error(`${label}: the canvas kept changing size`);
}

/** waitForFunction, failing with a message that says what did not happen. */
export async function waitFor(page, what, fn, arg, timeout = 30_000) {
  try {
    await page.waitForFunction(fn, arg, { timeout, polling: 50 });
  } catch (err) {
    throw new Error(`timed out waiting for ${what}`, { cause: err });
  }
}

/**
 * Resizes the page's window and waits until the page has laid itself out
 * at the new size: the page maps stage to client coordinates from its last
 * layout, so a click computed before the resize event lands elsewhere.
 */
export async function resizeTo(page, size) {
  await page.setViewportSize(size);
  await waitFor(page, `the page laid out at ${size.width}x${size.height}`,
    ([w, h]) => window.innerWidth === w && window.innerHeight === h, [size.width, size.height]);
  await settle(page);
}

/** Two animation frames: the newest state has been drawn and presented. */
export function settle(page) {
  return page.evaluate(() => new Promise((r) => requestAnimationFrame(() => requestAnimationFrame(r))));
}

/**
 * Waits until the stage holds still on the page (stage point `at` at the
 * same client point over two presented frames) and answers that point. A
 * tool's settings appear after the click that turns it on and re-lay out the
 * toolbar and the stage; on a loaded machine a pointer computed before that
 * landed 10 units away from where the test meant (a curve drawn from the
 * wrong point).
 */
export async function heldStill(page, at) {
  let last;
  for (let i = 0; i < 50; i++) {
    await settle(page);
    const now = await stageToClient(page, at);
    if (last && now[0] === last[0] && now[1] === last[1]) return now;
    last = now;
  }
  throw new Error('the page never held its layout still');
}

/** Keeps the GL canvas's pixels now as the "before" picture (see changedPixels, changesIn). */
export async function keepSnapshot(page) {
  await settle(page);
  await page.evaluate(() => {
    window.__before = window.puppetry.snapshot();
    window.__beforeSize = [document.getElementById('gl').width, document.getElementById('gl').height];
  });
}

/**
 * A grid of `n` × `n` stage points over the stage rectangle [x0, y0, x1,
 * y1], each read in keepSnapshot's picture and in the canvas now (each at
 * its own size, so a layout in between does not matter): {samples,
 * changed (beyond rounding noise), near (within 60 of `colour` [r, g, b]
 * now)}.
 */
export async function changesIn(page, rect, colour, n = 40) {
  await settle(page);
  return page.evaluate(([[x0, y0, x1, y1], rgb, count]) => {
    const { width: W, height: H } = window.puppetry.stage.stage;
    const canvas = document.getElementById('gl');
    const pictures = [[window.__before, ...window.__beforeSize], [window.puppetry.snapshot(), canvas.width, canvas.height]];
    // Snapshots are bottom row first, as stage coordinates are y-up.
    const at = ([px, w, h], x, y) => {
      const i = 4 * (Math.min(h - 1, Math.floor((y / H) * h)) * w + Math.min(w - 1, Math.floor((x / W) * w)));
      return [px[i], px[i + 1], px[i + 2]];
    };
    const distance = (a, b) => Math.abs(a[0] - b[0]) + Math.abs(a[1] - b[1]) + Math.abs(a[2] - b[2]);
    let changed = 0;
    let near = 0;
    for (let i = 0; i < count; i++) {
      for (let j = 0; j < count; j++) {
        const x = x0 + ((i + 0.5) / count) * (x1 - x0);
        const y = y0 + ((j + 0.5) / count) * (y1 - y0);
        const now = at(pictures[1], x, y);
        if (distance(at(pictures[0], x, y), now) > 24) changed++;
        if (distance(now, rgb) <= 60) near++;
      }
    }
    return { samples: count * count, changed, near };
  }, [rect, colour, n]);
}

/**
 * Pixels of the GL canvas (the puppet's picture alone, never the overlay)
 * that differ from keepSnapshot's picture beyond rounding noise; -1 when the
 * canvas was resized in between.
 */
export async function changedPixels(page) {
  await settle(page);
  return page.evaluate(() => {
    const a = window.__before;
    const b = window.puppetry.snapshot();
    if (a.length !== b.length) return -1;
    let changed = 0;
    for (let i = 0; i < a.length; i += 4) {
      const d = Math.abs(a[i] - b[i]) + Math.abs(a[i + 1] - b[i + 1]) + Math.abs(a[i + 2] - b[i + 2]);
      if (d > 24) changed++;
    }
    return changed;
  });
}

/**
 * changedPixels, measured again until at least `min` changed or `ms` passed:
 * the last frames of a motion may still be on their way.
 */
export async function changedPixelsAtLeast(page, min, ms = 15_000) {
  let changed = await changedPixels(page);
  const until = Date.now() + ms;
  while (changed >= 0 && changed < min && Date.now() < until) {
    await page.waitForTimeout(100);
    changed = await changedPixels(page);
  }
  return changed;
}

/** Client coordinates of a stage point on the page. */
export function stageToClient(page, [x, y]) {
  return page.evaluate(([sx, sy]) => window.puppetry.stageToClient(sx, sy), [x, y]);
}

/** Whatever the page reported (its own errors list too) after a failure. */
export async function pageState(page) {
  const status = await page?.textContent('#status', { timeout: 1000 }).catch(() => undefined);
  const errors = await page?.evaluate(() => window.puppetry?.errors ?? []).catch(() => []);
  return { status, errors: errors ?? [] };
}

/** `base` (any URL of the server) with its query replaced by `query` ("?role=…" or ""). */
export function pageUrl(base, query) {
  const u = new URL(base);
  u.search = query;
  u.hash = '';
  return u.toString();
}

/** "x,y" (an environment variable) as [x, y], or `fallback` when unset. */
export function pointEnv(name, fallback) {
  const text = process.env[name];
  if (text === undefined || text === '') return fallback;
  const p = text.split(',').map(Number);
  if (p.length !== 2 || p.some((v) => !Number.isFinite(v))) throw new Error(`${name} must be "x,y", not ${text}`);
  return p;
}

/** Every error the pages and their own lists reported. */
export async function allErrors(errors, pages) {
  const own = [];
  for (const p of pages) own.push(...(await p?.evaluate(() => window.puppetry?.errors ?? []).catch(() => []) ?? []));
  return [...errors, ...own];
}

/** "#E69F00" or "rgb(230, 159, 0)" as [r, g, b]. */
export function rgbOf(colour) {
  const hex = /^#([0-9a-f]{6})$/i.exec(colour ?? '');
  if (hex) {
    const n = parseInt(hex[1], 16);
    return [(n >> 16) & 255, (n >> 8) & 255, n & 255];
  }
  return (colour?.match(/\d+(\.\d+)?/g) ?? []).slice(0, 3).map(Number);
}

/** Sum of absolute channel differences of two [r, g, b]. */
export function colourDistance(a, b) {
  return Math.abs(a[0] - b[0]) + Math.abs(a[1] - b[1]) + Math.abs(a[2] - b[2]);
}

/**
 * Ends a script of several pages: on success (`err` undefined) checks that
 * no page reported an error and closes the browser; on failure records
 * every page's state and what they reported. Either way prints the
 * summary and exits (`finish`).
 */
export async function endPages({ err, context, pages, errors, summary, finish }) {
  if (err === undefined) {
    summary.errors = await allErrors(errors, Object.values(pages));
    summary.step = 'done';
    await context.close();
    if (summary.errors.length) finish(false, 'the pages reported errors');
    finish(true);
    return;
  }
  const states = {};
  for (const [name, p] of Object.entries(pages)) states[name] = await pageState(p);
  Object.assign(summary, { pages: states, errors: await allErrors(errors, Object.values(pages)) });
  finish(false, err.message.split('\n')[0]);
}

