// Headless-browser check of the show view and the performer view's chrome
// (issue 12, observation 9, page side):
//
//   1. `?view=show`: no UI element at all, the stage as large as the window
//      allows, no handle dots (a performer's pin is on the puppet), an
//      opaque background; with `background=transparent&size=1920x1080` the
//      page and the canvas are transparent and the canvas draws at that
//      size in a smaller window; with `dots=1` the pin's dot is drawn;
//   2. the performer's view at 1920×1080: the toolbar (and the status line
//      in it) is above the stage, never over it; `h` and the bar's buttons
//      hide it and the stage takes the whole window; the fullscreen button
//      works; the connection indicator is green, and a dropped connection
//      shows the red banner until it is back; the latency and frame rate
//      readout fills in.
//
//   PUPPETRY_URL='http://127.0.0.1:PORT/' PUPPETRY_POINT='640,360' PUPPETRY_TOKEN=ana node show.mjs
//
// PUPPETRY_POINT: a stage point on the puppet (pinned there by the performer).
// Optional: PUPPETRY_SCREENSHOTS=DIR, CHROMIUM=/path/to/chromium.
// Prints one JSON line; exits 0 only on success, and within 2 minutes either way.

import fs from 'node:fs';
import path from 'node:path';
import {
  startScript, allErrors, openPage, pageState, pageUrl, resizeTo, settle, stageToClient, waitFor,
} from './page-common.mjs';

const { url, point, shotDir, summary, finish, launch } = startScript();
const token = process.env.PUPPETRY_TOKEN ?? 'ana';
const FULL_HD = { width: 1920, height: 1080 };

const errors = [];
const pages = {};
const step = (what) => { summary.step = what; };

async function shot(p, name, options = {}) {
  if (!shotDir) return;
  fs.mkdirSync(shotDir, { recursive: true });
  fs.writeFileSync(path.join(shotDir, `${name}.png`), await p.screenshot(options));
}

// Elements of the page a person would see, besides the stage and its canvases.
const visibleUi = (p) => p.evaluate(() => [...document.body.querySelectorAll('*')]
  .filter((e) => !['stage', 'gl', 'overlay'].includes(e.id) && e.tagName !== 'SCRIPT' && e.checkVisibility())
  .map((e) => e.id || e.tagName.toLowerCase()));

const rect = (p, sel) => p.evaluate((s) => {
  const e = document.querySelector(s);
  if (!e || !e.checkVisibility()) return null;
  const r = e.getBoundingClientRect();
  return { left: r.left, top: r.top, right: r.right, bottom: r.bottom, width: r.width, height: r.height };
}, sel);

const overlaps = (a, b) => a.left < b.right && b.left < a.right && a.top < b.bottom && b.top < a.bottom;

// The stage as large as the window allows: it spans the window's width or its height.
async function fillsWindow(p) {
  const r = await rect(p, '#stage');
  const win = await p.evaluate(() => ({ width: innerWidth, height: innerHeight }));
  const spans = (Math.abs(r.width - win.width) < 1 && r.left > -1 && r.right < win.width + 1)
    || (Math.abs(r.height - win.height) < 1 && r.top > -1 && r.bottom < win.height + 1);
  return { spans, stage: r, window: win };
}

// Overlay pixels with any alpha: whatever the overlay drew.
const overlayPixels = (p) => p.evaluate(() => {
  const c = document.getElementById('overlay');
  const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
  let n = 0;
  for (let i = 3; i < d.length; i += 4) if (d[i] > 0) n++;
  return n;
});

// The GL canvas's alpha at a stage point and at its lower left corner.
const alphas = (p, at) => p.evaluate(([x, y]) => {
  const api = window.puppetry;
  const px = api.snapshot();
  const c = document.getElementById('gl');
  const { width, height } = api.stage.stage;
  const ix = Math.floor((x / width) * c.width);
  const iy = Math.floor((y / height) * c.height);
  return { puppet: px[4 * (iy * c.width + ix) + 3], corner: px[3] };
}, at);

