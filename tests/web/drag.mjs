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
import path from 'node:path';
import {
  changedPixelsAtLeast, keepSnapshot, openPage, stageToClient, startScript, waitFor,
} from './page-common.mjs';

const { url, point, shotDir, summary, finish, launch } = startScript();
const input = process.env.PUPPETRY_INPUT ?? 'mouse';
const minChanged = Number(process.env.PUPPETRY_MIN_CHANGED ?? 500);
summary.input = input;
const errors = [];
let page;

try {
  const context = await launch({ hasTouch: input === 'touch' });
  page = await openPage(context, url, errors, 'performer');

  const shot = async (name) => {
    if (!shotDir) return;
    fs.mkdirSync(shotDir, { recursive: true });
    fs.writeFileSync(path.join(shotDir, `${name}.png`), await page.screenshot());
  };
  // The pixel check reads the WebGL canvas alone, so the handle circles of the
  // overlay cannot make it pass: only the puppet's picture counts.
  await keepSnapshot(page);
  const size = () => page.evaluate(() => `${document.getElementById('gl').width}x${document.getElementById('gl').height}`);
  const sizeBefore = await size();
  await shot('before');

  const [x, y] = await stageToClient(page, point);
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

  await waitFor(page, 'frames after the drag', (n) => window.puppetry.framesReceived > n, framesBefore);
  // The drag's last frames may still be on their way.
  const changed = await changedPixelsAtLeast(page, minChanged);
  const sizeAfter = await size();
  const state = await page.evaluate(() => ({
    framesReceived: window.puppetry.framesReceived,
    lastSequence: window.puppetry.lastSequence,
  }));
  await shot('after');
  const stageRect = () => page.evaluate(() => {
    const r = document.getElementById('stage').getBoundingClientRect();
    return [r.x, r.y, r.width, r.height];
  });
  const stageHeld = await stageRect();
  await release();
  await page.waitForTimeout(100); // a rejected lift would come back as an error
  // The first let-go says the puppet springs back and what keeps a pose.
  summary.letGo = await page.textContent('#hint');
  // Saying so never lays the stage out again under the next touch.
  summary.stageRects = [stageHeld, await stageRect()];
  const pageErrors = await page.evaluate(() => window.puppetry.errors);

  Object.assign(summary, {
    framesBefore, framesAfter: state.framesReceived, lastSequence: state.lastSequence,
    changedPixels: changed, canvas: [sizeBefore, sizeAfter],
    errors: [...pageErrors, ...errors],
  });
  if (shotDir) summary.screenshots = shotDir;
  await context.close();
  if (summary.errors.length) finish(false, 'the page reported errors');
  if (summary.stageRects[0].join() !== summary.stageRects[1].join()) finish(false, 'the stage moved when the let-go hint showed');
  if (changed < 0) finish(false, `the canvas was resized between the pictures (${sizeBefore} to ${sizeAfter})`);
  if (changed < minChanged) finish(false, `only ${changed} pixels changed (need ${minChanged})`);
  finish(true);
} catch (err) {
  // What the page knew: its status line and errors say why it failed.
  summary.status = await page?.textContent('#status', { timeout: 1000 }).catch(() => undefined);
  const ownErrors = await page?.evaluate(() => window.puppetry?.errors ?? []).catch(() => []);
  summary.errors = [...(ownErrors ?? []), ...errors];
  finish(false, err.message.split('\n')[0]);
}
