// Headless-browser check that a director sees a source holding the puppet
// and can let it go (issue 45): a TUIO sender that died mid-touch is not a
// person, yet the people list shows it with how many contacts it holds;
// its "×" lets go, and its handle leaves every page.
//
//   PUPPETRY_URL='http://127.0.0.1:PORT/?role=director&token=T' \
//   PUPPETRY_POINT='640,360' PUPPETRY_HOLDER='tuio:table' node release.mjs
//
// Prints one JSON line: {before, after} (the holder's legend entry, then
// the contact handles left); exits 0 only on success, and within 2
// minutes either way.

import { endPages, openPage, startScript, waitFor } from './page-common.mjs';

const { url, viewerUrl, summary, finish, launch } = startScript();
const holder = process.env.PUPPETRY_HOLDER ?? 'tuio:table';
const errors = [];
const pages = {};
let context;

// The legend entry of `owner` on page `p`: its text, or null.
const entry = (p, owner) => p.evaluate((o) => {
  const e = [...document.querySelectorAll('#people .person')].find((x) => x.dataset.owner === o);
  return e ? { text: e.textContent, button: Boolean(e.querySelector('.let-go')) } : null;
}, owner);

try {
  summary.step = 'launch';
  context = await launch();
  pages.director = await openPage(context, url, errors, 'director');
  pages.viewer = await openPage(context, viewerUrl, errors, 'viewer');
  summary.step = 'the holder in the legends';
  for (const p of Object.values(pages)) {
    await waitFor(p, `${holder} holding one contact in the legend`, (o) => [...document.querySelectorAll('#people .person')]
      .some((e) => e.dataset.owner === o && e.querySelector('.holds')?.textContent === '✋1'), holder);
  }
  summary.before = await entry(pages.director, holder);
  const viewerEntry = await entry(pages.viewer, holder);
  if (!summary.before.button) throw new Error(`the director has no let-go button for ${holder}`);
  if (viewerEntry.button) throw new Error('a viewer has a let-go button');
  summary.step = 'let go';
  await pages.director.click(`#people .person[data-owner="${holder}"] .let-go`);
  for (const [name, p] of Object.entries(pages)) {
    await waitFor(p, `${name}: ${holder}'s handle to go`, (o) => !Object.values(window.puppetry.handles)
      .some((hs) => hs.some((h) => h.owner === o && h.kind === 'contact')), holder);
    await waitFor(p, `${name}: ${holder} to leave the legend`, (o) => ![...document.querySelectorAll('#people .person')]
      .some((e) => e.dataset.owner === o), holder);
  }
  summary.after = await pages.director.evaluate(() => Object.values(window.puppetry.handles).flat().filter((h) => h.kind === 'contact').length);
  summary.step = 'done';
  await endPages({ context, pages, errors, summary, finish });
} catch (err) {
  await endPages({ err, context, pages, errors, summary, finish });
}
