// Headless-browser check of a stage's keyframing pad areas (a `[[pad]]` in
// the stage file, docs/keyframing.md), issue 31: a contact landing in one
// moves the key cursor instead of grabbing, so the page must draw it.
//
//   1. every puppet's `pads` in the stage message are drawn on the overlay
//      (window.puppetry.pads()), dashed in the key colour, at their stage
//      rectangle;
//   2. the key pad panel shows (the stage has keys), and its key names
//      overlap neither each other nor a key's dot (they did: "wave
//      leftwave right").
//
//   PUPPETRY_URL='http://127.0.0.1:PORT/?role=director&token=T' \
//   PUPPETRY_POINT='110,110' node padarea.mjs      (config/keyframe.toml)
//
// PUPPETRY_POINT is a stage point inside the pad area.
// Optional: PUPPETRY_SCREENSHOTS=DIR, CHROMIUM=/path/to/chromium.
// Prints one JSON line; exits 0 only on success, and within 2 minutes either way.

import fs from 'node:fs';
import path from 'node:path';
import { startScript, openPage, pageState, stageToClient, waitFor } from './page-common.mjs';

const { url, point, shotDir, summary, finish, launch } = startScript();
const errors = [];
let page;
const step = (what) => { summary.step = what; };
const KEY_RGB = [0xff, 0xab, 0x00];

try {
  step('launch');
  const context = await launch();
  page = await openPage(context, url, errors, 'director');
  await waitFor(page, 'the stage\'s pad areas', () => window.puppetry.stage?.puppets.some((p) => p.pads?.length));
  summary.sent = await page.evaluate(() => window.puppetry.stage.puppets.flatMap((p) => (p.pads ?? []).map((pad) => ({ puppet: p.id, ...pad }))));

  step('the pad area is drawn');
  await waitFor(page, 'the overlay to draw the pad areas', (n) => window.puppetry.pads().length === n, summary.sent.length);
  summary.drawn = await page.evaluate(() => window.puppetry.pads());
  for (const sent of summary.sent) {
    if (!summary.drawn.some((d) => d.puppet === sent.puppet && d.area.join() === sent.area.join())) {
      throw new Error(`pad ${JSON.stringify(sent)} is not drawn: ${JSON.stringify(summary.drawn)}`);
    }
  }
  const area = summary.sent[0].area;
  if (!(point[0] > area[0] && point[0] < area[2] && point[1] > area[1] && point[1] < area[3])) {
    throw new Error(`PUPPETRY_POINT ${point} is not in the pad ${area}`);
  }
  // Its outline in the key colour, on the overlay canvas, around the area.
  const [x0, y0] = await stageToClient(page, [area[0], area[3]]);
  const [x1, y1] = await stageToClient(page, [area[2], area[1]]);
  summary.outlinePixels = await page.evaluate(([box, rgb]) => {
    const c = document.getElementById('overlay');
    const r = c.getBoundingClientRect();
    const s = c.width / r.width;
    const [ax, ay, bx, by] = [(box[0] - r.left) * s, (box[1] - r.top) * s, (box[2] - r.left) * s, (box[3] - r.top) * s]
      .map(Math.round);
    const d = c.getContext('2d').getImageData(ax - 3, ay - 3, bx - ax + 6, by - ay + 6).data;
    let n = 0;
    for (let i = 0; i < d.length; i += 4) {
      if (d[i + 3] > 150 && Math.abs(d[i] - rgb[0]) + Math.abs(d[i + 1] - rgb[1]) + Math.abs(d[i + 2] - rgb[2]) < 90) n++;
    }
    return n;
  }, [[x0, y0, x1, y1], KEY_RGB]);
  const perimeter = 2 * ((x1 - x0) + (y1 - y0));
  if (summary.outlinePixels < perimeter / 3) {
    throw new Error(`the pad's outline: ${summary.outlinePixels} key-coloured pixels on a ${Math.round(perimeter)} px perimeter`);
  }

  step('the key names do not overlap');
  await waitFor(page, 'the key pad', () => !document.getElementById('keypad').hidden && window.puppetry.keyLabels().length > 1);
  summary.labels = await page.evaluate(() => window.puppetry.keyLabels());
  const keys = await page.evaluate(() => {
    const k = Object.values(window.puppetry.keys).find((m) => m.keys.length);
    const css = document.getElementById('keypad-canvas').clientWidth;
    return { css, dots: k.keys.map((key) => [key.at[0] * css, (1 - key.at[1]) * css]) };
  });
  const cover = (a, b) => Math.max(0, Math.min(a.x + a.w, b.x + b.w) - Math.max(a.x, b.x))
    * Math.max(0, Math.min(a.y + a.h, b.y + b.h) - Math.max(a.y, b.y));
  summary.labels.forEach((a, i) => {
    if (a.x < 0 || a.y < 0 || a.x + a.w > keys.css + 0.5 || a.y + a.h > keys.css + 0.5) throw new Error(`"${a.text}" sticks out of the pad`);
    summary.labels.slice(i + 1).forEach((b) => {
      if (cover(a, b) > 0) throw new Error(`"${a.text}" and "${b.text}" overlap: ${JSON.stringify([a, b])}`);
    });
    keys.dots.forEach(([x, y], j) => {
      if (cover(a, { x: x - 6, y: y - 6, w: 12, h: 12 }) > 0) throw new Error(`"${a.text}" covers key ${j}'s dot`);
    });
  });
  if (shotDir) {
    fs.mkdirSync(shotDir, { recursive: true });
    fs.writeFileSync(path.join(shotDir, 'padarea.png'), await page.screenshot());
  }
  summary.errors = [...errors, ...(await page.evaluate(() => window.puppetry.errors))];
  step('done');
  await context.close();
  if (summary.errors.length) finish(false, 'the page reported errors');
  finish(true);
} catch (err) {
  const p = await pageState(page);
  Object.assign(summary, { status: p.status, errors: [...errors, ...p.errors] });
  finish(false, err.message.split('\n')[0]);
}
