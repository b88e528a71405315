// Headless-browser check of the page's soundtrack (issue 35): a director
// picks a sound file (♪), presses record and drags the puppet: the sound
// plays from the take's start, in time with the take's clock; a page
// that joins the take later and picks the same file plays it from where
// the take is, not from its own start; stopping stops the sound, and
// playing the take back plays it again from the take's start.
//
//   PUPPETRY_URL='http://127.0.0.1:PORT/?role=director&token=T' \
//   PUPPETRY_POINT='640,360' node soundtrack.mjs
//
// The daemon records into an empty takes folder (the take is take-001).
// Prints one JSON line; exits 0 only on success, and within 2 minutes either way.

import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { startScript, endPages, openPage, stageToClient, waitFor } from './page-common.mjs';

const { url, point, summary, finish, launch } = startScript();

const errors = [];
const pages = {};
let context;
const step = (what) => { summary.step = what; };
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
// How far the sound may be from the take's time as the page reckons it
// from the daemon's clock (the page's clock guess, a check every 0.5 s).
// Against this script's own clock the sound may only be late, by the
// click's way to the daemon: on a busy two-core machine that can take
// longer than the tolerance, and it is not the soundtrack's doing.
const TOLERANCE = 0.3;

// 30 s of silence, 8 kHz mono 16-bit.
function silence(file) {
  const n = 8000 * 30;
  const b = Buffer.alloc(44 + 2 * n);
  b.write('RIFF', 0); b.writeUInt32LE(36 + 2 * n, 4); b.write('WAVEfmt ', 8);
  b.writeUInt32LE(16, 16); b.writeUInt16LE(1, 20); b.writeUInt16LE(1, 22);
  b.writeUInt32LE(8000, 24); b.writeUInt32LE(16000, 28); b.writeUInt16LE(2, 32); b.writeUInt16LE(16, 34);
  b.write('data', 36); b.writeUInt32LE(2 * n, 40);
  fs.writeFileSync(file, b);
}

// The page's sound against the take's time measured here from `t0`
// (`off`) and against the page's own reckoning of it (`lag`).
async function offBy(page, t0) {
  const s = await page.evaluate(() => window.puppetry.soundtrack());
  const truth = (Date.now() - t0) / 1000;
  return { ...s, truth, off: s.at - truth, lag: s.at - s.expected };
}

try {
  const wav = path.join(fs.mkdtempSync(path.join(os.tmpdir(), 'puppetry-sound-')), 'song.wav');
  silence(wav);
  step('launch');
  context = await launch();
  pages.director = await openPage(context, url, errors, 'director');
  const { director } = pages;
  await director.setInputFiles('#soundtrack-file', wav);
  await waitFor(director, 'the soundtrack loaded', () => window.puppetry.soundtrack().loaded);
  if ((await director.evaluate(() => window.puppetry.soundtrack())).playing) throw new Error('the sound plays with no take');

  step('record, and drag the puppet');
  const t0 = Date.now();
  await director.click('#record');
  await waitFor(director, 'take-001 recording', () => window.puppetry.take?.recording === 'take-001');
  const [x, y] = await stageToClient(director, point);
  await director.mouse.move(x, y);
  await director.mouse.down();
  for (let k = 1; k <= 10; k += 1) {
    await director.mouse.move(x + 6 * k, y + 4 * k);
    await sleep(60);
  }
  await director.mouse.up();
  await waitFor(director, 'the sound playing', () => window.puppetry.soundtrack().playing);
  await sleep(500);
  summary.recording = await offBy(director, t0);
  if (Math.abs(summary.recording.lag) > TOLERANCE || summary.recording.off > TOLERANCE) {
    throw new Error(`while recording the sound is ${summary.recording.lag.toFixed(3)} s off the take (${summary.recording.off.toFixed(3)} s off this script's clock)`);
  }

  step('a page joining the take plays from where it is');
  pages.late = await openPage(context, url, errors, 'late');
  await pages.late.setInputFiles('#soundtrack-file', wav);
  await waitFor(pages.late, 'the late page\'s sound playing', () => window.puppetry.soundtrack().playing);
  await sleep(600);
  summary.late = await offBy(pages.late, t0);
  if (summary.late.truth < 1.5 || summary.late.at < 1 || Math.abs(summary.late.lag) > TOLERANCE
      || summary.late.off > TOLERANCE) {
    throw new Error(`the late page's sound is at ${summary.late.at.toFixed(3)} s, the take at ${summary.late.expected.toFixed(3)} s (${summary.late.truth.toFixed(3)} s by this script's clock)`);
  }

  step('stop');
  await director.click('#record');
  await waitFor(director, 'the take stopped', () => !window.puppetry.take?.recording);
  for (const [name, p] of Object.entries(pages)) {
    await waitFor(p, `${name}: the sound stopped, back at 0`, () => {
      const s = window.puppetry.soundtrack();
      return !s.playing && s.at === 0;
    });
  }

  step('play the take back');
  await waitFor(director, 'take-001 to play', () => !document.getElementById('take-play').disabled
    && [...document.querySelectorAll('#take-list option')].some((o) => o.value === 'take-001' && !o.disabled));
  await director.selectOption('#take-list', 'take-001');
  const t1 = Date.now();
  await director.click('#take-play');
  await waitFor(director, 'the take playing', () => window.puppetry.take?.playing === 'take-001');
  await waitFor(director, 'the sound playing with it', () => window.puppetry.soundtrack().playing);
  // The take's time now is the daemon's (it starts playing once it has
  // read the take): the sound against the page's reckoning of it.
  await sleep(600);
  summary.playing = await offBy(director, t1);
  const lag = summary.playing.at - summary.playing.expected;
  if (summary.playing.expected > 3 || Math.abs(lag) > TOLERANCE) {
    throw new Error(`while playing back the sound is at ${summary.playing.at.toFixed(3)} s, the take at ${summary.playing.expected.toFixed(3)} s`);
  }
  await waitFor(director, 'the take played out, the sound stopped', () => !window.puppetry.take?.playing && !window.puppetry.soundtrack().playing);

  await endPages({ context, pages, errors, summary, finish });
} catch (err) {
  await endPages({ err, pages, errors, summary, finish });
}
