// Headless-browser check of the director's Puppets panel (puppets added,
// reordered and removed at runtime):
//
//   1. a director's page has the panel; a performer's, a viewer's and the
//      show view have none, and the daemon refuses a performer's upload;
//   2. while a performer holds a puppet deformed, the director picks a PNG
//      with a transparent background and an opaque figure, asks for 300
//      vertices and adds it: every page's stage gets one more puppet,
//      named after the file, whose mesh has about 300 vertices, and the
//      director's page draws the figure where it is, sets its panels up
//      again, and still draws the held puppet as it was (not at rest);
//   3. a fully opaque PNG is added with the warning that it is meshed as
//      its whole rectangle, shown in the panel's notice; a text file named
//      .png is refused (bad_image), the notice says so;
//   4. a picture in two pieces (a head 5 px off its body) is added with
//      the warning that each moves on its own, the notice draws its two
//      pieces, and "join pieces" adds it again as one piece in its place;
//   5. the figure moves one place down in the drawing order (up if the
//      daemon put it at the bottom; every page's stage lists it so);
//      removing asks first (dismissed: nothing goes), then both new
//      puppets go and every page is back to the puppets it had, without
//      an error (frames of a removed puppet still on their way are
//      dropped quietly).
//
//   PUPPETRY_URL='http://127.0.0.1:PORT/?role=director&token=director' \
//   PUPPETRY_POINT='640,360' PUPPETRY_TOKEN=ana node puppets.mjs
//
// PUPPETRY_URL is the director's page; PUPPETRY_TOKEN a performer's token
// (default ana); PUPPETRY_POINT a stage point on the stage's first puppet,
// where the performer holds it.
// Optional: PUPPETRY_SCREENSHOTS=DIR, CHROMIUM=/path/to/chromium.
// Prints one JSON line; exits 0 only on success, and within 2 minutes either way.

import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { encodePng } from './png.mjs';
import {
  startScript, allErrors, changesIn, keepSnapshot, openPage, pageState, pageUrl, stageToClient, waitFor,
} from './page-common.mjs';

const { url, point, shotDir, viewerUrl, summary, finish, launch } = startScript();
const performerToken = process.env.PUPPETRY_TOKEN ?? 'ana';
const VERTICES = 300;
const FIGURE = [220, 30, 200]; // magenta: unlike any puppet of the bundled stages

const errors = [];
const pages = {};
const step = (what) => { summary.step = what; };

async function shot(p, name) {
  if (!shotDir) return;
  fs.mkdirSync(shotDir, { recursive: true });
  fs.writeFileSync(path.join(shotDir, `${name}.png`), await p.screenshot());
}

// The pictures: a figure (a body and a head) cut out on a transparent
// background, a fully opaque rectangle, and text that only calls itself a PNG.
const pictures = fs.mkdtempSync(path.join(os.tmpdir(), 'puppetry-pictures-'));
const inside = (x, y, cx, cy, rx, ry) => ((x - cx) / rx) ** 2 + ((y - cy) / ry) ** 2 <= 1;
const files = {
  figure: path.join(pictures, 'figure.png'),
  opaque: path.join(pictures, 'opaque.png'),
  text: path.join(pictures, 'not-a-picture.png'),
  split: path.join(pictures, 'split.png'),
};
fs.writeFileSync(files.split, encodePng(160, 120, (x, y) => (
  inside(x, y, 80, 80, 50, 34) || inside(x, y, 80, 25, 16, 16) ? [...FIGURE, 255] : [0, 0, 0, 0])));
fs.writeFileSync(files.figure, encodePng(160, 120, (x, y) => (
  inside(x, y, 80, 78, 50, 34) || inside(x, y, 80, 30, 22, 22) ? [...FIGURE, 255] : [0, 0, 0, 0])));
fs.writeFileSync(files.opaque, encodePng(200, 100, () => [20, 150, 160, 255]));
fs.writeFileSync(files.text, 'This is a text file, whatever its name says.\n');

