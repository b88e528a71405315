// Headless-browser check of MIDI learn on the page (issue 35): a
// director's page shows the MIDI controls of a stage with a MIDI input;
// the director picks "gingerbread: cursor y", presses "learn MIDI" (the
// button says to move a control), and a controller's knob (CC 40 on
// channel 1, written to the stage's MIDI port) is learnt (CC 0, which the
// stage already maps, is passed over first, saying so): the page says
// what it does and where it was saved, and the knob moves the cursor at
// once. A performer's page has no MIDI controls.
//
//   PUPPETRY_URL='http://127.0.0.1:PORT/' PUPPETRY_MIDI_PORT=/path/to/fifo \
//   PUPPETRY_DIRECTOR=director node midi.mjs
//
// Prints one JSON line; exits 0 only on success, and within 2 minutes either way.

import fs from 'node:fs';
import { startScript, endPages, openPage, pageUrl, waitFor } from './page-common.mjs';

const { url, summary, finish, launch } = startScript();
const directorToken = process.env.PUPPETRY_DIRECTOR ?? 'director';
const port = process.env.PUPPETRY_MIDI_PORT;

const errors = [];
const pages = {};
let context;
const step = (what) => { summary.step = what; };

try {
  if (!port) throw new Error('PUPPETRY_MIDI_PORT names no MIDI port');
  step('launch');
  context = await launch();
  pages.director = await openPage(context, pageUrl(url, `?role=director&token=${encodeURIComponent(directorToken)}`), errors, 'director');
  pages.performer = await openPage(context, pageUrl(url, '?role=performer&token=demo'), errors, 'performer');
  const { director, performer } = pages;

  step('the MIDI controls');
  await waitFor(director, 'the MIDI inputs', () => window.puppetry.inputs?.midi?.inputs?.length > 0);
  await waitFor(director, 'the MIDI controls shown', () => document.querySelector('#midi-controls')?.checkVisibility());
  await waitFor(performer, 'the performer\'s inputs', () => window.puppetry.inputs !== null);
  if (await performer.evaluate(() => document.querySelector('#midi-controls')?.checkVisibility())) {
    throw new Error('a performer has the MIDI controls');
  }

  step('learn');
  await director.selectOption('#midi-target', { label: 'gingerbread: cursor y' });
  await director.click('#midi-learn');
  await waitFor(director, 'waiting for a control', () => window.puppetry.inputs?.midi?.waiting?.action === 'cursor_y');
  summary.waiting = await director.textContent('#midi-learn');
  if (!summary.waiting.includes('move a control')) throw new Error(`the learn button says ${summary.waiting}`);
  // A control the input already maps (CC 0: the cursor's x) is passed
  // over, saying so, and the wait goes on.
  fs.writeFileSync(port, Buffer.from([0xB0, 0, 64]));
  await waitFor(director, 'the mapped control passed over', () => /already does/.test(document.querySelector('#midi-status')?.textContent ?? ''));
  summary.passed_over = await director.textContent('#midi-status');
  if (!(await director.evaluate(() => !!window.puppetry.inputs?.midi?.waiting))) throw new Error('a mapped control ended the wait');
  // A clock byte teaches nothing; the knob does.
  fs.writeFileSync(port, Buffer.from([0xF8, 0xB0, 40, 100]));
  await waitFor(director, 'the mapping learnt', () => /saved to/.test(document.querySelector('#midi-status')?.textContent ?? ''));
  summary.status = await director.textContent('#midi-status');
  summary.button = await director.textContent('#midi-learn');

  step('the learnt knob works at once');
  fs.writeFileSync(port, Buffer.from([0xB0, 40, 127]));
  await waitFor(director, 'the cursor at y 1', () => window.puppetry.keys[0]?.cursor?.[1] === 1);

  await endPages({ context, pages, errors, summary, finish });
} catch (err) {
  await endPages({ err, pages, errors, summary, finish });
}
