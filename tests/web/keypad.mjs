// Headless-browser check of the keyframing pad (docs/protocol.md "Spatial
// keyframing"): a performer makes two key poses of the puppet from the page
// and blends between them by dragging on the pad.
//
//   1. click the pad at A: the cursor goes there (every page's `keys`
//      message says so);
//   2. hold the puppet's head with a finger, drag it left, click "+ key"
//      (the mouse: the finger is busy), lift: key 1 at A;
//   3. click the pad at B, grab the head with the mouse, drag it right,
//      press K (the mouse is busy), let go: key 2 at B;
//   4. drag on the pad from B to A: the puppet's picture changes, the
//      cursor follows, key handles hold the head and are drawn;
//   5. a viewer sees the pad read-only; Shift-drag moves a key, "let go"
//      frees the puppet, right-click and Alt-click delete the keys.
//
//   PUPPETRY_URL='http://127.0.0.1:PORT/?role=performer&token=T' \
//   PUPPETRY_POINT='640,570' node keypad.mjs
//
// PUPPETRY_POINT is a stage point of the part to key (the demo puppet's head);
// PUPPETRY_SHIFT (stage units, default 100) how far it is dragged each way.
// Optional: PUPPETRY_SCREENSHOTS=DIR, CHROMIUM=/path/to/chromium.
// Prints one JSON line; exits 0 only on success, and within 2 minutes either way.

import fs from 'node:fs';
import path from 'node:path';
import {
  startScript,
  changedPixelsAtLeast, keepSnapshot, openPage, pageState, stageToClient, waitFor,
} from './page-common.mjs';

const { url, point, shotDir, viewerUrl, summary, finish, launch } = startScript();
const shift = Number(process.env.PUPPETRY_SHIFT ?? 100);

// The two pad points the keys sit at.
const A = [0.2, 0.2];
const B = [0.8, 0.8];
// How near a pad point counts as there: the pad is 180 CSS px, a pixel is 0.0056.
const NEAR = 0.02;

const errors = [];
let page;
let viewer;
const step = (what) => { summary.step = what; };

async function shot(p, name) {
  if (!shotDir) return;
  fs.mkdirSync(shotDir, { recursive: true });
  fs.writeFileSync(path.join(shotDir, `${name}.png`), await p.screenshot());
}

/** Client coordinates of a pad point on the performer's page. */
function padClient([u, v]) {
  return page.evaluate(([pu, pv]) => {
    const r = document.getElementById('keypad-canvas').getBoundingClientRect();
    return [r.left + pu * r.width, r.top + (1 - pv) * r.height];
  }, [u, v]);
}

/** Waits until puppet 0's cursor (from the server) is near `at`, on page `p`. */
function waitCursor(p, at, what) {
  return waitFor(p, what, ([[u, v], near]) => {
    const c = window.puppetry.keys[0]?.cursor;
    return c && Math.abs(c[0] - u) < near && Math.abs(c[1] - v) < near;
  }, [at, NEAR]);
}

const keyCount = (p) => p.evaluate(() => window.puppetry.keys[0]?.keys.length ?? -1);
const keyHandles = (p) => p.evaluate(() => (window.puppetry.handles[0] ?? []).filter((h) => h.kind === 'key').length);
const waitKeys = (p, n, what) => waitFor(p, what, (count) => window.puppetry.keys[0]?.keys.length === count, n);
const waitKeyHandles = (p, present, what) => waitFor(p, what,
  (on) => (window.puppetry.handles[0] ?? []).some((h) => h.kind === 'key') === on, present);
const waitOwnContact = (p, what) => waitFor(p, what, () => {
  const own = `client:${window.puppetry.stage.client}`;
  return (window.puppetry.handles[0] ?? []).some((h) => h.kind === 'contact' && h.owner === own);
});

// Pixels of a canvas near an RGB colour (the pad's dots and cursor, the overlay's diamonds).
function colourPixels(p, id, [r, g, b]) {
  return p.evaluate(([canvasId, rgb]) => {
    const c = document.getElementById(canvasId);
    const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
    let n = 0;
    for (let i = 0; i < d.length; i += 4) {
      if (d[i + 3] > 200 && Math.abs(d[i] - rgb[0]) + Math.abs(d[i + 1] - rgb[1]) + Math.abs(d[i + 2] - rgb[2]) < 60) n++;
    }
    return n;
  }, [id, [r, g, b]]);
}
const KEY_RGB = [0xff, 0xab, 0x00];
const CURSOR_RGB = [0x00, 0xe5, 0xff];

// Mouse moves in `steps` steps from where it is to (x, y), a frame apart,
// as a hand would (and so the page sends several messages on the way).
async function mouseTo(from, to, steps = 20, each) {
  for (let i = 1; i <= steps; i++) {
    await page.waitForTimeout(16);
    await page.mouse.move(from[0] + ((to[0] - from[0]) * i) / steps, from[1] + ((to[1] - from[1]) * i) / steps);
    if (each) await each(i);
  }
}

