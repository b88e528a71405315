// The real web renderer (clients/web, unchanged) draws given vertices, for
// comparison with the exporter's own rasteriser:
//   node export-render.mjs SCENE.json OUT_DIR
// SCENE.json: {stage: {width, height}, size: [W, H], puppets: [{name,
// texture: PNG file, uv: [u0, v0, …], triangles: [i, j, k, …]}], frames:
// [{name, positions: [[x0, y0, x1, y1, …] per puppet]}]}.
// Serves the page and a stand-in for the daemon's stream (docs/protocol.md:
// the stage message, then binary vertex frames) on 127.0.0.1, opens the page
// in headless Chromium (WebGL on SwiftShader) at W×H CSS pixels with a
// device pixel ratio of 1, and for each frame sends its vertices, waits for
// the page to have them, and writes the GL canvas's pixels (the page's
// snapshot(): no overlay) to OUT_DIR/NAME.rgba, RGBA rows top to bottom.

import fs from 'node:fs';
import path from 'node:path';
import { WebSocketServer } from 'ws';
import { ROOT, launch, run, serve } from './export-common.mjs';


run(async () => {
  const [sceneFile, outDir] = process.argv.slice(2);
  const scene = JSON.parse(fs.readFileSync(sceneFile, 'utf8'));
  const [width, height] = scene.size;
  // clients/web's files at the root, as the daemon serves them; the pictures.
  const web = path.join(ROOT, 'clients/web');
  const types = { '.js': 'text/javascript', '.css': 'text/css', '.html': 'text/html' };
  const routes = {};
  for (const name of fs.readdirSync(web)) {
    routes[`/${name}`] = { body: fs.readFileSync(path.join(web, name)), type: types[path.extname(name)] ?? 'text/plain' };
  }
  routes['/'] = routes['/index.html'];
  scene.puppets.forEach((p, id) => {
    routes[`/puppets/${id}/texture.png`] = { body: fs.readFileSync(p.texture), type: 'image/png' };
  });
  let socket = null;
  let onSocket;
  const connected = new Promise((resolve) => { onSocket = resolve; });
  const { server, url } = await serve(routes, (srv) => {
    const wss = new WebSocketServer({ server: srv, path: '/ws' });
    wss.on('connection', (ws) => {
      ws.on('message', (data, isBinary) => {
        const msg = isBinary ? null : JSON.parse(data.toString());
        if (msg?.type !== 'hello') return;
        ws.send(JSON.stringify({
          type: 'stage', client: 1, role: 'viewer', stage: scene.stage,
          puppets: scene.puppets.map((p, id) => ({
            id, name: p.name, texture: `/puppets/${id}/texture.png`,
            rest: scene.frames[0].positions[id], uv: p.uv, triangles: p.triangles,
            handles: [], weights: Array(p.triangles.length / 3).fill(1), rig: { kind: 'free' },
          })),
        }));
        socket = ws;
        onSocket(ws);
      });
    });
  });
  const browser = await launch({ width, height, webgl: true });
  let sequence = 0;
  const written = [];
  try {
    const { page } = browser;
    // The show view: only the puppets, filling the window (no toolbar).
    await page.goto(`${url}/?view=show`);
    await connected;
    await page.waitForFunction(() => window.puppetry?.connected && window.puppetry.ready);
    const canvas = await page.evaluate(() => [document.getElementById('gl').width, document.getElementById('gl').height]);
    if (canvas[0] !== width || canvas[1] !== height) throw new Error(`canvas is ${canvas}, expected ${width}x${height}`);
    fs.mkdirSync(outDir, { recursive: true });
    for (const frame of scene.frames) {
      sequence++;
      frame.positions.forEach((pos, id) => {
        const n = pos.length / 2;
        const buf = Buffer.alloc(32 + 8 * n);
        buf.writeUInt32LE(1, 0);
        buf.writeUInt32LE(id, 4);
        buf.writeBigUInt64LE(BigInt(sequence), 8);
        buf.writeDoubleLE(0, 16);
        buf.writeUInt32LE(n, 24);
        pos.forEach((v, i) => buf.writeFloatLE(v, 32 + 4 * i));
        socket.send(buf);
      });
      await page.waitForFunction(([s, count]) => {
        const seen = window.puppetry.lastSequence;
        for (let id = 0; id < count; id++) if (seen[id] !== s) return false;
        return true;
      }, [sequence, frame.positions.length]);
      const base64 = await page.evaluate(() => {
        const px = window.puppetry.snapshot();
        let text = '';
        for (let i = 0; i < px.length; i += 0x8000) text += String.fromCharCode(...px.subarray(i, i + 0x8000));
        return btoa(text);
      });
      const bytes = Buffer.from(base64, 'base64');
      const rows = Buffer.alloc(width * height * 4);
      for (let y = 0; y < height; y++) {
        // snapshot() is bottom row first.
        bytes.copy(rows, y * width * 4, (height - 1 - y) * width * 4, (height - y) * width * 4);
      }
      const file = path.join(outDir, `${frame.name}.rgba`);
      fs.writeFileSync(file, rows);
      written.push(file);
    }
    const errors = await page.evaluate(() => window.puppetry.errors);
    if (errors.length || browser.errors.length) throw new Error([...errors, ...browser.errors].join('\n'));
    return { written };
  } finally {
    await browser.close();
    server.close();
  }
});
