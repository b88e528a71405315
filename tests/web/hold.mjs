// Headless-browser check that the stage does not move under a performer's
// finger: while a contact holds the puppet, the toolbar growing a line (a
// name joining the people list, an added puppet's controls; here a wide
// stand-in added to it) does not move the stage; after the lift it does, and without a
// contact it does at once. With PUPPETRY_HOLD_WITH=stroke (a director's
// page) the stage is held by a brush stroke half painted instead.
//
//   PUPPETRY_URL='http://127.0.0.1:PORT/?role=performer&token=T' \
//   PUPPETRY_POINT='400,300' [PUPPETRY_HOLD_WITH=stroke] node hold.mjs
//
// Prints one JSON line: {heldShift, liftShift, freeShift} (how far, in CSS
// pixels, the stage point PUPPETRY_POINT moved on the page while held,
// after the lift, and when the bar grew with nothing held); exits 0 only on
// success, and within 2 minutes either way.

import {
  heldStill, openPage, settle, stageToClient, startScript, waitFor,
} from './page-common.mjs';

const { url, point, summary, finish, launch } = startScript();
const withStroke = process.env.PUPPETRY_HOLD_WITH === 'stroke';
summary.heldWith = withStroke ? 'stroke' : 'contact';
const errors = [];
let page;

const barHeight = () => page.evaluate(() => document.getElementById('bar').getBoundingClientRect().height);
// Makes the toolbar at least one line taller, and waits until it is.
async function growBar(words) {
  const before = await barHeight();
  // Something wide joins the bar (the status line is cut to one line,
  // so it no longer can): a stand-in of `words` words.
  await page.evaluate((n) => {
    const bar = document.getElementById('bar');
    let wide = document.getElementById('test-widener');
    if (!wide) {
      wide = document.createElement('span');
      wide.id = 'test-widener';
      bar.insertBefore(wide, bar.firstChild);
    }
    wide.textContent = Array.from({ length: n }, (_, i) => `word${i}`).join(' ');
  }, words);
  await waitFor(page, 'the toolbar to grow a line', (h) => document.getElementById('bar').getBoundingClientRect().height > h + 10, before);
  await settle(page);
}
const shift = (a, b) => Math.hypot(a[0] - b[0], a[1] - b[1]);

try {
  const context = await launch();
  page = await openPage(context, url, errors, withStroke ? 'director' : 'performer');
  if (withStroke) await page.click('#paint-tool');

  const start = await heldStill(page, point);
  await page.mouse.move(start[0], start[1]);
  await page.mouse.down();
  for (let i = 1; i <= 5; i++) {
    await page.mouse.move(start[0], start[1] - 6 * i);
    await page.waitForTimeout(16);
  }
  if (withStroke) {
    await waitFor(page, 'the stroke to hold the stage', () => window.puppetry.held() === 1);
  } else {
    await waitFor(page, 'the contact to hold the puppet', () => window.puppetry.framesReceived > 0);
  }

  const held = await stageToClient(page, point);
  await growBar(40);
  const whileHeld = await stageToClient(page, point);
  summary.heldShift = shift(held, whileHeld);

  await page.mouse.up();
  await waitFor(page, 'the stage to move down after the lift',
    ([x, y, p]) => window.puppetry.stageToClient(p[0], p[1])[1] > y + 5 || window.puppetry.stageToClient(p[0], p[1])[0] !== x,
    [...held, point]);
  const afterLift = await stageToClient(page, point);
  summary.liftShift = shift(held, afterLift);

  await growBar(120);
  const free = await stageToClient(page, point);
  summary.freeShift = shift(afterLift, free);

  summary.errors = [...(await page.evaluate(() => window.puppetry.errors)), ...errors];
  await context.close();
  if (summary.errors.length) finish(false, 'the page reported errors');
  if (summary.heldShift > 0.5) finish(false, `the stage moved ${summary.heldShift} px under the held ${summary.heldWith}`);
  if (summary.freeShift < 5) finish(false, `with nothing held the stage did not move as the bar grew (${summary.freeShift} px)`);
  finish(true);
} catch (err) {
  summary.errors = [...(await page?.evaluate(() => window.puppetry?.errors ?? []).catch(() => []) ?? []), ...errors];
  finish(false, err.message.split('\n')[0]);
}
