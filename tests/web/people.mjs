// Headless-browser check of who holds what (issue 12, observations 1 and 2):
// two named performers and a viewer, plus a show page (`?view=show`,
// transparent, `dots=1`), in one Chromium.
//
//   1. every page's legend lists both performers, each in the colour the
//      server gave them, and the two colours are far apart;
//   2. performer A holds the puppet at HOLD with the mouse, performer B
//      grabs it at POINT and drags it by DRAG; halfway and at the end
//      (still holding) every page draws A's dot under A's finger and B's
//      dot under B's finger, each in its owner's colour (the dot list and
//      the overlay's pixels), and the show page's picture is opaque there:
//      the dot sits on the puppet, not on the background.
//
//   PUPPETRY_URL='http://127.0.0.1:PORT/' PUPPETRY_TOKENS='ana,ben' \
//   PUPPETRY_HOLD='330,230' PUPPETRY_POINT='470,370' PUPPETRY_DRAG='30,0' node people.mjs
//
// PUPPETRY_TOLERANCE: how far (CSS pixels of the page) a dot may be from
// the finger (default 8). Optional: PUPPETRY_SCREENSHOTS=DIR, CHROMIUM.
// Prints one JSON line; exits 0 only on success, and within 2 minutes either way.

import fs from 'node:fs';
import path from 'node:path';
import {
  startScript,
  allErrors, colourDistance, openPage, pageState, pageUrl, pointEnv, rgbOf, stageToClient, waitFor,
} from './page-common.mjs';

const { url, point, shotDir, viewerUrl, summary, finish, launch } = startScript();
const [tokenA, tokenB] = (process.env.PUPPETRY_TOKENS ?? 'ana,ben').split(',');
const hold = pointEnv('PUPPETRY_HOLD', null);
const drag = pointEnv('PUPPETRY_DRAG', [30, 0]);
const tolerance = Number(process.env.PUPPETRY_TOLERANCE ?? 8);
// Okabe–Ito colours differ by at least this much (sum of channel differences).
const DISTINCT = 80;

const errors = [];
const pages = {};
const step = (what) => { summary.step = what; };

async function shot(p, name) {
  if (!shotDir) return;
  fs.mkdirSync(shotDir, { recursive: true });
  fs.writeFileSync(path.join(shotDir, `${name}.png`), await p.screenshot());
}

// The legend's entries on page `p`: owner -> swatch colour "rgb(…)".
const legend = (p) => p.evaluate(() => Object.fromEntries([...document.querySelectorAll('#people .person')]
  .map((e) => [e.dataset.owner, getComputedStyle(e.querySelector('.swatch')).backgroundColor])));

/**
 * Waits until page `p` draws a contact dot of `owner` within `tolerance`
 * CSS pixels of the stage point `at`; returns that dot.
 */
async function waitDot(p, label, owner, at) {
  await waitFor(p, `${label}: ${owner}'s dot at the finger (${at.map(Math.round)})`, ([o, [x, y], tol]) => {
    const api = window.puppetry;
    const [cx, cy] = api.stageToClient(x, y);
    return api.dots().some((d) => d.owner === o && d.kind === 'contact'
      && Math.hypot(...api.stageToClient(...d.at).map((v, i) => v - [cx, cy][i])) <= tol);
  }, [owner, at, tolerance]);
  return p.evaluate(([o]) => window.puppetry.dots().find((d) => d.owner === o && d.kind === 'contact'), [owner]);
}

// The overlay's pixel at a stage point (RGBA, unpremultiplied).
const overlayPixel = (p, at) => p.evaluate(([x, y]) => {
  const c = document.getElementById('overlay');
  const r = c.getBoundingClientRect();
  const [cx, cy] = window.puppetry.stageToClient(x, y);
  const px = Math.round(((cx - r.left) / r.width) * c.width);
  const py = Math.round(((cy - r.top) / r.height) * c.height);
  return [...c.getContext('2d').getImageData(px, py, 1, 1).data];
}, at);

// The show page's GL alpha at a stage point: the puppet is opaque, the
// transparent background is not.
const showAlpha = (p, at) => p.evaluate(([x, y]) => {
  const api = window.puppetry;
  const px = api.snapshot();
  const c = document.getElementById('gl');
  const { width, height } = api.stage.stage;
  const ix = Math.min(c.width - 1, Math.max(0, Math.floor((x / width) * c.width)));
  const iy = Math.min(c.height - 1, Math.max(0, Math.floor((y / height) * c.height))); // bottom row first
  return px[4 * (iy * c.width + ix) + 3];
}, at);