try {
  step('launch');
  const context = await launch();

  step('a performer pins the puppet');
  pages.performer = await openPage(context, pageUrl(url, `?role=performer&token=${encodeURIComponent(token)}`), errors, 'performer');
  const performer = pages.performer;
  await resizeTo(performer, FULL_HD);
  const pinsBefore = await performer.evaluate(() => (window.puppetry.handles[0] ?? []).filter((h) => h.kind === 'pin').length);
  const [px, py] = await stageToClient(performer, point);
  await performer.keyboard.down('Shift');
  await performer.mouse.click(px, py);
  await performer.keyboard.up('Shift');
  await waitFor(performer, 'the new pin', (n) => (window.puppetry.handles[0] ?? []).filter((h) => h.kind === 'pin').length > n, pinsBefore);

  step('the show view');
  pages.show = await openPage(context, pageUrl(url, '?view=show'), errors, 'show');
  const show = pages.show;
  await resizeTo(show, FULL_HD);
  await waitFor(show, 'the pin in the show view', () => (window.puppetry.handles[0] ?? []).some((h) => h.kind === 'pin'));
  await settle(show);
  summary.show = {
    ui: await visibleUi(show),
    fills: await fillsWindow(show),
    dots: await show.evaluate(() => window.puppetry.dots().length),
    overlayPixels: await overlayPixels(show),
    alpha: await alphas(show, point),
  };
  await shot(show, 'show');
  if (summary.show.ui.length) throw new Error(`the show view shows ${summary.show.ui.join(', ')}`);
  if (!summary.show.fills.spans) throw new Error(`the show view's stage does not fill the window: ${JSON.stringify(summary.show.fills)}`);
  if (summary.show.dots || summary.show.overlayPixels) throw new Error('the show view draws dots without dots=1');
  if (summary.show.alpha.corner !== 255) throw new Error('the show view is transparent without background=transparent');

  step('the show view, transparent at 1920x1080');
  pages.transparent = await openPage(context, pageUrl(url, '?view=show&background=transparent&size=1920x1080'), errors, 'transparent');
  const transparent = pages.transparent;
  await settle(transparent);
  summary.transparent = await transparent.evaluate(() => {
    const c = document.getElementById('gl');
    const { width, height } = window.puppetry.stage.stage;
    const s = Math.min(1920 / width, 1080 / height);
    return {
      canvas: [c.width, c.height], expected: [Math.round(width * s), Math.round(height * s)],
      css: [c.clientWidth, c.clientHeight], window: [innerWidth, innerHeight],
      html: getComputedStyle(document.documentElement).backgroundColor,
      body: getComputedStyle(document.body).backgroundColor,
    };
  });
  summary.transparent.alpha = await alphas(transparent, point);
  summary.transparent.ui = await visibleUi(transparent);
  await shot(transparent, 'show-transparent', { omitBackground: true });
  const t = summary.transparent;
  if (t.canvas.join() !== t.expected.join()) throw new Error(`the canvas draws at ${t.canvas}, not ${t.expected}`);
  if (t.css[0] >= t.canvas[0]) throw new Error('the window was not smaller than the fixed size: the test proves nothing');
  if (t.html !== 'rgba(0, 0, 0, 0)' || t.body !== 'rgba(0, 0, 0, 0)') throw new Error(`the page's background is ${t.html} / ${t.body}`);
  if (t.alpha.corner !== 0) throw new Error(`the stage's background has alpha ${t.alpha.corner}`);
  if (t.alpha.puppet < 200) throw new Error(`the puppet has alpha ${t.alpha.puppet}`);
  if (t.ui.length) throw new Error(`the transparent show view shows ${t.ui.join(', ')}`);

  step('the show view with dots=1');
  pages.dots = await openPage(context, pageUrl(url, '?view=show&dots=1'), errors, 'dots');
  await waitFor(pages.dots, 'the pin\'s dot', () => window.puppetry.dots().some((d) => d.kind === 'pin'));
  summary.dotsPixels = await overlayPixels(pages.dots);
  if (summary.dotsPixels < 20) throw new Error('the dots are not drawn');

  step('the performer view: the toolbar above the stage');
  await performer.bringToFront();
  await settle(performer);
  const bar = await rect(performer, '#bar');
  const status = await rect(performer, '#status');
  const stage = await rect(performer, '#stage');
  summary.performer = { bar, status, stage };
  await shot(performer, 'performer-1080p');
  if (!bar || !status) throw new Error('the performer has no toolbar or status line');
  if (overlaps(bar, stage) || overlaps(status, stage)) throw new Error('the toolbar sits over the stage');

  step('h hides the toolbar');
  await performer.keyboard.press('h');
  await waitFor(performer, 'the toolbar to hide', () => !document.getElementById('bar').checkVisibility());
  await settle(performer);
  summary.hidden = { fills: await fillsWindow(performer), showBar: await rect(performer, '#show-bar'), ui: await visibleUi(performer) };
  await shot(performer, 'performer-hidden');
  if (!summary.hidden.fills.spans) throw new Error('with the toolbar hidden the stage does not fill the window');
  const sb = summary.hidden.showBar;
  if (!sb || sb.width > 48 || sb.height > 48) throw new Error(`the button that brings the toolbar back is ${JSON.stringify(sb)}`);
  if (summary.hidden.ui.some((id) => id !== 'show-bar')) throw new Error(`with the toolbar hidden the page shows ${summary.hidden.ui.join(', ')}`);
  await performer.keyboard.press('h');
  await waitFor(performer, 'the toolbar back', () => document.getElementById('bar').checkVisibility());
  await performer.click('#hide-bar');
  await waitFor(performer, 'the hide button to hide it', () => !document.getElementById('bar').checkVisibility());
  await performer.click('#show-bar');
  await waitFor(performer, 'the show button to bring it back', () => document.getElementById('bar').checkVisibility());
  await settle(performer);
  if (overlaps(await rect(performer, '#bar'), await rect(performer, '#stage'))) throw new Error('the toolbar came back over the stage');

  step('fullscreen');
  await performer.click('#fullscreen');
  await waitFor(performer, 'fullscreen', () => document.fullscreenElement !== null);
  await performer.click('#fullscreen');
  await waitFor(performer, 'fullscreen to end', () => document.fullscreenElement === null);

  step('latency and frame rate');
  await waitFor(performer, 'a round trip and a frame rate', () => window.puppetry.latency !== null && window.puppetry.fps > 0
    && /rtt [\d.]+ ms · \d+ fps/.test(document.getElementById('readout').textContent));
  summary.readout = await performer.textContent('#readout');

  step('the connection indicator');
  const indicator = () => performer.evaluate(() => ({
    connection: document.getElementById('connection').className,
    banner: document.getElementById('banner').checkVisibility() ? document.getElementById('banner-text').textContent : null,
    colour: getComputedStyle(document.getElementById('banner')).backgroundColor,
  }));
  summary.connected = await indicator();
  if (summary.connected.connection !== 'up' || summary.connected.banner !== null) throw new Error(`connected, the indicator is ${JSON.stringify(summary.connected)}`);
  await performer.evaluate(() => window.puppetry.drop());
  await waitFor(performer, 'the red banner', () => !window.puppetry.connected && document.getElementById('banner').checkVisibility());
  summary.disconnected = await indicator();
  await shot(performer, 'performer-disconnected');
  const [r, g, b] = summary.disconnected.colour.match(/\d+/g).map(Number);
  if (!(r > 150 && g < 80 && b < 80)) throw new Error(`the disconnected banner is ${summary.disconnected.colour}, not red`);
  if (summary.disconnected.connection !== 'down') throw new Error('the indicator does not say disconnected');
  await waitFor(performer, 'the reconnect', () => window.puppetry.connected && !document.getElementById('banner').checkVisibility());

  summary.errors = await allErrors(errors, Object.values(pages));
  step('done');
  await context.close();
  if (summary.errors.length) finish(false, 'the pages reported errors');
  finish(true);
} catch (err) {
  const states = {};
  for (const [name, p] of Object.entries(pages)) states[name] = await pageState(p);
  Object.assign(summary, { pages: states, errors: await allErrors(errors, Object.values(pages)) });
  finish(false, err.message.split('\n')[0]);
}
