// Headless-browser check of roles and safe edits on the page (issue 12):
//
//   1. a director's page has the director's tools (paint, save weights,
//      record, the replays' toggles, key edits); a performer's page only
//      the performer's (pin, undo/redo/reset, the pad's cursor), no
//      director tool;
//   2. the director paints a stroke: every page's undo button lights up
//      (the `history` message); the performer undoes it (the weights are
//      as before the stroke), redoes it, and resets the puppet (pressing
//      twice) to its weights as loaded;
//   3. the director pauses a replay and plays it again from its toggle;
//      every page hears it (the `inputs` message);
//   4. with PUPPETRY_SAVE=1, "save weights" answers with a new versioned
//      file (NAME.vN.mesh.json), not the mesh file itself.
//
//   PUPPETRY_URL='http://127.0.0.1:PORT/' PUPPETRY_POINT='640,360' \
//   PUPPETRY_TOKEN=ana PUPPETRY_DIRECTOR=director node edits.mjs
//
// PUPPETRY_POINT: a stage point on puppet 0 to paint at. The stage needs a
// replay input. Optional: PUPPETRY_SCREENSHOTS=DIR, CHROMIUM.
// Prints one JSON line; exits 0 only on success, and within 2 minutes either way.

import fs from 'node:fs';
import path from 'node:path';
import { startScript, allErrors, heldStill, openPage, pageState, pageUrl, waitFor } from './page-common.mjs';

const { url, point, shotDir, viewerUrl, summary, finish, launch } = startScript();
const token = process.env.PUPPETRY_TOKEN ?? 'ana';
const directorToken = process.env.PUPPETRY_DIRECTOR ?? 'director';
const save = process.env.PUPPETRY_SAVE === '1';

const errors = [];
const pages = {};
const step = (what) => { summary.step = what; };

async function shot(p, name) {
  if (!shotDir) return;
  fs.mkdirSync(shotDir, { recursive: true });
  fs.writeFileSync(path.join(shotDir, `${name}.png`), await p.screenshot());
}

// A stage with no keys and no pad area shows no empty key pad: the
// director gets the toolbar's "keys" to open it (issue 31).
const DIRECTOR_TOOLS = ['#paint-controls', '#save-weights', '#record', '#take-play', '#replay-controls', '#keypad-open'];
const PERFORMER_TOOLS = ['#pin-tool', '#edit-controls'];
const visible = (p, sels) => p.evaluate((s) => s.filter((q) => document.querySelector(q)?.checkVisibility()), sels);
const weightsOf = (p) => p.evaluate(() => window.puppetry.weights[0]);
const sameWeights = (a, b) => a.length === b.length && a.every((v, i) => Math.abs(v - b[i]) <= 1e-6 * Math.max(1, Math.abs(v)));
const button = (kind) => `#edit-controls .edit-group[data-puppet="0"] button.${kind}`;

// Waits until every page's history of puppet 0 says `undo`/`redo` and the
// performer's buttons are enabled accordingly.
async function waitHistory(undo, redo, what) {
  for (const [name, p] of Object.entries(pages)) {
    await waitFor(p, `${name}: ${what} (undo ${undo}, redo ${redo})`, ([u, r]) => {
      const h = window.puppetry.history[0];
      return h && h.undo === u && h.redo === r;
    }, [undo, redo]);
  }
  const state = await pages.performer.evaluate(([u, r]) => [document.querySelector(u).disabled, document.querySelector(r).disabled],
    [button('undo'), button('redo')]);
  if (state[0] !== (undo === 0) || state[1] !== (redo === 0)) throw new Error(`${what}: undo/redo disabled ${state}, history ${undo}/${redo}`);
}

async function waitWeights(expected, what) {
  for (const [name, p] of Object.entries(pages)) {
    await waitFor(p, `${name}: ${what}`, (w) => {
      const now = window.puppetry.weights[0];
      return now && now.length === w.length && now.every((v, i) => Math.abs(v - w[i]) <= 1e-6 * Math.max(1, Math.abs(v)));
    }, expected);
  }
}

