// spine-player (4.2, Esoteric's web player) opens an exported skeleton as a
// user would, in headless Chromium with WebGL (SwiftShader):
//   node export-player.mjs FOLDER NAME ANIMATION
// serves FOLDER (the export: NAME.json, NAME.atlas and its pages) and the
// player, points the player at NAME.json and NAME.atlas, and waits for its
// success or error callback. Prints one JSON line {ok, loaded, error,
// failed: [URLs answered 4xx/5xx], drawn: pixels of the canvas that are
// not the background}.

import path from 'node:path';
import { HERE, launch, run, serve } from './export-common.mjs';

const page = (name, animation) => `<!doctype html><meta charset="utf-8"><title>spine-player check</title>
<link rel="icon" href="data:,">
<link rel="stylesheet" href="/player/spine-player.css">
<script src="/player/iife/spine-player.js"></script>
<div id="player" style="width: 640px; height: 480px"></div>
<script>
window.result = new Promise((resolve) => {
  new spine.SpinePlayer('player', {
    skeleton: '/export/${name}.json',
    atlas: '/export/${name}.atlas',
    animation: ${JSON.stringify(animation)},
    premultipliedAlpha: false,
    backgroundColor: '#000000ff',
    preserveDrawingBuffer: true,
    showControls: false,
    success: () => resolve({ loaded: true }),
    error: (_, message) => resolve({ loaded: false, error: String(message) }),
  });
});
</script>`;

run(async () => {
  const [folder, name, animation] = process.argv.slice(2);
  const { server, url } = await serve({
    '/': { body: page(name, animation), type: 'text/html' },
    '/export/': path.resolve(folder),
    '/player/': path.join(HERE, 'node_modules/@esotericsoftware/spine-player/dist'),
  });
  const browser = await launch({ width: 640, height: 480, webgl: true });
  const failed = [];
  browser.page.on('response', (r) => { if (r.status() >= 400) failed.push(`${r.status()} ${r.url()}`); });
  try {
    await browser.page.goto(`${url}/`);
    const result = await browser.page.evaluate(() => window.result);
    let drawn = 0;
    if (result.loaded) {
      // A few frames of the animation, then the canvas's pixels.
      await browser.page.waitForTimeout(500);
      drawn = await browser.page.evaluate(() => {
        const canvas = document.querySelector('#player canvas');
        const gl = canvas.getContext('webgl2') ?? canvas.getContext('webgl');
        const px = new Uint8Array(canvas.width * canvas.height * 4);
        gl.readPixels(0, 0, canvas.width, canvas.height, gl.RGBA, gl.UNSIGNED_BYTE, px);
        let n = 0;
        for (let i = 0; i < px.length; i += 4) if (px[i] + px[i + 1] + px[i + 2] > 30) n++;
        return n;
      });
    }
    return { ...result, failed, drawn, errors: browser.errors };
  } finally {
    await browser.close();
    server.close();
  }
});