const ids = (p) => p.evaluate(() => window.puppetry.stage.puppets.map((q) => q.id));
const visible = (p, sel) => p.evaluate((s) => !!document.querySelector(s)?.checkVisibility(), sel);
// How far puppet `id` is drawn from its rest shape (stage units, the largest vertex offset).
const deformation = (p, id) => p.evaluate((i) => {
  const rest = window.puppetry.stage.puppets.find((q) => q.id === i).rest;
  return Math.max(...window.puppetry.positions(i).map((v, k) => Math.abs(v - rest[k])));
}, id);
const notice = (p) => p.evaluate(() => {
  const n = document.getElementById('puppet-notice');
  return { shown: !n.hidden && n.checkVisibility(), kind: n.dataset.kind, text: n.textContent };
});

// Every page's stage lists exactly `order` (bottom to top), textures drawn.
async function everyPageShows(order, what) {
  for (const [name, p] of Object.entries(pages)) {
    await waitFor(p, `${name}: ${what} (puppets ${order.join(', ')})`, (o) => {
      const a = window.puppetry;
      return a.ready && a.stage.puppets.length === o.length && a.stage.puppets.every((q, i) => q.id === o[i]);
    }, order);
  }
}

// Every page's stage has the puppets `wanted` (any order; the daemon puts a
// new one where it likes), textures drawn; the director's lineup then.
async function everyPageHas(wanted, what) {
  for (const [name, p] of Object.entries(pages)) {
    await waitFor(p, `${name}: ${what} (puppets ${wanted.join(', ')})`, (w) => {
      const a = window.puppetry;
      return a.ready && a.stage.puppets.length === w.length && w.every((id) => a.stage.puppets.some((q) => q.id === id));
    }, wanted);
  }
  const lineup = await ids(pages.director);
  for (const name of Object.keys(pages)) {
    const theirs = await ids(pages[name]);
    if (theirs.join() !== lineup.join()) throw new Error(`${what}: the ${name} draws ${theirs.join(', ')}, the director ${lineup.join(', ')}`);
  }
  return lineup;
}

// Picks `file`, clicks add, and returns the daemon's answer.
async function upload(p, file, vertices) {
  const before = await p.evaluate(() => window.puppetry.uploads);
  await p.setInputFiles('#puppet-file', file);
  await p.fill('#puppet-vertices', String(vertices));
  await p.click('#puppet-add');
  await waitFor(p, `the answer to uploading ${path.basename(file)}`, (n) => window.puppetry.uploads > n, before, 30_000);
  if (!(await p.evaluate(() => !document.getElementById('puppet-add').disabled))) throw new Error('add stays disabled after the answer');
  return p.evaluate(() => window.puppetry.lastUpload);
}

// Clicks `remove` of puppet `id`, answering the confirm dialog with `accept`.
async function clickRemove(p, id, accept) {
  const asked = new Promise((resolve) => {
    p.once('dialog', async (d) => {
      const text = d.message();
      await (accept ? d.accept() : d.dismiss());
      resolve(text);
    });
  });
  await p.click(`#puppet-list li[data-puppet="${id}"] .puppet-remove`);
  return asked;
}