try {
  step('launch');
  // Touch too: a finger holds the puppet while the mouse clicks "+ key".
  const context = await launch({ hasTouch: true });
  step('open the viewer page');
  viewer = await openPage(context, viewerUrl, errors, 'viewer');
  step('open the performer page');
  page = await openPage(context, url, errors, 'performer');
  await page.bringToFront();
  await waitFor(page, 'the keys of puppet 0', () => window.puppetry.keys[0] !== undefined);
  await waitFor(viewer, 'the viewer\'s keys of puppet 0', () => window.puppetry.keys[0] !== undefined);
  if (await keyCount(page) !== 0) throw new Error('the puppet has keys already');
  // Issue 31: no empty pad over the stage's corner; the toolbar's "keys"
  // opens it for a director to make the first key.
  await waitFor(page, 'the "keys" button', () => document.getElementById('keypad-open').checkVisibility());
  if (await page.isVisible('#keypad')) throw new Error('an empty key pad shows over a stage with no keys and no pad');
  step('open the key pad');
  await page.click('#keypad-open');
  if (!(await page.isVisible('#keypad'))) throw new Error('the performer has no key pad');
  if (await viewer.isVisible('#keypad')) throw new Error('a viewer sees the pad of a puppet without keys');

  step('cursor to A');
  const [ax, ay] = await padClient(A);
  await page.mouse.click(ax, ay);
  await waitCursor(page, A, 'the cursor at A');

  step('key 1: a finger holds the head to the left, "+ key"');
  const head = await stageToClient(page, point);
  const left = await stageToClient(page, [point[0] - shift, point[1]]);
  const right = await stageToClient(page, [point[0] + shift, point[1]]);
  const cdp = await context.newCDPSession(page);
  const touch = (type, x, y) => cdp.send('Input.dispatchTouchEvent', {
    type, touchPoints: type === 'touchEnd' ? [] : [{ x, y, id: 1 }],
  });
  const framesHeld = await page.evaluate(() => window.puppetry.framesReceived);
  await touch('touchStart', ...head);
  for (let i = 1; i <= 20; i++) {
    await page.waitForTimeout(16);
    await touch('touchMove', head[0] + ((left[0] - head[0]) * i) / 20, head[1]);
  }
  await waitOwnContact(page, 'the finger to hold the head');
  await waitFor(page, 'frames of the held head', (n) => window.puppetry.framesReceived > n, framesHeld);
  await page.click('#key-add');
  await waitKeys(page, 1, 'key 1');
  summary.key1 = await page.evaluate(() => window.puppetry.keys[0].keys[0]);
  await touch('touchEnd');
  await waitKeyHandles(page, true, 'a key handle once the finger lifted');

  step('the pad fits its panel');
  // The panel is as wide as its pad (its buttons once left a blank strip
  // at the pad's right), and all of it is on screen.
  summary.padFit = await page.evaluate(() => {
    const panel = document.getElementById('keypad').getBoundingClientRect();
    const canvas = document.getElementById('keypad-canvas').getBoundingClientRect();
    const outside = [...document.querySelectorAll('#keypad *')]
      .filter((el) => el.getClientRects().length > 0)
      .map((el) => [el.id || el.className || el.tagName, el.getBoundingClientRect()])
      .filter(([, r]) => r.left < panel.left - 0.5 || r.right > panel.right + 0.5)
      .map(([name]) => name);
    const style = getComputedStyle(document.getElementById('keypad'));
    const contentRight = panel.right - parseFloat(style.paddingRight) - parseFloat(style.borderRightWidth);
    return {
      panel: [panel.left, panel.right], canvasRight: canvas.right, contentRight, outside,
      onScreen: panel.left >= 0 && panel.right <= window.innerWidth,
    };
  });
  if (!summary.padFit.onScreen || summary.padFit.outside.length
    || Math.abs(summary.padFit.canvasRight - summary.padFit.contentRight) > 0.5) {
    throw new Error('the key pad does not fit its panel');
  }

  step('cursor to B');
  const [bx, by] = await padClient(B);
  await page.mouse.click(bx, by);
  await waitCursor(page, B, 'the cursor at B');

  step('key 2: the mouse holds the head to the right, K');
  // One key: the blend is that key everywhere, so the head is still left.
  await page.mouse.move(...left);
  await page.mouse.down();
  await waitOwnContact(page, 'the mouse to hold the head');
  await waitKeyHandles(page, false, 'the mouse to take the head over from the key handle');
  const framesRight = await page.evaluate(() => window.puppetry.framesReceived);
  await mouseTo(left, right);
  await waitFor(page, 'frames of the head held right', (n) => window.puppetry.framesReceived > n, framesRight);
  await page.keyboard.press('k');
  await waitKeys(page, 2, 'key 2');
  summary.key2 = await page.evaluate(() => window.puppetry.keys[0].keys[1]);
  await page.mouse.up();
  await waitKeyHandles(page, true, 'the key handle back once the mouse let go');
  await shot(page, 'keyed-at-B');

  step('drag on the pad from B to A');
  await keepSnapshot(page);
  const cursors = [];
  await page.mouse.move(bx, by);
  await page.mouse.down(); // on key 2's dot: the cursor snaps to it
  await mouseTo([bx, by], [ax, ay], 20, async () => {
    cursors.push(await page.evaluate(() => window.puppetry.keys[0].cursor));
  });
  await waitCursor(page, A, 'the cursor to follow the drag to A');
  summary.changedPixels = await changedPixelsAtLeast(page, 500);
  await page.mouse.up();
  // The cursor went through the pad between B and A, not only to the ends.
  const between = new Set(cursors.filter((c) => c && c[0] < B[0] - NEAR && c[0] > A[0] + NEAR
    && c[1] < B[1] - NEAR && c[1] > A[1] + NEAR).map((c) => c.join()));
  summary.cursorsOnTheWay = between.size;
  summary.keyHandles = await keyHandles(page);
  summary.keyHandlePixels = await colourPixels(page, 'overlay', KEY_RGB);
  summary.padKeyPixels = await colourPixels(page, 'keypad-canvas', KEY_RGB);
  summary.padCursorPixels = await colourPixels(page, 'keypad-canvas', CURSOR_RGB);
  await shot(page, 'blended-to-A');
  if (summary.changedPixels < 500) throw new Error(`the pad drag changed only ${summary.changedPixels} pixels`);
  if (between.size < 3) throw new Error(`the cursor took ${between.size} points between B and A`);
  if (summary.keyHandles < 1) throw new Error('no key handles');
  if (summary.keyHandlePixels < 20) throw new Error('the key handles are not drawn');
  if (summary.padKeyPixels < 40 || summary.padCursorPixels < 20) throw new Error('the pad does not show its keys and cursor');

  step('the viewer sees the pad, read-only');
  await waitCursor(viewer, A, 'the viewer\'s cursor at A');
  await waitFor(viewer, 'the viewer\'s pad', () => !document.getElementById('keypad').hidden
    && window.puppetry.keys[0].keys.length === 2);
  if (await viewer.isVisible('#key-add')) throw new Error('a viewer can add keys');
  await viewer.evaluate(() => new Promise((r) => requestAnimationFrame(() => requestAnimationFrame(r))));
  summary.viewerPadKeyPixels = await colourPixels(viewer, 'keypad-canvas', KEY_RGB);
  if (summary.viewerPadKeyPixels < 40) throw new Error('the viewer\'s pad does not show the keys');
  await shot(viewer, 'viewer');

  step('Shift-drag key 2 down');
  const moved = [B[0], 0.4];
  const [mx, my] = await padClient(moved);
  await page.keyboard.down('Shift');
  await page.mouse.move(bx, by);
  await page.mouse.down();
  await mouseTo([bx, by], [mx, my], 10);
  await page.mouse.up();
  await page.keyboard.up('Shift');
  await waitFor(page, 'key 2 to move', ([[u, v], near]) => {
    const k = window.puppetry.keys[0].keys[1];
    return k && Math.abs(k.at[0] - u) < near && Math.abs(k.at[1] - v) < near;
  }, [moved, NEAR]);
  // Moving a key is not moving the cursor.
  await waitCursor(page, A, 'the cursor to stay at A');

  step('let go');
  await page.click('#key-let-go');
  await waitFor(page, 'the cursor to let go', () => window.puppetry.keys[0].cursor === undefined);
  await waitKeyHandles(page, false, 'the key handles to go');

  step('right-click deletes key 2, Alt-click key 1');
  await page.mouse.click(mx, my, { button: 'right' });
  await waitKeys(page, 1, 'key 2 deleted');
  await page.keyboard.down('Alt');
  await page.mouse.click(ax, ay);
  await page.keyboard.up('Alt');
  await waitKeys(page, 0, 'key 1 deleted');
  await waitFor(viewer, 'the viewer\'s pad to hide with no keys', () => document.getElementById('keypad').hidden);

  summary.errors = [...errors, ...(await page.evaluate(() => window.puppetry.errors)),
    ...(await viewer.evaluate(() => window.puppetry.errors))];
  step('done');
  await context.close();
  if (summary.errors.length) finish(false, 'the pages reported errors');
  finish(true);
} catch (err) {
  const p = await pageState(page);
  const v = await pageState(viewer);
  Object.assign(summary, { status: p.status, viewerStatus: v.status, errors: [...errors, ...p.errors, ...v.errors] });
  finish(false, err.message.split('\n')[0]);
}
