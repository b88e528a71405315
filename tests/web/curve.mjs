// Headless-browser check of curve puppets (issue 13) on the bundled curve
// stage: the rope and the ribbon are drawn as strokes of their colours
// along their centre lines, and a performer's mouse drag near one end of
// the ribbon moves the stroke on the page: the grabbed point is drawn where
// the pointer went, and the far end stays where it was (peeling). Then a
// director draws a stroke with the page's curve tool: it becomes a fourth
// puppet on every page, drawn where it was drawn.
//
//   PUPPETRY_URL='http://127.0.0.1:PORT/?role=performer&token=demo' PUPPETRY_POINT='1110,300' node curve.mjs
//
// Optional: PUPPETRY_SCREENSHOTS=DIR, CHROMIUM=/path/to/chromium. Prints one
// JSON line; exits 0 only on success, and within 2 minutes either way.

import fs from 'node:fs';
import path from 'node:path';
import { startScript, allErrors, heldStill, openPage, pageState, pageUrl, settle, stageToClient, waitFor, rgbOf, colourDistance } from './page-common.mjs';

const { url, shotDir, summary, finish, launch } = startScript();
const errors = [];
const pages = {};
const step = (what) => { summary.step = what; };

// Of a curve puppet's centre-line points (midpoints of its ribbon's vertex
// pairs, as drawn now), how many are drawn in `colour` on the canvas.
async function strokeCoverage(p, id, colour) {
  await settle(p);
  return p.evaluate(([id, colour]) => {
    const api = window.puppetry;
    const pos = api.positions(id);
    const { width: W, height: H } = api.stage.stage;
    const canvas = document.getElementById('gl');
    const shot = api.snapshot(); // bottom row first, as stage y is up
    let on = 0, total = 0;
    for (let i = 0; i + 3 < pos.length; i += 4) {
      const x = (pos[i] + pos[i + 2]) / 2, y = (pos[i + 1] + pos[i + 3]) / 2;
      const px = Math.min(canvas.width - 1, Math.floor((x / W) * canvas.width));
      const py = Math.min(canvas.height - 1, Math.floor((y / H) * canvas.height));
      const k = 4 * (py * canvas.width + px);
      const d = Math.abs(shot[k] - colour[0]) + Math.abs(shot[k + 1] - colour[1]) + Math.abs(shot[k + 2] - colour[2]);
      total++;
      if (d < 60) on++;
    }
    return { on, total };
  }, [id, colour]);
}

// The colour drawn at a stage point.
function drawnAt(p, at) {
  return p.evaluate(([x, y]) => {
    const api = window.puppetry;
    const { width: W, height: H } = api.stage.stage;
    const canvas = document.getElementById('gl');
    const shot = api.snapshot();
    const px = Math.min(canvas.width - 1, Math.floor((x / W) * canvas.width));
    const py = Math.min(canvas.height - 1, Math.floor((y / H) * canvas.height));
    const k = 4 * (py * canvas.width + px);
    return [shot[k], shot[k + 1], shot[k + 2]];
  }, at);
}