try {
  step('launch');
  const context = await launch();
  pages.director = await openPage(context, url, errors, 'director');
  pages.viewer = await openPage(context, viewerUrl, errors, 'viewer');
  pages.performer = await openPage(context, pageUrl(url, `?role=performer&token=${encodeURIComponent(performerToken)}`), errors, 'performer');
  const { director, viewer, performer } = pages;

  step('only directors have the panel');
  summary.roles = { director: await director.evaluate(() => window.puppetry.role), performer: await performer.evaluate(() => window.puppetry.role) };
  if (summary.roles.director !== 'director' || summary.roles.performer !== 'performer') throw new Error(`roles ${JSON.stringify(summary.roles)}`);
  if (!(await visible(director, '#puppets-panel'))) throw new Error('the director has no puppets panel');
  for (const name of ['viewer', 'performer']) {
    if (await visible(pages[name], '#puppets-panel')) throw new Error(`a ${name} has the puppets panel`);
  }
  const show = await openPage(context, pageUrl(url, '?view=show'), errors, 'show');
  if (await show.evaluate(() => document.getElementById('puppets-panel') !== null)) throw new Error('the show view has the puppets panel');
  await show.close();

  step('a performer cannot add a puppet');
  const figureBytes = [...fs.readFileSync(files.figure)];
  summary.performerUpload = await performer.evaluate(async (bytes) => {
    const res = await fetch(`/puppets?name=sneaky&vertices=${300}`, {
      method: 'POST',
      headers: { Authorization: `Bearer ${sessionStorage.getItem('puppetry.token')}`, 'Content-Type': 'image/png' },
      body: new Uint8Array(bytes),
    });
    const answer = await res.json().catch(() => null);
    return { status: res.status, code: answer?.code };
  }, figureBytes);
  if (summary.performerUpload.code !== 'forbidden') throw new Error(`a performer's upload was answered ${JSON.stringify(summary.performerUpload)}`);

  step('a performer holds a puppet deformed');
  const before = await ids(director);
  summary.before = before;
  const held = before[0];
  const [hx, hy] = await stageToClient(performer, point);
  await performer.bringToFront();
  await performer.mouse.move(hx, hy);
  await performer.mouse.down();
  await performer.mouse.move(hx + 40, hy, { steps: 8 });
  await waitFor(director, `the director's page draws puppet ${held} deformed`, (id) => {
    const rest = window.puppetry.stage.puppets.find((q) => q.id === id).rest;
    return window.puppetry.positions(id).some((v, k) => Math.abs(v - rest[k]) > 5);
  }, held);

  step('the director adds a figure');
  await director.bringToFront();
  await director.click('#puppets-toggle');
  summary.defaultVertices = await director.inputValue('#puppet-vertices');
  if (summary.defaultVertices !== '1000') throw new Error(`the vertex count starts at ${summary.defaultVertices}, not 1000`);
  await keepSnapshot(director);
  const added = await upload(director, files.figure, VERTICES);
  summary.added = added;
  if (added?.type !== 'puppet_added') throw new Error(`the figure was not added: ${JSON.stringify(added)}`);
  const figure = added.puppet;
  if (added.name !== 'figure') throw new Error(`the puppet is named ${added.name}, not after its file`);
  if (Math.abs(added.vertices - VERTICES) > 0.15 * VERTICES) throw new Error(`asked for ${VERTICES} vertices, got ${added.vertices}`);
  const withFigure = await everyPageHas([...before, figure], 'the figure added');
  const src = await director.evaluate((id) => window.puppetry.stage.puppets.find((q) => q.id === id), figure);
  if (src.rest.length / 2 !== added.vertices) throw new Error(`the stage's mesh has ${src.rest.length / 2} vertices, the answer said ${added.vertices}`);
  const xs = src.rest.filter((_, i) => i % 2 === 0);
  const ys = src.rest.filter((_, i) => i % 2 === 1);
  const box = [Math.min(...xs), Math.min(...ys), Math.max(...xs), Math.max(...ys)];
  summary.box = box;
  summary.drawn = await changesIn(director, box, FIGURE);
  if (summary.drawn.changed < 0.1 * summary.drawn.samples || summary.drawn.near < 0.1 * summary.drawn.samples) {
    throw new Error(`the figure is not drawn where it is: ${JSON.stringify(summary.drawn)}`);
  }
  // The page set itself up again from the new stage message, once, and
  // kept what it knew of the puppets that stayed.
  summary.setUpAgain = await director.evaluate((old) => ({
    editGroups: document.querySelectorAll('#edit-controls .edit-group').length,
    padPuppets: document.getElementById('keypad-puppet').options.length,
    listed: [...document.querySelectorAll('#puppet-list li')].map((li) => Number(li.dataset.puppet)),
    historyKept: old.every((id) => window.puppetry.history[id] !== undefined),
  }), before);
  const again = summary.setUpAgain;
  again.heldDeformation = await deformation(director, held);
  if (!(again.heldDeformation > 5)) throw new Error(`the held puppet is drawn at rest after the lineup changed: ${JSON.stringify(again)}`);
  if (again.editGroups !== withFigure.length || again.padPuppets !== withFigure.length || again.listed.join() !== withFigure.join()
    || !again.historyKept) {
    throw new Error(`the page did not set itself up for the new lineup: ${JSON.stringify(again)}`);
  }
  summary.addedNotice = await notice(director);
  if (!summary.addedNotice.shown || summary.addedNotice.kind === 'error') throw new Error(`the notice after adding: ${JSON.stringify(summary.addedNotice)}`);
  await shot(director, 'puppets-added');
  await performer.mouse.up();

  step('a fully opaque picture is added with a warning');
  const opaque = await upload(director, files.opaque, VERTICES);
  summary.opaque = opaque;
  if (opaque?.type !== 'puppet_added') throw new Error(`the opaque picture was not added: ${JSON.stringify(opaque)}`);
  const warning = (opaque.warnings ?? []).find((w) => /opaque/i.test(w));
  if (!warning) throw new Error(`no warning that every pixel is opaque: ${JSON.stringify(opaque.warnings)}`);
  summary.opaqueNotice = await notice(director);
  if (!summary.opaqueNotice.shown || summary.opaqueNotice.kind !== 'warning' || !summary.opaqueNotice.text.includes(warning)) {
    throw new Error(`the notice does not show the warning: ${JSON.stringify(summary.opaqueNotice)}`);
  }
  const lineup = await everyPageHas([...withFigure, opaque.puppet], 'the opaque picture added');
  await shot(director, 'puppets-opaque');

  step('the toolbar stays at most two rows, the new pictures cover no puppet');
  // Issue 31: at 1280 px the director's toolbar took 3–4 rows and grew a
  // group of buttons with each puppet; each new picture landed on the
  // others at the centre.
  summary.toolbar = await director.evaluate(() => {
    const bar = document.getElementById('bar');
    const rows = new Set([...bar.children].filter((e) => e.checkVisibility()).map((e) => {
      const r = e.getBoundingClientRect();
      return Math.round((r.top + r.height / 2) / 12);
    }));
    return { width: innerWidth, rows: rows.size, height: bar.getBoundingClientRect().height, puppets: window.puppetry.stage.puppets.length };
  });
  if (summary.toolbar.width !== 1280 || summary.toolbar.puppets < 3 || summary.toolbar.rows > 2) {
    throw new Error(`the director's toolbar at ${summary.toolbar.width} px with ${summary.toolbar.puppets} puppets takes ${summary.toolbar.rows} rows`);
  }
  summary.boxes = await director.evaluate(() => window.puppetry.stage.puppets.map((q) => {
    const xs = q.rest.filter((_, k) => k % 2 === 0);
    const ys = q.rest.filter((_, k) => k % 2 === 1);
    return { id: q.id, box: [Math.min(...xs), Math.min(...ys), Math.max(...xs), Math.max(...ys)] };
  }));
  for (const added of [figure, opaque.puppet]) {
    const a = summary.boxes.find((b) => b.id === added).box;
    for (const { id, box: b } of summary.boxes) {
      const cover = Math.max(0, Math.min(a[2], b[2]) - Math.max(a[0], b[0])) * Math.max(0, Math.min(a[3], b[3]) - Math.max(a[1], b[1]));
      if (id !== added && cover > 0) throw new Error(`puppet ${added} was put over puppet ${id}: ${JSON.stringify(summary.boxes)}`);
    }
  }

  step('a text file named .png is refused');
  const bad = await upload(director, files.text, VERTICES);
  summary.badImage = bad;
  if (bad?.type !== 'error' || bad.code !== 'bad_image') throw new Error(`a text file was answered ${JSON.stringify(bad)}`);
  summary.badNotice = await notice(director);
  const said = summary.badNotice;
  if (!said.shown || said.kind !== 'error' || !said.text.includes(bad.message) || !said.text.includes('bad_image')) {
    throw new Error(`the notice does not show the refusal: ${JSON.stringify(said)}`);
  }
  await shot(director, 'puppets-refused');
  await director.click('#puppet-notice-close');
  if ((await notice(director)).shown) throw new Error('the notice stays after dismissing it');
  if ((await ids(director)).join() !== lineup.join()) throw new Error('the refused picture changed the stage');

  step('a picture in two pieces is added with a warning, and joined');
  const split = await upload(director, files.split, VERTICES);
  summary.split = { type: split?.type, pieces: split?.pieces, join: split?.join, warnings: split?.warnings };
  if (split?.type !== 'puppet_added' || split.pieces !== 2 || !(split.join >= 4)) throw new Error(`the split picture: ${JSON.stringify(summary.split)}`);
  if (!(split.warnings ?? []).some((w) => /separate pieces/.test(w))) throw new Error(`no warning of the pieces: ${JSON.stringify(split.warnings)}`);
  await waitFor(director, 'the notice to draw the two pieces', () => document.querySelector('#puppet-notice .puppet-pieces')?.dataset.pieces === '2');
  await shot(director, 'puppets-pieces');
  const beforeJoin = await director.evaluate(() => window.puppetry.uploads);
  await director.click('#puppet-notice .puppet-join');
  await waitFor(director, 'the answer to joining the pieces', (n) => window.puppetry.uploads > n, beforeJoin, 30_000);
  const joined = await director.evaluate(() => window.puppetry.lastUpload);
  summary.joined = { type: joined?.type, pieces: joined?.pieces, warnings: joined?.warnings };
  if (joined?.type !== 'puppet_added' || joined.pieces !== 1) throw new Error(`the joined picture: ${JSON.stringify(summary.joined)}`);
  await everyPageHas([...lineup, joined.puppet], 'the joined picture in place of the split one');
  await clickRemove(director, joined.puppet, true);
  await everyPageHas(lineup, 'the joined picture removed');

  step('the figure moves down');
  // Down, unless the daemon put it at the bottom: then up.
  const i = lineup.indexOf(figure);
  const way = i > 0 ? 'down' : 'up';
  const j = i > 0 ? i - 1 : i + 1;
  const moved = lineup.slice();
  [moved[i], moved[j]] = [moved[j], moved[i]];
  await director.click(`#puppet-list li[data-puppet="${figure}"] .puppet-${way}`);
  await everyPageShows(moved, `the figure one place ${way}`);
  summary.order = { before: lineup, after: moved, way };

  step('removing asks first');
  summary.confirm = await clickRemove(director, opaque.puppet, false);
  await director.waitForTimeout(500);
  if ((await ids(director)).length !== moved.length) throw new Error('a dismissed confirm removed the puppet');
  await clickRemove(director, opaque.puppet, true);
  await everyPageShows(moved.filter((id) => id !== opaque.puppet), 'the opaque picture gone');
  await clickRemove(director, figure, true);
  // The others kept their order: moving the figure only swapped it with a neighbour.
  await everyPageShows(before, 'the figure gone');
  summary.after = await ids(viewer);

  // The browser logs each refused request as a console error: those are the test's own.
  const expected = /Failed to load resource: the server responded with a status of (400|403)/;
  summary.errors = (await allErrors(errors, Object.values(pages))).filter((e) => !expected.test(e));
  step('done');
  await context.close();
  fs.rmSync(pictures, { recursive: true, force: true });
  if (summary.errors.length) finish(false, 'the pages reported errors');
  finish(true);
} catch (err) {
  const states = {};
  for (const [name, p] of Object.entries(pages)) states[name] = { ...(await pageState(p)), notice: await notice(p).catch(() => null) };
  Object.assign(summary, { pages: states, errors: await allErrors(errors, Object.values(pages)) });
  fs.rmSync(pictures, { recursive: true, force: true });
  finish(false, err.message.split('\n')[0]);
}