try {
  step('launch');
  const context = await launch();
  pages.director = await openPage(context, pageUrl(url, `?role=director&token=${encodeURIComponent(directorToken)}`), errors, 'director');
  pages.performer = await openPage(context, pageUrl(url, `?role=performer&token=${encodeURIComponent(token)}`), errors, 'performer');
  pages.viewer = await openPage(context, viewerUrl, errors, 'viewer');
  const { director, performer, viewer } = pages;

  step('the tools each role gets');
  await waitFor(director, 'the replays', () => window.puppetry.inputs?.replays?.length > 0);
  await waitFor(performer, 'the performer\'s history', () => window.puppetry.history[0] !== undefined);
  summary.roles = {
    director: await director.evaluate(() => window.puppetry.role),
    performer: await performer.evaluate(() => window.puppetry.role),
  };
  if (summary.roles.director !== 'director' || summary.roles.performer !== 'performer') throw new Error(`roles ${JSON.stringify(summary.roles)}`);
  // The director opens the pad for a puppet without keys (a director makes them).
  const directorHas = await visible(director, [...DIRECTOR_TOOLS, ...PERFORMER_TOOLS]);
  const directorLacks = [...DIRECTOR_TOOLS, ...PERFORMER_TOOLS].filter((s) => !directorHas.includes(s));
  if (directorLacks.length) throw new Error(`the director lacks ${directorLacks.join(', ')}`);
  const performerDirects = await visible(performer, DIRECTOR_TOOLS);
  if (performerDirects.length) throw new Error(`a performer has director tools: ${performerDirects.join(', ')}`);
  const performerTools = await visible(performer, PERFORMER_TOOLS);
  const performerLacks = PERFORMER_TOOLS.filter((s) => !performerTools.includes(s));
  if (performerLacks.length) throw new Error(`the performer lacks ${performerLacks.join(', ')}`);
  const viewerHas = await visible(viewer, [...DIRECTOR_TOOLS, ...PERFORMER_TOOLS]);
  if (viewerHas.length) throw new Error(`a viewer has tools: ${viewerHas.join(', ')}`);
  await shot(director, 'edits-director');
  await shot(performer, 'edits-performer');

  const history0 = await performer.evaluate(() => window.puppetry.history[0]);
  summary.historyBefore = history0;
  const loaded = await weightsOf(performer);

  step('the director paints a stroke');
  await director.bringToFront();
  await director.click('#paint-tool');
  const [x, y] = await heldStill(director, point);
  const weightsBefore = await director.evaluate(() => window.puppetry.weightsReceived);
  await director.mouse.move(x - 30, y);
  await director.mouse.down();
  for (let i = 1; i <= 10; i++) {
    await director.waitForTimeout(16);
    await director.mouse.move(x - 30 + 6 * i, y);
  }
  await director.mouse.up();
  await director.click('#paint-tool');
  await waitFor(director, 'the painted weights', (n) => window.puppetry.weightsReceived > n, weightsBefore);
  await waitHistory(history0.undo + 1, 0, 'one stroke, one undo step');
  const painted = await weightsOf(director);
  if (sameWeights(painted, loaded)) throw new Error('the stroke changed no weight');
  await waitWeights(painted, 'the painted weights');

  step('the performer undoes, redoes and resets');
  await performer.bringToFront();
  await performer.click(button('undo'));
  await waitWeights(loaded, 'the weights after undo');
  await waitHistory(history0.undo, 1, 'after undo');
  await performer.click(button('redo'));
  await waitWeights(painted, 'the weights after redo');
  await waitHistory(history0.undo + 1, 0, 'after redo');
  await performer.click(button('reset'));
  if (!(await performer.evaluate((s) => document.querySelector(s).classList.contains('armed'), button('reset')))) {
    throw new Error('one press of reset did not ask to press again');
  }
  await performer.click(button('reset'));
  await waitWeights(loaded, 'the weights after reset');
  summary.historyAfterReset = await performer.evaluate(() => window.puppetry.history[0]);

  step('the director pauses and plays a replay');
  await director.bringToFront();
  const replay = await director.evaluate(() => window.puppetry.inputs.replays[0]);
  summary.replay = replay;
  const toggle = `#replay-controls button[data-source="${replay.name}"]`;
  for (const playing of [!replay.playing, replay.playing]) {
    await director.click(toggle);
    for (const [name, p] of Object.entries(pages)) {
      await waitFor(p, `${name}: ${replay.name} ${playing ? 'playing' : 'paused'}`,
        ([n, on]) => window.puppetry.inputs?.replays.some((r) => r.name === n && r.playing === on), [replay.name, playing]);
    }
    const pressed = await director.getAttribute(toggle, 'aria-pressed');
    if (pressed !== String(playing)) throw new Error(`the toggle says aria-pressed=${pressed} while ${playing ? 'playing' : 'paused'}`);
  }

  if (save) {
    step('save weights');
    await director.click('#save-weights');
    await waitFor(director, 'weights_saved', () => window.puppetry.weightsSaved !== undefined);
    summary.saved = await director.evaluate(() => window.puppetry.weightsSaved.file);
    if (!/\.v\d+\.mesh\.json$/.test(summary.saved)) throw new Error(`the weights went to ${summary.saved}, not a new versioned file`);
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
