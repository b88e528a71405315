// Headless-browser check of depth on self-overlap (issue 13): a performer
// pins the demo figure's chest and drags its right hand across its body.
// Where the arm and the body then overlap and their pictures differ, the
// page shows the arm's picture: the fold is drawn wholly in front, not
// interleaved triangle by triangle.
//
//   PUPPETRY_URL='http://127.0.0.1:PORT/?role=performer&token=demo' PUPPETRY_POINT='640,364' node depth.mjs
//
// PUPPETRY_POINT is the chest, where the pin goes. Optional:
// PUPPETRY_SCREENSHOTS=DIR, CHROMIUM=/path/to/chromium. Prints one JSON
// line; exits 0 only on success, and within 2 minutes either way.

import fs from 'node:fs';
import path from 'node:path';
import { startScript, allErrors, openPage, pageState, settle, stageToClient, waitFor } from './page-common.mjs';

const { url, point, shotDir, summary, finish, launch } = startScript();
const errors = [];
const pages = {};
const step = (what) => { summary.step = what; };

// Of the stage points covered by two triangles of puppet 0 at different
// depths, those where the two pictures differ clearly: is the drawn pixel
// the nearer triangle's texel or the farther one's?
async function overlapPixels(p) {
  await settle(p);
  return p.evaluate(async () => {
    const api = window.puppetry;
    const puppet = api.stage.puppets[0];
    const pos = api.positions(puppet.id);
    const depths = api.depth[puppet.id]?.depths;
    if (!depths) return { error: 'no depth frame' };
    const { triangles: tri, uv } = puppet;
    const image = new Image();
    image.src = puppet.texture;
    await image.decode();
    const c = new OffscreenCanvas(image.width, image.height);
    const g = c.getContext('2d');
    g.drawImage(image, 0, 0);
    const tex = g.getImageData(0, 0, image.width, image.height).data;
    const texel = (u, v) => {
      const x = Math.min(image.width - 1, Math.max(0, Math.floor(u * image.width)));
      const y = Math.min(image.height - 1, Math.max(0, Math.floor(v * image.height)));
      const i = 4 * (y * image.width + x);
      return [tex[i], tex[i + 1], tex[i + 2], tex[i + 3]];
    };
    const { width: W, height: H } = api.stage.stage;
    const canvas = document.getElementById('gl');
    const shot = api.snapshot(); // bottom row first, as stage y is up
    const pixel = (x, y) => {
      const px = Math.min(canvas.width - 1, Math.floor((x / W) * canvas.width));
      const py = Math.min(canvas.height - 1, Math.floor((y / H) * canvas.height));
      const i = 4 * (py * canvas.width + px);
      return [shot[i], shot[i + 1], shot[i + 2]];
    };
    const distance = (a, b) => Math.abs(a[0] - b[0]) + Math.abs(a[1] - b[1]) + Math.abs(a[2] - b[2]);
    // Barycentric coordinates of (x, y) in triangle t, or null outside it.
    const inside = (t, x, y) => {
      const [a, b, cc] = [tri[3 * t], tri[3 * t + 1], tri[3 * t + 2]];
      const ax = pos[2 * a], ay = pos[2 * a + 1], bx = pos[2 * b], by = pos[2 * b + 1];
      const cx = pos[2 * cc], cy = pos[2 * cc + 1];
      const d = (by - cy) * (ax - cx) + (cx - bx) * (ay - cy);
      if (Math.abs(d) < 1e-9) return null;
      const l1 = ((by - cy) * (x - cx) + (cx - bx) * (y - cy)) / d;
      const l2 = ((cy - ay) * (x - cx) + (ax - cx) * (y - cy)) / d;
      const l3 = 1 - l1 - l2;
      // Well inside: pixels on an edge blend both sides.
      return l1 > 0.1 && l2 > 0.1 && l3 > 0.1 ? [l1, l2, l3] : null;
    };
    const texelOf = (t, l) => {
      const v = [tri[3 * t], tri[3 * t + 1], tri[3 * t + 2]];
      const u = l[0] * uv[2 * v[0]] + l[1] * uv[2 * v[1]] + l[2] * uv[2 * v[2]];
      const w = l[0] * uv[2 * v[0] + 1] + l[1] * uv[2 * v[1] + 1] + l[2] * uv[2 * v[2] + 1];
      return texel(u, w);
    };
    const n = tri.length / 3;
    const boxes = Array.from({ length: n }, (_, t) => {
      const xs = [0, 1, 2].map((k) => pos[2 * tri[3 * t + k]]);
      const ys = [0, 1, 2].map((k) => pos[2 * tri[3 * t + k] + 1]);
      return [Math.min(...xs), Math.min(...ys), Math.max(...xs), Math.max(...ys)];
    });
    let covered = 0, telling = 0, near = 0, far = 0;
    for (let x = 0.5; x < W; x += 3) {
      for (let y = 0.5; y < H; y += 3) {
        const over = [];
        for (let t = 0; t < n; t++) {
          const b = boxes[t];
          if (x < b[0] || x > b[2] || y < b[1] || y > b[3]) continue;
          const l = inside(t, x, y);
          if (l) over.push([t, l]);
        }
        if (over.length < 2) continue;
        over.sort((a, b) => depths[a[0]] - depths[b[0]]);
        const [back, front] = [over[0], over[over.length - 1]];
        if (depths[back[0]] === depths[front[0]]) continue;
        covered++;
        const [tb, tf] = [texelOf(...back), texelOf(...front)];
        if (tb[3] < 250 || tf[3] < 250 || distance(tb, tf) < 90) continue;
        telling++;
        const drawn = pixel(x, y);
        if (distance(drawn, tf) < distance(drawn, tb)) near++; else far++;
      }
    }
    return { covered, telling, near, far };
  });
}

