// Headless-browser check of takes from the page: a performer presses the
// record button, which turns red with "REC take-001" and a running time on
// the performer's page and on a viewer's; while it records, that button is
// the page's one stop, play, overdub and replace are disabled and take-001
// is listed but cannot be chosen; drags the puppet; presses it again, and
// the take list then holds take-001, which can be played.
//
//   PUPPETRY_URL='http://127.0.0.1:PORT/?role=performer&token=T' \
//   PUPPETRY_POINT='640,360' node record.mjs
//
// The daemon must record into an empty takes folder (the take is take-001).
// PUPPETRY_POINT is a stage point on the puppet to drag. Optional:
// PUPPETRY_SCREENSHOTS=DIR, CHROMIUM=/path/to/chromium.
// Prints one JSON line; exits 0 only on success, and within 2 minutes either way.

import fs from 'node:fs';
import path from 'node:path';
import {
  startScript,
  changedPixelsAtLeast, keepSnapshot, openPage, pageState, stageToClient, waitFor,
} from './page-common.mjs';

const { url, point, shotDir, viewerUrl, summary, finish, launch } = startScript();

const errors = [];
let performer;
let viewer;
const step = (what) => { summary.step = what; };

async function shot(page, name) {
  if (!shotDir) return;
  fs.mkdirSync(shotDir, { recursive: true });
  fs.writeFileSync(path.join(shotDir, `${name}.png`), await page.screenshot());
}

// The state line's time, "REC take-001 0:01.3" -> 1.3 s (NaN if not recording).
const ELAPSED = /^REC (\S+) (\d+):(\d+(?:\.\d+)?)/;
const elapsedOf = (text) => {
  const m = ELAPSED.exec(text ?? '');
  return m ? Number(m[2]) * 60 + Number(m[3]) : NaN;
};

// "rgb(r, g, b)" (or rgba) as numbers.
const rgb = (css) => (css.match(/\d+(\.\d+)?/g) ?? []).slice(0, 3).map(Number);
const reddish = ([r, g, b]) => r >= 150 && g <= 120 && b <= 120;