// Every page: each finger's dot under it, in its owner's colour, on the puppet.
async function checkDots(label, fingers) {
  const out = {};
  for (const [name, p] of Object.entries(pages)) {
    for (const f of fingers) {
      const dot = await waitDot(p, `${name} ${label}`, f.owner, f.at);
      const colour = rgbOf(f.colour);
      if (colourDistance(rgbOf(dot.colour), colour) > 6) {
        throw new Error(`${name} ${label}: ${f.owner}'s dot is ${dot.colour}, not ${f.colour}`);
      }
      const pixel = await overlayPixel(p, dot.at);
      if (pixel[3] < 100 || colourDistance(pixel, colour) > 40) {
        throw new Error(`${name} ${label}: the overlay at ${f.owner}'s dot is rgba(${pixel}), not ${f.colour}`);
      }
      const alpha = await showAlpha(pages.show, dot.at);
      if (alpha < 200) throw new Error(`${name} ${label}: ${f.owner}'s dot at ${dot.at.map(Math.round)} is off the puppet (alpha ${alpha})`);
      out[`${name}/${f.name}`] = { dot: dot.at.map((v) => Math.round(v * 10) / 10), finger: f.at.map((v) => Math.round(v * 10) / 10), pixel, alpha };
    }
  }
  return out;
}

try {
  if (!hold) throw new Error('set PUPPETRY_HOLD="x,y": where performer A holds the puppet');
  step('launch');
  const context = await launch();
  step('open the pages');
  pages.a = await openPage(context, pageUrl(url, `?role=performer&token=${encodeURIComponent(tokenA)}`), errors, 'A');
  pages.b = await openPage(context, pageUrl(url, `?role=performer&token=${encodeURIComponent(tokenB)}`), errors, 'B');
  pages.viewer = await openPage(context, viewerUrl, errors, 'viewer');
  pages.show = await openPage(context, pageUrl(url, '?view=show&background=transparent&dots=1'), errors, 'show');
  const you = {};
  for (const k of ['a', 'b']) {
    you[k] = await pages[k].evaluate(() => window.puppetry.you);
    if (!you[k]?.owner || !you[k].colour) throw new Error(`page ${k} has no "you" with an owner and colour: ${JSON.stringify(you[k])}`);
  }
  summary.you = you;

  step('the legends');
  summary.legends = {};
  for (const [name, p] of Object.entries(pages)) {
    if (name === 'show') continue;
    await waitFor(p, `${name}: both performers in the legend`, ([a, b]) => {
      const owners = [...document.querySelectorAll('#people .person')].map((e) => e.dataset.owner);
      return owners.includes(a) && owners.includes(b);
    }, [you.a.owner, you.b.owner]);
    const entries = await legend(p);
    summary.legends[name] = entries;
    for (const k of ['a', 'b']) {
      if (colourDistance(rgbOf(entries[you[k].owner]), rgbOf(you[k].colour)) > 6) {
        throw new Error(`${name}: the legend shows ${you[k].owner} in ${entries[you[k].owner]}, the server said ${you[k].colour}`);
      }
    }
  }
  summary.colourDistance = colourDistance(rgbOf(you.a.colour), rgbOf(you.b.colour));
  if (summary.colourDistance < DISTINCT) {
    throw new Error(`the performers' colours ${you.a.colour} and ${you.b.colour} are too alike (${summary.colourDistance})`);
  }

  step('A holds the puppet');
  const [hx, hy] = await stageToClient(pages.a, hold);
  await pages.a.mouse.move(hx, hy);
  await pages.a.mouse.down();
  const fingerA = { name: 'A', owner: you.a.owner, colour: you.a.colour, at: await pages.a.evaluate(([x, y]) => window.puppetry.clientToStage(x, y), [hx, hy]) };

  step('B drags the puppet');
  const [bx, by] = await stageToClient(pages.b, point);
  const to = await stageToClient(pages.b, [point[0] + drag[0], point[1] + drag[1]]);
  await pages.b.mouse.move(bx, by);
  await pages.b.mouse.down();
  const steps = 10;
  const fingerB = { name: 'B', owner: you.b.owner, colour: you.b.colour, at: point };
  for (let i = 1; i <= steps; i++) {
    await pages.b.waitForTimeout(16);
    const [x, y] = [bx + ((to[0] - bx) * i) / steps, by + ((to[1] - by) * i) / steps];
    await pages.b.mouse.move(x, y);
    if (i === steps / 2) {
      fingerB.at = await pages.b.evaluate(([cx, cy]) => window.puppetry.clientToStage(cx, cy), [x, y]);
      step('the dots halfway');
      summary.halfway = await checkDots('halfway', [fingerA, fingerB]);
    }
  }
  fingerB.at = await pages.b.evaluate(([cx, cy]) => window.puppetry.clientToStage(cx, cy), to);
  step('the dots at the end of the drag');
  summary.end = await checkDots('at the end', [fingerA, fingerB]);
  for (const [name, p] of Object.entries(pages)) await shot(p, `people-${name}`);

  step('let go');
  await pages.b.mouse.up();
  await pages.a.mouse.up();
  for (const [name, p] of Object.entries(pages)) {
    await waitFor(p, `${name}: the contact dots to go`, () => !window.puppetry.dots().some((d) => d.kind === 'contact'));
  }
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