try {
  step('launch');
  const context = await launch();
  pages.performer = await openPage(context, url, errors, 'performer');
  const page = pages.performer;
  await waitFor(page, 'the curve puppets', () => {
    const ps = window.puppetry.stage?.puppets ?? [];
    return ps.length === 3 && ps[1].rig.kind === 'curve' && ps[2].rig.kind === 'curve';
  });
  const rope = rgbOf('#9c4a1a');
  const ribbon = rgbOf('#1f5fa8');

  step('both strokes are drawn in their colours');
  summary.rope = await strokeCoverage(page, 1, rope);
  summary.ribbon = await strokeCoverage(page, 2, ribbon);
  // The rope swings (a replay): its frame and the picture may be a frame
  // apart, so most rather than all of its points.
  if (summary.rope.on < 0.6 * summary.rope.total) throw new Error(`the rope is not drawn along its line: ${JSON.stringify(summary.rope)}`);
  if (summary.ribbon.on < 0.9 * summary.ribbon.total) throw new Error(`the ribbon is not drawn along its line: ${JSON.stringify(summary.ribbon)}`);

  step('the ribbon is drawn without corners');
  // Its centre line (the midpoint of each vertex pair) turns smoothly: the
  // stage file's eight points once drew it with 14–20° kinks.
  summary.ribbonTurn = await page.evaluate(() => {
    const v = window.puppetry.positions(2);
    const centre = [];
    for (let i = 0; i + 3 < v.length; i += 4) centre.push([(v[i] + v[i + 2]) / 2, (v[i + 1] + v[i + 3]) / 2]);
    let most = 0;
    for (let i = 2; i < centre.length; i++) {
      const a = Math.atan2(centre[i - 1][1] - centre[i - 2][1], centre[i - 1][0] - centre[i - 2][0]);
      const b = Math.atan2(centre[i][1] - centre[i - 1][1], centre[i][0] - centre[i - 1][0]);
      const turn = Math.abs(((b - a + 3 * Math.PI) % (2 * Math.PI)) - Math.PI);
      most = Math.max(most, (turn * 180) / Math.PI);
    }
    return most;
  });
  if (summary.ribbonTurn > 6) throw new Error(`the ribbon turns ${summary.ribbonTurn.toFixed(1)}° at one point: a corner`);

  step('a drag near the ribbon\'s end moves it there');
  const line = await page.evaluate(() => {
    const pos = window.puppetry.positions(2);
    const out = [];
    for (let i = 0; i + 3 < pos.length; i += 4) out.push([(pos[i] + pos[i + 2]) / 2, (pos[i + 1] + pos[i + 3]) / 2]);
    return out;
  });
  const k = line.length - 8;
  const grab = line[k];
  const to = [grab[0] - 120, grab[1] - 40];
  const [gx, gy] = await heldStill(page, grab);
  await page.mouse.move(gx, gy);
  await page.mouse.down();
  for (let s = 1; s <= 12; s++) {
    const at = [grab[0] + ((to[0] - grab[0]) * s) / 12, grab[1] + ((to[1] - grab[1]) * s) / 12];
    const [x, y] = await stageToClient(page, at);
    await page.mouse.move(x, y);
  }
  await waitFor(page, 'the grabbed point under the pointer', ([k, x, y]) => {
    const pos = window.puppetry.positions(2);
    const cx = (pos[4 * k] + pos[4 * k + 2]) / 2, cy = (pos[4 * k + 1] + pos[4 * k + 3]) / 2;
    return Math.hypot(cx - x, cy - y) < 3;
  }, [k, ...to]);
  const farEnd = await page.evaluate(() => {
    const pos = window.puppetry.positions(2);
    return [(pos[0] + pos[2]) / 2, (pos[1] + pos[3]) / 2];
  });
  summary.farEndMoved = Math.hypot(farEnd[0] - line[0][0], farEnd[1] - line[0][1]);
  if (summary.farEndMoved > 0.5) throw new Error(`the far end moved ${summary.farEndMoved}: the peel reached it`);
  summary.after = await strokeCoverage(page, 2, ribbon);
  if (summary.after.on < 0.9 * summary.after.total) throw new Error(`the dragged ribbon is not drawn along its line: ${JSON.stringify(summary.after)}`);
  const there = await drawnAt(page, to);
  const left = await drawnAt(page, grab);
  summary.there = there;
  summary.left = left;
  if (colourDistance(there, ribbon) > 60) throw new Error(`the pointer's end point is not drawn in the ribbon's colour: ${there}`);
  if (colourDistance(left, ribbon) < 60) throw new Error(`the ribbon is still drawn where it was grabbed: ${left}`);
  if (shotDir) {
    fs.mkdirSync(shotDir, { recursive: true });
    fs.writeFileSync(path.join(shotDir, 'curve-drag.png'), await page.screenshot());
  }
  await page.mouse.up();

  step('a director draws a curve');
  pages.director = await openPage(context, pageUrl(url, '?role=director&token=director'), errors, 'director');
  const director = pages.director;
  await waitFor(director, 'the stage', () => (window.puppetry.stage?.puppets ?? []).length === 3);
  await director.click('#curve-tool');
  await director.fill('#curve-colour', '#2e7d32');
  const drawn = [];
  for (let s = 0; s <= 40; s++) drawn.push([420 + 11 * s, 80 + 25 * Math.sin(s / 6)]);
  const [dx, dy] = await heldStill(director, drawn[0]);
  await director.mouse.move(dx, dy);
  await director.mouse.down();
  for (const at of drawn.slice(1)) {
    const [x, y] = await stageToClient(director, at);
    await director.mouse.move(x, y);
  }
  await director.mouse.up();
  for (const [name, p] of [['director', director], ['performer', page]]) {
    await waitFor(p, `the drawn curve on the ${name}'s page`, () => {
      const ps = window.puppetry.stage?.puppets ?? [];
      return ps.length === 4 && ps[3].rig.kind === 'curve' && ps[3].name === 'curve 1' && window.puppetry.positions(ps[3].id).length > 0;
    });
  }
  summary.drawn = await strokeCoverage(page, 3, rgbOf('#2e7d32'));
  if (summary.drawn.on < 0.9 * summary.drawn.total) throw new Error(`the drawn curve is not drawn along its line: ${JSON.stringify(summary.drawn)}`);
  // Where it was drawn: its centre line starts and ends at the stroke's ends.
  const ends = await page.evaluate(() => {
    const pos = window.puppetry.positions(3);
    const n = pos.length;
    return [[(pos[0] + pos[2]) / 2, (pos[1] + pos[3]) / 2], [(pos[n - 4] + pos[n - 2]) / 2, (pos[n - 3] + pos[n - 1]) / 2]];
  });
  summary.drawnEnds = ends;
  const near = (a, b) => Math.hypot(a[0] - b[0], a[1] - b[1]) < 4;
  if (!near(ends[0], drawn[0]) || !near(ends[1], drawn[drawn.length - 1])) throw new Error(`the curve is not where it was drawn: ${JSON.stringify(ends)}`);

  step('done');
  const all = await allErrors(errors, Object.values(pages));
  if (all.length) throw new Error(`page errors: ${all.join('; ')}`);
  // Closed before its profile is removed, which it writes into until then.
  await context.close();
  finish(true);
} catch (err) {
  summary.pages = {};
  for (const [name, p] of Object.entries(pages)) summary.pages[name] = await pageState(p);
  summary.errors = errors;
  finish(false, String(err?.message ?? err));
}