try {
  step('launch');
  const context = await launch();
  step('open the performer page');
  performer = await openPage(context, url, errors, 'performer');
  step('open the viewer page');
  viewer = await openPage(context, viewerUrl, errors, 'viewer');
  await performer.bringToFront();

  step('the record button before recording');
  summary.viewerRole = await viewer.evaluate(() => window.puppetry.stage.role);
  if (summary.viewerRole !== 'viewer') throw new Error(`the second page is a ${summary.viewerRole}, not a viewer`);
  if (!(await performer.isVisible('#record'))) throw new Error('the performer has no record button');
  if (await viewer.isVisible('#record')) throw new Error('a viewer has a record button');
  const pressedBefore = await performer.getAttribute('#record', 'aria-pressed');
  if (pressedBefore !== 'false') throw new Error(`#record is aria-pressed=${pressedBefore} before recording`);

  step('start recording');
  // Recording never lays the stage out again (the running time once
  // wrapped a director's toolbar onto a third line at 1280 px).
  const layoutOf = (p) => p.evaluate(() => ({
    bar: document.getElementById('bar').getBoundingClientRect().height,
    stageTop: document.getElementById('stage').getBoundingClientRect().top,
  }));
  summary.layout = { before: await layoutOf(performer) };
  await performer.click('#record');
  await waitFor(performer, 'the record button to turn on', () => document.getElementById('record').getAttribute('aria-pressed') === 'true');
  summary.recordBackground = await performer.evaluate(() => getComputedStyle(document.getElementById('record')).backgroundColor);
  if (!reddish(rgb(summary.recordBackground))) throw new Error(`the record button is ${summary.recordBackground}, not red`);

  step('REC take-001 with a running time');
  await waitFor(performer, '"REC take-001" in #take-state',
    (re) => new RegExp(re).test(document.getElementById('take-state').textContent), ELAPSED.source.replace('(\\S+)', 'take-001'));
  const first = elapsedOf(await performer.textContent('#take-state'));
  await waitFor(performer, 'the recording time to increase', ([re, t0]) => {
    const m = new RegExp(re).exec(document.getElementById('take-state').textContent);
    return m && Number(m[2]) * 60 + Number(m[3]) > t0;
  }, [ELAPSED.source, first]);
  summary.elapsed = [first, elapsedOf(await performer.textContent('#take-state'))];
  summary.layout.during = await layoutOf(performer);
  if (JSON.stringify(summary.layout.before) !== JSON.stringify(summary.layout.during)) {
    throw new Error('the toolbar changed height while recording: the stage moved');
  }

  step('the viewer sees the recording');
  await waitFor(viewer, 'the viewer\'s #take-state to say "REC take-001"', () => {
    const el = document.getElementById('take-state');
    return el.textContent.startsWith('REC take-001') && el.classList.contains('recording')
      && window.puppetry.take?.recording === 'take-001';
  });
  if (!(await viewer.isVisible('#take-state'))) throw new Error('the viewer\'s take state is not shown');
  summary.viewerStateColour = await viewer.evaluate(() => getComputedStyle(document.getElementById('take-state')).color);
  if (!reddish(rgb(summary.viewerStateColour))) throw new Error(`the viewer's take state is ${summary.viewerStateColour}, not red`);
  summary.viewerState = await viewer.textContent('#take-state');
  await shot(performer, 'recording-performer');
  await shot(viewer, 'recording-viewer');

  step('while recording: one stop, and nothing to play');
  await performer.bringToFront();
  await waitFor(performer, 'take-001 listed as recording, not to be chosen', () => {
    const o = document.querySelector('#take-list option[value="take-001"]');
    return o && o.disabled && /recording/.test(o.textContent);
  });
  summary.whileRecording = await performer.evaluate(() => {
    const shown = (el) => el && !el.hidden && el.getClientRects().length > 0;
    const buttons = [...document.querySelectorAll('#take-controls button')].filter(shown);
    return {
      stops: buttons.filter((b) => /stop/i.test(b.textContent)).map((b) => b.id),
      record: document.getElementById('record').textContent,
      disabled: ['take-play', 'take-overdub', 'take-replace'].filter((id) => document.getElementById(id).disabled),
      list: [...document.querySelectorAll('#take-list option')].map((o) => ({ name: o.value, disabled: o.disabled, text: o.textContent })),
    };
  });
  const w = summary.whileRecording;
  if (w.stops.length !== 1 || w.stops[0] !== 'record') throw new Error(`while recording the stop buttons are ${JSON.stringify(w.stops)}, not the one record button`);
  if (w.disabled.length !== 3) throw new Error(`while recording only ${JSON.stringify(w.disabled)} of play, overdub and replace are disabled`);
  if (w.list.some((o) => !o.disabled)) throw new Error(`while recording the list offers ${JSON.stringify(w.list)}`);

  step('drag the puppet');
  await performer.bringToFront();
  await keepSnapshot(performer);
  const [x, y] = await stageToClient(performer, point);
  const framesBefore = await performer.evaluate(() => window.puppetry.framesReceived);
  await performer.mouse.move(x, y);
  await performer.mouse.down();
  for (let i = 1; i <= 20; i++) {
    await performer.waitForTimeout(16);
    await performer.mouse.move(x, y - (100 * i) / 20);
  }
  await waitFor(performer, 'frames after the drag', (n) => window.puppetry.framesReceived > n, framesBefore);
  summary.changedPixels = await changedPixelsAtLeast(performer, 500);
  await performer.mouse.up();
  if (summary.changedPixels < 500) throw new Error(`the drag changed only ${summary.changedPixels} pixels`);

  step('stop recording');
  await performer.click('#record');
  await waitFor(performer, 'the record button to turn off', () => document.getElementById('record').getAttribute('aria-pressed') === 'false');
  step('take-001 in the take list');
  await waitFor(performer, 'take-001 in #take-list',
    () => [...document.querySelectorAll('#take-list option')].some((o) => o.value === 'take-001'));
  summary.takeList = await performer.evaluate(() => [...document.querySelectorAll('#take-list option')].map((o) => o.textContent));
  summary.take = await performer.evaluate(() => window.puppetry.takes?.find((t) => t.name === 'take-001'));
  summary.afterState = await performer.textContent('#take-state');
  if (ELAPSED.test(summary.afterState)) throw new Error(`#take-state still says ${summary.afterState}`);
  await waitFor(performer, 'take-001 to be chosen and playable after the recording',
    () => document.getElementById('take-list').value === 'take-001'
      && !document.querySelector('#take-list option[value="take-001"]').disabled
      && !document.getElementById('take-play').disabled && !document.getElementById('take-overdub').disabled
      && document.getElementById('record').textContent === '● rec');
  await waitFor(viewer, 'the viewer to see the take end', () => !document.getElementById('take-state').classList.contains('recording'));
  await shot(performer, 'stopped-performer');

  step('a take is not served without the director\'s token');
  // What a link on any page would fire: no Authorization header (asked
  // from here, not the page, whose console would log the refusals).
  summary.bare = await Promise.all(['/takes/take-001.take', '/takes/take-001/export?format=glb']
    .map((p) => fetch(new URL(p, url), { cache: 'no-store' }).then((r) => r.status)));
  if (summary.bare.some((s) => s !== 401)) throw new Error(`without a token the take and its export answered ${summary.bare}, not 401`);

  step('download the take as glTF from the take list');
  await performer.selectOption('#take-list', 'take-001');
  await performer.selectOption('#take-format', 'glb');
  const [download] = await Promise.all([
    performer.waitForEvent('download', { timeout: 30_000 }),
    performer.click('#take-download'),
  ]);
  const head = fs.readFileSync(await download.path()).subarray(0, 4).toString('latin1');
  summary.download = { name: download.suggestedFilename(), head };
  if (head !== 'glTF' || summary.download.name !== 'take-001.glb') {
    throw new Error(`the download is ${JSON.stringify(summary.download)}, not take-001.glb`);
  }
  // Every page hears how the export went.
  await waitFor(viewer, 'the export to end on the viewer page',
    () => window.puppetry.export?.finished === true && !window.puppetry.export.error);

  step('overdub take-001, replacing the part its hand dragged');
  await performer.bringToFront();
  await performer.click('#take-replace');
  await performer.mouse.click(x, y);
  await waitFor(performer, 'a replace region where the drag began', () => window.puppetry.replaceRegions().length === 1);
  summary.replace = await performer.evaluate(() => window.puppetry.replaceRegions());
  await performer.click('#take-overdub');
  // Seen at once with the state: the one stop, and nothing else to play.
  await waitFor(performer, 'the overdub recording take-002 over take-001, with one stop',
    () => window.puppetry.take?.recording === 'take-002' && window.puppetry.take?.playing === 'take-001'
      && document.getElementById('record').textContent === '■ stop'
      && document.getElementById('take-play').disabled && document.getElementById('take-overdub').disabled
      && ![...document.querySelectorAll('#take-controls button')].some((b) => b.id !== 'record' && !b.hidden && /stop/i.test(b.textContent)));
  await waitFor(performer, 'the overdub to end with take-001',
    () => window.puppetry.take && !window.puppetry.take.recording && !window.puppetry.take.playing);

  summary.errors = [...errors, ...(await performer.evaluate(() => window.puppetry.errors)),
    ...(await viewer.evaluate(() => window.puppetry.errors))];
  step('done');
  await context.close();
  if (summary.errors.length) finish(false, 'the pages reported errors');
  finish(true);
} catch (err) {
  const p = await pageState(performer);
  const v = await pageState(viewer);
  Object.assign(summary, { status: p.status, viewerStatus: v.status, errors: [...errors, ...p.errors, ...v.errors] });
  finish(false, err.message.split('\n')[0]);
}
