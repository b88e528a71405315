// Headless-browser check of the page's token handling (issue 12,
// observations 3 and 5, page side):
//
//   1. a wrong token: the page says "token refused — viewing only" in a
//      banner, connects again at once as a viewer (the stage shows, the
//      performer tools do not), and never sends the token again: a dropped
//      connection reconnects as a viewer without it;
//   2. a good token: it leaves the address bar at load (kept in
//      sessionStorage), is sent in the hello only, and a reload of the
//      tab is the performer again.
//
//   PUPPETRY_URL='http://127.0.0.1:PORT/' PUPPETRY_POINT='640,360' PUPPETRY_TOKEN=ana node token.mjs
//
// Optional: PUPPETRY_SCREENSHOTS=DIR, CHROMIUM=/path/to/chromium.
// Prints one JSON line; exits 0 only on success, and within 2 minutes either way.

import fs from 'node:fs';
import path from 'node:path';
import { startScript, allErrors, openPage, pageState, pageUrl, waitFor } from './page-common.mjs';

const { url, shotDir, summary, finish, launch } = startScript();
const token = process.env.PUPPETRY_TOKEN ?? 'ana';
const WRONG = 'not-the-token';
const REFUSED = 'token refused — viewing only';

const errors = [];
let wrong;
let good;
const step = (what) => { summary.step = what; };

// Tools only a performer (or director) has; none may show to a viewer.
const PERFORMER_TOOLS = ['#pin-tool', '#edit-controls', '#record', '#paint-controls', '#key-let-go', '#take-download'];
const visibleTools = (p) => p.evaluate((sel) => sel.filter((s) => {
  const e = document.querySelector(s);
  return e && e.checkVisibility();
}), PERFORMER_TOOLS);

try {
  step('launch');
  const context = await launch();

  step('a wrong token');
  // openPage waits for a connected page with its stage: as a viewer here.
  wrong = await openPage(context, pageUrl(url, `?role=performer&token=${WRONG}`), errors, 'wrong');
  await waitFor(wrong, 'the refusal', () => window.puppetry.tokenRefused && window.puppetry.connected);
  summary.wrong = await wrong.evaluate(() => ({
    role: window.puppetry.role,
    stageRole: window.puppetry.stage.role,
    hellos: window.puppetry.hellos,
    href: location.href,
    stored: sessionStorage.getItem('puppetry.token'),
    banner: document.getElementById('banner').checkVisibility() ? document.getElementById('banner-text').textContent : null,
    bannerColour: getComputedStyle(document.getElementById('banner')).backgroundColor,
  }));
  await shot(wrong, 'token-refused');
  const w = summary.wrong;
  if (w.role !== 'viewer' || w.stageRole !== 'viewer') throw new Error(`the refused page is a ${w.role} (stage says ${w.stageRole}), not a viewer`);
  if (w.banner !== REFUSED) throw new Error(`the banner says ${JSON.stringify(w.banner)}, not "${REFUSED}"`);
  if (w.href.includes(WRONG)) throw new Error(`the token is still in the address: ${w.href}`);
  if (w.stored !== null) throw new Error('the refused token is still stored');
  const tools = await visibleTools(wrong);
  if (tools.length) throw new Error(`the refused page shows performer tools: ${tools.join(', ')}`);
  if (JSON.stringify(w.hellos) !== JSON.stringify([{ role: 'performer', token: true }, { role: 'viewer', token: false }])) {
    throw new Error(`the hellos were ${JSON.stringify(w.hellos)}: one with the token, then one viewer`);
  }

  step('the refused page reconnects as a viewer');
  await wrong.evaluate(() => window.puppetry.drop());
  await waitFor(wrong, 'a reconnect', () => window.puppetry.hellos.length === 3 && window.puppetry.connected);
  summary.wrongAfterDrop = await wrong.evaluate(() => window.puppetry.hellos);
  if (JSON.stringify(summary.wrongAfterDrop[2]) !== JSON.stringify({ role: 'viewer', token: false })) {
    throw new Error(`after a drop the page said hello as ${JSON.stringify(summary.wrongAfterDrop[2])}`);
  }

  step('a good token');
  good = await openPage(context, pageUrl(url, `?role=performer&token=${encodeURIComponent(token)}`), errors, 'good');
  summary.good = await good.evaluate(() => ({
    role: window.puppetry.role, href: location.href, stored: sessionStorage.getItem('puppetry.token'),
    hellos: window.puppetry.hellos, banner: document.getElementById('banner').checkVisibility(),
  }));
  if (summary.good.role === 'viewer') throw new Error('the good token made a viewer');
  if (summary.good.href.includes('token=')) throw new Error(`the token is still in the address: ${summary.good.href}`);
  if (!new URL(summary.good.href).searchParams.get('role')) throw new Error('the role left the address too');
  if (summary.good.stored !== token) throw new Error('the token is not kept for a reload');
  if (summary.good.banner) throw new Error('a banner shows on a page that was let in');
  if (!(await good.isVisible('#pin-tool'))) throw new Error('the performer has no pin tool');

  step('a reload is the performer again');
  await good.reload();
  await waitFor(good, 'the reloaded page', () => window.puppetry?.connected && window.puppetry.ready);
  summary.reloaded = await good.evaluate(() => ({ role: window.puppetry.role, hellos: window.puppetry.hellos, href: location.href }));
  if (summary.reloaded.role !== summary.good.role) throw new Error(`after a reload the page is a ${summary.reloaded.role}`);

  summary.errors = await allErrors(errors, [wrong, good]);
  step('done');
  await context.close();
  if (summary.errors.length) finish(false, 'the pages reported errors');
  finish(true);
} catch (err) {
  const a = await pageState(wrong);
  const b = await pageState(good);
  Object.assign(summary, { wrongState: a, goodState: b, errors: await allErrors(errors, [wrong, good]) });
  finish(false, err.message.split('\n')[0]);
}

async function shot(p, name) {
  if (!shotDir) return;
  fs.mkdirSync(shotDir, { recursive: true });
  fs.writeFileSync(path.join(shotDir, `${name}.png`), await p.screenshot());
}
