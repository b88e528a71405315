// Headless-browser check that a page opened later shows the live key pose
// blend (issue 12, observation 8, page side): a performer moves the key
// pose slider of a skeleton puppet to first pose → last pose at t = 0.5;
// a viewer and a second performer page opened afterwards show exactly
// that on their sliders (not the default first → second pose at 0), and
// follow when the performer moves it again.
//
//   PUPPETRY_URL='http://127.0.0.1:PORT/' PUPPETRY_POINT='640,360' PUPPETRY_TOKEN=ana node pose.mjs
//
// Optional: PUPPETRY_SCREENSHOTS=DIR, CHROMIUM=/path/to/chromium.
// Prints one JSON line; exits 0 only on success, and within 2 minutes either way.

import fs from 'node:fs';
import path from 'node:path';
import { startScript, allErrors, openPage, pageState, pageUrl, waitFor } from './page-common.mjs';

const { url, shotDir, viewerUrl, summary, finish, launch } = startScript();
const token = process.env.PUPPETRY_TOKEN ?? 'ana';

const errors = [];
const pages = {};
const step = (what) => { summary.step = what; };

async function shot(p, name) {
  if (!shotDir) return;
  fs.mkdirSync(shotDir, { recursive: true });
  fs.writeFileSync(path.join(shotDir, `${name}.png`), await p.screenshot());
}

// Moves the performer's slider as a hand would: the selects, then the range.
function setPose(p, from, to, t) {
  return p.evaluate(([f, to_, tv]) => {
    const set = (id, value, event) => {
      const e = document.getElementById(id);
      e.value = value;
      e.dispatchEvent(new Event(event, { bubbles: true }));
    };
    set('pose-from', f, 'change');
    set('pose-to', to_, 'change');
    set('pose-t', String(tv), 'input');
  }, [from, to, t]);
}

// What page `p`'s slider shows, read from the controls themselves.
const sliderOf = (p) => p.evaluate(() => ({
  from: document.getElementById('pose-from').value,
  to: document.getElementById('pose-to').value,
  t: Number(document.getElementById('pose-t').value),
  visible: document.getElementById('pose-controls').checkVisibility(),
}));

const same = (a, b) => a.from === b.from && a.to === b.to && Math.abs(a.t - b.t) < 1e-6;

try {
  step('launch');
  const context = await launch();
  step('the performer');
  pages.performer = await openPage(context, pageUrl(url, `?role=performer&token=${encodeURIComponent(token)}`), errors, 'performer');
  const performer = pages.performer;
  await waitFor(performer, 'the key pose slider', () => document.getElementById('pose-controls').checkVisibility());
  const poses = await performer.evaluate(() => [...document.getElementById('pose-from').options].map((o) => o.value));
  summary.poses = poses;
  if (poses.length < 3) throw new Error(`the skeleton has ${poses.length} key poses; the test needs 3`);
  // Not the slider's defaults (first → second at 0).
  const wanted = { from: poses[0], to: poses[poses.length - 1], t: 0.5 };
  summary.wanted = wanted;

  step('the performer moves the slider');
  await setPose(performer, wanted.from, wanted.to, wanted.t);
  await waitFor(performer, 'the server\'s pose message', (w) => {
    const p = Object.values(window.puppetry.pose)[0];
    return p && p.from === w.from && p.to === w.to && Math.abs(p.t - w.t) < 1e-6;
  }, wanted);

  step('pages opened later');
  pages.viewer = await openPage(context, viewerUrl, errors, 'viewer');
  pages.late = await openPage(context, pageUrl(url, `?role=performer&token=${encodeURIComponent(token)}`), errors, 'late performer');
  summary.newcomers = {};
  for (const name of ['viewer', 'late']) {
    await waitFor(pages[name], `${name}: the live pose on the slider`, (w) => {
      const s = window.puppetry.poseShown();
      return s && s.from === w.from && s.to === w.to && Math.abs(s.t - w.t) < 1e-6;
    }, wanted);
    const shown = await sliderOf(pages[name]);
    summary.newcomers[name] = shown;
    if (!shown.visible || !same(shown, wanted)) throw new Error(`${name}'s slider shows ${JSON.stringify(shown)}, not ${JSON.stringify(wanted)}`);
    await shot(pages[name], `pose-${name}`);
  }
  if (!(await pages.viewer.evaluate(() => document.getElementById('pose-t').disabled))) throw new Error('a viewer can move the slider');

  step('the slider follows a later move');
  const again = { from: poses[1], to: poses[0], t: 0.25 };
  await setPose(performer, again.from, again.to, again.t);
  for (const name of ['viewer', 'late']) {
    await waitFor(pages[name], `${name}: the slider to follow`, (w) => {
      const s = window.puppetry.poseShown();
      return s && s.from === w.from && s.to === w.to && Math.abs(s.t - w.t) < 1e-6;
    }, again);
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