try {
  step('launch');
  const context = await launch();
  pages.performer = await openPage(context, url, errors, 'performer');
  const performer = pages.performer;

  step('the chest is pinned');
  const pinsBefore = await performer.evaluate(() => (window.puppetry.handles[0] ?? []).filter((h) => h.kind === 'pin').length);
  const [cx, cy] = await stageToClient(performer, point);
  await performer.keyboard.down('Shift');
  await performer.mouse.click(cx, cy);
  await performer.keyboard.up('Shift');
  await waitFor(performer, 'the chest pin', (n) => (window.puppetry.handles[0] ?? []).filter((h) => h.kind === 'pin').length > n, pinsBefore);

  step('the hand is dragged across the body');
  const hand = await performer.evaluate(() => {
    const rest = window.puppetry.stage.puppets[0].rest;
    let best = 0;
    for (let i = 0; i < rest.length; i += 2) if (rest[i] > rest[best]) best = i;
    return [rest[best] - 15, rest[best + 1]];
  });
  const to = [point[0] - 30, point[1] - 14];
  const [hx, hy] = await stageToClient(performer, hand);
  await performer.mouse.move(hx, hy);
  await performer.mouse.down();
  for (let k = 1; k <= 12; k++) {
    const at = [hand[0] + ((to[0] - hand[0]) * k) / 12, hand[1] + ((to[1] - hand[1]) * k) / 12];
    const [x, y] = await stageToClient(performer, at);
    await performer.mouse.move(x, y);
  }
  await waitFor(performer, 'a depth frame with the fold', () => {
    const d = window.puppetry.depth[0]?.depths;
    return d && d.some((v) => v !== d[0]);
  });
  // The newest vertex frame too: the hand has reached its target.
  await waitFor(performer, 'the hand at its target', ([x, y]) => {
    const p = window.puppetry.stage.puppets[0];
    const pos = window.puppetry.positions(p.id);
    let best = 0;
    for (let i = 0; i < p.rest.length; i += 2) if (p.rest[i] > p.rest[best]) best = i;
    return Math.hypot(pos[best] - 15 - x, pos[best + 1] - y) < 40;
  }, to);

  step('the overlap shows the arm');
  summary.pixels = await overlapPixels(performer);
  if (shotDir) {
    fs.mkdirSync(shotDir, { recursive: true });
    fs.writeFileSync(path.join(shotDir, 'depth-fold.png'), await performer.screenshot());
  }
  const { telling, near, far } = summary.pixels;
  if (!(telling >= 30)) throw new Error(`too few overlap samples where the pictures differ: ${JSON.stringify(summary.pixels)}`);
  if (near < 0.9 * telling) throw new Error(`the overlap shows the part behind: ${JSON.stringify(summary.pixels)}`);
  await performer.mouse.up();

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
